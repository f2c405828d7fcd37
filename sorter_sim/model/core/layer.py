"""
The break-away layer: the slip's first, stiff growth after a stick breaks.

After a break the slip grows from zero along the maximal-dissipation direction: the
direction in which the other surfaces' wrench, less what the patch supplies while
slipping, pulls (``_pull_direction``, a Newton solve in the plane). Its growth is a
stiff layer that the full model cannot start from zero slip; it is integrated on
its slow manifold (``_layer``) until the slip is large enough for the accurate
method's Dormand-Prince steps to take over.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from sorter_sim.model.core.common import (
    STIFF_RATIO,
    _corner_event_values,
    rhs_slide,
    surface_velocity,
)
from sorter_sim.model.core.dopri import dense, error_norm, make_step, sign_change, step_factor
from sorter_sim.model.core.jit import borrowing, kernel
from sorter_sim.model.core.layout import P_INERTIA, P_MASS, P_ROTATION
from sorter_sim.model.core.newton import make_plane_newton
from sorter_sim.model.core.stick import limit_gauge
from sorter_sim.model.core.wrench import (
    clip_scratch,
    kinetic_wrench,
    rest_surface_wrench,
    surface_area,
)

# the pull direction after a break, and its Newton metric, carried from solve to solve
Pull = namedtuple('Pull', ['z', 'hess'])


@borrowing
def _kinetic_pull(y, contact, surf, ox, oy, ow, rho, z, clip, out):
    """
    Growth term W_o·σ - D_k(σ) of a unit slip σ (generalized) on ``surf``, and its gradient.

    W_o = (ox, oy, ow): the other surfaces' kinetic wrench at the stuck motion, D_k the
    stuck patch's kinetic dissipation at vanishing slip (μ_k(0), 1-homogeneous in σ).
    ``out`` gets W_o - ∇D_k(σ). Generalized coordinates (x, y, ρφ): the mass matrix is m I.
    """
    fx, fy, ft = rest_surface_wrench(y, contact, surf, z[0], z[1], z[2] / rho, True, clip)
    out[0] = ox + fx
    out[1] = oy + fy
    out[2] = ow + ft / rho
    return out[0] * z[0] + out[1] * z[1] + out[2] * z[2]


@borrowing
def _others_wrench(y, contact, surf, clip):
    """
    Kinetic wrench of every surface but ``surf`` at the state y, generalized (Fx, Fy, T/ρ).

    Returns it and ``surf``'s contact area (0: the parcel has left it).
    """
    strips, parcel = contact.strips, contact.parcel
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    fx, fy, t = kinetic_wrench(y, contact, surf, clip)
    ow = t / rho if parcel[P_ROTATION] > 0.5 else 0.0
    return fx, fy, ow, surface_area(y, strips, parcel, surf, clip)


@borrowing
def _negative_pull(z, ctx, g):
    """Return -f, and -∇f in g, of ``_kinetic_pull`` at the unit slip z (a minimisation)."""
    y, contact, surf, ox, oy, ow, rho, clip = ctx
    f = _kinetic_pull(y, contact, surf, ox, oy, ow, rho, z, clip, g)
    for i in range(3):
        g[i] = -g[i]
    return -f


# the pull direction's maximisation on the unit sphere of slips
_pull_newton = make_plane_newton(_negative_pull, True)


@kernel
def _pull_direction(yp, contact, surf, ox, oy, ow, pull, clip):
    """
    Find the unit slip σ̂ (in ``z``) maximising W_o·σ - D_k(σ), W_o = (ox, oy, ow).

    Returns λ and |∇D_k(σ̂)| [N], the patch's generalized friction there.

    W_o is the other surfaces' generalized kinetic wrench, D_k the patch of ``surf``
    slipping infinitely slowly (μ_k(0), ``rest_surface_wrench``). The maximiser is the
    direction a small slip on ``surf`` settles to (its own acceleration W_o - ∇D_k(σ̂)
    = m λ σ̂ is along it) and λ its growth rate [m/s², generalized; negative: a slip
    there decays, along σ̂, at -λ, as it approaches a stick]: a concave problem,
    solved by Newton's method on the unit sphere (``newton.make_plane_newton``).
    ``z`` carries a start (a zero vector: the limit set's maximal-dissipation twist
    for W_o, else W_o's direction) and returns σ̂.

    ``hess`` (4, in/out) carries the last differenced Hessian, [k + 1 (0: none), h00,
    h01, h11] in the tangent basis built on axis k: a layer solves this at every stage
    of every step, each next to the last, and the carried Hessian starts Newton's method
    there without two gradient differences (it is only Newton's metric: the minimiser
    is where the exact gradient vanishes). It is differenced anew whenever a step with
    it backtracks or fails to cut the gradient tenfold.
    """
    z, hess = pull.z, pull.hess
    parcel = contact.parcel
    mass = parcel[P_MASS]
    rho = math.sqrt(parcel[P_INERTIA] / mass)
    rot = parcel[P_ROTATION] > 0.5
    norm = math.sqrt(ox * ox + oy * oy + ow * ow)
    zn = math.sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
    if norm == 0.0 and zn == 0.0:
        return 0.0, 0.0
    if zn == 0.0 and rot:
        limit_gauge(yp, contact, surf, ox, oy, ow * rho, z, clip)
        zn = math.sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
        if zn > 0.0 and (ox * z[0] + oy * z[1] + ow * z[2]) <= 0.0:
            zn = 0.0
    if not zn > 0.0:
        z[0] = ox / norm
        z[1] = oy / norm
        z[2] = ow / norm
    else:
        for i in range(3):
            z[i] /= zn
    if not rot:
        z[2] = 0.0
        zn = math.hypot(z[0], z[1])
        z[0] /= zn
        z[1] /= zn
    g = np.empty(3)
    ctx = (yp, contact, surf, ox, oy, ow, rho, clip)
    # maximise f: minimise -f (its gradient negated), a concave problem on the sphere
    f0 = _negative_pull(z, ctx, g)
    f = -_pull_newton(z, ctx, z, not rot, norm, hess, f0, g, np.empty((4, 3)))
    # ∇f = W_o - ∇D_k(σ̂) at the final σ̂: |∇D_k| is the patch's friction there
    return f / mass, math.sqrt((-g[0] - ox) ** 2 + (-g[1] - oy) ** 2 + (-g[2] - ow) ** 2)


@borrowing
def _layer_state(u, z, vsx, vsy, parcel, out):
    """
    Fill ``out`` with the full state of the layer state u = (x, y, φ, s); returns s >= 0.

    The velocity is the surface's plus the slip s along the unit generalized direction
    z = σ̂ (its third component ρ φ̇).
    """
    sl = max(u[3], 0.0)
    for j in range(3):
        out[j] = u[j]
    out[3] = vsx + sl * z[0]
    out[4] = vsy + sl * z[1]
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    out[5] = sl * z[2] / rho if parcel[P_ROTATION] > 0.5 else 0.0
    return sl


@kernel
def _layer_rhs(u, contact, clip, surf, vsx, vsy, pull, yv, acc, out):
    """
    Right-hand side of the slip layer on ``surf``: u = (x, y, φ, s), s the slip magnitude.

    On the layer's slow manifold the slip points along σ̂, the direction a small slip
    settles to against the other surfaces' wrench at the current motion
    (``_pull_direction``, warm-started from and returned in ``z``); the pose moves
    with the surface plus s σ̂, and s grows at σ̂·a, a the full model's (generalized)
    acceleration at that motion. ``yv`` gets the full state. Returns the stuck
    patch's friction magnitude |∇D_k| [N] (its stiffness is that over m s).
    """
    z = pull.z
    parcel = contact.parcel
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    sl = _layer_state(u, z, vsx, vsy, parcel, yv)
    ox, oy, ow, _ = _others_wrench(yv, contact, surf, clip)
    lam, fmag = _pull_direction(yv, contact, surf, ox, oy, ow, pull, clip)
    _layer_state(u, z, vsx, vsy, parcel, yv)  # at the settled direction
    rhs_slide(yv, contact, clip, acc)
    out[0] = yv[3]
    out[1] = yv[4]
    out[2] = yv[5]
    if sl > 0.0:
        out[3] = z[0] * acc[3] + z[1] * acc[4] + z[2] * rho * acc[5]
    elif u[3] < 0.0:
        # past zero (a stage of the step in which an approaching slip reaches zero): the
        # rate's continuation, so that the step's interpolant locates the zero smoothly
        out[3] = lam
    else:
        # at zero slip the full model has no friction direction on ``surf`` (it would
        # leave the patch's friction out); the growth is its limit s -> 0+, λ (where λ
        # <= 0 the slip cannot grow: it stays zero)
        out[3] = max(lam, 0.0)
    return fmag


@kernel
def _layer_stage(us, c, h, ctx, out):
    """
    Evaluate ``_layer_rhs`` at a stage of a layer step.

    Each stage starts its pull direction from the step's start (``z``, copied to
    ``zs``), so that the step's end leaves in ``zs`` the direction it settled to there.
    """
    contact, clip, surf, vsx, vsy, z, zs, hess, yv, acc = ctx
    for j in range(3):
        zs[j] = z[j]
    _layer_rhs(us, contact, clip, surf, vsx, vsy, Pull(zs, hess), yv, acc, out)
    return True


# one Dormand-Prince step of the layer's state (x, y, φ, s)
_layer_step = make_step(_layer_stage, allocates=True)


@kernel
def _layer_step_crosses(u, un, y_target, parcel, borders, yv, ev0, ev1):
    """
    Whether a layer step from pose ``u`` to ``un`` crosses the scrap line or a strip border.

    The scrap line is y = ``y_target`` for the centre of gravity; a border crossing is a
    sign change of a corner's offset from a strip border (``_corner_event_values``), where
    the area functions have kinks. Either ends the layer: the full model locates it.
    ``yv``, ``ev0`` and ``ev1`` are scratch.
    """
    crossed = y_target < math.inf and u[1] < y_target <= un[1]
    if borders.shape[0] > 0 and not crossed:
        yv[:3] = u[:3]
        _corner_event_values(yv, parcel, borders, ev0)
        yv[:3] = un[:3]
        _corner_event_values(yv, parcel, borders, ev1)
        crossed = sign_change(ev0, ev1) >= 0
    return crossed


@kernel
def _slip_zero_fraction(u, K, h, us):
    """
    Return the fraction θ of a layer step at which the slip s reaches zero (a stick nears).

    Bisection to 1e-15 on the step's 4th-order dense output, s(t + θ h) = 0; returns the
    upper end, so that the step redone to θ h ends at or just past the zero. ``us`` is
    scratch.
    """
    lo = 0.0
    hi = 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        dense(u, K, h, mid, us)
        if us[3] <= 0.0:
            hi = mid
        else:
            lo = mid
        if hi - lo < 1e-15:
            break
    return hi


@kernel
def _layer(
    y,
    t,
    t_end,
    slide,
    surf,
    s0,
    z,
    counters,
    grow_exit,
    s_floor,
):
    """
    Integrate the slip layer on ``surf`` from slip ``s0`` at time t; returns (t, healthy).

    At a break-away the slip on the stuck surface starts at zero, where kinetic
    friction has no direction: a slip direction off the settled one turns onto it at a
    rate F/(m s), an arbitrarily stiff layer where explicit steps of the full model
    chatter about the direction and the slip hardly grows. On the layer's slow
    manifold (``_layer_rhs``) the direction is slaved to the pose, so the layer is a
    smooth 4-state problem (pose and slip magnitude), integrated here by the same
    Dormand-Prince pair under the same tolerances. It ends, handing over to the full
    model, once the slip has grown so that the full model's step is bound by the
    direction's stiffness only mildly (F h / (m s) <= 10 at the layer's step h), or
    before a corner crosses a strip border or the centre of gravity the scrap line
    (the full model locates those), or at t_end; or where a falling slip reaches zero
    (the zero of the step's interpolant), where the caller decides stick or break-away.
    The same slow manifold carries a slip approaching a stick: there the direction's
    stiffness F/(m s) grows without bound as s -> 0, and explicit steps of the full
    model would shrink with s.

    With ``grow_exit`` it also ends (``healthy``) once the slip grows at F/m times
    STIFF_RATIO rtol^(1/5) (F/(20 m) at rtol 1e-8) or faster: from there the caller
    carries it in ln s, no approximation.

    Neither hand-over comes before the slip reaches ``s_floor``, the slip below which the
    full model hands a slip back (``run_accurate``'s ``s_check``): a slip growing slowly
    in a near balance would otherwise go back and forth between the two, a layer step
    of the smallest size at a time.

    ``y`` (in: the pose; out: the full state at the end, velocity = surface + s σ̂),
    ``z`` (in: a start for σ̂, may be zero; out: σ̂). counters[0] += rhs evaluations.
    """
    y_target, contact, borders, rtol, atol = (
        slide.y_target,
        slide.contact,
        slide.borders,
        slide.rtol,
        slide.atol,
    )
    strips, parcel = contact.strips, contact.parcel
    mass = parcel[P_MASS]
    vsx, vsy = surface_velocity(strips, surf)
    u = np.array([y[0], y[1], y[2], s0])
    un = np.empty(4)
    us = np.empty(4)
    err = np.empty(4)
    K = np.empty((7, 4))
    yv = np.empty(6)
    acc = np.empty(6)
    zs = z.copy()
    hess = np.zeros(4)  # _pull_direction's Newton metric, carried from stage to stage
    grow_ratio = STIFF_RATIO * rtol**0.2
    clip = clip_scratch()
    stage = (contact, clip, surf, vsx, vsy, z, zs, hess, yv, acc)
    # the slip relative to itself: the trajectory after a break is sensitive to when
    # the slip grows (its growth starts from λ = 0), so an absolute slip error of the
    # full model's velocity scale put Fig. 9a 100 rtol m off; atol 1e-3 x: a floor
    # only where the slip is zero
    atol_scale, rtol_ref = np.array([1.0, 1.0, 1.0, 1e-3]), -np.ones(4)
    nb = borders.shape[0]
    ev0 = np.empty(4 * nb)
    ev1 = np.empty(4 * nb)
    _layer_rhs(u, contact, clip, surf, vsx, vsy, Pull(z, hess), yv, acc, K[0])
    counters[0] += 1
    h = min(1e-5, t_end - t)
    healthy = False
    for _ in range(10000):
        if t >= t_end or h <= 1e-14 * max(1.0, abs(t)):
            break
        h = min(h, t_end - t)
        _layer_step(u, h, K, stage, us, err)
        for j in range(4):
            un[j] = us[j]
        counters[0] += 6
        en = error_norm(err, u, un, rtol, atol, atol_scale, rtol_ref)
        crossed = _layer_step_crosses(u, un, y_target, parcel, borders, yv, ev0, ev1)
        if not math.isfinite(en) or en > 1.0 or crossed:
            h *= 0.25 if (crossed or not math.isfinite(en)) else step_factor(en)
            if crossed and h < 1e-9:
                break  # the event is just ahead: the full model locates it
            continue
        to_zero = un[3] < 0.0 and u[3] > 0.0
        if to_zero:
            # the slip reaches zero inside the step (an approach to a stick): end the
            # layer there, at the zero of the step's interpolant, by redoing the step
            # to it so that no stage sees past it
            h *= _slip_zero_fraction(u, K, h, us)
            _layer_step(u, h, K, stage, us, err)
            for j in range(4):
                un[j] = us[j]
            un[3] = 0.0
            counters[0] += 6
        t += h
        for j in range(4):
            u[j] = un[j]
        for j in range(3):
            z[j] = zs[j]
        for j in range(4):
            K[0, j] = K[6, j]
        fmag = _layer_rhs(u, contact, clip, surf, vsx, vsy, Pull(z, hess), yv, acc, K[0])
        counters[0] += 1
        h *= step_factor(en)
        # hand over once the full model's explicit step would be stiff-bound by the
        # direction only 10x past the layer's own (F h / (m s) = 10): later, the slow
        # manifold's zeroth-order direction costs accuracy (handing over at F h/(m s) = 1
        # put Fig. 9a 3e-7 m off at rtol 1e-8; at 10 and at 50 it converges to the same
        # limit, 4e-9 m off there); earlier, the full model's steps pay for the stiffness
        if to_zero:
            break
        if u[3] < s_floor:
            continue
        if K[0, 3] > 0.0 and u[3] * mass >= 0.1 * fmag * h:
            break
        # growing at F/m times the stiffness ratio STIFF_RATIO rtol^(1/5) (a twentieth
        # at rtol 1e-8, an eighth at 1e-6): on in ln s, exactly (``_approach`` with
        # ``grow``), where the turning's stiffness in ln s, F/(m ṡ), is at most the
        # inverse ratio, the same at which the full model goes over to ln s on the way
        # down (a fixed ratio, tight enough for tight tolerances, wastes evaluations at
        # loose ones)
        if grow_exit and u[3] > 0.0 and K[0, 3] > 0.0 and K[0, 3] * mass >= grow_ratio * fmag:
            healthy = True
            break
    _layer_state(u, z, vsx, vsy, parcel, y)
    return t, healthy
