"""
What can be observed of parcels on the cell over a control period, in closed form.

A footprint's extents (``half_extents``), the time a feature of it (an edge, the
centre of gravity) crosses a line inside the period (``crossing_time``: exact for
linear motion, else bisection on the cubic Hermite interpolant), whether a sensor is
blocked and when its edge falls (``sensor_blocked``, ``_edge_time``), overlaps of two
footprints (separating-axis test) and crossings of a side wall outside the chute
openings; and the views the runtime takes of the parcels (``upstream_room``,
``cell_snapshot``). ``cell_kernels.advance_cell`` calls these every period.

Units: SI (m, s, rad); tau in s from the period start.
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.core.cell_layout import (
    C_HALF_W,
    C_OPEN_HI,
    C_OPEN_LO,
    F_XCOG,
    F_XMAX,
    F_XMIN,
    F_YMAX,
    F_YMIN,
    MODE_DISKS,
    MODE_SLIDE,
    PH_CELL,
    PH_CHUTE_LEFT,
    PH_CHUTE_RIGHT,
    PH_FREE,
    PH_JAMMED,
    S_DIVERTED,
    S_JAMMED,
    S_ON_BELT,
    S_ON_DISKS,
    S_SLIDING,
    S_STRAIGHT,
)
from sorter_sim.model.core.geometry import box_corners
from sorter_sim.model.core.jit import allocating, kernel
from sorter_sim.model.core.layout import P_HALF_A, P_HALF_B


@kernel
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


@kernel
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


@kernel
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


@kernel
def _feature_at(kind, motion, tau, half_a, half_b):
    s0, s1, h = motion.s0, motion.s1, motion.h
    x = _hermite(s0[0], s0[3], s1[0], s1[3], h, tau)
    y = _hermite(s0[1], s0[4], s1[1], s1[4], h, tau)
    phi = _hermite(s0[2], s0[5], s1[2], s1[5], h, tau)
    return _feature(kind, x, y, phi, half_a, half_b)


@kernel
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


@kernel
def _condition(conditions, c, kind, level, sign):
    kinds, levels, signs = conditions.kinds, conditions.levels, conditions.signs
    kinds[c] = kind
    levels[c] = level
    signs[c] = sign


@kernel
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


@kernel
def _phase_counts(sensor, n_eyes, phase):
    if phase == PH_CELL or phase == PH_JAMMED:
        return True
    if phase == PH_CHUTE_LEFT:
        return sensor == n_eyes
    if phase == PH_CHUTE_RIGHT:
        return sensor == n_eyes + 1
    return False


@kernel
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


@kernel
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


@kernel
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


@allocating
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


@kernel
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


@kernel
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


__all__ = [
    "half_extents",
    "crossing_time",
    "sensor_blocked",
    "rectangles_overlap",
    "crosses_wall",
    "upstream_room",
    "cell_snapshot",
]
