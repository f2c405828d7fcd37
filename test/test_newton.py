"""
The Newton solver both stick solves share, on problems with a closed-form answer.

On the plane: the minimum of a norm ||ξ||_A = sqrt(ξᵀAξ) on W·ξ = 1 is
1/sqrt(WᵀA⁻¹W), at ξ* = A⁻¹W/(WᵀA⁻¹W) (the gauge of W in the ellipsoid whose support
function the norm is: the limit-set gauge's problem with a known limit set). On the
sphere: the minimum of ξᵀBξ is B's smallest eigenvalue, at its eigenvector. Each with
the metric carried from an earlier solve, none, or a wrong one.
"""

import math

import numpy as np
import pytest
from numba import njit

from sorter_sim.model.core.newton import make_plane_newton


# objectives allocate nothing (the solver is compiled without numba's runtime)
@njit(cache=True)
def _norm_a(z, ctx, g):
    (a,) = ctx
    v2 = 0.0
    for i in range(3):
        g[i] = a[i, 0] * z[0] + a[i, 1] * z[1] + a[i, 2] * z[2]
        v2 += z[i] * g[i]
    v = math.sqrt(v2)
    for i in range(3):
        g[i] /= v
    return v


@njit(cache=True)
def _quadratic(z, ctx, g):
    (b,) = ctx
    v = 0.0
    for i in range(3):
        bz = b[i, 0] * z[0] + b[i, 1] * z[1] + b[i, 2] * z[2]
        g[i] = 2.0 * bz
        v += z[i] * bz
    return v


_plane_solver = make_plane_newton(_norm_a, False)
_sphere_solver = make_plane_newton(_quadratic, True)


def _plane(z, ctx, normal, planar, scale_floor, metric, g, work):
    # the solver starts from the objective the caller evaluated to choose its start
    return _plane_solver(z, ctx, normal, planar, scale_floor, metric, _norm_a(z, ctx, g), g, work)


def _sphere(z, ctx, normal, planar, scale_floor, metric, g, work):
    f = _quadratic(z, ctx, g)
    return _sphere_solver(z, ctx, normal, planar, scale_floor, metric, f, g, work)


def _spd(rng, spread):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q @ np.diag(spread) @ q.T


@pytest.mark.parametrize('seed', range(6))
def test_the_minimum_of_a_norm_on_a_plane_is_its_dual_norm(seed):
    rng = np.random.default_rng(seed)
    a = _spd(rng, [1.0, 4.0, 25.0])  # an ellipsoidal limit set, 5:1 in its axes
    w = rng.normal(size=3)
    dual = math.sqrt(w @ np.linalg.solve(a, w))
    xi_star = np.linalg.solve(a, w) / dual**2
    metric = np.zeros(4)
    for start in (w / (w @ w), xi_star + 0.3 * np.cross(w, rng.normal(size=3))):
        z = start.copy()
        g = np.empty(3)
        value = _plane(z, (a,), w, False, 0.0, metric, g, np.empty((4, 3)))
        assert value == pytest.approx(1.0 / dual, rel=1e-12)
        assert w @ z == pytest.approx(1.0, rel=1e-12)  # the steps stay on the plane
        np.testing.assert_allclose(z, xi_star, rtol=0, atol=1e-7 * np.linalg.norm(xi_star))
    assert metric[0] > 0.0  # a metric was differenced and carried: its axis + 1


@pytest.mark.parametrize(
    'wrong', [(-1.0, 0.0, -1.0), (1e6, 0.0, 1e6), (1e-6, 0.0, 1e-6), (1.0, 5.0, 1.0)]
)
def test_a_wrong_carried_metric_costs_iterations_not_the_answer(wrong):
    rng = np.random.default_rng(11)
    a = _spd(rng, [1.0, 4.0, 25.0])
    w = rng.normal(size=3)
    dual = math.sqrt(w @ np.linalg.solve(a, w))
    fresh = np.zeros(4)
    z = w / (w @ w)
    _plane(z, (a,), w, False, 0.0, fresh, np.empty(3), np.empty((4, 3)))
    for axis in (fresh[0], 1.0, 2.0, 3.0):  # its own basis, or another one's
        metric = np.array([axis, *wrong])
        z = w / (w @ w)
        value = _plane(z, (a,), w, False, 0.0, metric, np.empty(3), np.empty((4, 3)))
        assert value == pytest.approx(1.0 / dual, rel=1e-12), (axis, wrong)


@pytest.mark.parametrize('seed', range(4))
def test_the_minimum_of_a_quadratic_on_the_sphere_is_its_least_eigenvalue(seed):
    rng = np.random.default_rng(100 + seed)
    b = _spd(rng, [0.5, 2.0, 3.0])
    lam, vec = np.linalg.eigh(b)
    z = rng.normal(size=3)
    z /= np.linalg.norm(z)
    if z @ vec[:, 0] < 0:
        z = -z  # start in the least eigenvector's hemisphere
    g = np.empty(3)
    value = _sphere(z, (b,), z.copy(), False, 0.0, np.zeros(4), g, np.empty((4, 3)))
    assert value == pytest.approx(lam[0], rel=1e-12)
    assert np.linalg.norm(z) == pytest.approx(1.0, rel=1e-14)  # retracted onto the sphere
    assert abs(z @ vec[:, 0]) == pytest.approx(1.0, abs=1e-9)


def test_on_the_great_circle_it_stays_in_the_plane():
    b = np.diag([2.0, 0.7, 0.1])  # the least eigenvector, z, is off the circle
    z = np.array([0.6, 0.8, 0.0])
    value = _sphere(z, (b,), z.copy(), True, 0.0, np.zeros(4), np.empty(3), np.empty((4, 3)))
    assert z[2] == 0.0
    assert value == pytest.approx(0.7, rel=1e-12)
    assert abs(z[1]) == pytest.approx(1.0, abs=1e-9)
