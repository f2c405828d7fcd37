"""
The accurate method's reductions, each switched off in turn: what each saves, and that it agrees.

The reductions are the closed-form stick, the jump to the next border on a single
surface, the limit set's inner bound and the exact constant-μ wrench; ``reductions()``
times the stiff cases with each on and off and checks that both give the same
trajectory (the work-precision report's last table).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from sorter_sim.model.core.accurate import run_accurate
from sorter_sim.model.core.common import N_COUNTERS, ST_END, ST_TARGET, n_surf_of
from sorter_sim.model.core.layout import Contact, Log, Slide, Trail
from sorter_sim.model.core.simulate import initial_mode, parcel_array, strip_array, strip_borders
from sorter_sim.model.core.wrench import gauss_legendre_01
from sorter_sim.studies.stiff_cases import const_law, sorting_case, two_belt_case
from sorter_sim.studies.workprecision import ParcelCase, Trajectory, compare


# ------------------------------------------------------------------ reductions
@dataclass
class ReductionRow:
    """
    Hold one reduction measured on one scene.

    One reduction on one scene: kernel times (min of runs), the largest CoG position
    difference between reduced and full run over a 1 kHz grid, and both runs' errors
    against a tight reference.
    """

    reduction: str
    scene: str
    how: str
    t_reduced: float
    t_full: float
    diff_grid: float
    tol: float
    err_reduced: float
    err_full: float

    @property
    def speedup(self) -> float:
        return self.t_full / self.t_reduced

    @property
    def agrees(self) -> bool:
        """Within the tolerance asked: the difference is at most 10 rtol·(1 m)."""
        return self.diff_grid <= 10.0 * self.tol


def run_accurate_flags(
    case: ParcelCase,
    closed_wrench: bool,
    stick_jumps: bool,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    max_points: int = 200_000,
):
    """
    Run the accurate method with chosen reductions.

    The accurate method with the closed-form wrench and the closed-form stick jumps
    switched separately (``simulate(reductions=...)`` switches both).
    Returns (Trajectory, kernel wall time [s]).

    Parameters
    ----------
    case : ParcelCase
        The case.
    closed_wrench : bool
        The exact constant-μ wrench on.
    stick_jumps : bool
        Closed-form sticks on.
    rtol : float
        The relative tolerance.
    atol : float
        The absolute tolerance.
    max_points : int
        Room for records.

    """
    arr = strip_array(case.strips)
    par = parcel_array(case.parcel, case.rotation, case.n_quad, closed_wrench)
    nodes, weights = gauss_legendre_01(case.n_quad)
    y0 = np.asarray(case.y0, float)
    ts = np.empty(max_points)
    ys = np.empty((max_points, 6))
    ms = np.empty(max_points, dtype=np.int64)
    ev = np.empty((4096, 3))
    counters = np.zeros(N_COUNTERS, dtype=np.int64)
    mode0 = initial_mode(y0, arr, par)
    wall = time.perf_counter()
    status, _, _ = run_accurate(
        y0,
        mode0,
        case.t_span[0],
        case.t_span[1],
        Slide(
            case.y_target,
            Contact(arr, par, nodes, weights),
            n_surf_of(arr),
            strip_borders(case.strips),
            rtol,
            atol,
            0.05,
        ),
        stick_jumps,
        Trail(ts, ys, ms),
        Log(ev, counters),
        np.zeros(3),
    )
    wall = time.perf_counter() - wall
    n = int(counters[3])
    traj = Trajectory(
        ts[:n], ys[:n, :3], ys[:n, 3:], [], n_steps=int(counters[0]), n_rhs=int(counters[1])
    )
    traj.status = "ok" if status in (ST_END, ST_TARGET) else f"status {status}"
    return traj, wall


def _core_flags(case: ParcelCase, **settings):
    res = case.run_core("accurate", **settings)
    return case.trajectory(res), res.wall_s


def reductions(repeats: int = 5, rtol: float = 1e-8) -> list[ReductionRow]:
    """
    Speed-up and agreement of each reduction against the full model.

    Parameters
    ----------
    repeats : int
        Timed repeats; the best counts.
    rtol : float
        The relative tolerance.

    Returns
    -------
    list of ReductionRow
        The rows.

    """
    rows = []
    fig9a = sorting_case()
    placed = sorting_case(y0=[1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    belt20 = two_belt_case(const_law(0.6), 20.0)

    def best_of(run):
        run()  # warm-up, discarded
        best, traj = math.inf, None
        for _ in range(repeats):
            traj, wall = run()
            best = min(best, wall)
        return traj, best

    def pair(name, scene, how, run_red, run_full, ref):
        red, t_red = best_of(run_red)
        full, t_full = best_of(run_full)
        rows.append(
            ReductionRow(
                name,
                scene,
                how,
                t_red,
                t_full,
                compare(red, full).grid_max,
                rtol,
                compare(red, ref).grid_max,
                compare(full, ref).grid_max,
            )
        )

    for scene, case in (("Fig. 9a", fig9a), ("placed on the disks", placed)):
        ref = case.core("accurate", rtol=1e-12, atol=1e-12, reductions=False)
        pair(
            "closed_form_wrench",
            scene,
            "exact edge integrals vs 8x8 Gauss per fan triangle",
            lambda c=case: run_accurate_flags(c, True, True, rtol, rtol),
            lambda c=case: run_accurate_flags(c, False, True, rtol, rtol),
            ref,
        )
        pair(
            "closed_form_stick",
            scene,
            "jump to the next border crossing vs scanning the margin",
            lambda c=case: run_accurate_flags(c, True, True, rtol, rtol),
            lambda c=case: run_accurate_flags(c, True, False, rtol, rtol),
            ref,
        )
        pair(
            "both (reductions=True/False)",
            scene,
            "simulate(..., reductions=False) as the full model",
            lambda c=case: _core_flags(c, rtol=rtol, atol=rtol),
            lambda c=case: _core_flags(c, rtol=rtol, atol=rtol, reductions=False),
            ref,
        )
    resting = sorting_case(y0=[1.0, 0.0, 0.0, 0.0, 1.5, 0.0])
    ref = resting.core("accurate", rtol=1e-12, atol=1e-12, reductions=False)
    pair(
        "closed_form_stick",
        "resting on the disks",
        "the whole run is one stick",
        lambda: run_accurate_flags(resting, True, True, rtol, rtol),
        lambda: run_accurate_flags(resting, True, False, rtol, rtol),
        ref,
    )
    for scene, case in (("two belts 20 s, φ0 = 0", belt20), ("placed on the disks", placed)):
        flat = ParcelCase(case.parcel, case.strips, case.y0, case.t_span, case.y_target, False)
        ref = case.core("accurate", rtol=1e-12, atol=1e-12)
        pair(
            "no_rotation",
            scene,
            "rotation dropped where symmetry keeps ω = 0",
            lambda c=flat: _core_flags(c, rtol=rtol, atol=rtol),
            lambda c=case: _core_flags(c, rtol=rtol, atol=rtol),
            ref,
        )
    far_c = sorting_case(b=1e3)
    pair(
        "zone_c_absent",
        "Fig. 9a",
        "b = inf (no zone c) vs b = 1000 m (zone c never reached)",
        lambda: _core_flags(fig9a, rtol=rtol, atol=rtol),
        lambda: _core_flags(far_c, rtol=rtol, atol=rtol),
        fig9a.core("accurate", rtol=1e-12, atol=1e-12),
    )
    return rows
