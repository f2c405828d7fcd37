"""
The accurate method: Dormand-Prince 5(4) inside a hybrid automaton of slide and stick.

Error-controlled steps with 4th-order dense output, run inside a hybrid automaton of
modes SLIDE / STICK(surface). Mode changes are events located by root finding on the
dense output, not a velocity threshold: stick when a surface's generalized slip
σ = (ẋ - v_sx, ẏ - v_sy, ρ φ̇) reaches zero (its projection on the step-start slip
changes sign, or it settles within the stick tolerance, where the forces decide:
``transitions._small_slip``), break-away when the wrench the stuck surface must
supply leaves its limit set (``stick``), corners crossing strip borders (where the
area functions have kinks, so steps restart there), and the scrap line. While stuck
the motion is rigid translation with the surface, so it is advanced in closed form.
After a break the slip grows through a stiff layer (``layer``).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from sorter_sim.model.core.common import (
    APPROACH_STEPS,
    EV_BORDER,
    EV_BREAK,
    EV_LEAVE,
    EV_STICK,
    EV_TARGET,
    N_EVENTS,
    N_JUMPS,
    N_OUT,
    N_REJECTED,
    N_RHS,
    N_STEPS,
    N_STICK_SCANS,
    ST_END,
    ST_MAX_STEPS,
    ST_NONFINITE,
    ST_STEP_FAIL,
    ST_TARGET,
    STIFF_RATIO,
    _contact_surfaces,
    _corner_event_values,
    _gen_slip,
    _log_event,
    _record,
    _record_new,
    n_surf_of,
    rhs_slide,
    slide_step,
    surface_velocity,
)
from sorter_sim.model.core.dopri import dense, error_norm, step_factor
from sorter_sim.model.core.friction import mu_kinetic, mu_static
from sorter_sim.model.core.jit import allocating, kernel, kernel_step
from sorter_sim.model.core.layout import (
    MODE_SLIDE,
    P_GRAV,
    P_INERTIA,
    P_MASS,
    P_ROTATION,
    S_LAW,
    S_PARAMS,
    S_VX,
    S_VY,
)
from sorter_sim.model.core.stick import _stick_advance
from sorter_sim.model.core.transitions import _break_away, _small_slip
from sorter_sim.model.core.wrench import clip_scratch, rest_surface_wrench


# the sliding loop's per-surface scratch: the generalized slip (sig), its direction and
# size at the step's start (sig0, sig0n), the size below which it settles (s_stiff),
# the contact areas, which surfaces may be stuck to again (armed), a dense-output state
# (yd) and the corners' offsets from the strip borders at the step's ends (ev0, ev1)
SlipScratch = namedtuple(
    'SlipScratch', ['sig', 'sig0', 'sig0n', 's_stiff', 'area', 'armed', 'yd', 'ev0', 'ev1']
)


@kernel
def _slip_scratch(nsurf, nb):
    """Return a ``SlipScratch`` for ``nsurf`` surfaces and ``nb`` strip borders."""
    # After breaking away from a surface its slip starts at zero: re-sticking to it is
    # armed only once the slip has grown past 10 stick tolerances, or the parcel would
    # chatter between stick and slip at the force balance (a Zeno loop).
    return SlipScratch(
        np.empty(3),
        np.empty(nsurf * 3),
        np.empty(nsurf),
        np.zeros(nsurf),
        np.empty(nsurf),
        np.ones(nsurf, dtype=np.bool_),
        np.empty(6),
        np.empty(4 * nb),
        np.empty(4 * nb),
    )


@kernel
def _slip_scales(strips, parcel, y0, rtol, atol):
    """
    Return the stick tolerance [m/s] and a bound on the slip's rate of fall [m/s²].

    The stick tolerance is atol or rtol of the largest speed about (a surface's, the
    start's, at least 1 mm/s). The bound is 1.5 μ_max g: a patch's generalized friction
    over m, sqrt(|F|² + (T/ρ)²)/m, is at most √2 μ g.
    """
    vscale = 0.0
    for k in range(strips.shape[0]):
        vscale = max(vscale, math.hypot(strips[k, S_VX], strips[k, S_VY]))
    vscale = max(vscale, math.hypot(y0[3], y0[4]), 1e-3)
    stick_tol = max(atol, rtol * vscale)
    # a bound on a patch's generalized friction over m, sqrt(|F|² + (T/ρ)²)/m <= √2 μ g
    mu_top = 0.0
    for k in range(strips.shape[0]):
        law = int(strips[k, S_LAW])
        mu_top = max(mu_top, mu_static(law, strips[k, S_PARAMS:]))
        mu_top = max(mu_top, mu_kinetic(law, strips[k, S_PARAMS:], 0.0))
    return stick_tol, 1.5 * mu_top * parcel[P_GRAV]


@kernel
def _stuck_phase(y, mode, span, slide, carry, s_check, sc, out, work):
    """
    Carry a stick on surface ``mode`` in closed form until it ends: target, break or leave.

    The stick holds while the wrench the surface must supply stays in its patch's
    limit set (``stick._stick_advance``). A break-away (reason 2) goes on through the
    slip's stiff layer (``transitions._break_away``) and disarms re-sticking to that
    surface (``sc.armed``); leaving the surface (3) just slides on. ``span`` is (t,
    t_end), ``carry`` (reductions, xi), ``out`` (trail, n_out, ev, n_ev): the trajectory
    and the event log with their counts, ``work`` (stick_counters, rec).

    Returns
    -------
    (float, int, int, int, int)
        The time reached, the mode there, the reason (``_stick_advance``'s: 1 the
        scrap line, 2 a break-away, 3 off the surface), and the records and events.

    """
    t, t_end = span
    reductions, xi = carry
    trail, n_out, ev, n_ev = out
    stick_counters, rec = work
    t, reason = _stick_advance(y, mode, t, t_end, slide, reductions, stick_counters, xi)
    n_out = _record(trail, n_out, t, y, mode)
    if reason == 1:
        n_ev = _log_event(ev, n_ev, t, EV_TARGET, mode)
        return t, mode, reason, n_out, n_ev
    if reason == 2 or reason == 3:
        n_ev = _log_event(ev, n_ev, t, EV_BREAK if reason == 2 else EV_LEAVE, mode)
        broke_from = mode
        mode = MODE_SLIDE
        if reason == 2:
            rec[0] = n_out
            t = _break_away(
                y,
                t,
                t_end,
                slide,
                broke_from,
                0.0,
                s_check,
                stick_counters,
                rec,
                trail,
            )
            sc.armed[broke_from] = False
            n_out = rec[0]
        n_out = _record_new(trail, n_out, t, y, mode)
    return t, mode, reason, n_out, n_ev


@kernel
def _slip_start(y, K, h_try, contact, clip, limits, sc):
    """
    Each surface's generalized slip σ at a step's start, and whether one is to settle.

    Fills sc.area with each surface's contact area (``_contact_surfaces``), and sc.sig0,
    sc.sig0n and sc.s_stiff: σ's direction and size per surface, and the slip below
    which a falling one goes on in ln |σ| (``_small_slip``): once it would reach zero
    within APPROACH_STEPS steps at its rate, or once its direction's stiffness F/(m s)
    binds the step. ``limits`` is (s_check, stiff_ratio, slip_bound).

    Returns
    -------
    (bool, int)
        Whether a slip is below its settling size, and the wrench evaluations taken.

    """
    s_check, stiff_ratio, slip_bound = limits
    sig, sig0, sig0n, s_stiff, area = sc.sig, sc.sig0, sc.sig0n, sc.s_stiff, sc.area
    strips, parcel = contact.strips, contact.parcel
    _contact_surfaces(y, strips, parcel, clip, area)
    rot = parcel[P_ROTATION] > 0.5
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    n_rhs = 0
    small = False
    for s in range(sig0n.shape[0]):
        vsx, vsy = surface_velocity(strips, s)
        sig0n[s] = _gen_slip(y, vsx, vsy, rho, rot, sig)
        for j in range(3):
            sig0[3 * s + j] = sig[j] / sig0n[s] if sig0n[s] > 0.0 else 0.0
        s_stiff[s] = 0.0
        if area[s] <= 0.0 or not sig0n[s] > 0.0:
            continue
        if sig0n[s] < s_check:
            small = True
        else:
            # a falling slip goes on in ln s (``_small_slip``) once it would reach zero
            # within a few steps at its rate, or once its direction's stiffness F/(m s)
            # binds the step (the patch's friction F: evaluated only near that range)
            rate = sig0[3 * s] * K[0, 3] + sig0[3 * s + 1] * K[0, 4]
            rate += sig0[3 * s + 2] * rho * K[0, 5]
            if rate < 0.0:
                s_soon = -APPROACH_STEPS * rate * h_try
                if sig0n[s] < s_soon or sig0n[s] * stiff_ratio < slip_bound * h_try:
                    fx, fy, ft = rest_surface_wrench(
                        y,
                        contact,
                        s,
                        sig0[3 * s],
                        sig0[3 * s + 1],
                        sig0[3 * s + 2] / rho,
                        True,
                        clip,
                    )
                    n_rhs += 1
                    fmag = math.sqrt(fx * fx + fy * fy + (ft / rho) ** 2)
                    # only where that patch's friction is what stops the slip: a slip
                    # that other surfaces slow against it, as in an oscillation between
                    # belts, turns before zero (its fall slows to nothing), and in
                    # ln |slip| such a turn is stiff where in t it is not
                    if -rate * parcel[P_MASS] >= 0.5 * fmag:
                        s_stiff[s] = max(s_soon, fmag * h_try / (stiff_ratio * parcel[P_MASS]))
                small = small or sig0n[s] < s_stiff[s]
    return small, n_rhs


@kernel
def _scrap_and_border_events(y, y_new, K, h, y_target, parcel, borders, sc):
    """
    Find the earliest scrap-line or strip-border crossing inside an accepted step.

    The scrap line y_cog = ``y_target``, and a corner crossing a strip border (a sign
    change of ``_corner_event_values``, where the area functions have kinks), each
    located by bisection to 1e-15 on the step's dense output. sc.ev0 holds the corner
    values at the step's start.

    Returns
    -------
    (float, int, int)
        The step fraction θ of the earliest (2.0: none), its kind (EV_TARGET,
        EV_BORDER, 0) and the border crossed (-1: none).

    """
    ev0, ev1, yd = sc.ev0, sc.ev1, sc.yd
    nb = borders.shape[0]
    theta_ev = 2.0
    ev_kind = 0
    ev_info = -1
    # scrap line
    if y_target < math.inf and y[1] < y_target <= y_new[1]:
        lo = 0.0
        hi = 1.0
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            dense(y, K, h, mid, yd)
            if yd[1] >= y_target:
                hi = mid
            else:
                lo = mid
            if hi - lo < 1e-15:
                break
        theta_ev = hi
        ev_kind = EV_TARGET
    # corners crossing borders
    if nb > 0:
        _corner_event_values(y_new, parcel, borders, ev1)
        for q in range(4 * nb):
            # as ``sign_change``, for every pair: the earliest crossing wins
            if abs(ev0[q]) > 1e-12 and ev0[q] * ev1[q] < 0.0:
                lo = 0.0
                hi = 1.0
                for _ in range(80):
                    mid = 0.5 * (lo + hi)
                    dense(y, K, h, mid, yd)
                    _corner_event_values(yd, parcel, borders, ev1)
                    if ev1[q] * ev0[q] <= 0.0:
                        hi = mid
                    else:
                        lo = mid
                    if hi - lo < 1e-15:
                        break
                if hi < theta_ev:
                    theta_ev = hi
                    ev_kind = EV_BORDER
                    ev_info = q % nb
                _corner_event_values(y_new, parcel, borders, ev1)
    return theta_ev, ev_kind, ev_info


@kernel
def _stick_event(y, y_new, K, h, contact, earliest, stick_tol, sc):
    """
    Find the earliest stick inside an accepted step: a surface's slip σ reaching zero.

    Its projection on the step-start slip changes sign (located by bisection to
    1e-15 on the dense output), or it ends the step within ``stick_tol`` and falling,
    d|σ|²/dt = 2 σ·σ̇ < 0. A surface broken away from re-arms once its slip has
    passed 10 ``stick_tol`` (sc.armed). ``earliest`` is (θ, kind) of the events found
    so far; sc.sig0 and sc.sig0n are ``_slip_start``'s.

    Returns
    -------
    (float, int, int)
        θ, the kind and the surface stuck to (-1: the earlier event stands).

    """
    theta_ev, ev_kind = earliest
    sig, sig0, sig0n, yd, armed, area = sc.sig, sc.sig0, sc.sig0n, sc.yd, sc.armed, sc.area
    strips, parcel = contact.strips, contact.parcel
    rot = parcel[P_ROTATION] > 0.5
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    stick_surf = -1
    for s in range(sig0n.shape[0]):
        if not armed[s]:
            vsx, vsy = surface_velocity(strips, s)
            if _gen_slip(y_new, vsx, vsy, rho, rot, sig) > 10.0 * stick_tol:
                armed[s] = True
            continue
        if area[s] <= 0.0 or sig0n[s] <= 0.0:
            continue
        vsx, vsy = surface_velocity(strips, s)
        n1 = _gen_slip(y_new, vsx, vsy, rho, rot, sig)
        proj1 = sig[0] * sig0[3 * s] + sig[1] * sig0[3 * s + 1] + sig[2] * sig0[3 * s + 2]
        # falling towards zero: d|σ|²/dt = 2 σ·σ̇ < 0 at the step end
        falling = (sig[0] * K[6, 3] + sig[1] * K[6, 4] + sig[2] * rho * K[6, 5]) < 0.0
        th = 2.0
        if proj1 <= 0.0:
            lo = 0.0
            hi = 1.0
            for _ in range(80):
                mid = 0.5 * (lo + hi)
                dense(y, K, h, mid, yd)
                _gen_slip(yd, vsx, vsy, rho, rot, sig)
                pr = sig[0] * sig0[3 * s] + sig[1] * sig0[3 * s + 1] + sig[2] * sig0[3 * s + 2]
                if pr <= 0.0:
                    hi = mid
                else:
                    lo = mid
                if hi - lo < 1e-15:
                    break
            th = hi
        elif n1 <= stick_tol and falling:
            th = 1.0
        if th < theta_ev or (th == theta_ev and th <= 1.0 and ev_kind != EV_TARGET):
            theta_ev = th
            ev_kind = EV_STICK
            stick_surf = s
    return theta_ev, ev_kind, stick_surf


@kernel
def _step_events(y, y_new, K, h, slide, stick_tol, sc):
    """
    Find the earliest event inside an accepted step (t, t + h]: scrap line, border, stick.

    ``_scrap_and_border_events`` then ``_stick_event``; a stick at the same θ as a
    border crossing wins, one at the scrap line's does not.

    Returns
    -------
    (float, int, int)
        The step fraction θ (2.0: none), the kind (0: none) and its border or surface.

    """
    contact = slide.contact
    theta_ev, ev_kind, ev_info = _scrap_and_border_events(
        y, y_new, K, h, slide.y_target, contact.parcel, slide.borders, sc
    )
    theta_ev, ev_kind, stick_surf = _stick_event(
        y, y_new, K, h, contact, (theta_ev, ev_kind), stick_tol, sc
    )
    if ev_kind == EV_STICK:
        ev_info = stick_surf
    return theta_ev, ev_kind, ev_info


@kernel
def _count(counters, n_steps, n_rhs, n_rej, n_out, n_ev, stick_counters):
    """Write a run's counters (``common.N_*``); the closed-form stick's scans count as rhs."""
    counters[N_STEPS] = n_steps
    counters[N_RHS] = n_rhs + stick_counters[0]
    counters[N_REJECTED] = n_rej
    counters[N_OUT] = n_out
    counters[N_EVENTS] = n_ev
    counters[N_JUMPS] = stick_counters[1]
    counters[N_STICK_SCANS] = stick_counters[0]


@kernel
def _settle_small_slip(y, t, t_end, slide, s_check, sc, out, work):
    """
    Settle a slip below its settling size: stick, or carry it on in ln |σ|.

    ``transitions._small_slip`` lets the forces decide (a stick where the limit set
    holds the wrench, else the approach or the layer in ln |σ|), below ``s_check`` or
    sc.s_stiff. ``out`` is (trail, n_out, ev, n_ev), ``work`` (stick_counters, rec).

    Returns
    -------
    (float, int, int, int)
        The time reached, the mode there (MODE_SLIDE unless stuck), and the records
        and events.

    """
    trail, n_out, ev, n_ev = out
    stick_counters, rec = work
    rec[0] = n_out
    t_new, s_act, stuck = _small_slip(
        y, t, t_end, slide, s_check, sc.s_stiff, stick_counters, rec, trail
    )
    n_out = rec[0]
    if stuck:
        n_ev = _log_event(ev, n_ev, t_new, EV_STICK, s_act)
        n_out = _record(trail, n_out, t_new, y, s_act)
        return t_new, s_act, n_out, n_ev
    if t_new > t:
        n_out = _record_new(trail, n_out, t_new, y, MODE_SLIDE)
    return t_new, MODE_SLIDE, n_out, n_ev


@kernel
def _land_event(y, t, kind, surf, contact, stick_tol, sig, ev, n_ev):
    """
    Act on a border crossing or a stick that ends a sliding step at time t.

    A border crossing (``kind`` EV_BORDER, ``surf`` the border) is only logged: the
    step ended there so that the next starts on the far side of the area functions'
    kink. A stick (EV_STICK) on ``surf`` holds if the slip there is within 100
    ``stick_tol`` of zero: the velocity snaps to the surface's (the mode becomes
    ``surf``); else the event was a turn of the slip, not a stop, and the parcel
    slides on. ``sig`` is scratch.

    Returns
    -------
    (int, int)
        The mode (``surf`` or MODE_SLIDE) and the events.

    """
    if kind == EV_BORDER:
        return MODE_SLIDE, _log_event(ev, n_ev, t, EV_BORDER, surf)
    if kind != EV_STICK:
        return MODE_SLIDE, n_ev
    parcel = contact.parcel
    rot = parcel[P_ROTATION] > 0.5
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    vsx, vsy = surface_velocity(contact.strips, surf)
    n1 = _gen_slip(y, vsx, vsy, rho, rot, sig)
    if n1 <= 100.0 * stick_tol:
        n_ev = _log_event(ev, n_ev, t, EV_STICK, surf)
        y[3] = vsx
        y[4] = vsy
        y[5] = 0.0
        return surf, n_ev
    return MODE_SLIDE, n_ev


# The automaton's loop keeps its dozen counters and its step size in locals that numba
# holds in registers; its phases (stick, settling, a step, its events) are the steps
# above, and what is left is their order.
@allocating
def run_accurate(y0, mode0, t0, t_end, slide, reductions, trail, log, xi):  # noqa: PLR0915 — the loop's state stays local
    """
    Integrate the hybrid model from y0 by event-located Dormand-Prince steps.

    Parameters
    ----------
    y0 : ndarray, shape (6,)
        The start (``layout``'s state vector).
    mode0 : int
        The start's mode: MODE_SLIDE, or the surface it is stuck to.
    t0, t_end : float
        The span [s].
    slide : Slide
        The problem: the scrap line, the contact, its surfaces, the strip borders, the
        tolerances and the longest step.
    reductions : bool
        Closed-form sticks and the exact constant-μ wrench where they apply.
    trail : Trail
        Receives the trajectory (t, state, mode), a record per step.
    log : Log
        Receives the events (t, kind, info) and the counters (``common.N_*``).
    xi : ndarray, shape (GAUGE_CARRY,), in/out
        The limit-set gauge's twist of a stick and its Newton metric, a warm start
        carried from call to call (the cell integrates a parcel period by period and
        keeps each one's); zeros: none. The result does not depend on it beyond
        rounding.

    Returns
    -------
    (int, float, int)
        The status (``common.ST_*``), the time reached and the mode there; the final
        state is the trajectory's last record.

    """
    ev, counters = log.ev, log.counters
    contact, borders = slide.contact, slide.borders
    rtol, atol, h_max = slide.rtol, slide.atol, slide.h_max
    ts = trail.ts
    strips, parcel = contact.strips, contact.parcel
    nsurf = n_surf_of(strips)
    y = y0.copy()
    t = t0
    mode = mode0
    n_out = _record(trail, 0, t, y, mode)
    n_ev = n_steps = n_rhs = n_rej = 0
    stick_tol, slip_bound = _slip_scales(strips, parcel, y0, rtol, atol)
    K = np.empty((7, 6))
    y_new = np.empty(6)
    err = np.empty(6)
    atol_scale = np.ones(6)  # atol on every component, rtol against its size
    rtol_ref = -np.ones(6)
    sc = _slip_scratch(nsurf, borders.shape[0])
    rec = np.zeros(1, dtype=np.int64)
    clip = clip_scratch()
    slide_ctx = (contact, clip)  # the sliding model's step context
    nb = borders.shape[0]
    stick_counters = np.zeros(2, dtype=np.int64)
    work = (stick_counters, rec)
    h = min(h_max, 1e-3)
    fresh = True
    status = ST_END
    max_out = ts.shape[0]
    # a slip below this is settled by the forces (``_small_slip``): stuck, or a layer
    s_check = 50.0 * stick_tol
    limits = (s_check, STIFF_RATIO * rtol**0.2, slip_bound)
    while t < t_end:
        if n_steps + n_out >= 50 * max_out:
            status = ST_MAX_STEPS
            break
        if mode >= 0:
            t, mode, reason, n_out, n_ev = _stuck_phase(
                y,
                mode,
                (t, t_end),
                slide,
                (reductions, xi),
                s_check,
                sc,
                (trail, n_out, ev, n_ev),
                work,
            )
            if reason == 1:
                status = ST_TARGET
                break
            if reason == 2 or reason == 3:
                fresh = True
            continue
        # ---- sliding: one Dormand-Prince step with event location ----
        if fresh:
            rhs_slide(y, contact, clip, K[0])
            n_rhs += 1
            fresh = False
        small, n_wrench = _slip_start(y, K, min(h, h_max), contact, clip, limits, sc)
        n_rhs += n_wrench
        if small:
            t_new, mode, n_out, n_ev = _settle_small_slip(
                y, t, t_end, slide, s_check, sc, (trail, n_out, ev, n_ev), work
            )
            if mode >= 0 or t_new > t:
                t = t_new
                fresh = True
                continue
        if not np.all(np.isfinite(K[0])):
            status = ST_NONFINITE
            break
        h = min(h, h_max, t_end - t)
        if h <= 1e-14 * max(1.0, abs(t)):
            status = ST_STEP_FAIL
            break
        if nb > 0:
            _corner_event_values(y, parcel, borders, sc.ev0)
        slide_step(y, h, K, slide_ctx, y_new, err)
        n_rhs += 6
        enorm = error_norm(err, y, y_new, rtol, atol, atol_scale, rtol_ref)
        if not enorm <= 1.0:
            # rejected: a non-finite error shrinks the step 5x, a large one as it says
            h *= 0.2 if not np.isfinite(enorm) else step_factor(enorm)
            n_rej += 1
            continue
        # accepted: look for the earliest event inside (t, t + h]
        theta_ev, ev_kind, ev_info = _step_events(y, y_new, K, h, slide, stick_tol, sc)
        h_next = h * step_factor(enorm)
        if theta_ev <= 1.0 and theta_ev < 1.0 - 1e-12:
            # redo the step to the event, so no stage sees past it
            h_next = h
            h = theta_ev * h
            slide_step(y, h, K, slide_ctx, y_new, err)
            n_rhs += 6
        n_steps += 1
        t = t + h
        for j in range(6):
            y[j] = y_new[j]
        for j in range(6):
            K[0, j] = K[6, j]
        if not np.all(np.isfinite(y)):
            status = ST_NONFINITE
            break
        if theta_ev <= 1.0:
            if ev_kind == EV_TARGET:
                n_out = _record(trail, n_out, t, y, mode)
                n_ev = _log_event(ev, n_ev, t, EV_TARGET, -1)
                status = ST_TARGET
                break
            mode, n_ev = _land_event(y, t, ev_kind, ev_info, contact, stick_tol, sc.sig, ev, n_ev)
            fresh = fresh or mode >= 0
        n_out = _record(trail, n_out, t, y, mode)
        # after a step cut at an event, resume with the size the controller had
        h = h_next
    _count(counters, n_steps, n_rhs, n_rej, n_out, n_ev, stick_counters)
    return status, t, mode


@kernel_step
def run_accurate_reduced(y0, mode0, t0, t_end, slide, trail, log, xi):
    """
    ``run_accurate`` with the reductions on, the flag a constant of the compiled code.

    What the cell and the single-parcel runs with their default call: one compiled
    integrator for both (a cold start compiled it once per caller when one passed a
    literal ``True`` and the other a run-time flag), and the constant lets numba fold
    the reductions' branches away (the cell's integrated parcel-periods ran about
    10 us slower each under a run-time flag).
    """
    return run_accurate(y0, mode0, t0, t_end, slide, True, trail, log, xi)
