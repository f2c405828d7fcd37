"""
The seed's stick-slip test body (Fig. 4): a block on a fixed surface pulled by a spring.

A body of mass m_p rests on a surface; a spring of stiffness k joins it to a
point B driven at constant speed ẋ_s, so the external force is
P_ext = k (x_s - x_p). Friction follows eq. (3.1): kinetic F_kin while sliding,
holding up to F_stat at rest. The seed's data: m_p = 1 kg, F_kin = 1 N,
F_stat = 1.5 N, k = 2 N/m, ẋ_s = 0.1 m/s, v_min = 0.001 m/s, all at rest at t = 0.

With ideal Coulomb friction each phase is solvable in closed form: at rest,
P grows linearly until it reaches F_stat (first at t = F_stat/(k ẋ_s) = 7.5 s);
sliding, x_p - (x_s - σ F_kin/k) is a harmonic oscillation of ω0 = sqrt(k/m),
until the body's speed returns to zero. ``exact_solution`` strings these phases.

Three methods mirror those of the planar model: ``accurate`` (Dormand-Prince
5(4) within each sliding phase, the phase ends located as events; rests in
closed form), ``implicit`` (backward Euler in velocity, Kikuuwe et al. 2005:
exact stick at any step) and ``threshold`` (eq. 3.1 with v_min, classic RK4).
Units: kg, N, m, s.
"""

from __future__ import annotations

import math
import time
from collections import namedtuple
from dataclasses import dataclass, field

import numpy as np

from sorter_sim.model.core.cache import check_kernel_cache
from sorter_sim.model.core.dopri import error_norm, make_step, step_factor
from sorter_sim.model.core.jit import borrowing, kernel

# what a run of the body writes: its records (t, x, v, the active row of eq. 3.1) and events
OscRecord = namedtuple('OscRecord', ['ts', 'xs', 'vs', 'rows'])
OscEvents = namedtuple('OscEvents', ['ev_t', 'ev_k'])

# rows of eq. (3.1), as the seed numbers them
ROW_KINETIC = 1  # F(1): |v| > v_min, F = F_kin sgn(v)
ROW_HOLD = 2  # F(2): |P| < F_stat, F = P (held)
ROW_BREAK = 3  # F(3): |P| >= F_stat, F = F_stat sgn(P) (leaving rest)


@dataclass(frozen=True)
class Oscillator:
    """Fig. 4 parameters: m [kg], F_kin, F_stat [N], k [N/m], v_drive = ẋ_s [m/s]."""

    m: float = 1.0
    F_kin: float = 1.0
    F_stat: float = 1.5
    k: float = 2.0
    v_drive: float = 0.1

    def __post_init__(self):
        for name in ("m", "k", "v_drive"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"oscillator {name} must be a finite number > 0, got {v}")
        if not (math.isfinite(self.F_kin) and self.F_kin >= 0):
            raise ValueError(f"oscillator F_kin must be finite and >= 0, got {self.F_kin}")
        if not (math.isfinite(self.F_stat) and self.F_stat >= self.F_kin):
            raise ValueError(f"oscillator F_stat must be finite and >= F_kin, got {self.F_stat}")

    @property
    def omega0(self) -> float:
        return math.sqrt(self.k / self.m)

    def params(self) -> np.ndarray:
        return np.array([self.m, self.F_kin, self.F_stat, self.k, self.v_drive])


@dataclass
class OscResult:
    """
    Hold a trajectory of the Fig. 4 body.

    Trajectory of the body: t, x (body), v, x_spring (point B), P (external force),
    F (friction force on the body, opposing), row (eq. 3.1 row, threshold method; else
    1 sliding / 2 at rest), events [(t, 'stick'|'slip')], counters and wall time.
    """

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    x_spring: np.ndarray
    P: np.ndarray
    F: np.ndarray
    row: np.ndarray
    events: list
    method: str
    n_steps: int = 0
    n_rhs: int = 0
    wall_s: float = 0.0
    extra: dict = field(default_factory=dict)


