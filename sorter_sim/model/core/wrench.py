"""
Friction force and moment on the parcel from each conveyor surface (seed eqs. 4.1-4.9).

Every area element dS of the footprint part over a strip opposes its own rubbing
velocity u(p) = V + φ̇ ẑ×(p - g) - v_surface with dF = -μ(|u|) (m g w / S) û dS.
Because u is the velocity field of a planar rigid motion it vanishes at one point,
the instantaneous centre c of the parcel's motion relative to that surface; then
û = sgn(φ̇) ẑ×(p - c)/|p - c| and, for a constant μ,

    F = -μ p sgn(φ̇) ẑ × ∫ ∇|p - c| dA,
    T = -μ p sgn(φ̇) [∫ |p - c| dA + (c - g)·∫ ∇|p - c| dA],

exact through ``geometry.distance_integrals``, and for pure translation simply
F = -μ p S û, T = (q - g)×F. When c is far away but not at infinity those terms
cancel catastrophically; there the integrand is analytic over the footprint and
the quadrature below is used instead (see ``SMALL_ROTATION``).

A speed-dependent μ needs quadrature. The fan of triangles from c with a Duffy
map p = c + s (e_i + t (e_{i+1} - e_i)) puts the kink of û at s = 0, where the
Jacobian s vanishes, so Gauss-Legendre in (s, t) converges fast (with a sinh
map along edges that pass close to c); when c is far the fan starts at the
centroid and the integrand is smooth anyway: no map there (it would slow Gauss's
convergence on thin slivers), and a constant-μ patch takes only the few points
per direction its ε = |φ̇| R / |u_q| needs (``smooth_order``: 2-4 points below
ε = 0.015 instead of 8, the cost of a nearly translating patch cut 4-16x).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from sorter_sim.model.core.dissipation import add_slip_curvature, dissipation_hessian
from sorter_sim.model.core.footprint import (
    CLIP_ROWS,
    clip_scratch,
    place_box,
    strip_part,
    surface_area,
)
from sorter_sim.model.core.friction import (
    law_is_constant,
    law_smooth_reach,
    mu_kinetic,
    mu_static,
)
from sorter_sim.model.core.geometry import (
    MAX_VERTS,
    distance_integrals,
    max_radius,
)
from sorter_sim.model.core.jit import borrowing, kernel
from sorter_sim.model.core.layout import (
    P_CLOSED,
    P_GRAV,
    P_HALF_A,
    P_HALF_B,
    P_MASS,
    S_LAW,
    S_PARAMS,
    S_SURF,
    S_VX,
    S_VY,
    S_WEIGHT,
)

# |φ̇| R / |u_q| below which the exact formula is not used: it loses about
# eps/ε² to cancellation (terms of size r², r = R/ε, cancel to R²), while the
# integrand is analytic over the footprint and the centroid-fan Gauss rule of
# order n errs by about ε^(2n): at 0.02 both stay near 1e-13.
SMALL_ROTATION = 0.02


@functools.lru_cache(maxsize=32)
def _gauss_legendre_01(n: int):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


def gauss_legendre_01(n: int):
    """
    Gauss-Legendre nodes and weights on [0, 1] (fresh arrays: the rule is computed once).

    Parameters
    ----------
    n : int
        Its vertex count.

    Returns
    -------
    (ndarray, ndarray)
        The nodes and the weights.

    """
    x, w = _gauss_legendre_01(int(n))
    return x.copy(), w.copy()


@borrowing
def closed_form_applies(poly, n, qx, qy, ux_q, uy_q, omega):
    """
    Return True where the exact constant-μ wrench is accurate (translation or a near ICR).

    Parameters
    ----------
    poly : ndarray, shape (MAX_VERTS, 2)
        A convex polygon's vertices, counter-clockwise [m].
    n : int
        Its vertex count.
    qx : float
        Its centroid's x [m].
    qy : float
        Its centroid's y [m].
    ux_q : float
        The rubbing velocity's x at the centroid [m/s].
    uy_q : float
        The rubbing velocity's y at the centroid [m/s].
    omega : float
        The angular velocity [rad/s] relative to the surface.

    Returns
    -------
    bool
        True where the exact constant-μ wrench is accurate.

    """
    if omega == 0.0:
        return True
    return abs(omega) * max_radius(poly, n, qx, qy) >= SMALL_ROTATION * math.hypot(ux_q, uy_q)


# The innermost kernels take scalars: a bundle would be packed and unpacked at each of
# the millions of calls a run makes, and these compile without reference counting
# (``jit.borrowing``), which a tuple of arrays would bring back.
@borrowing
def strip_wrench_closed(poly, n, area, qx, qy, gx, gy, ux_q, uy_q, omega, mu, pressure):  # noqa: PLR0913 — innermost borrowing kernel: scalars, no bundle to build per call (jit.py)
    """
    Exact friction wrench (Fx, Fy, T about g) of a constant-μ strip part.

    Valid where ``closed_form_applies``; for φ̇ = 0 it is F = -μ p S û_q, T = (q - g)×F.

    Parameters
    ----------
    poly : ndarray, shape (MAX_VERTS, 2)
        A convex polygon's vertices, counter-clockwise [m].
    n : int
        Its vertex count.
    area : float
        Its area [m²].
    qx : float
        Its centroid's x [m].
    qy : float
        Its centroid's y [m].
    gx : float
        The centre of gravity's x [m].
    gy : float
        The centre of gravity's y [m].
    ux_q : float
        The rubbing velocity's x at the centroid [m/s].
    uy_q : float
        The rubbing velocity's y at the centroid [m/s].
    omega : float
        The angular velocity [rad/s] relative to the surface.
    mu : float
        The constant friction coefficient.
    pressure : float
        The normal pressure on the part [N/m²] (its load share included).

    Returns
    -------
    (float, float, float)
        Fx, Fy [N] and T about the centre of gravity [N m].

    """
    scale = mu * pressure
    if omega == 0.0:
        uq = math.hypot(ux_q, uy_q)
        if uq == 0.0:
            return 0.0, 0.0, 0.0
        fx = -scale * area * ux_q / uq
        fy = -scale * area * uy_q / uq
        return fx, fy, (qx - gx) * fy - (qy - gy) * fx
    cx = qx - uy_q / omega
    cy = qy + ux_q / omega
    i_r, g_x, g_y = distance_integrals(poly, n, cx, cy)
    sgn = 1.0 if omega > 0.0 else -1.0
    fx = -scale * sgn * (-g_y)
    fy = -scale * sgn * g_x
    t = -scale * sgn * (i_r + (cx - gx) * g_x + (cy - gy) * g_y)
    return fx, fy, t


def _gauss_table(n_max: int):
    nodes = np.zeros((n_max + 1, n_max))
    weights = np.zeros((n_max + 1, n_max))
    for n in range(1, n_max + 1):
        nodes[n, :n], weights[n, :n] = gauss_legendre_01(n)
    return nodes, weights


# Gauss-Legendre rules of 1..8 points on [0, 1] (row n: the n-point rule)
_GL_NODES, _GL_WEIGHTS = _gauss_table(8)

# A constant-μ patch whose instantaneous centre is far away (ε = |φ̇| R / |u_q| small)
# has an integrand analytic over a disk ~R/ε wide, so few points per direction of the
# centroid fan reach rounding: measured on rectangles, slivers and pentagons, the
# n-point rule's largest relative wrench error is ~3e-15 for ε up to these bounds.
_SMOOTH_EPS = (0.0, 0.0, 5e-7, 2e-3, 0.015, 0.05, 0.1, 0.2)


@borrowing
def smooth_order(eps):
    """
    Points per direction that integrate a constant-μ patch with far centre to rounding.

    Parameters
    ----------
    eps : float
        The relative accuracy wanted.

    Returns
    -------
    int
        The points per direction.

    """
    for n in range(2, 8):
        if eps <= _SMOOTH_EPS[n]:
            return n
    return 8


@borrowing
def _fan_centre(qx, qy, ux_q, uy_q, omega, radius):
    """
    Return the centre (cx, cy) of a strip part's quadrature fan, and whether it is the ICR.

    The instantaneous centre of the relative motion, c = q + ẑ×u_q/φ̇, where it lies
    within 4 ``radius`` of the centroid q (the kink of û is then near or inside the
    part, and the Duffy fan from c takes it at s = 0); else the centroid itself.
    """
    if omega != 0.0:
        icx = qx - uy_q / omega
        icy = qy + ux_q / omega
        if math.hypot(icx - qx, icy - qy) < 4.0 * radius:
            return icx, icy, True
    return qx, qy, False


@borrowing
def _smooth_points(ux_q, uy_q, omega, radius, constant, law, params, nq):
    """
    Gauss points per direction enough where μ is analytic over a patch's speeds.

    ε = |φ̇| R / min(|u_q|, reach) (``smooth_order``), reach the law's smooth reach
    (``law_smooth_reach``, inf for a constant μ), where that reach is at least 3|φ̇|R;
    ``nq`` (no fewer points to take) otherwise.
    """
    uq = math.hypot(ux_q, uy_q)
    ns = nq
    spread = abs(omega) * radius  # the patch's speeds lie within uq ± spread
    reach = math.inf if constant else law_smooth_reach(law, params, uq)
    if uq > 0.0 and spread == 0.0:
        # a patch in pure translation rubs at one speed: μ is one number over it,
        # whatever the law (a law not analysed for smoothness has reach 0, and
        # 0/0 below would be no order at all)
        ns = smooth_order(0.0)
    elif uq > 0.0 and reach >= 3.0 * spread:
        # analytic over a disk ~min(uq, reach)/|φ̇| wide: ε measured against both
        ns = smooth_order(spread / min(uq, reach))
    return ns


@borrowing
def strip_wrench_quad(  # noqa: PLR0913 — innermost borrowing kernel: scalars, no bundle to build per call (jit.py)
    poly,
    n,
    qx,
    qy,
    gx,
    gy,
    ux_q,
    uy_q,
    omega,
    law,
    params,
    pressure,
    nodes,
    weights,
    adapt=False,
    mu_fixed=-1.0,
):
    """
    Friction wrench (Fx, Fy, T about g) of a strip part by Duffy-fan Gauss quadrature.

    μ is the law's kinetic μ(|u|) at every point, or ``mu_fixed`` where that is >= 0
    (a coefficient of rest, the same at every speed).

    With ``adapt`` a patch whose instantaneous centre is far away takes the fewer points
    of ``smooth_order`` (never more than ``nodes`` has) where μ is analytic over its
    speeds and well beyond (``law_smooth_reach`` at least 3|φ̇|R; ε taken against the
    nearer of |u_q| and that reach, as a knot just outside the patch's speeds slows
    Gauss's convergence as the centre does): a constant μ, or a speed-dependent one
    inside one of its smooth pieces, measured to rounding alike.

    Parameters
    ----------
    poly : ndarray, shape (MAX_VERTS, 2)
        A convex polygon's vertices, counter-clockwise [m].
    n : int
        Its vertex count.
    qx : float
        Its centroid's x [m].
    qy : float
        Its centroid's y [m].
    gx : float
        The centre of gravity's x [m].
    gy : float
        The centre of gravity's y [m].
    ux_q : float
        The rubbing velocity's x at the centroid [m/s].
    uy_q : float
        The rubbing velocity's y at the centroid [m/s].
    omega : float
        The angular velocity [rad/s] relative to the surface.
    law : int
        The friction law's id (``friction.LAW_IDS``).
    params : ndarray
        The law's parameters (``friction.N_LAW_PARAMS``).
    pressure : float
        The normal pressure on the part [N/m²] (its load share included).
    nodes : ndarray
        Gauss-Legendre nodes on [0, 1].
    weights : ndarray
        Their weights.
    adapt : bool
        Refine the fan near the instantaneous centre of rotation.
    mu_fixed : float
        μ to use everywhere; < 0: the law's at each point.

    Returns
    -------
    (float, float, float)
        Fx, Fy [N] and T about the centre of gravity [N m].

    """
    radius = max_radius(poly, n, qx, qy)
    cx, cy, at_icr = _fan_centre(qx, qy, ux_q, uy_q, omega, radius)
    fx = 0.0
    fy = 0.0
    t = 0.0
    nq = nodes.shape[0]
    constant = mu_fixed >= 0.0 or law_is_constant(law)
    mu_const = mu_fixed if mu_fixed >= 0.0 else mu_kinetic(law, params, 1.0)
    if adapt and not at_icr:
        ns = _smooth_points(ux_q, uy_q, omega, radius, constant, law, params, nq)
        if ns < nq:
            nq = ns
            nodes = _GL_NODES[ns, :ns]
            weights = _GL_WEIGHTS[ns, :ns]
    for i in range(n):
        j = (i + 1) % n
        e0x = poly[i, 0] - cx
        e0y = poly[i, 1] - cy
        dex = poly[j, 0] - poly[i, 0]
        dey = poly[j, 1] - poly[i, 1]
        det = e0x * dey - e0y * dex
        if det == 0.0:
            continue
        # Fanned from the instantaneous centre, e(t)/|e(t)| along the edge is nearly
        # singular at t = t_f ± i a, where t_f is the foot of the perpendicular from c
        # and a its distance in units of t; the sinh map t = t_f + a sinh(u) moves that
        # singularity far from the real axis. Fanned from the centroid the integrand is
        # smooth and the map would only slow Gauss's convergence (thin slivers).
        d2 = dex * dex + dey * dey
        t_f = -(e0x * dex + e0y * dey) / d2
        a_t = abs(det) / d2
        use_map = at_icr and a_t < 0.5
        u_lo = math.asinh((0.0 - t_f) / a_t) if use_map else 0.0
        u_hi = math.asinh((1.0 - t_f) / a_t) if use_map else 0.0
        for a in range(nq):
            if use_map:
                u = u_lo + (u_hi - u_lo) * nodes[a]
                tt = t_f + a_t * math.sinh(u)
                jac_t = (u_hi - u_lo) * a_t * math.cosh(u)
            else:
                tt = nodes[a]
                jac_t = 1.0
            ex = e0x + tt * dex
            ey = e0y + tt * dey
            w_edge = weights[a] * jac_t * det * pressure
            for b in range(nq):
                s = nodes[b]
                px = cx + s * ex
                py = cy + s * ey
                ux = ux_q - omega * (py - qy)
                uy = uy_q + omega * (px - qx)
                # speeds are O(1) m/s: no overflow for hypot's scaling to guard against
                sp = math.sqrt(ux * ux + uy * uy)
                if sp == 0.0:
                    continue
                mu = mu_const if constant else mu_kinetic(law, params, sp)
                wgt = w_edge * weights[b] * s * mu / sp
                dfx = -wgt * ux
                dfy = -wgt * uy
                fx += dfx
                fy += dfy
                t += (px - gx) * dfy - (py - gy) * dfx
    return fx, fy, t


@borrowing
def strip_part_wrench(  # noqa: PLR0913 — innermost borrowing kernel: scalars, no bundle to build per call (jit.py)
    poly,
    n,
    a,
    qx,
    qy,
    gx,
    gy,
    ux_q,
    uy_q,
    omega,
    law,
    params,
    mu_fixed,
    pressure,
    nodes,
    weights,
    closed_ok,
):
    """
    Friction wrench (Fx, Fy, T about g) of one strip's part of the footprint.

    Exact (``strip_wrench_closed``) where μ is constant there and the closed form is
    accurate, Gauss quadrature elsewhere; μ is the law's kinetic μ(|u|), or ``mu_fixed``
    where that is >= 0 (a coefficient of rest). ``closed_ok`` False forces quadrature
    (the full model, for checking the reductions).

    Parameters
    ----------
    poly : ndarray, shape (MAX_VERTS, 2)
        A convex polygon's vertices, counter-clockwise [m].
    n : int
        Its vertex count.
    a : float
        Its area [m²].
    qx : float
        Its centroid's x [m].
    qy : float
        Its centroid's y [m].
    gx : float
        The centre of gravity's x [m].
    gy : float
        The centre of gravity's y [m].
    ux_q : float
        The rubbing velocity's x at the centroid [m/s].
    uy_q : float
        The rubbing velocity's y at the centroid [m/s].
    omega : float
        The angular velocity [rad/s] relative to the surface.
    law : int
        The friction law's id (``friction.LAW_IDS``).
    params : ndarray
        The law's parameters (``friction.N_LAW_PARAMS``).
    mu_fixed : float
        μ to use everywhere; < 0: the law's at each point.
    pressure : float
        The normal pressure on the part [N/m²] (its load share included).
    nodes : ndarray
        Gauss-Legendre nodes on [0, 1].
    weights : ndarray
        Their weights.
    closed_ok : bool
        The exact constant-μ wrench may be used where it applies.

    Returns
    -------
    (float, float, float)
        Fx, Fy [N] and T about the centre of gravity [N m].

    """
    constant = mu_fixed >= 0.0 or law_is_constant(law)
    if closed_ok and constant and closed_form_applies(poly, n, qx, qy, ux_q, uy_q, omega):
        mu = mu_fixed if mu_fixed >= 0.0 else mu_kinetic(law, params, 1.0)
        return strip_wrench_closed(poly, n, a, qx, qy, gx, gy, ux_q, uy_q, omega, mu, pressure)
    return strip_wrench_quad(
        poly,
        n,
        qx,
        qy,
        gx,
        gy,
        ux_q,
        uy_q,
        omega,
        law,
        params,
        pressure,
        nodes,
        weights,
        closed_ok,
        mu_fixed,
    )


@borrowing
def kinetic_wrench(state, contact, skip, clip):
    """
    Total kinetic friction wrench (Fx, Fy, T about g) on the parcel in ``state``.

    Every surface but ``skip`` (-1 or less: none) at the law's μ(|u|); the sum of
    ``evaluate_surfaces``' kinetic rows, without its per-surface bookkeeping.

    Parameters
    ----------
    state : ndarray, shape (6,)
        The state: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.
    contact : Contact
        What the parcel slides on (``layout.Contact``).
    skip : int
        A surface left out (-1 or less: none).
    clip : ndarray
        A footprint scratch (``wrench.clip_scratch``).

    Returns
    -------
    (float, float, float)
        Fx, Fy [N] and T about the centre of gravity [N m].

    """
    strips, parcel, nodes, weights = contact
    x = state[0]
    y = state[1]
    om = state[5]
    p_unit = parcel[P_MASS] * parcel[P_GRAV] / (4.0 * parcel[P_HALF_A] * parcel[P_HALF_B])
    closed_ok = parcel[P_CLOSED] > 0.5
    xmin, xmax = place_box(state, parcel, clip)
    poly = clip[4 : 4 + MAX_VERTS]
    fx = 0.0
    fy = 0.0
    t = 0.0
    for k in range(strips.shape[0]):
        if int(strips[k, S_SURF]) == skip:
            continue
        n, a, qx, qy = strip_part(clip, strips, k, xmin, xmax)
        if a <= 0.0:
            continue
        dfx, dfy, dt = strip_part_wrench(
            poly,
            n,
            a,
            qx,
            qy,
            x,
            y,
            state[3] - om * (qy - y) - strips[k, S_VX],
            state[4] + om * (qx - x) - strips[k, S_VY],
            om,
            int(strips[k, S_LAW]),
            strips[k, S_PARAMS:],
            -1.0,
            p_unit * strips[k, S_WEIGHT],
            nodes,
            weights,
            closed_ok,
        )
        fx += dfx
        fy += dfy
        t += dt
    return fx, fy, t


@kernel
def evaluate_surfaces(state, contact, skip_kinetic, need_static, kin, stat, area, slip_c):
    """
    Per-surface kinetic wrench, static limits, contact area and centroid slip speed.

    Fills, for every surface k:
      kin[k]    = (Fx, Fy, T) of kinetic friction from its strips (zero for
                  ``skip_kinetic``, whose slip is zero while the parcel sticks to it),
      stat[k]   = (F_max, T_max) with μ_s: eq. 4.3 and the rest row of eq. 4.5
                  (only when ``need_static``; sliding needs none),
      area[k]   = footprint area over it, weighted by load share [m²],
      slip_c[k] = rubbing speed at the area-weighted centroid of its parts [m/s]
                  (the zone speed the threshold model compares with v_min).
    Strips the footprint does not reach cost one clip and nothing else.

    Parameters
    ----------
    state : ndarray, shape (6,)
        The state: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.
    contact : Contact
        What the parcel slides on (``layout.Contact``).
    skip_kinetic : int
        A surface whose kinetic wrench is left out (the one the parcel sticks to);
        negative: none.
    need_static : bool
        Compute the static limits too.
    kin : ndarray, shape (nsurf, 3)
        Receives each surface's kinetic wrench.
    stat : ndarray, shape (nsurf, 2)
        Receives each surface's static limits (F_max, T_max).
    area : ndarray, shape (nsurf,)
        Receives each surface's footprint area, weighted by load share [m²].
    slip_c : ndarray, shape (nsurf,)
        Receives each surface's slip speed at the footprint's centroid [m/s].

    """
    strips, parcel, nodes, weights = contact
    x = state[0]
    y = state[1]
    vx = state[3]
    vy = state[4]
    om = state[5]
    p_unit = parcel[P_MASS] * parcel[P_GRAV] / (4.0 * parcel[P_HALF_A] * parcel[P_HALF_B])
    closed_ok = parcel[P_CLOSED] > 0.5
    kin[:, :] = 0.0
    stat[:, :] = 0.0
    area[:] = 0.0
    slip_c[:] = 0.0
    qsum = np.zeros((kin.shape[0], 2))
    clip = clip_scratch()
    poly = clip[4 : 4 + MAX_VERTS]
    xmin, xmax = place_box(state, parcel, clip)
    for k in range(strips.shape[0]):
        n, a, qx, qy = strip_part(clip, strips, k, xmin, xmax)
        if a <= 0.0:
            continue
        surf = int(strips[k, S_SURF])
        w = strips[k, S_WEIGHT]
        law = int(strips[k, S_LAW])
        params = strips[k, S_PARAMS:]
        pressure = p_unit * w
        area[surf] += w * a
        qsum[surf, 0] += w * a * qx
        qsum[surf, 1] += w * a * qy
        if need_static:
            mus = mu_static(law, params)
            i_r, _, _ = distance_integrals(poly, n, x, y)
            stat[surf, 0] += mus * pressure * a
            stat[surf, 1] += mus * pressure * i_r
        if surf == skip_kinetic:
            continue
        fx, fy, t = strip_part_wrench(
            poly,
            n,
            a,
            qx,
            qy,
            x,
            y,
            vx - om * (qy - y) - strips[k, S_VX],
            vy + om * (qx - x) - strips[k, S_VY],
            om,
            law,
            params,
            -1.0,
            pressure,
            nodes,
            weights,
            closed_ok,
        )
        kin[surf, 0] += fx
        kin[surf, 1] += fy
        kin[surf, 2] += t
    for s in range(kin.shape[0]):
        if area[s] > 0.0:
            qx = qsum[s, 0] / area[s]
            qy = qsum[s, 1] / area[s]
            # any strip of the surface has its velocity
            for k in range(strips.shape[0]):
                if int(strips[k, S_SURF]) == s:
                    ux = vx - om * (qy - y) - strips[k, S_VX]
                    uy = vy + om * (qx - x) - strips[k, S_VY]
                    slip_c[s] = math.hypot(ux, uy)
                    break


@borrowing
def static_surface_wrench(state, contact, surf, ux, uy, om, clip):
    """
    Friction wrench (Fx, Fy, T about g) of surface ``surf`` at its static coefficients.

    For the rigid twist (ux, uy, om) of the parcel relative to the surface (velocity
    of the centre of gravity relative to the surface [m/s], φ̇ [rad/s]) this is
    -∇D, D(twist) = Σ μ_s p w ∫ |u| dA the patch's dissipation rate at μ_s: the point
    of the patch's limit set (Goyal, Ruina and Papadopoulos 1991) whose outward
    normal is the twist. Exact for polygons (``strip_wrench_closed``) wherever that
    is accurate, Gauss quadrature at constant μ_s elsewhere. ``clip``: a footprint
    scratch (``clip_scratch``).

    Parameters
    ----------
    state : ndarray, shape (6,)
        The state: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.
    contact : Contact
        What the parcel slides on (``layout.Contact``).
    surf : int
        A surface id.
    ux : float
        The twist's velocity x [m/s].
    uy : float
        The twist's velocity y [m/s].
    om : float
        Its angular velocity [rad/s].
    clip : ndarray
        A footprint scratch (``wrench.clip_scratch``).

    Returns
    -------
    (float, float, float)
        Fx, Fy [N] and T about the centre of gravity [N m].

    """
    return rest_surface_wrench(state, contact, surf, ux, uy, om, False, clip)


@borrowing
def rest_surface_wrench(state, contact, surf, ux, uy, om, kinetic, clip):
    """
    Wrench of surface ``surf`` for the twist direction (ux, uy, om), at the coefficient of rest.

    The coefficient is μ_s (``kinetic`` False: the limit set's support point, see
    ``static_surface_wrench``) or the kinetic law's limit at vanishing speed μ_k(0)
    (``kinetic`` True: the friction a patch slipping infinitely slowly with that
    twist direction feels, which a break-away starts from).

    Parameters
    ----------
    state : ndarray, shape (6,)
        The state: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.
    contact : Contact
        What the parcel slides on (``layout.Contact``).
    surf : int
        A surface id.
    ux : float
        The twist's velocity x [m/s].
    uy : float
        The twist's velocity y [m/s].
    om : float
        Its angular velocity [rad/s].
    kinetic : bool
        At μ_k(0) (kinetic, vanishing slip) rather than μ_s.
    clip : ndarray
        A footprint scratch (``wrench.clip_scratch``).

    Returns
    -------
    (float, float, float)
        Fx, Fy [N] and T about the centre of gravity [N m].

    """
    strips, parcel, nodes, weights = contact
    x = state[0]
    y = state[1]
    p_unit = parcel[P_MASS] * parcel[P_GRAV] / (4.0 * parcel[P_HALF_A] * parcel[P_HALF_B])
    closed_ok = parcel[P_CLOSED] > 0.5
    xmin, xmax = place_box(state, parcel, clip)
    poly = clip[4 : 4 + MAX_VERTS]
    fx = 0.0
    fy = 0.0
    t = 0.0
    for k in range(strips.shape[0]):
        if int(strips[k, S_SURF]) != surf:
            continue
        n, a, qx, qy = strip_part(clip, strips, k, xmin, xmax)
        if a <= 0.0:
            continue
        law = int(strips[k, S_LAW])
        params = strips[k, S_PARAMS:]
        mus = mu_kinetic(law, params, 0.0) if kinetic else mu_static(law, params)
        dfx, dfy, dt = strip_part_wrench(
            poly,
            n,
            a,
            qx,
            qy,
            x,
            y,
            ux - om * (qy - y),
            uy + om * (qx - x),
            om,
            law,
            params,
            mus,
            p_unit * strips[k, S_WEIGHT],
            nodes,
            weights,
            closed_ok,
        )
        fx += dfx
        fy += dfy
        t += dt
    return fx, fy, t


__all__ = [
    "CLIP_ROWS",
    "add_slip_curvature",
    "dissipation_hessian",
    "clip_scratch",
    "evaluate_surfaces",
    "kinetic_wrench",
    "place_box",
    "strip_part",
    "strip_part_wrench",
    "surface_area",
    "gauss_legendre_01",
    "smooth_order",
    "rest_surface_wrench",
    "static_surface_wrench",
    "strip_wrench_closed",
    "strip_wrench_quad",
]
