"""
The cases of the work-precision report, each method swept against a stated reference.

``precision_cases`` measures the Fig. 4 oscillator (exact reference), Fig. 9a and a
parcel straddling all three zones (the accurate method at 1e-12, cross-checked against
scipy) and the Fig. 13 two-belt positioning (exact for constant μ, cross-checked for the
B-spline law); ``sweeps`` says which settings each family runs at. Each method is
measured against its own model: the accurate and implicit methods (and scipy on the
same model) decide sticks by the exact limit set, the threshold method (and scipy on
the threshold model) is the seed's decoupled stick test, so its reference is the
accurate method on the seed's stick law (``seed_reference``); the difference between
the two references is a difference of models, reported apart from any error. ``bench`` turns the
rows into the report and shares the Fig. 9a case and the cross-check tolerance with its
core benchmark.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial

from sorter_sim.model.core.oscillator import Oscillator
from sorter_sim.studies import stiff_cases as sx
from sorter_sim.studies.precision_report import PrecisionCase
from sorter_sim.studies.scipy_baseline import ScipyParcel, oscillator_scipy
from sorter_sim.studies.workprecision import (
    ParcelCase,
    Trajectory,
    WPRow,
    compare,
    fmt_e,
    fmt_ms,
    measure,
    oscillator_core,
    oscillator_exact,
    oscillator_trajectory,
)

SCIPY_METHODS = ("RK45", "DOP853", "Radau", "BDF", "LSODA")


def fig9a_case() -> ParcelCase:
    """Seed Fig. 9a with rotation: 0.7 x 0.2 m, v = 1.5 m/s, α = 90°, μ = 0.6, b -> ∞."""
    return sx.sorting_case(t_max=3.0)


def three_zone_case() -> ParcelCase:
    """
    Return the three-zone precision case.

    config/scenes/three_zones.yaml with zones.b = 0.6 m (so that it scraps): 0.6 x 0.3 m,
    φ0 = 30°, v = 1.2 m/s, α = 60°, μ = 0.6 in every zone; the parcel straddles a, b, c.
    """
    return sx.sorting_case(v=1.2, alpha_deg=60.0, b=0.6, A=0.6, B=0.3, phi0_deg=30.0, t_max=3.0)


@dataclass
class Sweeps:
    acc_rtol: tuple
    imp_dt: tuple
    thr_dt: tuple
    thr_vmin: tuple
    scipy: dict  # method -> rtols
    scipy_thr: dict  # method -> rtols (threshold model)
    repeats: int
    budget_s: float
    max_rhs: float = 4e5  # scipy runs stop (and count as failures) beyond this


def sweeps(quick: bool, long_case: bool) -> Sweeps:
    """
    Return the settings per family; a long case (20 s or more) skips the finest fixed steps.

    Parameters
    ----------
    quick : bool
        Coarse grids, for tests and quick looks.
    long_case : bool
        Include the long two-belt case.

    Returns
    -------
    Sweeps
        The settings swept for each method.

    """
    if quick:
        return Sweeps(
            acc_rtol=(1e-4, 1e-6, 1e-8, 1e-10),
            imp_dt=(1e-2, 3e-3) if long_case else (1e-2, 1e-3, 1e-4),
            thr_dt=(1e-2, 3e-3) if long_case else (1e-3, 1e-4),
            thr_vmin=() if long_case else (1e-3, 1e-6, 1e-9),
            scipy={"DOP853": (1e-4, 1e-7, 1e-10)}
            if long_case
            else {
                "RK45": (1e-4, 1e-7),
                "DOP853": (1e-4, 1e-7, 1e-10),
                "Radau": (1e-4, 1e-7),
                "LSODA": (1e-6,),
                "BDF": (1e-6,),
            },
            scipy_thr={} if long_case else {"RK45": (1e-6,)},
            repeats=2,
            budget_s=0.3,
            # scipy's explicit methods resolve an exact stick's break-away layer step by
            # step (1e4-4e5 evaluations on Fig. 9a): a quick report reports them past
            # this, each such run at a few seconds of Python right-hand sides
            max_rhs=2e4,
        )
    return Sweeps(
        acc_rtol=(1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11),
        imp_dt=(1e-2, 3e-3, 1e-3, 3e-4, 1e-4) + (() if long_case else (3e-5, 1e-5)),
        thr_dt=(1e-2, 3e-3, 1e-3, 3e-4) + (() if long_case else (1e-4, 3e-5, 1e-5)),
        thr_vmin=(1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9),
        scipy={m: (1e-3, 1e-5, 1e-7, 1e-9, 1e-11) for m in SCIPY_METHODS},
        scipy_thr={} if long_case else {"RK45": (1e-3, 1e-6, 1e-9), "LSODA": (1e-3, 1e-6, 1e-9)},
        repeats=5,
        budget_s=2.0,
        max_rhs=1e5 if long_case else 4e5,
    )


def core_settings(
    sw: Sweeps, v_min: float, thr_vmin_dt: float
) -> list[tuple[str, str, str, dict]]:
    """
    Return the core's settings a sweep runs: (family, setting, method, its arguments) each.

    The accurate method by rtol (atol = rtol / 100), the implicit method by step, the
    threshold model by step at ``v_min`` and by v_min at the step ``thr_vmin_dt``: one
    list, so that the oscillator and the parcels sweep the same families by one name.
    """
    out = [
        ("accurate (rtol)", f"rtol={rt:g}", "accurate", {"rtol": rt, "atol": rt * 1e-2})
        for rt in sw.acc_rtol
    ]
    out += [("implicit (h)", f"h={dt:g}", "implicit", {"dt": dt}) for dt in sw.imp_dt]
    by_h = [(f"h={dt:g}", dt, v_min) for dt in sw.thr_dt]
    by_v_min = [(f"v_min={vm:g}", thr_vmin_dt, vm) for vm in sw.thr_vmin]
    for family, sweep in (
        (f"threshold (h, v_min={v_min:g})", by_h),
        (f"threshold (v_min, h={thr_vmin_dt:g})", by_v_min),
    ):
        out += [
            (family, setting, "threshold", {"dt": dt, "v_min": vm}) for setting, dt, vm in sweep
        ]
    return out


def scipy_runs(sp: ScipyParcel, method: str, rtol: float, budget: float, threshold: bool = False):
    """
    Return the timed run of a scipy setting (atol = rtol / 100) and the run it is judged on.

    The timed run keeps no dense output, which would cost scipy time the core does not
    spend; its error is taken on a second, dense run of the same setting. ``threshold``:
    the seed's threshold model at v_min = 1e-6 instead of the exact stick.
    """
    go = sp.run_threshold if threshold else sp.run
    more = {"v_min": 1e-6} if threshold else {}
    return (
        lambda: go(method, rtol, rtol * 1e-2, max_rhs=budget, **more),
        lambda _: sp.finish(go(method, rtol, rtol * 1e-2, max_rhs=budget, dense=True, **more)),
    )


def on_seed_law(family: str) -> bool:
    """Return True for a family whose own model is the seed's stick law (the threshold model)."""
    return family.startswith("threshold") or "threshold model" in family


