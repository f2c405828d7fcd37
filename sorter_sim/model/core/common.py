"""
What every method of the core shares: its codes, the sliding right-hand side, records and events.

Each method (``accurate``, ``implicit``, ``threshold``) advances one parcel from
``t0`` towards ``t_end`` over a fixed set of strips and writes a trajectory (t, state,
mode) into caller-owned arrays, stopping early at the scrap line y = ``y_target``
(``inf`` for none). They return a status (``ST_*``) and counters, and log events
(``EV_*``); ``simulate.py`` wraps them in a result object. Here: those codes, the
equation of motion while sliding (eq. 4.1 with kinetic friction), the trajectory and
event records, and the contact bookkeeping (which surfaces lie under the footprint,
when a corner next crosses a strip border).

Units: SI throughout (m, s, rad, kg, N).
"""

from __future__ import annotations

import math

from sorter_sim.model.core.dopri import make_step
from sorter_sim.model.core.geometry import corner_x
from sorter_sim.model.core.jit import borrowing, kernel
from sorter_sim.model.core.layout import (
    P_HALF_A,
    P_HALF_B,
    P_INERTIA,
    P_MASS,
    P_ROTATION,
    S_SURF,
    S_VX,
    S_VY,
    S_WEIGHT,
)
from sorter_sim.model.core.wrench import kinetic_wrench, place_box, strip_part

METHOD_ACCURATE = 0
METHOD_IMPLICIT = 1
METHOD_THRESHOLD = 2

# status codes
ST_END = 0  # reached t_end
ST_TARGET = 1  # reached the scrap line
ST_MAX_STEPS = 2  # ran out of output capacity / step budget
ST_STEP_FAIL = 3  # step size underflow
ST_NONFINITE = 4  # a NaN or inf appeared

# a run's counters (its int64 ``counters`` array, written at its end), by name
N_STEPS = 0  # accepted steps
N_RHS = 1  # right-hand-side (wrench) evaluations
N_REJECTED = 2  # rejected steps
N_OUT = 3  # trajectory records written
N_EVENTS = 4  # events logged
N_JUMPS = 5  # sticks advanced in closed form to the next border
N_STICK_SCANS = 6  # stick checks of the limit set
N_COUNTERS = 8

# event kinds in the event log
EV_STICK = 1
EV_BREAK = 2
EV_BORDER = 3
EV_TARGET = 4
EV_LEAVE = 5


@borrowing
def n_surf_of(strips):
    """
    Return the number of surfaces the strips reference.

    Parameters
    ----------
    strips : ndarray, shape (n, STRIP_WIDTH)
        The strips (``layout``).

    Returns
    -------
    int
        The number of surfaces the strips reference.

    """
    n = 0
    for k in range(strips.shape[0]):
        n = max(n, int(strips[k, S_SURF]) + 1)
    return n


@borrowing
def surface_velocity(strips, surf):
    """
    Return a surface's velocity.

    Parameters
    ----------
    strips : ndarray, shape (n, STRIP_WIDTH)
        The strips (``layout``).
    surf : int
        A surface id.

    Returns
    -------
    (float, float)
        The surface's velocity [m/s].

    """
    for k in range(strips.shape[0]):
        if int(strips[k, S_SURF]) == surf:
            return strips[k, S_VX], strips[k, S_VY]
    return 0.0, 0.0


@borrowing
def rhs_slide(state, contact, clip, out):
    """
    Time derivative of the state while sliding (eq. 4.1 with kinetic friction).

    ``clip``: a footprint scratch (``wrench.clip_scratch``), so that it allocates nothing.

    Parameters
    ----------
    state : ndarray, shape (6,)
        The state: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.
    contact : Contact
        What the parcel slides on (``layout.Contact``).
    clip : ndarray
        A footprint scratch (``wrench.clip_scratch``).
    out : ndarray, shape (6,)
        Receives the state's time derivative.

    """
    parcel = contact.parcel
    fx, fy, t = kinetic_wrench(state, contact, -1, clip)
    out[0] = state[3]
    out[1] = state[4]
    out[2] = state[5]
    out[3] = fx / parcel[P_MASS]
    out[4] = fy / parcel[P_MASS]
    out[5] = t / parcel[P_INERTIA] if parcel[P_ROTATION] > 0.5 else 0.0


# a falling slip s is carried on in ln s (``_approach``) once it would reach zero within
# APPROACH_STEPS steps h at its rate, or once F h / (m s) >= STIFF_RATIO rtol^(1/5) (F the
# patch's friction, which does at least half the slowing): on the way to zero its
# direction turns at F/(m s), and explicit steps in t shrink with s, accuracy-bound at
# such a ratio (measured on Fig. 9a's approach to its stick and on a spinning slide to
# rest: 0.2-0.4 at rtol 1e-6, 0.05-0.15 at rtol 1e-10)
APPROACH_STEPS = 5.0
STIFF_RATIO = 2.0  # x rtol^(1/5): where a 5th-order step's error in the turning reaches rtol


