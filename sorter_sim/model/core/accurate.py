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

import numpy as np
from numba import njit

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


@njit(cache=True)
def run_accurate(
    y0,
    mode0,
    t0,
    t_end,
    slide,
    reductions,
    trail,
    log,
    xi,
):
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
    y_target, contact, borders, rtol, atol, h_max = (
        slide.y_target,
        slide.contact,
        slide.borders,
        slide.rtol,
        slide.atol,
        slide.h_max,
    )
    ts = trail.ts
    strips, parcel = contact.strips, contact.parcel
    nsurf = n_surf_of(strips)
    rot = parcel[P_ROTATION] > 0.5
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    y = y0.copy()
    t = t0
    mode = mode0
    n_out = _record(trail, 0, t, y, mode)
    n_ev = 0
    n_steps = 0
    n_rhs = 0
    n_rej = 0
    vscale = 0.0
    for k in range(strips.shape[0]):
        vscale = max(vscale, math.hypot(strips[k, S_VX], strips[k, S_VY]))
    vscale = max(vscale, math.hypot(y0[3], y0[4]), 1e-3)
    stick_tol = max(atol, rtol * vscale)
    K = np.empty((7, 6))
    y_new = np.empty(6)
    err = np.empty(6)
    atol_scale = np.ones(6)  # atol on every component, rtol against its size
    rtol_ref = -np.ones(6)
    yd = np.empty(6)
    sig = np.empty(3)
    sig0 = np.empty(nsurf * 3)
    sig0n = np.empty(nsurf)
    s_stiff = np.zeros(nsurf)
    rec = np.zeros(1, dtype=np.int64)
    area = np.empty(nsurf)
    clip = clip_scratch()
    slide_ctx = (contact, clip)  # the sliding model's step context
    nb = borders.shape[0]
    ev0 = np.empty(4 * nb)
    ev1 = np.empty(4 * nb)
    stick_counters = np.zeros(2, dtype=np.int64)
    # After breaking away from a surface its slip starts at zero: re-sticking to it is
    # armed only once the slip has grown past 10 stick tolerances, or the parcel would
    # chatter between stick and slip at the force balance (a Zeno loop).
    armed = np.ones(nsurf, dtype=np.bool_)
    h = min(h_max, 1e-3)
    fresh = True
    status = ST_END
    max_out = ts.shape[0]
    # a slip below this is settled by the forces (``_small_slip``): stuck, or a layer
    s_check = 50.0 * stick_tol
    # a bound on a patch's generalized friction over m, sqrt(|F|² + (T/ρ)²)/m <= √2 μ g
    mu_top = 0.0
    for k in range(strips.shape[0]):
        law = int(strips[k, S_LAW])
        mu_top = max(mu_top, mu_static(law, strips[k, S_PARAMS:]))
        mu_top = max(mu_top, mu_kinetic(law, strips[k, S_PARAMS:], 0.0))
    slip_bound = 1.5 * mu_top * parcel[P_GRAV]
    stiff_ratio = STIFF_RATIO * rtol**0.2
    while t < t_end:
        if n_steps + n_out >= 50 * max_out:
            status = ST_MAX_STEPS
            break
        if mode >= 0:
            t_new, reason = _stick_advance(
                y,
                mode,
                t,
                t_end,
                slide,
                reductions,
                stick_counters,
                xi,
            )
            t = t_new
            n_out = _record(trail, n_out, t, y, mode)
            if reason == 1:
                n_ev = _log_event(ev, n_ev, t, EV_TARGET, mode)
                status = ST_TARGET
                break
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
                    armed[broke_from] = False
                    n_out = rec[0]
                fresh = True
                n_out = _record_new(trail, n_out, t, y, mode)
            continue
        # ---- sliding: one Dormand-Prince step with event location ----
        if fresh:
            rhs_slide(y, contact, clip, K[0])
            n_rhs += 1
            fresh = False
        _contact_surfaces(y, strips, parcel, clip, area)
        small = False
        h_try = min(h, h_max)
        for s in range(nsurf):
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
        if small:
            rec[0] = n_out
            t_new, s_act, stuck = _small_slip(
                y,
                t,
                t_end,
                slide,
                s_check,
                s_stiff,
                stick_counters,
                rec,
                trail,
            )
            n_out = rec[0]
            if stuck:
                t = t_new
                n_ev = _log_event(ev, n_ev, t, EV_STICK, s_act)
                mode = s_act
                fresh = True
                n_out = _record(trail, n_out, t, y, mode)
                continue
            if t_new > t:
                t = t_new
                fresh = True
                n_out = _record_new(trail, n_out, t, y, mode)
                continue
        if not np.all(np.isfinite(K[0])):
            status = ST_NONFINITE
            break
        h = min(h, h_max, t_end - t)
        if h <= 1e-14 * max(1.0, abs(t)):
            status = ST_STEP_FAIL
            break
        if nb > 0:
            _corner_event_values(y, parcel, borders, ev0)
        slide_step(y, h, K, slide_ctx, y_new, err)
        n_rhs += 6
        enorm = error_norm(err, y, y_new, rtol, atol, atol_scale, rtol_ref)
        if not np.isfinite(enorm):
            h *= 0.2
            n_rej += 1
            continue
        if enorm > 1.0:
            h *= step_factor(enorm)
            n_rej += 1
            continue
        # accepted: look for the earliest event inside (t, t + h]
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
        # slip of a surface reaching zero
        stick_surf = -1
        for s in range(nsurf):
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
            if ev_kind == EV_BORDER:
                n_ev = _log_event(ev, n_ev, t, EV_BORDER, ev_info)
            if ev_kind == EV_STICK:
                vsx, vsy = surface_velocity(strips, stick_surf)
                n1 = _gen_slip(y, vsx, vsy, rho, rot, sig)
                if n1 <= 100.0 * stick_tol:
                    n_ev = _log_event(ev, n_ev, t, EV_STICK, stick_surf)
                    mode = stick_surf
                    y[3] = vsx
                    y[4] = vsy
                    y[5] = 0.0
                    fresh = True
        n_out = _record(trail, n_out, t, y, mode)
        # after a step cut at an event, resume with the size the controller had
        h = h_next
    counters[N_STEPS] = n_steps
    counters[N_RHS] = n_rhs + stick_counters[0]
    counters[N_REJECTED] = n_rej
    counters[N_OUT] = n_out
    counters[N_EVENTS] = n_ev
    counters[N_JUMPS] = stick_counters[1]
    counters[N_STICK_SCANS] = stick_counters[0]
    return status, t, mode