def seed_reference(case: ParcelCase) -> Trajectory:
    """
    Return the converged solution of the seed's stick law: the threshold method's own model.

    The accurate method at rtol = atol = 1e-12 with the seed's decoupled stick test
    (|F| <= F_max, |T| <= T_max, eqs. 4.2 and 4.4); the threshold method tends to it as
    h and v_min fall, not to the exact-stick solution.
    """
    return case.core("accurate", rtol=1e-12, atol=1e-12, stick="seed")


def _measured(name, family, setting, run, ref, finish, key, sw: Sweeps, log) -> WPRow:
    """Measure one setting of a case (``workprecision.measure``) and log its line."""
    r = measure(
        name,
        family,
        setting,
        run,
        ref,
        finish,
        sw.repeats,
        sw.budget_s,
        key,
    )
    log(
        f"  {name:<12} {family:<28} {setting:<18} {fmt_ms(r.wall_s):>8} ms  "
        f"err {fmt_e(r.errors.final) if r.errors else '–':>8}  {r.failure}"
    )
    return r


def _parcel_rows(
    name: str,
    case: ParcelCase,
    sw: Sweeps,
    refs: tuple[Trajectory, Trajectory],
    v_min: float,
    thr_vmin_dt: float,
    log,
) -> list[WPRow]:
    """Measure every family on ``case``, each against its own model's reference of ``refs``."""
    rows = []
    sp = ScipyParcel(case)
    ref, ref_seed = refs

    def add(family, setting, run, finish, key=None):
        own = ref_seed if on_seed_law(family) else ref
        rows.append(_measured(name, family, setting, run, own, finish, key, sw, log))

    for family, setting, method, kw in core_settings(sw, v_min, thr_vmin_dt):
        add(
            family,
            setting,
            partial(case.run_core, method, **kw),
            case.trajectory,
            f"core-{method}",
        )
    for meth, rtols in sw.scipy.items():
        for rt in rtols:
            run, finish = scipy_runs(sp, meth, rt, sw.max_rhs)
            add(f"scipy {meth} (rtol)", f"rtol={rt:g}", run, finish, f"scipy-{meth}")
    for meth, rtols in sw.scipy_thr.items():
        for rt in rtols:
            run, finish = scipy_runs(sp, meth, rt, sw.max_rhs, threshold=True)
            add(f"scipy {meth} threshold model", f"rtol={rt:g}", run, finish, f"scipy-thr-{meth}")
    return rows


