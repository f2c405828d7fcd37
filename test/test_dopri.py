"""The core's one Dormand-Prince 5(4) pair: its tableau's order conditions, its orders."""

import math

import numpy as np
import pytest
from numba import njit

from sorter_sim.model.core import dopri


def test_tableau_is_consistent():
    # every stage's node is its row sum; both solutions are consistent (weights sum to 1)
    np.testing.assert_allclose(dopri.A.sum(axis=1), dopri.C, atol=1e-15)
    assert dopri.B.sum() == pytest.approx(1.0, abs=1e-15)
    assert dopri.E.sum() == pytest.approx(0.0, abs=1e-15)
    # the 5th-order conditions Σ b c^k = 1/(k+1), k = 1..4
    for k in range(1, 5):
        assert (dopri.B * dopri.C**k).sum() == pytest.approx(1.0 / (k + 1), abs=1e-14)
    # the dense output is the step's end at θ = 1: Σ_j P_ij = b_i (b_7 = 0, FSAL)
    np.testing.assert_allclose(dopri.P.sum(axis=1), np.append(dopri.B, 0.0), atol=1e-14)


def _one_step(lam: complex, h: float):
    """One step of y' = λ y, λ complex as a 2 x 2 real system, from y = (1, 0)."""
    a, b = lam.real, lam.imag
    jac = np.array([[a, -b], [b, a]])
    y = np.array([1.0, 0.0])
    K = np.empty((7, 2))
    K[0] = jac @ y
    ys = np.empty(2)
    for i in range(1, 6):
        dopri.stage_state(y, K, h, i, ys)
        K[i] = jac @ ys
    y1 = np.empty(2)
    dopri.stage_state(y, K, h, 6, y1)
    K[6] = jac @ y1
    err = np.empty(2)
    dopri.step_error(K, h, err)
    mid = np.empty(2)
    dopri.dense(y, K, h, 0.5, mid)
    return y1, err, mid


def _exact(lam: complex, t: float) -> np.ndarray:
    z = np.exp(lam * t)
    return np.array([z.real, z.imag])


def test_local_orders_of_step_error_estimate_and_dense_output():
    lam = complex(-0.7, 2.0)
    rows = []
    for h in (0.2, 0.1, 0.05):
        y1, err, mid = _one_step(lam, h)
        rows.append(
            (
                np.linalg.norm(y1 - _exact(lam, h)),
                np.linalg.norm(err),
                np.linalg.norm(mid - _exact(lam, 0.5 * h)),
            )
        )
    for coarse, fine in zip(rows, rows[1:]):
        # local errors: the 5th-order solution O(h^6), the embedded estimate (the 4th-order
        # solution's error) O(h^5), the 4th-order interpolant O(h^5): halving h divides them
        # by 64, 32, 32 (asymptotically; a factor 0.7-1.4 slack for the higher terms)
        assert 0.7 * 64 < coarse[0] / fine[0] < 1.4 * 64, (coarse, fine)
        assert 0.7 * 32 < coarse[1] / fine[1] < 1.4 * 32, (coarse, fine)
        assert 0.7 * 32 < coarse[2] / fine[2] < 1.4 * 32, (coarse, fine)


def test_step_factor_is_bounded_and_fifth_order():
    assert dopri.step_factor(0.0) == dopri.MAX_FACTOR
    assert dopri.step_factor(math.inf) == dopri.MIN_FACTOR
    assert dopri.step_factor(math.nan) == dopri.MIN_FACTOR
    assert dopri.step_factor(1e6) == dopri.MIN_FACTOR
    assert dopri.step_factor(32.0) == pytest.approx(dopri.SAFETY / 2.0)


def test_sign_change_skips_values_at_round_off_of_zero():
    assert dopri.sign_change(np.array([1.0, -2.0]), np.array([0.5, 1.0])) == 1
    assert dopri.sign_change(np.array([1e-13, 1.0]), np.array([-1.0, 0.5])) == -1
    assert dopri.sign_change(np.array([1.0, 1.0]), np.array([0.5, 2.0])) == -1


# a right-hand side of t, through the stage's node: y' = cos(t) y (y = exp(sin t))
@njit(cache=True)
def _cos_rhs(y, c, h, ctx, out):
    (t0,) = ctx
    out[0] = math.cos(t0 + c * h) * y[0]
    return True


@njit(cache=True)
def _refuses_negative(y, c, h, ctx, out):
    out[0] = -10.0
    return y[0] > 0.0  # the stage's state is 1 - 10 c h from y = 1


_cos_step = dopri.make_step(_cos_rhs)
_refusing_step = dopri.make_step(_refuses_negative)


def test_the_step_driver_places_stages_in_time_and_keeps_fsal():
    t0 = 0.3
    y = np.array([math.exp(math.sin(t0))])
    rows = []
    for h in (0.2, 0.1, 0.05):
        K = np.empty((7, 1))
        _cos_rhs(y, 0.0, h, (t0,), K[0])
        y_new = np.empty(1)
        err = np.empty(1)
        assert _cos_step(y, h, K, (t0,), y_new, err)
        exact = math.exp(math.sin(t0 + h))
        rows.append((abs(y_new[0] - exact), abs(err[0])))
        # FSAL: the last stage is f at the step's end, the next step's first
        assert K[6, 0] == pytest.approx(math.cos(t0 + h) * y_new[0], rel=1e-15)
    for coarse, fine in zip(rows, rows[1:]):
        # a stage placed at the wrong time would be first order wrong: the orders show it
        assert 0.7 * 64 < coarse[0] / fine[0] < 1.4 * 64, (coarse, fine)
        assert 0.7 * 32 < coarse[1] / fine[1] < 1.4 * 32, (coarse, fine)


def test_a_stage_the_right_hand_side_refuses_fails_the_step():
    y = np.array([1.0])
    K = np.full((7, 1), -10.0)
    y_new = np.empty(1)
    err = np.empty(1)
    assert _refusing_step(y, 0.05, K, (), y_new, err)  # every stage at y >= 0.5
    assert not _refusing_step(y, 0.2, K, (), y_new, err)  # the last stages below zero


def test_the_error_norm_takes_its_scales_as_arguments():
    err = np.array([1e-6, 2e-6, 3e-6])
    y0 = np.array([1.0, -4.0, 0.5])
    y1 = np.array([2.0, 0.0, 0.25])
    rtol, atol = 1e-3, 1e-5
    plain = dopri.error_norm(err, y0, y1, rtol, atol, np.ones(3), -np.ones(3))
    sc = atol + rtol * np.maximum(abs(y0), abs(y1))
    assert plain == pytest.approx(math.sqrt(np.mean((err / sc) ** 2)), rel=1e-15)
    # a finer absolute floor on one component, a fixed size on another
    a, r = np.array([1.0, 1.0, 1e-3]), np.array([-1.0, 1.0, -1.0])
    sc = np.array([atol + rtol * 2.0, atol + rtol * 1.0, 1e-3 * atol + rtol * 0.5])
    got = dopri.error_norm(err, y0, y1, rtol, atol, a, r)
    assert got == pytest.approx(math.sqrt(np.mean((err / sc) ** 2)), rel=1e-15)
