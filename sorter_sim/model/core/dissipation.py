"""
A model of the Hessian of the friction's dissipation rate, for Newton's steps.

The implicit method's velocity step minimises an objective whose nonsmooth part is
the dissipation rate D = Σ ∫ μ p |u| dA (seed eqs. 4.1-4.9 integrated against the
twist); ``dissipation_hessian`` sets the scale and shape of its Newton steps.
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.core.friction import mu_kinetic
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
    P_MASS,
    S_LAW,
    S_PARAMS,
    S_VX,
    S_VY,
    S_WEIGHT,
    S_XHI,
    S_XLO,
)


@borrowing
def add_slip_curvature(out, c, ux, uy, sp, rx, ry):
    """
    Add the Hessian of c |u| in the twist, c Jᵀ(I - ûûᵀ)J / |u|, to the upper triangle of ``out``.

    u = (ux, uy) the rubbing velocity of a point at r = (rx, ry) from g, sp = |u| > 0,
    J = [[1, 0, -r_y], [0, 1, r_x]] its velocity's derivative in the twist. As
    I - ûûᵀ = n nᵀ with n = ẑ × û, it is one rank-one term.

    Parameters
    ----------
    out : ndarray
        Receives the result.
    c : float
        The coefficient of |u|.
    ux : float
        The twist's velocity x [m/s].
    uy : float
        The twist's velocity y [m/s].
    sp : float
        The rubbing speed |u| [m/s].
    rx : float
        The point's offset x from the centre of gravity [m].
    ry : float
        Its offset y [m].

    """
    c = c / sp
    jn0 = -uy / sp
    jn1 = ux / sp
    jn2 = -ry * jn0 + rx * jn1
    out[0, 0] += c * jn0 * jn0
    out[0, 1] += c * jn0 * jn1
    out[0, 2] += c * jn0 * jn2
    out[1, 1] += c * jn1 * jn1
    out[1, 2] += c * jn1 * jn2
    out[2, 2] += c * jn2 * jn2


@kernel
def dissipation_hessian(state, strips, parcel, out):
    """
    Model the Hessian of the dissipation rate D at the twist in ``state`` (3 x 3, ``out``).

    D(V, φ̇) = Σ ∫ μ p |u| dA over the footprint, so ∇²D = Σ ∫ μ p Jᵀ(I - ûûᵀ)J / |u| dA
    with J = [[1, 0, -r_y], [0, 1, r_x]], r = p - g (moments about g), μ taken as
    constant at each point's speed. Summed here at the centroid of each triangle of
    the centroid fan: the integrand's 1/|u| is integrable but not smooth at an
    instantaneous centre inside a patch, so this is a model that sets the scale and
    shape of Newton's steps (the implicit step's), not a value.

    Parameters
    ----------
    state : ndarray, shape (6,)
        The state: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.
    strips : ndarray, shape (n, STRIP_WIDTH)
        The strips (``layout``).
    parcel : ndarray, shape (PARCEL_WIDTH,)
        The parcel's row (``layout``).
    out : ndarray
        Receives the result.

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
    out[:, :] = 0.0
    for k in range(strips.shape[0]):
        w = strips[k, S_WEIGHT]
        if w <= 0.0:
            continue
        n = clip_to_strip(corners, strips[k, S_XLO], strips[k, S_XHI], poly, work)
        a, qx, qy = polygon_area_centroid(poly, n)
        if a <= 0.0:
            continue
        law = int(strips[k, S_LAW])
        params = strips[k, S_PARAMS:]
        for i in range(n):
            j = (i + 1) % n
            e0x = poly[i, 0] - qx
            e0y = poly[i, 1] - qy
            dex = poly[j, 0] - poly[i, 0]
            dey = poly[j, 1] - poly[i, 1]
            det = e0x * dey - e0y * dex
            rx = qx + (e0x + e0x + dex) / 3.0 - x
            ry = qy + (e0y + e0y + dey) / 3.0 - y
            ux = state[3] - state[5] * ry - strips[k, S_VX]
            uy = state[4] + state[5] * rx - strips[k, S_VY]
            sp = max(math.sqrt(ux * ux + uy * uy), 1e-300)
            c = 0.5 * det * p_unit * w * mu_kinetic(law, params, sp)
            add_slip_curvature(out, c, ux, uy, sp, rx, ry)
    out[1, 0] = out[0, 1]
    out[2, 0] = out[0, 2]
    out[2, 1] = out[1, 2]


__all__ = ["add_slip_curvature", "dissipation_hessian"]
