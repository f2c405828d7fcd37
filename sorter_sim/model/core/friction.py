"""
Friction-coefficient characteristics μ(v_o) of the seed's Fig. 3, as numba kernels.

A characteristic is a law id plus a row of float64 parameters, so that strips of
the conveyor can carry their own law inside plain arrays that numba kernels read.
Every law gives the kinetic coefficient μ(v_o) for a rubbing speed v_o > 0 [m/s]
and a static coefficient μ_s = lim μ(v_o) as v_o -> 0+, which is what eq. (3.1)
compares the external force with.

Laws (seed Fig. 3; parameter rows are documented on each ``LAW_*`` constant):

(a) CONST2   constant two-parameter: μ_s = μ0 at rest, μ_G while sliding
(b) CONST1   constant one-parameter: μ everywhere
(c) LINEAR   μ0 + c·v_o, clipped at 0
(d) POLY     Σ c_k v_o^k (k = 0..5), clipped at 0
(e) STRIBECK the seed's two-Stribeck-curve formula (μ0, μ_min, b1, b2, b3, v_knee)
(f) BSPLINE  clamped cubic b-spline with 6 control points (v_i, μ_i), the curve
             parametric in t, inverted for v_o by safeguarded Newton iteration;
             beyond the last control point the last μ holds.

Units: speeds in m/s, coefficients dimensionless.
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.core.jit import borrowing

LAW_CONST2 = 0  # params: [mu0, muG]
LAW_CONST1 = 1  # params: [mu]
LAW_LINEAR = 2  # params: [mu0, c]                 mu = mu0 + c v
LAW_POLY = 3  # params: [c0, c1, c2, c3, c4, c5] mu = sum c_k v^k
LAW_STRIBECK = 4  # params: [mu0, mu_min, b1, b2, b3, v_knee]
LAW_BSPLINE = 5  # params: [v0..v5, mu0..mu5]       control points

N_LAW_PARAMS = 38  # the b-spline keeps derived span coefficients after its 12 values

LAW_NAMES = {
    "const2": LAW_CONST2,
    "const1": LAW_CONST1,
    "linear": LAW_LINEAR,
    "polynomial": LAW_POLY,
    "stribeck": LAW_STRIBECK,
    "bspline": LAW_BSPLINE,
}

# Knots of a clamped cubic b-spline with six control points on t in [0, 1]; its three
# spans [0,1/3], [1/3,2/3], [2/3,1] each hold one cubic in the local u = 3t - j.
_BSPLINE_KNOTS = np.array([0.0, 0.0, 0.0, 0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0, 1.0, 1.0, 1.0])
_BS_SPAN = 12  # per span j: 4 coefficients of v(u), then 4 of μ(u), ascending powers
_BS_BOUNDS = 36  # v at the two inner knots


def _bspline_basis(t: float) -> np.ndarray:
    """Return the six cubic basis functions of the clamped knot vector at t (Cox-de Boor)."""
    kn = _BSPLINE_KNOTS
    nb = np.zeros(9)
    if t >= 1.0:
        nb[5] = 1.0
    else:
        for i in range(9):
            if kn[i] <= t < kn[i + 1]:
                nb[i] = 1.0
    for p in range(1, 4):
        for i in range(9 - p):
            left = (t - kn[i]) / (kn[i + p] - kn[i]) * nb[i] if kn[i + p] > kn[i] else 0.0
            den = kn[i + p + 1] - kn[i + 1]
            right = (kn[i + p + 1] - t) / den * nb[i + 1] if den > 0.0 else 0.0
            nb[i] = left + right
    return nb[:6]


def bspline_curve(control_v, control_mu, t) -> tuple[np.ndarray, np.ndarray]:
    """
    Points (v(t), μ(t)) of the b-spline through its control polygon, t in [0, 1].

    Parameters
    ----------
    control_v : ndarray
        The control polygon's speeds [m/s].
    control_mu : ndarray
        Its coefficients.
    t : ndarray
        Curve parameters in [0, 1].

    Returns
    -------
    (ndarray, ndarray)
        The curve's speeds and coefficients.

    """
    basis = np.array([_bspline_basis(float(ti)) for ti in np.atleast_1d(t)])
    return basis @ np.asarray(control_v, float), basis @ np.asarray(control_mu, float)


def _bspline_row(values) -> np.ndarray:
    """Control points plus the per-span cubic coefficients the kernel evaluates."""
    vals = np.asarray(values, dtype=float).ravel()
    row = np.zeros(N_LAW_PARAMS)
    row[:12] = vals
    for j in range(3):
        u = np.linspace(0.0, 1.0, 4)
        v, mu = bspline_curve(vals[:6], vals[6:12], (j + u) / 3.0)
        # four points fix a cubic exactly; ascending powers of u
        row[_BS_SPAN + 8 * j : _BS_SPAN + 8 * j + 4] = np.polynomial.polynomial.polyfit(u, v, 3)
        row[_BS_SPAN + 8 * j + 4 : _BS_SPAN + 8 * j + 8] = np.polynomial.polynomial.polyfit(
            u, mu, 3
        )
    inner_v, _ = bspline_curve(vals[:6], vals[6:12], [1.0 / 3.0, 2.0 / 3.0])
    row[_BS_BOUNDS : _BS_BOUNDS + 2] = inner_v
    return row


@borrowing
def _bspline_mu(params, speed):
    v_first = params[0]
    v_last = params[5]
    if speed <= v_first:
        return params[6]
    if speed >= v_last:
        return params[11]
    j = 0
    lo_v = v_first
    hi_v = params[_BS_BOUNDS]
    if speed >= params[_BS_BOUNDS + 1]:
        j = 2
        lo_v = params[_BS_BOUNDS + 1]
        hi_v = v_last
    elif speed >= params[_BS_BOUNDS]:
        j = 1
        lo_v = params[_BS_BOUNDS]
        hi_v = params[_BS_BOUNDS + 1]
    o = _BS_SPAN + 8 * j
    c0 = params[o]
    c1 = params[o + 1]
    c2 = params[o + 2]
    c3 = params[o + 3]
    # v(u) increases on the span (control abscissae increase, checked at load time):
    # safeguarded Newton on the cubic, bracket [0, 1].
    lo = 0.0
    hi = 1.0
    u = (speed - lo_v) / (hi_v - lo_v) if hi_v > lo_v else 0.5
    for _ in range(50):
        f = ((c3 * u + c2) * u + c1) * u + c0 - speed
        if f > 0.0:
            hi = u
        else:
            lo = u
        d = (3.0 * c3 * u + 2.0 * c2) * u + c1
        un = u - f / d if d > 0.0 else 0.5 * (lo + hi)
        if not (lo <= un <= hi):
            un = 0.5 * (lo + hi)
        # quadratic convergence: after a correction below 1e-8 the error left is
        # O(1e-16), so the iterate is taken without one more evaluation to confirm it
        if abs(un - u) <= 1e-8:
            u = un
            break
        u = un
    return ((params[o + 7] * u + params[o + 6]) * u + params[o + 5]) * u + params[o + 4]


@borrowing
def mu_kinetic(law, params, speed):
    """
    Return the kinetic friction coefficient at a rubbing speed.

    Parameters
    ----------
    law : int
        The law's id (``LAW_IDS``).
    params : ndarray
        Its parameters (``N_LAW_PARAMS``).
    speed : float
        The rubbing speed [m/s], > 0.

    Returns
    -------
    float
        μ at that speed.

    """
    s = abs(speed)
    if law == LAW_CONST2:
        return params[1]
    if law == LAW_CONST1:
        return params[0]
    if law == LAW_LINEAR:
        return max(0.0, params[0] + params[1] * s)
    if law == LAW_POLY:
        acc = 0.0
        for k in range(5, -1, -1):
            acc = acc * s + params[k]
        return max(0.0, acc)
    if law == LAW_STRIBECK:
        mu0 = params[0]
        mu_min = params[1]
        b1 = params[2]
        b2 = params[3]
        b3 = params[4]
        v_knee = params[5]
        base = mu_min + (mu0 - mu_min) * math.exp(-b1 * s)
        if s > v_knee:
            base += b2 * b3 * (s - v_knee) / (1.0 + b2 * (s - v_knee))
        return base
    if law == LAW_BSPLINE:
        return _bspline_mu(params, s)
    return math.nan


@borrowing
def mu_static(law, params):
    """
    Return the limiting static coefficient μ_s: the law's value as v_o -> 0+ (eq. 3.1).

    Parameters
    ----------
    law : int
        The law's id (``LAW_IDS``).
    params : ndarray
        Its parameters (``N_LAW_PARAMS``).

    Returns
    -------
    float
        μ_s, which F_stat of eq. (3.1) is.

    """
    if law == LAW_CONST2:
        return params[0]
    if law == LAW_CONST1:
        return params[0]
    if law == LAW_LINEAR:
        return max(0.0, params[0])
    if law == LAW_POLY:
        return max(0.0, params[0])
    if law == LAW_STRIBECK:
        return params[0]
    if law == LAW_BSPLINE:
        return params[6]
    return math.nan


@borrowing
def law_is_constant(law):
    """
    Return True where μ does not depend on the rubbing speed (closed-form wrench).

    Parameters
    ----------
    law : int
        The friction law's id (``friction.LAW_IDS``).

    Returns
    -------
    bool
        True where μ does not depend on the rubbing speed.

    """
    return law == LAW_CONST1 or law == LAW_CONST2


@borrowing
def law_smooth_reach(law, params, speed):
    """
    Return how far [m/s] from ``speed`` μ(v) stays analytic (no kink, knot or clipping).

    inf for a constant law and a linear law that stays positive; for the b-spline the
    distance to its nearest knot (inside a span μ is a cubic of the inverse of a cubic);
    0 for the laws not analysed here (the polynomial's clipping at zero, the Stribeck
    law's steep exponential and knee).

    Parameters
    ----------
    law : int
        The friction law's id (``friction.LAW_IDS``).
    params : ndarray
        The law's parameters (``friction.N_LAW_PARAMS``).
    speed : float
        The rubbing speed [m/s].

    Returns
    -------
    float
        How far from ``speed`` μ(v) stays analytic [m/s] (inf: everywhere).

    """
    if law_is_constant(law):
        return math.inf
    if law == LAW_LINEAR:
        if params[1] >= 0.0:
            return math.inf if params[0] > 0.0 else 0.0
        return max(0.0, -params[0] / params[1] - speed)
    if law == LAW_BSPLINE:
        reach = math.inf
        for knot in (params[0], params[_BS_BOUNDS], params[_BS_BOUNDS + 1], params[5]):
            reach = min(reach, abs(speed - knot))
        return reach
    return 0.0


def mu_kinetic_array(law: int, params: np.ndarray, speeds) -> np.ndarray:
    """
    Vectorised helper for plots and checks: μ at each speed of ``speeds``.

    Parameters
    ----------
    law : int
        The friction law's id (``friction.LAW_IDS``).
    params : ndarray
        The law's parameters (``friction.N_LAW_PARAMS``).
    speeds : ndarray
        Rubbing speeds [m/s].

    Returns
    -------
    ndarray
        μ at each speed.

    """
    return np.array([mu_kinetic(law, params, float(s)) for s in np.atleast_1d(speeds)])


def law_row(law: int, values) -> np.ndarray:
    """
    Return a parameter row of length N_LAW_PARAMS for ``law`` from its listed values.

    Parameters
    ----------
    law : int
        The friction law's id (``friction.LAW_IDS``).
    values : list of float
        The law's listed values.

    Returns
    -------
    ndarray
        The parameter row.

    """
    if law == LAW_BSPLINE:
        return _bspline_row(values)
    row = np.zeros(N_LAW_PARAMS)
    vals = np.asarray(values, dtype=float).ravel()
    row[: vals.size] = vals
    return row
