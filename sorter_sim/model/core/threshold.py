"""
The threshold method: the seed's own model, integrated by classic RK4 at a fixed step.

Eqs. 3.1/4.2/4.4 with the threshold speed v_min: a surface slipping slower than
v_min is "static" and pushes back with at most its limit against the other surfaces'
force, and likewise the moments with φ̇_min = v_min/ρ. Kept for comparison with the
paper and for the error study.
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.core.common import (
    EV_BREAK,
    EV_STICK,
    EV_TARGET,
    N_EVENTS,
    N_OUT,
    N_REJECTED,
    N_RHS,
    N_STEPS,
    ST_END,
    ST_MAX_STEPS,
    ST_NONFINITE,
    ST_TARGET,
    _log_event,
    _record,
    _take_fixed_step,
    n_surf_of,
)
from sorter_sim.model.core.layout import MODE_SLIDE, P_INERTIA, P_MASS, P_ROTATION
from sorter_sim.model.core.wrench import evaluate_surfaces
from sorter_sim.model.core.jit import kernel


# ---------------------------------------------------------------- the seed's threshold model
@kernel
def rhs_threshold(state, contact, nsurf, v_min, out, modes_out):
    """
    Eqs. 4.1/4.2/4.4: kinetic where a surface slips faster than v_min, else static.

    A 'static' surface answers the kinetic pull of the others with at most its limit
    (middle rows of eqs. 4.2 and 4.4); its own kinetic wrench is not applied.
    modes_out[s] = 1 where surface s is static in force.

    Parameters
    ----------
    state : ndarray, shape (6,)
        The state: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.
    contact : Contact
        What the parcel slides on (``layout.Contact``).
    nsurf : int
        The number of surfaces.
    v_min : float
        The threshold speed [m/s] of eq. (3.1).
    out : ndarray, shape (6,)
        Receives the state's time derivative.
    modes_out : ndarray, shape (nsurf,)
        Receives 1 where a surface is static in force.

    """
    parcel = contact.parcel
    kin = np.empty((nsurf, 3))
    stat = np.empty((nsurf, 2))
    area = np.empty(nsurf)
    slip = np.empty(nsurf)
    evaluate_surfaces(state, contact, -2, True, kin, stat, area, slip)
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    om_min = v_min / rho
    rot = parcel[P_ROTATION] > 0.5
    slow = abs(state[5]) <= om_min
    fkx = 0.0
    fky = 0.0
    tk = 0.0
    for s in range(nsurf):
        modes_out[s] = 0
        if area[s] > 0.0 and slip[s] <= v_min:
            modes_out[s] = 1
        else:
            fkx += kin[s, 0]
            fky += kin[s, 1]
    for s in range(nsurf):
        if not slow or not rot:
            tk += kin[s, 2]
        elif modes_out[s] == 0:
            tk += kin[s, 2]
    fx = fkx
    fy = fky
    fn = math.hypot(fkx, fky)
    for s in range(nsurf):
        if modes_out[s] == 1 and fn > 0.0:
            lim = min(stat[s, 0], fn)
            fx -= lim * fkx / fn
            fy -= lim * fky / fn
    t = tk
    if rot and slow:
        t_stat = tk
        for s in range(nsurf):
            if area[s] > 0.0 and modes_out[s] == 1:
                lim = min(stat[s, 1], abs(t_stat))
                t -= lim * (1.0 if t_stat > 0.0 else -1.0) if t_stat != 0.0 else 0.0
    out[0] = state[3]
    out[1] = state[4]
    out[2] = state[5]
    out[3] = fx / parcel[P_MASS]
    out[4] = fy / parcel[P_MASS]
    out[5] = t / parcel[P_INERTIA] if rot else 0.0


@kernel
def run_threshold(
    y0,
    mode0,
    t0,
    t_end,
    y_target,
    contact,
    h,
    v_min,
    trail,
    log,
):
    """
    Integrate the seed's threshold model by classic RK4 at a fixed step.

    Parameters
    ----------
    y0 : ndarray, shape (6,)
        The start.
    mode0 : int
        The start's mode.
    t0, t_end : float
        The span [s].
    y_target : float
        The scrap line [m].
    contact : Contact
        What the parcel slides on.
    h : float
        The step [s].
    v_min : float
        The threshold speed [m/s] of eq. (3.1).
    trail : Trail
        Receives a record per step.
    log : Log
        Receives the events (every change of a surface between static and kinetic) and
        the counters.

    Returns
    -------
    (int, float, int)
        The status, the time reached and the mode there.

    """
    ev, counters = log.ev, log.counters
    ts = trail.ts
    strips = contact.strips
    nsurf = n_surf_of(strips)
    y = y0.copy()
    k1 = np.empty(6)
    k2 = np.empty(6)
    k3 = np.empty(6)
    k4 = np.empty(6)
    yt = np.empty(6)
    y_new = np.empty(6)
    mo = np.zeros(nsurf, dtype=np.int64)
    t = t0
    mode_code = 0 if mode0 < 0 else (1 << mode0)
    rec_mode = mode0
    n_out = _record(trail, 0, t, y, mode0)
    n_ev = 0
    n_steps = 0
    status = ST_END
    n_total = max(1, int(math.ceil((t_end - t0) / h - 1e-9)))
    for i_step in range(n_total):
        t_next = t_end if i_step == n_total - 1 else t0 + (i_step + 1) * h
        hh = t_next - t
        rhs_threshold(y, contact, nsurf, v_min, k1, mo)
        code = 0
        for s in range(nsurf):
            code += mo[s] << s
        for j in range(6):
            yt[j] = y[j] + 0.5 * hh * k1[j]
        rhs_threshold(yt, contact, nsurf, v_min, k2, mo)
        for j in range(6):
            yt[j] = y[j] + 0.5 * hh * k2[j]
        rhs_threshold(yt, contact, nsurf, v_min, k3, mo)
        for j in range(6):
            yt[j] = y[j] + hh * k3[j]
        rhs_threshold(yt, contact, nsurf, v_min, k4, mo)
        for j in range(6):
            y_new[j] = y[j] + hh / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        n_steps += 1
        if code != mode_code:
            n_ev = _log_event(ev, n_ev, t, EV_STICK if code > mode_code else EV_BREAK, code)
            mode_code = code
            # the trajectory's mode: the one 'static' surface, else sliding
            rec_mode = MODE_SLIDE
            for s in range(nsurf):
                if code == (1 << s):
                    rec_mode = s
        if not np.all(np.isfinite(y_new)):
            status = ST_NONFINITE
            break
        t, crossed = _take_fixed_step(y, y_new, t, t_next, y_target)
        n_out = _record(trail, n_out, t, y, rec_mode)
        if crossed:
            n_ev = _log_event(ev, n_ev, t, EV_TARGET, -1)
            status = ST_TARGET
            break
        if n_out >= ts.shape[0]:
            status = ST_MAX_STEPS
            break
    counters[N_STEPS] = n_steps
    counters[N_RHS] = 4 * n_steps
    counters[N_REJECTED] = 0
    counters[N_OUT] = n_out
    counters[N_EVENTS] = n_ev
    return status, t, MODE_SLIDE