def exact_phases(osc: Oscillator, t_end: float):
    """
    Return the exact sequence of phases up to t_end: list of (t_start, kind, x0, v0, sigma).

    Parameters
    ----------
    osc : Oscillator
        The body.
    t_end : float
        The end [s].

    Returns
    -------
    list of tuple
        (t_start, kind, x0, v0, σ) of each phase.

    """
    if not (math.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end must be a finite time > 0 s, got {t_end}")
    w0 = osc.omega0
    t = 0.0
    x = 0.0
    v = 0.0
    phases = []
    kind = "rest"
    guard = 0
    while t < t_end and guard < 100000:
        guard += 1
        if kind == "rest":
            # P(t) = k (v_d t - x) grows; rest ends when it reaches F_stat
            phases.append((t, "rest", x, 0.0, 0.0))
            t_break = (osc.F_stat / osc.k + x) / osc.v_drive
            t = max(t_break, t)
            kind = "slide"
            continue
        p = osc.k * (osc.v_drive * t - x)
        sigma = 1.0 if (v > 0 or (v == 0 and p > 0)) else -1.0
        phases.append((t, "slide", x, v, sigma))
        # z = x - (x_s - σ F_kin/k), ż = v - v_d, harmonic with ω0
        z0 = x - (osc.v_drive * t - sigma * osc.F_kin / osc.k)
        zd0 = v - osc.v_drive
        amp = math.hypot(z0 * w0, zd0)
        psi = math.atan2(z0 * w0, zd0)
        # v(τ) = v_d + amp cos(ω0 τ + ψ) = 0 again: ω0 τ = -2ψ (mod 2π)
        if amp <= osc.v_drive:
            # never slows to rest: slides for good
            t = t_end
            break
        theta = (-2.0 * psi) % (2.0 * math.pi)
        if theta <= 1e-12:
            theta = 2.0 * math.pi
        tau = theta / w0
        # sliding the other way could stop earlier; check the first zero crossing of v
        c = math.acos(max(-1.0, min(1.0, -osc.v_drive / amp)))
        cand = [((c - psi) % (2 * math.pi)) / w0, ((-c - psi) % (2 * math.pi)) / w0]
        cand = [tc for tc in cand if tc > 1e-12]
        tau = min(cand) if cand else tau
        zt = z0 * math.cos(w0 * tau) + zd0 / w0 * math.sin(w0 * tau)
        x = zt + osc.v_drive * (t + tau) - sigma * osc.F_kin / osc.k
        t = t + tau
        v = 0.0
        p_end = osc.k * (osc.v_drive * t - x)
        kind = "rest" if abs(p_end) <= osc.F_stat else "slide"
    return phases


def exact_solution(osc: Oscillator, t_end: float, n: int = 2001, t_eval=None) -> OscResult:
    """
    Return the Fig. 4 body's exact piecewise trajectory.

    Parameters
    ----------
    osc : Oscillator
        The body.
    t_end : float
        The end [s].
    n : int
        Uniform samples over [0, t_end], where ``t_eval`` is not given.
    t_eval : array_like, optional
        The times to sample at.

    Returns
    -------
    OscResult
        The closed-form trajectory between its phase changes, sampled.

    """
    phases = exact_phases(osc, t_end)
    ts = np.linspace(0.0, t_end, n) if t_eval is None else np.asarray(t_eval, float)
    w0 = osc.omega0
    x = np.empty_like(ts)
    v = np.empty_like(ts)
    row = np.empty(ts.shape, dtype=int)
    starts = np.array([p[0] for p in phases])
    for i, t in enumerate(ts):
        j = max(0, int(np.searchsorted(starts, t, side="right")) - 1)
        t0, kind, x0, v0, sigma = phases[j]
        if kind == "rest":
            x[i] = x0
            v[i] = 0.0
            row[i] = ROW_HOLD
        else:
            tau = t - t0
            z0 = x0 - (osc.v_drive * t0 - sigma * osc.F_kin / osc.k)
            zd0 = v0 - osc.v_drive
            z = z0 * math.cos(w0 * tau) + zd0 / w0 * math.sin(w0 * tau)
            zd = -z0 * w0 * math.sin(w0 * tau) + zd0 * math.cos(w0 * tau)
            x[i] = z + osc.v_drive * t - sigma * osc.F_kin / osc.k
            v[i] = zd + osc.v_drive
            row[i] = ROW_KINETIC
    xs = osc.v_drive * ts
    P = osc.k * (xs - x)
    F = np.where(row == ROW_KINETIC, osc.F_kin * np.sign(v), P)
    events = []
    for t0, kind, *_ in phases[1:]:
        events.append((t0, "slip" if kind == "slide" else "stick"))
    return OscResult(ts, x, v, xs, P, F, row, events, "exact")


# ------------------------------------------------------------------ numerical methods
@kernel
def _accel(x, v, t, p, sigma):
    """Sliding acceleration with friction sign σ (the sign of v while sliding)."""
    m, f_kin, k, vd = p[0], p[1], p[3], p[4]
    return (k * (vd * t - x) - sigma * f_kin) / m


@borrowing
def _osc_rhs(y, c, h, ctx, out):
    """Evaluate the sliding body's (x, v)' at a stage; ctx: the step's start t, p, σ."""
    t, p, sigma = ctx
    out[0] = y[1]
    out[1] = _accel(y[0], y[1], t + c * h, p, sigma)
    return True


# one Dormand-Prince step of the sliding body (x, v)
_osc_step = make_step(_osc_rhs)


@kernel
def _run_accurate(p, t_end, rtol, atol, h_max, oscrecord, oscevents, counters):  # noqa: PLR0915 — one stick-slip cycle read as one loop
    ev_t, ev_k = oscevents.ev_t, oscevents.ev_k
    ts, xs, vs, rows = oscrecord.ts, oscrecord.xs, oscrecord.vs, oscrecord.rows
    f_stat, k, vd = p[2], p[3], p[4]
    t = 0.0
    x = 0.0
    v = 0.0
    n = 0
    ne = 0
    steps = 0
    nrhs = 0
    resting = True
    cap = ts.shape[0]
    ts[0] = t
    xs[0] = x
    vs[0] = v
    rows[0] = 2
    n = 1
    h = 1e-2
    y = np.empty(2)
    y_new = np.empty(2)
    y_err = np.empty(2)
    K = np.empty((7, 2))
    atol_scale, rtol_ref = np.ones(2), -np.ones(2)
    while t < t_end and n < cap:
        if resting:
            # P = k (vd t - x) reaches ±F_stat at a time known in closed form
            t_b = (f_stat / k + x) / vd
            if t_b >= t_end:
                t = t_end
                ts[n] = t
                xs[n] = x
                vs[n] = 0.0
                rows[n] = 2
                n += 1
                break
            t = max(t, t_b)
            ts[n] = t
            xs[n] = x
            vs[n] = 0.0
            rows[n] = 2
            n += 1
            ev_t[ne] = t
            ev_k[ne] = 1
            ne += 1
            resting = False
            sigma = 1.0
            continue
        # sliding: Dormand-Prince on (x, v); ends when v returns to 0
        sigma = 1.0 if v > 0 or (v == 0 and k * (vd * t - x) > 0) else -1.0
        h = min(h, t_end - t, h_max)
        y[0] = x
        y[1] = v
        stage = (t, p, sigma)
        _osc_rhs(y, 0.0, h, stage, K[0])
        _osc_step(y, h, K, stage, y_new, y_err)
        nrhs += 7
        x_new = y_new[0]
        v_new = y_new[1]
        err = error_norm(y_err, y, y_new, rtol, atol, atol_scale, rtol_ref)
        if not err <= 1.0:
            h *= step_factor(err)
            continue
        if v_new * sigma <= 0.0 and abs(v) > 0.0:
            # the slide ends inside this step: shrink to the zero of v (secant on the
            # step's end values, then retried), so no stage crosses the discontinuity
            frac = v / (v - v_new)
            if frac < 1.0 - 1e-12 and h * frac > 1e-14:
                h = h * min(max(frac, 1e-3), 0.999999) if abs(v_new) > atol else h * frac
                if abs(v_new) > atol:
                    continue
            t += h
            x = x_new
            ts[n] = t
            xs[n] = x
            vs[n] = 0.0
            rows[n] = 2
            n += 1
            v = 0.0
            steps += 1
            p_now = k * (vd * t - x)
            if abs(p_now) <= f_stat:
                resting = True
                ev_t[ne] = t
                ev_k[ne] = 2
                ne += 1
            h = 1e-2
            continue
        t += h
        x = x_new
        v = v_new
        steps += 1
        ts[n] = t
        xs[n] = x
        vs[n] = v
        rows[n] = 1
        n += 1
        h *= step_factor(err)
    counters[0] = n
    counters[1] = ne
    counters[2] = steps
    counters[3] = nrhs


@kernel
def _run_implicit(p, t_end, dt, oscrecord, oscevents, counters):
    """Backward Euler in velocity with set-valued friction (Kikuuwe et al. 2005)."""
    ev_t, ev_k = oscevents.ev_t, oscevents.ev_k
    ts, xs, vs, rows = oscrecord.ts, oscrecord.xs, oscrecord.vs, oscrecord.rows
    m, f_kin, f_stat, k, vd = p[0], p[1], p[2], p[3], p[4]
    t = 0.0
    x = 0.0
    v = 0.0
    n_steps = int(math.ceil(t_end / dt - 1e-9))
    cap = ts.shape[0]
    ts[0] = 0.0
    xs[0] = 0.0
    vs[0] = 0.0
    rows[0] = 2
    n = 1
    ne = 0
    prev = 2
    for i in range(n_steps):
        h = min(dt, t_end - t)
        # spring force at the step end with x+ = x + h v+: implicit in position too
        t1 = t + h
        p_free = k * (vd * t1 - x)
        # m (v+ - v)/h = p_free - k h v+ - f,  f in F_s [-1, 1] or F_kin sgn(v+)
        denom = m / h + k * h
        v_star = (m / h * v + p_free) / denom
        limit = (f_stat if v == 0.0 else f_kin) / denom
        if abs(v_star) <= limit:
            v_new = 0.0
            row = 2
        else:
            v_new = v_star - math.copysign(f_kin / denom, v_star)
            row = 1
        v = v_new
        x = x + h * v
        t = t1
        if row != prev:
            if ne < ev_t.shape[0]:
                ev_t[ne] = t
                ev_k[ne] = 1 if row == 1 else 2
            ne += 1
            prev = row
        if n < cap:
            ts[n] = t
            xs[n] = x
            vs[n] = v
            rows[n] = row
            n += 1
    counters[0] = n
    counters[1] = min(ne, ev_t.shape[0])
    counters[2] = n_steps
    counters[3] = n_steps


@kernel
def _threshold_force(x, v, t, p, v_min):
    """Friction by eq. (3.1) and the active row."""
    f_kin, f_stat, k, vd = p[1], p[2], p[3], p[4]
    pe = k * (vd * t - x)
    if abs(v) > v_min:
        return f_kin * (1.0 if v > 0 else -1.0), 1
    if f_stat > abs(pe):
        return pe, 2
    return f_stat * (1.0 if pe > 0 else -1.0), 3


@kernel
def _run_threshold(p, t_end, dt, v_min, oscrecord, oscevents, counters):
    ev_t, ev_k = oscevents.ev_t, oscevents.ev_k
    ts, xs, vs, rows = oscrecord.ts, oscrecord.xs, oscrecord.vs, oscrecord.rows
    m, k, vd = p[0], p[3], p[4]
    t = 0.0
    x = 0.0
    v = 0.0
    n_steps = int(math.ceil(t_end / dt - 1e-9))
    cap = ts.shape[0]
    ts[0] = 0.0
    xs[0] = 0.0
    vs[0] = 0.0
    _, r0 = _threshold_force(0.0, 0.0, 0.0, p, v_min)
    rows[0] = r0
    n = 1
    ne = 0
    prev = r0
    for i in range(n_steps):
        h = min(dt, t_end - t)
        f1, row = _threshold_force(x, v, t, p, v_min)
        a1 = (k * (vd * t - x) - f1) / m
        x2 = x + 0.5 * h * v
        v2 = v + 0.5 * h * a1
        f2, _ = _threshold_force(x2, v2, t + 0.5 * h, p, v_min)
        a2 = (k * (vd * (t + 0.5 * h) - x2) - f2) / m
        x3 = x + 0.5 * h * v2
        v3 = v + 0.5 * h * a2
        f3, _ = _threshold_force(x3, v3, t + 0.5 * h, p, v_min)
        a3 = (k * (vd * (t + 0.5 * h) - x3) - f3) / m
        x4 = x + h * v3
        v4 = v + h * a3
        f4, _ = _threshold_force(x4, v4, t + h, p, v_min)
        a4 = (k * (vd * (t + h) - x4) - f4) / m
        x = x + h / 6.0 * (v + 2 * v2 + 2 * v3 + v4)
        v = v + h / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)
        t += h
        if row != prev:
            if ne < ev_t.shape[0]:
                ev_t[ne] = t - h
                ev_k[ne] = row
            ne += 1
            prev = row
        if n < cap:
            ts[n] = t
            xs[n] = x
            vs[n] = v
            rows[n] = row
            n += 1
    counters[0] = n
    counters[1] = min(ne, ev_t.shape[0])
    counters[2] = n_steps
    counters[3] = 4 * n_steps