def cross_check_tol(quick: bool) -> float:
    """
    Return scipy DOP853's rtol = atol for cross-checking a reference.

    1e-13 resolves an exact stick's break-away layer to round-off but costs 20-50 s a
    parcel case on this model; the quick report cross-checks at 1e-10 (2-6 s a case,
    agreement to ~1e-9 m), which still catches any model or event defect (a wrong
    zone force or a missed event moves the end by millimetres); 1e-11 took twice as
    long for a tenfold agreement the quick report does not need.

    Parameters
    ----------
    quick : bool
        Coarse grids, for tests and quick looks.

    Returns
    -------
    float
        The tolerance [m].

    """
    return 1e-10 if quick else 1e-13


def _reference(case: ParcelCase, label: str, log, quick: bool) -> tuple[Trajectory, list]:
    """
    Return the reference run of a case and its cross-checks.

    Accurate method at rtol = atol = 1e-12, cross-checked against scipy DOP853 on the
    same model (rtol = atol = ``cross_check_tol``, stick phases in closed form).
    """
    w = time.perf_counter()
    ref = case.core("accurate", rtol=1e-12, atol=1e-12)
    sp = ScipyParcel(case)
    tol = cross_check_tol(quick)
    cross = sp.finish(sp.run("DOP853", tol, tol, dense=True))
    e = compare(cross, ref)
    log(
        f"  {label}: reference and cross-check in {time.perf_counter() - w:.1f} s; "
        f"difference {e.final:.1e} m (final), {e.grid_max:.1e} m (1 kHz grid)"
    )
    return ref, [(f"scipy DOP853, rtol = atol = {tol:g}, on the same model", e)]


# the report's cases by group, in its order: the oscillator, the two parcels, the two belts
CASE_GROUPS = ("fig4", "fig9a", "three_zones", "fig13")


def precision_cases(quick: bool, log=print, groups=CASE_GROUPS) -> list[PrecisionCase]:
    """
    Measure the cases of the work-precision report, each method swept against its reference.

    Parameters
    ----------
    quick : bool
        Coarse grids, for tests and quick looks.
    log : callable, optional
        Progress lines go here.
    groups : sequence of str, optional
        Which of ``CASE_GROUPS`` to measure (default: all); ``fig13`` is two cases.

    Returns
    -------
    list of PrecisionCase
        The measured cases, in the report's order.

    """
    out = [_fig4_case(quick, log)] if "fig4" in groups else []
    out += _parcel_cases(quick, log, [k for k in ("fig9a", "three_zones") if k in groups])
    if "fig13" in groups:
        out += _fig13_cases(quick, log)
    return out


def _fig4_case(quick: bool, log) -> PrecisionCase:
    """
    Measure the Fig. 4 oscillator, every method against the exact piecewise solution.

    The one case with a closed-form reference, hence no cross-check; it has its own
    ``add`` because the body is no parcel: ``oscillator_trajectory`` turns each run into
    the trajectory that the errors are taken on.
    """
    osc = Oscillator()
    t_osc = 30.0
    log("Fig. 4 oscillator")
    ref = oscillator_exact(osc, t_osc)
    pc = PrecisionCase(
        "fig4",
        "Fig. 4 stick-slip body (30 s)",
        "m = 1 kg, F_kin = 1 N, F_stat = 1.5 N, k = 2 N/m, ẋ_s = 0.1 m/s, from rest; "
        "first rest ends at 7.5 s, then slip/stick cycles (4 events in 30 s).",
        ref,
        "exact piecewise Coulomb solution (`oscillator.exact_solution`)",
    )
    sw = sweeps(quick, long_case=False)
    rows = pc.rows

    def add(family, setting, run, finish, key):
        rows.append(_measured("fig4", family, setting, run, ref, finish, key, sw, log))

    def fin(res):
        return oscillator_trajectory(osc, res)

    keys = {"accurate": "osc-acc", "implicit": "osc-imp", "threshold": "osc-thr"}
    for family, setting, method, kw in core_settings(sw, 1e-3, 1e-4):
        add(family, setting, partial(oscillator_core, osc, t_osc, method, **kw), fin, keys[method])
    for meth, rtols in sw.scipy.items():
        for rt in rtols:
            add(
                f"scipy {meth} (rtol)",
                f"rtol={rt:g}",
                lambda m=meth, rt=rt: oscillator_scipy(osc, t_osc, m, rt, rt * 1e-2),
                lambda _, m=meth, rt=rt: oscillator_scipy(
                    osc, t_osc, m, rt, rt * 1e-2, dense=True
                ),
                f"osc-scipy-{meth}",
            )
    return pc


