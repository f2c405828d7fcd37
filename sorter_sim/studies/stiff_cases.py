"""
Stiff and extreme cases: a matrix of hard scenes, each run through the methods and checked.

The seed integrates a discontinuous friction law and says the threshold speed v_min is
chosen "on experience and intuition" (section 3). This module measures instead: every
case of ``matrix()`` runs with the three methods and ``check_run`` tests what must hold
whatever the scene; ``CHECKS`` states each check and its bound precisely (the report
prints it).

``two_belt_long`` runs 10 minutes of the seed's Fig. 13 positioning: with constant μ
the oscillation is a frictional harmonic oscillator (ω² = 2μg/A) and must keep its
energy (drift per cycle reported), with the B-spline law it must decay.
``reductions`` measures each "leave out what a scene does not need" against the full
model. Everything returns plain rows for ``bench.py`` to print and for the tests. The
scenes themselves are ``stiff_scenes`` (re-exported here).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from sorter_sim.model.core.common import _contact_surfaces
from sorter_sim.model.core.layout import Contact
from sorter_sim.model.core.simulate import (
    G_STANDARD,
    parcel_array,
    strip_array,
    surface_velocities,
)
from sorter_sim.model.core.wrench import clip_scratch, evaluate_surfaces, gauss_legendre_01
from sorter_sim.studies.stiff_scenes import (
    DEFAULT_SETTINGS,
    KNOWN_DEFECTS,
    SCRAP_S,
    StiffCase,
    _law_range,
    bspline_law,
    const_law,
    matrix,
    sorting_case,
    two_belt_1d,
    two_belt_case,
    two_belt_exact,
)
from sorter_sim.studies.workprecision import ParcelCase, Trajectory, compare, timed

CHECKS = """\
- **finite**: no NaN/inf in any record, and the run ended as asked (time span or scrap line).
- **cog_speed**: the centre of gravity never moves faster than the surfaces can make it.
  For a parcel in pure translation (ω ≡ 0) this is a theorem and is checked as such: every area
  element pulls V towards its surface's velocity, so the distance of V from the convex hull of
  the surface velocities never grows. With rotation it is a checked property, not a theorem
  (a spinning parcel can trade spin for translation): |V| <= max(S, |V(0)|) + tol, S the largest
  surface speed. tol: accurate 10·max(atol, rtol·S); implicit 1e-9·S (the backward-Euler step is
  itself dissipative); threshold μ_max·g·h (one RK4 step's velocity change across the v_min
  switch).
- **corner_speed**: every footprint corner, |V + ω×r_c| <= S + 2·max(|σ_C(0)|, σ*) + tol, a
  theorem:
  with c the point of the hull C of surface velocities nearest V and σ_C = (V - c, ρω),
  d/dt ½m|σ_C|² = Σ∫(w - c)·dF <= Σ∫ μ p (D - |u|) dA (D the diameter of C, u the local slip),
  negative once |σ_C| > σ* = D(1 + μ_hi/μ_lo)/κ, κ the least mean |a + ω×r| over the footprint
  for unit (a, ρω); and |w_c - c| <= sqrt(1 + R²/ρ²)·|σ_C| = 2|σ_C| for a rectangle. The corners
  do exceed S itself, physically: the moment of two surfaces spins the parcel while its centre
  moves at nearly S (Fig. 9a: 1.59 m/s against S = 1.5 m/s, the same with all three methods);
  the tables list the measured ratio (corner/S).
- **energy_single_surface**: over every pair of consecutive records at which the footprint lies
  over one surface k only, T_k = ½m|V - v_k|² + ½Iω² does not grow (dT_k/dt = -∫ μ p |u| dA <= 0),
  within m·S·tol (tol as for cog_speed).
- **energy_surface_power**: at every record (400 sampled at most), each surface's friction power in
  its own frame, P_k = (V - v_k)·F_k + ω·T_k, is <= 1e-9·μ_hi·m·g·S: friction never adds energy
  relative to the surface it comes from, whatever else pushes the parcel.
