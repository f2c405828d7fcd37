"""
Friction laws, footprint geometry and the friction wrench.

Friction laws (Fig. 3), footprint geometry and the friction wrench, against closed forms
and independent brute-force integrals.
"""

import math
from typing import NamedTuple

import numpy as np
import pytest

from sorter_sim.model.core import friction as fr
from sorter_sim.model.core.geometry import (
    clip_to_strip,
    distance_integrals,
    footprint,
    polygon_area_centroid,
)
from sorter_sim.model.core.simulate import FrictionLaw
from sorter_sim.model.core.wrench import gauss_legendre_01, strip_wrench_closed, strip_wrench_quad


# ---------------------------------------------------------------- friction laws
def test_constant_laws():
    two = fr.law_row(fr.LAW_CONST2, [0.65, 0.46])
    assert fr.mu_static(fr.LAW_CONST2, two) == 0.65
    for v in (1e-9, 0.3, 2.5):
        assert fr.mu_kinetic(fr.LAW_CONST2, two, v) == 0.46
    one = fr.law_row(fr.LAW_CONST1, [0.6])
    assert fr.mu_static(fr.LAW_CONST1, one) == fr.mu_kinetic(fr.LAW_CONST1, one, 1.7) == 0.6


def test_linear_and_polynomial_laws():
    lin = fr.law_row(fr.LAW_LINEAR, [0.65, -0.15])
    assert fr.mu_kinetic(fr.LAW_LINEAR, lin, 1.0) == pytest.approx(0.5)
    assert fr.mu_kinetic(fr.LAW_LINEAR, lin, 10.0) == 0.0  # clipped, never negative
    poly = fr.law_row(fr.LAW_POLY, [0.65, -1.0, 0.0, 2.0])
    for v in (0.1, 0.5, 1.0):
        assert fr.mu_kinetic(fr.LAW_POLY, poly, v) == pytest.approx(0.65 - v + 2 * v**3)


def test_stribeck_formula_of_the_seed():
    mu0, mu_min, b1, b2, b3, vk = 0.65, 0.3, 10.0, 5.0, 1.5, 0.1
    row = fr.law_row(fr.LAW_STRIBECK, [mu0, mu_min, b1, b2, b3, vk])
    for v in (0.02, 0.09, 0.5, 1.0):
        expect = mu_min + (mu0 - mu_min) * math.exp(-b1 * v)
        if v > vk:
            expect += b2 * b3 * (v - vk) / (1 + b2 * (v - vk))
        assert fr.mu_kinetic(fr.LAW_STRIBECK, row, v) == pytest.approx(expect, rel=1e-14)
    assert fr.mu_static(fr.LAW_STRIBECK, row) == mu0


def test_bspline_law_follows_its_curve():
    vals = [0.0, 0.1, 0.25, 0.6, 1.5, 2.5, 0.65, 0.45, 0.42, 0.47, 0.50, 0.52]
    row = fr.law_row(fr.LAW_BSPLINE, vals)
    t = np.linspace(0.0, 1.0, 501)
    v, mu = fr.bspline_curve(vals[:6], vals[6:], t)
    # a clamped b-spline interpolates its end control points
    assert v[0] == 0.0 and mu[0] == pytest.approx(0.65) and mu[-1] == pytest.approx(0.52)
    got = fr.mu_kinetic_array(fr.LAW_BSPLINE, row, v)
    assert np.max(np.abs(got - mu)) < 1e-12
    assert fr.mu_kinetic(fr.LAW_BSPLINE, row, 9.0) == pytest.approx(0.52)  # constant beyond


@pytest.mark.parametrize(
    "model,values",
    [
        ("const2", [0.65, -0.1]),
        ("bspline", [0, 0.2, 0.1, 0.6, 1.5, 2.5, 0.6, 0.5, 0.4, 0.4, 0.5, 0.5]),
        ("const1", [math.nan]),
        ("stribeck", [0.6, 0.3]),
        ("unknown", [1.0]),
    ],
)
def test_bad_laws_are_refused_with_a_reason(model, values):
    with pytest.raises(ValueError, match="friction"):
        FrictionLaw(model, tuple(values))


# ---------------------------------------------------------------- geometry
def _clip(corners, lo, hi):
    out = np.empty((8, 2))
    work = np.empty((8, 2))
    n = clip_to_strip(corners, lo, hi, out, work)
    return out, n


def test_clip_of_an_aligned_box_straddling_the_border():
    c = footprint(0.1, 0.0, 0.0, 0.4, 0.2)  # spans x in [-0.1, 0.3]
    poly, n = _clip(c, 0.0, math.inf)
    area, cx, cy = polygon_area_centroid(poly, n)
    assert area == pytest.approx(0.3 * 0.2)
    assert cx == pytest.approx(0.15) and cy == pytest.approx(0.0, abs=1e-15)
    poly, n = _clip(c, -math.inf, 0.0)
    assert polygon_area_centroid(poly, n)[0] == pytest.approx(0.1 * 0.2)


