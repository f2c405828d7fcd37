"""
Many parcels on one cell, advanced a control period at a time: the numba kernels.

The cell is the seed's three-zone conveyor (Fig. 6) seen as hardware: a belt
moving at v, a disk field 0 <= x <= b whose surface moves at v(cos α, sin α) and
carries the share ``stroke`` of a parcel's load there, side walls at y = ±w/2
with a chute opening on each side over the disk field, photo-eyes across the
belt and a chute-entry sensor per side. ``advance_cell`` moves every parcel over
``n`` control periods and writes what a PLC could observe, and what left the
cell, into an event buffer; ``sorter_sim/runtime/cell.py`` drives it.

Per parcel and period:

* A parcel stuck to the belt and clear of the popped-up disks for the whole
  period is advanced in closed form, x += v dt: nothing can break that stick.
  This is most parcels most of the time, and it costs nothing. Likewise a
  parcel stuck to fully raised disks and wholly over them moves with them.
* Any other parcel (touching raised disks, sliding, stuck to the disks) is
  integrated by the model core over the period with the strips of that period
  (α and stroke at the period's midpoint, the actuators moving at their rate).
  The default, ``accurate``, restarts the event-located Dormand-Prince method of
  ``accurate.run_accurate`` every period: measured on the seed's Fig. 9a
  parcel through a 1.0 m disk field (0.5 s of diversion, 1 ms periods) it costs
  about 9 us per parcel-period at rtol 1e-6 and ends 4e-11 m from a 1e-12
  reference, where one backward-Euler step per period (``implicit``, exact
  stick too) costs about 4.5 us and errs by 6e-5 m (first order in the period).
  So the accurate method, exact at about twice that, stays the default.
* A surface that changed velocity since the last period (α slewing, the belt
  stopped by an e-stop or restarted) cannot hold a parcel stuck to its old
  velocity: the parcel is handed to the integrator as sliding and re-sticks
  where the physics says.

Sensor edges are located inside the period, not sampled: exactly (linear
motion) for parcels moving rigidly, else by bisection on the cubic Hermite
interpolant of the parcel's motion with the velocities at both ends. Parcel
overlaps (separating-axis test) and crossings of a side wall outside a chute
opening jam the parcels involved: they stop, never pass through each other.

Units: SI (m, s, rad, kg); sensor edge offsets tau in s from the period start.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

from sorter_sim.model.core.accurate import run_accurate
from sorter_sim.model.core.common import (
    N_COUNTERS,
    N_OUT,
    N_RHS,
    N_STEPS,
    ST_END,
    ST_TARGET,
    n_surf_of,
)
from sorter_sim.model.core.geometry import box_corners
from sorter_sim.model.core.implicit import run_implicit
from sorter_sim.model.core.layout import (
    P_HALF_A,
    P_HALF_B,
    S_LAW,
    S_PARAMS,
    S_SURF,
    S_VX,
    S_VY,
    S_WEIGHT,
    S_XHI,
    S_XLO,
    STRIP_WIDTH,
    Contact,
    Log,
    Slide,
    Trail,
)

# a period's motion of a parcel: its state at the start and the end, and the period
Motion = namedtuple('Motion', ['s0', 's1', 'h'])
# the conditions a sensor's blocked set is made of (scratch): feature kinds, levels, signs
Conditions = namedtuple('Conditions', ['kinds', 'levels', 'signs'])

# ---- configuration row (float64) ---------------------------------------------------
C_V = 0  # belt speed v [m/s] while the belt runs
C_HALF_W = 1  # w/2 [m]
C_B = 2  # disk field length b [m]
C_OPEN_LO = 3  # chute openings: x range [m]
C_OPEN_HI = 4
C_EXIT_X = 5  # straight exit: CoG beyond this x [m]
C_SCAN_X = 6  # scanner line x [m]
C_DT = 7  # control period [s]
C_ALPHA_RATE = 8  # disk-angle slew rate [rad/s]
C_STROKE_RATE = 9  # pop-up stroke rate [1/s] (inf: instantaneous)
C_RTOL = 10
C_ATOL = 11
C_METHOD = 12  # 0 accurate, 1 implicit
C_LAW_A = 13  # law ids of the belt and the disks
C_LAW_B = 14
CFG_WIDTH = 15

# ---- actuator state (float64) ------------------------------------------------------
A_ALPHA = 0  # physical disk angle [rad]
A_ALPHA_CMD = 1  # commanded disk angle [rad]
A_STROKE = 2  # pop-up position 0 (down) .. 1 (up)
A_STROKE_TARGET = 3
A_BELT_ON = 4  # 1 running, 0 stopped (e-stop)
A_ALPHA_DOT = 5  # rates over the last period [rad/s], [1/s]
A_STROKE_DOT = 6
ACT_WIDTH = 7

# ---- parcel phases -----------------------------------------------------------------
PH_FREE = 0  # empty slot
PH_CELL = 1  # on the belt / disks
PH_CHUTE_LEFT = 2  # centre of gravity past y = +w/2: sliding off onto the left chute
PH_CHUTE_RIGHT = 3
PH_JAMMED = 4  # stopped by a jam until reset

# parcel modes (surface ids of the cell's strips: the belt is always surface 0)
MODE_SLIDE = -1
MODE_BELT = 0
MODE_DISKS = 1

# what a parcel is doing, for markers: codes into cell.STATE_NAMES
S_ON_BELT = 0
S_ON_DISKS = 1
S_SLIDING = 2
S_DIVERTED = 3
S_STRAIGHT = 4
S_JAMMED = 5

# ---- events: ev_i rows [period index, kind, a, b], ev_f rows [tau, x, y] ------------
EV_EDGE = 1  # a sensor changed: a = sensor index, b = 1 rising (blocked) / 0 falling
EV_SCAN = 2  # leading edge crossed the scanner line: a = slot
EV_LEFT = 3  # CoG crossed y = +w/2 in the opening: a = slot, (x, y) there
EV_RIGHT = 4  # CoG crossed y = -w/2 in the opening
EV_STRAIGHT = 5  # CoG passed exit_x: a = slot (now free), (x, y) there
EV_JAM = 6  # a = slot jammed; b = other slot, -1 side wall, -2 integration failed
EV_GONE = 7  # a parcel on a chute cleared the entry line: a = slot (now free)

# geometric features a sensor condition looks at
F_XMAX = 0
F_XMIN = 1
F_YMAX = 2
F_YMIN = 3
F_XCOG = 4
F_YCOG = 5

# overlaps and wall crossings below this are contact, not a jam [m]
CONTACT_TOL = 1e-9
MAX_STRIPS = 4  # strips of a period at most (``cell_strips``)
_INT_BUF = 512  # integrator output rows per parcel-period (a few are used)


# what ``advance_cell`` takes, by name
CellSetup = namedtuple('CellSetup', ['cfg', 'laws', 'nodes', 'weights'])
Parcels = namedtuple('Parcels', ['state', 'mode', 'phase', 'par', 'scanned', 'gauge_xi'])
Sensors = namedtuple('Sensors', ['eye_x', 'blocked', 'counts'])
EventLog = namedtuple('EventLog', ['ev_i', 'ev_f', 'reserve'])
Memo = namedtuple('Memo', ['stats', 'last_strips', 'last_info'])


@njit(cache=True)
def _isclose(a, b):
    # math.isclose(a, b, abs_tol=1e-15), as simulate.strip_array merges surfaces
    return abs(a - b) <= max(1e-9 * max(abs(a), abs(b)), 1e-15)


@njit(cache=True)
def _set_strip(out, k, x_lo, x_hi, vx, vy, weight, surf, law_id, law):
    out[k, S_XLO] = x_lo
    out[k, S_XHI] = x_hi
    out[k, S_VX] = vx
    out[k, S_VY] = vy
    out[k, S_WEIGHT] = weight
    out[k, S_SURF] = surf
    out[k, S_LAW] = law_id
    for j in range(law.shape[0]):
        out[k, S_PARAMS + j] = law[j]


@njit(cache=True)
def cell_strips(v, alpha, b, stroke, law_a_id, law_a, law_b_id, law_b, out):
    """
    Return the cell's strips for one period, as ``strip_array(three_zone_strips(...))``.

    Zone a (x < 0, belt), zone b (0..b: disks at v(cos α, sin α) carrying ``stroke`` of
    the load, the belt between them the rest), zone c (x > b, belt). Returns (number of
    strips, surface id of the disks: 1, 0 when they move with the belt, -1 when down).

    Parameters
    ----------
    v : float
        The belt speed [m/s].
    alpha : float
        The disk angle [rad].
    b : float
        The disk field's length [m].
    stroke : float
        The pop-up position, 0 down .. 1 up.
    law_a_id : int
        The belt's law id.
    law_a : ndarray
        Its parameters.
    law_b_id : int
        The disks' law id.
    law_b : ndarray
        Their parameters.
    out : ndarray
        Receives the result.

    Returns
    -------
    list of Strip or ndarray
        The zones a, b, c.

    """
    _set_strip(out, 0, -math.inf, 0.0, v, 0.0, 1.0, 0, law_a_id, law_a)
    n = 1
    disk_sid = -1
    if stroke > 0.0:
        dvx = v * math.cos(alpha)
        dvy = v * math.sin(alpha)
        if _isclose(dvx, v) and _isclose(dvy, 0.0):
            disk_sid = 0
            dvx = v
            dvy = 0.0
        else:
            disk_sid = 1
        _set_strip(out, n, 0.0, b, dvx, dvy, stroke, disk_sid, law_b_id, law_b)
        n += 1
    if stroke < 1.0:
        _set_strip(out, n, 0.0, b, v, 0.0, 1.0 - stroke, 0, law_a_id, law_a)
        n += 1
    _set_strip(out, n, b, math.inf, v, 0.0, 1.0, 0, law_a_id, law_a)
    return n + 1, disk_sid


@njit(cache=True)
def toward(value, target, max_step):
    """
    Move ``value`` toward ``target`` by at most ``max_step`` (a slew-rate limit).

    Parameters
    ----------
    value : float
        The value.
    target : float
        Where it moves to.
    max_step : float
        The most it may move.

    Returns
    -------
    float
        The value moved.

    """
    if target > value:
        return min(target, value + max_step)
    return max(target, value - max_step)


@njit(cache=True)
def half_extents(phi, half_a, half_b):
    """
    Half extents along x and y of the footprint turned by φ [m].

    Parameters
    ----------
    phi : float
        The turn [rad].
    half_a : float
        Half the parcel's length A [m].
    half_b : float
        Half the parcel's width B [m].

    Returns
    -------
    (float, float)
        The half extents along x and y [m].

    """
    c = abs(math.cos(phi))
    s = abs(math.sin(phi))
    return half_a * c + half_b * s, half_a * s + half_b * c


@njit(cache=True)
def _hermite(p0, v0, p1, v1, h, tau):
    s = tau / h
    s2 = s * s
    s3 = s2 * s
    return (
        (2.0 * s3 - 3.0 * s2 + 1.0) * p0
        + (s3 - 2.0 * s2 + s) * h * v0
        + (-2.0 * s3 + 3.0 * s2) * p1
        + (s3 - s2) * h * v1
    )


@njit(cache=True)
def _feature(kind, x, y, phi, half_a, half_b):
    hx, hy = half_extents(phi, half_a, half_b)
    if kind == F_XMAX:
        return x + hx
    if kind == F_XMIN:
        return x - hx
    if kind == F_YMAX:
        return y + hy
    if kind == F_YMIN:
        return y - hy
    if kind == F_XCOG:
        return x
    return y


@njit(cache=True)
def _feature_at(kind, motion, tau, half_a, half_b):
    s0, s1, h = motion.s0, motion.s1, motion.h
    x = _hermite(s0[0], s0[3], s1[0], s1[3], h, tau)
    y = _hermite(s0[1], s0[4], s1[1], s1[4], h, tau)
    phi = _hermite(s0[2], s0[5], s1[2], s1[5], h, tau)
    return _feature(kind, x, y, phi, half_a, half_b)


@njit(cache=True)
def crossing_time(kind, level, motion, half_a, half_b):
    """
    When in [0, h] the feature crosses ``level`` (it must be on opposite sides at the ends).

    Motion at constant velocity without rotation (a parcel on the belt, or on a chute) makes
    every feature linear in time, solved exactly; otherwise bisection on the cubic Hermite
    interpolant of (x, y, φ) with the velocities at both ends.

    Parameters
    ----------
    kind : int
        The feature (``_feature``'s kinds).
    level : float
        The level it must cross.
    motion : Motion
        The period's motion: the state at its start and end, and the period.
    half_a : float
        Half the parcel's length A [m].
    half_b : float
        Half the parcel's width B [m].

    Returns
    -------
    float
        The time in [0, h] [s].

    """
    s0, s1, h = motion.s0, motion.s1, motion.h
    f0 = _feature(kind, s0[0], s0[1], s0[2], half_a, half_b) - level
    f1 = _feature(kind, s1[0], s1[1], s1[2], half_a, half_b) - level
    if f0 == f1:
        return h
    if s0[3] == s1[3] and s0[4] == s1[4] and s0[5] == 0.0 and s1[5] == 0.0:
        return min(h, max(0.0, h * (-f0) / (f1 - f0)))
    lo = 0.0
    hi = h
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        fm = _feature_at(kind, motion, mid, half_a, half_b) - level
        if (fm > 0.0) == (f1 > 0.0):
            hi = mid
        else:
            lo = mid
        if hi - lo <= 1e-15 * h:
            break
    return hi


@njit(cache=True)
def _condition(conditions, c, kind, level, sign):
    kinds, levels, signs = conditions.kinds, conditions.levels, conditions.signs
    kinds[c] = kind
    levels[c] = level
    signs[c] = sign


@njit(cache=True)
def _conditions(sensor, n_eyes, eye_x, cfg, conditions):
    """Return the conditions that block a sensor: every sign*(feature - level) > 0."""
    if sensor < n_eyes:
        # the footprint spans the beam's x
        _condition(conditions, 0, F_XMAX, eye_x[sensor], 1.0)
        _condition(conditions, 1, F_XMIN, eye_x[sensor], -1.0)
        return 2
    # the footprint spans the entry line y = ±w/2, inside the opening's x range
    line = cfg[C_HALF_W] if sensor == n_eyes else -cfg[C_HALF_W]
    _condition(conditions, 0, F_YMAX, line, 1.0)
    _condition(conditions, 1, F_YMIN, line, -1.0)
    _condition(conditions, 2, F_XMAX, cfg[C_OPEN_LO], 1.0)
    _condition(conditions, 3, F_XMIN, cfg[C_OPEN_HI], -1.0)
    return 4


@njit(cache=True)
def _phase_counts(sensor, n_eyes, phase):
    if phase == PH_CELL or phase == PH_JAMMED:
        return True
    if phase == PH_CHUTE_LEFT:
        return sensor == n_eyes
    if phase == PH_CHUTE_RIGHT:
        return sensor == n_eyes + 1
    return False


@njit(cache=True)
def sensor_blocked(sensor, n_eyes, eye_x, cfg, s, phase, half_a, half_b):
    """
    Return whether a parcel blocks a sensor.

    Whether a parcel in pose ``s`` and ``phase`` blocks ``sensor`` (the conditions of
    ``_conditions``, written out: this runs for every parcel and period).

    Parameters
    ----------
    sensor : int
        The sensor's index (photo-eyes, then chute_left, chute_right).
    n_eyes : int
        The number of photo-eyes.
    eye_x : ndarray
        The photo-eyes' x [m].
    cfg : ndarray
        The cell's configuration row (``C_*``).
    s : ndarray, shape (6,)
        The parcel's state.
    phase : int
        The parcel's phase (on the cell, leaving, gone).
    half_a : float
        Half the parcel's length A [m].
    half_b : float
        Half the parcel's width B [m].

    Returns
    -------
    bool
        Whether it blocks the sensor.

    """
    if not _phase_counts(sensor, n_eyes, phase):
        return False
    hx, hy = half_extents(s[2], half_a, half_b)
    if sensor < n_eyes:
        return s[0] + hx > eye_x[sensor] and s[0] - hx < eye_x[sensor]
    line = cfg[C_HALF_W] if sensor == n_eyes else -cfg[C_HALF_W]
    return (
        s[1] + hy > line
        and s[1] - hy < line
        and s[0] + hx > cfg[C_OPEN_LO]
        and s[0] - hx < cfg[C_OPEN_HI]
    )


@njit(cache=True)
def _edge_time(sensor, n_eyes, eye_x, cfg, motion, half_a, half_b, rising, tau_phase, conditions):
    """
    Time of a parcel's own block/unblock of a sensor inside the period.

    The blocked set is an intersection of half-lines in each feature, so it is entered when
    the last condition becomes true and left when the first becomes false. A parcel leaving
    the sensor's view by changing phase (off the cell) clears it at ``tau_phase``.
    """
    s0, s1, h = motion.s0, motion.s1, motion.h
    kinds, levels, signs = conditions.kinds, conditions.levels, conditions.signs
    nc = _conditions(sensor, n_eyes, eye_x, cfg, conditions)
    best = 0.0 if rising else h
    any_geo = False
    for c in range(nc):
        g0 = signs[c] * (_feature(kinds[c], s0[0], s0[1], s0[2], half_a, half_b) - levels[c]) > 0.0
        g1 = signs[c] * (_feature(kinds[c], s1[0], s1[1], s1[2], half_a, half_b) - levels[c]) > 0.0
        if rising and g1 and not g0:
            best = max(best, crossing_time(kinds[c], levels[c], motion, half_a, half_b))
            any_geo = True
        elif not rising and g0 and not g1:
            best = min(best, crossing_time(kinds[c], levels[c], motion, half_a, half_b))
            any_geo = True
    if not rising and tau_phase >= 0.0 and (tau_phase < best or not any_geo):
        best = tau_phase
    return best


@njit(cache=True)
def rectangles_overlap(s1, ha1, hb1, s2, ha2, hb2, tol):
    """
    Separating-axis test of two turned rectangles: True if they interpenetrate by > tol.

    Parameters
    ----------
    s1 : ndarray, shape (6,)
        The first footprint's state.
    ha1 : float
        Its half length [m].
    hb1 : float
        Its half width [m].
    s2 : ndarray, shape (6,)
        The second footprint's state.
    ha2 : float
        Its half length [m].
    hb2 : float
        Its half width [m].
    tol : float
        The overlap or reach that counts [m].

    Returns
    -------
    bool
        True if they interpenetrate by more than ``tol``.

    """
    dx = s2[0] - s1[0]
    dy = s2[1] - s1[1]
    c1 = math.cos(s1[2])
    n1 = math.sin(s1[2])
    c2 = math.cos(s2[2])
    n2 = math.sin(s2[2])
    # axes: the two rectangles' own (cos, sin) and (-sin, cos)
    axes = ((c1, n1), (-n1, c1), (c2, n2), (-n2, c2))
    for ax, ay in axes:
        r1 = ha1 * abs(c1 * ax + n1 * ay) + hb1 * abs(-n1 * ax + c1 * ay)
        r2 = ha2 * abs(c2 * ax + n2 * ay) + hb2 * abs(-n2 * ax + c2 * ay)
        if abs(dx * ax + dy * ay) >= r1 + r2 - tol:
            return False
    return True


@njit(cache=True)
def crosses_wall(s, half_a, half_b, half_w, open_lo, open_hi, tol):
    """
    Return True if the footprint reaches past a side wall y = ±w/2 beside the chute openings.

    Parameters
    ----------
    s : ndarray, shape (6,)
        The parcel's state.
    half_a : float
        Half the parcel's length A [m].
    half_b : float
        Half the parcel's width B [m].
    half_w : float
        Half the belt's width [m].
    open_lo : float
        Where the chute openings begin, x [m].
    open_hi : float
        Where they end, x [m].
    tol : float
        The overlap or reach that counts [m].

    Returns
    -------
    bool
        True if the footprint reaches past a wall where there is no opening.

    """
    corners = np.empty((4, 2))
    box_corners(s[0], s[1], s[2], half_a, half_b, corners)
    for side in (1.0, -1.0):
        for i in range(4):
            xa = corners[i, 0]
            ya = side * corners[i, 1] - half_w
            if ya > tol and (xa < open_lo or xa > open_hi):
                return True
            j = (i + 1) % 4
            xb = corners[j, 0]
            yb = side * corners[j, 1] - half_w
            if (ya > tol) != (yb > tol):
                xc = xa + (xb - xa) * (tol - ya) / (yb - ya)
                if xc < open_lo or xc > open_hi:
                    return True
    return False


@njit(cache=True)
def upstream_room(state, phase, par, induct_x):
    """
    Return the free belt length in front of the induct point.

    Free belt length in front of the induct point [m] and the slot whose trailing edge
    bounds it (-1 and inf when no parcel is on the cell).

    Parameters
    ----------
    state : ndarray, shape (cap, 6)
        Every parcel's state.
    phase : ndarray
        Every parcel's phase.
    par : ndarray, shape (cap, PARCEL_WIDTH)
        Every parcel's row.
    induct_x : float
        The induct point's x [m].

    Returns
    -------
    (float, float)
        The free belt length [m] and the slowest parcel's speed there [m/s].

    """
    room = math.inf
    slot = -1
    for i in range(state.shape[0]):
        if phase[i] == PH_CELL or phase[i] == PH_JAMMED:
            hx, _ = half_extents(state[i, 2], par[i, P_HALF_A], par[i, P_HALF_B])
            r = state[i, 0] - hx - induct_x
            if r < room:
                room = r
                slot = i
    return room, slot


@njit(cache=True)
def cell_snapshot(phase, mode, ids, state, par, b, out):
    """
    Write the rows of the parcels in the cell into ``out``.

    Rows (id, x, y, φ, A, B, state code) of the parcels in the cell, in id order, into
    ``out``; returns their number. Past the disk field on the belt counts as straight.

    Parameters
    ----------
    phase : ndarray
        Every parcel's phase.
    mode : ndarray
        Every parcel's mode.
    ids : ndarray
        The parcels' ids.
    state : ndarray, shape (cap, 6)
        Every parcel's state.
    par : ndarray, shape (cap, PARCEL_WIDTH)
        Every parcel's row.
    b : float
        The disk field's length [m].
    out : ndarray
        Receives the result.

    Returns
    -------
    int
        The number of rows written.

    """
    n = 0
    for i in range(phase.shape[0]):
        if phase[i] == PH_FREE:
            continue
        hx, _ = half_extents(state[i, 2], par[i, P_HALF_A], par[i, P_HALF_B])
        if phase[i] == PH_JAMMED:
            code = S_JAMMED
        elif phase[i] != PH_CELL:
            code = S_DIVERTED
        elif mode[i] == MODE_SLIDE:
            code = S_SLIDING
        elif mode[i] == MODE_DISKS:
            code = S_ON_DISKS
        elif state[i, 0] - hx > b:
            code = S_STRAIGHT
        else:
            code = S_ON_BELT
        out[n, 0] = ids[i]
        out[n, 1] = state[i, 0]
        out[n, 2] = state[i, 1]
        out[n, 3] = state[i, 2]
        out[n, 4] = 2.0 * par[i, P_HALF_A]
        out[n, 5] = 2.0 * par[i, P_HALF_B]
        out[n, 6] = code
        n += 1
    order = np.argsort(out[:n, 0], kind='mergesort')
    out[:n] = out[:n][order]
    return n


@njit(cache=True)
def _emit(ev_i, ev_f, n_ev, k, kind, a, b, tau, x, y):
    if n_ev < ev_i.shape[0]:
        ev_i[n_ev, 0] = k
        ev_i[n_ev, 1] = kind
        ev_i[n_ev, 2] = a
        ev_i[n_ev, 3] = b
        ev_f[n_ev, 0] = tau
        ev_f[n_ev, 1] = x
        ev_f[n_ev, 2] = y
    return n_ev + 1


@njit(cache=True)
def advance_cell(n_periods, k0, setup, act, parcels, sensors, log, memo):
    """
    Advance the cell over up to ``n_periods`` control periods from period index ``k0``.

    Parameters
    ----------
    n_periods : int
        The most periods to advance.
    k0 : int
        The index of the first.
    setup : CellSetup
        The configuration row cfg (``C_*``), the (2, N) law parameter rows of belt and
        disks, and the footprint quadrature's nodes and weights.
    act : ndarray
        The actuators' state (``A_*``), updated.
    parcels : Parcels
        state (cap, 6), mode, phase, par (cap, PARCEL_WIDTH), scanned, and gauge_xi
        (cap, GAUGE_CARRY): each parcel's limit-set gauge twist and Newton metric (a
        stick checked period after period, riding the belt onto raised disks, starts
        each Newton solve from the last one's); all updated.
    sensors : Sensors
        The photo-eyes' x [m], and which parcel blocks which sensor (blocked (cap,
        n_sensors), counts (n_sensors)), updated; the sensors are the photo-eyes, then
        chute_left, chute_right.
    log : EventLog
        Events go to ev_i/ev_f; the kernel stops after a period that leaves fewer than
        ``reserve`` free rows.
    memo : Memo
        stats (int64: parcel-periods in closed form, integrated, integrator steps, rhs),
        and last_strips (MAX_STRIPS, STRIP_WIDTH) with last_info (int64 [period index,
        count]): the strips of the last period advanced, updated (a stick that held
        through it holds through the next under the same strips where nothing about
        the parcel changes).

    Returns
    -------
    (int, int)
        The periods done and the events written.

    """
    cfg, laws, nodes, weights = setup.cfg, setup.laws, setup.nodes, setup.weights
    state, mode, phase, par = parcels.state, parcels.mode, parcels.phase, parcels.par
    scanned, gauge_xi = parcels.scanned, parcels.gauge_xi
    eye_x, blocked, counts = sensors.eye_x, sensors.blocked, sensors.counts
    ev_i, ev_f, ev_reserve = log.ev_i, log.ev_f, log.reserve
    stats, last_strips, last_info = memo.stats, memo.last_strips, memo.last_info
    cap = state.shape[0]
    n_eyes = eye_x.shape[0]
    n_sens = n_eyes + 2
    h = cfg[C_DT]
    v_run = cfg[C_V]
    half_w = cfg[C_HALF_W]
    b = cfg[C_B]
    law_a_id = int(cfg[C_LAW_A])
    law_b_id = int(cfg[C_LAW_B])
    accurate = cfg[C_METHOD] < 0.5
    strips = np.zeros((MAX_STRIPS, STRIP_WIDTH))
    borders = np.array([0.0, b])
    ts = np.empty(_INT_BUF)
    ys = np.empty((_INT_BUF, 6))
    ms = np.empty(_INT_BUF, dtype=np.int64)
    evb = np.empty((_INT_BUF, 3))
    counters = np.zeros(N_COUNTERS, dtype=np.int64)
    s0 = np.empty(6)
    s1 = np.empty(6)
    rigid = np.zeros(cap, dtype=np.bool_)
    # each footprint's circumradius, bounding its extent in any direction [m]
    r_out = np.empty(cap)
    for i in range(cap):
        # not math.hypot: libm's is slower
        r_out[i] = math.sqrt(
            par[i, P_HALF_A] * par[i, P_HALF_A] + par[i, P_HALF_B] * par[i, P_HALF_B]
        )
    tr_tau = np.empty(cap * n_sens)
    tr_s = np.empty(cap * n_sens, dtype=np.int64)
    tr_d = np.empty(cap * n_sens, dtype=np.int64)
    kinds = np.empty(4, np.int64)
    levels = np.empty(4)
    signs = np.empty(4)
    n_ev = 0
    done = 0
    for step in range(n_periods):
        k = k0 + step
        a_start = act[A_ALPHA]
        st_start = act[A_STROKE]
        da = cfg[C_ALPHA_RATE] * h
        ds = cfg[C_STROKE_RATE] * h
        a_mid = toward(a_start, act[A_ALPHA_CMD], 0.5 * da)
        st_mid = toward(st_start, act[A_STROKE_TARGET], 0.5 * ds)
        v = v_run if act[A_BELT_ON] > 0.5 else 0.0
        n_strips, disk_sid = cell_strips(
            v, a_mid, b, st_mid, law_a_id, laws[0], law_b_id, laws[1], strips
        )
        strip_view = strips[:n_strips]
        same_strips = last_info[0] == k - 1 and last_info[1] == n_strips
        for q in range(n_strips):
            for j in range(STRIP_WIDTH):
                same_strips = same_strips and strips[q, j] == last_strips[q, j]
                last_strips[q, j] = strips[q, j]
        last_info[0] = k
        last_info[1] = n_strips
        ntr = 0
        for i in range(cap):
            ph = phase[i]
            rigid[i] = False
            if ph == PH_FREE or ph == PH_JAMMED:
                continue
            for j in range(6):
                s0[j] = state[i, j]
            ha = par[i, P_HALF_A]
            hb = par[i, P_HALF_B]
            # the half extent along x only where a decision needs it: the footprint's
            # circumradius bounds it, and most parcels are far from every border and eye
            r_i = r_out[i]
            hx0 = -1.0
            new_phase = ph
            tau_phase = -1.0
            if ph == PH_CELL:
                m = mode[i]
                # a stick holds only to the velocity the surface has in this period
                if m == MODE_BELT:
                    if not (s0[3] == v and s0[4] == 0.0 and s0[5] == 0.0):
                        m = MODE_SLIDE
                elif m >= 0:
                    m = MODE_SLIDE
                    if (
                        disk_sid >= 0
                        and s0[3] == strips[1, S_VX]
                        and s0[4] == strips[1, S_VY]
                        and s0[5] == 0.0
                    ):
                        m = disk_sid
                on_disks_alone = False
                if m == MODE_BELT:
                    if disk_sid <= 0 or s0[0] + r_i + v * h <= 0.0 or s0[0] - r_i >= b:
                        rigid[i] = True
                    else:
                        hx0, _ = half_extents(s0[2], ha, hb)
                        rigid[i] = s0[0] + hx0 + v * h <= 0.0 or s0[0] - hx0 >= b
                if not rigid[i] and hx0 < 0.0:
                    hx0, _ = half_extents(s0[2], ha, hb)
                if m == MODE_DISKS and disk_sid == MODE_DISKS:
                    if strips[1, S_WEIGHT] == 1.0:
                        # stuck to fully raised disks and over nothing else for the whole
                        # period: as on the belt, no force can break this stick
                        x_end = s0[0] + strips[1, S_VX] * h
                        on_disks_alone = (
                            min(s0[0], x_end) - hx0 >= 0.0 and max(s0[0], x_end) + hx0 <= b
                        )
                    if not on_disks_alone and same_strips and abs(strips[1, S_VX]) * h <= 1e-15:
                        # stuck to disks carrying it straight across the belt (α = 90°, its
                        # x moving less than rounding): its footprint's part over every
                        # strip only slides along y, so no force on it changes, and the
                        # stick that held through the last period with these very strips
                        # holds through this one
                        on_disks_alone = True
                if rigid[i]:
                    state[i, 0] = s0[0] + v * h
                    mode[i] = MODE_BELT
                    stats[0] += 1
                elif on_disks_alone:
                    state[i, 0] = s0[0] + strips[1, S_VX] * h
                    state[i, 1] = s0[1] + strips[1, S_VY] * h
                    stats[0] += 1
                else:
                    counters[:] = 0
                    if accurate:
                        status, _, m_new = run_accurate(
                            s0,
                            m,
                            0.0,
                            h,
                            Slide(
                                math.inf,
                                Contact(strip_view, par[i], nodes, weights),
                                n_surf_of(strip_view),
                                borders,
                                cfg[C_RTOL],
                                cfg[C_ATOL],
                                h,
                            ),
                            True,
                            Trail(ts, ys, ms),
                            Log(evb, counters),
                            gauge_xi[i],
                        )
                    else:
                        status, _, m_new = run_implicit(
                            s0,
                            m,
                            0.0,
                            h,
                            math.inf,
                            Contact(strip_view, par[i], nodes, weights),
                            h,
                            Trail(ts, ys, ms),
                            Log(evb, counters),
                        )
                    stats[1] += 1
                    stats[2] += counters[N_STEPS]
                    stats[3] += counters[N_RHS]
                    last = counters[N_OUT] - 1
                    if (status != ST_END and status != ST_TARGET) or not 0 <= last < _INT_BUF:
                        # the physics failed for this parcel: stop it and say so
                        phase[i] = PH_JAMMED
                        mode[i] = MODE_SLIDE
                        state[i, 3] = 0.0
                        state[i, 4] = 0.0
                        state[i, 5] = 0.0
                        n_ev = _emit(ev_i, ev_f, n_ev, k, EV_JAM, i, -2, h, s0[0], s0[1])
                        new_phase = PH_JAMMED
                    else:
                        for j in range(6):
                            state[i, j] = ys[last, j]
                        mode[i] = m_new
                for j in range(6):
                    s1[j] = state[i, j]
                if new_phase == PH_CELL:
                    # scanner: the leading edge crosses the scanner line
                    if not scanned[i]:
                        if hx0 < 0.0:
                            hx0, _ = half_extents(s0[2], ha, hb)
                        hx1 = hx0 if s1[2] == s0[2] else half_extents(s1[2], ha, hb)[0]
                        if s1[0] + hx1 >= cfg[C_SCAN_X]:
                            tau = crossing_time(F_XMAX, cfg[C_SCAN_X], Motion(s0, s1, h), ha, hb)
                            n_ev = _emit(ev_i, ev_f, n_ev, k, EV_SCAN, i, 0, tau, s1[0], s1[1])
                            scanned[i] = True
                    # leaving: the centre of gravity crosses a chute entry line or the exit
                    if abs(s1[1]) >= half_w:
                        side = 1.0 if s1[1] > 0.0 else -1.0
                        tau = crossing_time(F_YCOG, side * half_w, Motion(s0, s1, h), ha, hb)
                        x_at = _hermite(s0[0], s0[3], s1[0], s1[3], h, tau)
                        if cfg[C_OPEN_LO] <= x_at <= cfg[C_OPEN_HI]:
                            new_phase = PH_CHUTE_LEFT if side > 0.0 else PH_CHUTE_RIGHT
                            tau_phase = tau
                            n_ev = _emit(
                                ev_i,
                                ev_f,
                                n_ev,
                                k,
                                EV_LEFT if side > 0.0 else EV_RIGHT,
                                i,
                                0,
                                tau,
                                x_at,
                                side * half_w,
                            )
                    elif s1[0] > cfg[C_EXIT_X]:
                        tau = crossing_time(F_XCOG, cfg[C_EXIT_X], Motion(s0, s1, h), ha, hb)
                        y_at = _hermite(s0[1], s0[4], s1[1], s1[4], h, tau)
                        new_phase = PH_FREE
                        tau_phase = tau
                        n_ev = _emit(
                            ev_i, ev_f, n_ev, k, EV_STRAIGHT, i, 0, tau, cfg[C_EXIT_X], y_at
                        )
            else:
                # on a chute: it slides off at the velocity it left with (the chute is not
                # modelled beyond its entry line), until the footprint has crossed the line
                for j in range(3):
                    state[i, j] = s0[j] + h * s0[j + 3]
                for j in range(6):
                    s1[j] = state[i, j]
                _, hy1 = half_extents(s1[2], ha, hb)
                gone = (s1[1] - hy1 > half_w) if ph == PH_CHUTE_LEFT else (s1[1] + hy1 < -half_w)
                if gone:
                    new_phase = PH_FREE
                    tau_phase = h
                    n_ev = _emit(ev_i, ev_f, n_ev, k, EV_GONE, i, 0, h, s1[0], s1[1])
            # this parcel's own sensor transitions. Moving rigidly along x on the cell it
            # can change only a photo-eye that one of its x edges passes in this period.
            along_x_only = rigid[i] and new_phase == PH_CELL
            for s in range(n_sens):
                if along_x_only:
                    if s >= n_eyes:
                        break
                    xe = eye_x[s]
                    if not s0[0] - r_i <= xe <= s1[0] + r_i:
                        continue
                    if hx0 < 0.0:
                        hx0, _ = half_extents(s0[2], ha, hb)
                    if not (s0[0] + hx0 <= xe <= s1[0] + hx0 or s0[0] - hx0 <= xe <= s1[0] - hx0):
                        continue
                b0 = blocked[i, s]
                b1 = sensor_blocked(s, n_eyes, eye_x, cfg, s1, new_phase, ha, hb)
                if b0 != b1:
                    tr_tau[ntr] = _edge_time(
                        s,
                        n_eyes,
                        eye_x,
                        cfg,
                        Motion(s0, s1, h),
                        ha,
                        hb,
                        b1,
                        tau_phase,
                        Conditions(kinds, levels, signs),
                    )
                    tr_s[ntr] = s
                    tr_d[ntr] = 1 if b1 else -1
                    ntr += 1
                    blocked[i, s] = b1
            phase[i] = new_phase
            if new_phase == PH_FREE:
                mode[i] = MODE_SLIDE
        # jams: overlaps between parcels that moved relative to each other this period.
        # A parcel moved rigidly with the belt keeps its distance to every other such
        # parcel, so a check starts only from a parcel that did not (integrated, or
        # jammed and standing while the belt carries the others on).
        for i in range(cap):
            i_starts = (phase[i] == PH_CELL and not rigid[i]) or phase[i] == PH_JAMMED
            if not i_starts:
                continue
            ha_i = par[i, P_HALF_A]
            hb_i = par[i, P_HALF_B]
            for j in range(cap):
                if j == i or (phase[j] != PH_CELL and phase[j] != PH_JAMMED):
                    continue
                if phase[i] == PH_JAMMED and phase[j] == PH_JAMMED:
                    continue
                j_starts = not rigid[j]
                if j_starts and j < i:
                    continue  # this pair was checked from j
                reach = r_out[i] + r_out[j]
                if (
                    abs(state[i, 0] - state[j, 0]) >= reach
                    or abs(state[i, 1] - state[j, 1]) >= reach
                ):
                    continue
                if rectangles_overlap(
                    state[i], ha_i, hb_i, state[j], par[j, P_HALF_A], par[j, P_HALF_B], CONTACT_TOL
                ):
                    for q, other in ((i, j), (j, i)):
                        if phase[q] == PH_CELL:
                            phase[q] = PH_JAMMED
                            mode[q] = MODE_SLIDE
                            state[q, 3] = 0.0
                            state[q, 4] = 0.0
                            state[q, 5] = 0.0
                            n_ev = _emit(
                                ev_i, ev_f, n_ev, k, EV_JAM, q, other, h, state[q, 0], state[q, 1]
                            )
        # side walls outside the chute openings
        for i in range(cap):
            if phase[i] != PH_CELL or rigid[i]:
                continue
            if crosses_wall(
                state[i],
                par[i, P_HALF_A],
                par[i, P_HALF_B],
                half_w,
                cfg[C_OPEN_LO],
                cfg[C_OPEN_HI],
                CONTACT_TOL,
            ):
                phase[i] = PH_JAMMED
                mode[i] = MODE_SLIDE
                state[i, 3] = 0.0
                state[i, 4] = 0.0
                state[i, 5] = 0.0
                n_ev = _emit(ev_i, ev_f, n_ev, k, EV_JAM, i, -1, h, state[i, 0], state[i, 1])
        # sensor edges: the OR over parcels, in time order
        if ntr > 0:
            order = np.argsort(tr_tau[:ntr], kind='mergesort')
            for q in order:
                s = tr_s[q]
                before = counts[s]
                counts[s] += tr_d[q]
                if before == 0 and counts[s] > 0:
                    n_ev = _emit(ev_i, ev_f, n_ev, k, EV_EDGE, s, 1, tr_tau[q], 0.0, 0.0)
                elif before > 0 and counts[s] == 0:
                    n_ev = _emit(ev_i, ev_f, n_ev, k, EV_EDGE, s, 0, tr_tau[q], 0.0, 0.0)
        # actuators reach their end-of-period positions
        a_end = toward(a_start, act[A_ALPHA_CMD], da)
        st_end = toward(st_start, act[A_STROKE_TARGET], ds)
        act[A_ALPHA_DOT] = (a_end - a_start) / h
        act[A_STROKE_DOT] = (st_end - st_start) / h
        act[A_ALPHA] = a_end
        act[A_STROKE] = st_end
        done += 1
        if ev_i.shape[0] - n_ev < ev_reserve:
            break
    return done, n_ev
