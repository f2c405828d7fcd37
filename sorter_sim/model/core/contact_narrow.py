"""
The narrow phase of parcels that touch: where two turned boxes touch, and along what.

``contact`` finds the pairs in reach (broad phase) and solves their contacts; this
module says, for one pair of boxes (parcels, or the walls and rails, which are
boxes too), the contact points with their normal and separation, by the separating
axes and the clipping of the incident face to the reference face.

Units: SI (m, rad).
"""

from __future__ import annotations

import math

from sorter_sim.model.core.jit import kernel_step

# a reference face is kept unless the other body's face separates by this much more
# [m]: two parallel faces keep one reference from period to period (stable features)
_FACE_BIAS = 1e-9


@kernel_step
def box_polygon(poly, x, y, phi, ha, hb):
    """Write a box's corners (counter-clockwise) and its faces' outward normals into ``poly``."""
    c = math.cos(phi)
    s = math.sin(phi)
    # corners (-a,-b), (a,-b), (a,b), (-a,b); face q runs from corner q to q + 1
    for q in range(4):
        lx = ha if q == 1 or q == 2 else -ha
        ly = hb if q >= 2 else -hb
        poly[q, 0] = x + c * lx - s * ly
        poly[q, 1] = y + s * lx + c * ly
    # outward normals (0,-1), (1,0), (0,1), (-1,0) turned by φ
    poly[0, 2] = s
    poly[0, 3] = -c
    poly[1, 2] = c
    poly[1, 3] = s
    poly[2, 2] = -s
    poly[2, 3] = c
    poly[3, 2] = -c
    poly[3, 3] = -s


@kernel_step
def _max_separation(p1, p2):
    """Return the face of box ``p1`` separating it most from box ``p2``, and the separation [m]."""
    best = -math.inf
    face = 0
    for q in range(4):
        nx = p1[q, 2]
        ny = p1[q, 3]
        least = math.inf
        for r in range(4):
            d = nx * (p2[r, 0] - p1[q, 0]) + ny * (p2[r, 1] - p1[q, 1])
            least = min(least, d)
        if least > best:
            best = least
            face = q
    return face, best


@kernel_step
def _clip(xa, ya, xb, yb, tx, ty, offset):
    """
    Clip the segment a-b to the half-plane t·p <= offset; return the clipped ends and a flag.

    Returns (x0, y0, x1, y1, kept, which): ``which`` is 0 where nothing was cut, 1 where
    the first end was moved to the plane, 2 where the second was; ``kept`` False where
    the whole segment lies outside.
    """
    da = tx * xa + ty * ya - offset
    db = tx * xb + ty * yb - offset
    if da <= 0.0 and db <= 0.0:
        return xa, ya, xb, yb, True, 0
    if da > 0.0 and db > 0.0:
        return xa, ya, xb, yb, False, 0
    w = da / (da - db)
    xi = xa + w * (xb - xa)
    yi = ya + w * (yb - ya)
    if da > 0.0:
        return xi, yi, xb, yb, True, 1
    return xa, ya, xi, yi, True, 2


@kernel_step
def box_contacts(poly, reach, out_f, out_fid):
    """
    Contact points of the two boxes in ``poly`` (``box_polygon``) closer than ``reach``.

    The reference face is the face of greatest separation over both boxes' faces (the
    separating axes of two rectangles), the incident edge the other box's face most
    opposed to it, clipped to the reference face's two side planes; each clipped end
    within ``reach`` of the reference face is a contact point. Writes up to two rows
    (point x, y, normal x, y from box 0 to box 1, separation) into ``out_f`` and a
    feature number each into ``out_fid`` (the faces and the clipping: the same contact
    in the next period has the same number).

    Returns
    -------
    int
        The number of points (0, 1 or 2).

    """
    face_a, sep_a = _max_separation(poly[0], poly[1])
    if sep_a > reach:
        return 0
    face_b, sep_b = _max_separation(poly[1], poly[0])
    if sep_b > reach:
        return 0
    ref = 0
    face = face_a
    if sep_b > sep_a + _FACE_BIAS:
        ref = 1
        face = face_b
    rp = poly[ref]
    ip = poly[1 - ref]
    nx = rp[face, 2]
    ny = rp[face, 3]
    # the incident face: the other box's face whose normal is most opposed to n
    inc = 0
    least = math.inf
    for q in range(4):
        d = ip[q, 2] * nx + ip[q, 3] * ny
        if d < least:
            least = d
            inc = q
    x0 = ip[inc, 0]
    y0 = ip[inc, 1]
    x1 = ip[(inc + 1) % 4, 0]
    y1 = ip[(inc + 1) % 4, 1]
    # the reference face from corner v1 to v2, its tangent t = (-ny, nx)... as the corners run
    v1x = rp[face, 0]
    v1y = rp[face, 1]
    v2x = rp[(face + 1) % 4, 0]
    v2y = rp[(face + 1) % 4, 1]
    tx = v2x - v1x
    ty = v2y - v1y
    tl = math.sqrt(tx * tx + ty * ty)
    tx /= tl
    ty /= tl
    x0, y0, x1, y1, kept, cut_lo = _clip(x0, y0, x1, y1, -tx, -ty, -(tx * v1x + ty * v1y))
    if not kept:
        return 0
    x0, y0, x1, y1, kept, cut_hi = _clip(x0, y0, x1, y1, tx, ty, tx * v2x + ty * v2y)
    if not kept:
        return 0
    sign = 1.0 if ref == 0 else -1.0
    n_pts = 0
    for e in range(2):
        px = x0 if e == 0 else x1
        py = y0 if e == 0 else y1
        sep = nx * (px - v1x) + ny * (py - v1y)
        if sep <= reach:
            out_f[n_pts, 0] = px
            out_f[n_pts, 1] = py
            out_f[n_pts, 2] = sign * nx
            out_f[n_pts, 3] = sign * ny
            out_f[n_pts, 4] = sep
            # which end of which clipped incident face against which reference face
            cut = cut_lo if e == 0 else cut_hi
            which_end = (1 if e == 0 else 2) if cut != (1 if e == 0 else 2) else 0
            out_fid[n_pts] = (((ref * 4 + face) * 4 + inc) * 3 + which_end) * 2 + e
            n_pts += 1
    return n_pts
