"""
A method's result as a trajectory, and its errors against a reference.

- ``Trajectory``: what any method produced, reduced to recorded times, generalized
  positions q (x, y, φ of the centre of gravity, or the Fig. 4 body's x) and their
  rates, plus its events. Between records it is read by cubic Hermite interpolation
  on (q, q̇), the same order as the accurate method's own dense output, so a method
  is judged at any time without resampling it.
- ``compare``: final position error, the maximum error over a 1 kHz output grid,
  and event-time errors (stick, break-away, zone entry, scrap), against a reference
  trajectory (``Errors``).
- ``dp5_pieces``: a Dormand-Prince run's own dense output, piece by piece.

Units: SI (m, s, rad); errors in m (positions) and s (event times).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sorter_sim.model.core.dopri import A as _DP_A
from sorter_sim.model.core.dopri import B as _DP_B
from sorter_sim.model.core.dopri import C as _DP_C
from sorter_sim.model.core.dopri import P as _DP_P

EVENT_KINDS = ("stick", "break", "zone", "scrap")


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


__all__ = ["EVENT_KINDS", "Errors", "Trajectory", "compare", "dp5_pieces"]
