"""
The scipy baseline of the work-precision study: the same model through ``solve_ivp``.

``ScipyParcel`` integrates the parcel's sliding model with any ``solve_ivp`` method,
calling the same compiled right-hand side as the core, and is handed the stick
phases in closed form (``solve_ivp`` cannot integrate an inequality-constrained
stick); ``oscillator_scipy`` does the same for the Fig. 4 body. A run that exceeds
its evaluation budget raises ``BudgetExceeded``, and the report keeps it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numba import njit
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from sorter_sim.model.core.cache import CORE_DIR, check_kernel_cache
from sorter_sim.model.core.common import n_surf_of, rhs_slide
from sorter_sim.model.core.layout import Contact
from sorter_sim.model.core.oscillator import Oscillator
from sorter_sim.model.core.simulate import (
    G_STANDARD,
    initial_mode,
    parcel_array,
    strip_array,
    surface_velocities,
)
from sorter_sim.model.core.stick import stick_margin
from sorter_sim.model.core.threshold import rhs_threshold
from sorter_sim.model.core.wrench import clip_scratch, gauss_legendre_01
from sorter_sim.studies.workprecision import ParcelCase, Trajectory, _after_start


# the wrappers below compile the core's kernels they call into themselves, and numba keys
# their cache by their own bytecode: the core's sources stamp their cache too, or after an
# edit of the core they would go on running its old code
STUDIES_DIR = Path(__file__).resolve().parent


class BudgetExceeded(RuntimeError):
    """A scipy run used more right-hand-side evaluations than it was allowed."""


# The baseline calls the core's right-hand sides and stick margin through these: numba's
# dispatch of a named tuple from Python costs about a microsecond a call more than of its
# arrays, which the baseline, calling once per evaluation, would otherwise pay and the core
# does not.
@njit(cache=True)
def _rhs_slide(y, strips, parcel, nodes, weights, clip, out):
    rhs_slide(y, Contact(strips, parcel, nodes, weights), clip, out)


@njit(cache=True)
def _stick_margin(y, strips, parcel, nodes, weights, nsurf, surf):
    m, a, _, _, _ = stick_margin(
        y, Contact(strips, parcel, nodes, weights), nsurf, surf, np.zeros(3)
    )
    return m, a


@njit(cache=True)
def _rhs_threshold(y, strips, parcel, nodes, weights, nsurf, v_min, out, modes):
    rhs_threshold(y, Contact(strips, parcel, nodes, weights), nsurf, v_min, out, modes)


class ScipyParcel:
    """
    scipy's ``solve_ivp`` on the core's planar model, stick/slip handled around it.

    solve_ivp integrates smooth ODEs; this model is a hybrid system. What scipy can
    do: the sliding phases, with the core's right-hand side ``rhs_slide`` (the same
    wrench code) and terminal events for the scrap line, each footprint corner
    crossing each strip border (the area functions have kinks there) and each
    surface's slip reaching zero (the slip projected on its direction at the
    segment start changes sign; a surface whose slip starts at zero, just after
    breaking away, watches |slip| falling below ``eps``; a sign change with the slip
    still large means it turned by more than 90 degrees, and the segment restarts
    aimed along it). What it cannot do is the
    stuck phase, a differential-algebraic mode with an inequality constraint: that
    is done here in closed form (rigid translation with the surface) with the
    break-away located by bracketing and ``brentq`` on the core's stick margin
    (eqs. 4.3/4.5) along that path, sampled at every corner/border crossing. After
    break-away the slide restarts from exactly zero slip; the stiff layer where the
    slip direction settles is left to solve_ivp's step control (no closed form),
    which is what an implicit method such as Radau must resolve by itself.
    """

    def __init__(self, case: ParcelCase, g: float = G_STANDARD):
        check_kernel_cache(STUDIES_DIR, inlined=(CORE_DIR,))
        self.case = case
        self.arr = strip_array(case.strips)
        self.par = parcel_array(case.parcel, case.rotation, case.n_quad, True, g)
        self.nodes, self.weights = gauss_legendre_01(case.n_quad)
        self.nsurf = n_surf_of(self.arr)
        self.borders = case.borders
        self.vel = surface_velocities(self.arr)
        self.rho = math.sqrt(case.parcel.inertia / case.parcel.m)
        self.n_rhs = 0
        self.max_rhs = math.inf
        self._out = np.empty(6)
        self._clip = clip_scratch()
        # the compiled wrappers loaded (or compiled) now, not inside a run the report
        # times: it times scipy from its first run (workprecision.measure, compiles=False)
        self.f(0.0, case.y0)
        self.f_threshold(1e-6)(0.0, case.y0)
        self.margin(case.y0, 0)
        self.n_rhs = 0

    # the model, as scipy sees it
    def f(self, t, y):
        """
        Return the sliding model's right-hand side at (t, y), as ``solve_ivp`` calls it.

        Parameters
        ----------
        t : float
            The time [s].
        y : ndarray, shape (6,)
            The state.

        """
        self.n_rhs += 1
        if self.n_rhs > self.max_rhs:
            raise BudgetExceeded(f"more than {self.max_rhs:.0f} right-hand-side evaluations")
        out = np.empty(6)
        _rhs_slide(
            np.asarray(y, float), self.arr, self.par, self.nodes, self.weights, self._clip, out
        )
        return out

    def f_threshold(self, v_min):
        """
        Return the threshold model's right-hand side at this v_min, as ``solve_ivp`` calls it.

        Parameters
        ----------
        v_min : float
            The threshold speed [m/s].

        """
        modes = np.zeros(self.nsurf, dtype=np.int64)

        def f(t, y):
            self.n_rhs += 1
            if self.n_rhs > self.max_rhs:
                raise BudgetExceeded(f"more than {self.max_rhs:.0f} right-hand-side evaluations")
            out = np.empty(6)
            _rhs_threshold(
                np.asarray(y, float),
                self.arr,
                self.par,
                self.nodes,
                self.weights,
                self.nsurf,
                v_min,
                out,
                modes,
            )
            return out

        return f

    def slip(self, y, s) -> np.ndarray:
        """
        Return the generalized slip of the state y on surface s.

        Parameters
        ----------
        y : ndarray, shape (6,)
            The state.
        s : int
            A surface id.

        Returns
        -------
        ndarray
            The generalized slip.

        """
        vx, vy = self.vel[s]
        return np.array([y[3] - vx, y[4] - vy, self.rho * y[5] if self.case.rotation else 0.0])

    def margin(self, y, s) -> tuple[float, float]:
        """
        Return the break-away margin of a stick to surface s at y, and the surface's area.

        Parameters
        ----------
        y : ndarray, shape (6,)
            The state.
        s : int
            A surface id.

        Returns
        -------
        (float, float)
            The margin and the area.

        """
        # a fresh gauge twist per check (``_stick_margin``) keeps every call independent
        # of the order brentq asks them in
        m, a = _stick_margin(
            np.asarray(y, float), self.arr, self.par, self.nodes, self.weights, self.nsurf, s
        )
        return m, a

    def _corner_offsets(self):
        ha, hb = 0.5 * self.case.parcel.A, 0.5 * self.case.parcel.B
        return ((ha, -hb), (ha, hb), (-ha, hb), (-ha, -hb))

    # stuck: rigid translation with the surface until the stick fails
    def _stick_phase(self, t, y, s, t_end, y_target):
        vx, vy = self.vel[s]
        y = y.copy()
        y[3], y[4], y[5] = vx, vy, 0.0
        t_stop, reason = t_end, "end"
        if vy > 0 and y_target < math.inf and y[1] < y_target:
            tt = t + (y_target - y[1]) / vy
            if tt < t_stop:
                t_stop, reason = tt, "scrap"
        t0, y_start = t, y.copy()

        def state(tt):
            z = y_start.copy()
            z[0] += vx * (tt - t0)
            z[1] += vy * (tt - t0)
            return z

        def fails(tt):
            m, a = self.margin(state(tt), s)
            return m if a > 0.0 else 1.0

        # the margin is smooth between corner/border crossings: sample each piece
        knots = {t0, t_stop}
        if vx != 0.0:
            c, sn = math.cos(y[2]), math.sin(y[2])
            for ox, oy in self._corner_offsets():
                cx = y[0] + c * ox - sn * oy
                for b in self.borders:
                    tc = t0 + (b - cx) / vx
                    if t0 < tc < t_stop:
                        knots.add(tc)
        knots = sorted(knots)
        grid = [t0]
        for a, b in zip(knots[:-1], knots[1:]):
            grid.extend(np.linspace(a, b, 17)[1:])
        g_prev = fails(grid[0])
        if g_prev > 0.0:
            return t0, state(t0), "break"
        for ta, tb in zip(grid[:-1], grid[1:]):
            if fails(tb) > 0.0:
                tr = brentq(fails, ta, tb, xtol=1e-15, rtol=1e-15)
                while fails(tr) <= 0.0:  # take the first instant the stick has failed
                    tr = np.nextafter(tr, math.inf)
                return tr, state(tr), "break"
        return t_stop, state(t_stop), reason

    def _slide_events(self, y, y_target: float, eps: float, offs, direction_next: dict):
        """
        Return the events that end a sliding segment from ``y``, their kinds, its slip speeds.

        The scrap line, each corner (``offs``) crossing each zone border (the friction
        changes there, which solve_ivp's step control would smear), and each surface's slip
        reaching zero.
        A slip that is not already small is watched through its projection on its start
        direction, which crosses zero cleanly where its norm only touches it; ``eps`` is
        the stick band used otherwise. ``direction_next`` holds the borders just crossed:
        only a crossing back counts there, or the segment would end where it starts.
        """
        evs, kinds = [], []
        if y_target < math.inf:

            def e_target(tt, z):
                return z[1] - y_target

            e_target.terminal, e_target.direction = True, 1
            evs.append(e_target)
            kinds.append(("scrap", None))
        for c, (ox, oy) in enumerate(offs):
            for b, xb in enumerate(self.borders):

                def e_border(tt, z, ox=ox, oy=oy, xb=xb):
                    return z[0] + math.cos(z[2]) * ox - math.sin(z[2]) * oy - xb

                e_border.terminal = True
                # right after a crossing only a crossing back counts
                e_border.direction = direction_next.get((c, b), 0)
                evs.append(e_border)
                kinds.append(("border", (c, b)))
        slip_start = {}
        for s in range(self.nsurf):
            sig0 = self.slip(y, s)
            n0 = float(np.linalg.norm(sig0))
            slip_start[s] = n0
            if n0 > 10.0 * eps:
                d = sig0 / n0

                def e_stick(tt, z, s=s, d=d):
                    return float(self.slip(z, s) @ d)
            else:

                def e_stick(tt, z, s=s):
                    return float(np.linalg.norm(self.slip(z, s))) - eps

            e_stick.terminal, e_stick.direction = True, -1
            evs.append(e_stick)
            kinds.append(("stick", s))
        return evs, kinds, slip_start

    def _land_on_stick(self, y, s: int, slip_start: float, tol: float):
        """
        Return the state snapped onto surface ``s``'s velocity, and whether the stick holds.

        The slip's projection also changes sign when the slip turns by more than 90
        degrees within one segment: that is no stick, and ``y`` comes back as it was so
        that the next segment starts aimed along the new slip. Otherwise the parcel takes
        the surface's velocity (the stick's closed form) and sticks if the surface can
        hold it (``margin``); if not, it slides on from the snapped state.
        """
        if np.linalg.norm(self.slip(y, s)) > 1e-2 * slip_start + tol:
            return y, False
        z = y.copy()
        z[3], z[4], z[5] = self.vel[s][0], self.vel[s][1], 0.0
        m, a = self.margin(z, s)
        return z, a > 0.0 and m <= 0.0

    def run(
        self,
        method: str = "DOP853",
        rtol: float = 1e-8,
        atol: float = 1e-10,
        eps: float | None = None,
        max_rhs: float = math.inf,
        max_segments: int = 20000,
        dense: bool = False,
    ) -> Trajectory:
        """
        Integrate the case; returns a Trajectory (raises on solver failure).

        dense: keep solve_ivp's own dense output of every sliding segment as the
        trajectory's pieces (what ``compare`` reads between steps).

        Parameters
        ----------
        method : str
            The method.
        rtol : float
            The relative tolerance.
        atol : float
            The absolute tolerance.
        eps : float
            The stick band [m/s].
        max_rhs : float
            The evaluation budget.
        max_segments : int
            The most slide/stick segments.
        dense : bool
            Keep the dense output.

        Returns
        -------
        int or str
            The exit code, or a message for a refused input.

        """
        case = self.case
        self.n_rhs = 0
        self.max_rhs = max_rhs
        t, t_end = float(case.t_span[0]), float(case.t_span[1])
        y = np.array(case.y0, float)
        y_target = case.y_target
        vscale = max(max(math.hypot(*v) for v in self.vel), math.hypot(y[3], y[4]), 1e-3)
        eps = eps if eps is not None else max(1e-3 * atol, 1e-3 * rtol * vscale, 1e-14)
        mode = initial_mode(y, self.arr, self.par)
        T, Y, events, pieces = [t], [y.copy()], [], []
        offs = self._corner_offsets()
        direction_next: dict = {}
        n_steps = 0
        for _ in range(max_segments):
            if t >= t_end:
                break
            if mode >= 0:
                t, y, reason = self._stick_phase(t, y, mode, t_end, y_target)
                T.append(t)
                Y.append(y.copy())
                if reason == "scrap":
                    events.append((t, "scrap", None))
                    break
                if reason == "break":
                    events.append((t, "break", mode))
                    mode = -1
                continue
            evs, kinds, slip_start = self._slide_events(y, y_target, eps, offs, direction_next)
            direction_next = {}
            sol = solve_ivp(
                self.f,
                (t, t_end),
                y,
                method=method,
                rtol=rtol,
                atol=atol,
                events=evs,
                dense_output=dense,
            )
            if sol.status == -1:
                raise RuntimeError(sol.message)
            if dense and sol.t[-1] > sol.t[0]:
                pieces.append((float(sol.t[0]), float(sol.t[-1]), _ode_piece(sol.sol)))
            n_steps += len(sol.t) - 1
            T.extend(sol.t[1:])
            Y.extend(sol.y.T[1:])
            t, y = float(sol.t[-1]), sol.y[:, -1].copy()
            if sol.status == 0:
                break
            k = next(i for i, te in enumerate(sol.t_events) if len(te))
            kind, info = kinds[k]
            if kind == "scrap":
                events.append((t, "scrap", None))
                break
            if kind == "border":
                g0 = evs[k](sol.t[0], sol.y[:, 0])
                direction_next[info] = 1 if g0 > 0 else -1
                continue
            tol = 10.0 * (atol + rtol * vscale)
            y, holds = self._land_on_stick(y, info, slip_start[info], tol)
            if holds:
                events.append((t, "stick", info))
                mode = info
                T.append(t)
                Y.append(y.copy())
        else:
            raise RuntimeError(f"more than {max_segments} phases")
        Y = np.array(Y)
        return Trajectory(
            np.array(T),
            Y[:, :3],
            Y[:, 3:],
            events,
            n_steps=n_steps,
            n_rhs=self.n_rhs,
            pieces=pieces,
        )

    def run_threshold(
        self,
        method: str = "RK45",
        rtol: float = 1e-6,
        atol: float = 1e-8,
        v_min: float = 1e-6,
        max_rhs: float = math.inf,
        dense: bool = False,
    ) -> Trajectory:
        """
        Run solve_ivp on the seed's threshold model.

        solve_ivp straight on the seed's threshold model (eqs. 3.1/4.2/4.4): no events
        but the scrap line; the switch at |slip| = v_min is left to step control.

        Parameters
        ----------
        method : str
            The method.
        rtol : float
            The relative tolerance.
        atol : float
            The absolute tolerance.
        v_min : float
            The threshold speed [m/s].
        max_rhs : float
            The evaluation budget.
        dense : bool
            Keep the dense output.

        Returns
        -------
        Trajectory
            The trajectory.

        """
        case = self.case
        self.n_rhs = 0
        self.max_rhs = max_rhs
        evs = []
        if case.y_target < math.inf:

            def e_target(tt, z):
                return z[1] - case.y_target

            e_target.terminal, e_target.direction = True, 1
            evs.append(e_target)
        sol = solve_ivp(
            self.f_threshold(v_min),
            case.t_span,
            np.array(case.y0, float),
            method=method,
            rtol=rtol,
            atol=atol,
            events=evs or None,
            dense_output=dense,
        )
        if sol.status == -1:
            raise RuntimeError(sol.message)
        events = [(float(sol.t[-1]), "scrap", None)] if sol.status == 1 else []
        pieces = [(float(sol.t[0]), float(sol.t[-1]), _ode_piece(sol.sol))] if dense else []
        return Trajectory(
            sol.t,
            sol.y[:3].T,
            sol.y[3:].T,
            events,
            n_steps=len(sol.t) - 1,
            n_rhs=self.n_rhs,
            pieces=pieces,
        )

    def finish(self, traj: Trajectory) -> Trajectory:
        """
        Zone events of a run (outside the timing).

        Parameters
        ----------
        traj : Trajectory
            The trajectory.

        Returns
        -------
        Trajectory
            The trajectory.

        """
        return traj.with_zone_events(self.case.parcel.A, self.case.parcel.B, self.borders)


def _ode_piece(sol, n_pos: int = 3):
    """Return a solve_ivp OdeSolution as a Trajectory piece (its own interpolant)."""

    def fn(tq):
        y = sol(tq)
        return y[:n_pos].T, y[n_pos : 2 * n_pos].T

    return fn


def oscillator_scipy(
    osc: Oscillator,
    t_end: float,
    method: str = "DOP853",
    rtol: float = 1e-8,
    atol: float = 1e-10,
    dense: bool = False,
) -> Trajectory:
    """
    Run solve_ivp on the Fig. 4 body, phase by phase.

    solve_ivp on each sliding phase (terminal event: speed back to zero); rests in
    closed form (P = k (ẋ_s t - x) reaches F_stat at a known time).

    Parameters
    ----------
    osc : Oscillator
        The Fig. 4 body.
    t_end : float
        The end [s].
    method : str
        The method.
    rtol : float
        The relative tolerance.
    atol : float
        The absolute tolerance.
    dense : bool
        Keep the dense output.

    Returns
    -------
    Trajectory
        The trajectory.

    """
    m, f_kin, f_stat, k, vd = osc.m, osc.F_kin, osc.F_stat, osc.k, osc.v_drive
    t, x, v = 0.0, 0.0, 0.0
    T, X, V, events, pieces = [0.0], [0.0], [0.0], [], []
    n_rhs = n_steps = 0
    resting = True
    while t < t_end:
        if resting:
            # the spring force k (ẋ_s t - x) only grows: the rest ends at +F_stat
            t_b = max(t, (x + f_stat / k) / vd)
            if t_b >= t_end:
                T.append(t_end), X.append(x), V.append(0.0)
                break
            t = t_b
            T.append(t), X.append(x), V.append(0.0)
            events.append((t, "break", 0))
            resting = False
            continue
        sigma = 1.0 if (v > 0 or (v == 0 and k * (vd * t - x) > 0)) else -1.0

        def f(tt, z, sigma=sigma):
            return [z[1], (k * (vd * tt - z[0]) - sigma * f_kin) / m]

        def stop(tt, z, sigma=sigma):
            return z[1] * sigma

        stop.terminal, stop.direction = True, -1
        # the speed starts at 0: skip the start by looking for it only once it moved
        sol = solve_ivp(
            f,
            (t, t_end),
            [x, v],
            method=method,
            rtol=rtol,
            atol=atol,
            events=stop if v != 0.0 else _after_start(stop, t),
            dense_output=dense,
        )
        if sol.status == -1:
            raise RuntimeError(sol.message)
        if dense and sol.t[-1] > sol.t[0]:
            pieces.append((float(sol.t[0]), float(sol.t[-1]), _ode_piece(sol.sol, 1)))
        n_rhs += sol.nfev
        n_steps += len(sol.t) - 1
        T.extend(sol.t[1:]), X.extend(sol.y[0, 1:]), V.extend(sol.y[1, 1:])
        t, x, v = float(sol.t[-1]), float(sol.y[0, -1]), float(sol.y[1, -1])
        if sol.status == 0:
            break
        v = 0.0
        V[-1] = 0.0
        if abs(k * (vd * t - x)) <= f_stat:
            resting = True
            events.append((t, "stick", 0))
    return Trajectory(T, X, V, events, n_steps=n_steps, n_rhs=n_rhs, pieces=pieces)
