"""
Work-precision measurement: run a method at a setting, time it, and measure its error.

This module owns the machinery behind ``sorter bench``, in the manner of SciML's
work-precision diagrams (DiffEqDevTools ``benchmark.jl``): a stated reference, the
warm-up run discarded, the minimum of several timed runs, failures kept in the table
with their reason, and the machine and library versions printed with the figures.

- ``Trajectory``: what any method produced, reduced to recorded times, generalized
  positions q (x, y, φ of the centre of gravity, or the Fig. 4 body's x) and their
  rates, plus its events. Between records it is read by cubic Hermite interpolation
  on (q, q̇), the same order as the accurate method's own dense output, so a method
  is judged at any time without resampling it.
- ``compare``: final position error, the maximum error over a 1 kHz output grid,
  and event-time errors (stick, break-away, zone entry, scrap), against a reference
  trajectory.
- Runners that turn each method into a ``Trajectory``: the core's three methods,
  scipy's ``solve_ivp`` on the same model (``ScipyParcel``: sliding phases by
  ``solve_ivp`` with events, stick phases in closed form), scipy on the seed's
  threshold model, and the same for the Fig. 4 body.
- ``measure``: one table row (``WPRow``) per method and setting.

Units: SI (m, s, rad); errors in m (positions) and s (event times).
"""

from __future__ import annotations

import math
import os
import platform
import time
from dataclasses import dataclass, field

import numpy as np

from sorter_sim.model.core.common import rhs_slide
from sorter_sim.model.core.dopri import A as _DP_A
from sorter_sim.model.core.dopri import B as _DP_B
from sorter_sim.model.core.dopri import C as _DP_C
from sorter_sim.model.core.dopri import P as _DP_P
from sorter_sim.model.core.layout import Contact
from sorter_sim.model.core.oscillator import Oscillator, exact_phases, run_oscillator
from sorter_sim.model.core.simulate import (
    Parcel,
    initial_mode,
    parcel_array,
    simulate,
    strip_array,
    strip_borders,
)
from sorter_sim.model.core.wrench import clip_scratch, gauss_legendre_01

EVENT_KINDS = ("stick", "break", "zone", "scrap")


