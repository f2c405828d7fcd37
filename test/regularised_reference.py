"""
An independent solution of the seed's three-zone model, written for the tests.

It shares nothing with the project's core: no strips, no closed forms, no events,
no stick/slip automaton. The footprint is a grid of n_a x n_b equal cells (midpoint
rule); every cell carries the load m g / (n_a n_b) and feels the friction of the
zone its centre lies over, regularised,

    f = -μ (m g / n) u / sqrt(|u|² + ε²),

u the cell's velocity relative to that zone's surface (belt (v, 0) for x < 0 and
x > b, disks v (cos α, sin α) for 0 <= x <= b, seed Fig. 6). Sticking is then a slow
creep of speed ~ε and break-away a smooth, fast transition: the whole set-valued
law becomes one stiff ODE, integrated by scipy's Radau with its exact Jacobian
(``footprint_friction``, one compiled loop over the cells). As ε -> 0 and the grid is
refined it converges to rigid-body Coulomb friction on the exact limit surface,
which is what the tests check the project's exact-stick mode against
(``converged`` shows the convergence in ε and grid).
"""

from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.integrate import Radau, solve_ivp
from scipy.linalg import get_lapack_funcs

G = 9.80665


@dataclass(frozen=True)
class Scene:
    A: float = 0.7
    B: float = 0.2
    m: float = 5.0
    v: float = 1.5
    alpha_deg: float = 45.0
    b: float = math.inf
    mu: float = 0.6  # one constant μ in every zone (seed Fig. 3b)
    rotation: bool = True
    s: float = 0.7  # scrap line y = s


# Radau's relative tolerance. At 1e-6 the reference moves from its value at 1e-9 by
# about 1e-6 of t_scrap and 2e-4° of φ (α = 30° and the three-zone case, both ε):
# thousands of times inside what the tests compare it to, and well inside its own
# error in ε and grid. The grid's convergence test checks it (``test_exact_stick``).
RTOL = 1e-6


@dataclass(frozen=True)
class Reference:
    t_scrap: float
    phi_deg: float  # rotation at the scrap line
    t_break: float  # first time the slip on the belt exceeds the detection speed
    t_stick: float  # first time after that the slip on the disks falls below it
    nfev: int


@functools.cache  # the grid's convergence test and the α = 45° case share a solution
def solve(scene: Scene, eps: float, n_a: int, n_b: int, rtol: float = RTOL) -> Reference:
    """Integrate the regularised model from the seed's entry state to the scrap line."""
    A, B, m, v = scene.A, scene.B, scene.m, scene.v
    alpha = math.radians(scene.alpha_deg)
    inertia = m * (A * A + B * B) / 12.0
    xi = (np.arange(n_a) + 0.5) / n_a * A - 0.5 * A
    eta = (np.arange(n_b) + 0.5) / n_b * B - 0.5 * B
    XI, ETA = (a.ravel() for a in np.meshgrid(xi, eta, indexing="ij"))
    c = scene.mu * m * G / XI.size
    disk = np.array([v * math.cos(alpha), v * math.sin(alpha)])

    scale = np.array([1.0 / m, 1.0 / m, 1.0 / inertia if scene.rotation else 0.0])
    zone = (scene.b, v, disk[0], disk[1], c, eps)

    def rhs(t, state):
        return footprint_rhs(state, XI, ETA, *zone, scale)

    def jacobian(t, state):
        return footprint_jacobian(state, XI, ETA, *zone, scale)

    def scrap(t, state):
        return state[1] - scene.s

    scrap.terminal = True
    scrap.direction = 1
    y0 = [-0.5 * A, 0.0, 0.0, v, 0.0, 0.0]
    with warnings.catch_warnings():
        # Radau's step-size predictor divides by the error estimate, which is exactly
        # zero where the parcel rides a belt at its speed (a straight line in the state):
        # it then grows the step by its largest factor, as it should
        warnings.filterwarnings("ignore", "divide by zero", RuntimeWarning)
        sol = _solve_ivp(rhs, jacobian, y0, scrap, eps, rtol)
    if sol.status != 1:
        raise RuntimeError(f"the reference did not reach the scrap line: {sol.message}")
    t_scrap = float(sol.t_events[0][0])
    phi = math.degrees(sol.y_events[0][0][2])
    # stick / break-away: the slip on the belt leaving, and on the disks reaching, a
    # detection speed well above the creep (~ε) and well below the sliding speeds
    detect = 30.0 * eps
    ts = np.linspace(0.0, t_scrap, 20001)
    states = sol.sol(ts)
    speed = np.hypot(states[3] - v, states[4])  # centre of gravity against the belt
    cgd = np.hypot(states[3] - disk[0], states[4] - disk[1])  # ... against the disks
    slips = np.column_stack((speed, cgd))
    k_break = int(np.argmax(slips[:, 0] > detect))
    after = np.nonzero(slips[k_break:, 1] < detect)[0]
    t_stick = float(ts[k_break + after[0]]) if after.size else math.inf
    return Reference(t_scrap, phi, float(ts[k_break]), t_stick, int(sol.nfev))