def test_clip_of_a_rotated_square_by_a_line_through_its_centre():
    # a square at 45 degrees cut through its centre leaves a triangle of half its area
    c = footprint(0.0, 0.0, math.pi / 4, 0.3, 0.3)
    poly, n = _clip(c, 0.0, math.inf)
    area, cx, _ = polygon_area_centroid(poly, n)
    assert area == pytest.approx(0.045)
    # centroid of that right triangle: one third of the half-diagonal from the cut
    assert cx == pytest.approx(0.3 * math.sqrt(2) / 2 / 3)


class Box(NamedTuple):
    """A parcel's footprint: A x B [m], turned by phi [rad], its centre at (x, y) [m]."""

    A: float
    B: float
    phi: float
    x: float
    y: float


def _fine_grid(box: Box, n: int):
    """Return the centres (px, py) of an n x n grid of cells over the footprint, and dA."""
    s = (np.arange(n) + 0.5) / n
    lx, ly = np.meshgrid((s - 0.5) * box.A, (s - 0.5) * box.B)
    px = box.x + math.cos(box.phi) * lx - math.sin(box.phi) * ly
    py = box.y + math.sin(box.phi) * lx + math.cos(box.phi) * ly
    return px, py, box.A * box.B / n / n


def _brute_distance_integrals(box: Box, lo, hi, cx, cy, n=1200):
    px, py, dA = _fine_grid(box, n)
    m = (px >= lo) & (px <= hi)
    r = np.hypot(px - cx, py - cy)
    return (r[m].sum() * dA, ((px - cx) / r)[m].sum() * dA, ((py - cy) / r)[m].sum() * dA)


@pytest.mark.parametrize("c", [(0.05, 0.02), (0.5, -0.3), (0.12, 0.0)])
def test_exact_distance_integrals_against_a_fine_grid(c):
    A, B, phi, x, y = 0.4, 0.2, 0.3, 0.1, 0.05
    corners = footprint(x, y, phi, A, B)
    poly, n = _clip(corners, 0.0, math.inf)
    exact = distance_integrals(poly, n, c[0], c[1])
    brute = _brute_distance_integrals(Box(A, B, phi, x, y), 0.0, math.inf, c[0], c[1])
    # the grid's own error is O(h²) ~ 1e-7 relative here
    assert np.allclose(exact, brute, rtol=2e-5, atol=2e-7)


def test_distance_integral_of_a_square_about_its_centre():
    # ∫|p| dA over a square of side a centred at 0: a³ (√2 + asinh 1)/6
    a = 0.5
    poly, n = _clip(footprint(0.0, 0.0, 0.0, a, a), -math.inf, math.inf)
    i_r, gx, gy = distance_integrals(poly, n, 0.0, 0.0)
    assert i_r == pytest.approx(a**3 * (math.sqrt(2) + math.asinh(1.0)) / 6, rel=1e-13)
    assert abs(gx) < 1e-15 and abs(gy) < 1e-15  # symmetry


@pytest.mark.parametrize("dist", [0.6, 2.0, 10.0, 40.0])
def test_distance_integrals_against_gauss_legendre_outside(dist):
    # A rectangle, c placed at dist x its diagonal from the centroid in eight directions
    # (edges wholly before, wholly after and across the foot of c's perpendicular); the
    # reference is a 60 x 60 Gauss-Legendre rule on the rectangle's own axes, to
    # rounding where c lies outside (|p - c| is analytic there).
    A, B, phi, x, y = 0.4, 0.2, 0.3, 0.1, 0.05
    poly, n = _clip(footprint(x, y, phi, A, B), -math.inf, math.inf)
    area, qx, qy = polygon_area_centroid(poly, n)
    nodes, weights = np.polynomial.legendre.leggauss(60)
    cs, sn = math.cos(phi), math.sin(phi)

    def ref(cx, cy):
        lx = cs * (cx - x) + sn * (cy - y)
        ly = -sn * (cx - x) + cs * (cy - y)
        out = np.zeros(3)
        for u0, u1 in _cells(-A / 2, A / 2, lx):
            for v0, v1 in _cells(-B / 2, B / 2, ly):
                u = 0.5 * (u0 + u1) + 0.5 * (u1 - u0) * nodes
                v = 0.5 * (v0 + v1) + 0.5 * (v1 - v0) * nodes
                uu, vv = np.meshgrid(u, v)
                w = np.outer(weights, weights) * 0.25 * (u1 - u0) * (v1 - v0)
                dx = x + cs * uu - sn * vv - cx
                dy = y + sn * uu + cs * vv - cy
                r = np.hypot(dx, dy)
                out += [(w * r).sum(), (w * dx / r).sum(), (w * dy / r).sum()]
        return out

    size = math.hypot(A, B)
    for k in range(8):
        cx = qx + dist * size * math.cos(k * math.pi / 4 + 0.1)
        cy = qy + dist * size * math.sin(k * math.pi / 4 + 0.1)
        got = np.array(distance_integrals(poly, n, cx, cy))
        want = ref(cx, cy)
        reach = math.hypot(cx - qx, cy - qy) + size
        # rounding, grown by the cancellation of edge terms ~ reach² against ~ area
        assert abs(got[0] - want[0]) <= 1e-13 * area * reach * (reach / size)
        assert np.all(np.abs(got[1:] - want[1:]) <= 1e-13 * area * (reach / size))


