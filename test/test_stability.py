"""
Stiff and extreme cases, and the references of the work-precision report.

Stiff and extreme cases: the quick subset of the matrix, plus the references
the work-precision report stands on, checked against closed forms and independent solvers.

The full matrix, 10 minutes of two-belt positioning and the quick report run behind the
``slow`` marker. Bounds and tolerances are stated in ``sorter_sim.studies.stiff_cases``.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sorter_sim.model.core.oscillator import Oscillator
from sorter_sim.model.core.simulate import three_zone_strips
from sorter_sim.studies import stiff_cases as sx
from sorter_sim.studies.bench import REPORT_PARTS, report_parts
from sorter_sim.studies.reductions import reductions
from sorter_sim.studies.scipy_baseline import ScipyParcel, oscillator_scipy
from sorter_sim.studies.workprecision import (
    _WARM,
    ParcelCase,
    Trajectory,
    _cpu_now,
    compare,
    dp5_pieces,
    measure,
    one_core,
    oscillator_core,
    oscillator_exact,
    oscillator_trajectory,
)


def _matrix_params(quick: bool):
    params = []
    for sc in sx.matrix(quick=quick):
        for method in sc.methods:
            marks = []
            known = sx.KNOWN_DEFECTS.get((sc.name, method))
            if known:
                marks.append(pytest.mark.xfail(strict=True, reason=f"core defect: {known}"))
            params.append(pytest.param(sc.name, method, id=f"{sc.name}-{method}", marks=marks))
    return params


def _run_one(name: str, method: str, quick: bool):
    sc = next(c for c in sx.matrix(quick=quick) if c.name == name)
    sc.methods = {method: sc.methods[method]}
    (run,) = sx.run_case(sc)
    failed = [f"{c.name}: {c.detail}" for c in run.checks if not c.passed]
    assert not failed, f"{name} / {method} ({run.setting}): " + "; ".join(failed)


@pytest.mark.parametrize("name,method", _matrix_params(quick=True))
def test_quick_matrix_case(name, method):
    _run_one(name, method, quick=True)


_QUICK = {(c.name, m) for c in sx.matrix(quick=True) for m in c.methods}


@pytest.mark.slow
@pytest.mark.parametrize(
    "name,method", [p for p in _matrix_params(quick=False) if tuple(p.values) not in _QUICK]
)
def test_full_matrix_case(name, method):
    _run_one(name, method, quick=False)


# ------------------------------------------------------------------ references used by the report
def test_two_belt_constant_mu_is_the_exact_harmonic_oscillator():
    """Constant μ: x = x0 cos ωt with ω² = 2μg/A; tolerance-scaled error of the accurate run."""
    case = sx.two_belt_case(sx.const_law(0.6), 10.0)
    exact = sx.two_belt_exact(case, 0.6)
    rtol, atol = 1e-9, 1e-11
    run = case.core("accurate", rtol=rtol, atol=atol)
    grid = np.linspace(0.0, 10.0, 2001)
    x = run.at(grid)[0][:, 0]
    x_ref = exact.at(grid)[0][:, 0]
    scaled = np.abs(x - x_ref) / (atol + rtol * np.abs(x_ref))
    # the global error of a 10 s run (about 9 periods) stays within a few hundred local tolerances
    assert scaled.max() < 500, scaled.max()
    # and the implicit method converges to it at first order
    errs = []
    for dt in (2e-3, 5e-4):
        imp = case.core("implicit", dt=dt)
        errs.append(np.abs(imp.at(grid)[0][:, 0] - x_ref).max())
    assert 2.5 < errs[0] / errs[1] < 6.0, errs


def test_the_implicit_method_with_constant_mu_has_no_quadrature_floor():
    """
    Check that the implicit method converges at first order on Fig. 9a, with no floor.

    Its friction over a rotating parcel's patch was once summed over fixed Gauss
    points, which do not resolve the kink of the slip speed at the instantaneous
    centre: the error stalled near 3e-5 m (n_quad 8) whatever the step. With constant
    μ the step takes the exact wrench: the error falls tenfold with the step, to the
    1e-6 m level, against the accurate method at rtol 1e-12 (itself checked against
    the regularised reference and the closed forms). Its solve costs at most two
    wrench evaluations a step on average.
    """
    case = sx.sorting_case(t_max=3.0)
    ref = case.core("accurate", rtol=1e-12, atol=1e-12)
    errs = [compare(case.core("implicit", dt=dt), ref).final for dt in (1e-4, 1e-5)]
    assert 8.0 < errs[0] / errs[1] < 12.0 and errs[1] < 2e-6, errs
    res = case.run_core("implicit", dt=1e-3)
    assert res.success and res.nfev <= 2 * res.n_steps, (res.nfev, res.n_steps)


def _tiny_fast_scene(method: str, dt: float = 1e-3) -> dict:
    """Fig. 9a with a 1 cm parcel at 10 m/s on μ = 3: it crosses the a/b border in 1 ms."""
    from sorter_sim.runtime.scene import apply_overrides, load_scene

    return apply_overrides(
        load_scene(Path(__file__).parents[1] / "config" / "scenes" / "fig9a.yaml"),
        [
            "parcel.A=0.01",
            "parcel.B=0.01",
            "belt.v=10",
            "zones.mu_a=3",
            "zones.mu_b=3",
            f"solver.method={method}",
            f"solver.dt={dt:g}",
        ],
    )


def test_a_parcel_crossing_a_border_inside_one_implicit_step_keeps_its_turn():
    """
    Check that the implicit method resolves a zone border a step would jump.

    The 1 cm parcel at 10 m/s passes the a/b border in one 1 ms step: taken whole, the
    step carried it from the belt onto the disks with no moment between and it reached
    the scrap line unturned (φ 0.0°, where the accurate method gives 8.10°). The
    parcel turns while it straddles the border, where the belt and the disks pull its
    halves different ways: the step is now split there into sub-steps that pass the
    border in at least ``CROSSING_STEPS``. The turn must match the accurate method's
    within 0.3° (first-order error of the sub-steps; 8.13° at h = 1e-5 s unsplit).
    """
    from sorter_sim.runtime.scene import run_scene

    acc = run_scene(_tiny_fast_scene("accurate"))[1]["phi_scrap_deg"]
    imp = run_scene(_tiny_fast_scene("implicit"))[1]["phi_scrap_deg"]
    assert abs(acc - 8.10) < 0.01, acc
    assert abs(imp - acc) < 0.3, (imp, acc)


def test_the_implicit_method_splits_no_step_away_from_the_borders():
    """
    Check that Fig. 9a at h = 1 ms takes one step per millisecond: no sub-steps.

    Its 0.7 m parcel passes the border at 1.5 m/s in some 470 steps, far more than
    ``CROSSING_STEPS``: the common case must not pay for the small fast one.
    """
    case = sx.sorting_case(t_max=3.0)
    res = case.run_core("implicit", dt=1e-3)
    assert res.success, res.message
    assert res.n_steps == math.ceil(res.t[-1] / 1e-3 - 1e-9), (res.n_steps, res.t[-1])


def test_a_slip_breaking_away_leaves_the_kink_under_a_speed_dependent_mu():
    """
    Check that the implicit method's slip grows after a break-away with a lagged μ.

    Fig. 9a with the B-spline law: the point set's friction has its kink at the belt's
    velocity, where Newton's steps from a start on the kink shrink to nothing. A solve
    once stopped there, the parcel riding on at the belt's speed after the break, and
    the error grew as the step shrank (1.7e-4 m at 1e-4 s, 6.7e-4 m at 3e-5 s). Now
    it stays at the point set's quadrature floor (about 3e-5 m at n_quad 8).
    """
    base = sx.sorting_case(t_max=3.0)
    law = sx.bspline_law()
    case = ParcelCase(
        base.parcel,
        three_zone_strips(1.5, math.radians(90.0), math.inf, law, law),
        base.y0,
        base.t_span,
        base.y_target,
    )
    ref = case.core("accurate", rtol=1e-12, atol=1e-12)
    errs = [compare(case.core("implicit", dt=dt), ref).final for dt in (1e-4, 3e-5)]
    assert errs[1] < 1e-4 and errs[1] < 1.2 * errs[0], errs


def test_an_oscillation_between_belts_is_not_taken_for_an_approach_to_a_stick():
    """
    Check that slips the other belt slows, never to zero, stay with the full model.

    Two belts at ±0.37 m/s and a parcel oscillating 5 cm about their parting line: its
    slip on each belt falls and rises every cycle between 0.1 and 0.64 m/s and never
    reaches zero, so no stick approaches. At rtol 1e-6 the accurate method once
    carried each fall in ln |slip| (predicted to reach zero within five steps), where
    the turn before zero is stiff: 35 such runs, 11 359 right-hand sides for 294
    steps. Now: the exact oscillator within 5e-6 m over the 17 cycles (some tens of
    local tolerances), at most 10 evaluations a step.
    """
    case = sx.two_belt_case(sx.const_law(0.6), 20.0)
    exact = sx.two_belt_exact(case, 0.6)
    res = case.run_core("accurate", rtol=1e-6, atol=1e-8)
    assert res.success, res.message
    assert res.nfev <= 10 * res.n_steps, (res.nfev, res.n_steps)
    grid = np.linspace(0.0, 20.0, 4001)
    x = case.trajectory(res).at(grid)[0][:, 0]
    assert np.abs(x - exact.at(grid)[0][:, 0]).max() < 5e-6


def test_two_belt_bspline_against_the_independent_1d_ode():
    """
    Check the B-spline two-belt case against the independent 1-D ODE.

    B-spline law: the planar model (clipping, quadrature wrench) against the 1-D ODE that
    uses the friction law alone; and the oscillation decays.
    """
    case = sx.two_belt_case(sx.bspline_law(), 6.0)
    one_d = sx.two_belt_1d(case, sx.bspline_law())
    run = case.core("accurate", rtol=1e-10, atol=1e-12)
    e = compare(run, one_d)
    assert e.grid_max < 1e-8, e
    assert abs(run.q[-1, 0]) < 0.5 * abs(case.y0[0])


def test_scipy_on_the_same_model_agrees_with_the_accurate_method():
    """
    Check two independent integrators of Fig. 9a against each other.

    Fig. 9a: two independent integrators of the same hybrid model (the core's event-located
    Dormand-Prince and solve_ivp with closed-form stick phases) agree far below 1e-6 m.
    """
    case = sx.sorting_case()
    ref = case.core("accurate", rtol=1e-10, atol=1e-12)
    sp = ScipyParcel(case)
    other = sp.finish(sp.run("DOP853", 1e-10, 1e-12, dense=True))
    e = compare(other, ref)
    assert e.grid_max < 1e-7, e
    assert e.events["scrap"] < 1e-8 and e.events["break"] < 1e-8 and e.events["stick"] < 1e-6, e
    assert not e.missing, e


@pytest.mark.parametrize(
    "family, compiles, runs",
    [
        ("family", True, 1 + 3),
        ("family", False, 3),
        ("accurate", None, 1 + 3),  # by its family's name
        ("scipy RK45 (rtol)", None, 3),
    ],
)
def test_a_compiled_method_is_warmed_up_untimed_once_and_scipy_is_timed_from_its_first_run(
    family, compiles, runs
):
    osc = Oscillator()
    ref = oscillator_exact(osc, 1.0)
    calls = []

    def run():
        calls.append(1)
        return ref

    key = ("warm-up test", family, compiles)
    _WARM.discard(key)  # as if measured for the first time in this process
    for _ in range(2):  # the second measurement of a family is not warmed up again
        calls.clear()
        row = measure("fig4", family, "s", run, ref, None, 3, 1e9, key, compiles=compiles)
        assert row.ok and row.n_runs == 3 and row.errors.final == 0.0, row
        assert len(calls) == runs
        runs = 3


def _running_on() -> int:
    with open("/proc/thread-self/stat", encoding="ascii") as f:
        return int(f.read().rsplit(")", 1)[1].split()[36])


@pytest.mark.skipif(
    not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="needs Linux and two CPUs to choose from",
)
def test_timing_pins_to_the_cpu_it_runs_on_and_gives_the_others_back():
    """Two timed runs side by side keep a core each: one_core takes the CPU it is on."""
    allowed = os.sched_getaffinity(0)
    last = max(allowed)
    try:
        os.sched_setaffinity(0, {last})
        assert _cpu_now(allowed) == last  # not the first CPU: the one it runs on
        os.sched_setaffinity(0, allowed)
        with one_core():
            pinned = os.sched_getaffinity(0)
            assert len(pinned) == 1 and pinned <= allowed
            assert pinned == {_running_on()}
        assert os.sched_getaffinity(0) == allowed  # given back
    finally:
        os.sched_setaffinity(0, allowed)


def test_scipy_oscillator_and_core_against_the_exact_fig4_solution():
    osc = Oscillator()
    ref = oscillator_exact(osc, 30.0)
    scipy_run = oscillator_scipy(osc, 30.0, "DOP853", 1e-10, 1e-12, dense=True)
    core_run = oscillator_trajectory(
        osc, oscillator_core(osc, 30.0, "accurate", rtol=1e-10, atol=1e-12)
    )
    for run in (scipy_run, core_run):
        e = compare(run, ref)
        assert e.grid_max < 1e-7 and max(e.events.values()) < 1e-6, e


def test_hermite_reading_is_exact_for_cubics_and_splits_at_velocity_jumps():
    t = np.array([0.0, 0.5, 1.0, 1.0, 2.0])
    q = t**3 - t
    dq = 3 * t**2 - 1
    q[3:], dq[3:] = 5.0, 0.0  # a jump at t = 1: after it the body rests at 5
    tr = Trajectory(t, q, dq)
    tq = np.array([0.1, 0.3, 0.77, 1.0, 1.5, 2.5])
    got, _ = tr.at(tq)
    want = np.where(tq < 1.0, tq**3 - tq, 5.0)
    assert np.allclose(got[:, 0], want, atol=1e-14)


def test_dense_output_pieces_reproduce_the_accurate_steps():
    """
    Check that dense-output pieces reproduce the accurate steps.

    Redoing each recorded Dormand-Prince step lands on the next record (the premise of
    reading the accurate method through its own interpolant).
    """
    # Fig. 13 with a speed-dependent law and a turned parcel: it slides all the way
    # (the approach to a stick and the growth after a break-away step in ln |slip|)
    case = sx.two_belt_case(sx.bspline_law(), t_end=2.0, phi0_deg=10.0)
    res = case.run_core("accurate", rtol=1e-6, atol=1e-8)
    tr = case.trajectory(res)
    tr.at(0.0)
    sliding = int(np.sum((res.mode[:-1] == -1) & (np.diff(res.t) > 0)))
    assert len(tr.pieces) >= sliding - 1 > 20
    for t0, t1, fn in tr.pieces:
        q_end, _ = fn(np.array([t1]))
        i = np.searchsorted(tr.t, t1)
        assert np.allclose(q_end[0, :2], tr.q[i, :2], atol=1e-12)


def test_dp5_pieces_reject_intervals_that_are_not_steps():
    t = np.array([0.0, 1.0])
    Y = np.array([[0.0, 1.0], [5.0, 1.0]])  # not where a step of y' = (y1, 0) lands

    def rhs(t0, y0):
        return lambda tt, y: np.array([y[1], 0.0])

    assert dp5_pieces(t, Y, rhs, 1) == []
    Y[1, 0] = 1.0
    assert len(dp5_pieces(t, Y, rhs, 1)) == 1


def test_corners_outrun_every_surface_while_the_bound_holds():
    """
    Check that corners outrun every surface while the bound holds.

    The physical finding the corner check states: at Fig. 9a the moment spins the parcel
    and its corners move faster than any surface (all methods agree); the proven bound holds.
    """
    sc = sx.StiffCase("fig9a", "t", sx.sorting_case())
    ratios = []
    for method in ("accurate", "implicit"):
        res = sc.case.run_core(method, **sx.DEFAULT_SETTINGS[method])
        traj = sc.case.trajectory(res)
        ratios.append(sx._corner_speeds(traj, 0.7, 0.2).max() / 1.5)
        checks = {
            c.name: c for c in sx.check_run(sc, method, sx.DEFAULT_SETTINGS[method], res, traj)
        }
        assert checks["corner_speed"].passed and checks["cog_speed"].passed
    assert min(ratios) > 1.05 and abs(ratios[0] - ratios[1]) < 2e-3, ratios


# ------------------------------------------------------------------ long runs and the report
_LONG_METHODS = {
    "accurate": dict(sx.DEFAULT_SETTINGS["accurate"], max_points=400_000),
    "implicit": {"dt": 1e-3},
}


@pytest.mark.slow
@pytest.mark.parametrize("method", sorted(_LONG_METHODS))
@pytest.mark.parametrize("label", [c[0] for c in sx.LONG_CASES])
def test_ten_minutes_of_two_belt_positioning(label, method):
    """
    Run 600 s of Fig. 13 for one law, rotation setting and method.

    600 s of Fig. 13 per law, rotation setting and method (one run per test, so that each
    stays well inside the suite's per-test budget; the report adds the threshold method).
    """
    (run,) = sx.two_belt_long(600.0, {method: _LONG_METHODS[method]}, cases=(label,))
    assert run.passed, f"{run.case} / {run.method}: " + "; ".join(
        c.detail for c in run.checks if not c.passed
    )


@pytest.mark.slow
def test_reductions_agree_with_the_full_model():
    rows = reductions(repeats=2)
    bad = [f"{r.reduction} on {r.scene}: {r.diff_grid:.1e} m" for r in rows if not r.agrees]
    assert not bad, bad


# the quick report part by part, each well inside the suite's per-test budget: the
# headings a part writes (and no other part's)
_REPORT_PARTS = {
    "fig4": ("## Fig. 4 stick-slip body",),
    "fig9a": ("## Fig. 9a diversion",),
    "three_zones": ("## Parcel straddling all three zones",),
    "fig13": ("## Fig. 13 two-belt positioning",),
    "core": ("## Core benchmark: Fig. 9a",),
    "matrix": ("## Stiff and extreme cases",),
    "contact": ("## Parcels that touch: stiff and extreme cases",),
    "long": ("## Two-belt positioning, long runs",),
    "reductions": ("## Reductions",),
    "quadrature": ("The implicit method's error floor is its quadrature",),
}


@pytest.mark.slow
@pytest.mark.parametrize("part", sorted(_REPORT_PARTS))
def test_quick_precision_report(tmp_path, part):
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "sorter_sim",
            "bench",
            "precision",
            "--quick",
            "--parts",
            part,
            "--out",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    text = (tmp_path / "accuracy.md").read_text()
    for heading in _REPORT_PARTS[part] + ("## Failures and findings", "Machine:"):
        assert heading in text, heading
    for other, headings in _REPORT_PARTS.items():
        if other != part:
            assert not any(h in text for h in headings), f"{other} ran with --parts {part}"
    # a plot a case: Fig. 13 is two (constant μ, the B-spline law)
    n_png = {"fig4": 1, "fig9a": 1, "three_zones": 1, "fig13": 2}.get(part, 0)
    assert len(list((tmp_path / "img").glob("accuracy_*.png"))) == n_png


def test_the_report_parts_are_each_part_once_and_cases_names_every_case():
    assert tuple(_REPORT_PARTS) == REPORT_PARTS  # the suite runs every part
    assert report_parts("cases") == ["fig4", "fig9a", "three_zones", "fig13"]
    assert report_parts("core, fig13,cases,core") == [
        "fig4",
        "fig9a",
        "three_zones",
        "fig13",
        "core",
    ]
    with pytest.raises(ValueError, match=r"\(unknown: fig9b\)$") as err:
        report_parts("fig9b,core")
    assert "cases (fig4, fig9a, three_zones, fig13)" in str(err.value)
    for empty in ("", " , ", ()):
        with pytest.raises(ValueError, match="--parts must list some of"):
            report_parts(empty)
    # the names as a sequence (write_precision_report's parts) read as the text does
    assert report_parts(("core", "cases")) == report_parts("core,cases")
    with pytest.raises(ValueError, match=r"\(unknown: fig9b\)$"):
        report_parts(["fig9b"])


def test_bench_command_line_errors_are_one_line_and_exit_2():
    for argv in (
        ["bench", "precision", "--parts", "cases,nonsense"],
        ["bench"],
        ["bench", "core", "--repeats", "0"],
        ["bench", "precision", "--bogus"],
    ):
        out = subprocess.run(
            [sys.executable, "-m", "sorter_sim", *argv],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert out.returncode == 2, (argv, out.stderr)
        assert len(out.stderr.strip().splitlines()) <= 2 and "Traceback" not in out.stderr


# ------------------------------------------------------ each method against its own model
def test_the_threshold_method_is_measured_against_the_seed_law_it_integrates():
    """
    Check that the threshold rows' reference is the converged seed law, not the exact stick.

    The threshold method is the seed's model: its stick test is the decoupled
    |F| <= F_max, |T| <= T_max. On Fig. 9a it sat 2.6e-2 m off the exact-stick
    reference at every step (the report read that plateau as missed sticks); that is
    the distance between the two laws' converged solutions. Against its own law it
    converges: well under 1e-3 m at h = 1e-4 s.
    """
    from sorter_sim.studies.precision_cases import fig9a_case, on_seed_law, seed_reference

    case = fig9a_case()
    exact = case.core("accurate", rtol=1e-12, atol=1e-12)
    own = seed_reference(case)
    run = case.core("threshold", dt=1e-4, v_min=1e-6)
    gap = compare(own, exact).final
    assert gap > 1e-2, gap  # two models, visibly apart
    assert compare(run, own).final < 1e-3 < compare(run, exact).final
    assert on_seed_law("threshold (h, v_min=1e-06)") and on_seed_law("scipy RK45 threshold model")
    assert not on_seed_law("implicit (h)") and not on_seed_law("scipy RK45 (rtol)")


def test_a_parcel_at_rest_filling_the_disk_field_leaves_at_the_closed_form():
    """
    Check the closed form of the extremes matrix against the seed's equations.

    At rest over the disks alone (b = A = 0.7 m, Fig. 9a otherwise), the parcel feels
    μ_b m g along the disks' velocity (0, v): it reaches v after v/(μ_b g) = 0.2548 s
    having crossed v²/(2 μ_b g) = 0.1911 m, then rides the remaining 0.5089 m at v:
    t = s/v + v/(2 μ_b g) = 0.594087 s (g = 9.81 m/s², the seed's).
    """
    from sorter_sim.studies.stiff_scenes import filling_b_leaves_at

    v, mu, g, s = 1.5, 0.6, 9.81, 0.7
    t1 = v / (mu * g)
    by_hand = t1 + (s - 0.5 * v * t1) / v
    assert filling_b_leaves_at(v, 90.0, mu) == pytest.approx(by_hand, rel=1e-12)
    assert by_hand == pytest.approx(0.594087, abs=1e-6)
    sc = next(c for c in sx.matrix(quick=True) if c.name == "rest_filling_b")
    res = sc.case.run_core("accurate", rtol=1e-12, atol=1e-12)
    assert abs(res.t[-1] - by_hand) < 1e-9, res.t[-1]
    assert abs(res.y[-1, 2]) < 1e-12  # no turn: the patch is symmetric about the centre