# ------------------------------------------------------------------ machine and versions
def machine_info() -> dict:
    """CPU model, core count and library versions, for the report's header."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import numba
    import scipy

    info = {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "os": platform.platform(terse=True),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
    }
    try:
        import matplotlib

        info["matplotlib"] = matplotlib.__version__
    except ImportError:
        pass
    return info


def machine_line(info: dict | None = None) -> str:
    """
    Return one line describing the machine and the library versions.

    Parameters
    ----------
    info : dict, optional
        The machine's description (``machine_info``).

    Returns
    -------
    str
        The line.

    """
    info = info or machine_info()
    libs = ", ".join(
        f"{k} {info[k]}" for k in ("python", "numpy", "scipy", "numba", "matplotlib") if k in info
    )
    return f"{info['cpu']}, {info['cores']} cores, {info['os']}; {libs}"


class one_core:
    """Pin this process to one CPU while timing (the targets are per core)."""

    def __enter__(self):
        self._saved = None
        if hasattr(os, "sched_getaffinity"):
            self._saved = os.sched_getaffinity(0)
            os.sched_setaffinity(0, {min(self._saved)})
        return self

    def __exit__(self, *exc):
        if self._saved is not None:
            os.sched_setaffinity(0, self._saved)
        return False


# ------------------------------------------------------------------ trajectories
@dataclass
class Trajectory:
    """
    Records of one run: t (n,), q (n, k) positions, dq (n, k) their rates.

    events: [(t, kind, key)] with kind in EVENT_KINDS; keys identify the same event
    in two runs (the surface for stick/break, (corner, border) for a zone entry).
    n_rhs counts right-hand-side evaluations (or implicit steps).
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    events: list = field(default_factory=list)
    n_steps: int = 0
    n_rhs: int = 0
    status: str = "ok"
    pieces: list = field(default_factory=list)  # [(t0, t1, fn(tq) -> (q, dq))], sorted
    make_pieces: object = None  # built on first use, outside any timing

    def __post_init__(self):
        self.t = np.asarray(self.t, float)
        self.q = np.asarray(self.q, float).reshape(len(self.t), -1)
        self.dq = np.asarray(self.dq, float).reshape(len(self.t), -1)

    @property
    def t_end(self) -> float:
        return float(self.t[-1])

    def at(self, tq) -> tuple[np.ndarray, np.ndarray]:
        """
        Return (q, q̇) at times tq.

        (q, q̇) at times tq: the method's own dense output where it has one
        (``pieces``), else cubic Hermite interpolation on (q, q̇) between records.

        A record pair at one time (a velocity jump at an event) splits the pieces:
        times after it use the later record. Past the last record the motion is
        continued at the last velocity (used only to read a run that stopped a
        hair before the reference's end, e.g. at the scrap line).

        Parameters
        ----------
        tq : ndarray
            Query times [s].

        Returns
        -------
        (ndarray, ndarray)
            The positions and velocities.

        """
        tq = np.atleast_1d(np.asarray(tq, float))
        q, dq = self._hermite(tq)
        if self.make_pieces is not None:
            self.pieces, self.make_pieces = self.make_pieces(self), None
        if self.pieces:
            starts = np.array([p[0] for p in self.pieces])
            k = np.searchsorted(starts, tq, side="right") - 1
            # group the query times by piece once (a mask per piece would cost
            # pieces x queries: minutes for a 10-minute run read on a 1 ms grid)
            order = np.argsort(k, kind="stable")
            groups = np.split(order, np.flatnonzero(np.diff(k[order])) + 1)
            for grp in groups:
                j = k[grp[0]]
                if j < 0:
                    continue
                t0, t1, fn = self.pieces[j]
                sel = grp[(tq[grp] >= t0) & (tq[grp] < t1)]
                if sel.size:
                    q[sel], dq[sel] = fn(tq[sel])
        return q, dq

    def _hermite(self, tq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(self.t)
        i = np.searchsorted(self.t, tq, side="right") - 1
        i = np.clip(i, 0, n - 1)
        last = i >= n - 1
        i2 = np.minimum(i + 1, n - 1)
        h = self.t[i2] - self.t[i]
        ok = (~last) & (h > 0)
        s = np.where(ok, (tq - self.t[i]) / np.where(ok, h, 1.0), 0.0)[:, None]
        hh = np.where(ok, h, 0.0)[:, None]
        q0, q1, d0, d1 = self.q[i], self.q[i2], self.dq[i], self.dq[i2]
        h00 = 2 * s**3 - 3 * s**2 + 1
        h10 = s**3 - 2 * s**2 + s
        h01 = -2 * s**3 + 3 * s**2
        h11 = s**3 - s**2
        q = h00 * q0 + h10 * hh * d0 + h01 * q1 + h11 * hh * d1
        with np.errstate(invalid="ignore", divide="ignore"):
            dq = np.where(
                ok[:, None],
                (
                    (6 * s**2 - 6 * s) * (q0 - q1) / np.where(hh > 0, hh, 1.0)
                    + (3 * s**2 - 4 * s + 1) * d0
                    + (3 * s**2 - 2 * s) * d1
                ),
                self.dq[i],
            )
        beyond = tq > self.t[-1]
        if np.any(beyond):
            q[beyond] = self.q[-1] + self.dq[-1] * (tq[beyond] - self.t[-1])[:, None]
            dq[beyond] = self.dq[-1]
        before = tq < self.t[0]
        q[before] = self.q[0]
        dq[before] = self.dq[0]
        return q, dq

    def with_zone_events(self, A: float, B: float, borders) -> "Trajectory":
        """
        Add 'zone' events: each footprint corner crossing each strip border.

        Times come from the interpolated trajectory (a sign change of corner x -
        border between records, refined by bisection on the Hermite pieces), so
        every method is read the same way. Key: (corner, border index, n-th crossing).

        Parameters
        ----------
        A : float
            The parcel's length [m].
        B : float
            Its width [m].
        borders : sequence of float
            The strip borders [m].

        Returns
        -------
        Trajectory
            The trajectory with its zone events.

        """
        borders = np.asarray(borders, float)
        if borders.size == 0 or self.q.shape[1] < 3:
            return self
        ha, hb = 0.5 * A, 0.5 * B
        offs = np.array([(ha, -hb), (ha, hb), (-ha, hb), (-ha, -hb)])

        def corner_x(q, c):
            return q[:, 0] + np.cos(q[:, 2]) * offs[c, 0] - np.sin(q[:, 2]) * offs[c, 1]

        found = []
        for c in range(4):
            cx = corner_x(self.q, c)
            for b, xb in enumerate(borders):
                g = cx - xb
                idx = np.nonzero((g[:-1] < 0) != (g[1:] < 0))[0]
                for n_cross, k in enumerate(idx):
                    lo, hi = self.t[k], self.t[k + 1]
                    glo = g[k]
                    for _ in range(60):
                        if hi - lo <= 1e-14 * max(1.0, abs(hi)):
                            break
                        mid = 0.5 * (lo + hi)
                        qm, _ = self.at(mid)
                        gm = corner_x(qm, c)[0] - xb
                        if (gm < 0) == (glo < 0):
                            lo = mid
                        else:
                            hi = mid
                    found.append((float(hi), "zone", (c, b, n_cross)))
        self.events = sorted(
            [e for e in self.events if e[1] != "zone"] + found, key=lambda e: e[0]
        )
        return self


# ------------------------------------------------------------------ errors
@dataclass
class Errors:
    """Errors of one run against the reference [m, s]; nan where not measurable."""

    final: float
    grid_max: float
    events: dict  # kind -> max |Δt| over the reference's events of that kind
    missing: dict  # kind -> count of reference events the run did not produce
    extra: dict  # kind -> count of events beyond the reference's

    def event_text(self, kind: str) -> str:
        """
        Return a table cell for the error of one kind of event (or what was missed).

        Parameters
        ----------
        kind : str
            The event's kind.

        Returns
        -------
        str
            The text.

        """
        e = self.events.get(kind, math.nan)
        miss = self.missing.get(kind, 0)
        if miss:
            return f"missed {miss}"
        return "–" if not math.isfinite(e) else f"{e:.1e}"


def _position(q: np.ndarray) -> np.ndarray:
    """Return the positional part compared: CoG (x, y) for the parcel, x for the Fig. 4 body."""
    return q[:, :2] if q.shape[1] >= 3 else q[:, :1]


def compare(run: Trajectory, ref: Trajectory, grid_hz: float = 1000.0) -> Errors:
    """
    Errors of ``run`` against ``ref`` (see the module docstring).

    final: |p(t_f) - p_ref(t_f)| at the reference's last time t_f (CoG position);
    grid_max: max of the same over t0, t0 + 1/grid_hz, ... up to the common end;
    events: for each reference event, the nearest run event with the same kind and
    key; the largest such |Δt| per kind.

    Parameters
    ----------
    run : Trajectory or callable
        The run, or what makes it.
    ref : Trajectory
        The reference.
    grid_hz : float
        The comparison grid's rate [Hz].

    Returns
    -------
    Errors
        The errors.

    """
    t_f = ref.t_end
    p_run, _ = run.at(t_f)
    p_ref, _ = ref.at(t_f)
    final = float(np.linalg.norm(_position(p_run) - _position(p_ref)))
    t_common = min(ref.t_end, run.t_end)
    grid = np.arange(ref.t[0], t_common, 1.0 / grid_hz)
    grid = np.append(grid, t_common)
    qa, _ = run.at(grid)
    qb, _ = ref.at(grid)
    grid_max = float(np.max(np.linalg.norm(_position(qa) - _position(qb), axis=1)))
    ev_err: dict = {}
    missing: dict = {}
    extra: dict = {}
    for kind in EVENT_KINDS:
        ref_ev = [(t, k) for t, kd, k in ref.events if kd == kind]
        run_ev = [(t, k) for t, kd, k in run.events if kd == kind]
        if not ref_ev:
            if run_ev:
                extra[kind] = len(run_ev)
            continue
        worst = 0.0
        miss = 0
        for t, key in ref_ev:
            cands = [abs(tr - t) for tr, kr in run_ev if kr == key]
            if cands:
                worst = max(worst, min(cands))
            else:
                miss += 1
        ev_err[kind] = worst if miss < len(ref_ev) else math.nan
        if miss:
            missing[kind] = miss
        if len(run_ev) > len(ref_ev):
            extra[kind] = len(run_ev) - len(ref_ev)
    return Errors(final, grid_max, ev_err, missing, extra)


# ------------------------------------------------------------------ dense output of DP5 records
def dp5_pieces(t: np.ndarray, Y: np.ndarray, rhs_for_step, n_pos: int) -> list:
    """
    Return the dense output of Dormand-Prince 5(4) steps that ended at consecutive records.

    The accurate methods record step ends only. Each interval between records is
    redone as one Dormand-Prince step from record i with h = t[i+1] - t[i] (same
    state, same h: the same stages), kept only if it lands on record i+1's position
    (velocities may have been set at a stick), and read through the 4th-order
    interpolant of Shampine (1986) that the core uses to locate events. Intervals
    that are not such a step (a stick advanced in closed form, the break-away
    layer) fail the check and keep cubic Hermite interpolation.
    rhs_for_step(t_i, y_i) -> f(t, y) = y', the right-hand side of the step starting at
    record i (the Fig. 4 body's friction sign is fixed per step). Returns the pieces.

    Parameters
    ----------
    t : ndarray
        The step times [s].
    Y : ndarray
        The states at the steps.
    rhs_for_step : callable
        The right-hand side at a step.
    n_pos : int
        The number of position components.

    Returns
    -------
    list
        The dense-output pieces.

    """
    pieces = []
    n = len(t)
    K = np.empty((7, Y.shape[1]))
    for i in range(n - 1):
        h = t[i + 1] - t[i]
        if not h > 0.0:
            continue
        y0 = Y[i]
        f = rhs_for_step(t[i], y0)
        K[0] = f(t[i], y0)
        for st in range(1, 6):
            K[st] = f(t[i] + _DP_C[st] * h, y0 + h * (_DP_A[st, :st] @ K[:st]))
        y1 = y0 + h * (_DP_B @ K[:6])
        scale = 1.0 + np.max(np.abs(y1[:n_pos]))
        if not np.max(np.abs(y1[:n_pos] - Y[i + 1, :n_pos])) <= 1e-9 * scale:
            continue
        K[6] = f(t[i] + h, y1)
        pieces.append((t[i], t[i + 1], _dp5_eval(t[i], h, y0.copy(), K.copy(), n_pos)))
    return pieces


def _dp5_eval(t0, h, y0, K, n_pos):
    def fn(tq):
        th = (np.asarray(tq) - t0) / h
        powers = np.vstack([th, th**2, th**3, th**4])  # (4, m)
        y = y0[None, :] + h * (K.T @ (_DP_P @ powers)).T
        return y[:, :n_pos], y[:, n_pos : 2 * n_pos]

    return fn


# ------------------------------------------------------------------ runners: the core model
def core_trajectory(res, mode0: int | None = None) -> Trajectory:
    """
    Return a ``SimResult`` as a Trajectory, its events named as ``compare`` matches them.

    The threshold method logs the set of 'static' surfaces as a bit mask; it is
    turned into per-surface stick (surface becomes static) and break events.

    Parameters
    ----------
    res : SimResult
        A run.
    mode0 : int, optional
        The start's mode.

    Returns
    -------
    Trajectory
        The trajectory.

    """
    events = []
    if res.method == "threshold":
        prev = 0 if mode0 is None or mode0 < 0 else (1 << mode0)
        for t, kind, code in res.events:
            if kind in ("stick", "break"):
                for s in range(len(res.surfaces)):
                    bit = 1 << s
                    if code & bit and not prev & bit:
                        events.append((t, "stick", s))
                    if prev & bit and not code & bit:
                        events.append((t, "break", s))
                prev = code
            elif kind == "target":
                events.append((t, "scrap", None))
    else:
        for t, kind, info in res.events:
            if kind in ("stick", "break"):
                events.append((t, kind, info))
            elif kind == "target":
                events.append((t, "scrap", None))
    return Trajectory(
        res.t,
        res.y[:, :3],
        res.y[:, 3:],
        events,
        n_steps=res.n_steps,
        n_rhs=res.n_rhs,
        status="ok" if res.success else res.message,
    )


@dataclass
class ParcelCase:
    """One parcel over one set of strips: what every runner of a study needs."""

    parcel: Parcel
    strips: list
    y0: np.ndarray
    t_span: tuple
    y_target: float = math.inf
    rotation: bool = True
    n_quad: int = 8

    @property
    def borders(self) -> np.ndarray:
        return strip_borders(self.strips)

    def run_core(self, method: str, **settings):
        """
        One run of a core method (settings: rtol/atol, dt, v_min, reductions ...).

        Parameters
        ----------
        method : str
            The method.

        """
        settings.setdefault("max_points", _capacity(self.t_span, settings.get("dt")))
        return simulate(
            self.parcel,
            self.strips,
            self.y0,
            self.t_span,
            method,
            y_target=self.y_target,
            rotation=self.rotation,
            n_quad=self.n_quad,
            **settings,
        )

    def trajectory(self, res) -> Trajectory:
        """
        Return a core result as a Trajectory with zone events.

        A core result as a Trajectory with zone events; the accurate method's records
        are read through its own dense output (``dp5_pieces``).

        Parameters
        ----------
        res : SimResult
            A run.

        Returns
        -------
        Trajectory
            The trajectory.

        """
        par = parcel_array(self.parcel, self.rotation, self.n_quad)
        arr = strip_array(self.strips)
        traj = core_trajectory(res, initial_mode(np.asarray(self.y0, float), arr, par))
        if res.method == "accurate":
            nodes, weights = gauss_legendre_01(self.n_quad)
            clip = clip_scratch()

            def f(t, y):
                out = np.empty(6)
                rhs_slide(y, Contact(arr, par, nodes, weights), clip, out)
                return out

            traj.make_pieces = lambda tr: dp5_pieces(
                tr.t, np.hstack([tr.q, tr.dq]), lambda t0, y0: f, 3
            )
        return traj.with_zone_events(self.parcel.A, self.parcel.B, self.borders)

    def core(self, method: str, **settings) -> Trajectory:
        """
        Run the core's method on this case and return its trajectory.

        Parameters
        ----------
        method : str
            The method.

        Returns
        -------
        Trajectory
            The trajectory.

        """
        return self.trajectory(self.run_core(method, **settings))


def _capacity(t_span, dt) -> int:
    if dt is None:
        return 200_000
    return int((t_span[1] - t_span[0]) / dt) + 1000


# ------------------------------------------------------------------ runners: the Fig. 4 body
def oscillator_exact(osc: Oscillator, t_end: float) -> Trajectory:
    """
    Return the exact piecewise Coulomb solution as a Trajectory, read exactly at any time.

    Parameters
    ----------
    osc : Oscillator
        The Fig. 4 body.
    t_end : float
        The end [s].

    Returns
    -------
    Trajectory
        The trajectory.

    """
    from sorter_sim.model.core.oscillator import exact_solution

    phases = exact_phases(osc, t_end)
    starts = [p[0] for p in phases if 0.0 < p[0] < t_end]
    t = np.unique(np.concatenate([np.linspace(0.0, t_end, int(t_end * 100) + 1), starts]))
    ex = exact_solution(osc, t_end, t_eval=t)
    events = [
        (p[0], "break" if p[1] == "slide" else "stick", 0) for p in phases[1:] if p[0] < t_end
    ]

    def exact(tq):
        e = exact_solution(osc, t_end, t_eval=tq)
        return e.x[:, None], e.v[:, None]

    return Trajectory(ex.t, ex.x, ex.v, events, pieces=[(0.0, t_end, exact)])


def _oscillator_rhs(osc: Oscillator):
    """Sliding right-hand side of the Fig. 4 body for a step starting at (t0, y0)."""

    def for_step(t0, y0):
        p0 = osc.k * (osc.v_drive * t0 - y0[0])
        sigma = 1.0 if (y0[1] > 0 or (y0[1] == 0 and p0 > 0)) else -1.0

        def f(t, y):
            return np.array([y[1], (osc.k * (osc.v_drive * t - y[0]) - sigma * osc.F_kin) / osc.m])

        return f

    return for_step


def oscillator_core(osc: Oscillator, t_end: float, method: str, **settings):
    """
    Run the Fig. 4 body with a core method.

    One core run of the Fig. 4 body (``oscillator_trajectory`` reads it); room for every
    fixed step's record (run_oscillator drops records beyond max_points).

    Parameters
    ----------
    osc : Oscillator
        The Fig. 4 body.
    t_end : float
        The end [s].
    method : str
        The method.

    """
    if method != "accurate":
        settings.setdefault("max_points", int(t_end / settings.get("dt", 1e-3)) + 10)
    return run_oscillator(osc, t_end, method, **settings)


def oscillator_trajectory(osc: Oscillator, res) -> Trajectory:
    """
    Return a core oscillator run as a Trajectory.

    A core oscillator run as a Trajectory; eq. 3.1 rows of the threshold method map to
    events as the seed reads them: entering row 3 = leaving rest, entering row 2 = rest.

    Parameters
    ----------
    osc : Oscillator
        The Fig. 4 body.
    res : SimResult
        A run.

    Returns
    -------
    Trajectory
        The trajectory.

    """
    events = []
    for t, kind in res.events:
        k = {"slip": "break", "row3": "break", "stick": "stick", "row2": "stick"}.get(kind)
        if k:
            events.append((t, k, 0))
    traj = Trajectory(res.t, res.x, res.v, events, n_steps=res.n_steps, n_rhs=res.n_rhs)
    if res.method == "accurate":
        traj.make_pieces = lambda tr: dp5_pieces(
            tr.t, np.hstack([tr.q, tr.dq]), _oscillator_rhs(osc), 1
        )
    return traj


def _after_start(event, t0, skip=1e-12):
    """Return an event that cannot fire within ``skip`` of the segment start (where it is 0)."""

    def e(tt, z):
        return event(tt, z) if tt > t0 + skip else 1.0

    e.terminal, e.direction = event.terminal, event.direction
    return e


# ------------------------------------------------------------------ timing and table rows
@dataclass
class WPRow:
    """One method at one setting: wall time (min of n_runs, warm-up discarded), errors."""

    case: str
    family: str
    setting: str
    wall_s: float = math.nan
    n_runs: int = 0
    n_rhs: int = 0
    errors: Errors | None = None
    failure: str = ""
    traj: Trajectory | None = None

    @property
    def ok(self) -> bool:
        return not self.failure


def timed(fn, repeats: int = 3, budget_s: float = 2.0):
    """
    Run ``fn`` repeatedly: returns (last result, min wall time, number of timed runs).

    The caller discards a warm-up run per method beforehand (``measure`` does);
    repeats stop early once ``budget_s`` has been spent, after at least one run.

    Parameters
    ----------
    fn : callable
        What to time.
    repeats : int
        Timed repeats; the best counts.
    budget_s : float
        The most time to spend [s].

    """
    best = math.inf
    out = None
    spent = 0.0
    n = 0
    for _ in range(max(1, repeats)):
        w = time.perf_counter()
        out = fn()
        w = time.perf_counter() - w
        best = min(best, w)
        spent += w
        n += 1
        if spent >= budget_s:
            break
    return out, best, n


_WARM: set = set()


def measure(
    case_name: str,
    family: str,
    setting: str,
    run,
    ref: Trajectory | None,
    finish=None,
    repeats: int = 3,
    budget_s: float = 2.0,
    warm_key=None,
) -> WPRow:
    """
    Time ``run()`` and compare ``finish(result)`` (a Trajectory) with ``ref``.

    Only ``run`` is timed; ``finish`` turns its result into a Trajectory (dense
    output, zone events) afterwards. The first call for each ``warm_key`` (default:
    the family) runs once untimed, so compilation never enters a figure. A failure
    (an exception, a non-finite state, an unsuccessful status) is kept in the row
    with its reason.

    Parameters
    ----------
    case_name : str
        The case.
    family : str
        The method family.
    setting : str
        The setting.
    run : Trajectory or callable
        The run, or what makes it.
    ref : Trajectory
        The reference.
    finish : callable, optional
        Turns the run's result into a trajectory.
    repeats : int
        Timed repeats; the best counts.
    budget_s : float
        The most time to spend [s].
    warm_key : object, optional
        Warm up once per key.

    Returns
    -------
    WPRow
        The row.

    """
    row = WPRow(case_name, family, setting)
    key = warm_key or family
    try:
        if key not in _WARM:
            run()
            _WARM.add(key)
        out, wall, n = timed(run, repeats, budget_s)
        traj = finish(out) if finish is not None else out
    except Exception as exc:  # kept in the table with its reason, as the report promises
        row.failure = f"{type(exc).__name__}: {exc}".splitlines()[0][:120]
        return row
    row.wall_s, row.n_runs, row.n_rhs, row.traj = wall, n, traj.n_rhs, traj
    if traj.status != "ok":
        row.failure = traj.status
    if not np.all(np.isfinite(traj.q)) or not np.all(np.isfinite(traj.dq)):
        row.failure = "non-finite state"
        return row
    if ref is not None:
        scrapped = any(k == "scrap" for _, k, _ in traj.events)
        if traj.t_end < ref.t_end - 1e-2 and not scrapped:
            row.failure = (
                f"output ends at t = {traj.t_end:.4g} s, before the reference's {ref.t_end:.4g} s"
            )
            return row
        row.errors = compare(traj, ref)
    return row


def cheapest_within(rows: list[WPRow], error: float, attr: str = "final") -> WPRow | None:
    """
    Return the fastest successful row whose error ``attr`` is at most ``error``.

    Parameters
    ----------
    rows : list of WPRow
        Measured rows.
    error : float
        The error level [m].
    attr : str
        Which error: final or max.

    Returns
    -------
    WPRow or None
        The row, or None.

    """
    ok = [r for r in rows if r.ok and r.errors is not None and getattr(r.errors, attr) <= error]
    return min(ok, key=lambda r: r.wall_s) if ok else None


def fmt_e(x: float) -> str:
    """
    Return an error for a table: one significant decimal, '–' where there is none.

    Parameters
    ----------
    x : float
        A number.

    Returns
    -------
    str
        The text.

    """
    return "–" if x is None or not math.isfinite(x) else f"{x:.1e}"


def fmt_ms(x: float) -> str:
    """
    Return a time in ms for a table, '–' where there is none.

    Parameters
    ----------
    x : float
        A number.

    Returns
    -------
    str
        The text.

    """
    if not math.isfinite(x):
        return "–"
    return f"{x * 1e3:.3g}"


def rows_markdown(rows: list[WPRow], kinds=EVENT_KINDS) -> str:
    """
    Return a markdown table of rows: family, setting, time, errors, events, failures.

    Parameters
    ----------
    rows : list of WPRow
        Measured rows.
    kinds : sequence of str
        The event kinds to show.

    Returns
    -------
    str
        The table.

    """
    head = (
        ["method", "setting", "time [ms]", "runs", "rhs", "final CoG err [m]", "max err 1 kHz [m]"]
        + [f"{k} Δt [s]" for k in kinds]
        + ["status"]
    )
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        e = r.errors
        cells = [
            r.family,
            r.setting,
            fmt_ms(r.wall_s),
            str(r.n_runs or "–"),
            str(r.n_rhs or "–"),
            fmt_e(e.final) if e else "–",
            fmt_e(e.grid_max) if e else "–",
        ]
        cells += [e.event_text(k) if e else "–" for k in kinds]
        status = r.failure or "ok"
        if e and e.extra:
            status += "; extra events: " + ", ".join(f"{k} +{n}" for k, n in e.extra.items())
        cells.append(status.replace("|", "/"))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_work_precision(rows: list[WPRow], path, title: str, attr: str = "final", ax=None) -> None:
    """
    Plot error against wall time.

    Error (log x) against wall time (log y), one line per family; failures left out.
    Draws into ``ax`` when given, else writes a PNG to ``path``.

    Parameters
    ----------
    rows : list of WPRow
        Measured rows.
    path : str or Path
        The path.
    title : str
        The plot's title.
    attr : str
        Which error: final or max.
    ax : matplotlib Axes, optional
        Where to draw.

    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(7.5, 5.0))
    families: dict = {}
    for r in rows:
        if r.ok and r.errors is not None:
            err = getattr(r.errors, attr)
            if math.isfinite(err) and math.isfinite(r.wall_s):
                families.setdefault(r.family, []).append((max(err, 1e-16), r.wall_s))
    markers = "osD^v<>pP*Xh"
    styles = ("-", "--", ":", "-.")
    for i, (fam, pts) in enumerate(families.items()):
        pts.sort()
        ax.loglog(
            [p[0] for p in pts],
            [p[1] for p in pts],
            marker=markers[i % len(markers)],
            ls=styles[(i // 10) % len(styles)],
            label=fam,
            lw=1.2,
            ms=4,
        )
    ax.set_xlabel(
        "error [m]" + (" (max over 1 kHz grid)" if attr == "grid_max" else " (final CoG position)")
    )
    ax.set_ylabel("wall time [s]")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6, loc="best")
    if own:
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
