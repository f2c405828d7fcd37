"""
Integrators of the planar parcel model: three methods behind one calling convention.

All three advance one parcel from ``t0`` towards ``t_end`` over a fixed set of
strips and write a trajectory (t, state, mode) into caller-owned arrays, stopping
early at the scrap line y = ``y_target`` (``inf`` for none). They return a status
and counters; ``simulate.py`` wraps them in a result object.

``accurate``  (ACCURATE) Dormand-Prince 5(4) with error control and 4th-order
    dense output, run inside a hybrid automaton of modes SLIDE / STICK(surface).
    Mode changes are events located by root finding on the dense output, not a
    velocity threshold: stick when a surface's generalized slip
    σ = (ẋ - v_sx, ẏ - v_sy, ρ φ̇) reaches zero (its projection on the step-start
    slip changes sign, or it settles within the stick tolerance, where the forces
    decide: ``_small_slip``), break-away when the wrench the stuck surface must supply
    leaves its limit set (exact stick: the convex set of wrenches a rigid patch under
    Coulomb friction can supply, Goyal, Ruina and Papadopoulos 1991, tested by its
    gauge ``limit_gauge``; seed stick: the decoupled limits of eqs. 4.3/4.5), corners
    crossing strip borders (where the area functions have kinks, so steps restart
    there), and the scrap line. While stuck the motion is rigid translation with the
    surface, so it is advanced in closed form; with a single surface under the parcel
    it jumps straight to the next border crossing. After a break the slip grows from
    zero along the maximal-dissipation direction through a stiff layer, integrated on
    its slow manifold (``_layer``) until the full model can take over.

``implicit``  (IMPLICIT) fixed step, backward Euler in velocity. The step
    M (W+ - W)/h = wrench(W+) with set-valued Coulomb friction is the minimiser of
    ½ (W+ - W)ᵀ M (W+ - W)/h + D(W+), D the footprint's dissipation rate, a
    strongly convex problem: one solution for any h, exact sticking (the minimiser
    sits on the kink at a surface's velocity when the limit set holds the wrench),
    no chatter. This is Kikuuwe et al.'s (2005) implicit friction step carried to
    the planar footprint (``implicit_step``). With constant μ, D and its gradient
    come from the exact wrench (no quadrature floor, about two wrench evaluations a
    step); where μ depends on the speed it is lagged one step at the Gauss points of
    the footprint, D = Σ_k c_k |u_k(W+)|. Positions follow with the new velocity
    (symplectic Euler).

``threshold`` (THRESHOLD) the seed's own model: eqs. 3.1/4.2/4.4 with the
    threshold speed v_min (a surface slipping slower than v_min is "static" and
    pushes back with at most its limit against the other surfaces' force, and
    likewise the moments with φ̇_min = v_min/ρ), integrated by classic RK4 at a
    fixed step. Kept for comparison with the paper and for the error study.

Units: SI throughout (m, s, rad, kg, N).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit import borrowing

from .layout import (
    MODE_SLIDE,
    P_HALF_A,
    P_HALF_B,
    P_INERTIA,
    P_MASS,
    P_ROTATION,
    P_STICK,
    S_SURF,
    S_VX,
    S_VY,
    S_WEIGHT,
    S_XHI,
    S_XLO,
    S_LAW,
    S_PARAMS,
    P_GRAV,
)
from .dopri import C, dense, rms_norm, sign_change, stage_state, step_error, step_factor
from .friction import law_is_constant, mu_kinetic, mu_static
from .geometry import MAX_VERTS, box_corners, clip_to_strip, corner_x, polygon_area_centroid
from .wrench import (
    add_slip_curvature,
    clip_scratch,
    kinetic_wrench,
    place_box,
    strip_part,
    surface_area,
    dissipation_hessian,
    evaluate_surfaces,
    rest_surface_wrench,
    static_surface_wrench,
)

METHOD_ACCURATE = 0
METHOD_IMPLICIT = 1
METHOD_THRESHOLD = 2

# status codes
ST_END = 0  # reached t_end
ST_TARGET = 1  # reached the scrap line
ST_MAX_STEPS = 2  # ran out of output capacity / step budget
ST_STEP_FAIL = 3  # step size underflow
ST_NONFINITE = 4  # a NaN or inf appeared

# event kinds in the event log
EV_STICK = 1
EV_BREAK = 2
EV_BORDER = 3
EV_TARGET = 4
EV_LEAVE = 5


@borrowing
def n_surf_of(strips):
    n = 0
    for k in range(strips.shape[0]):
        n = max(n, int(strips[k, S_SURF]) + 1)
    return n


@borrowing
def surface_velocity(strips, surf):
    for k in range(strips.shape[0]):
        if int(strips[k, S_SURF]) == surf:
            return strips[k, S_VX], strips[k, S_VY]
    return 0.0, 0.0


@borrowing
def rhs_slide(state, strips, parcel, nodes, weights, clip, out):
    """
    Time derivative of the state while sliding (eq. 4.1 with kinetic friction).

    ``clip``: a footprint scratch (``wrench.clip_scratch``), so that it allocates nothing.
    """
    fx, fy, t = kinetic_wrench(state, strips, parcel, nodes, weights, -1, clip)
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
STICK_RTOL = 1e-13  # relative: a balance to rounding (a few ulps of the wrench sums) holds
GAUGE_ITERATIONS = 60
# a limit-set gauge's warm start (``limit_gauge``'s xi): its twist, then its Hessian
GAUGE_CARRY = 7
F_NOISE = 1e-13  # relative rounding of a sum of wrench-based dissipations (closed form)
SOLVE_RATIO = 1e-2  # the implicit solve's error bound, relative to how far it moved


@borrowing
def _dissipation_gradient(state, strips, parcel, nodes, weights, surf, rho, z0, z1, z2, clip, out):
    """∇D at the generalized twist (z0, z1, z2) = (ẋ, ẏ, ρφ̇) relative to ``surf``; returns D."""
    fx, fy, ft = static_surface_wrench(
        state, strips, parcel, nodes, weights, surf, z0, z1, z2 / rho, clip
    )
    # the friction wrench is -∇D; D = ξ·∇D by Euler's relation (D is 1-homogeneous)
    out[0] = -fx
    out[1] = -fy
    out[2] = -ft / rho
    return z0 * out[0] + z1 * out[1] + z2 * out[2]


@njit(cache=True)
def limit_gauge(state, strips, parcel, nodes, weights, surf, wx, wy, wt, xi, clip):
    """
    Gauge of the wrench (wx, wy, wt) in the limit set of ``surf``'s patch: <= 1 iff it holds.

    A rigid patch under distributed Coulomb friction can supply exactly the wrenches
    W with W·ξ <= D(ξ) for every twist ξ, D the patch's dissipation rate at μ_s
    (``static_surface_wrench``): a convex set whose support function is D. Its gauge
    is γ(W) = max_ξ W·ξ / D(ξ) = 1 / min {D(ξ) : W·ξ = 1}, the minimum of a convex
    function on a plane. It is found by Newton's method in that plane (generalized
    twists (ẋ, ẏ, ρφ̇)): the gradient is exact (the closed-form wrench), the 2 x 2
    Hessian a forward difference of it, with a backtracking line search on D. At the
    minimiser ξ* the limit-surface point ∇D(ξ*) = W / γ: ξ* is the twist the patch
    slips with when the stick breaks (maximal dissipation). ``xi`` (in/out) carries
    ξ* between calls: a stick scanned along its path starts each solve next to the
    last minimiser. Of GAUGE_CARRY entries, it carries the last differenced Hessian
    too ([k + 1, |ξ| H] in the plane basis built on axis k; D is 1-homogeneous, so H
    scales as 1/|ξ|): Newton's first steps there take no differences, and the Hessian
    is differenced anew where a step with it backtracks or fails to cut the gradient
    tenfold (it is only Newton's metric). ``clip``: a footprint scratch
    (``wrench.clip_scratch``).

    Returns γ (0 for W = 0; inf when the patch supplies no friction at all).
    """
    mass = parcel[P_MASS]
    rho = math.sqrt(parcel[P_INERTIA] / mass)
    w = np.array([wx, wy, wt / rho])
    w2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    if w2 == 0.0:
        return 0.0
    wn = math.sqrt(w2)
    # an orthonormal basis (p, q) of the plane's directions, W⊥
    e = np.zeros(3)
    k = 0
    for i in range(1, 3):
        if abs(w[i]) < abs(w[k]):
            k = i
    e[k] = 1.0
    p = np.empty(3)
    dot = (e[0] * w[0] + e[1] * w[1] + e[2] * w[2]) / w2
    for i in range(3):
        p[i] = e[i] - dot * w[i]
    pn = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    for i in range(3):
        p[i] /= pn
    q = np.array(
        [
            (w[1] * p[2] - w[2] * p[1]) / wn,
            (w[2] * p[0] - w[0] * p[2]) / wn,
            (w[0] * p[1] - w[1] * p[0]) / wn,
        ]
    )
    # start: the carried twist scaled onto the plane, else W itself (W·ξ = 1 both)
    z = np.empty(3)
    wx_ = w[0] * xi[0] + w[1] * xi[1] + w[2] * xi[2]
    if wx_ > 0.0 and math.isfinite(wx_):
        for i in range(3):
            z[i] = xi[i] / wx_
    else:
        for i in range(3):
            z[i] = w[i] / w2
    g = np.empty(3)
    gp = np.empty(3)
    zt = np.empty(3)
    d = _dissipation_gradient(
        state, strips, parcel, nodes, weights, surf, rho, z[0], z[1], z[2], clip, g
    )
    if not d > 0.0:
        return math.inf
    carry = xi.shape[0] >= GAUGE_CARRY
    carried = carry and xi[3] == k + 1.0
    gn_last = math.inf
    step = 1.0
    for _ in range(GAUGE_ITERATIONS):
        # reduced gradient and Hessian in the plane
        g0 = g[0] * p[0] + g[1] * p[1] + g[2] * p[2]
        g1 = g[0] * q[0] + g[1] * q[1] + g[2] * q[2]
        zn = math.sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
        gn = math.hypot(g0, g1)
        # at the minimum the reduced gradient vanishes: ∇D ∥ W, |∇D| ~ D/|ξ|
        if gn <= 1e-14 * d / zn:
            break
        if carried and (step < 1.0 or gn > 0.1 * gn_last):
            carried = False  # the carried metric no longer converges fast: difference
        gn_last = gn
        h00 = 0.0
        h01 = 0.0
        h10 = 0.0
        h11 = 0.0
        if carried:
            h00 = xi[4] / zn
            h01 = xi[5] / zn
            h10 = h01
            h11 = xi[6] / zn
        hstep = 1e-5 * zn
        for j in range(0 if carried else 2):
            # a forward difference of the exact gradient: the Hessian only shapes Newton's
            # step (the minimiser is where the exact gradient vanishes), at half the cost
            for i in range(3):
                dirn = p[i] if j == 0 else q[i]
                zt[i] = z[i] + hstep * dirn
            _dissipation_gradient(
                state, strips, parcel, nodes, weights, surf, rho, zt[0], zt[1], zt[2], clip, gp
            )
            c0 = ((gp[0] - g[0]) * p[0] + (gp[1] - g[1]) * p[1] + (gp[2] - g[2]) * p[2]) / hstep
            c1 = ((gp[0] - g[0]) * q[0] + (gp[1] - g[1]) * q[1] + (gp[2] - g[2]) * q[2]) / hstep
            if j == 0:
                h00 = c0
                h10 = c1
            else:
                h01 = c0
                h11 = c1
        h01 = 0.5 * (h01 + h10)
        if carry and not carried:
            xi[3] = k + 1.0
            xi[4] = h00 * zn
            xi[5] = h01 * zn
            xi[6] = h11 * zn
            carried = True
        det = h00 * h11 - h01 * h01
        if h00 > 0.0 and h11 > 0.0 and det > 1e-12 * h00 * h11:
            s0 = -(h11 * g0 - h01 * g1) / det
            s1 = -(h00 * g1 - h01 * g0) / det
            if -0.5 * (g0 * s0 + g1 * s1) <= 1e-15 * d:
                # Newton's predicted decrease is below D's rounding (the gradient's
                # quadrature is exact only to ~1e-10 of it): no line search can resolve
                # the rest, and γ, stationary here, is exact to second order
                break
        else:
            # not positive definite (rounding near a kink): a gradient step of Newton's scale
            scale = zn * zn / d
            s0 = -scale * g0
            s1 = -scale * g1
        slope = g0 * s0 + g1 * s1
        step = 1.0
        dt_ = d
        for _ls in range(40):
            for i in range(3):
                zt[i] = z[i] + step * (s0 * p[i] + s1 * q[i])
            dt_ = _dissipation_gradient(
                state, strips, parcel, nodes, weights, surf, rho, zt[0], zt[1], zt[2], clip, gp
            )
            if dt_ <= d + 1e-4 * step * slope:
                break
            step *= 0.5
        if not dt_ <= d:
            break  # no descent left at rounding level: z is the minimiser
        moved = step * math.hypot(s0, s1)
        for i in range(3):
            z[i] = zt[i]
            g[i] = gp[i]
        d = dt_
        if moved <= 1e-15 * zn:
            break
    zn = math.sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
    for i in range(3):
        xi[i] = z[i] / zn
    # W·ξ = 1 on the plane; recompute it against drift
    return (w[0] * z[0] + w[1] * z[1] + w[2] * z[2]) / d


@njit(cache=True)
def stick_margin(state, strips, parcel, nodes, weights, nsurf, surf, xi):
    """
    Break-away margin of sticking to ``surf`` at this pose (> 0: the stick breaks).

    Returns (margin, area of surf, Fx, Fy, T of the other surfaces' kinetic wrench).
    ``state`` must carry the stuck velocity (surface velocity, φ̇ = 0), so the stuck
    surface must supply exactly the opposite of the others' wrench. Exact stick
    (``P_STICK``): margin = γ - 1, γ that wrench's gauge in the surface's limit set
    (``limit_gauge``; without rotation φ̇ = 0 is a constraint and the set is the disk
    |F| <= F_max). Seed stick: the decoupled test of eqs. 4.2/4.4, |F| <= F_max and
    |T| <= T_max separately, in force units. ``xi`` (3, or GAUGE_CARRY to carry its
    Newton metric too): the gauge's warm start.
    """
    # a pull equal to the capacity within STICK_RTOL holds: at an exact balance (the
    # disks carrying half the load at the belt's μ, a stroke of 0.5) rounding would
    # otherwise break the stick and make it again at every step, without end
    if parcel[P_ROTATION] > 0.5 and parcel[P_STICK] > 0.5:
        clip = clip_scratch()
        fx, fy, t = kinetic_wrench(state, strips, parcel, nodes, weights, surf, clip)
        a = surface_area(state, strips, parcel, surf, clip)
        if a <= 0.0:
            return (math.inf if fx != 0.0 or fy != 0.0 or t != 0.0 else 0.0), 0.0, fx, fy, t
        gamma = limit_gauge(state, strips, parcel, nodes, weights, surf, fx, fy, t, xi, clip)
        return gamma - (1.0 + STICK_RTOL), a, fx, fy, t
    kin = np.empty((nsurf, 3))
    stat = np.empty((nsurf, 2))
    area = np.empty(nsurf)
    slip = np.empty(nsurf)
    evaluate_surfaces(state, strips, parcel, nodes, weights, surf, True, kin, stat, area, slip)
    fx = 0.0
    fy = 0.0
    t = 0.0
    for s in range(nsurf):
        if s != surf:
            fx += kin[s, 0]
            fy += kin[s, 1]
            t += kin[s, 2]
    margin = math.hypot(fx, fy) - stat[surf, 0] * (1.0 + STICK_RTOL)
    if parcel[P_ROTATION] > 0.5:
        margin = max(margin, abs(t) - stat[surf, 1] * (1.0 + STICK_RTOL))
    return margin, area[surf], fx, fy, t


@borrowing
def _dp_step(y, h, K, strips, parcel, nodes, weights, clip, y_new, err):
    """One Dormand-Prince step of the sliding model; K[0] holds f(y); fills K[1..6], y_new, err."""
    for i in range(1, 6):
        # y_new holds each stage's state until it takes the step's end
        stage_state(y, K, h, i, y_new)
        rhs_slide(y_new, strips, parcel, nodes, weights, clip, K[i])
    stage_state(y, K, h, 6, y_new)
    rhs_slide(y_new, strips, parcel, nodes, weights, clip, K[6])
    step_error(K, h, err)


@borrowing
def _gen_slip(state, vsx, vsy, rho, rot, out):
    out[0] = state[3] - vsx
    out[1] = state[4] - vsy
    out[2] = rho * state[5] if rot else 0.0
    return math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2)


@borrowing
def _record_new(ts, ys, ms, n_out, t, y, mode):
    """``_record``, unless the last record is this one (a slip carried in ln s records it)."""
    last = min(n_out, ts.shape[0]) - 1
    same = n_out > 0 and ts[last] == t and ms[last] == mode
    for j in range(6):
        same = same and ys[last, j] == y[j]
    return n_out if same else _record(ts, ys, ms, n_out, t, y, mode)


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
def _record(ts, ys, ms, n_out, t, y, mode):
    """
    Record (t, y, mode) as record ``n_out``; returns the count.

    Past the arrays' capacity the last slot takes every further record, so it
    always holds the latest state: a run that outgrows its output (the accurate
    method may take many times more steps) still ends on its true final state.
    """
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


@njit(cache=True)
def _margin_at(tt, y0x, y0y, t0, vsx, vsy, ys, strips, parcel, nodes, weights, nsurf, surf, xi):
    """
    Stick margin and contact area on ``surf`` at time tt of a parcel carried from t0.

    The parcel translates rigidly with the surface from (y0x, y0y); ``ys`` (the stuck
    state) gets the pose at tt.
    """
    ys[0] = y0x + vsx * (tt - t0)
    ys[1] = y0y + vsy * (tt - t0)
    m, a, _, _, _ = stick_margin(ys, strips, parcel, nodes, weights, nsurf, surf, xi)
    return m, a


@njit(cache=True)
def _break_time(
    lo,
    hi,
    m_hi,
    y0x,
    y0y,
    t0,
    vsx,
    vsy,
    ys,
    strips,
    parcel,
    nodes,
    weights,
    nsurf,
    surf,
    xi,
    counters,
):
    """
    First time in (lo, hi] where the stick breaks: margin(lo) <= 0 < margin(hi) = m_hi.

    Brent's method (inverse quadratic interpolation safeguarded by bisection, as
    scipy's brentq) to 1e-13 relative in time: the margin is a smooth function of the
    carried pose, so ~8 gauges locate the break where bisection takes ~45. Returns a
    time on the breaking side (margin > 0), within the tolerance of the root.
    """
    fpre, _ = _margin_at(
        lo, y0x, y0y, t0, vsx, vsy, ys, strips, parcel, nodes, weights, nsurf, surf, xi
    )
    counters[0] += 1
    if fpre > 0.0:
        return lo  # broken at the scan's first point already (round-off)
    # scipy's brentq: xcur the best estimate, xblk the far end of the bracket
    xpre = lo
    xcur = hi
    fcur = m_hi
    xblk = xpre
    fblk = fpre
    spre = 0.0
    scur = 0.0
    for _ in range(100):
        # sides by "breaks" (margin > 0) or "holds": a margin of exactly 0 holds, so the
        # search goes on to the first breaking time instead of stopping at the root
        if (fpre > 0.0) != (fcur > 0.0):
            xblk = xpre
            fblk = fpre
            spre = xcur - xpre
            scur = spre
        if abs(fblk) < abs(fcur):
            xpre = xcur
            xcur = xblk
            xblk = xpre
            fpre = fcur
            fcur = fblk
            fblk = fpre
        delta = 0.5e-13 * (1.0 + abs(xcur))
        sbis = 0.5 * (xblk - xcur)
        if abs(sbis) < delta:
            break
        finite = math.isfinite(fcur) and math.isfinite(fpre) and math.isfinite(fblk)
        if finite and abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:
                stry = -fcur * (xcur - xpre) / (fcur - fpre)  # secant
            else:
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            if 2.0 * abs(stry) < min(abs(spre), 3.0 * abs(sbis) - delta):
                spre = scur
                scur = stry
            else:
                spre = sbis
                scur = sbis
        else:
            spre = sbis
            scur = sbis
        xpre = xcur
        fpre = fcur
        xcur += scur if abs(scur) > delta else (delta if sbis > 0.0 else -delta)
        fcur, _ = _margin_at(
            xcur, y0x, y0y, t0, vsx, vsy, ys, strips, parcel, nodes, weights, nsurf, surf, xi
        )
        counters[0] += 1
    # the breaking side of the final bracket, within the tolerance of the root
    return xcur if fcur > 0.0 else xblk


@njit(cache=True)
def _stick_advance(
    y,
    surf,
    t,
    t_end,
    y_target,
    strips,
    parcel,
    nodes,
    weights,
    nsurf,
    borders,
    reductions,
    counters,
    xi,
):
    """
    Advance a parcel stuck to ``surf``; returns (t_new, reason).

    reason: 0 reached t_end, 1 reached the target line, 2 break-away, 3 left the surface.
    ``y`` is updated in place (rigid translation with the surface, φ̇ = 0).
    ``counters``: [n_rhs, closed_form_jumps]. ``xi`` (GAUGE_CARRY, in/out): the limit-set
    gauge's twist and Newton metric, carried along the stick from scan to scan (a warm
    start; zero: none).
    """
    vsx, vsy = surface_velocity(strips, surf)
    y[3] = vsx
    y[4] = vsy
    y[5] = 0.0
    t_stop = t_end
    reason_stop = 0
    if vsy > 0.0 and y_target < math.inf and y[1] < y_target:
        tt = t + (y_target - y[1]) / vsy
        if tt < t_stop:
            t_stop = tt
            reason_stop = 1
    speed = math.hypot(vsx, vsy)
    if speed == 0.0:
        # a stopped surface holds the parcel for good (only the other surfaces could
        # move it, and they are checked at the start)
        m, a, _, _, _ = stick_margin(y, strips, parcel, nodes, weights, nsurf, surf, xi)
        counters[0] += 1
        if m > 0.0:
            return t, 2
        if a <= 0.0:
            return t, 3
        return t_stop, reason_stop
    area = np.empty(nsurf)
    clip = clip_scratch()
    lmin = 2.0 * min(parcel[P_HALF_A], parcel[P_HALF_B])
    dt_scan = lmin / (16.0 * speed)
    bound_first = parcel[P_ROTATION] > 0.5 and parcel[P_STICK] > 0.5
    y0x = y[0]
    y0y = y[1]
    t0 = t
    ys = y.copy()
    while t < t_stop:
        # reduction: only this surface under the parcel -> no force can break the stick
        # until a corner reaches a border; jump there in closed form.
        if reductions:
            alone = _alone_on(y, strips, parcel, clip, surf, area)
            dt_b = _time_to_next_border(y, vsx, parcel, borders) if alone else 0.0
            # a corner sitting on a border and moving across it gives dt_b ~ 0: scan instead
            if alone and dt_b > 1e-12:
                t_next = min(t_stop, t + dt_b)
                counters[1] += 1
                t = t_next
                y[0] = y0x + vsx * (t - t0)
                y[1] = y0y + vsy * (t - t0)
                if t >= t_stop:
                    break
                continue
        t_next = min(t_stop, t + dt_scan)
        if bound_first:
            # the scan only asks whether the stick holds: a wrench well inside the
            # limit set says so without the gauge's Newton solve (the break's own
            # search below takes the gauge's values)
            ys[0] = y0x + vsx * (t_next - t0)
            ys[1] = y0y + vsy * (t_next - t0)
            fx, fy, tq = kinetic_wrench(ys, strips, parcel, nodes, weights, surf, clip)
            counters[0] += 1
            if inside_limit_set(ys, strips, parcel, surf, fx, fy, tq):
                t = t_next
                y[0] = ys[0]
                y[1] = ys[1]
                continue
        m, a = _margin_at(
            t_next, y0x, y0y, t0, vsx, vsy, ys, strips, parcel, nodes, weights, nsurf, surf, xi
        )
        counters[0] += 1
        if m > 0.0 or a <= 0.0:
            if a <= 0.0:
                # left the surface: bisect on the contact area alone (the cheap clipping)
                lo = t
                hi = t_next
                for _ in range(60):
                    mid = 0.5 * (lo + hi)
                    ys[0] = y0x + vsx * (mid - t0)
                    ys[1] = y0y + vsy * (mid - t0)
                    _contact_surfaces(ys, strips, parcel, clip, area)
                    if area[surf] <= 0.0:
                        hi = mid
                    else:
                        lo = mid
                    if hi - lo <= 1e-13 * (1.0 + abs(hi)):
                        break
                t = hi
                reason = 3
            else:
                # the margin is continuous along the stuck path: its root by Brent's method
                t = _break_time(
                    t,
                    t_next,
                    m,
                    y0x,
                    y0y,
                    t0,
                    vsx,
                    vsy,
                    ys,
                    strips,
                    parcel,
                    nodes,
                    weights,
                    nsurf,
                    surf,
                    xi,
                    counters,
                )
                reason = 2
            y[0] = y0x + vsx * (t - t0)
            y[1] = y0y + vsy * (t - t0)
            return t, reason
        t = t_next
        y[0] = ys[0]
        y[1] = ys[1]
    t = t_stop
    y[0] = y0x + vsx * (t - t0)
    y[1] = y0y + vsy * (t - t0)
    return t, reason_stop


@borrowing
def _kinetic_pull(y, strips, parcel, nodes, weights, surf, ox, oy, ow, rho, z, clip, out):
    """
    Growth term W_o·σ - D_k(σ) of a unit slip σ (generalized) on ``surf``, and its gradient.

    W_o = (ox, oy, ow): the other surfaces' kinetic wrench at the stuck motion, D_k the
    stuck patch's kinetic dissipation at vanishing slip (μ_k(0), 1-homogeneous in σ).
    ``out`` gets W_o - ∇D_k(σ). Generalized coordinates (x, y, ρφ): the mass matrix is m I.
    """
    fx, fy, ft = rest_surface_wrench(
        y, strips, parcel, nodes, weights, surf, z[0], z[1], z[2] / rho, True, clip
    )
    out[0] = ox + fx
    out[1] = oy + fy
    out[2] = ow + ft / rho
    return out[0] * z[0] + out[1] * z[1] + out[2] * z[2]


@borrowing
def _others_wrench(y, strips, parcel, nodes, weights, surf, clip):
    """
    Kinetic wrench of every surface but ``surf`` at the state y, generalized (Fx, Fy, T/ρ).

    Returns it and ``surf``'s contact area (0: the parcel has left it).
    """
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    fx, fy, t = kinetic_wrench(y, strips, parcel, nodes, weights, surf, clip)
    ow = t / rho if parcel[P_ROTATION] > 0.5 else 0.0
    return fx, fy, ow, surface_area(y, strips, parcel, surf, clip)


@njit(cache=True)
def _pull_direction(yp, strips, parcel, nodes, weights, surf, ox, oy, ow, z, hess, clip):
    """
    Find the unit slip σ̂ (in ``z``) maximising W_o·σ - D_k(σ), W_o = (ox, oy, ow).

    Returns λ and |∇D_k(σ̂)| [N], the patch's generalized friction there.

    W_o is the other surfaces' generalized kinetic wrench, D_k the patch of ``surf``
    slipping infinitely slowly (μ_k(0), ``rest_surface_wrench``). The maximiser is the
    direction a small slip on ``surf`` settles to (its own acceleration W_o - ∇D_k(σ̂)
    = m λ σ̂ is along it) and λ its growth rate [m/s², generalized; negative: a slip
    there decays, along σ̂, at -λ, as it approaches a stick]: a concave problem,
    solved by Newton's method on the unit sphere (exact gradient, differenced Hessian,
    backtracking line search). ``z`` carries a start (a zero vector: the limit set's
    maximal-dissipation twist for W_o, else W_o's direction) and returns σ̂.

    ``hess`` (4, in/out) carries the last differenced Hessian, [k + 1 (0: none), h00,
    h01, h11] in the tangent basis built on axis k: a layer solves this at every stage
    of every step, each next to the last, and the carried Hessian starts Newton's method
    there without two gradient differences (it is only Newton's metric: the minimiser
    is where the exact gradient vanishes). It is differenced anew whenever a step with
    it backtracks or fails to cut the gradient tenfold.
    """
    mass = parcel[P_MASS]
    rho = math.sqrt(parcel[P_INERTIA] / mass)
    rot = parcel[P_ROTATION] > 0.5
    norm = math.sqrt(ox * ox + oy * oy + ow * ow)
    zn = math.sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
    if norm == 0.0 and zn == 0.0:
        return 0.0, 0.0
    if zn == 0.0 and rot:
        limit_gauge(yp, strips, parcel, nodes, weights, surf, ox, oy, ow * rho, z, clip)
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
    gp = np.empty(3)
    zt = np.empty(3)
    f = _kinetic_pull(yp, strips, parcel, nodes, weights, surf, ox, oy, ow, rho, z, clip, g)
    p = np.empty(3)
    q = np.empty(3)
    ndim = 2 if rot else 1
    gn_last = math.inf
    carried = False
    for _ in range(60):
        # a basis of the tangent plane at z (the line, without rotation)
        k = 0
        for i in range(1, 3):
            if abs(z[i]) < abs(z[k]):
                k = i
        for i in range(3):
            p[i] = (1.0 if i == k else 0.0) - z[k] * z[i]
        if not rot:
            p[0] = -z[1]
            p[1] = z[0]
            p[2] = 0.0
        pn = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
        for i in range(3):
            p[i] /= pn
        q[0] = z[1] * p[2] - z[2] * p[1]
        q[1] = z[2] * p[0] - z[0] * p[2]
        q[2] = z[0] * p[1] - z[1] * p[0]
        g0 = g[0] * p[0] + g[1] * p[1] + g[2] * p[2]
        g1 = (g[0] * q[0] + g[1] * q[1] + g[2] * q[2]) if ndim == 2 else 0.0
        radial = g[0] * z[0] + g[1] * z[1] + g[2] * z[2]  # = f, m λ at the optimum
        gscale = math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
        gn = math.hypot(g0, g1)
        # converged: relative to the wrenches whose difference the gradient is (W_o and
        # the patch's friction, each ~ norm), not to that difference, which vanishes at
        # a balance. Their quadratures agree to ~1e-10 there (the point sets move with
        # the pose), so below that f is flat to rounding and a line search on it could
        # only halve its step some twenty times before giving up. f's error is second
        # order in σ̂'s: the growth λ is exact to rounding all the same.
        if gn <= 1e-9 * max(gscale, norm):
            break
        if carried and gn > 0.1 * gn_last:
            hess[0] = 0.0  # the carried metric no longer serves: difference it anew
        gn_last = gn
        carried = hess[0] == k + 1.0
        if carried:
            h00 = hess[1]
            h01 = hess[2]
            h11 = hess[3]
        else:
            hstep = 1e-5
            h00 = 0.0
            h01 = 0.0
            h10 = 0.0
            h11 = 0.0
            for jd in range(ndim):
                # forward differences of the exact gradient, as in ``limit_gauge``
                for i in range(3):
                    zt[i] = z[i] + hstep * (p[i] if jd == 0 else q[i])
                _kinetic_pull(
                    yp, strips, parcel, nodes, weights, surf, ox, oy, ow, rho, zt, clip, gp
                )
                c0 = (gp[0] - g[0]) * p[0] + (gp[1] - g[1]) * p[1] + (gp[2] - g[2]) * p[2]
                c1 = (gp[0] - g[0]) * q[0] + (gp[1] - g[1]) * q[1] + (gp[2] - g[2]) * q[2]
                if jd == 0:
                    h00 = c0 / hstep
                    h10 = c1 / hstep
                else:
                    h01 = c0 / hstep
                    h11 = c1 / hstep
            h01 = 0.5 * (h01 + h10)
            hess[0] = k + 1.0
            hess[1] = h00
            hess[2] = h01
            hess[3] = h11
        # the Riemannian Hessian of f on the sphere: the ambient one minus the radial term
        h00 -= radial
        h11 -= radial
        if ndim == 1:
            s0 = -g0 / h00 if h00 < 0.0 else g0 * 1.0 / max(gscale, 1e-300)
            s1 = 0.0
        else:
            det = h00 * h11 - h01 * h01
            if h00 < 0.0 and h11 < 0.0 and det > 0.0:
                s0 = -(h11 * g0 - h01 * g1) / det
                s1 = -(h00 * g1 - h01 * g0) / det
            else:
                s0 = g0 / max(gscale, 1e-300)
                s1 = g1 / max(gscale, 1e-300)
        if not carried and 0.5 * (g0 * s0 + g1 * s1) <= 1e-15 * max(gscale, norm):
            # Newton's predicted gain is below f's rounding (some ulps of the wrenches it
            # is the difference of): no line search can resolve the rest
            break
        step = 1.0
        ft = f
        for _ls in range(40):
            for i in range(3):
                zt[i] = z[i] + step * (s0 * p[i] + s1 * q[i])
            tn = math.sqrt(zt[0] * zt[0] + zt[1] * zt[1] + zt[2] * zt[2])
            for i in range(3):
                zt[i] /= tn
            ft = _kinetic_pull(
                yp, strips, parcel, nodes, weights, surf, ox, oy, ow, rho, zt, clip, gp
            )
            if ft >= f:
                break
            step *= 0.5
        if step < 1.0 and carried:
            hess[0] = 0.0
        if not ft >= f:
            if carried:
                continue  # retry from here with a fresh Hessian
            break
        moved = step * math.hypot(s0, s1)
        for i in range(3):
            z[i] = zt[i]
            g[i] = gp[i]
        f = ft
        if moved <= 1e-15:
            break
    # g = W_o - ∇D_k(σ̂) at the final σ̂ (accepted points only carry their gradient)
    return f / mass, math.sqrt((g[0] - ox) ** 2 + (g[1] - oy) ** 2 + (g[2] - ow) ** 2)


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


@njit(cache=True)
def _layer_rhs(u, strips, parcel, nodes, weights, clip, surf, vsx, vsy, z, hess, yv, acc, out):
    """
    Right-hand side of the slip layer on ``surf``: u = (x, y, φ, s), s the slip magnitude.

    On the layer's slow manifold the slip points along σ̂, the direction a small slip
    settles to against the other surfaces' wrench at the current motion
    (``_pull_direction``, warm-started from and returned in ``z``); the pose moves
    with the surface plus s σ̂, and s grows at σ̂·a, a the full model's (generalized)
    acceleration at that motion. ``yv`` gets the full state. Returns the stuck
    patch's friction magnitude |∇D_k| [N] (its stiffness is that over m s).
    """
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    sl = _layer_state(u, z, vsx, vsy, parcel, yv)
    ox, oy, ow, _ = _others_wrench(yv, strips, parcel, nodes, weights, surf, clip)
    lam, fmag = _pull_direction(
        yv, strips, parcel, nodes, weights, surf, ox, oy, ow, z, hess, clip
    )
    _layer_state(u, z, vsx, vsy, parcel, yv)  # at the settled direction
    rhs_slide(yv, strips, parcel, nodes, weights, clip, acc)
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


@njit(cache=True)
def _layer(
    y,
    t,
    t_end,
    y_target,
    strips,
    parcel,
    nodes,
    weights,
    nsurf,
    surf,
    s0,
    z,
    rtol,
    atol,
    borders,
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
    nb = borders.shape[0]
    ev0 = np.empty(4 * nb)
    ev1 = np.empty(4 * nb)
    _layer_rhs(u, strips, parcel, nodes, weights, clip, surf, vsx, vsy, z, hess, yv, acc, K[0])
    counters[0] += 1
    h = min(1e-5, t_end - t)
    healthy = False
    for _ in range(10000):
        if t >= t_end or h <= 1e-14 * max(1.0, abs(t)):
            break
        h = min(h, t_end - t)
        for i in range(1, 7):
            stage_state(u, K, h, i, us)
            for j in range(3):
                zs[j] = z[j]
            _layer_rhs(
                us, strips, parcel, nodes, weights, clip, surf, vsx, vsy, zs, hess, yv, acc, K[i]
            )
        for j in range(4):
            un[j] = us[j]
        counters[0] += 6
        step_error(K, h, err)
        # the slip relative to itself: the trajectory after a break is sensitive to when
        # the slip grows (its growth starts from λ = 0), so an absolute slip error of the
        # full model's velocity scale put Fig. 9a 100 rtol m off; atol 1e-3 x: a floor
        # only where the slip is zero
        en = 0.0
        for j in range(4):
            sc = (atol if j < 3 else 1e-3 * atol) + rtol * max(abs(u[j]), abs(un[j]))
            en += (err[j] / sc) ** 2
        en = math.sqrt(en / 4.0)
        crossed = y_target < math.inf and u[1] < y_target <= un[1]
        if nb > 0 and not crossed:
            yv[:3] = u[:3]
            _corner_event_values(yv, parcel, borders, ev0)
            yv[:3] = un[:3]
            _corner_event_values(yv, parcel, borders, ev1)
            crossed = sign_change(ev0, ev1) >= 0
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
            h *= hi
            for i in range(1, 7):
                stage_state(u, K, h, i, us)
                for j in range(3):
                    zs[j] = z[j]
                _layer_rhs(
                    us,
                    strips,
                    parcel,
                    nodes,
                    weights,
                    clip,
                    surf,
                    vsx,
                    vsy,
                    zs,
                    hess,
                    yv,
                    acc,
                    K[i],
                )
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
        fmag = _layer_rhs(
            u, strips, parcel, nodes, weights, clip, surf, vsx, vsy, z, hess, yv, acc, K[0]
        )
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
        # down. Measured against a fixed twentieth: Fig. 9a at rtol 1e-6 675 -> 576
        # evaluations for the same error, the same run at 1e-8
        if grow_exit and u[3] > 0.0 and K[0, 3] > 0.0 and K[0, 3] * mass >= grow_ratio * fmag:
            healthy = True
            break
    _layer_state(u, z, vsx, vsy, parcel, y)
    return t, healthy


@njit(cache=True)
def _break_away(
    y,
    t,
    t_end,
    y_target,
    strips,
    parcel,
    nodes,
    weights,
    nsurf,
    surf,
    s0,
    s_floor,
    rtol,
    atol,
    borders,
    counters,
    rec,
    ts,
    ys,
    ms,
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
        y_target,
        strips,
        parcel,
        nodes,
        weights,
        nsurf,
        surf,
        s0,
        z,
        rtol,
        atol,
        borders,
        counters,
        True,
        s_floor,
    )
    if healthy:
        t_new, _ = _approach(
            y,
            t,
            t_end,
            y_target,
            strips,
            parcel,
            nodes,
            weights,
            nsurf,
            surf,
            0.0,
            rtol,
            atol,
            borders,
            counters,
            rec,
            ts,
            ys,
            ms,
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
def _approach_rhs(u, s, sgn, strips, parcel, nodes, weights, clip, vsx, vsy, yv, acc, out):
    """
    Right-hand side of a slip on one surface in τ = sgn ln(s / s_e).

    u = (x, y, φ, t, d): pose, time and the slip's direction d (its norm is ignored);
    s = s_e e^(sgn τ) the slip there (sgn -1: falling to a stick, +1: growing from a
    break-away). With a the full model's generalized acceleration at that motion and
    r = d̂·a the slip's rate, q = sgn r > 0: dt/dτ = s / q, the pose moves at its
    velocity times that, and dd/dτ = (a - r d̂) / q: the direction's turning, which in
    t runs at a rate ~F/(m s), is O(1) per unit of τ. Returns r.
    """
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    rot = parcel[P_ROTATION] > 0.5
    d0, d1, d2 = _approach_state(u, s, vsx, vsy, parcel, yv)
    rhs_slide(yv, strips, parcel, nodes, weights, clip, acc)
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


@njit(cache=True)
def _approach(
    y,
    t,
    t_end,
    y_target,
    strips,
    parcel,
    nodes,
    weights,
    nsurf,
    surf,
    s_end,
    rtol,
    atol,
    borders,
    counters,
    rec,
    ts,
    ys,
    ms,
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
    r = _approach_rhs(u, s_e, sgn, strips, parcel, nodes, weights, clip, vsx, vsy, yv, acc, K[0])
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
        ok = True
        for i in range(1, 7):
            stage_state(u, K, h, i, un)
            ri = _approach_rhs(
                un,
                s_e * math.exp(sgn * (tau + (C[i] if i < 6 else 1.0) * h)),
                sgn,
                strips,
                parcel,
                nodes,
                weights,
                clip,
                vsx,
                vsy,
                yv,
                acc,
                K[i],
            )
            ok = ok and sgn * ri > 0.0
        counters[0] += 6
        step_error(K, h, err)
        en = 0.0
        for j in range(7):
            sc = atol + rtol * (max(abs(u[j]), abs(un[j])) if j < 4 else 1.0)
            en += (err[j] / sc) ** 2
        en = math.sqrt(en / 7.0)
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
            strips,
            parcel,
            nodes,
            weights,
            clip,
            vsx,
            vsy,
            yv,
            acc,
            K[0],
        )
        counters[0] += 1
        rec[0] = _record(ts, ys, ms, rec[0], u[3], yv, MODE_SLIDE)
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


@njit(cache=True)
def _small_slip(
    y,
    t,
    t_end,
    y_target,
    strips,
    parcel,
    nodes,
    weights,
    nsurf,
    s_check,
    s_stiff,
    rtol,
    atol,
    borders,
    counters,
    rec,
    ts,
    ys,
    ms,
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
            m, _, _, _, _ = stick_margin(stuck, strips, parcel, nodes, weights, nsurf, s, xi)
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
                y_target,
                strips,
                parcel,
                nodes,
                weights,
                nsurf,
                s,
                s_check,
                rtol,
                atol,
                borders,
                counters,
                rec,
                ts,
                ys,
                ms,
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
                y_target,
                strips,
                parcel,
                nodes,
                weights,
                nsurf,
                s,
                n,
                s_check,
                rtol,
                atol,
                borders,
                counters,
                rec,
                ts,
                ys,
                ms,
            )
            if not t_new > t:
                continue
            at_zero = _gen_slip(yl, vsx, vsy, rho, rot, sig) == 0.0 and t_new < t_end
        for j in range(6):
            y[j] = yl[j]
        if at_zero:
            # the slip reached zero: the limit set decides, stick or break away from there
            m, _, _, _, _ = stick_margin(y, strips, parcel, nodes, weights, nsurf, s, xi)
            counters[0] += 1
            if m <= 0.0:
                return t_new, s, True
            t_new = _break_away(
                y,
                t_new,
                t_end,
                y_target,
                strips,
                parcel,
                nodes,
                weights,
                nsurf,
                s,
                0.0,
                s_check,
                rtol,
                atol,
                borders,
                counters,
                rec,
                ts,
                ys,
                ms,
            )
        return t_new, s, False
    return t, -1, False


@njit(cache=True)
def run_accurate(
    y0,
    mode0,
    t0,
    t_end,
    y_target,
    strips,
    parcel,
    nodes,
    weights,
    borders,
    rtol,
    atol,
    h_max,
    reductions,
    ts,
    ys,
    ms,
    ev,
    counters,
    xi,
):
    """
    Event-located Dormand-Prince integration of the hybrid model.

    counters (out): [n_steps, n_rhs, n_rejected, n_out, n_events, closed_form_jumps,
                     stick_scans]. Returns (status, t, mode) with the final state in ys.
    xi (GAUGE_CARRY, in/out): the limit-set gauge's twist of a stick and its Newton
    metric, a warm start for its solve carried from call to call (the cell integrates
    a parcel period by period and keeps each one's); zeros: none. The result does not
    depend on it beyond rounding.
    """
    nsurf = n_surf_of(strips)
    rot = parcel[P_ROTATION] > 0.5
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    y = y0.copy()
    t = t0
    mode = mode0
    n_out = _record(ts, ys, ms, 0, t, y, mode)
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
    yd = np.empty(6)
    sig = np.empty(3)
    sig0 = np.empty(nsurf * 3)
    sig0n = np.empty(nsurf)
    s_stiff = np.zeros(nsurf)
    rec = np.zeros(1, dtype=np.int64)
    area = np.empty(nsurf)
    clip = clip_scratch()
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
                y_target,
                strips,
                parcel,
                nodes,
                weights,
                nsurf,
                borders,
                reductions,
                stick_counters,
                xi,
            )
            t = t_new
            n_out = _record(ts, ys, ms, n_out, t, y, mode)
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
                        y_target,
                        strips,
                        parcel,
                        nodes,
                        weights,
                        nsurf,
                        broke_from,
                        0.0,
                        s_check,
                        rtol,
                        atol,
                        borders,
                        stick_counters,
                        rec,
                        ts,
                        ys,
                        ms,
                    )
                    armed[broke_from] = False
                    n_out = rec[0]
                fresh = True
                n_out = _record_new(ts, ys, ms, n_out, t, y, mode)
            continue
        # ---- sliding: one Dormand-Prince step with event location ----
        if fresh:
            rhs_slide(y, strips, parcel, nodes, weights, clip, K[0])
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
                            strips,
                            parcel,
                            nodes,
                            weights,
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
                y_target,
                strips,
                parcel,
                nodes,
                weights,
                nsurf,
                s_check,
                s_stiff,
                rtol,
                atol,
                borders,
                stick_counters,
                rec,
                ts,
                ys,
                ms,
            )
            n_out = rec[0]
            if stuck:
                t = t_new
                n_ev = _log_event(ev, n_ev, t, EV_STICK, s_act)
                mode = s_act
                fresh = True
                n_out = _record(ts, ys, ms, n_out, t, y, mode)
                continue
            if t_new > t:
                t = t_new
                fresh = True
                n_out = _record_new(ts, ys, ms, n_out, t, y, mode)
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
        _dp_step(y, h, K, strips, parcel, nodes, weights, clip, y_new, err)
        n_rhs += 6
        enorm = rms_norm(err, y, y_new, rtol, atol)
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
            _dp_step(y, h, K, strips, parcel, nodes, weights, clip, y_new, err)
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
                n_out = _record(ts, ys, ms, n_out, t, y, mode)
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
        n_out = _record(ts, ys, ms, n_out, t, y, mode)
        # after a step cut at an event, resume with the size the controller had
        h = h_next
    counters[0] = n_steps
    counters[1] = n_rhs + stick_counters[0]
    counters[2] = n_rej
    counters[3] = n_out
    counters[4] = n_ev
    counters[5] = stick_counters[1]
    counters[6] = stick_counters[0]
    return status, t, mode


# ---------------------------------------------------------------- implicit step
# columns of the implicit step's point set (``_build_points``)
PT_X, PT_Y, PT_C, PT_SURF, PT_VX, PT_VY = 0, 1, 2, 3, 4, 5


@njit(cache=True)
def _build_points(y, strips, parcel, nodes, weights, pts, stat, pull, area):
    """
    Quadrature points of the footprint (centroid fans, Gauss n x n per triangle).

    ``pts`` (rows, one per point; columns PT_*): its position, surface and that
    surface's velocity, and c = weight · μ_k · pressure with μ_k the kinetic
    coefficient at the point's current slip (the 'lag' that keeps the implicit
    problem convex). Per surface: stat = (F_max, T_max) its static limits, pull the
    most its kinetic friction can pull (Σ ck, Σ ck |r|), area its share of the
    footprint. Returns the number of points.
    """
    corners = np.empty((4, 2))
    poly = np.empty((MAX_VERTS, 2))
    work = np.empty((MAX_VERTS, 2))
    half_a = parcel[P_HALF_A]
    half_b = parcel[P_HALF_B]
    box_corners(y[0], y[1], y[2], half_a, half_b, corners)
    p_unit = parcel[P_MASS] * parcel[P_GRAV] / (4.0 * half_a * half_b)
    nq = nodes.shape[0]
    npt = 0
    stat[:, :] = 0.0
    pull[:, :] = 0.0
    area[:] = 0.0
    for k in range(strips.shape[0]):
        w = strips[k, S_WEIGHT]
        if w <= 0.0:
            continue
        n = clip_to_strip(corners, strips[k, S_XLO], strips[k, S_XHI], poly, work)
        a, qx, qy = polygon_area_centroid(poly, n)
        if a <= 0.0:
            continue
        s_id = int(strips[k, S_SURF])
        law = int(strips[k, S_LAW])
        params = strips[k, S_PARAMS:]
        pressure = p_unit * w
        mus = mu_static(law, params)
        area[s_id] += w * a
        for i in range(n):
            j = (i + 1) % n
            e0x = poly[i, 0] - qx
            e0y = poly[i, 1] - qy
            dex = poly[j, 0] - poly[i, 0]
            dey = poly[j, 1] - poly[i, 1]
            det = e0x * dey - e0y * dex
            for aa in range(nq):
                ex = e0x + nodes[aa] * dex
                ey = e0y + nodes[aa] * dey
                for bb in range(nq):
                    s = nodes[bb]
                    xk = qx + s * ex
                    yk = qy + s * ey
                    wk = weights[aa] * weights[bb] * s * det
                    ux = y[3] - y[5] * (yk - y[1]) - strips[k, S_VX]
                    uy = y[4] + y[5] * (xk - y[0]) - strips[k, S_VY]
                    sp = math.sqrt(ux * ux + uy * uy)
                    mu = mu_kinetic(law, params, max(sp, 1e-12))
                    c = wk * mu * pressure
                    pts[npt, PT_X] = xk
                    pts[npt, PT_Y] = yk
                    pts[npt, PT_C] = c
                    pts[npt, PT_SURF] = s_id
                    pts[npt, PT_VX] = strips[k, S_VX]
                    pts[npt, PT_VY] = strips[k, S_VY]
                    rr = math.sqrt((xk - y[0]) ** 2 + (yk - y[1]) ** 2)
                    stat[s_id, 0] += wk * mus * pressure
                    stat[s_id, 1] += wk * mus * pressure * rr
                    pull[s_id, 0] += c
                    pull[s_id, 1] += c * rr
                    npt += 1
    return npt


@njit(cache=True)
def _points_wrench(st, npt, pts, skip, kin):
    """Kinetic wrench per surface of the point set at the twist in ``st`` (``skip``: zero)."""
    kin[:, :] = 0.0
    for k in range(npt):
        s = int(pts[k, PT_SURF])
        if s == skip:
            continue
        rx = pts[k, PT_X] - st[0]
        ry = pts[k, PT_Y] - st[1]
        ux = st[3] - st[5] * ry - pts[k, PT_VX]
        uy = st[4] + st[5] * rx - pts[k, PT_VY]
        # sqrt, not hypot: speeds are O(1) m/s, and libm's hypot costs several times more
        sp = math.sqrt(ux * ux + uy * uy)
        if sp > 0.0:
            fx = -pts[k, PT_C] * ux / sp
            fy = -pts[k, PT_C] * uy / sp
            kin[s, 0] += fx
            kin[s, 1] += fy
            kin[s, 2] += rx * fy - ry * fx


@njit(cache=True)
def _points_hessian(st, npt, pts, out):
    """Put the point set's dissipation Hessian Σ c_k Jᵀ(I - ûûᵀ)J / |u_k| at ``st`` in ``out``."""
    out[:, :] = 0.0
    for k in range(npt):
        rx = pts[k, PT_X] - st[0]
        ry = pts[k, PT_Y] - st[1]
        ux = st[3] - st[5] * ry - pts[k, PT_VX]
        uy = st[4] + st[5] * rx - pts[k, PT_VY]
        sp = max(math.sqrt(ux * ux + uy * uy), 1e-12)
        add_slip_curvature(out, pts[k, PT_C], ux, uy, sp, rx, ry)
    out[1, 0] = out[0, 1]
    out[2, 0] = out[0, 2]
    out[2, 1] = out[1, 2]


# inlined: a call would count references to the point set and the other arrays at every
# evaluation, a tenth of an exact step's cost
@njit(cache=True, inline="always")
def _step_wrenches(
    exact, st, skip, need, strips, parcel, nodes, weights, npt, pts, kin, stat, area, slip
):
    """
    Every surface's kinetic wrench at the twist in ``st`` (``skip`` left out) into ``kin``.

    The exact wrench (``evaluate_surfaces``; with ``need`` also the static limits and
    areas) or the step's point set (whose limits and areas come with it).
    """
    if exact:
        # (evaluate_surfaces clears the limits it is not asked for: keep them)
        lim = stat if need else np.empty((0, 2))
        evaluate_surfaces(st, strips, parcel, nodes, weights, skip, need, kin, lim, area, slip)
    else:
        _points_wrench(st, npt, pts, skip, kin)


@njit(cache=True)
def _solve_spd(H, grad, nvar):
    """-H⁻¹ grad for the 2x2 or 3x3 symmetric positive-definite Newton system (Cramer)."""
    out = np.zeros(3)
    if nvar == 2:
        det = H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
        out[0] = -(H[1, 1] * grad[0] - H[0, 1] * grad[1]) / det
        out[1] = -(H[0, 0] * grad[1] - H[1, 0] * grad[0]) / det
        return out
    c00 = H[1, 1] * H[2, 2] - H[1, 2] * H[2, 1]
    c01 = H[1, 2] * H[2, 0] - H[1, 0] * H[2, 2]
    c02 = H[1, 0] * H[2, 1] - H[1, 1] * H[2, 0]
    det = H[0, 0] * c00 + H[0, 1] * c01 + H[0, 2] * c02
    c11 = H[0, 0] * H[2, 2] - H[0, 2] * H[2, 0]
    c12 = H[0, 1] * H[2, 0] - H[0, 0] * H[2, 1]
    c22 = H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
    # H symmetric: the adjugate is symmetric too
    out[0] = -(c00 * grad[0] + c01 * grad[1] + c02 * grad[2]) / det
    out[1] = -(c01 * grad[0] + c11 * grad[1] + c12 * grad[2]) / det
    out[2] = -(c02 * grad[0] + c12 * grad[1] + c22 * grad[2]) / det
    return out


@njit(cache=True)
def _ratio(load, limit):
    """Return load / limit, where a zero limit holds a zero load only."""
    if limit > 0.0:
        return load / limit
    return 0.0 if load == 0.0 else math.inf


@njit(cache=True)
def _stick_load(y, strips, parcel, nodes, weights, s, rfx, rfy, rt, stat, xi, clip):
    """
    How far the wrench (rfx, rfy, rt) that surface ``s`` must supply loads its stick.

    At most 1 (within STICK_RTOL) iff the stick holds: the wrench lies in the patch's
    limit set (exact stick, ``limit_gauge``: the value is the gauge) or within the
    seed's decoupled force and moment limits ``stat[s]`` (seed stick; also without
    rotation, where φ̇ = 0 is a constraint). Above 1 it is the larger of the decoupled
    ratios, or the gauge where those hold. The gauge's Newton solve runs only where
    ``inside_limit_set`` cannot tell the wrench is inside.
    """
    rot = parcel[P_ROTATION] > 0.5
    tol = 1.0 + STICK_RTOL
    load = _ratio(math.hypot(rfx, rfy), stat[s, 0] * tol)
    if rot:
        load = max(load, _ratio(abs(rt), stat[s, 1] * tol))
    # the decoupled limits are necessary for the limit set too (|F| <= μN, and |T|
    # about g at most the pure spin's): the gauge runs only where they hold
    if load <= 1.0 and rot and parcel[P_STICK] > 0.5:
        if not inside_limit_set(y, strips, parcel, s, rfx, rfy, rt):
            gamma = limit_gauge(y, strips, parcel, nodes, weights, s, rfx, rfy, rt, xi, clip)
            load = gamma / tol
    return load


@njit(cache=True)
def inside_limit_set(state, strips, parcel, surf, fx, fy, t):
    """
    Return True if the wrench (fx, fy, t about g) lies in ``surf``'s limit set, by a bound.

    Sufficient, not necessary: it saves the gauge's Newton solve for a wrench well
    inside. The patch's dissipation D(V, ω) = ∫ρ|V + ω ẑ×(p - g)| dA (ρ = μ_s times the
    pressure) is at least |∫ρ(V + ω ẑ×(p - g))| >= F_max (|V| - |ω| d), d the distance
    from g to the patch's load centroid, and at least |ω| J with J = min over centres
    c of ∫ρ|p - c| dA >= (2/3) F_max sqrt(F_max / (π ρ_max)) (the load packed at its
    densest into a disk about c). Mixing the two bounds with the weights |F|/F_max and
    1 - |F|/F_max gives D >= |F||V| + |T||ω| >= F·V + Tω for every twist, i.e. the
    wrench is in the set, where |T| + |F| d <= (1 - |F|/F_max) J.
    """
    x = state[0]
    y = state[1]
    half_a = parcel[P_HALF_A]
    half_b = parcel[P_HALF_B]
    p_unit = parcel[P_MASS] * parcel[P_GRAV] / (4.0 * half_a * half_b)
    corners = np.empty((4, 2))
    poly = np.empty((MAX_VERTS, 2))
    work = np.empty((MAX_VERTS, 2))
    box_corners(x, y, state[2], half_a, half_b, corners)
    f_max = 0.0
    mx = 0.0
    my = 0.0
    rho_max = 0.0
    for k in range(strips.shape[0]):
        w = strips[k, S_WEIGHT]
        if w <= 0.0 or int(strips[k, S_SURF]) != surf:
            continue
        n = clip_to_strip(corners, strips[k, S_XLO], strips[k, S_XHI], poly, work)
        a, qx, qy = polygon_area_centroid(poly, n)
        if a <= 0.0:
            continue
        rho = mu_static(int(strips[k, S_LAW]), strips[k, S_PARAMS:]) * p_unit * w
        f_max += rho * a
        mx += rho * a * (qx - x)
        my += rho * a * (qy - y)
        rho_max = max(rho_max, rho)
    if not f_max > 0.0:
        return False
    f = math.hypot(fx, fy)
    d = math.hypot(mx, my) / f_max
    j_min = (2.0 / 3.0) * f_max * math.sqrt(f_max / (math.pi * rho_max))
    # (a hair of margin for the rounding of the sums)
    return abs(t) + f * d <= (1.0 - f / f_max) * j_min * (1.0 - 1e-9)


@njit(cache=True)
def _implicit_objective(W, W0, mass, h, kin, nsurf, strips, rot, grad):
    """
    f(W) = ½ (W-W0)ᵀM(W-W0)/h + Σ_s D_s(W) and its gradient, from the surfaces' wrenches at W.

    With a constant μ each D_s is 1-homogeneous in the twist ξ_s = W - W_s relative to
    surface s (moments about g), so D_s = -ξ_s·wrench_s (Euler's relation) and the
    gradient of D is minus the wrench: no integral of its own.
    """
    f = 0.0
    for i in range(3):
        grad[i] = mass[i] * (W[i] - W0[i]) / h
        f += 0.5 * mass[i] * (W[i] - W0[i]) ** 2 / h
    for s in range(nsurf):
        vsx, vsy = surface_velocity(strips, s)
        f -= (W[0] - vsx) * kin[s, 0] + (W[1] - vsy) * kin[s, 1] + W[2] * kin[s, 2]
        grad[0] -= kin[s, 0]
        grad[1] -= kin[s, 1]
        grad[2] -= kin[s, 2]
    if not rot:
        grad[2] = 0.0
    return f


@njit(cache=True)
def _scaled(ratio, x):
    """Return ratio · x for x >= 0, with 0 for x = 0 even where ratio is inf."""
    return ratio * x if x > 0.0 else 0.0


@njit(cache=True)
def _bfgs_update(hess, sv, yv, nvar, hs):
    """
    BFGS update of ``hess`` (its leading nvar x nvar block) by the secant pair (sv, yv).

    Skipped where the pair's curvature sv·yv is not clearly positive (a convex
    function's never is negative; zero at rounding), so the matrix stays positive
    semidefinite. ``hs``: scratch (3).
    """
    sy = 0.0
    shs = 0.0
    ss = 0.0
    yy = 0.0
    for i in range(nvar):
        hs[i] = 0.0
        for j in range(nvar):
            hs[i] += hess[i, j] * sv[j]
        sy += sv[i] * yv[i]
        shs += sv[i] * hs[i]
        ss += sv[i] * sv[i]
        yy += yv[i] * yv[i]
    if sy > 1e-12 * math.sqrt(ss * yy):
        for i in range(nvar):
            for j in range(nvar):
                hess[i, j] += yv[i] * yv[j] / sy
                if shs > 0.0:
                    hess[i, j] -= hs[i] * hs[j] / shs


@njit(cache=True)
def _set_twist(state, w):
    """Put the twist w = (ẋ, ẏ, φ̇) into ``state``'s velocities."""
    state[3] = w[0]
    state[4] = w[1]
    state[5] = w[2]


@njit(cache=True)
def _stuck_step(y, h, vsx, vsy, y_out):
    """Take a step stuck to a surface moving at (vsx, vsy): rigid translation with it."""
    y_out[0] = y[0] + h * vsx
    y_out[1] = y[1] + h * vsy
    y_out[2] = y[2]
    y_out[3] = vsx
    y_out[4] = vsy
    y_out[5] = 0.0


@njit(cache=True)
def implicit_step(
    y,
    h,
    mode,
    strips,
    parcel,
    nodes,
    weights,
    exact,
    mu_ratio,
    pts,
    guess,
    hess,
    fresh,
    xis,
    y_out,
):
    """
    One backward-Euler velocity step; returns (mode, friction evaluations).

    W+ minimises f(W) = ½ (W-W0)ᵀM(W-W0)/h + D(W), D the footprint's dissipation rate
    at the step's pose. With constant μ everywhere (``exact``) D and its gradient come
    from the exact wrench (``evaluate_surfaces``), so the method has no quadrature
    floor; otherwise from the point set of ``_build_points`` (``pts``, μ lagged). Both
    ways each D_s is 1-homogeneous in the twist relative to its surface, so
    ``_implicit_objective`` has f from the wrenches alone.

    A stick is tested first (``_stick_load``): on the surface stuck to, then on any
    other the step could bring to rest (the change of momentum within all the limits:
    the others' pull bounded by ``mu_ratio`` times their static limits, or by the
    point set's own sums); a parcel riding a surface alone under it needs no more
    than a clip. Then Newton on f from ``guess`` (the caller's prediction of W+,
    about the step's local error off), moved off the kink of a surface that does not
    hold where it sits on one, with a backtracking line search. Its Hessian: the
    point set's own, exactly, or for the exact wrench a model (``dissipation_hessian``,
    where ``fresh``) that BFGS updates carry from step to step in ``hess`` (3 x 3):
    about 1.5 wrench evaluations a step on Fig. 9a. ``xis`` (nsurf x
    GAUGE_CARRY): each surface's limit-set gauge twist and Newton metric, carried from
    step to step.
    """
    m = parcel[P_MASS]
    rot = parcel[P_ROTATION] > 0.5
    nsurf = xis.shape[0]
    mass = np.array([m, m, parcel[P_INERTIA] if rot else 1.0])
    W0 = np.array([y[3], y[4], y[5] if rot else 0.0])
    nvar = 3 if rot else 2
    kin = np.empty((nsurf, 3))
    others = np.empty((nsurf, 3))
    stat = np.empty((nsurf, 2))
    pull = np.empty((nsurf, 2))
    area = np.empty(nsurf)
    slip = np.empty(nsurf)
    clip = clip_scratch()
    if mode >= 0:
        vsx, vsy = surface_velocity(strips, mode)
        # riding a surface alone under the parcel: it must supply no wrench at all,
        # which every limit set holds (the clip alone tells)
        if (
            W0[0] == vsx
            and W0[1] == vsy
            and W0[2] == 0.0
            and _alone_on(y, strips, parcel, clip, mode, area)
        ):
            _stuck_step(y, h, vsx, vsy, y_out)
            return mode, 0
    st = y.copy()
    npt = 0 if exact else _build_points(y, strips, parcel, nodes, weights, pts, stat, pull, area)
    # the Newton start and the wrenches there: the guess, or while stuck the surface's
    # velocity (the stuck surface's own wrench left out: zero slip, and the stick test
    # needs the others' alone)
    W = np.empty(3)
    if mode >= 0:
        W[0], W[1] = surface_velocity(strips, mode)
        W[2] = 0.0
    else:
        for i in range(3):
            W[i] = guess[i]
        if not rot:
            W[2] = 0.0
    _set_twist(st, W)
    _step_wrenches(
        exact, st, mode, True, strips, parcel, nodes, weights, npt, pts, kin, stat, area, slip
    )
    n_eval = 1
    if exact:
        for s in range(nsurf):
            pull[s, 0] = _scaled(mu_ratio, stat[s, 0])
            pull[s, 1] = _scaled(mu_ratio, stat[s, 1])
    pull_f = 0.0
    pull_t = 0.0
    f_all = 0.0
    for s in range(nsurf):
        pull_f += pull[s, 0]
        pull_t += pull[s, 1]
        f_all += stat[s, 0]
    # --- stick: first the surface stuck to, then any other the step could bring to rest
    for s in range(-1, nsurf):
        cand = mode if s < 0 else s
        if cand < 0 or (s >= 0 and s == mode) or area[cand] <= 0.0:
            continue
        vsx, vsy = surface_velocity(strips, cand)
        dfx = m * (vsx - W0[0]) / h
        dfy = m * (vsy - W0[1]) / h
        dt_ = -mass[2] * W0[2] / h
        if cand != mode:
            # necessary: the change of momentum to rest on cand within cand's static
            # limits and the most the others can pull
            reach_f = stat[cand, 0] + pull_f - pull[cand, 0]
            reach_t = stat[cand, 1] + pull_t - pull[cand, 1]
            if math.hypot(dfx, dfy) > reach_f * (1.0 + 1e-9) or (
                rot and abs(dt_) > reach_t * (1.0 + 1e-9)
            ):
                continue
            st[3] = vsx
            st[4] = vsy
            st[5] = 0.0
            _step_wrenches(
                exact,
                st,
                cand,
                False,
                strips,
                parcel,
                nodes,
                weights,
                npt,
                pts,
                others,
                stat,
                area,
                slip,
            )
            n_eval += 1
            src = others
        else:
            src = kin
        wfx = dfx
        wfy = dfy
        wt = dt_
        for o in range(nsurf):
            if o != cand:
                wfx -= src[o, 0]
                wfy -= src[o, 1]
                wt -= src[o, 2]
        load = _stick_load(
            y, strips, parcel, nodes, weights, cand, wfx, wfy, wt, stat, xis[cand], clip
        )
        if load <= 1.0:
            _stuck_step(y, h, vsx, vsy, y_out)
            return cand, n_eval
        # no stick: the surplus the patch cannot hold moves the parcel off its velocity
        # by about b in one step. A start within 1 % of that from the velocity sits on
        # the kink of its friction (just stuck, or a slip just broken away), where
        # Newton's steps shrink to nothing: start at b instead (Newton and its line
        # search take it from there).
        excess = 1.0 - 1.0 / load if load < math.inf else 1.0
        bx = -excess * h * wfx / m
        by = -excess * h * wfy / m
        bt = -excess * h * wt / mass[2] if rot else 0.0
        off = m * ((W[0] - vsx) ** 2 + (W[1] - vsy) ** 2) + mass[2] * W[2] ** 2
        if cand == mode or off < 1e-4 * (m * (bx * bx + by * by) + mass[2] * bt * bt):
            W[0] = vsx + bx
            W[1] = vsy + by
            W[2] = bt
            _set_twist(st, W)
            _step_wrenches(
                exact,
                st,
                -1,
                False,
                strips,
                parcel,
                nodes,
                weights,
                npt,
                pts,
                kin,
                stat,
                area,
                slip,
            )
            n_eval += 1
    # --- slide: Newton on f with a backtracking line search
    grad = np.empty(3)
    gt = np.empty(3)
    Wt = np.empty(3)
    H = np.empty((3, 3))
    _set_twist(st, W)
    fresh = fresh or mode >= 0 or not exact  # the point set's Hessian is exact anyway
    if exact and fresh:
        dissipation_hessian(st, strips, parcel, hess)
    fval = _implicit_objective(W, W0, mass, h, kin, nsurf, strips, rot, grad)
    # f is (M/h)-strongly convex: |W - W+|_M <= h |grad|_M⁻¹ whatever the Hessian
    # model. The solve stops where that bound falls below SOLVE_RATIO of how far W has
    # moved from its start (from a guess: about the step's local error), or the
    # gradient reaches the wrenches' rounding. Not relative to the first gradient: a
    # start at a kink (a slip just broken away) has the whole jump of a surface's
    # friction in it. Not on f's rounding: at small h the velocity errors a gain below
    # it leaves add up over the many steps.
    g_round = 1e-12 * f_all / math.sqrt(m)
    w_start = W.copy()
    sv = np.empty(3)
    yv = np.empty(3)
    hs = np.empty(3)
    for _ in range(60):
        gnorm = 0.0
        moved = 0.0
        for i in range(nvar):
            gnorm += grad[i] ** 2 / mass[i]
            moved += mass[i] * (W[i] - w_start[i]) ** 2
        gnorm = math.sqrt(gnorm)
        moved = math.sqrt(moved)
        if not exact:
            _set_twist(st, W)
            _points_hessian(st, npt, pts, hess)
        for i in range(3):
            for j in range(3):
                H[i, j] = hess[i, j]
            H[i, i] += mass[i] / h
        dW = _solve_spd(H, grad, nvar)
        if h * gnorm <= SOLVE_RATIO * moved or gnorm <= g_round:
            # the model's Newton step costs nothing, and as H >= M/h it moves W by at
            # most the bound that was just accepted
            for i in range(nvar):
                W[i] += dW[i]
            break
        f_noise = F_NOISE * abs(fval)
        slope = grad[0] * dW[0] + grad[1] * dW[1] + grad[2] * dW[2]
        step = 1.0
        ok = False
        ft = fval
        for _ls in range(30):
            for i in range(3):
                Wt[i] = W[i] + step * dW[i]
            _set_twist(st, Wt)
            _step_wrenches(
                exact,
                st,
                -1,
                False,
                strips,
                parcel,
                nodes,
                weights,
                npt,
                pts,
                kin,
                stat,
                area,
                slip,
            )
            n_eval += 1
            ft = _implicit_objective(Wt, W0, mass, h, kin, nsurf, strips, rot, gt)
            if -step * slope > f_noise:
                ok = ft <= fval + 1e-4 * step * slope
            else:
                # a gain below f's rounding (small steps h): the gradient decides
                gt_norm = 0.0
                for i in range(nvar):
                    gt_norm += gt[i] ** 2 / mass[i]
                ok = math.sqrt(gt_norm) <= (1.0 - 0.5 * step) * gnorm
            if ok:
                break
            step *= 0.5
        if not ok:
            if fresh:
                break  # no descent left at rounding level
            # the carried model misled the step: start again from a fresh one
            _set_twist(st, W)
            dissipation_hessian(st, strips, parcel, hess)
            fresh = True
            continue
        if exact:
            # D's part of the accepted step's secant pair
            for i in range(nvar):
                sv[i] = Wt[i] - W[i]
                yv[i] = gt[i] - grad[i] - mass[i] * sv[i] / h
            _bfgs_update(hess, sv, yv, nvar, hs)
        for i in range(3):
            W[i] = Wt[i]
            grad[i] = gt[i]
        fval = ft
    y_out[3] = W[0]
    y_out[4] = W[1]
    y_out[5] = W[2] if rot else 0.0
    y_out[0] = y[0] + h * y_out[3]
    y_out[1] = y[1] + h * y_out[4]
    y_out[2] = y[2] + h * y_out[5]
    return MODE_SLIDE, n_eval


@njit(cache=True)
def _constant_friction(strips):
    """
    (every loaded strip has a constant μ, the largest μ_k / μ_s among them).

    The ratio is inf where a strip holds nothing at rest but rubs while sliding.
    """
    constant = True
    ratio = 1.0
    for k in range(strips.shape[0]):
        if strips[k, S_WEIGHT] <= 0.0:
            continue
        law = int(strips[k, S_LAW])
        if not law_is_constant(law):
            constant = False
            continue
        params = strips[k, S_PARAMS:]
        mus = mu_static(law, params)
        muk = mu_kinetic(law, params, 1.0)
        if mus > 0.0:
            ratio = max(ratio, muk / mus)
        elif muk > 0.0:
            ratio = math.inf
    return constant, ratio


@njit(cache=True)
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


@njit(cache=True)
def run_implicit(
    y0, mode0, t0, t_end, y_target, strips, parcel, nodes, weights, h, ts, ys, ms, ev, counters
):
    """Fixed-step implicit integration; the scrap line is located by linear interpolation."""
    nsurf = n_surf_of(strips)
    # constant μ everywhere: the exact step (no point set); its bound on the others' pull
    exact, mu_ratio = _constant_friction(strips)
    cap = 1 if exact else 4 * nodes.shape[0] * nodes.shape[0] * MAX_VERTS * strips.shape[0] + 1
    pts = np.empty((cap, 6))
    xis = np.zeros((nsurf, GAUGE_CARRY))
    guess = np.empty(3)
    w_last = np.empty(3)
    h_last = 0.0
    hess = np.zeros((3, 3))
    y = y0.copy()
    y_new = np.empty(6)
    t = t0
    mode = mode0
    n_out = _record(ts, ys, ms, 0, t, y, mode)
    n_ev = 0
    n_steps = 0
    n_rhs = 0
    status = ST_END
    # step times as t0 + i h, so round-off never adds a sliver of a last step
    n_total = max(1, int(math.ceil((t_end - t0) / h - 1e-9)))
    for i_step in range(n_total):
        t_next = t_end if i_step == n_total - 1 else t0 + (i_step + 1) * h
        hh = t_next - t
        # W+ predicted by the last step's change of velocity, where it slid throughout
        for i in range(3):
            guess[i] = y[3 + i]
            if mode < 0 and h_last > 0.0:
                guess[i] += (y[3 + i] - w_last[i]) * (hh / h_last)
            w_last[i] = y[3 + i]
        new_mode, its = implicit_step(
            y,
            hh,
            mode,
            strips,
            parcel,
            nodes,
            weights,
            exact,
            mu_ratio,
            pts,
            guess,
            hess,
            h_last == 0.0,  # the Hessian carried from a sliding step, or a fresh model
            xis,
            y_new,
        )
        h_last = hh if new_mode < 0 else 0.0
        n_rhs += its
        n_steps += 1
        if new_mode != mode:
            n_ev = _log_event(
                ev,
                n_ev,
                t + hh,
                EV_STICK if new_mode >= 0 else EV_BREAK,
                new_mode if new_mode >= 0 else mode,
            )
        if not np.all(np.isfinite(y_new)):
            status = ST_NONFINITE
            break
        mode = new_mode
        t, crossed = _take_fixed_step(y, y_new, t, t_next, y_target)
        n_out = _record(ts, ys, ms, n_out, t, y, mode)
        if crossed:
            n_ev = _log_event(ev, n_ev, t, EV_TARGET, -1)
            status = ST_TARGET
            break
        if n_out >= ts.shape[0]:
            status = ST_MAX_STEPS
            break
    counters[0] = n_steps
    counters[1] = n_rhs
    counters[2] = 0  # a fixed step is never rejected
    counters[3] = n_out
    counters[4] = n_ev
    return status, t, mode


# ---------------------------------------------------------------- the seed's threshold model
@njit(cache=True)
def rhs_threshold(state, strips, parcel, nodes, weights, nsurf, v_min, out, modes_out):
    """
    Eqs. 4.1/4.2/4.4: kinetic where a surface slips faster than v_min, else static.

    A 'static' surface answers the kinetic pull of the others with at most its limit
    (middle rows of eqs. 4.2 and 4.4); its own kinetic wrench is not applied.
    modes_out[s] = 1 where surface s is static in force.
    """
    kin = np.empty((nsurf, 3))
    stat = np.empty((nsurf, 2))
    area = np.empty(nsurf)
    slip = np.empty(nsurf)
    evaluate_surfaces(state, strips, parcel, nodes, weights, -2, True, kin, stat, area, slip)
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


@njit(cache=True)
def run_threshold(
    y0,
    mode0,
    t0,
    t_end,
    y_target,
    strips,
    parcel,
    nodes,
    weights,
    h,
    v_min,
    ts,
    ys,
    ms,
    ev,
    counters,
):
    """Classic RK4 at a fixed step on the seed's threshold model."""
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
    n_out = _record(ts, ys, ms, 0, t, y, mode0)
    n_ev = 0
    n_steps = 0
    status = ST_END
    n_total = max(1, int(math.ceil((t_end - t0) / h - 1e-9)))
    for i_step in range(n_total):
        t_next = t_end if i_step == n_total - 1 else t0 + (i_step + 1) * h
        hh = t_next - t
        rhs_threshold(y, strips, parcel, nodes, weights, nsurf, v_min, k1, mo)
        code = 0
        for s in range(nsurf):
            code += mo[s] << s
        for j in range(6):
            yt[j] = y[j] + 0.5 * hh * k1[j]
        rhs_threshold(yt, strips, parcel, nodes, weights, nsurf, v_min, k2, mo)
        for j in range(6):
            yt[j] = y[j] + 0.5 * hh * k2[j]
        rhs_threshold(yt, strips, parcel, nodes, weights, nsurf, v_min, k3, mo)
        for j in range(6):
            yt[j] = y[j] + hh * k3[j]
        rhs_threshold(yt, strips, parcel, nodes, weights, nsurf, v_min, k4, mo)
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
        n_out = _record(ts, ys, ms, n_out, t, y, rec_mode)
        if crossed:
            n_ev = _log_event(ev, n_ev, t, EV_TARGET, -1)
            status = ST_TARGET
            break
        if n_out >= ts.shape[0]:
            status = ST_MAX_STEPS
            break
    counters[0] = n_steps
    counters[1] = 4 * n_steps
    counters[2] = 0
    counters[3] = n_out
    counters[4] = n_ev
    return status, t, MODE_SLIDE