def _about_corner(a, b):
    # ∫|p - c| dA over an a x b rectangle with c on a corner: [2abd + a³ ln((b + d)/a)
    # + b³ ln((a + d)/b)] / 6, d its diagonal
    d = math.hypot(a, b)
    return (2 * a * b * d + a**3 * math.log((b + d) / a) + b**3 * math.log((a + d) / b)) / 6


def test_distance_integral_about_a_corner_and_inside():
    # c on a corner (edges through c: h = 0 and t = 0 ends), then inside, where the
    # rectangle is four with c on a corner of each
    a, b, phi, x, y = 0.4, 0.2, 0.7, 0.3, -0.1
    poly, n = _clip(footprint(x, y, phi, a, b), -math.inf, math.inf)
    for i in range(4):
        i_r, _, _ = distance_integrals(poly, n, poly[i, 0], poly[i, 1])
        assert i_r == pytest.approx(_about_corner(a, b), rel=1e-13)
    for lx, ly in [(0.0, 0.0), (0.13, -0.02), (-0.19, 0.099), (0.05, 0.0999999)]:
        cx = x + math.cos(phi) * lx - math.sin(phi) * ly
        cy = y + math.sin(phi) * lx + math.cos(phi) * ly
        want = sum(
            _about_corner(a / 2 + su * lx, b / 2 + sv * ly) for su in (-1, 1) for sv in (-1, 1)
        )
        i_r, _, _ = distance_integrals(poly, n, cx, cy)
        assert i_r == pytest.approx(want, rel=1e-13)


def _cells(lo, hi, cut):
    """Split [lo, hi] at ``cut`` where it lies inside."""
    return [(lo, cut), (cut, hi)] if lo < cut < hi else [(lo, hi)]


# ---------------------------------------------------------------- wrench
def _brute_wrench(box: Box, V, omega, vs, mu_of, lo=0.0, n=1500):
    px, py, dA = _fine_grid(box, n)
    x, y = box.x, box.y
    m = px >= lo
    ux = V[0] - omega * (py - y) - vs[0]
    uy = V[1] + omega * (px - x) - vs[1]
    sp = np.hypot(ux, uy)
    mu = mu_of(sp)
    fx = -(mu * ux / sp)[m].sum() * dA
    fy = -(mu * uy / sp)[m].sum() * dA
    t = ((px - x) * (-mu * uy / sp) - (py - y) * (-mu * ux / sp))[m].sum() * dA
    return np.array([fx, fy, t])


CASES = [
    ((1.0, 0.2), 0.0),
    ((1.0, 0.2), 0.5),
    ((1.0, 0.2), 30.0),
    ((0.0, 1.0), 3.0),
    ((0.0, 1.0 + 1e-9), -8.0),
]


@pytest.mark.parametrize("V,omega", CASES)
def test_closed_form_and_quadrature_wrench_against_a_fine_grid(V, omega):
    A, B, phi, x, y = 0.4, 0.2, 0.4, 0.1, 0.05
    vs = (0.0, 1.0)
    poly, n = _clip(footprint(x, y, phi, A, B), 0.0, math.inf)
    area, qx, qy = polygon_area_centroid(poly, n)
    ux_q = V[0] - omega * (qy - y) - vs[0]
    uy_q = V[1] + omega * (qx - x) - vs[1]
    brute = _brute_wrench(Box(A, B, phi, x, y), V, omega, vs, lambda s: 0.6 + 0 * s)
    closed = np.array(
        strip_wrench_closed(poly, n, area, qx, qy, x, y, ux_q, uy_q, omega, 0.6, 1.0)
    )
    nodes, weights = gauss_legendre_01(12)
    quad = np.array(
        strip_wrench_quad(
            poly,
            n,
            qx,
            qy,
            x,
            y,
            ux_q,
            uy_q,
            omega,
            fr.LAW_CONST1,
            fr.law_row(fr.LAW_CONST1, [0.6]),
            1.0,
            nodes,
            weights,
        )
    )
    scale = 0.6 * area
    assert np.max(np.abs(closed - brute)) < 1e-6 * scale * 10
    assert np.max(np.abs(quad - closed)) < 1e-5 * scale


