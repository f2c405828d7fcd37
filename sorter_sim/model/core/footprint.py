"""
The parcel's footprint placed on the conveyor plane and clipped to its strips.

Every wrench starts here: the box's corners at the state's pose (``place_box``), the
convex part of it over a strip (``strip_part``), the load-weighted area over a
surface (``surface_area``), all into one footprint scratch (``clip_scratch``).
"""

from __future__ import annotations

import numpy as np

from sorter_sim.model.core.geometry import (
    MAX_VERTS,
    box_corners,
    clip_to_strip,
    polygon_area_centroid,
)
from sorter_sim.model.core.jit import borrowing, kernel
from sorter_sim.model.core.layout import (
    P_HALF_A,
    P_HALF_B,
    S_SURF,
    S_WEIGHT,
    S_XHI,
    S_XLO,
)

# A footprint scratch (``clip_scratch``): rows [0, 4) the box's corners, then the part
# clipped to a strip (rows [4, 4 + MAX_VERTS)) and the clipper's work polygon. The
# kernels that take one allocate nothing, so they compile without reference counting
# (``jit.borrowing``); a caller makes one for many evaluations.
CLIP_ROWS = 4 + 2 * MAX_VERTS


@kernel
def clip_scratch():
    """Return a footprint scratch for the kernels that take ``clip``."""
    return np.empty((CLIP_ROWS, 2))


@borrowing
def place_box(state, parcel, clip):
    """
    Put the corners of the parcel in ``state`` into ``clip``; returns their x range.

    Parameters
    ----------
    state : ndarray, shape (6,)
        The state: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.
    parcel : ndarray, shape (PARCEL_WIDTH,)
        The parcel's row (``layout``).
    clip : ndarray
        A footprint scratch (``wrench.clip_scratch``).

    Returns
    -------
    (float, float)
        The corners' x range [m].

    """
    c = clip[0:4]
    box_corners(state[0], state[1], state[2], parcel[P_HALF_A], parcel[P_HALF_B], c)
    return min(c[0, 0], c[1, 0], c[2, 0], c[3, 0]), max(c[0, 0], c[1, 0], c[2, 0], c[3, 0])


@borrowing
def strip_part(clip, strips, k, xmin, xmax):
    """
    Clip the box placed in ``clip`` to strip k, into clip[PART]; returns (n, area, qx, qy).

    A strip of no load share, or beyond the box's x range [xmin, xmax], has none (n = 0,
    area 0) for the price of two comparisons.

    Parameters
    ----------
    clip : ndarray
        A footprint scratch (``wrench.clip_scratch``).
    strips : ndarray, shape (n, STRIP_WIDTH)
        The strips (``layout``).
    k : int
        The strip's row.
    xmin : float
        The box's x range, low [m].
    xmax : float
        High [m].

    Returns
    -------
    (int, float, float, float)
        The part's vertex count, area [m²] and centroid [m].

    """
    if strips[k, S_WEIGHT] <= 0.0 or strips[k, S_XHI] <= xmin or strips[k, S_XLO] >= xmax:
        return 0, 0.0, 0.0, 0.0
    poly = clip[4 : 4 + MAX_VERTS]
    n = clip_to_strip(clip[0:4], strips[k, S_XLO], strips[k, S_XHI], poly, clip[4 + MAX_VERTS :])
    a, qx, qy = polygon_area_centroid(poly, n)
    return n, a, qx, qy


@borrowing
def surface_area(state, strips, parcel, surf, clip):
    """
    Footprint area over surface ``surf``, weighted by load share [m²] (clipping only).

    Parameters
    ----------
    state : ndarray, shape (6,)
        The state: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.
    strips : ndarray, shape (n, STRIP_WIDTH)
        The strips (``layout``).
    parcel : ndarray, shape (PARCEL_WIDTH,)
        The parcel's row (``layout``).
    surf : int
        A surface id.
    clip : ndarray
        A footprint scratch (``wrench.clip_scratch``).

    Returns
    -------
    float
        The area [m²].

    """
    xmin, xmax = place_box(state, parcel, clip)
    total = 0.0
    for k in range(strips.shape[0]):
        if int(strips[k, S_SURF]) == surf:
            _, a, _, _ = strip_part(clip, strips, k, xmin, xmax)
            total += strips[k, S_WEIGHT] * a
    return total


__all__ = ["CLIP_ROWS", "clip_scratch", "place_box", "strip_part", "surface_area"]
