"""
The other reading of the seed's zone force, eqs. (4.2)-(4.3), run where it decides.

Eq. (4.2) writes a zone's friction force as F_max · j/v_o with F_max = (m g / S) ∫ μ w dS
(4.3): no velocity inside the integral, while (4.5) puts w/v_o inside the moment's.
Two readings: j/v_o per area element inside the integral (the project's core: each
element opposes its own slip), or j/v_o taken once at the gravity centre (the zone's
force at its full magnitude F_max, directed against the centre's slip), the moment
per element as (4.5) writes it. They agree whenever φ̇ = 0: every element then slips
as the centre does. So the simplified model (moment neglected) and every stage in
which the parcel is held without turning (E1 on the belt) are the same in both.

This module runs the centre reading without touching the core: the zone force is the
core's per-element kinetic force evaluated at the same pose with φ̇ set to 0 (then
exactly F_max(v_o) against the centre's slip), the moment the core's at the true φ̇.
A sort is the core's run up to the break-away off the belt (stage E1, φ̇ = 0: the
readings agree), then stage E2 integrated here (classic RK4 at a fixed step) until
the centre's slip on the disks vanishes; from there the parcel rides the disks, its
spin running down under the disks' moment, to the scrap line (at the points run
here, b -> ∞, the belt is no longer under it by then). The seed's stick law only:
the question is how the seed computed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sorter_sim.model.core.common import n_surf_of
from sorter_sim.model.core.layout import Contact
from sorter_sim.model.core.simulate import parcel_array, strip_array
from sorter_sim.model.core.wrench import evaluate_surfaces, gauss_legendre_01
from sorter_sim.runtime.scene import run_scene, scene_parcel, scene_strips

SLIP_STOP = 1e-3  # m/s: the centre's slip on the disks counted as gone (its force flips there)


@dataclass
class Reading:
    """
    One sort under the centre reading.

    t_c [s], x_o [m], phi_deg at the scrap line; e2, e3: start of E2 (break-away off
    the belt) and of the ride on the disks [s]; t, F_b: |F_b| [N] along E2.
    """

    t_c: float
    x_o: float
    phi_deg: float
    e2: float
    e3: float
    t: np.ndarray
    F_b: np.ndarray


class _Wrench:
    """The core's per-surface kinetic wrench at a state (``evaluate_surfaces``)."""

    def __init__(self, scene: dict):
        parcel = scene_parcel(scene)
        strips = scene_strips(scene)
        arr = strip_array(strips)
        par = parcel_array(parcel, True, 8, True, scene["model"]["g"], "seed")
        nodes, weights = gauss_legendre_01(8)
        self.contact = Contact(arr, par, nodes, weights)
        ns = n_surf_of(arr)
        self.kin = np.zeros((ns, 3))
        self.stat = np.zeros((ns, 2))
        self.area = np.zeros(ns)
        self.slip = np.zeros(ns)
        self.m = parcel.m
        self.inertia = parcel.m * (parcel.A**2 + parcel.B**2) / 12.0

    def __call__(self, state, need_static=False):
        evaluate_surfaces(
            np.asarray(state, float), self.contact, -1, need_static, self.kin, self.stat,
            self.area, self.slip,
        )  # fmt: skip
        return self.kin.copy(), self.stat.copy()

    def centre(self, state):
        """Per-surface (Fx, Fy) with j/v_o at the gravity centre, and the moments per element."""
        spun, _ = self(state)
        still = np.array(state, float)
        still[5] = 0.0
        flat, _ = self(still)
        return flat[:, :2], spun[:, 2]


def sort_centre_reading(scene: dict, dt: float = 1e-4) -> Reading:
    """
    Run one sort of ``scene`` (seed stick, b -> ∞) under the centre reading of eq. (4.2).

    Parameters
    ----------
    scene : dict
        A validated sorting scene (``sorting_scene(..., stick="seed")``) with α > 0.
    dt : float
        The RK4 step in E2 [s].

    Returns
    -------
    Reading
        Its t_c, x_o, φ at the scrap line, stages and |F_b| along E2.

    """
    res, summ = run_scene(scene)
    e2 = summ["stages"]["E2"]
    k = int(np.argmin(np.abs(res.t - e2)))
    y0 = res.y[0].copy()
    w = _Wrench(scene)
    v = scene["belt"]["v"]
    al = math.radians(scene["diverter"]["alpha_deg"])
    disk = np.array([v * math.cos(al), v * math.sin(al)])
    b = 1  # the disks: surface 1 (the belt, zones a and c, is surface 0)
    y_target = y0[1] + scene["belt"]["s"]

    def rhs(s):
        f, torque = w.centre(s)
        fx, fy = f[:, 0].sum(), f[:, 1].sum()
        return np.array([s[3], s[4], s[5], fx / w.m, fy / w.m, torque.sum() / w.inertia])

    def slip_b(s):
        return np.array([s[3] - disk[0], s[4] - disk[1]])

    # classic RK4 at a fixed step, as the seed's threshold method: right after the
    # break-away the belt's slip grows from zero and its direction turns fast, which
    # error-controlled steps chase down to nothing
    s = res.y[k].copy()
    t = res.t[k]
    ts, fb = [t], [float(np.hypot(*w.centre(s)[0][b]))]
    scrapped = False
    while t < res.t[k] + 20.0:
        k1 = rhs(s)
        k2 = rhs(s + 0.5 * dt * k1)
        k3 = rhs(s + 0.5 * dt * k2)
        k4 = rhs(s + dt * k3)
        nxt = s + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        before, after = slip_b(s), slip_b(nxt)
        if nxt[1] >= y_target:  # the scrap line, within the step (linear)
            frac = (y_target - s[1]) / (nxt[1] - s[1])
            s, t, scrapped = s + frac * (nxt - s), t + frac * dt, True
            break
        if np.hypot(*after) < SLIP_STOP or before @ after < 0.0:  # the slip on the disks ends
            n0, n1 = np.hypot(*before), np.hypot(*after)
            frac = n0 / (n0 + n1) if before @ after < 0.0 else 1.0
            s, t = s + frac * (nxt - s), t + frac * dt
            s[3:5] = disk
            break
        s, t = nxt, t + dt
        ts.append(t)
        fb.append(float(np.hypot(*w.centre(s)[0][b])))
    t_e2, F_b, end = np.array(ts), np.array(fb), s
    if scrapped:  # still sliding on the disks at the scrap line
        return Reading(t, end[0] - y0[0], math.degrees(end[2]), e2, math.nan, t_e2, F_b)
    t3 = t
    # riding the disks: translation with them, the spin running down under their moment
    t_c = t3 + (y_target - end[1]) / disk[1]
    phi, om = end[2], end[5]
    if om != 0.0:
        spin = np.array([end[0], end[1], phi, disk[0], disk[1], om])
        decel = abs(w(spin)[0][:, 2].sum()) / w.inertia
        t_spin = min(abs(om) / decel, t_c - t3) if decel > 0 else t_c - t3
        phi += om * t_spin - math.copysign(0.5 * decel * t_spin**2, om)
    x_o = end[0] + disk[0] * (t_c - t3) - y0[0]
    return Reading(t_c, x_o, math.degrees(phi), e2, t3, t_e2, F_b)
