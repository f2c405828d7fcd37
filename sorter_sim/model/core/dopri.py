"""
The Dormand-Prince 5(4) pair every explicit stepper of the core takes its steps with.

One tableau (Dormand & Prince 1980), one dense output (Shampine 1986) and one step
driver, for any state length: the parcel's accurate method (``accurate``), its
break-away layer (``layer``), its approach to a stick (``transitions``), the cell's
period runs and the Fig. 4 oscillator all step and interpolate through these, and the
work-precision study reads their records through the same dense output.

Like scipy's ``rk_step``, one function takes a step: ``make_step(rhs)`` compiles the
step for a right-hand side ``rhs(y, c, h, ctx, out) -> valid`` (``c`` the stage's
node, so that a right-hand side of t or of a stage-dependent parameter can place the
stage; ``ctx`` a tuple of whatever else it needs; False: it cannot be evaluated there,
which fails the step). numba compiles the step for each right-hand side as it would a
hand-written loop: the right-hand side is a constant of the step's closure, not a
function value passed at run time (which numba would neither inline nor cache). The
caller keeps K[0] = f(y) (FSAL: the step's K[6] is the next step's K[0]), measures the
step with ``error_norm``, whose scales are its arguments, and sizes the next one with
``step_factor``.
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.core.jit import borrowing, kernel

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
    Fill ``out`` with the state stage i is evaluated at.

    Stages 1-5 are y + h Σ_{k<i} a_ik K_k; stage 6 (the FSAL point) y + h Σ b_k K_k, the
    5th-order solution, whose derivative is K[6] and the next step's K[0].

    Parameters
    ----------
    y : ndarray, shape (n,)
        The state at the step's start.
    K : ndarray, shape (7, n)
        The stages so far (K[0] = f(y)).
    h : float
        The step.
    i : int
        The stage, 1..6 (6: the step's end).
    out : ndarray, shape (n,)
        Receives the stage's state.

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
    """
    Fill ``err`` with the embedded error estimate h Σ e_k K_k (all seven stages).

    Parameters
    ----------
    K : ndarray, shape (7, n)
        The step's stages, K[6] = f at its end.
    h : float
        The step.
    err : ndarray, shape (n,)
        Receives the difference of the 5th- and the 4th-order solutions.

    """
    for j in range(err.shape[0]):
        acc = 0.0
        for k in range(N_STAGES):
            acc += E[k] * K[k, j]
        err[j] = h * acc


@borrowing
def error_norm(err, y0, y1, rtol, atol, atol_scale, rtol_ref):
    """
    Hairer's scaled RMS norm of a step's error estimate, with per-component scales.

    Parameters
    ----------
    err : ndarray, shape (n,)
        The embedded error estimate (``step_error``).
    y0, y1 : ndarray, shape (n,) or longer
        The state at the step's start and end (their first n components count).
    rtol, atol : float
        The tolerances.
    atol_scale : ndarray, shape (n,)
        Each component's absolute tolerance is ``atol * atol_scale[j]`` (1: atol itself;
        smaller where a component's zero must be resolved finer).
    rtol_ref : ndarray, shape (n,)
        Each component's relative tolerance applies to ``rtol_ref[j]`` where it is >= 0
        (a component of known size, as a unit direction's), else to max(|y0|, |y1|).

    Returns
    -------
    float
        sqrt(mean_j (err_j / (atol atol_scale_j + rtol ref_j))²): <= 1 accepts the step.

    """
    acc = 0.0
    n = err.shape[0]
    for j in range(n):
        ref = max(abs(y0[j]), abs(y1[j])) if rtol_ref[j] < 0.0 else rtol_ref[j]
        sc = atol * atol_scale[j] + rtol * ref
        acc += (err[j] / sc) ** 2
    return math.sqrt(acc / n)


def make_step(rhs, allocates=False):
    """
    Compile one Dormand-Prince step over the right-hand side ``rhs``.

    Parameters
    ----------
    rhs : numba function
        ``rhs(y, c, h, ctx, out) -> bool``: fill ``out`` with f at the stage state ``y``,
        whose node is ``c`` (its time is t0 + c h); return False if f cannot be
        evaluated there.
    allocates : bool
        Whether ``rhs`` allocates (needs numba's runtime); a step over one that does not
        is compiled without it (``jit.borrowing``), as the stages' kernels are.

    Returns
    -------
    numba function
        ``step(y, h, K, ctx, y_new, err) -> bool``: with K[0] = f(y) given, fills K[1..6]
        (K[6] = f(y_new), the next step's K[0]), the 5th-order solution ``y_new`` and the
        embedded error estimate ``err``; returns whether every stage was valid.

    """
    jit = kernel if allocates else borrowing

    @jit
    def step(y, h, K, ctx, y_new, err):
        valid = True
        for i in range(1, 7):
            # y_new holds each stage's state until it takes the step's end
            stage_state(y, K, h, i, y_new)
            c = C[i] if i < 6 else 1.0
            if not rhs(y_new, c, h, ctx, K[i]):
                valid = False
        step_error(K, h, err)
        return valid

    return step


@borrowing
def step_factor(enorm):
    """
    Return the factor on the step size after a step with error norm ``enorm``.

    Parameters
    ----------
    enorm : float
        The step's ``error_norm`` (<= 1: accepted).

    Returns
    -------
    float
        SAFETY enorm^(-1/5) (5th order), within [MIN_FACTOR, MAX_FACTOR]; MAX_FACTOR at
        zero error, MIN_FACTOR at a non-finite one.

    """
    if enorm == 0.0:
        return MAX_FACTOR
    if not math.isfinite(enorm):
        return MIN_FACTOR
    return min(MAX_FACTOR, max(MIN_FACTOR, SAFETY * enorm**-0.2))


@borrowing
def dense(y0, K, h, theta, out):
    """
    Fill ``out`` with the dense output y(t0 + θh) of a step.

    Parameters
    ----------
    y0 : ndarray, shape (n,)
        The state at the step's start.
    K : ndarray, shape (7, n)
        The step's stages.
    h : float
        The step.
    theta : float
        Where in the step, 0..1.
    out : ndarray, shape (n,)
        Receives the 4th-order interpolant's value (Shampine 1986).

    """
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
    Return the first index whose event value changes sign between a step's ends.

    A value within round-off of zero at the start has crossed already (two corners of an
    aligned box cross a border together), so it does not count again.

    Parameters
    ----------
    ev0, ev1 : ndarray
        The event values at the step's start and end.

    Returns
    -------
    int
        The first such index, or -1.

    """
    for q in range(ev0.shape[0]):
        if abs(ev0[q]) > 1e-12 and ev0[q] * ev1[q] < 0.0:
            return q
    return -1