def run_oscillator(
    osc: Oscillator,
    t_end: float,
    method: str = "accurate",
    *,
    dt: float = 1e-3,
    v_min: float = 1e-3,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    h_max: float = math.inf,
    max_points: int | None = None,
) -> OscResult:
    """
    Integrate the Fig. 4 body with one of the three methods (see the module docstring).

    Parameters
    ----------
    osc : Oscillator
        The body, its spring and the friction it slides with.
    t_end : float
        The end of the run [s].
    method : {'accurate', 'implicit', 'threshold'}
        The method, as ``simulate``'s.
    dt : float
        The fixed-step methods' step [s].
    v_min : float
        The threshold method's threshold speed [m/s].
    rtol, atol : float
        The accurate method's tolerances.
    h_max : float
        The accurate method's longest step [s] (a denser output; rests are still one
        record).
    max_points : int, optional
        Room for records: the fixed-step methods' step count by default, 2 000 000 for
        the accurate method.

    Returns
    -------
    OscResult
        The trajectory and the events: 'slip' (leaves rest) and 'stick' (comes to
        rest); for the threshold method every change of the active row of eq. (3.1), as
        'row<N>'. Records beyond ``max_points`` are dropped (the run itself completes),
        and ``extra['truncated']`` says so.

    """
    if method not in ("accurate", "implicit", "threshold"):
        raise ValueError(f"method must be one of accurate, implicit, threshold, got {method!r}")
    check_kernel_cache()
    if not (math.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end must be a finite time > 0 s, got {t_end}")
    if not (h_max > 0):
        raise ValueError(f"h_max must be > 0 s, got {h_max}")
    for name, val, lo, hi in (
        ("dt", dt, 0.0, 10.0),
        ("v_min", v_min, 0.0, 10.0),
        ("rtol", rtol, 0.0, 0.1),
        ("atol", atol, 0.0, 1.0),
    ):
        if not (math.isfinite(val) and lo < val <= hi):
            raise ValueError(f"{name} must be in ({lo}, {hi}], got {val}")
    p = osc.params()
    if max_points is None:
        max_points = 2_000_000 if method == "accurate" else int(math.ceil(t_end / dt)) + 10
    cap = int(min(max_points, (t_end / dt + 10) if method != "accurate" else max_points))
    ts = np.empty(cap)
    xs = np.empty(cap)
    vs = np.empty(cap)
    rows = np.empty(cap, dtype=np.int64)
    ev_t = np.empty(100000)
    ev_k = np.empty(100000, dtype=np.int64)
    counters = np.zeros(4, dtype=np.int64)
    wall = time.perf_counter()
    if method == "accurate":
        _run_accurate(
            p,
            t_end,
            rtol,
            atol,
            float(h_max),
            OscRecord(ts, xs, vs, rows),
            OscEvents(ev_t, ev_k),
            counters,
        )
    elif method == "implicit":
        _run_implicit(p, t_end, dt, OscRecord(ts, xs, vs, rows), OscEvents(ev_t, ev_k), counters)
    else:
        _run_threshold(
            p, t_end, dt, v_min, OscRecord(ts, xs, vs, rows), OscEvents(ev_t, ev_k), counters
        )
    wall = time.perf_counter() - wall
    n, ne = int(counters[0]), int(counters[1])
    t, x, v, row = ts[:n].copy(), xs[:n].copy(), vs[:n].copy(), rows[:n].copy()
    x_spring = osc.v_drive * t
    P = osc.k * (x_spring - x)
    if method == "threshold":
        F = np.array([_threshold_force(xi, vi, ti, p, v_min)[0] for xi, vi, ti in zip(x, v, t)])
        names = {1: "row1", 2: "row2", 3: "row3"}
        events = [(float(ev_t[i]), names[int(ev_k[i])]) for i in range(ne)]
    else:
        F = np.where(row == ROW_KINETIC, osc.F_kin * np.sign(v), P)
        events = [(float(ev_t[i]), "slip" if ev_k[i] == 1 else "stick") for i in range(ne)]
    return OscResult(
        t,
        x,
        v,
        x_spring,
        P,
        F,
        row,
        events,
        method,
        n_steps=int(counters[2]),
        n_rhs=int(counters[3]),
        wall_s=wall,
        extra={"truncated": bool(t[-1] < t_end - 1e-9 * max(1.0, t_end))},
    )


def static_stage_durations(res: OscResult, n_cycles: int = 3) -> list[float]:
    """
    Durations of the F(3) stage (row 3 of eq. 3.1) of the first stick-slip cycles (Fig. 5).

    Parameters
    ----------
    res : SimResult or OscResult
        A run's result.
    n_cycles : int
        How many cycles.

    Returns
    -------
    ndarray
        The durations [s].

    """
    out = []
    inside = False
    start = 0.0
    for i in range(len(res.t)):
        r = res.row[i]
        if r == ROW_BREAK and not inside:
            inside = True
            start = res.t[i - 1] if i > 0 else res.t[i]
        elif r != ROW_BREAK and inside:
            inside = False
            out.append(float(res.t[i - 1] - start))
            if len(out) >= n_cycles:
                break
    return out
