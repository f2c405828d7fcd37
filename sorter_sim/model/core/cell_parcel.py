"""
One parcel over one control period of the cell: the steps of ``advance_cell``.

A parcel on the cell starts the period in the mode its stick still holds
(``_held_mode``), moves in closed form where no force can break that stick
(``_closed_form``) or is integrated by the model core (``_integrate``), then passes
the scanner and may leave (``_on_cell_events``); a parcel on a chute slides off it
(``_on_chute``). Its own sensor transitions follow (``_sensor_changes``).
``_advance_parcel`` runs these in order; ``cell_kernels.advance_cell`` runs it for
every parcel, every period.

Units: SI (m, s, rad); tau in s from the period start.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from sorter_sim.model.core.accurate import run_accurate_reduced
from sorter_sim.model.core.cell_layout import (
    C_ATOL,
    C_B,
    C_DT,
    C_EXIT_X,
    C_HALF_W,
    C_OPEN_HI,
    C_OPEN_LO,
    C_RTOL,
    C_SCAN_X,
    EV_GONE,
    EV_JAM,
    EV_LEFT,
    EV_RIGHT,
    EV_SCAN,
    EV_STRAIGHT,
    F_XCOG,
    F_XMAX,
    F_YCOG,
    MAX_STRIPS,
    MODE_BELT,
    MODE_DISKS,
    MODE_SLIDE,
    PH_CELL,
    PH_CHUTE_LEFT,
    PH_CHUTE_RIGHT,
    PH_FREE,
    PH_JAMMED,
    Conditions,
    Motion,
)
from sorter_sim.model.core.cell_sensing import (
    _edge_time,
    _hermite,
    crossing_time,
    half_extents,
    sensor_blocked,
)
from sorter_sim.model.core.common import (
    N_COUNTERS,
    N_OUT,
    N_RHS,
    N_STEPS,
    ST_END,
    ST_TARGET,
    n_surf_of,
)
from sorter_sim.model.core.implicit import run_implicit
from sorter_sim.model.core.jit import borrowing, kernel, kernel_step
from sorter_sim.model.core.layout import (
    P_HALF_A,
    P_HALF_B,
    S_VX,
    S_VY,
    S_WEIGHT,
    STRIP_WIDTH,
    Contact,
    Log,
    Slide,
    Trail,
)

_INT_BUF = 512  # integrator output rows per parcel-period (a few are used)


@borrowing
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


# what ``advance_cell`` keeps from parcel to parcel and period to period (scratch): this
# period's strips and the disk field's borders, the integrator's trail, events and
# counters, a parcel's state at the period's start and end, which parcels moved rigidly
# with the belt, each footprint's circumradius [m] (bounding its extent in any
# direction), this period's sensor transitions (tau, sensor, +1/-1) and their time
# order, the sensor conditions, and the contact step's narrow-phase scratch (two
# points' rows and feature numbers, ``contact.contact_step``)
CellWork = namedtuple(
    'CellWork',
    [
        'strips',
        'borders',
        'ts',
        'ys',
        'ms',
        'evb',
        'counters',
        's0',
        's1',
        'rigid',
        'r_out',
        'tr_tau',
        'tr_s',
        'tr_d',
        'order',
        'conditions',
        'contact_scratch',
    ],
)


@kernel
def _cell_work(par, n_sens, b):
    """Return the ``CellWork`` scratch of a cell: parcel rows ``par``, ``n_sens`` sensors."""
    cap = par.shape[0]
    r_out = np.empty(cap)
    for i in range(cap):
        # not math.hypot: libm's is slower
        r_out[i] = math.sqrt(
            par[i, P_HALF_A] * par[i, P_HALF_A] + par[i, P_HALF_B] * par[i, P_HALF_B]
        )
    return CellWork(
        np.zeros((MAX_STRIPS, STRIP_WIDTH)),
        np.array([0.0, b]),
        np.empty(_INT_BUF),
        np.empty((_INT_BUF, 6)),
        np.empty(_INT_BUF, dtype=np.int64),
        np.empty((_INT_BUF, 3)),
        np.zeros(N_COUNTERS, dtype=np.int64),
        np.empty(6),
        np.empty(6),
        np.zeros(cap, dtype=np.bool_),
        r_out,
        np.empty(cap * n_sens),
        np.empty(cap * n_sens, dtype=np.int64),
        np.empty(cap * n_sens, dtype=np.int64),
        np.empty(cap * n_sens, dtype=np.int64),
        Conditions(np.empty(4, np.int64), np.empty(4), np.empty(4)),
        (np.zeros((2, 5)), np.zeros(2, dtype=np.int64)),
    )


@kernel_step
def _held_mode(m, s0, v, strips, disk_sid):
    """
    Return the mode a parcel in mode ``m`` starts the period in: a stick holds to its velocity.

    A parcel stuck to the belt whose velocity is not the belt's this period (an e-stop,
    a restart), or stuck to disks that changed velocity (α slewing) or went down,
    starts the period sliding and re-sticks where the physics says.
    """
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
    return m


@kernel_step
def _closed_form(i, m, period, setup, parcels, work, stats):
    """
    Move parcel i over the period in closed form where no force can break its stick.

    Stuck to the belt and clear of the popped-up disks for the whole period: x += v h
    (``rigid``). Stuck to fully raised disks and wholly over them, or carried straight
    across the belt by them (α = 90°, x moving less than rounding) under the very
    strips of the last period through which the stick held: it moves with the disks.
    ``period`` is (v, disk_sid, same_strips).

    Returns
    -------
    (bool, int)
        Whether it moved in closed form, and its half extent along x at the start [m]
        (-1.0 where not needed: rigid with the belt far from every border).

    """
    v, disk_sid, same_strips = period
    state, par, rigid, strips = parcels.state, parcels.par, work.rigid, work.strips
    s0, r_i = work.s0, work.r_out[i]
    h = setup.cfg[C_DT]
    b = setup.cfg[C_B]
    ha = par[i, P_HALF_A]
    hb = par[i, P_HALF_B]
    # the half extent along x only where a decision needs it: the footprint's
    # circumradius bounds it, and most parcels are far from every border and eye
    hx0 = -1.0
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
            on_disks_alone = min(s0[0], x_end) - hx0 >= 0.0 and max(s0[0], x_end) + hx0 <= b
        if not on_disks_alone and same_strips and abs(strips[1, S_VX]) * h <= 1e-15:
            # stuck to disks carrying it straight across the belt (α = 90°, its
            # x moving less than rounding): its footprint's part over every
            # strip only slides along y, so no force on it changes, and the
            # stick that held through the last period with these very strips
            # holds through this one
            on_disks_alone = True
    if rigid[i]:
        state[i, 0] = s0[0] + v * h
        parcels.mode[i] = MODE_BELT
        stats[0] += 1
    elif on_disks_alone:
        state[i, 0] = s0[0] + strips[1, S_VX] * h
        state[i, 1] = s0[1] + strips[1, S_VY] * h
        stats[0] += 1
    return rigid[i] or on_disks_alone, hx0


@kernel_step
def _integrate_accurate(i, m, n_strips, setup, parcels, work, counters, h):
    """
    Integrate parcel i over a time ``h`` (the period, or less) by the accurate method.

    ``accurate.run_accurate``: event-located Dormand-Prince, restarted every period,
    from mode ``m`` under the period's ``n_strips`` strips. Returns its status and the
    mode reached; the trajectory is in the scratch (``work.ys``), the counts in
    ``counters``.
    """
    cfg, nodes, weights = setup.cfg, setup.nodes, setup.weights
    strip_view = work.strips[:n_strips]
    contact = Contact(strip_view, parcels.par[i], nodes, weights)
    slide = Slide(
        math.inf,
        contact,
        n_surf_of(strip_view),
        work.borders,
        cfg[C_RTOL],
        cfg[C_ATOL],
        h,
    )
    # the reductions always apply in the cell
    status, _, m_new = run_accurate_reduced(
        work.s0,
        m,
        0.0,
        h,
        slide,
        Trail(work.ts, work.ys, work.ms),
        Log(work.evb, counters),
        parcels.gauge_xi[i],
    )
    return status, m_new


@kernel_step
def _integrate_implicit(i, m, n_strips, setup, parcels, work, counters, h):
    """
    Integrate parcel i over a time ``h`` by one backward-Euler step, from mode ``m``.

    ``implicit.run_implicit`` (exact stick too) under the period's ``n_strips``
    strips. Returns its status and the mode reached, as ``_integrate_accurate``.
    """
    contact = Contact(work.strips[:n_strips], parcels.par[i], setup.nodes, setup.weights)
    status, _, m_new = run_implicit(
        work.s0,
        m,
        0.0,
        h,
        math.inf,
        contact,
        h,
        Trail(work.ts, work.ys, work.ms),
        Log(work.evb, counters),
    )
    return status, m_new


@kernel_step
def _integrate(i, k, m, period, setup, parcels, work, stats, log, n_ev):
    """
    Integrate parcel i over the period with the model core, from mode ``m``.

    ``period`` is as ``_advance_parcel``'s: its strips' count and the cell's method
    (``_integrate_accurate`` or ``_integrate_implicit``, fixed when the kernel is
    compiled) are used. A failed integration jams the parcel (EV_JAM, b = -2).

    Returns
    -------
    (int, int)
        The parcel's phase after it (PH_CELL or PH_JAMMED) and the events.

    """
    n_strips, integrate = period[1], period[4]
    state, ys, counters = parcels.state, work.ys, work.counters
    counters[:] = 0
    status, m_new = integrate(i, m, n_strips, setup, parcels, work, counters, setup.cfg[C_DT])
    stats[1] += 1
    stats[2] += counters[N_STEPS]
    stats[3] += counters[N_RHS]
    last = counters[N_OUT] - 1
    if (status != ST_END and status != ST_TARGET) or not 0 <= last < _INT_BUF:
        # the physics failed for this parcel: stop it and say so
        return PH_JAMMED, _jam(i, -2, k, setup.cfg[C_DT], parcels, log, n_ev)
    for j in range(6):
        state[i, j] = ys[last, j]
    parcels.mode[i] = m_new
    return PH_CELL, n_ev


@kernel_step
def _jam(q, other, k, tau, parcels, log, n_ev):
    """Jam parcel q where it stands (EV_JAM, b = ``other``: a slot, -1 wall, -2 integration)."""
    state = parcels.state
    parcels.phase[q] = PH_JAMMED
    parcels.mode[q] = MODE_SLIDE
    state[q, 3] = 0.0
    state[q, 4] = 0.0
    state[q, 5] = 0.0
    return _emit(log.ev_i, log.ev_f, n_ev, k, EV_JAM, q, other, tau, state[q, 0], state[q, 1])


@kernel_step
def _on_cell_events(i, k, hx0, cfg, parcels, s0, s1, log, n_ev):
    """
    Detect the scanner and the ways off the cell of parcel i, moved from ``s0`` to ``s1``.

    The scanner reads a label once its leading edge crosses the scanner line
    (EV_SCAN); the centre of gravity leaves over a chute entry line y = ±w/2 inside
    the opening (EV_LEFT, EV_RIGHT) or past the straight exit (EV_STRAIGHT), each at
    the time located on the period's motion (``crossing_time``, ``_hermite``).

    Returns
    -------
    (int, float, int)
        The phase after the period, the time into it at which that changed (-1.0: it
        did not) and the events.

    """
    ha = parcels.par[i, P_HALF_A]
    hb = parcels.par[i, P_HALF_B]
    half_w = cfg[C_HALF_W]
    h = cfg[C_DT]
    new_phase = PH_CELL
    tau_phase = -1.0
    # scanner: the leading edge crosses the scanner line
    if not parcels.scanned[i]:
        if hx0 < 0.0:
            hx0, _ = half_extents(s0[2], ha, hb)
        hx1 = hx0 if s1[2] == s0[2] else half_extents(s1[2], ha, hb)[0]
        if s1[0] + hx1 >= cfg[C_SCAN_X]:
            tau = crossing_time(F_XMAX, cfg[C_SCAN_X], Motion(s0, s1, h), ha, hb)
            n_ev = _emit(log.ev_i, log.ev_f, n_ev, k, EV_SCAN, i, 0, tau, s1[0], s1[1])
            parcels.scanned[i] = True
    # leaving: the centre of gravity crosses a chute entry line or the exit
    if abs(s1[1]) >= half_w:
        side = 1.0 if s1[1] > 0.0 else -1.0
        tau = crossing_time(F_YCOG, side * half_w, Motion(s0, s1, h), ha, hb)
        x_at = _hermite(s0[0], s0[3], s1[0], s1[3], h, tau)
        if cfg[C_OPEN_LO] <= x_at <= cfg[C_OPEN_HI]:
            new_phase = PH_CHUTE_LEFT if side > 0.0 else PH_CHUTE_RIGHT
            tau_phase = tau
            kind = EV_LEFT if side > 0.0 else EV_RIGHT
            n_ev = _emit(log.ev_i, log.ev_f, n_ev, k, kind, i, 0, tau, x_at, side * half_w)
    elif s1[0] > cfg[C_EXIT_X]:
        tau = crossing_time(F_XCOG, cfg[C_EXIT_X], Motion(s0, s1, h), ha, hb)
        y_at = _hermite(s0[1], s0[4], s1[1], s1[4], h, tau)
        new_phase = PH_FREE
        tau_phase = tau
        n_ev = _emit(log.ev_i, log.ev_f, n_ev, k, EV_STRAIGHT, i, 0, tau, cfg[C_EXIT_X], y_at)
    return new_phase, tau_phase, n_ev


@kernel_step
def _on_chute(i, k, ph, cfg, parcels, s0, s1, log, n_ev):
    """
    Parcel i on a chute: it slides off at the velocity it left with until it is gone.

    The chute is not modelled beyond its entry line: x += h ẋ, y += h ẏ, φ += h φ̇
    until the whole footprint is past the line (EV_GONE, the slot freed).

    Returns
    -------
    (int, float, int)
        The phase after the period, the time into it at which that changed (-1.0: it
        did not) and the events.

    """
    state = parcels.state
    h = cfg[C_DT]
    half_w = cfg[C_HALF_W]
    for j in range(3):
        state[i, j] = s0[j] + h * s0[j + 3]
    for j in range(6):
        s1[j] = state[i, j]
    _, hy1 = half_extents(s1[2], parcels.par[i, P_HALF_A], parcels.par[i, P_HALF_B])
    gone = (s1[1] - hy1 > half_w) if ph == PH_CHUTE_LEFT else (s1[1] + hy1 < -half_w)
    if gone:
        n_ev = _emit(log.ev_i, log.ev_f, n_ev, k, EV_GONE, i, 0, h, s1[0], s1[1])
        return PH_FREE, h, n_ev
    return ph, -1.0, n_ev


@kernel_step
def _sensor_changes(i, hx0, moved, cfg, parcels, sensors, work, ntr):
    """
    Parcel i's own sensor transitions over the period, each at its located time.

    A sensor whose blocked state by this parcel changed (``sensor_blocked``) gets a
    transition (tau, sensor, +1 blocked / -1 cleared) at the edge time on the
    period's motion (``_edge_time``). ``moved`` is (its phase after the period, the
    time that changed, whether it moved rigidly with the belt): moving rigidly along x
    on the cell it can change only a photo-eye that one of its x edges passes.

    Returns
    -------
    int
        The transitions recorded so far this period.

    """
    new_phase, tau_phase, rigid = moved
    eye_x, blocked = sensors.eye_x, sensors.blocked
    s0, s1, r_i = work.s0, work.s1, work.r_out[i]
    ha = parcels.par[i, P_HALF_A]
    hb = parcels.par[i, P_HALF_B]
    n_eyes = eye_x.shape[0]
    along_x_only = rigid and new_phase == PH_CELL
    for s in range(n_eyes + 2):
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
            motion = Motion(s0, s1, cfg[C_DT])
            work.tr_tau[ntr] = _edge_time(
                s, n_eyes, eye_x, cfg, motion, ha, hb, b1, tau_phase, work.conditions
            )
            work.tr_s[ntr] = s
            work.tr_d[ntr] = 1 if b1 else -1
            ntr += 1
            blocked[i, s] = b1
    return ntr


@kernel_step
def _advance_parcel(i, k, period, setup, parcels, sensors, work, stats, log, counts):
    """
    Advance parcel i over period k: closed form or integrated, then its events and sensors.

    ``period`` is (v, n_strips, disk_sid, same_strips, integrate), the last the cell's
    method (see ``_integrate``); ``counts`` (n_ev, ntr): the events and sensor
    transitions so far. A free or jammed slot does not move.

    Returns
    -------
    (int, int)
        The events and the sensor transitions after it.

    """
    v, _, disk_sid, same_strips, _ = period
    n_ev, ntr = counts
    cfg = setup.cfg
    state, phase, s0, s1 = parcels.state, parcels.phase, work.s0, work.s1
    ph = phase[i]
    work.rigid[i] = False
    if ph == PH_FREE or ph == PH_JAMMED:
        return n_ev, ntr
    for j in range(6):
        s0[j] = state[i, j]
    hx0 = -1.0
    if ph == PH_CELL:
        m = _held_mode(parcels.mode[i], s0, v, work.strips, disk_sid)
        moved, hx0 = _closed_form(i, m, (v, disk_sid, same_strips), setup, parcels, work, stats)
        new_phase = PH_CELL
        if not moved:
            new_phase, n_ev = _integrate(i, k, m, period, setup, parcels, work, stats, log, n_ev)
        for j in range(6):
            s1[j] = state[i, j]
        tau_phase = -1.0
        if new_phase == PH_CELL:
            new_phase, tau_phase, n_ev = _on_cell_events(
                i, k, hx0, cfg, parcels, s0, s1, log, n_ev
            )
    else:
        new_phase, tau_phase, n_ev = _on_chute(i, k, ph, cfg, parcels, s0, s1, log, n_ev)
    moved_how = (new_phase, tau_phase, work.rigid[i])
    ntr = _sensor_changes(i, hx0, moved_how, cfg, parcels, sensors, work, ntr)
    phase[i] = new_phase
    if new_phase == PH_FREE:
        parcels.mode[i] = MODE_SLIDE
    return n_ev, ntr
