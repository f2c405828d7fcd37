"""
The model of one cell, built from its quantities without a scene.

A scene (``runtime/scene.py``) is a user's YAML-backed configuration of one run; the
controller's timing predictor, the cell runtime and the scene loader all need the
same thing underneath: the friction law of each zone and the three-zone cell of
the seed's Fig. 6 with one parcel on it. This module builds those from plain
numbers, so no caller has to make up a scene dictionary to reach them.

The friction laws' own parameters (``LAW_DEFAULTS``) are declared here once; a
zone's coefficient ``mu`` scales its law to that value at the reference speed
``V_REF`` (the law keeps its shape).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from sorter_sim.model.core.friction import mu_kinetic, mu_static
from sorter_sim.model.core.simulate import FrictionLaw, Parcel, Strip, three_zone_strips

# Default B-spline control points (v_i [m/s], μ_i): an assumption, since the seed
# does not list Piątkowski & Sempruch's (2006b) values. Shape: μ_0 = 0.65 at rest
# (the seed's μ_0), a minimum near 0.2 m/s, then a slow rise towards μ_G-like
# values at sorting speeds. The rise around 0.37 m/s is what damps the two-belt
# positioning oscillation of Fig. 13 (a constant μ cannot damp it).
BSPLINE_DEFAULT = [0.0, 0.1, 0.25, 0.6, 1.5, 2.5, 0.65, 0.45, 0.42, 0.47, 0.50, 0.52]

V_REF = 1.0  # [m/s] the speed at which a zone's coefficient is given

LAW_DEFAULTS: dict[str, list[float]] = {
    "const2": [0.65, 0.46],  # the seed's μ_0, μ_G (models 2 and 3)
    "const1": [0.6],  # the seed's sorting runs
    "linear": [0.65, -0.15],  # assumption
    "polynomial": [0.65, -1.0, 0.0, 2.0],  # assumption: Fig. 3d's rise at 1 m/s
    "stribeck": [0.65, 0.3, 10.0, 5.0, 1.5, 0.1],  # assumption: μ0, μmin, b1, b2, b3, v_knee
    "bspline": list(BSPLINE_DEFAULT),
}


def zone_law(model: str, mu: float | None, params=None, v_ref: float | None = None):
    """
    Return the friction law of one zone: law ``model`` scaled to ``mu`` at ``v_ref``.

    ``params`` are the law's own values (default: ``LAW_DEFAULTS``, the seed's
    where it gives them); ``mu`` None takes the law as given. The law must not be 0
    at ``v_ref`` when it is scaled (``scene.validate`` checks a scene for that).

    Parameters
    ----------
    model : str
        The friction law's name (``LAW_NAMES``).
    mu : float
        The constant friction coefficient.
    params : list of float, optional
        The law's own values (default: ``LAW_DEFAULTS``).
    v_ref : float
        The speed at which ``mu`` holds [m/s].

    Returns
    -------
    FrictionLaw
        The law, shaped as its parameters say and scaled to ``mu`` at ``v_ref``.

    """
    law = FrictionLaw(model, tuple(LAW_DEFAULTS[model] if params is None else params))
    if mu is None:
        return law
    ref = mu_kinetic(law.law_id, law.row(), V_REF if v_ref is None else v_ref)
    return law.scaled(mu / ref)


N_SPEEDS = 2001  # speeds at which a law is checked


def law_problem(model: str, params, v_max: float) -> str | None:
    """
    Say what is wrong with friction law ``model`` of these parameters, or None.

    See ``_law_problem``; the answer is remembered per law and speed range, so a
    sweep that validates every point pays for each law once.

    Parameters
    ----------
    model : str
        The friction law's name (``LAW_NAMES``).
    params : list of float, optional
        The law's own values (default: ``LAW_DEFAULTS``).
    v_max : float
        The highest rubbing speed checked [m/s].

    Returns
    -------
    str or None
        What is wrong (a negative or non-finite μ below ``v_max``), or None.

    """
    return _law_problem(model, tuple(float(p) for p in params), float(v_max))


@functools.lru_cache(maxsize=4096)
def _law_problem(model: str, params: tuple, v_max: float) -> str | None:
    """
    Say what is wrong with friction law ``model`` of these parameters, or None.

    A law must build (its own rules: counts, increasing B-spline speeds...) and
    give a finite coefficient >= 0 at every slip speed from 0 to ``v_max``
    [m/s], the most a parcel can slip on a surface of the cell (twice the belt
    speed: a parcel carried one way over disks turning the other). A law that goes
    negative would push a parcel along its slip, and the model would run away.
    """
    try:
        law = FrictionLaw(model, tuple(params))
    except ValueError as exc:
        return str(exc)
    row = law.row()
    speeds = np.linspace(0.0, v_max, N_SPEEDS)
    mu = np.array([mu_kinetic(law.law_id, row, float(s)) for s in speeds])
    mu_s = mu_static(law.law_id, row)
    bad = ~np.isfinite(mu) | (mu < 0.0)
    if bad.any():
        i = int(np.argmax(bad))
        return (
            f"μ({speeds[i]:.3g} m/s) = {mu[i]:.3g}: the law must be a finite number >= 0 at "
            f"every slip speed from 0 to {v_max:.3g} m/s"
        )
    if not (math.isfinite(mu_s) and mu_s >= 0.0):
        return f"static μ = {mu_s:.3g}: must be a finite number >= 0"
    return None


def cell_strips(
    v: float,
    alpha_deg: float,
    b: float,
    mu_a: float | None,
    mu_b: float | None,
    mu_c: float | None,
    friction_model: str = "const1",
    stroke: float = 1.0,
    params=None,
    v_ref: float | None = None,
) -> list[Strip]:
    """
    Return the three zones (Fig. 6) at belt speed v [m/s], disks at α [deg], field b [m].

    Parameters
    ----------
    v : float
        The belt speed [m/s].
    alpha_deg : float
        The disk angle [deg].
    b : float
        The disk field's length [m] (inf: the seed's b -> ∞).
    mu_a : float
        The belt's μ before the disks.
    mu_b : float
        The disks' μ.
    mu_c : float
        The belt's μ after them.
    friction_model : str
        The friction law's name.
    stroke : float
        The pop-up position, 0 down .. 1 up.
    params : list of float, optional
        The law's own values (default: ``LAW_DEFAULTS``).
    v_ref : float
        The speed at which ``mu`` holds [m/s].

    Returns
    -------
    list of Strip or ndarray
        The zones a, b, c.

    """
    return three_zone_strips(
        v,
        math.radians(alpha_deg),
        b,
        zone_law(friction_model, mu_a, params, v_ref),
        zone_law(friction_model, mu_b, params, v_ref),
        zone_law(friction_model, mu_c, params, v_ref),
        stroke,
    )


def entry_state(parcel: Parcel, v: float, phi0_deg: float = 0.0) -> np.ndarray:
    """
    Leading edge on the zone a/b border, moving with the belt, φ̇ = 0.

    Parameters
    ----------
    parcel : Parcel
        The box.
    v : float
        The belt speed [m/s].
    phi0_deg : float
        The parcel's skew [deg].

    Returns
    -------
    ndarray, shape (6,)
        The state with the leading edge on the zone a/b border, moving with the belt.

    """
    phi = math.radians(phi0_deg)
    return np.array([-parcel.leading_edge_offset(phi), 0.0, phi, v, 0.0, 0.0])
