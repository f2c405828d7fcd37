"""
The Dormand-Prince 5(4) pair every explicit stepper of the core takes its steps with.

One tableau (Dormand & Prince 1980), one dense output (Shampine 1986) and one set of
step pieces, for any state length: the parcel's accurate method (``integrators``),
its break-away layer, the cell's period runs and the Fig. 4 oscillator all step and
interpolate through these, and the work-precision study reads their records through
the same dense output. The caller owns the right-hand side (numba has no cheap
function arguments): it fills stage i of K (7 x n, K[0] = f(y), FSAL) at
``stage_state(y, K, h, i, ys)``, then calls ``finish_step``.
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.core.jit import borrowing

# nodes c_i, coefficients a_ij, 5th-order weights b_i, and e_i = b_i - b*_i (the
# 4th-order embedded solution's difference, FSAL stage 7 included)
C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0])
A = np.array(
    [
        [0.0, 0.0, 0.0, 0.0, 0.0],
        [1 / 5, 0.0, 0.0, 0.0, 0.0],
        [3 / 40, 9 / 40, 0.0, 0.0, 0.0],
        [44 / 45, -56 / 15, 32 / 9, 0.0, 0.0],
        [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0.0],
        [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656],
    ]
)
B = np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84])
E = np.array([-71 / 57600, 0.0, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40])
# dense output: y(t0 + θh) = y0 + h Σ_i K_i (P_i0 θ + P_i1 θ² + P_i2 θ³ + P_i3 θ⁴)
P = np.array(
    [
        [1.0, -8048581381 / 2820520608, 8663915743 / 2820520608, -12715105075 / 11282082432],
        [0.0, 0.0, 0.0, 0.0],
        [0.0, 131558114200 / 32700410799, -68118460800 / 10900136933, 87487479700 / 32700410799],
        [0.0, -1754552775 / 470086768, 14199869525 / 1410260304, -10690763975 / 1880347072],
        [
            0.0,
            127303824393 / 49829197408,
            -318862633887 / 49829197408,
            701980252875 / 199316789632,
        ],
        [0.0, -282668133 / 205662961, 2019193451 / 616988883, -1453857185 / 822651844],
        [0.0, 40617522 / 29380423, -110615467 / 29380423, 69997945 / 29380423],
    ]
)

N_STAGES = 7  # six stages and the FSAL evaluation at the step's end
SAFETY = 0.9
MIN_FACTOR = 0.2
MAX_FACTOR = 5.0


@borrowing
def stage_state(y, K, h, i, out):
    """
    Fill ``out`` with the state stage i (1..6) is evaluated at; i = 6 is the step's end.

    Stages 1-5 are y + h Σ_{k<i} a_ik K_k; stage 6 (the FSAL point) y + h Σ b_k K_k, the
    5th-order solution, whose derivative is K[6] and the next step's K[0].
    """
    n = y.shape[0]
    for j in range(n):
        acc = 0.0
        if i < 6:
            for k in range(i):
                acc += A[i, k] * K[k, j]
        else:
            for k in range(6):
                acc += B[k] * K[k, j]
        out[j] = y[j] + h * acc


@borrowing
def step_error(K, h, err):
    """Fill ``err`` with the embedded error estimate h Σ e_k K_k (all seven stages)."""
    for j in range(err.shape[0]):
        acc = 0.0
        for k in range(N_STAGES):
            acc += E[k] * K[k, j]
        err[j] = h * acc


@borrowing
def rms_norm(err, y0, y1, rtol, atol):
    """Hairer's scaled RMS norm: each component against atol + rtol max(|y0|, |y1|)."""
    acc = 0.0
    for i in range(err.shape[0]):
        sc = atol + rtol * max(abs(y0[i]), abs(y1[i]))
        acc += (err[i] / sc) ** 2
    return math.sqrt(acc / err.shape[0])


@borrowing
def step_factor(enorm):
    """Factor on the step size after a step with error norm ``enorm`` (5th order: ^-1/5)."""
    if enorm == 0.0:
        return MAX_FACTOR
    if not math.isfinite(enorm):
        return MIN_FACTOR
    return min(MAX_FACTOR, max(MIN_FACTOR, SAFETY * enorm**-0.2))


@borrowing
def dense(y0, K, h, theta, out):
    """Dense output y(t0 + θh), θ in [0, 1], of the step from y0 with stages K."""
    q0 = theta
    q1 = theta * theta
    q2 = q1 * theta
    q3 = q2 * theta
    for j in range(out.shape[0]):
        acc = 0.0
        for i in range(N_STAGES):
            acc += K[i, j] * (P[i, 0] * q0 + P[i, 1] * q1 + P[i, 2] * q2 + P[i, 3] * q3)
        out[j] = y0[j] + h * acc


@borrowing
def sign_change(ev0, ev1):
    """
    First index whose event value changes sign between a step's ends, else -1.

    A value within round-off of zero at the start has crossed already (two corners of an
    aligned box cross a border together), so it does not count again.
    """
    for q in range(ev0.shape[0]):
        if abs(ev0[q]) > 1e-12 and ev0[q] * ev1[q] < 0.0:
            return q
    return -1