@borrowing
def _slide_rhs(y, c, h, ctx, out):
    """Evaluate ``rhs_slide`` as a step's right-hand side; ctx: (contact, clip)."""
    contact, clip = ctx
    rhs_slide(y, contact, clip, out)
    return True


# one Dormand-Prince step of the sliding model: K[0] holds f(y); fills K[1..6], y_new, err
slide_step = make_step(_slide_rhs)


@borrowing
def _gen_slip(state, vsx, vsy, rho, rot, out):
    out[0] = state[3] - vsx
    out[1] = state[4] - vsy
    out[2] = rho * state[5] if rot else 0.0
    return math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2)


@borrowing
def _record_new(trail, n_out, t, y, mode):
    """``_record``, unless the last record is this one (a slip carried in ln s records it)."""
    ts, ys, ms = trail.ts, trail.ys, trail.ms
    last = min(n_out, ts.shape[0]) - 1
    same = n_out > 0 and ts[last] == t and ms[last] == mode
    for j in range(6):
        same = same and ys[last, j] == y[j]
    return n_out if same else _record(trail, n_out, t, y, mode)


@borrowing
def _corner_event_values(state, parcel, borders, out):
    """Corner x minus border x for every (corner, border) pair."""
    nb = borders.shape[0]
    for i in range(4):
        cx = corner_x(state[0], state[2], parcel[P_HALF_A], parcel[P_HALF_B], i)
        for b in range(nb):
            out[i * nb + b] = cx - borders[b]


@borrowing
def _log_event(ev, n_ev, t, kind, info):
    if n_ev < ev.shape[0]:
        ev[n_ev, 0] = t
        ev[n_ev, 1] = kind
        ev[n_ev, 2] = info
    return n_ev + 1


@borrowing
def _record(trail, n_out, t, y, mode):
    """
    Record (t, y, mode) as record ``n_out``; returns the count.

    Past the arrays' capacity the last slot takes every further record, so it
    always holds the latest state: a run that outgrows its output (the accurate
    method may take many times more steps) still ends on its true final state.
    """
    ts, ys, ms = trail.ts, trail.ys, trail.ms
    i = min(n_out, ts.shape[0] - 1)
    ts[i] = t
    for j in range(6):
        ys[i, j] = y[j]
    ms[i] = mode
    return n_out + 1


@borrowing
def _contact_surfaces(state, strips, parcel, clip, out_area):
    """Weighted contact area per surface (cheap: clipping only); ``clip`` a footprint scratch."""
    xmin, xmax = place_box(state, parcel, clip)
    out_area[:] = 0.0
    for k in range(strips.shape[0]):
        _, a, _, _ = strip_part(clip, strips, k, xmin, xmax)
        out_area[int(strips[k, S_SURF])] += strips[k, S_WEIGHT] * a


@borrowing
def _alone_on(state, strips, parcel, clip, surf, area):
    """Return True where ``surf`` alone is under the parcel (scratch: ``clip``, ``area``)."""
    _contact_surfaces(state, strips, parcel, clip, area)
    if area[surf] <= 0.0:
        return False
    for s in range(area.shape[0]):
        if s != surf and area[s] > 0.0:
            return False
    return True


@borrowing
def _time_to_next_border(state, vx, parcel, borders):
    """Time until a corner of a parcel translating at vx reaches the next strip border."""
    if vx == 0.0 or borders.shape[0] == 0:
        return math.inf
    best = math.inf
    for i in range(4):
        cx = corner_x(state[0], state[2], parcel[P_HALF_A], parcel[P_HALF_B], i)
        for b in range(borders.shape[0]):
            dt = (borders[b] - cx) / vx
            if dt >= 0.0 and dt < best:
                best = dt
    return best


@kernel
def _take_fixed_step(y, y_new, t, t_next, y_target):
    """
    Take a fixed step, stopping at the scrap line.

    Move y to the step's end, or to where the scrap line is crossed inside it
    (linear in the step); returns (t, crossed).
    """
    if y_target < math.inf and y[1] < y_target <= y_new[1]:
        th = (y_target - y[1]) / (y_new[1] - y[1])
        for j in range(6):
            y[j] = y[j] + th * (y_new[j] - y[j])
        return t + th * (t_next - t), True
    for j in range(6):
        y[j] = y_new[j]
    return t_next, False