- **chatter**: at most 10 stick/break switches in any 1 s of simulated time. A stick-slip cycle
  needs one stick and one break, and the fastest physical cycles here last seconds; a chattering
  integrator switches every step (hundreds to thousands per second).
- **reference** (the extremes group): the CoG at the end against a converged solution of the
  method's own model, the accurate method at rtol = atol = 1e-12 with the exact stick (accurate
  and implicit) or the seed's decoupled stick test (threshold, ``stick = seed``): within
  1e3·rtol m (accurate), 2·S·h (implicit, first order: S the largest surface speed) or
  2·S·h + 1e3·v_min·t_end (threshold, RK4 at h with the threshold speed's drift); where the
  scene has a closed form for t_scrap (a parcel at rest filling the disk field), the reference
  must meet it within 1e-8 s and the run within 1e3·rtol·t_scrap s (accurate) or 2h (the
  fixed-step methods).
- **convergence**: refining the tolerance (accurate: rtol 1e-6, 1e-8, 1e-10 with atol = rtol/100)
  or the step (implicit: h, h/4, h/16) brings the CoG position at the common end time closer to
  the finest run: |p2 - p3| <= |p1 - p3| (or both below 1e-12 m).
"""

MAX_SWITCHES_PER_S = 10  # chatter bound: stick/break switches in any 1 s window


# ------------------------------------------------------------------ checks
@dataclass
class Check:
    name: str
    passed: bool
    value: float
    detail: str = ""


@dataclass
class CaseRun:
    """One method on one matrix case: its trajectory and the checks."""

    case: str
    group: str
    method: str
    setting: str
    wall_s: float
    status: str
    checks: list
    figures: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)


@functools.lru_cache(maxsize=64)
def _kappa(A: float, B: float, n: int = 40) -> float:
    """
    Return the constant of the corner-speed bound.

    Min over unit generalized velocities (a, ρω) of the mean |a + ω×r| over the A x B
    footprint (the constant of the corner bound); minimised over a grid of directions.
    """
    xs = (np.arange(n) + 0.5) / n - 0.5
    X, Y = np.meshgrid(xs * A, xs * B)
    X, Y = X.ravel(), Y.ravel()
    rho = math.sqrt((A * A + B * B) / 12.0)
    best = math.inf
    for th in np.linspace(0.0, math.pi, 61):  # angle between (a, ρω) and the ω axis
        for ps in np.linspace(0.0, math.pi, 31):  # direction of a in the plane
            ax, ay = math.sin(th) * math.cos(ps), math.sin(th) * math.sin(ps)
            om = math.cos(th) / rho
            best = min(best, float(np.mean(np.hypot(ax - om * Y, ay + om * X))))
    return best


def _corner_speeds(traj: Trajectory, A: float, B: float) -> np.ndarray:
    ha, hb = 0.5 * A, 0.5 * B
    phi, om = traj.q[:, 2], traj.dq[:, 2]
    out = np.zeros(len(traj.t))
    for ox, oy in ((ha, -hb), (ha, hb), (-ha, hb), (-ha, -hb)):
        rx = np.cos(phi) * ox - np.sin(phi) * oy
        ry = np.sin(phi) * ox + np.cos(phi) * oy
        out = np.maximum(out, np.hypot(traj.dq[:, 0] - om * ry, traj.dq[:, 1] + om * rx))
    return out


def _hull_distance(V: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Distance of each velocity V (n, 2) from the convex hull of the points (k, 2)."""
    if len(pts) == 1:
        return np.linalg.norm(V - pts[0], axis=1)
    best = np.full(len(V), math.inf)
    for i in range(len(pts)):
        for j in range(i, len(pts)):
            a, b = pts[i], pts[j]
            d = b - a
            dd = float(d @ d)
            s = np.clip(((V - a) @ d) / dd, 0.0, 1.0) if dd > 0 else np.zeros(len(V))
            best = np.minimum(best, np.linalg.norm(V - (a + s[:, None] * d), axis=1))
    if len(pts) >= 3:
        # inside a triangle of surface points (the cells here have at most 3 surfaces)
        from itertools import combinations

        for a, b, c in combinations(pts, 3):
            m = np.array([b - a, c - a]).T
            if abs(np.linalg.det(m)) > 0:
                lam = np.linalg.solve(m, (V - a).T).T
                inside = (lam[:, 0] >= 0) & (lam[:, 1] >= 0) & (lam.sum(axis=1) <= 1)
                best[inside] = 0.0
    return best


def _switch_times(traj: Trajectory) -> np.ndarray:
    return np.sort(np.array([t for t, k, _ in traj.events if k in ("stick", "break")], float))


def _max_in_window(times: np.ndarray, window: float = 1.0) -> int:
    if len(times) == 0:
        return 0
    j = np.searchsorted(times, times + window, side="right")
    return int(np.max(j - np.arange(len(times))))


def _energy_checks(case, vel, traj: Trajectory, S: float, tol_v: float, mu_hi: float) -> list:
    """
    Return the two energy checks of ``CHECKS`` on one run's trajectory.

    energy_single_surface: T_k does not grow between records over surface k alone;
    energy_surface_power: each surface's friction power in its own frame is <= 0.
    ``vel`` holds the surface velocities, S the largest speed, tol_v the run's
    velocity tolerance and mu_hi the largest μ.
    """
    parcel = case.parcel
    arr = strip_array(case.strips)
    g = G_STANDARD
    V = traj.dq[:, :2]
    checks = []
    # (i) single-surface intervals; (ii) surface power at records
    nodes, weights = gauss_legendre_01(case.n_quad)
    par = parcel_array(parcel, case.rotation, case.n_quad)
    nsurf = len(vel)
    areas = np.zeros((len(traj.t), nsurf))
    clip = clip_scratch()
    for i in range(len(traj.t)):
        st = np.concatenate([traj.q[i], traj.dq[i]])
        _contact_surfaces(st, arr, par, clip, areas[i])
    worst_rise = 0.0
    for k in range(nsurf):
        alone = (areas[:, k] > 0) & (np.sum(areas > 0, axis=1) == 1)
        Tk = (
            0.5 * parcel.m * np.sum((V - vel[k]) ** 2, axis=1)
            + 0.5 * parcel.inertia * traj.dq[:, 2] ** 2
        )
        both = alone[:-1] & alone[1:]
        if np.any(both):
            worst_rise = max(worst_rise, float(np.max(np.diff(Tk)[both])))
    tol_e = parcel.m * max(S, 1e-3) * tol_v
    checks.append(
        Check(
            "energy_single_surface",
            worst_rise <= tol_e,
            worst_rise,
            f"largest rise of T_k between records on one surface {worst_rise:.1e} J "
            f"(tol {tol_e:.1e} J)",
        )
    )
    idx = np.unique(np.linspace(0, len(traj.t) - 1, min(400, len(traj.t))).astype(int))
    kin = np.empty((nsurf, 3))
    stat = np.empty((nsurf, 2))
    area = np.empty(nsurf)
    slip = np.empty(nsurf)
    worst_p = -math.inf
    for i in idx:
        st = np.concatenate([traj.q[i], traj.dq[i]])
        evaluate_surfaces(st, Contact(arr, par, nodes, weights), -2, False, kin, stat, area, slip)
        for k in range(nsurf):
            if area[k] > 0:
                p_k = (
                    (st[3] - vel[k, 0]) * kin[k, 0]
                    + (st[4] - vel[k, 1]) * kin[k, 1]
                    + st[5] * kin[k, 2]
                )
                worst_p = max(worst_p, p_k)
    worst_p = max(worst_p, 0.0) if worst_p > -math.inf else 0.0
    tol_p = 1e-9 * max(mu_hi, 1e-3) * parcel.m * g * max(S, 1e-3)
    checks.append(
        Check(
            "energy_surface_power",
            worst_p <= tol_p,
            worst_p,
            f"max friction power of a surface in its own frame {worst_p:.1e} W "
            f"(tol {tol_p:.1e} W)",
        )
    )
    return checks


def check_run(sc: StiffCase, method: str, settings: dict, res, traj: Trajectory) -> list:
    """
    Return the checks of the module docstring on one run.

    Parameters
    ----------
    sc : StiffCase
        The case.
    method : str
        The method.
    settings : dict
        The method's settings.
    res : SimResult
        A run.
    traj : Trajectory
        The trajectory.

    Returns
    -------
    list of Check
        The checks.

    """
    case = sc.case
    parcel = case.parcel
    arr = strip_array(case.strips)
    vel = np.array(surface_velocities(arr))
    S = float(np.max(np.hypot(vel[:, 0], vel[:, 1])))
    mu_lo, mu_hi = sc.mu_range
    g = G_STANDARD
    if method == "accurate":
        tol_v = 10.0 * max(settings.get("atol", 1e-10), settings.get("rtol", 1e-8) * max(S, 1e-3))
    elif method == "implicit":
        tol_v = 1e-9 * max(S, 1e-3)
    else:
        tol_v = mu_hi * g * settings.get("dt", 1e-3) + 1e-12
    checks = []
    finite = bool(np.all(np.isfinite(traj.q)) and np.all(np.isfinite(traj.dq)))
    checks.append(
        Check("finite", finite and res.success, 0.0, "" if finite and res.success else res.message)
    )
    if not finite:
        return checks
    V = traj.dq[:, :2]
    speed = np.hypot(V[:, 0], V[:, 1])
    rotating = bool(np.any(traj.dq[:, 2] != 0.0))
    if not rotating:
        # the theorem: the distance of V from the convex hull of the surface
        # velocities never grows (and is 0 for a parcel starting on a surface)
        d_hull = _hull_distance(V, vel)
        rise = float(max(0.0, np.max(np.diff(d_hull)))) if len(d_hull) > 1 else 0.0
        checks.append(
            Check(
                "cog_speed",
                rise <= tol_v,
                rise,
                f"pure translation: distance of V from the hull of the surface "
                f"velocities {d_hull[0]:.2g} -> {d_hull[-1]:.2g} m/s, largest rise "
                f"{rise:.1e} (tol {tol_v:.1e}); max |V| {speed.max():.6g}, S {S:g}",
            )
        )
    else:
        excess = float(speed.max() - max(S, speed[0]))
        checks.append(
            Check(
                "cog_speed",
                excess <= tol_v,
                excess,
                f"max |V| - max(S, |V0|) = {excess:.1e} m/s (tol {tol_v:.1e}), S = {S:g} m/s",
            )
        )
    corner = _corner_speeds(traj, parcel.A, parcel.B)
    D = float(max(np.hypot(*(vel[i] - vel[j])) for i in range(len(vel)) for j in range(len(vel))))
    kappa = _kappa(parcel.A, parcel.B)
    rho = math.sqrt(parcel.inertia / parcel.m)
    c0 = _hull_distance(V[:1], vel)[0]
    sigma0 = math.hypot(c0, rho * traj.dq[0, 2])
    sigma_star = D * (1.0 + mu_hi / mu_lo) / kappa if mu_lo > 0 else (0.0 if D == 0 else math.inf)
    bound = S + 2.0 * max(sigma0, sigma_star) + tol_v
    cmax = float(corner.max())
    checks.append(
        Check(
            "corner_speed",
            cmax <= bound,
            cmax,
            f"max corner speed {cmax:.4g} m/s = {cmax / S if S > 0 else math.inf:.3f} S; "
            f"bound {bound:.3g} m/s",
        )
    )
    checks += _energy_checks(case, vel, traj, S, tol_v, mu_hi)
    sw = _switch_times(traj)
    n_win = _max_in_window(sw)
    span = traj.t_end - traj.t[0]
    checks.append(
        Check(
            "chatter",
            n_win <= MAX_SWITCHES_PER_S,
            float(n_win),
            f"{len(sw)} stick/break switches in {span:.3g} s, at most {n_win} in any 1 s "
            f"(bound {MAX_SWITCHES_PER_S})",
        )
    )
    return checks


REFERENCE_TOL = 1e-12  # rtol = atol of the converged solutions the extremes are measured on


def reference_bounds(method: str, settings: dict, S: float, t_end: float) -> tuple:
    """
    Return the bounds of the reference check: (CoG error [m], t_scrap error [s]).

    As the module's CHECKS state them: the accurate method's error follows its
    tolerance; a fixed step's is first order in h (S h: how far the fastest surface
    carries a parcel in one step), the threshold method's also drifts by up to v_min
    over the run.
    """
    if method == "accurate":
        rtol = settings.get("rtol", 1e-8)
        return 1e3 * rtol, 1e3 * rtol * max(t_end, 1.0)
    h = settings.get("dt", 1e-3)
    bound = 2.0 * max(S, 1e-3) * h
    if method == "threshold":
        bound += 1e3 * settings.get("v_min", 1e-6) * t_end
    return bound, 2.0 * h


def reference_check(sc: StiffCase, method: str, settings: dict, traj: Trajectory, ref) -> list:
    """
    Return the reference check (and the closed form's, where the scene has one) of a run.

    ``ref`` is the converged solution of the method's own model (``own_reference``).
    """
    S = max(math.hypot(st.vx, st.vy) for st in sc.case.strips)
    e = compare(traj, ref)
    b_pos, b_t = reference_bounds(method, settings, S, ref.t_end)
    out = [
        Check(
            "reference",
            e.final <= b_pos,
            e.final,
            f"CoG {e.final:.1e} m off the converged solution at t = {ref.t_end:.6g} s "
            f"(bound {b_pos:.1e} m)",
        )
    ]
    if sc.closed_form is not None:
        t_cf, formula = sc.closed_form
        d_ref = abs(ref.t_end - t_cf)
        d_run = abs(traj.t_end - t_cf)
        out.append(
            Check(
                "closed_form",
                d_ref <= 1e-8 and d_run <= b_t,
                d_run,
                f"t_scrap {traj.t_end:.9g} s against {formula} = {t_cf:.9g} s: run off by "
                f"{d_run:.1e} s (bound {b_t:.1e}), converged solution by {d_ref:.1e} s",
            )
        )
    return out


def own_reference(sc: StiffCase, method: str, cache: dict) -> Trajectory:
    """
    Return the converged solution of ``method``'s own model on ``sc`` (computed once a law).

    The accurate method at rtol = atol = ``REFERENCE_TOL``: with the seed's decoupled
    stick test for the threshold method (eqs. 4.2, 4.4, the model it integrates), with
    the exact stick for the accurate and implicit methods.
    """
    stick = "seed" if method == "threshold" else "exact"
    if stick not in cache:
        cache[stick] = sc.case.core(
            "accurate",
            rtol=REFERENCE_TOL,
            atol=REFERENCE_TOL,
            stick=stick,
            max_points=ACCURATE_MAX_POINTS * 10,
        )
    return cache[stick]


def _setting_text(settings: dict) -> str:
    return ", ".join(f"{k}={v:g}" for k, v in settings.items() if k != "max_points")


# the accurate method's step budget in the matrix: simulate() stops after 50 steps per
# output record, so a run whose steps collapse ends as a failure instead of hanging
ACCURATE_MAX_POINTS = 20000
_WARM_METHODS: set = set()


def run_case(sc: StiffCase, repeats: int = 1) -> list[CaseRun]:
    """
    Every method of a case, with the checks, plus the convergence check.

    Parameters
    ----------
    sc : StiffCase
        The case.
    repeats : int
        Timed repeats; the best counts.

    Returns
    -------
    list of CaseRun
        The runs.

    """
    out = []
    refs: dict = {}
    for method, settings in sc.methods.items():
        if method == "accurate":
            settings = dict(settings, max_points=settings.get("max_points", ACCURATE_MAX_POINTS))
        try:
            if method not in _WARM_METHODS:  # compilation never enters a figure
                sorting_case(t_max=0.1).run_core(method, **DEFAULT_SETTINGS[method])
                _WARM_METHODS.add(method)
            res, wall, _ = timed(lambda: sc.case.run_core(method, **settings), repeats, 1.0)
        except Exception as exc:  # kept as a failed run with its reason
            out.append(
                CaseRun(
                    sc.name,
                    sc.group,
                    method,
                    _setting_text(settings),
                    math.nan,
                    f"{type(exc).__name__}: {exc}",
                    [Check("finite", False, 0.0, str(exc))],
                )
            )
            continue
        traj = sc.case.trajectory(res)
        checks = check_run(sc, method, settings, res, traj)
        run = CaseRun(
            sc.name, sc.group, method, _setting_text(settings), wall, res.message, checks
        )
        run.figures["corner_over_S"] = float(
            _corner_speeds(traj, sc.case.parcel.A, sc.case.parcel.B).max()
            / max(1e-12, max(math.hypot(s.vx, s.vy) for s in sc.case.strips))
        )
        run.figures["t_end"] = traj.t_end
        run.figures["switches"] = len(_switch_times(traj))
        if method in sc.converge:
            run.checks.append(convergence_check(sc, method, settings))
        if sc.reference:
            ref_checks = reference_check(
                sc, method, settings, traj, own_reference(sc, method, refs)
            )
            run.checks += ref_checks
            run.figures["ref_err"] = ref_checks[0].value
        out.append(run)
    return out


def convergence_check(sc: StiffCase, method: str, settings: dict) -> Check:
    """
    Refine tolerance (accurate) or step (implicit) three times; errors must shrink.

    Parameters
    ----------
    sc : StiffCase
        The case.
    method : str
        The method.
    settings : dict
        The method's settings.

    Returns
    -------
    Check
        The check.

    """
    if method == "accurate":
        seq = [dict(settings, rtol=r, atol=1e-2 * r) for r in (1e-6, 1e-8, 1e-10)]
        label = "rtol 1e-6/1e-8/1e-10 (atol = rtol/100)"
    else:
        h = settings.get("dt", 1e-3)
        seq = [dict(settings, dt=h / f) for f in (1.0, 4.0, 16.0)]
        label = f"h {h:g}/{h / 4:g}/{h / 16:g}"
    results = [sc.case.run_core(method, **s) for s in seq]
    failed = [
        f"{label.split(':')[0]} run {i + 1}: {r.message}"
        for i, r in enumerate(results)
        if not r.success
    ]
    if failed:
        return Check(f"convergence_{method}", False, math.nan, "; ".join(failed))
    trajs = [sc.case.trajectory(r) for r in results]
    t_c = min(tr.t_end for tr in trajs)
    p = [tr.at(t_c)[0][0, :2] for tr in trajs]
    d1 = float(np.linalg.norm(p[0] - p[2]))
    d2 = float(np.linalg.norm(p[1] - p[2]))
    ok = d2 <= d1 or max(d1, d2) <= 1e-12
    order = (
        math.log(d1 / d2, 4.0 if method != "accurate" else 100.0)
        if d2 > 0 and d1 > 0
        else math.nan
    )
    return Check(
        f"convergence_{method}",
        ok,
        d2,
        f"{label}: |p1-p3| {d1:.1e} m, |p2-p3| {d2:.1e} m at t = {t_c:.4g} s"
        + (
            f" (observed order {order:.2f} per {'decade²' if method == 'accurate' else 'h/4'})"
            if math.isfinite(order)
            else ""
        ),
    )


# ------------------------------------------------------------------ 10 minutes of Fig. 13
@dataclass
class LongRun:
    case: str
    method: str
    setting: str
    wall_s: float
    status: str
    figures: dict
    checks: list

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)


