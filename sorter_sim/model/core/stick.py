"""
Sticking: the limit set of wrenches a stuck patch can supply, and the break-away time.

A parcel stuck to a surface moves rigidly with it; the stick holds while the wrench
the surface must supply (to hold it against the other surfaces' friction) lies in
its patch's limit set. Exact stick: that set is the convex set of wrenches a rigid
patch under Coulomb friction can supply (Goyal, Ruina and Papadopoulos 1991), tested
by its gauge (``limit_gauge``, a Newton solve in the plane of twists, warm-started
by the previous gauge) or, well inside, by a cheap bound (``inside_limit_set``).
Seed stick: the decoupled limits of eqs. 4.3/4.5, |F| <= F_max and |T| <= T_max.
While stuck the motion is advanced in closed form (``_stick_advance``), jumping
straight to the next border crossing with a single surface under the parcel; the
break-away instant is located by root finding on the margin (``_break_time``).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from sorter_sim.model.core.common import (
    _alone_on,
    _contact_surfaces,
    _time_to_next_border,
    surface_velocity,
)
from sorter_sim.model.core.friction import mu_static
from sorter_sim.model.core.geometry import (
    MAX_VERTS,
    box_corners,
    clip_to_strip,
    polygon_area_centroid,
)
from sorter_sim.model.core.jit import borrowing, kernel
from sorter_sim.model.core.layout import (
    P_GRAV,
    P_HALF_A,
    P_HALF_B,
    P_INERTIA,
    P_MASS,
    P_ROTATION,
    P_STICK,
    S_LAW,
    S_PARAMS,
    S_SURF,
    S_WEIGHT,
    S_XHI,
    S_XLO,
)
from sorter_sim.model.core.newton import make_plane_newton
from sorter_sim.model.core.wrench import (
    clip_scratch,
    evaluate_surfaces,
    kinetic_wrench,
    static_surface_wrench,
    surface_area,
)

# a parcel riding its surface while stuck: from (y0x, y0y) at t0 with the surface's
# velocity (vsx, vsy); ys is a pose scratch
Ride = namedtuple('Ride', ['y0x', 'y0y', 't0', 'vsx', 'vsy', 'ys'])

STICK_RTOL = 1e-13  # relative: a balance to rounding (a few ulps of the wrench sums) holds
# a limit-set gauge's warm start (``limit_gauge``'s xi): its twist, then its Hessian
GAUGE_CARRY = 7


@borrowing
def _dissipation_gradient(state, contact, surf, rho, z0, z1, z2, clip, out):
    """∇D at the generalized twist (z0, z1, z2) = (ẋ, ẏ, ρφ̇) relative to ``surf``; returns D."""
    fx, fy, ft = static_surface_wrench(state, contact, surf, z0, z1, z2 / rho, clip)
    # the friction wrench is -∇D; D = ξ·∇D by Euler's relation (D is 1-homogeneous)
    out[0] = -fx
    out[1] = -fy
    out[2] = -ft / rho
    return z0 * out[0] + z1 * out[1] + z2 * out[2]


@borrowing
def _dissipation(z, ctx, g):
    """D and ∇D at the generalized twist z; ctx: (state, contact, surf, rho, clip)."""
    state, contact, surf, rho, clip = ctx
    return _dissipation_gradient(state, contact, surf, rho, z[0], z[1], z[2], clip, g)


# the gauge's minimisation of D on the plane W·ξ = 1
_gauge_newton = make_plane_newton(_dissipation, False)


@kernel
def limit_gauge(state, contact, surf, wx, wy, wt, xi, clip):
    """
    Gauge of the wrench (wx, wy, wt) in the limit set of ``surf``'s patch: <= 1 iff it holds.

    A rigid patch under distributed Coulomb friction can supply exactly the wrenches
    W with W·ξ <= D(ξ) for every twist ξ, D the patch's dissipation rate at μ_s
    (``static_surface_wrench``): a convex set whose support function is D. Its gauge
    is γ(W) = max_ξ W·ξ / D(ξ) = 1 / min {D(ξ) : W·ξ = 1}, the minimum of a convex
    function on a plane. It is found by Newton's method in that plane (generalized
    twists (ẋ, ẏ, ρφ̇), ``newton.make_plane_newton``): the gradient is exact (the
    closed-form wrench), the Hessian a forward difference of it. At the
    minimiser ξ* the limit-surface point ∇D(ξ*) = W / γ: ξ* is the twist the patch
    slips with when the stick breaks (maximal dissipation). ``xi`` (in/out) carries
    ξ* between calls: a stick scanned along its path starts each solve next to the
    last minimiser. Of GAUGE_CARRY entries, it carries the last differenced Hessian
    too ([k + 1, |ξ| H] in the plane basis built on axis k; D is 1-homogeneous, so H
    scales as 1/|ξ|): Newton's first steps there take no differences, and the Hessian
    is differenced anew where a step with it backtracks or fails to cut the gradient
    tenfold (it is only Newton's metric). ``clip``: a footprint scratch
    (``wrench.clip_scratch``).

    Parameters
    ----------
    state : ndarray, shape (6,)
        The pose the stick is checked at (``layout``).
    contact : Contact
        What the parcel slides on (``layout.Contact``).
    surf : int
        A surface id.
    wx : float
        The wrench's force x [N].
    wy : float
        The wrench's force y [N].
    wt : float
        Its moment about the centre of gravity [N m].
    xi : ndarray, shape (3,) or (GAUGE_CARRY,), in/out
        The limit-set gauge's warm start: its twist, and (with room) its Newton metric.
    clip : ndarray
        A footprint scratch (``wrench.clip_scratch``).

    Returns
    -------
    float
        γ (0 for W = 0; inf when the patch supplies no friction at all).

    """
    parcel = contact.parcel
    rho = math.sqrt(parcel[P_INERTIA] / parcel[P_MASS])
    w = np.array([wx, wy, wt / rho])
    w2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    if w2 == 0.0:
        return 0.0
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
    ctx = (state, contact, surf, rho, clip)
    d = _dissipation(z, ctx, g)
    if not d > 0.0:
        return math.inf
    # the metric is carried where xi has room for it, else it serves this solve only
    metric = xi[3:GAUGE_CARRY] if xi.shape[0] >= GAUGE_CARRY else np.zeros(4)
    d = _gauge_newton(z, ctx, w, False, 0.0, metric, d, g, np.empty((4, 3)))
    zn = math.sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
    for i in range(3):
        xi[i] = z[i] / zn
    # W·ξ = 1 on the plane; recompute it against drift
    return (w[0] * z[0] + w[1] * z[1] + w[2] * z[2]) / d


@kernel
def stick_margin(state, contact, nsurf, surf, xi):
    """
    Break-away margin of sticking to ``surf`` at this pose (> 0: the stick breaks).

    ``state`` must carry the stuck velocity (surface velocity, φ̇ = 0), so the stuck
    surface must supply exactly the opposite of the others' wrench. Exact stick
    (``P_STICK``): margin = γ - 1, γ that wrench's gauge in the surface's limit set
    (``limit_gauge``; without rotation φ̇ = 0 is a constraint and the set is the disk
    |F| <= F_max). Seed stick: the decoupled test of eqs. 4.2/4.4, |F| <= F_max and
    |T| <= T_max separately, in force units. ``xi`` (3, or GAUGE_CARRY to carry its
    Newton metric too): the gauge's warm start.

    Parameters
    ----------
    state : ndarray, shape (6,)
        The pose the stick is checked at (``layout``).
    contact : Contact
        What the parcel slides on (``layout.Contact``).
    nsurf : int
        The number of surfaces.
    surf : int
        A surface id.
    xi : ndarray, shape (3,) or (GAUGE_CARRY,), in/out
        The limit-set gauge's warm start: its twist, and (with room) its Newton metric.

    Returns
    -------
    (float, float, float, float, float)
        The margin (> 0: the stick breaks), the area of ``surf``, and Fx, Fy, T of
        the other surfaces' kinetic wrench.

    """
    strips, parcel = contact.strips, contact.parcel
    # a pull equal to the capacity within STICK_RTOL holds: at an exact balance (the
    # disks carrying half the load at the belt's μ, a stroke of 0.5) rounding would
    # otherwise break the stick and make it again at every step, without end
    if parcel[P_ROTATION] > 0.5 and parcel[P_STICK] > 0.5:
        clip = clip_scratch()
        fx, fy, t = kinetic_wrench(state, contact, surf, clip)
        a = surface_area(state, strips, parcel, surf, clip)
        if a <= 0.0:
            return (math.inf if fx != 0.0 or fy != 0.0 or t != 0.0 else 0.0), 0.0, fx, fy, t
        gamma = limit_gauge(state, contact, surf, fx, fy, t, xi, clip)
        return gamma - (1.0 + STICK_RTOL), a, fx, fy, t
    kin = np.empty((nsurf, 3))
    stat = np.empty((nsurf, 2))
    area = np.empty(nsurf)
    slip = np.empty(nsurf)
    evaluate_surfaces(state, contact, surf, True, kin, stat, area, slip)
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


@kernel
def _margin_at(tt, ride, contact, nsurf, surf, xi):
    """
    Stick margin and contact area on ``surf`` at time tt of a parcel carried from t0.

    The parcel translates rigidly with the surface from (y0x, y0y); ``ys`` (the stuck
    state) gets the pose at tt.
    """
    y0x, y0y, t0, vsx, vsy, ys = ride.y0x, ride.y0y, ride.t0, ride.vsx, ride.vsy, ride.ys
    ys[0] = y0x + vsx * (tt - t0)
    ys[1] = y0y + vsy * (tt - t0)
    m, a, _, _, _ = stick_margin(ys, contact, nsurf, surf, xi)
    return m, a


@kernel
def _break_time(
    lo,
    hi,
    m_hi,
    ride,
    contact,
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
    fpre, _ = _margin_at(lo, ride, contact, nsurf, surf, xi)
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
        fcur, _ = _margin_at(xcur, ride, contact, nsurf, surf, xi)
        counters[0] += 1
    # the breaking side of the final bracket, within the tolerance of the root
    return xcur if fcur > 0.0 else xblk


@kernel
def _stick_advance(  # noqa: PLR0915 — scan, jump, locate the break: the ride's state stays local
    y,
    surf,
    t,
    t_end,
    slide,
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
    y_target, contact, nsurf, borders = slide.y_target, slide.contact, slide.nsurf, slide.borders
    strips, parcel = contact.strips, contact.parcel
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
        m, a, _, _, _ = stick_margin(y, contact, nsurf, surf, xi)
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
            fx, fy, tq = kinetic_wrench(ys, contact, surf, clip)
            counters[0] += 1
            if inside_limit_set(ys, strips, parcel, surf, fx, fy, tq):
                t = t_next
                y[0] = ys[0]
                y[1] = ys[1]
                continue
        m, a = _margin_at(t_next, Ride(y0x, y0y, t0, vsx, vsy, ys), contact, nsurf, surf, xi)
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
                    Ride(y0x, y0y, t0, vsx, vsy, ys),
                    contact,
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


@kernel
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

    Parameters
    ----------
    state : ndarray, shape (6,)
        The pose the stick is checked at (``layout``).
    strips : ndarray, shape (n, STRIP_WIDTH)
        The strips (``layout``).
    parcel : ndarray, shape (PARCEL_WIDTH,)
        The parcel's row (``layout``).
    surf : int
        A surface id.
    fx : float
        The wrench's force x [N].
    fy : float
        The wrench's force y [N].
    t : float
        Its moment about the centre of gravity [N m].

    Returns
    -------
    bool
        True if the bound shows the wrench inside (False decides nothing).

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
