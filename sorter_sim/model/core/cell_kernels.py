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

The rows and bundles the kernels exchange with the runtime are in ``cell_layout``,
what a sensor or a wall observes of a footprint in ``cell_sensing``, and one
parcel's period in ``cell_parcel``; this module re-exports what the runtime uses.

Units: SI (m, s, rad, kg); sensor edge offsets tau in s from the period start.
"""

from __future__ import annotations

import math

from sorter_sim.model.core.cell_layout import (
    A_ALPHA,
    A_ALPHA_CMD,
    A_ALPHA_DOT,
    A_BELT_ON,
    A_STROKE,
    A_STROKE_DOT,
    A_STROKE_TARGET,
    ACT_WIDTH,
    C_ALPHA_RATE,
    C_ATOL,
    C_B,
    C_CONTACT,
    C_DT,
    C_EXIT_X,
    C_HALF_W,
    C_JAM_TIME,
    C_LAW_A,
    C_LAW_B,
    C_METHOD,
    C_MU_PARCEL,
    C_MU_WALL,
    C_OPEN_HI,
    C_OPEN_LO,
    C_RESTITUTION,
    C_RTOL,
    C_SCAN_X,
    C_STROKE_RATE,
    C_V,
    CFG_WIDTH,
    CONTACT_TOL,
    EV_EDGE,
    EV_JAM,
    EV_LEFT,
    EV_RIGHT,
    EV_SCAN,
    EV_STRAIGHT,
    F_XMAX,
    MAX_STRIPS,
    MODE_BELT,
    MODE_DISKS,
    MODE_SLIDE,
    PH_CELL,
    PH_FREE,
    PH_JAMMED,
    CellSetup,
    EventLog,
    Memo,
    Motion,
    Parcels,
    Sensors,
)
from sorter_sim.model.core.cell_parcel import (
    _advance_parcel,
    _cell_work,
    _emit,
    _integrate_accurate,
    _integrate_implicit,
    _jam,
)
from sorter_sim.model.core.cell_sensing import (
    cell_snapshot,
    crosses_wall,
    crossing_time,
    rectangles_overlap,
    sensor_blocked,
    upstream_room,
)
from sorter_sim.model.core.contact import (
    H_BY,
    H_CLOCK,
    OB_KIND,
    N_OLD,
    N_QUIET,
    OBK_WALL,
    contact_step,
    hold_clocks,
    keep_start,
    quiet_movers,
    quiet_slot,
)
from sorter_sim.model.core.common import N_OUT, N_RHS, N_STEPS, ST_END, ST_TARGET
from sorter_sim.model.core.jit import borrowing, kernel, kernel_step
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
)


@kernel
def _isclose(a, b):
    # math.isclose(a, b, abs_tol=1e-15), as simulate.strip_array merges surfaces
    return abs(a - b) <= max(1e-9 * max(abs(a), abs(b)), 1e-15)


@kernel
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


@kernel
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


@kernel
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


@kernel_step
def _period_strips(k, v, act, setup, strips, memo):
    """
    Make the strips of period k (belt speed ``v``); say if they are the last period's.

    α and the stroke at the period's midpoint, each slewing toward its command at its
    rate (``toward``), give the strips (``cell_strips``), written into ``strips`` and
    remembered in ``memo`` for the next period.

    Returns
    -------
    (int, int, bool)
        The number of strips, the disks' surface id (``cell_strips``) and whether
        period k - 1 had the very same strips.

    """
    cfg, laws = setup.cfg, setup.laws
    last_strips, last_info = memo.last_strips, memo.last_info
    h = cfg[C_DT]
    a_mid = toward(act[A_ALPHA], act[A_ALPHA_CMD], 0.5 * (cfg[C_ALPHA_RATE] * h))
    st_mid = toward(act[A_STROKE], act[A_STROKE_TARGET], 0.5 * (cfg[C_STROKE_RATE] * h))
    n_strips, disk_sid = cell_strips(
        v, a_mid, cfg[C_B], st_mid, int(cfg[C_LAW_A]), laws[0], int(cfg[C_LAW_B]), laws[1], strips
    )
    same_strips = last_info[0] == k - 1 and last_info[1] == n_strips
    for q in range(n_strips):
        for j in range(STRIP_WIDTH):
            same_strips = same_strips and strips[q, j] == last_strips[q, j]
            last_strips[q, j] = strips[q, j]
    last_info[0] = k
    last_info[1] = n_strips
    return n_strips, disk_sid, same_strips


@kernel_step
def _parcel_jams(k, h, parcels, work, log, n_ev):
    """
    Jam the parcels that overlap after the period (separating-axis test, ``rectangles_overlap``).

    Only pairs that moved relative to each other: a parcel moved rigidly with the belt
    keeps its distance to every other such parcel, so a check starts only from a
    parcel that did not (integrated, or jammed and standing while the belt carries the
    others on). Both parcels of an overlapping pair on the cell jam (EV_JAM, b = the
    other slot).
    """
    state, phase, par = parcels.state, parcels.phase, parcels.par
    rigid, r_out = work.rigid, work.r_out
    cap = state.shape[0]
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
            if abs(state[i, 0] - state[j, 0]) >= reach or abs(state[i, 1] - state[j, 1]) >= reach:
                continue
            if rectangles_overlap(
                state[i], ha_i, hb_i, state[j], par[j, P_HALF_A], par[j, P_HALF_B], CONTACT_TOL
            ):
                for q, other in ((i, j), (j, i)):
                    if phase[q] == PH_CELL:
                        n_ev = _jam(q, other, k, h, parcels, log, n_ev)
    return n_ev


@kernel_step
def _wall_jams(k, cfg, parcels, work, log, n_ev):
    """Jam the parcels that cross a side wall outside the chute openings (EV_JAM, b = -1)."""
    state, phase, par = parcels.state, parcels.phase, parcels.par
    for i in range(state.shape[0]):
        if phase[i] != PH_CELL or work.rigid[i]:
            continue
        if crosses_wall(
            state[i],
            par[i, P_HALF_A],
            par[i, P_HALF_B],
            cfg[C_HALF_W],
            cfg[C_OPEN_LO],
            cfg[C_OPEN_HI],
            CONTACT_TOL,
        ):
            n_ev = _jam(i, -1, k, cfg[C_DT], parcels, log, n_ev)
    return n_ev


@kernel_step
def _replay_floor(k, period, setup, parcels, work, contacts, stats, log, n_ev):
    """
    Contact: rigid. Give each parcel struck this period its floor friction since the touch.

    The contact step applied an impact's impulse at the period's end and moved the
    bodies as if it had acted at the touch, t_o earlier (``contact.impact``); the
    floor friction over t_o is that of the old velocity. Each struck parcel is taken
    back to the touch along its new velocity and integrated over t_o by the cell's
    method from sliding: a parcel at rest that is struck slides from the touch on.
    """
    state, impact, ct_i = parcels.state, contacts.impact, contacts.ct_i
    s0, ys, counters = work.s0, work.ys, work.counters
    for c in range(contacts.counts[0]):
        for e in range(2):
            i = ct_i[c, e]
            if i < 0 or impact[i] <= 0.0:
                continue
            t_o = impact[i]
            impact[i] = 0.0
            for j in range(3):
                s0[j] = state[i, j] - t_o * state[i, j + 3]
                s0[j + 3] = state[i, j + 3]
            counters[:] = 0
            status, m_new = period[4](
                i, MODE_SLIDE, period[1], setup, parcels, work, counters, t_o
            )
            stats[2] += counters[N_STEPS]
            stats[3] += counters[N_RHS]
            last = counters[N_OUT] - 1
            if (status != ST_END and status != ST_TARGET) or not 0 <= last < ys.shape[0]:
                n_ev = _jam(i, -2, k, setup.cfg[C_DT], parcels, log, n_ev)
                continue
            for j in range(6):
                state[i, j] = ys[last, j]
            parcels.mode[i] = m_new
    return n_ev


@kernel_step
def _contact_jams(k, cfg, parcels, contacts, log, n_ev):
    """
    Contact: rigid. Jam the parcels held by contacts without progress for ``jam_time``.

    ``contact.hold_clocks`` keeps each parcel's clock; one that reaches C_JAM_TIME jams
    where it stands (EV_JAM, b = the parcel that holds it, -1 a side wall, -3 a rail).
    """
    phase, hold, obs = parcels.phase, contacts.hold, contacts.obstacles
    hold_clocks(cfg[C_DT], parcels.state, phase, PH_CELL, contacts)
    for i in range(phase.shape[0]):
        if phase[i] != PH_CELL or hold[i, H_CLOCK] < cfg[C_JAM_TIME] * (1.0 - 1e-12):
            continue
        by = int(hold[i, H_BY])
        if by < 0:
            by = -1 if obs[-1 - by, OB_KIND] == OBK_WALL else -3
        n_ev = _jam(i, by, k, cfg[C_DT], parcels, log, n_ev)
    return n_ev


@kernel_step
def _time_order(tau, n, order):
    """
    Write into ``order[:n]`` the indices of ``tau[:n]`` in increasing order, ties in index order.

    The order of ``np.argsort(tau[:n], kind='mergesort')`` (stable, NaN last), found by
    insertion, in place: a period has a few sensor transitions, and the period's steps
    allocate nothing (``_advance_periods``).
    """
    for q in range(n):
        x = tau[q]
        r = q
        while r > 0:
            y = tau[order[r - 1]]
            if not (x < y or (y != y and x == x)):
                break
            order[r] = order[r - 1]
            r -= 1
        order[r] = q


@kernel_step
def _sensor_edges(k, ntr, work, counts, log, n_ev):
    """
    Emit the sensors' edges over the period: the OR over parcels of its ``ntr`` transitions.

    A sensor rises (EV_EDGE, b = 1) when its first parcel blocks it and falls (b = 0)
    when its last clears it, in time order; ``counts`` holds how many parcels block each.
    """
    order = work.order
    _time_order(work.tr_tau, ntr, order)
    for r in range(ntr):
        q = order[r]
        s = work.tr_s[q]
        before = counts[s]
        counts[s] += work.tr_d[q]
        if before == 0 and counts[s] > 0:
            n_ev = _emit(log.ev_i, log.ev_f, n_ev, k, EV_EDGE, s, 1, work.tr_tau[q], 0.0, 0.0)
        elif before > 0 and counts[s] == 0:
            n_ev = _emit(log.ev_i, log.ev_f, n_ev, k, EV_EDGE, s, 0, work.tr_tau[q], 0.0, 0.0)
    return n_ev


@kernel_step
def _actuators_end(act, cfg):
    """Slew α and the stroke to their end-of-period positions at their rates; record the rates."""
    h = cfg[C_DT]
    a_start = act[A_ALPHA]
    st_start = act[A_STROKE]
    a_end = toward(a_start, act[A_ALPHA_CMD], cfg[C_ALPHA_RATE] * h)
    st_end = toward(st_start, act[A_STROKE_TARGET], cfg[C_STROKE_RATE] * h)
    act[A_ALPHA_DOT] = (a_end - a_start) / h
    act[A_STROKE_DOT] = (st_end - st_start) / h
    act[A_ALPHA] = a_end
    act[A_STROKE] = st_end


def _compiled_for(method: str, function, decorator):
    """
    Compile ``function``, a kernel made for one method, under a name of its own.

    numba names a kernel's cache files after its qualified name, and the factories'
    functions share theirs (``_period_loop.<locals>.advance_periods``); named per method,
    each method's kernel has its own cache files and is compiled or loaded alone.
    """
    function.__name__ = f"{function.__name__}_{method}"
    function.__qualname__ = function.__name__
    return decorator(function)


def _period_loop(accurate: bool):
    """
    Return the period loop with one integration method compiled in.

    ``accurate`` is a constant of the loop's code: numba drops the branch it rules out
    before it types the code, so the loop compiles (and a cold start waits for) one
    integrator and what it calls, not both.
    """

    def advance_periods(n_periods, k0, setup, act, parcels, sensors, log, memo, work, contacts):
        """
        Advance the cell period by period: ``advance_cell``'s loop, with its scratch ``work``.

        Each period: its strips, every parcel's motion, events and sensor transitions,
        the contacts (``contact.contact_step``; the jams of the old rule under
        ``contact: jam``), the sensors' edges, the actuators. Compiled without reference
        counting (``jit.borrowing``) and its steps inlined (``jit.kernel_step``): the
        loop runs for every slot of the cell every period, and counting the references
        of the thirty arrays its steps receive cost more than a parcel's closed-form
        motion; ``advance_cell`` holds the arrays.

        Returns
        -------
        (int, int)
            The periods done and the events written.

        """
        cfg, stats = setup.cfg, memo.stats
        ev_rows, reserve = log.ev_i.shape[0], log.reserve
        n_ev = 0
        done = 0
        for step in range(n_periods):
            k = k0 + step
            v = cfg[C_V] if act[A_BELT_ON] > 0.5 else 0.0
            n_strips, disk_sid, same_strips = _period_strips(k, v, act, setup, work.strips, memo)
            if accurate:
                period = (v, n_strips, disk_sid, same_strips, _integrate_accurate)
            else:
                period = (v, n_strips, disk_sid, same_strips, _integrate_implicit)
            ntr = 0
            rigid_contact = cfg[C_CONTACT] > 0.5
            # quiet (no contact step) only where nothing touched at the last period's
            # end; each slot's part of the check while its row is at hand
            quiet = rigid_contact and contacts.counts[N_OLD] == 0
            n_mov = 0
            codes = (PH_CELL, PH_JAMMED)
            for i in range(parcels.state.shape[0]):
                if rigid_contact and parcels.phase[i] == PH_CELL:
                    keep_start(i, parcels.state, contacts)
                n_ev, ntr = _advance_parcel(
                    i, k, period, setup, parcels, sensors, work, stats, log, (n_ev, ntr)
                )
                if quiet:
                    quiet, n_mov = quiet_slot(
                        i,
                        parcels.state,
                        parcels.phase,
                        parcels.par,
                        work.rigid,
                        codes,
                        contacts,
                        n_mov,
                    )
            if quiet and quiet_movers(
                n_mov, parcels.state, parcels.phase, parcels.par, work.r_out, codes, contacts
            ):
                # nothing in reach, nothing touched last period: no contact step
                contacts.counts[N_QUIET] = 1
            elif rigid_contact:
                contact_step(
                    cfg[C_DT],
                    parcels.state,
                    parcels.phase,
                    parcels.par,
                    work.r_out,
                    codes,
                    (cfg[C_MU_PARCEL], cfg[C_MU_WALL], cfg[C_RESTITUTION]),
                    contacts,
                    work.contact_scratch,
                )
                n_ev = _replay_floor(k, period, setup, parcels, work, contacts, stats, log, n_ev)
                n_ev = _contact_jams(k, cfg, parcels, contacts, log, n_ev)
            else:
                n_ev = _parcel_jams(k, cfg[C_DT], parcels, work, log, n_ev)
                n_ev = _wall_jams(k, cfg, parcels, work, log, n_ev)
            n_ev = _sensor_edges(k, ntr, work, sensors.counts, log, n_ev)
            _actuators_end(act, cfg)
            done += 1
            if ev_rows - n_ev < reserve:
                break
        return done, n_ev

    return _compiled_for("accurate" if accurate else "implicit", advance_periods, borrowing)


_advance_periods_accurate = _period_loop(True)
_advance_periods_implicit = _period_loop(False)


def _cell_kernel(accurate: bool):
    """Return ``advance_cell`` compiled for one method (see ``_period_loop``)."""

    def advance_cell(n_periods, k0, setup, act, parcels, sensors, log, memo, contacts):
        n_sens = sensors.eye_x.shape[0] + 2
        work = _cell_work(parcels.par, n_sens, setup.cfg[C_B])
        if accurate:
            return _advance_periods_accurate(
                n_periods, k0, setup, act, parcels, sensors, log, memo, work, contacts
            )
        return _advance_periods_implicit(
            n_periods, k0, setup, act, parcels, sensors, log, memo, work, contacts
        )

    return _compiled_for("accurate" if accurate else "implicit", advance_cell, kernel)


advance_cell_accurate = _cell_kernel(True)
advance_cell_implicit = _cell_kernel(False)


def advance_cell(n_periods, k0, setup, act, parcels, sensors, log, memo, contacts):
    """
    Advance the cell over up to ``n_periods`` control periods from period index ``k0``.

    Runs the kernel of the cell's method (``cfg[C_METHOD]``): ``advance_cell_accurate``
    or ``advance_cell_implicit``, each compiled with its integrator only.

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
    contacts : Contacts
        The contact step's obstacles and what it keeps from period to period
        (``contact.contacts_for``), updated; used under ``cfg[C_CONTACT]`` = 1 (rigid).

    Returns
    -------
    (int, int)
        The periods done and the events written.

    """
    kernel = advance_cell_accurate if setup.cfg[C_METHOD] < 0.5 else advance_cell_implicit
    return kernel(n_periods, k0, setup, act, parcels, sensors, log, memo, contacts)


# what the runtime and the tests use of the cell (``ck.*``): the layout and the sensing
# kernels are re-exported from their modules
__all__ = [
    "ACT_WIDTH",
    "A_ALPHA",
    "A_ALPHA_CMD",
    "A_ALPHA_DOT",
    "A_BELT_ON",
    "A_STROKE",
    "A_STROKE_DOT",
    "A_STROKE_TARGET",
    "CFG_WIDTH",
    "C_ALPHA_RATE",
    "C_ATOL",
    "C_B",
    "C_DT",
    "C_EXIT_X",
    "C_HALF_W",
    "C_LAW_A",
    "C_LAW_B",
    "C_METHOD",
    "C_OPEN_HI",
    "C_OPEN_LO",
    "C_RTOL",
    "C_SCAN_X",
    "C_STROKE_RATE",
    "C_V",
    "CellSetup",
    "EV_EDGE",
    "EV_JAM",
    "EV_LEFT",
    "EV_RIGHT",
    "EV_SCAN",
    "EV_STRAIGHT",
    "EventLog",
    "F_XMAX",
    "MAX_STRIPS",
    "MODE_BELT",
    "MODE_DISKS",
    "MODE_SLIDE",
    "Memo",
    "Motion",
    "PH_CELL",
    "PH_FREE",
    "PH_JAMMED",
    "Parcels",
    "Sensors",
    "advance_cell",
    "cell_snapshot",
    "cell_strips",
    "crossing_time",
    "rectangles_overlap",
    "sensor_blocked",
    "toward",
    "upstream_room",
]