LONG_CASES = (
    ("const μ = 0.6, rotation off", const_law(0.6), False),
    ("B-spline, rotation off", bspline_law(), False),
    ("const μ = 0.6, rotation on", const_law(0.6), True),
    ("B-spline, rotation on", bspline_law(), True),
)


def two_belt_long(
    t_end: float = 600.0, methods: dict | None = None, cases: tuple | None = None
) -> list[LongRun]:
    """
    Run 10 minutes of two-belt positioning.

    10 minutes of two-belt positioning: energy drift per cycle (constant μ), decay
    (B-spline), and the matrix checks with rotation on. ``cases``: labels of
    ``LONG_CASES`` to run (default all).

    Parameters
    ----------
    t_end : float
        The end [s].
    methods : dict, optional
        {method: settings} to run (default: the implicit and threshold methods at
        1 ms steps, the accurate one at the matrix's tolerances with room for 400 000
        records).
    cases : tuple of str, optional
        Labels of ``LONG_CASES`` to run (default: all).

    Returns
    -------
    list of LongRun
        The runs.

    """
    methods = methods or {
        "accurate": dict(DEFAULT_SETTINGS["accurate"], max_points=400_000),
        "implicit": {"dt": 1e-3},
        "threshold": {"dt": 1e-3, "v_min": 1e-6},
    }
    out = []
    mu = 0.6
    for label, law, rotation in LONG_CASES:
        if cases is not None and label not in cases:
            continue
        case = two_belt_case(law, t_end, rotation=rotation)
        sc = StiffCase(label, "two-belt 10 min", case, mu_range=_law_range(law))
        for method, settings in methods.items():
            wall = time.perf_counter()
            try:
                res = case.run_core(method, **settings)
                wall = res.wall_s
            except Exception as exc:
                out.append(
                    LongRun(
                        label,
                        method,
                        _setting_text(settings),
                        math.nan,
                        f"{type(exc).__name__}: {exc}",
                        {},
                        [Check("finite", False, 0.0)],
                    )
                )
                continue
            traj = case.trajectory(res)
            checks = check_run(sc, method, settings, res, traj)
            figs = _oscillation_figures(case, traj, mu)
            if "const" in label and not rotation:
                drift = figs["energy_drift_per_cycle"]
                checks.append(
                    Check(
                        "amplitude_kept",
                        abs(drift) <= 1e-4,
                        drift,
                        f"energy drift {drift:.1e} per cycle over {figs['cycles']:.0f} cycles",
                    )
                )
            if "B-spline" in label:
                ratio = figs["amplitude_ratio"]
                checks.append(
                    Check(
                        "decays",
                        ratio <= 1e-3,
                        ratio,
                        f"amplitude over the last cycle / first: {ratio:.1e}",
                    )
                )
            out.append(
                LongRun(label, method, _setting_text(settings), wall, res.message, figs, checks)
            )
    return out


