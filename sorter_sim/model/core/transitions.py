"""
The accurate method's mode changes: breaking away, approaching a stick, tiny slips.

``_break_away`` runs the layer after a stick breaks and hands the state back to the
sliding integration; ``_approach`` carries a falling slip s on in ln s once it would
reach zero within a few steps (explicit steps in t would shrink with s), and stops
at the stick; ``_small_slip`` decides a slip that settled within the stick tolerance
by the forces: stick if the limit set holds, else break away along the pull.
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.core.common import (
    _contact_surfaces,
    _corner_event_values,
    _gen_slip,
    _record,
    rhs_slide,
    surface_velocity,
)
from sorter_sim.model.core.dopri import error_norm, make_step, sign_change, step_factor
from sorter_sim.model.core.jit import borrowing, kernel
from sorter_sim.model.core.layer import _layer
from sorter_sim.model.core.layout import MODE_SLIDE, P_INERTIA, P_MASS, P_ROTATION
from sorter_sim.model.core.stick import GAUGE_CARRY, stick_margin
from sorter_sim.model.core.wrench import clip_scratch


@kernel
def _break_away(
    y,
    t,
    t_end,
    slide,
    surf,
    s0,
    s_floor,
    counters,
    rec,
    trail,
):
    """
    Leave a stick to ``surf`` (s0 = 0), or continue a small slip s0 on it; returns the time.

    ``y`` holds the stuck motion (s0 = 0) or the state s0 into the layer, whose slip
    direction starts the layer's. A stick breaks where the margin crosses zero, so the
    slip's growth rate starts at zero too: the slip starts on the layer (``_layer``),
    whose slow manifold is exact as s -> 0 and good while the turning's stiffness F/(m ṡ)
    is large; once the slip grows at F/m times STIFF_RATIO rtol^(1/5) (F/(20 m) at rtol
    1e-8) it goes on exactly in ln s (``_approach`` with ``grow``), until the full model
    can take over.
    """
    contact = slide.contact
    strips, parcel = contact.strips, contact.parcel
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    rot = parcel[P_ROTATION] > 0.5
    vsx, vsy = surface_velocity(strips, surf)
    z = np.zeros(3)
    if s0 > 0.0:
        _gen_slip(y, vsx, vsy, rho, rot, z)
        for j in range(3):
            z[j] /= s0
    t, healthy = _layer(
        y,
        t,
        t_end,
        slide,
        surf,
        s0,
        z,
        counters,
        True,
        s_floor,
    )
    if healthy:
        t_new, _ = _approach(
            y,
            t,
            t_end,
            slide,
            surf,
            0.0,
            counters,
            rec,
            trail,
            True,
        )
        t = t_new
    return t


@borrowing
def _approach_state(u, s, vsx, vsy, parcel, out):
    """
    Fill ``out`` with the full state at u = (x, y, φ, t, d) and slip s; returns d̂.

    The velocity is the surface's plus s d̂ (generalized: its third component ρ φ̇), as
    ``_layer_state`` builds it for the layer.
    """
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    rot = parcel[P_ROTATION] > 0.5
    dn = math.sqrt(u[4] * u[4] + u[5] * u[5] + u[6] * u[6])
    d0 = u[4] / dn
    d1 = u[5] / dn
    d2 = u[6] / dn if rot else 0.0
    out[0] = u[0]
    out[1] = u[1]
    out[2] = u[2]
    out[3] = vsx + s * d0
    out[4] = vsy + s * d1
    out[5] = s * d2 / rho if rot else 0.0
    return d0, d1, d2


@borrowing
def _approach_rhs(u, s, sgn, contact, clip, vsx, vsy, yv, acc, out):
    """
    Right-hand side of a slip on one surface in τ = sgn ln(s / s_e).

    u = (x, y, φ, t, d): pose, time and the slip's direction d (its norm is ignored);
    s = s_e e^(sgn τ) the slip there (sgn -1: falling to a stick, +1: growing from a
    break-away). With a the full model's generalized acceleration at that motion and
    r = d̂·a the slip's rate, q = sgn r > 0: dt/dτ = s / q, the pose moves at its
    velocity times that, and dd/dτ = (a - r d̂) / q: the direction's turning, which in
    t runs at a rate ~F/(m s), is O(1) per unit of τ. Returns r.
    """
    parcel = contact.parcel
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    rot = parcel[P_ROTATION] > 0.5
    d0, d1, d2 = _approach_state(u, s, vsx, vsy, parcel, yv)
    rhs_slide(yv, contact, clip, acc)
    a2 = rho * acc[5] if rot else 0.0
    r = d0 * acc[3] + d1 * acc[4] + d2 * a2
    q = sgn * r
    dt = s / q if q > 0.0 else 0.0
    out[0] = yv[3] * dt
    out[1] = yv[4] * dt
    out[2] = yv[5] * dt
    out[3] = dt
    if q > 0.0:
        out[4] = (acc[3] - r * d0) / q
        out[5] = (acc[4] - r * d1) / q
        out[6] = (a2 - r * d2) / q
    else:
        out[4] = 0.0
        out[5] = 0.0
        out[6] = 0.0
    return r


@borrowing
def _approach_stage(un, c, h, ctx, out):
    """
    Evaluate ``_approach_rhs`` at a stage of a step in τ; valid while the slip's rate has its sign.

    The stage's slip is s_e e^(sgn (τ + c h)): the step runs in τ, and the slip is
    its known function.
    """
    s_e, sgn, tau, contact, clip, vsx, vsy, yv, acc = ctx
    s = s_e * math.exp(sgn * (tau + c * h))
    ri = _approach_rhs(un, s, sgn, contact, clip, vsx, vsy, yv, acc, out)
    return sgn * ri > 0.0


# one Dormand-Prince step in τ of (x, y, φ, t, d)
_approach_step = make_step(_approach_stage)


@kernel
def _approach(
    y,
    t,
    t_end,
    slide,
    surf,
    s_end,
    counters,
    rec,
    trail,
    grow,
):
    """
    Carry a slip on ``surf`` falling towards zero down to ``s_end``; returns (t, reason).

    A slip s falling to a stick turns its direction at a rate F/(m s): explicit steps
    in t shrink with s, ~30 of them for every decade. In τ = ln(s_e/s) the same motion
    (``_approach_rhs``, the full model, no approximation) is smooth, the direction
    settling exponentially in τ, and the same Dormand-Prince pair under the same
    tolerances crosses the decades in a few steps. With ``grow`` the same carries a slip
    growing from a break-away (started a hair above zero along its limit direction)
    up the decades, until its growth slows to a quarter of its rate at the start
    (reason 2: the full model, no longer stiff, takes over). Below ``s_end`` the rest is taken
    in closed form at the last rate r (Δt = s / -r, the pose moving with the surface
    plus half the slip), an error O(s² Δt) per decade of the direction's change.

    reason: 0 the slip reached zero (``y`` then moves with the surface exactly),
    1 a border crossing or the scrap line is within the next step (``y`` at the last
    accepted point before it, for the full model to locate), 2 the slip's fall slowed
    to a twentieth of its rate at the start (a near balance: in τ the direction's
    turning would grow stiff as F/(m |r|)), 3 t_end.
    counters[0] += right-hand-side evaluations; every accepted step is recorded
    (``_record``, sliding) into ts/ys/ms from rec[0] on, rec[0] the count.
    """
    y_target, contact, borders, rtol, atol = (
        slide.y_target,
        slide.contact,
        slide.borders,
        slide.rtol,
        slide.atol,
    )
    strips, parcel = contact.strips, contact.parcel
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    rot = parcel[P_ROTATION] > 0.5
    vsx, vsy = surface_velocity(strips, surf)
    sig = np.empty(3)
    s_e = _gen_slip(y, vsx, vsy, rho, rot, sig)
    if not s_e > 0.0:
        return t, 2  # no slip to carry: the caller's other means decide
    u = np.array([y[0], y[1], y[2], t, sig[0] / s_e, sig[1] / s_e, sig[2] / s_e])
    un = np.empty(7)
    err = np.empty(7)
    # the pose and the time against their size, the unit direction against 1
    atol_scale, rtol_ref = np.ones(7), np.array([-1.0, -1.0, -1.0, -1.0, 1.0, 1.0, 1.0])
    K = np.empty((7, 7))
    clip = clip_scratch()
    yv = np.empty(6)
    acc = np.empty(6)
    nb = borders.shape[0]
    ev0 = np.empty(4 * nb)
    ev1 = np.empty(4 * nb)
    tau_end = math.inf if grow else (math.log(s_e / s_end) if s_end < s_e else 0.0)
    tau = 0.0
    sgn = 1.0 if grow else -1.0
    r = _approach_rhs(u, s_e, sgn, contact, clip, vsx, vsy, yv, acc, K[0])
    counters[0] += 1
    r_min = (0.25 if grow else 0.05) * abs(r)
    reason = 2 if grow else 0
    h = 0.25
    for _ in range(10000):
        if sgn * r < r_min:
            reason = 2
            break
        if tau >= tau_end:
            break
        h = min(h, tau_end - tau)
        stage = (s_e, sgn, tau, contact, clip, vsx, vsy, yv, acc)
        ok = _approach_step(u, h, K, stage, un, err)
        counters[0] += 6
        en = error_norm(err, u, un, rtol, atol, atol_scale, rtol_ref)
        if not ok or not math.isfinite(en) or en > 1.0:
            h *= 0.25 if not ok or not math.isfinite(en) else step_factor(en)
            if h < 1e-6:
                reason = 2
                break
            continue
        crossed = un[3] > t_end or (y_target < math.inf and u[1] < y_target <= un[1])
        if nb > 0 and not crossed:
            yv[:3] = u[:3]
            _corner_event_values(yv, parcel, borders, ev0)
            yv[:3] = un[:3]
            _corner_event_values(yv, parcel, borders, ev1)
            crossed = sign_change(ev0, ev1) >= 0
        if crossed:
            reason = 1 if un[3] <= t_end else 3
            break
        tau += h
        for j in range(7):
            u[j] = un[j]
        for j in range(7):
            K[0, j] = K[6, j]
        # the FSAL stage is this point's derivative, but r needs the acceleration too
        r = _approach_rhs(
            u,
            s_e * math.exp(sgn * tau),
            sgn,
            contact,
            clip,
            vsx,
            vsy,
            yv,
            acc,
            K[0],
        )
        counters[0] += 1
        rec[0] = _record(trail, rec[0], u[3], yv, MODE_SLIDE)
        h *= step_factor(en)
    t = u[3]
    s = s_e * math.exp(sgn * tau)
    s1 = s
    if reason == 0:
        # the last stretch, s_end -> 0, at the rate reached: the slip falls linearly
        # (to t_end, if that comes first)
        dt = s / -r
        if t + dt > t_end:
            dt = t_end - t
            s1 = s + r * dt
            reason = 3
        else:
            s1 = 0.0
        # the pose moves at the stretch's mean velocity (the slip linear in time)
        _approach_state(u, 0.5 * (s + s1), vsx, vsy, parcel, y)
        for j in range(3):
            u[j] += y[3 + j] * dt
        t += dt
    _approach_state(u, s1, vsx, vsy, parcel, y)
    return t, reason


@kernel
def _small_slip(
    y,
    t,
    t_end,
    slide,
    s_check,
    s_stiff,
    counters,
    rec,
    trail,
):
    """
    Settle a surface whose slip is small: stick to it, or carry the slip on its layer.

    Near zero slip the kinetic friction's direction turns at a rate F/(m |slip|): an
    explicit step there settles into a chatter of |slip| ~ μ g h that neither falls
    to zero nor grows (a stall of steps ~1e-10 s), and a slip falling to zero makes
    the steps shrink with it. The slip's fate at this pose is decided by the forces,
    not by a band: below ``s_check`` (the stick tolerance's scale), if the wrench the
    surface must supply to carry the parcel lies in its limit set (``stick_margin``
    <= 0) the parcel sticks (the slip, below the stick tolerances, is dropped). A
    falling slip below ``s_stiff[surface]`` (where its direction's stiffness binds the
    explicit step) is carried down in the logarithm of the slip (``_approach``) to
    zero, where the margin decides: stick, or break away from there; it stops short
    where the slip's fall slows to a twentieth of its rate at the start (a near
    balance, left to the full model). Below ``s_check`` a slip
    the surface cannot hold goes on along its layer (``_break_away`` with s0). Also
    resumes a layer a run starts inside (an earlier run, as the cell integrates period
    by period, ended there).

    Returns (t, surf, stuck): the new time, the surface acted on (-1 none) and
    whether the parcel now sticks to it (``y`` then carries the stuck motion).
    """
    contact, nsurf = slide.contact, slide.nsurf
    strips, parcel = contact.strips, contact.parcel
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    rot = parcel[P_ROTATION] > 0.5
    area = np.empty(nsurf)
    clip = clip_scratch()
    sig = np.empty(3)
    xi = np.zeros(GAUGE_CARRY)
    _contact_surfaces(y, strips, parcel, clip, area)
    for s in range(nsurf):
        if area[s] <= 0.0:
            continue
        vsx, vsy = surface_velocity(strips, s)
        n = _gen_slip(y, vsx, vsy, rho, rot, sig)
        if n == 0.0 or (n >= s_check and n >= s_stiff[s]):
            continue
        stuck = y.copy()
        stuck[3] = vsx
        stuck[4] = vsy
        stuck[5] = 0.0
        if n < s_check:
            m, _, _, _, _ = stick_margin(stuck, contact, nsurf, s, xi)
            counters[0] += 1
            if m <= 0.0:
                for j in range(6):
                    y[j] = stuck[j]
                return t, s, True
        yl = y.copy()
        if n >= s_check:
            t_new, reason = _approach(
                yl,
                t,
                t_end,
                slide,
                s,
                s_check,
                counters,
                rec,
                trail,
                False,
            )
            if reason != 0:
                # stopped short of zero: an event ahead, t_end, or a near balance, where
                # the full model's steps are not bound by the direction (it falls slower
                # than the patch could stop it) and take over
                for j in range(6):
                    y[j] = yl[j]
                return t_new, (s if t_new > t else -1), False
            at_zero = True
        else:
            t_new = _break_away(
                yl,
                t,
                t_end,
                slide,
                s,
                n,
                s_check,
                counters,
                rec,
                trail,
            )
            if not t_new > t:
                continue
            at_zero = _gen_slip(yl, vsx, vsy, rho, rot, sig) == 0.0 and t_new < t_end
        for j in range(6):
            y[j] = yl[j]
        if at_zero:
            # the slip reached zero: the limit set decides, stick or break away from there
            m, _, _, _, _ = stick_margin(y, contact, nsurf, s, xi)
            counters[0] += 1
            if m <= 0.0:
                return t_new, s, True
            t_new = _break_away(
                y,
                t_new,
                t_end,
                slide,
                s,
                0.0,
                s_check,
                counters,
                rec,
                trail,
            )
        return t_new, s, False
    return t, -1, False