def test_quadrature_of_a_speed_dependent_law_converges_to_the_fine_grid():
    vals = [0.0, 0.1, 0.25, 0.6, 1.5, 2.5, 0.65, 0.45, 0.42, 0.47, 0.50, 0.52]
    row = fr.law_row(fr.LAW_BSPLINE, vals)
    A, B, phi, x, y = 0.4, 0.2, 0.4, 0.1, 0.05
    V, omega, vs = (1.0, 0.2), 2.0, (0.0, 1.0)
    poly, n = _clip(footprint(x, y, phi, A, B), 0.0, math.inf)
    _, qx, qy = polygon_area_centroid(poly, n)
    ux_q = V[0] - omega * (qy - y) - vs[0]
    uy_q = V[1] + omega * (qx - x) - vs[1]
    brute = _brute_wrench(
        Box(A, B, phi, x, y),
        V,
        omega,
        vs,
        lambda s: fr.mu_kinetic_array(fr.LAW_BSPLINE, row, s.ravel()).reshape(s.shape),
        n=700,
    )
    errs = []
    for nq in (4, 8, 16):
        nodes, weights = gauss_legendre_01(nq)
        q = np.array(
            strip_wrench_quad(
                poly, n, qx, qy, x, y, ux_q, uy_q, omega, fr.LAW_BSPLINE, row, 1.0, nodes, weights
            )
        )
        errs.append(np.max(np.abs(q - brute)))
    assert errs[2] < errs[0]
    assert errs[2] < 2e-6


@pytest.mark.parametrize(
    "model,vals",
    [
        ("const1", [0.6]),
        ("linear", [0.8, -0.3]),
        ("bspline", [0.0, 0.1, 0.25, 0.6, 1.5, 2.5, 0.65, 0.45, 0.42, 0.47, 0.50, 0.52]),
        # control points bunched at low speed: a steep first span
        ("bspline", [0.0, 0.01, 0.02, 0.6, 1.5, 2.5, 0.65, 0.2, 0.6, 0.47, 0.50, 0.52]),
    ],
)
def test_the_adaptive_rule_of_a_nearly_translating_patch_is_exact_to_rounding(model, vals):
    """
    Check the few-point rule of a patch whose instantaneous centre is far away.

    With ``adapt`` such a patch takes ``smooth_order``'s points per direction where μ
    is analytic over its speeds and well beyond: against a 24-point rule, within 1e-13
    of the wrench, for ε = |φ̇|R/|u_q| from 1e-6 to 0.1 and rubbing speeds inside a
    span of the b-spline and 1 % either side of a knot; where a knot lies within 3|φ̇|R
    of the patch's speed it keeps all of its points.
    """
    law = fr.LAW_NAMES[model]
    row = fr.law_row(law, vals)
    # the speeds where μ is not analytic: the spline's knots, the linear law's zero
    knots = [vals[0], row[36], row[37], vals[5]] if model == "bspline" else []
    knots += [-vals[0] / vals[1]] if model == "linear" else []
    poly, n = _clip(footprint(0.1, 0.0, 0.3, 0.4, 0.3), 0.0, math.inf)
    _, qx, qy = polygon_area_centroid(poly, n)
    radius = max(math.hypot(px - qx, py - qy) for px, py in poly[:n])
    nodes, weights = gauss_legendre_01(8)
    ref_nodes, ref_weights = gauss_legendre_01(24)
    speeds = [0.05, 0.3, 0.37, 0.64, 1.0, 3.0]
    speeds += [k * (1.0 + d) for k in knots if k > 0.0 for d in (-0.01, 0.01)]
    for uq in speeds:
        for eps in (1e-6, 1e-4, 2e-3, 0.015, 0.05, 0.1):
            omega = eps * uq / radius
            args = (poly, n, qx, qy, 0.1, 0.0, 0.6 * uq, -0.8 * uq, omega, law, row, 1.0)
            got = np.array(strip_wrench_quad(*args, nodes, weights, True))
            reach = 3.0 * eps * uq
            if any(uq - reach <= k <= uq + reach for k in knots):
                # a knot among its speeds: the full rule, as without adapt
                full = np.array(strip_wrench_quad(*args, nodes, weights))
                assert np.array_equal(got, full), (uq, eps)
                continue
            ref = np.array(strip_wrench_quad(*args, ref_nodes, ref_weights))
            assert np.abs(got - ref).max() <= 1e-13 * np.abs(ref).max(), (uq, eps)
