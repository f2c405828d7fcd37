"""
``sorter bench``: what accuracy each integration method buys for its run time.

``sorter bench core`` prints the core benchmark: the seed's Fig. 9a diversion with
rotation (0.7 x 0.2 m, v = 1.5 m/s, α = 90°, μ = 0.6, b -> ∞), for every method the
wall time per diversion after compilation (minimum of several runs, one CPU) and its
error against a reference, and whether the targets are met: accurate method within
1e-6 m of the reference CoG position at t_scrap in at most 0.5 ms, at least 20x
faster than the best of scipy's solve_ivp methods on the same model at the same error,
and the implicit method at most 3 µs per 1 ms step with its error below 1e-7 m at
small steps (no floor, constant μ).

``sorter bench precision [--quick] [--out DIR]`` writes DIR/accuracy.md and
DIR/img/accuracy_*.png: work-precision tables and log-log plots for the Fig. 4
oscillator, Fig. 9a, a parcel straddling all three zones and the Fig. 13 two-belt
positioning, then the stiff/extreme-case matrix (``stiff_cases``), the stiff and
extreme cases of parcels that touch (``contact_cases``), 10 minutes of two-belt
positioning and the reductions. ``--quick`` (coarse sweeps, the matrix's
quick subset, 20 s of two-belt positioning) is what the test suite runs.

The measuring itself is ``workprecision`` and the report's cases are
``precision_cases``; this module only chooses the core benchmark's settings and words.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from sorter_sim.model.core.simulate import three_zone_strips
from sorter_sim.studies.contact_cases import contact_rows
from sorter_sim.studies import stiff_cases as sx
from sorter_sim.studies.outpaths import dir_problem
from sorter_sim.studies.precision_cases import (
    CASE_GROUPS,
    SCIPY_METHODS,
    cross_check_tol,
    fig9a_case,
    on_seed_law,
    precision_cases,
    scipy_runs,
    seed_reference,
)
from sorter_sim.studies.precision_report import (
    QUICK_LONG_S,
    TARGET_ERROR,
    PrecisionParts,
    _report_markdown,
    _scipy_rows,
)
from sorter_sim.studies.progress import progress_bar
from sorter_sim.studies.reductions import reductions
from sorter_sim.studies.scipy_baseline import ScipyParcel
from sorter_sim.studies.workprecision import (
    Errors,
    ParcelCase,
    Trajectory,
    WPRow,
    cheapest_within,
    compare,
    fmt_e,
    fmt_ms,
    machine_info,
    machine_line,
    measure,
    one_core,
)

TARGET_TIME = 0.5e-3  # s per diversion, one core
TARGET_IMPLICIT_STEP = 3e-6  # s per 1 ms implicit step
TARGET_IMPLICIT_FLOOR = 1e-7  # m: the implicit method's error gets below it (constant μ)
TARGET_SPEEDUP = 20.0  # against the best scipy method at the same error


# the report's parts, in its order; `--parts` picks some (the suite checks them one by one):
# its cases by group (``cases`` names the four), then the benchmark and the stability runs
REPORT_PARTS = CASE_GROUPS + ("core", "matrix", "contact", "long", "reductions", "quadrature")


def report_parts(names) -> list[str]:
    """
    Return the parts a ``--parts`` list names, ``cases`` standing for every case group.

    Raises ``ValueError`` naming what is unknown and what is allowed.

    Parameters
    ----------
    names : str or sequence of str
        Comma-separated part names (``--parts``), or the names.

    Returns
    -------
    list of str
        The parts, each once, in the report's order.

    """
    text = names if isinstance(names, str) else ",".join(map(str, names))
    named = {x.strip() for x in text.split(",") if x.strip()}
    if "cases" in named:
        named = (named - {"cases"}) | set(CASE_GROUPS)
    bad = sorted(named - set(REPORT_PARTS))
    if bad or not named:
        raise ValueError(
            f"--parts must list some of cases ({', '.join(CASE_GROUPS)}), "
            f"{', '.join(REPORT_PARTS[len(CASE_GROUPS) :])}, got {text!r}"
            + (f" (unknown: {', '.join(bad)})" if bad else "")
        )
    return [p for p in REPORT_PARTS if p in named]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """
    Add the verb's arguments to its parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's parser.

    """
    sub = parser.add_subparsers(dest="bench_what", metavar="WHAT")
    p = sub.add_parser(
        "precision",
        help="write the work-precision report (docs/accuracy.md)",
        description="Work-precision report: tables, log-log plots, the stiff-case "
        "matrix and the reductions, written to OUT/accuracy.md and OUT/img/.",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="coarse sweeps, the matrix's quick subset, 20 s of two-belt positioning "
        "(under a minute)",
    )
    p.add_argument(
        "--out",
        default=None,
        help="output directory (default: docs for the full report; out/precision_quick for "
        "--quick, so that a quick run never overwrites the committed report)",
    )
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no progress bar (there is none either when stderr is not a terminal)",
    )
    p.add_argument(
        "--parts",
        default=",".join(REPORT_PARTS),
        metavar="LIST",
        help="comma-separated parts of the report to run (default all: cases, that is "
        f"{','.join(CASE_GROUPS)}, then {','.join(REPORT_PARTS[len(CASE_GROUPS) :])})",
    )
    c = sub.add_parser(
        "core",
        help="the core benchmark: Fig. 9a, every method, targets",
        description="Fig. 9a diversion with rotation: time per diversion and error "
        "for every method, scipy's solve_ivp included.",
    )
    c.add_argument(
        "--repeats",
        type=int,
        default=7,
        help="timed runs per setting, the minimum is reported (default 7)",
    )
    c.add_argument("--quick", action="store_true", help="fewer settings")


def run(args) -> int | str | None:
    """
    Run ``sorter bench``: the precision report or the core benchmark.

    Parameters
    ----------
    args : argparse.Namespace
        The verb's parsed arguments.

    Returns
    -------
    int or str
        The exit code, or a message for a refused input.

    """
    what = getattr(args, "bench_what", None)
    if what is None:
        return (
            "say what to run: 'sorter bench precision [--quick] [--out DIR]' or "
            "'sorter bench core'"
        )
    if what == "core":
        if not 1 <= args.repeats <= 1000:
            return f"--repeats must be an integer in [1, 1000], got {args.repeats}"
        text, _ = bench_core(repeats=args.repeats, quick=args.quick)
        print(text)
        return 0
    try:
        parts = report_parts(args.parts)
    except ValueError as exc:
        return str(exc)
    out = Path(args.out or ("out/precision_quick" if args.quick else "docs"))
    problem = dir_problem(out) or dir_problem(out / "img")
    if problem:
        return problem
    path = write_precision_report(out, quick=args.quick, log=print, parts=parts, quiet=args.quiet)
    print(f"wrote {path}")
    return 0


# ---------------------------------------------------------------------------- the cases


def implicit_exact_convergence(
    case: ParcelCase, ref: Trajectory, quick: bool
) -> list[tuple[float, float]]:
    """
    Measure the implicit method's error at ever smaller steps on a constant-μ case: (h, error).

    With constant μ its step takes the exact wrench, so the error should fall at first
    order with no floor; the smallest step shows whether it gets below 1e-7 m.

    Parameters
    ----------
    case : ParcelCase
        The case.
    ref : Trajectory
        The reference trajectory.
    quick : bool
        Coarse grids, for tests and quick looks.

    Returns
    -------
    list of (float, float)
        (h, error) pairs.

    """
    steps = (1e-4, 1e-5) if quick else (1e-5, 1e-6, 5e-7)
    return [(h, compare(case.core("implicit", dt=h), ref).final) for h in steps]


def implicit_quadrature_floor(quick: bool) -> list[tuple[int, float, float]]:
    """
    Measure the implicit method's quadrature floor with a speed-dependent μ.

    There μ is lagged at fixed Gauss points (n_quad² per centroid-fan triangle), which
    resolve the kink of the slip speed at the instantaneous centre only to a limited
    order: the error stops falling. Fig. 9a with the default B-spline law on both
    belts and disks at a small step, final CoG error against the accurate method at
    rtol 1e-12 for several n_quad: (n_quad, h, error).

    Parameters
    ----------
    quick : bool
        Coarse grids, for tests and quick looks.

    Returns
    -------
    list of (int, float, float)
        (points, h, error) rows.

    """
    base = fig9a_case()
    law = sx.bspline_law()
    strips = three_zone_strips(1.5, math.radians(90.0), math.inf, law, law)
    case = ParcelCase(base.parcel, strips, base.y0, base.t_span, base.y_target, True)
    ref = case.core("accurate", rtol=1e-12, atol=1e-12)
    h = 1e-4 if quick else 3e-5
    out = []
    for nq in (4, 8) if quick else (4, 8, 16):
        c = ParcelCase(case.parcel, case.strips, case.y0, case.t_span, case.y_target, True, nq)
        out.append((nq, h, compare(c.core("implicit", dt=h), ref).final))
    return out


# ---------------------------------------------------------------------------- bench core
def bench_core(repeats: int = 7, quick: bool = False, log=None) -> tuple[str, dict]:
    """
    Return the core benchmark on Fig. 9a; returns the printed text and the headline figures.

    Parameters
    ----------
    repeats : int
        Timed repeats; the best counts.
    quick : bool
        Coarse grids, for tests and quick looks.
    log : callable, optional
        Progress lines go here.

    Returns
    -------
    (str, dict)
        The report's text and its figures.

    """
    log = log or (lambda s: None)
    case = fig9a_case()
    with one_core():
        info = machine_info()
        ref = case.core("accurate", rtol=1e-12, atol=1e-12)
        ref_seed = seed_reference(case)
        sp = ScipyParcel(case)
        tol = cross_check_tol(quick)
        cross = compare(sp.finish(sp.run("DOP853", tol, tol, dense=True)), ref)
        rows = _core_rows(case, (ref, ref_seed), sp, repeats, quick, log)
    gap = compare(ref_seed, ref)
    lines = _core_table(rows, info, repeats, (ref, ref_seed, gap), tol, cross)
    figures = {
        "t_scrap_ref": ref.t_end,
        "t_scrap_ref_seed": ref_seed.t_end,
        "law_gap_m": gap.final,
        "cross_check_m": cross.final,
    }
    lines += _core_targets(rows, case, ref, quick, figures)
    return "\n".join(lines), figures


def _core_rows(
    case: ParcelCase, refs: tuple, sp: ScipyParcel, repeats: int, quick: bool, log
) -> list[WPRow]:
    """
    Time every method of the core benchmark on ``case``; its error against its own model.

    The core's three methods, then scipy's on the same model, then scipy on the seed's
    threshold model: the targets compare the core with the best of scipy at one error.
    ``refs`` is (exact-stick reference, seed-law reference): the threshold rows (the
    seed's stick test) are measured against the second (``on_seed_law``).
    Each row is measured at 5 s of budget at most, so that a slow scipy setting is a row
    that says so rather than a benchmark that does not end.
    """
    acc = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-10) if not quick else (1e-6, 1e-8)
    rows: list[WPRow] = []
    # scipy's explicit methods resolve the break-away layer step by step: past 1e5
    # evaluations a quick run reports the setting as over budget (RK45 at rtol 1e-7 needs
    # more than 4e5) rather than spend ten seconds a row finding out
    budget = 1e5 if quick else 4e5

    def add(family, setting, run, finish, key):
        own = refs[1] if on_seed_law(family) else refs[0]
        r = measure("fig9a", family, setting, run, own, finish, repeats, 5.0, key)
        rows.append(r)
        log(f"{family} {setting}: {fmt_ms(r.wall_s)} ms")

    for rt in acc:
        add(
            "accurate",
            f"rtol={rt:g}, atol={rt * 1e-2:g}",
            lambda rt=rt: case.run_core("accurate", rtol=rt, atol=rt * 1e-2),
            case.trajectory,
            "a",
        )
    for dt in (1e-3, 1e-4) if not quick else (1e-3,):
        add(
            "implicit",
            f"h={dt:g}",
            lambda dt=dt: case.run_core("implicit", dt=dt),
            case.trajectory,
            "i",
        )
    for dt in (1e-3, 1e-4) if not quick else (1e-4,):
        add(
            "threshold",
            f"h={dt:g}, v_min=1e-6",
            lambda dt=dt: case.run_core("threshold", dt=dt, v_min=1e-6),
            case.trajectory,
            "t",
        )
    scipy_rtols = (1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10) if not quick else (1e-7, 1e-9)
    for meth in SCIPY_METHODS if not quick else ("RK45", "DOP853"):
        for rt in scipy_rtols:
            run, finish = scipy_runs(sp, meth, rt, budget)
            add(f"scipy {meth}", f"rtol={rt:g}, atol={rt * 1e-2:g}", run, finish, f"s-{meth}")
    run, finish = scipy_runs(sp, "RK45", 1e-6, budget, threshold=True)
    add("scipy RK45, threshold model", "rtol=1e-6, v_min=1e-6", run, finish, "s-thr")
    return rows


def _core_table(
    rows: list[WPRow], info: dict, repeats: int, refs: tuple, tol: float, cross: Errors
) -> list[str]:
    """
    Return the core benchmark's heading and its table, a row a measured setting.

    The heading states what the figures rest on (the machine, the two references, how
    far they differ and how far scipy's cross-check agrees), so that a reader can judge
    the table alone. ``refs`` is (exact-stick reference, seed-law reference, their gap).
    """
    ref, ref_seed, gap = refs
    lines = [
        "sorter bench core: seed Fig. 9a with rotation (0.7 x 0.2 m, v = 1.5 m/s, α = 90°, "
        "μ = 0.6, b = inf)",
        f"machine: {machine_line(info)}; timed on one CPU, minimum of up to {repeats} runs "
        "after an untimed warm-up of each of the core's methods",
        f"reference: accurate method, rtol = atol = 1e-12: t_scrap = {ref.t_end:.10f} s, "
        f"CoG ({ref.q[-1, 0]:.10f}, {ref.q[-1, 1]:.10f}) m, φ = {math.degrees(ref.q[-1, 2]):.6f}°",
        f"cross-check: scipy DOP853 (rtol = atol = {tol:g}, stick phases in closed form) differs "
        f"by {cross.final:.1e} m at t_scrap, {cross.grid_max:.1e} m at most on a 1 kHz grid, "
        f"{cross.events.get('scrap', math.nan):.1e} s in t_scrap",
        f"threshold rows' own model, the seed's stick law: accurate method, stick = seed, "
        f"rtol = atol = 1e-12: t_scrap = {ref_seed.t_end:.10f} s, CoG ({ref_seed.q[-1, 0]:.10f}, "
        f"{ref_seed.q[-1, 1]:.10f}) m; the two laws differ by {gap.final:.1e} m at t_scrap, "
        f"{gap.events.get('scrap', math.nan):.1e} s in t_scrap (models, not errors)",
        "error: |CoG(t) - CoG_ref(t)| at the reference's t_scrap [m]; Δt_scrap [s]; each row "
        "against its own model's reference",
        "",
    ]
    head = (
        f"{'method':<30} {'setting':<24} {'ms/diversion':>12} {'runs':>4} {'rhs':>7} "
        f"{'CoG err [m]':>11} {'Δt_scrap [s]':>12}  status"
    )
    lines.append(head)
    lines.append("-" * len(head))
    for r in rows:
        e = r.errors
        lines.append(
            f"{r.family:<30} {r.setting:<24} {fmt_ms(r.wall_s):>12} {r.n_runs or '–':>4} "
            f"{r.n_rhs or '–':>7} {fmt_e(e.final) if e else '–':>11} "
            f"{fmt_e(e.events.get('scrap', math.nan)) if e else '–':>12}  {r.failure or 'ok'}"
        )
    return lines


def _core_targets(
    rows: list[WPRow], case: ParcelCase, ref: Trajectory, quick: bool, figures: dict
) -> list[str]:
    """
    Return the verdict lines on the three targets; their headline figures go into ``figures``.

    Each target is judged on the cheapest setting within 1e-6 m, not on a chosen one, so
    that a faster method that misses the error cannot meet it; the implicit method's
    target also runs its convergence (``implicit_exact_convergence``) to show no floor.
    """
    acc_rows = [r for r in rows if r.family == "accurate"]
    scipy_rows = _scipy_rows(rows)
    best_acc = cheapest_within(acc_rows, TARGET_ERROR)
    best_scipy = cheapest_within(scipy_rows, TARGET_ERROR)
    default = next((r for r in acc_rows if r.setting.startswith("rtol=1e-08")), None)
    lines = [""]
    if best_acc:
        ok_err = best_acc.errors.final <= TARGET_ERROR
        ok_time = best_acc.wall_s <= TARGET_TIME
        lines.append(
            f"target 1: accurate error <= 1e-6 m in <= 0.5 ms: {best_acc.setting} gives "
            f"{best_acc.errors.final:.1e} m in {best_acc.wall_s * 1e3:.2f} ms -> "
            f"{'MET' if ok_err and ok_time else 'NOT MET'}"
        )
        figures.update(
            acc_setting=best_acc.setting,
            acc_err=best_acc.errors.final,
            acc_ms=best_acc.wall_s * 1e3,
        )
    else:
        lines.append("target 1: no accurate setting reached 1e-6 m -> NOT MET")
    if default and default.errors:
        lines.append(
            f"          (default rtol = 1e-8, atol = 1e-10: {default.errors.final:.1e} m in "
            f"{default.wall_s * 1e3:.2f} ms)"
        )
        figures.update(default_err=default.errors.final, default_ms=default.wall_s * 1e3)
    if best_acc and best_scipy:
        ratio = best_scipy.wall_s / best_acc.wall_s
        lines.append(
            f"target 2: >= 20x faster than scipy at the same error (<= 1e-6 m): best scipy is "
            f"{best_scipy.family} {best_scipy.setting}, {best_scipy.errors.final:.1e} m in "
            f"{best_scipy.wall_s * 1e3:.2f} ms -> {ratio:.1f}x -> "
            f"{'MET' if ratio >= TARGET_SPEEDUP else 'NOT MET'}"
        )
        figures.update(
            scipy_best=f"{best_scipy.family} {best_scipy.setting}",
            scipy_ms=best_scipy.wall_s * 1e3,
            scipy_err=best_scipy.errors.final,
            speedup=ratio,
        )
    else:
        lines.append("target 2: no scipy run within its budget reached 1e-6 m -> cannot compare")
    imp = next((r for r in rows if r.family == "implicit" and r.setting == "h=0.001"), None)
    if imp and imp.errors:
        per_step = imp.wall_s / (ref.t_end / 1e-3)
        conv = implicit_exact_convergence(case, ref, quick)
        # no floor: the error still falls at (at least 0.7 of) first order at the smallest steps
        falling = all(e1 <= 1.0 / 0.7 * e0 * h1 / h0 for (h0, e0), (h1, e1) in zip(conv, conv[1:]))
        floor_ok = falling and conv[-1][1] < TARGET_IMPLICIT_FLOOR
        lines.append(
            f"target 3: implicit <= 3 µs per 1 ms step with its error floor below 1e-7 m "
            f"(constant μ): {per_step * 1e6:.2f} µs ({imp.errors.final:.1e} m at h = 1 ms); "
            + ", ".join(f"{e:.1e} m at h = {h:g} s" for h, e in conv)
            + f" ({'falling at first order, no floor' if falling else 'a floor'}) -> "
            f"{'MET' if per_step <= TARGET_IMPLICIT_STEP and floor_ok else 'NOT MET'}"
        )
        figures["implicit_us_per_step"] = per_step * 1e6
        figures["implicit_convergence"] = conv
    for fam in ("implicit", "threshold"):
        r = next((r for r in rows if r.family == fam and r.errors), None)
        if r:
            figures[f"{fam}_setting"] = r.setting
            figures[f"{fam}_err"] = r.errors.final
            figures[f"{fam}_ms"] = r.wall_s * 1e3
    return lines


def write_precision_report(
    out: Path, quick: bool = False, log=print, parts=REPORT_PARTS, quiet: bool = True
) -> Path:
    """
    Run the report's ``parts`` (default all) and write OUT/accuracy.md and OUT/img/*.png.

    Unless ``quiet``, a progress bar on a terminal counts the parts (each case of the
    matrix one part); ``log`` lines are written above it.

    Parameters
    ----------
    out : Path
        The report's folder.
    quick : bool
        Coarse grids, for tests and quick looks.
    log : callable, optional
        Progress lines go here.
    parts : sequence of str, optional
        The report's parts to run (default: all; ``cases`` stands for every case group).
    quiet : bool
        No bar.

    Returns
    -------
    Path
        The report.

    """
    t_start = time.perf_counter()
    parts = report_parts(parts)  # ``cases`` as every case group
    matrix = sx.matrix(quick=quick) if "matrix" in parts else []
    bar = progress_bar(
        len(parts) - ("matrix" in parts) + len(matrix), "bench precision", "part", quiet=quiet
    )
    say = log

    def log(line):
        # printed lines go above the bar; another logger gets them as they are
        if say is print:
            bar.write(line)
        else:
            say(line)

    def done(what):
        bar.set_postfix_str(what)
        bar.update(1)

    img = out / "img"
    img.mkdir(parents=True, exist_ok=True)
    info = machine_info()
    cases, core_text, core_fig, matrix_runs, contact_runs, long_runs, red_rows, quad = (
        [],
        None,
        {},
        [],
        [],
        [],
        [],
        (),
    )
    with one_core():
        for group in CASE_GROUPS:
            if group in parts:
                cases += precision_cases(quick, log, (group,))
                done(group)
        if "core" in parts:
            log("benchmark (Fig. 9a)")
            core_text, core_fig = bench_core(repeats=3 if quick else 7, quick=quick)
            done("core")
        if "matrix" in parts:
            log("stiff/extreme-case matrix")
        for sc in matrix:
            w = time.perf_counter()
            runs = sx.run_case(sc)
            matrix_runs.append((sc, runs))
            log(
                f"  {sc.name:<22} {time.perf_counter() - w:6.1f} s  "
                + " ".join(f"{r.method}:{'pass' if r.passed else 'FAIL'}" for r in runs)
            )
            done(sc.name)
        if "contact" in parts:
            log("parcels that touch: stiff and extreme cases")
            contact_runs = contact_rows(quick=quick, log=log)
            done("contact")
        if "long" in parts:
            log("two-belt positioning, long runs")
            long_runs = sx.two_belt_long(QUICK_LONG_S if quick else 600.0)
            done("long")
        if "reductions" in parts:
            log("reductions")
            red_rows = reductions(repeats=2 if quick else 7)
            done("reductions")
        if "quadrature" in parts:
            log("implicit method: quadrature order")
            quad = implicit_quadrature_floor(quick)
            done("quadrature")
    bar.close()
    md = _report_markdown(
        PrecisionParts(
            cases=cases,
            core_text=core_text,
            core_fig=core_fig,
            matrix_runs=matrix_runs,
            contact_runs=contact_runs,
            long_runs=long_runs,
            red_rows=red_rows,
            quad=quad,
        ),
        info=info,
        quick=quick,
        img=img,
        elapsed=time.perf_counter() - t_start,
    )
    path = out / "accuracy.md"
    path.write_text(md)
    return path