def _parcel_cases(quick: bool, log, keys=("fig9a", "three_zones")) -> list[PrecisionCase]:
    """
    Measure Fig. 9a and the three-zone parcel (those of ``keys``) against checked references.

    A rotating parcel has no closed form: the reference is the accurate method at
    rtol = atol = 1e-12, checked against scipy DOP853 on the same model (``_reference``).
    """
    out = []
    for key, title, about, make_case in (
        (
            "fig9a",
            "Fig. 9a diversion with rotation",
            "0.7 x 0.2 m, 5 kg, v = 1.5 m/s, α = 90°, μa = μb = 0.6, b -> ∞, φ0 = 0, from the "
            "leading edge on the a/b border to the scrap line s = 0.7 m.",
            fig9a_case,
        ),
        (
            "three_zones",
            "Parcel straddling all three zones",
            "config/scenes/three_zones.yaml with zones.b = 0.6 m: 0.6 x 0.3 m, φ0 = 30°, "
            "v = 1.2 m/s, α = 60°, μ = 0.6 in a, b and c.",
            three_zone_case,
        ),
    ):
        if key not in keys:
            continue  # nor made: a part of the report builds only its own case
        case = make_case()
        log(title)
        ref, cross = _reference(case, key, log, quick)
        pc = PrecisionCase(
            key,
            title,
            about,
            ref,
            "accurate method at rtol = atol = 1e-12, cross-checked against scipy "
            f"DOP853 (rtol = atol = {cross_check_tol(quick):g}) on the same model",
            cross,
        )
        pc.seed_reference = seed_reference(case)
        pc.rows = _parcel_rows(
            key, case, sweeps(quick, False), (ref, pc.seed_reference), 1e-6, 1e-4, log
        )
        out.append(pc)
    return out


def _fig13_cases(quick: bool, log) -> list[PrecisionCase]:
    """
    Measure 20 s of Fig. 13 two-belt positioning: constant μ, then the B-spline law.

    Constant μ has an exact solution (a frictional harmonic oscillator), against which
    the accurate method is itself checked; the B-spline law has none, so its reference is
    cross-checked twice: by scipy and by an independent 1-D ODE of the friction law alone.
    """
    out = []
    t13 = 20.0
    log("Fig. 13 two belts, constant μ")
    case = sx.two_belt_case(sx.const_law(0.6), t13)
    ref = sx.two_belt_exact(case, 0.6)
    acc = case.core("accurate", rtol=1e-12, atol=1e-12)
    pc = PrecisionCase(
        "fig13_const",
        "Fig. 13 two-belt positioning, constant μ = 0.6 (20 s)",
        "Belts at ±0.37 m/s meeting at x = 0, 0.4 x 0.3 m, 5 kg, let go at rest "
        "5 cm off the centre line, rotation on.",
        ref,
        "exact: x = x0 cos ωt, ω² = 2μg/A (a frictional harmonic oscillator while "
        "|ẋ| < v; the rotation the model allows stays at round-off level)",
        [("accurate method, rtol = atol = 1e-12", compare(acc, ref))],
    )
    pc.seed_reference = seed_reference(case)
    pc.rows = _parcel_rows(
        "fig13_const", case, sweeps(quick, True), (ref, pc.seed_reference), 1e-6, 1e-3, log
    )
    out.append(pc)
    log("Fig. 13 two belts, B-spline law")
    case = sx.two_belt_case(sx.bspline_law(), t13)
    ref, cross = _reference(case, "fig13_bspline", log, quick)
    one_d = sx.two_belt_1d(case, sx.bspline_law())
    cross.append(
        (
            "independent 1-D ODE ẍ = (g/A)[μ(v-ẋ)(A/2-x) - μ(v+ẋ)(A/2+x)], DOP853 "
            "rtol 1e-13 (friction law only: no clipping, no wrench code)",
            compare(one_d, ref),
        )
    )
    pc = PrecisionCase(
        "fig13_bspline",
        "Fig. 13 two-belt positioning, B-spline law (20 s)",
        "As above with the default B-spline characteristic (model 1): the oscillation decays.",
        ref,
        "accurate method at rtol = atol = 1e-12, cross-checked as listed",
        cross,
    )
    pc.seed_reference = seed_reference(case)
    pc.rows = _parcel_rows(
        "fig13_bspline", case, sweeps(quick, True), (ref, pc.seed_reference), 1e-6, 1e-3, log
    )
    out.append(pc)
    return out
