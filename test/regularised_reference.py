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
law becomes one stiff ODE, integrated by scipy's Radau. As ε -> 0 and the grid is
refined it converges to rigid-body Coulomb friction on the exact limit surface,
which is what the tests check the project's exact-stick mode against
(``converged`` shows the convergence in ε and grid).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

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


@dataclass
class Reference:
    t_scrap: float
    phi_deg: float  # rotation at the scrap line
    t_break: float  # first time the slip on the belt exceeds the detection speed
    t_stick: float  # first time after that the slip on the disks falls below it
    nfev: int


def solve(scene: Scene, eps: float, n_a: int, n_b: int, rtol: float = 1e-9) -> Reference:
    """Integrate the regularised model from the seed's entry state to the scrap line."""
    A, B, m, v = scene.A, scene.B, scene.m, scene.v
    alpha = math.radians(scene.alpha_deg)
    inertia = m * (A * A + B * B) / 12.0
    xi = (np.arange(n_a) + 0.5) / n_a * A - 0.5 * A
    eta = (np.arange(n_b) + 0.5) / n_b * B - 0.5 * B
    XI, ETA = (a.ravel() for a in np.meshgrid(xi, eta, indexing="ij"))
    c = scene.mu * m * G / XI.size
    disk = np.array([v * math.cos(alpha), v * math.sin(alpha)])

    def parts(state):
        x, y, phi, vx, vy, om = state
        cp, sp = math.cos(phi), math.sin(phi)
        rx = cp * XI - sp * ETA
        ry = sp * XI + cp * ETA
        on_disks = (x + rx >= 0.0) & (x + rx <= scene.b)
        ux = vx - om * ry - np.where(on_disks, disk[0], v)
        uy = vy + om * rx - np.where(on_disks, disk[1], 0.0)
        return rx, ry, on_disks, ux, uy

    def rhs(t, state):
        rx, ry, _, ux, uy = parts(state)
        k = -c / np.sqrt(ux * ux + uy * uy + eps * eps)
        fx = k * ux
        fy = k * uy
        torque = np.sum(rx * fy - ry * fx)
        return [
            state[3],
            state[4],
            state[5],
            fx.sum() / m,
            fy.sum() / m,
            torque / inertia if scene.rotation else 0.0,
        ]

    def scrap(t, state):
        return state[1] - scene.s

    scrap.terminal = True
    scrap.direction = 1
    y0 = [-0.5 * A, 0.0, 0.0, v, 0.0, 0.0]
    with warnings.catch_warnings():
        # Radau's finite-difference Jacobian grows its probe factors past float range
        # on the stiff stick phases (harmless: it then resets them)
        warnings.simplefilter("ignore", RuntimeWarning)
        sol = _solve_ivp(rhs, y0, scrap, eps, rtol)
    if sol.status != 1:
        raise RuntimeError(f"the reference did not reach the scrap line: {sol.message}")
    t_scrap = float(sol.t_events[0][0])
    phi = math.degrees(sol.y_events[0][0][2])
    # stick / break-away: the slip on the belt leaving, and on the disks reaching, a
    # detection speed well above the creep (~ε) and well below the sliding speeds
    detect = 30.0 * eps
    ts = np.linspace(0.0, t_scrap, 20001)
    slips = []
    for t in ts:
        st = sol.sol(t)
        _, _, on_disks, ux, uy = parts(st)
        speed = np.hypot(st[3] - v, st[4])  # centre of gravity against the belt
        cgd = np.hypot(st[3] - disk[0], st[4] - disk[1])
        slips.append((speed, cgd))
    slips = np.array(slips)
    k_break = int(np.argmax(slips[:, 0] > detect))
    after = np.nonzero(slips[k_break:, 1] < detect)[0]
    t_stick = float(ts[k_break + after[0]]) if after.size else math.inf
    return Reference(t_scrap, phi, float(ts[k_break]), t_stick, int(sol.nfev))


def _solve_ivp(rhs, y0, scrap, eps, rtol):
    return solve_ivp(
        rhs,
        (0.0, 20.0),
        y0,
        method="Radau",
        rtol=rtol,
        atol=[1e-10, 1e-10, 1e-10, eps * 1e-3, eps * 1e-3, eps * 1e-3],
        events=scrap,
        dense_output=True,
    )


def converged(scene: Scene, eps=(1e-4, 3e-5), grids=((70, 20), (140, 40))):
    """Solutions over a ladder of ε and grids: (eps, n_a, n_b, Reference) tuples."""
    return [(e, na, nb, solve(scene, e, na, nb)) for e in eps for na, nb in grids]