@njit(cache=True, fastmath=True)
def footprint_friction(state, xi, eta, b, v, disk_x, disk_y, c, eps, with_jacobian):
    """
    Sum the regularised friction of the footprint's cells, and its derivatives.

    Returns (F_x, F_y, torque about g) and, ``with_jacobian``, their 3 x 4 Jacobian in
    (φ, v_x, v_y, ω) (else zeros).
    Cell i sits at (xi_i, eta_i) in the parcel's frame; it feels the disks where its
    centre lies in 0 <= x <= b, the belt elsewhere (a switch: no derivative in x).
    The Jacobian is exact. Radau's finite-difference one was erratic on the stick
    phases, where it differences a sum of thousands of terms over probe steps near its
    rounding: the same case took 80 784 evaluations with one grid or summation order
    and 1.4 million with another.
    """
    x, _, phi, vx, vy, om = state[0], state[1], state[2], state[3], state[4], state[5]
    cp, sp = math.cos(phi), math.sin(phi)
    wrench = np.zeros(3)
    jac = np.zeros((3, 4))  # d(F_x, F_y, torque) / d(φ, v_x, v_y, ω)
    for i in range(xi.size):
        rx = cp * xi[i] - sp * eta[i]
        ry = sp * xi[i] + cp * eta[i]
        on_disks = 0.0 <= x + rx <= b
        ux = vx - om * ry - (disk_x if on_disks else v)
        uy = vy + om * rx - (disk_y if on_disks else 0.0)
        s2 = ux * ux + uy * uy + eps * eps
        k = -c / math.sqrt(s2)
        fx, fy = k * ux, k * uy
        wrench[0] += fx
        wrench[1] += fy
        wrench[2] += rx * fy - ry * fx
        if not with_jacobian:
            continue
        # df/du = k (I - u u^T / s²); du/dφ = -ω (r_x, r_y), du/dv = I, du/dω = (-r_y, r_x)
        m11, m12, m22 = k * (1.0 - ux * ux / s2), -k * ux * uy / s2, k * (1.0 - uy * uy / s2)
        for j, (dux, duy) in enumerate(((-om * rx, -om * ry), (1.0, 0.0), (0.0, 1.0), (-ry, rx))):
            dfx = m11 * dux + m12 * duy
            dfy = m12 * dux + m22 * duy
            jac[0, j] += dfx
            jac[1, j] += dfy
            jac[2, j] += rx * dfy - ry * dfx
        jac[2, 0] -= rx * fx + ry * fy  # the lever arms turn with φ
    return wrench, jac


@njit(cache=True)
def footprint_rhs(state, xi, eta, b, v, disk_x, disk_y, c, eps, scale):
    """Return the state's derivative: (v_x, v_y, ω) and the footprint's friction / inertia."""
    wrench, _ = footprint_friction(state, xi, eta, b, v, disk_x, disk_y, c, eps, False)
    out = np.empty(6)
    out[:3] = state[3:]
    out[3:] = wrench * scale
    return out


@njit(cache=True)
def footprint_jacobian(state, xi, eta, b, v, disk_x, disk_y, c, eps, scale):
    """Return the 6 x 6 Jacobian of ``footprint_rhs`` (the friction's, exact)."""
    _, dacc = footprint_friction(state, xi, eta, b, v, disk_x, disk_y, c, eps, True)
    jac = np.zeros((6, 6))
    jac[0, 3] = jac[1, 4] = jac[2, 5] = 1.0
    for i in range(3):
        jac[3 + i, 2:] = dacc[i] * scale[i]
    return jac


class _Radau(Radau):
    """
    scipy's Radau, its LU back-substitutions made by LAPACK's getrs directly.

    ``lu_solve`` checks its right-hand side is finite and dispatches over batches on
    each of its tens of thousands of calls here, a third of the solve's time; getrs is
    the routine it ends in, so the numbers are the same. The check never fires here:
    Radau leaves its Newton iteration at a non-finite right-hand side before it solves.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        getrs = {}

        def solve_lu(lu_piv, b):
            lu, piv = lu_piv
            key = lu.dtype.char
            if key not in getrs:
                (getrs[key],) = get_lapack_funcs(("getrs",), (lu,))
            x, info = getrs[key](lu, piv, b, overwrite_b=True)
            if info != 0:
                raise ValueError(f"getrs: illegal value in argument {-info}")
            return x

        self.solve_lu = solve_lu


def _solve_ivp(rhs, jacobian, y0, scrap, eps, rtol):
    return solve_ivp(
        rhs,
        (0.0, 20.0),
        y0,
        method=_Radau,
        jac=jacobian,
        rtol=rtol,
        atol=[1e-10, 1e-10, 1e-10, eps * 1e-3, eps * 1e-3, eps * 1e-3],
        events=scrap,
        dense_output=True,
    )


def converged(scene: Scene, eps=(1e-4, 3e-5), grids=((70, 20), (140, 40))):
    """Solutions over a ladder of ε and grids: (eps, n_a, n_b, Reference) tuples."""
    return [(e, na, nb, solve(scene, e, na, nb)) for e in eps for na, nb in grids]