def _oscillation_figures(case: ParcelCase, traj: Trajectory, mu: float) -> dict:
    """
    Return the oscillation figures of a two-belt run.

    Energy of the frictional oscillator E = ½mẋ² + ½kx², k = 2μmg/A, per cycle; the
    amplitude of the first and the last cycle; the final angle.
    """
    m, A = case.parcel.m, case.parcel.A
    k = 2.0 * mu * m * G_STANDARD / A
    w = math.sqrt(k / m)
    period = 2 * math.pi / w
    t0, t1 = case.t_span
    grid = np.arange(t0, t1, 1e-3)
    q, dq = traj.at(grid)
    E = 0.5 * m * dq[:, 0] ** 2 + 0.5 * k * q[:, 0] ** 2
    cycles = (t1 - t0) / period
    first_cycle = grid < t0 + period
    last_cycle = grid > t1 - period
    first = np.abs(q[first_cycle, 0]).max()
    last = np.abs(q[last_cycle, 0]).max()
    # cycle means: a fixed-step method's energy oscillates within a cycle without drifting
    drift = (E[last_cycle].mean() - E[first_cycle].mean()) / E[first_cycle].mean() / (cycles - 1)
    return {
        "cycles": cycles,
        "energy_drift_per_cycle": float(drift),
        "amplitude_first": float(first),
        "amplitude_last": float(last),
        "amplitude_ratio": float(last / first) if first > 0 else math.nan,
        "phi_end_deg": float(math.degrees(traj.q[-1, 2])),
        "phi_max_deg": float(math.degrees(np.abs(traj.q[:, 2]).max())),
    }


# the scenes are part of this module's interface (``sx.*``), as before they had their own
__all__ = [
    "CHECKS",
    "DEFAULT_SETTINGS",
    "KNOWN_DEFECTS",
    "LONG_CASES",
    "SCRAP_S",
    "StiffCase",
    "bspline_law",
    "check_run",
    "const_law",
    "convergence_check",
    "matrix",
    "run_case",
    "sorting_case",
    "two_belt_1d",
    "two_belt_case",
    "two_belt_exact",
    "two_belt_long",
]
