"""
Footprint geometry: the parcel box, its part over one conveyor strip, and exact integrals.

A zone's share of the footprint (the seed's S_i, eq. 4.3) is the convex polygon
box ∩ {x_lo <= x <= x_hi}: at most six vertices, kept in fixed-size arrays so the
numba kernels allocate nothing large. Besides area and centroid this module gives
two exact integrals over such a polygon P about a point c,

    ∫_P |p - c| dA                 (the seed's ∫ r dS of eq. 4.5, static moment limit)
    ∫_P (p - c)/|p - c| dA         (= ∫ ∇|p - c| dA = ∮ |p - c| n ds)

both by the divergence theorem reduced to the edge integral ∫ sqrt(τ² + h²) dτ,
which has a closed form. They make the constant-μ friction wrench exact
(see ``wrench.py``). Lengths in m, areas in m².
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.core.jit import borrowing

MAX_VERTS = 8


@borrowing
def corner_x(x, phi, half_a, half_b, i):
    """
    Return the x of corner i (``box_corners``' order) of the box centred at x, turned by φ.

    Parameters
    ----------
    x : float
        The centre's x [m].
    phi : float
        The turn [rad].
    half_a : float
        Half the parcel's length A [m].
    half_b : float
        Half the parcel's width B [m].
    i : int
        The corner's index, in ``box_corners``' order.

    Returns
    -------
    float
        The corner's x [m].

    """
    ox = half_a if i < 2 else -half_a
    oy = -half_b if i == 0 or i == 3 else half_b
    return x + math.cos(phi) * ox - math.sin(phi) * oy


@borrowing
def box_corners(x, y, phi, half_a, half_b, out):
    """
    Fill ``out`` with the corners of a box, counter-clockwise.

    Parameters
    ----------
    x, y : float
        Its centre [m].
    phi : float
        Its turn [rad] (A along x at φ = 0).
    half_a, half_b : float
        Half its length A and width B [m].
    out : ndarray, shape (4, 2)
        Receives the corners.

    """
    c = math.cos(phi)
    s = math.sin(phi)
    # order (a,-b) -> (a,b) -> (-a,b) -> (-a,-b) is counter-clockwise
    ox = (half_a, half_a, -half_a, -half_a)
    oy = (-half_b, half_b, half_b, -half_b)
    for i in range(4):
        out[i, 0] = x + c * ox[i] - s * oy[i]
        out[i, 1] = y + s * ox[i] + c * oy[i]


@borrowing
def _clip_halfplane(src, n_src, dst, bound, keep_above):
    """Sutherland-Hodgman step against x >= bound (keep_above) or x <= bound."""
    n = 0
    if n_src == 0:
        return 0
    for i in range(n_src):
        j = (i + 1) % n_src
        xi = src[i, 0]
        xj = src[j, 0]
        if keep_above:
            in_i = xi >= bound
            in_j = xj >= bound
        else:
            in_i = xi <= bound
            in_j = xj <= bound
        if in_i:
            dst[n, 0] = src[i, 0]
            dst[n, 1] = src[i, 1]
            n += 1
        if in_i != in_j:
            t = (bound - xi) / (xj - xi)
            dst[n, 0] = bound
            dst[n, 1] = src[i, 1] + t * (src[j, 1] - src[i, 1])
            n += 1
    return n


@borrowing
def clip_to_strip(corners, x_lo, x_hi, out, work):
    """
    Clip a convex polygon to the strip x_lo <= x <= x_hi.

    Parameters
    ----------
    corners : ndarray, shape (m, 2)
        The polygon, counter-clockwise.
    x_lo, x_hi : float
        The strip's borders [m] (infinite for a half-plane).
    out, work : ndarray, shape (MAX_VERTS, 2)
        ``out`` receives the clipped polygon; ``work`` is scratch.

    Returns
    -------
    int
        The clipped polygon's vertex count (0: no overlap).

    """
    n = 4
    for i in range(4):
        work[i, 0] = corners[i, 0]
        work[i, 1] = corners[i, 1]
    if x_lo > -math.inf:
        n = _clip_halfplane(work, n, out, x_lo, True)
        for i in range(n):
            work[i, 0] = out[i, 0]
            work[i, 1] = out[i, 1]
    if x_hi < math.inf:
        n = _clip_halfplane(work, n, out, x_hi, False)
    else:
        for i in range(n):
            out[i, 0] = work[i, 0]
            out[i, 1] = work[i, 1]
    return n


@borrowing
def polygon_area_centroid(poly, n):
    """
    Return the area and the centroid of a counter-clockwise polygon.

    Parameters
    ----------
    poly : ndarray, shape (>= n, 2)
        The polygon's vertices.
    n : int
        How many of them.

    Returns
    -------
    (float, float, float)
        Its area [m²] (positive) and its centroid's x, y [m].

    """
    if n < 3:
        return 0.0, 0.0, 0.0
    # shift to the first vertex for round-off
    x0 = poly[0, 0]
    y0 = poly[0, 1]
    a2 = 0.0
    cx = 0.0
    cy = 0.0
    for i in range(n):
        j = (i + 1) % n
        xi = poly[i, 0] - x0
        yi = poly[i, 1] - y0
        xj = poly[j, 0] - x0
        yj = poly[j, 1] - y0
        cr = xi * yj - xj * yi
        a2 += cr
        cx += (xi + xj) * cr
        cy += (yi + yj) * cr
    if a2 <= 0.0:
        return 0.0, 0.0, 0.0
    area = 0.5 * a2
    return area, x0 + cx / (3.0 * a2), y0 + cy / (3.0 * a2)


@borrowing
def _edge_sqrt_integral(t0, t1, r0, r1, h):
    """
    Return ∫ sqrt(τ² + h²) dτ from t0 to t1 > t0, given r = sqrt(t² + h²) at both ends.

    It is ½ [t r + h² asinh(t/|h|)] between the ends; the difference of the two asinh
    is taken as one logarithm (asinh(t/|h|) = ±ln((|t| + r)/|h|)), through log1p of a
    ratio's excess over one where both ends lie on one side of the foot of the
    perpendicular: one libm call instead of two, and no cancellation on a short edge
    far from c.
    """
    base = t1 * r1 - t0 * r0
    # the end nearer the foot: t0 + r0 (t0 >= 0) or r1 - t1 (t1 <= 0) is at least |h|,
    # so it vanishes only with h (c on the edge's line, up to rounding of h), where the
    # h² term is nothing
    if t0 >= 0.0:
        # ln((t1 + r1)/(t0 + r0)), with r1 - r0 = (t1 - t0)(t1 + t0)/(r1 + r0)
        near = t0 + r0
        if h == 0.0 or near <= 0.0:
            return 0.5 * base
        diff = math.log1p((t1 - t0) * (1.0 + (t1 + t0) / (r1 + r0)) / near)
    elif t1 <= 0.0:
        # ln((r0 - t0)/(r1 - t1))
        near = r1 - t1
        if h == 0.0 or near <= 0.0:
            return 0.5 * base
        diff = math.log1p((t1 - t0) * (1.0 - (t1 + t0) / (r1 + r0)) / near)
    else:
        if h == 0.0:
            return 0.5 * base
        diff = math.log((t1 + r1) * (r0 - t0) / (h * h))
    return 0.5 * (base + h * h * diff)


@borrowing
def distance_integrals(poly, n, cx, cy):
    """
    Exact (∫_P |p-c| dA, ∫_P (p-c)/|p-c| dA) for a counter-clockwise polygon.

    Returns (I_r, Gx, Gy). Each edge contributes ∫ r ds = ∫ sqrt(τ² + h²) dτ with
    h its signed distance from c: ∫ r dA = (1/3) Σ h_e ∫_e r ds (since ∇·((p-c) r) = 3r)
    and ∫ ∇r dA = Σ n_e ∫_e r ds. A vertex's distance from c serves both its edges.

    Parameters
    ----------
    poly : ndarray, shape (MAX_VERTS, 2)
        A convex polygon's vertices, counter-clockwise [m].
    n : int
        Its vertex count.
    cx : float
        The centre's x [m].
    cy : float
        The centre's y [m].

    Returns
    -------
    (float, float, float)
        ∫_P |p-c| dA and the two components of ∫_P (p-c)/|p-c| dA.

    """
    i_r = 0.0
    gx = 0.0
    gy = 0.0
    if n == 0:
        return i_r, gx, gy
    r_start = math.sqrt((poly[0, 0] - cx) ** 2 + (poly[0, 1] - cy) ** 2)
    r0 = r_start
    for i in range(n):
        j = (i + 1) % n
        r1 = r_start if j == 0 else math.sqrt((poly[j, 0] - cx) ** 2 + (poly[j, 1] - cy) ** 2)
        ex = poly[j, 0] - poly[i, 0]
        ey = poly[j, 1] - poly[i, 1]
        length = math.sqrt(ex * ex + ey * ey)
        if length == 0.0:
            r0 = r1
            continue
        dx = ex / length
        dy = ey / length
        # outward normal of a counter-clockwise polygon
        nx = dy
        ny = -dx
        px = poly[i, 0] - cx
        py = poly[i, 1] - cy
        t0 = px * dx + py * dy  # coordinate of the edge start along the edge
        h = px * nx + py * ny  # signed distance of the edge line from c
        line = _edge_sqrt_integral(t0, t0 + length, r0, r1, h)
        i_r += h * line / 3.0
        gx += nx * line
        gy += ny * line
        r0 = r1
    return i_r, gx, gy


@borrowing
def max_radius(poly, n, qx, qy):
    """
    Largest vertex distance from (qx, qy).

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

    Returns
    -------
    float
        The largest distance [m].

    """
    r2 = 0.0
    for i in range(n):
        dx = poly[i, 0] - qx
        dy = poly[i, 1] - qy
        r2 = max(r2, dx * dx + dy * dy)
    return math.sqrt(r2)


def footprint(x: float, y: float, phi: float, A: float, B: float) -> np.ndarray:
    """
    Return the corners of a parcel's outline (a convenience for callers outside numba).

    Parameters
    ----------
    x, y : float
        The centre of gravity [m].
    phi : float
        The turn [rad].
    A, B : float
        Length and width [m].

    Returns
    -------
    ndarray, shape (4, 2)
        The corners, counter-clockwise.

    """
    out = np.empty((4, 2))
    box_corners(x, y, phi, 0.5 * A, 0.5 * B, out)
    return out
