"""
Scenes: one parcel through one cell, as a validated, YAML-backed configuration.

A scene is a nested mapping with the sections below; every key has a default
(``DEFAULTS``), so a scene file lists only what differs. ``load_scene`` reads a
YAML file, ``apply_overrides`` takes ``key.sub=value`` strings, ``validate``
checks everything and raises ``SceneError`` naming the key and what is allowed.
``run_scene`` turns a valid scene into a core run and a JSON-ready summary.

Zone coefficients: ``zones.mu_a|mu_b|mu_c`` are the coefficient of that zone at
the reference speed ``friction.v_ref`` (1 m/s): the law of ``friction.model``
keeps its shape and is scaled to that value; ``null`` takes the law as given.
For ``const1`` this is simply μ; for ``const2`` it is μ_G with μ_0/μ_G kept.

Defaults that the seed does not state are assumptions, marked so below.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np

from sorter_ros.strict_yaml import StrictYamlError, load_yaml_text, read_yaml_file
from sorter_sim.model.build import (
    LAW_DEFAULTS,
    V_REF,
    cell_strips,
    entry_state,
    law_problem,
    zone_law,
)
from sorter_sim.model.core.common import ST_MAX_STEPS
from sorter_sim.model.core.friction import mu_kinetic
from sorter_sim.model.core.simulate import FrictionLaw, Parcel, SimResult, simulate
from sorter_sim.model.description import Q, shown


class SceneError(ValueError):
    """A scene key is missing, unknown or out of its allowed range."""


DEFAULTS: dict[str, dict[str, Any]] = {
    "parcel": {
        "A": 0.7,
        "B": 0.2,
        "m": 5.0,
        "phi0_deg": 0.0,
    },  # m: assumption (seed: 5 kg in Fig. 14)
    "belt": {"v": 1.5, "s": 0.7},
    "zones": {"b": math.inf, "mu_a": 0.6, "mu_b": 0.6, "mu_c": 0.6},
    "diverter": {"alpha_deg": 90.0, "stroke": 1.0},
    "friction": {
        "model": "const1",
        "v_ref": V_REF,
        **{name: list(values) for name, values in LAW_DEFAULTS.items()},
    },
    "model": {"rotation": True, "stick": "exact", "v_min": 1e-6, "g": 9.81},
    "solver": {
        "method": "accurate",
        "rtol": 1e-8,
        "atol": 1e-10,
        "dt": 1e-3,
        "n_quad": 8,
        "reductions": True,
        "t_max": 20.0,
    },
}


def _cell(key: str, kind: str = "float") -> tuple:
    """Return the rule of a scene key that is one of the cell's quantities."""
    q = Q[key]
    allowed = q.allowed + (", or null" if kind == "mu" else "")
    return (kind, q.lo, q.hi, allowed)


# key -> (kind, lo, hi, what is allowed); kind: float, bool, int, choice, list
_RULES: dict[str, tuple] = {
    # the cell's quantities: ranges from the cell description
    "parcel.A": _cell("parcel.length"),
    "parcel.B": _cell("parcel.width"),
    "parcel.m": _cell("parcel.mass"),
    "parcel.phi0_deg": _cell("parcel.skew_deg"),
    "belt.v": _cell("belt.speed"),
    "belt.s": _cell("belt.width"),
    # zone b of a scene may be absent (0) or the seed's b -> ∞
    "zones.b": (
        "float_inf",
        0.0,
        math.inf,
        "a disk-field length: 0, or " + Q["disk_field.length"].allowed + ", or .inf",
    ),
    "zones.mu_a": _cell("friction.mu", "mu"),
    "zones.mu_b": _cell("friction.mu", "mu"),
    "zones.mu_c": _cell("friction.mu", "mu"),
    "diverter.alpha_deg": _cell("diverter.alpha_deg"),
    "diverter.stroke": _cell("diverter.stroke"),
    "friction.model": (
        "choice",
        ("const2", "const1", "linear", "polynomial", "stribeck", "bspline"),
        None,
        "one of const2, const1, linear, polynomial, stribeck, bspline",
    ),
    "friction.v_ref": ("float", 0.0, 10.0, "a reference speed in (0, 10] m/s"),
    "friction.const2": ("list", 2, 2, "[mu0, muG]"),
    "friction.const1": ("list", 1, 1, "[mu]"),
    "friction.linear": ("list", 2, 2, "[mu0, c]"),
    "friction.polynomial": ("list", 1, 6, "1 to 6 coefficients [c0, c1, ...]"),
    "friction.stribeck": ("list", 6, 6, "[mu0, mu_min, b1, b2, b3, v_knee]"),
    "friction.bspline": ("list", 12, 12, "[v0..v5, mu0..mu5]"),
    "model.rotation": ("bool", None, None, "true or false"),
    "model.stick": ("choice", ("exact", "seed"), None, "one of exact, seed"),
    "model.v_min": ("float", 0.0, 1.0, "a threshold speed in (0, 1] m/s"),
    "model.g": ("float", 0.0, 100.0, "gravity in (0, 100] m/s²"),
    "solver.method": (
        "choice",
        ("accurate", "implicit", "threshold"),
        None,
        "one of accurate, implicit, threshold",
    ),
    "solver.rtol": ("float", 1e-14, 0.1, "a relative tolerance in [1e-14, 0.1]"),
    "solver.atol": ("float", 1e-16, 1.0, "an absolute tolerance in [1e-16, 1]"),
    "solver.dt": ("float", 1e-7, 0.1, "a step in [1e-7, 0.1] s"),
    "solver.n_quad": ("int", 2, 24, "a Gauss order in [2, 24]"),
    "solver.reductions": ("bool", None, None, "true or false"),
    "solver.t_max": ("float", 0.0, 3600.0, "a time limit in (0, 3600] s"),
}
_OPEN_LOW = {
    "friction.v_ref",
    "model.v_min",
    "model.g",
    "solver.t_max",
}


def _as_number(value: Any) -> Any:
    """YAML 1.1 reads 1e-6 (no dot) as a string; take such strings as the number they spell."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _check(key: str, value: Any) -> Any:
    kind, lo, hi, allowed = _RULES[key]
    if kind in ("float", "float_inf", "mu", "int"):
        value = _as_number(value)
    elif kind == "list" and isinstance(value, (list, tuple)):
        value = [_as_number(v) for v in value]
    if kind == "bool":
        if not isinstance(value, bool):
            raise SceneError(f"{key}: must be {allowed}, got {shown(value)}")
        return value
    if kind == "choice":
        if value not in lo:
            raise SceneError(f"{key}: must be {allowed}, got {shown(value)}")
        return value
    if kind == "list":
        if not isinstance(value, (list, tuple)) or not lo <= len(value) <= hi:
            raise SceneError(f"{key}: must be a list {allowed}, got {shown(value)}")
        out = []
        for v in value:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise SceneError(
                    f"{key}: every entry must be a finite number ({allowed}), got {shown(value)}"
                )
            out.append(float(v))
        return out
    if kind == "mu" and value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(f"{key}: must be {allowed}, got {shown(value)}")
    v = float(value)
    if math.isnan(v) or (math.isinf(v) and kind != "float_inf"):
        raise SceneError(f"{key}: must be {allowed}, got {shown(value)}")
    if kind == "int":
        if v != int(v):
            raise SceneError(f"{key}: must be {allowed}, got {shown(value)}")
        v = int(v)
    too_low = v <= lo if key in _OPEN_LOW else v < lo
    if too_low or v > hi:
        raise SceneError(f"{key}: must be {allowed}, got {shown(value)}")
    if key == "zones.b" and 0.0 < v < math.inf and not Q["disk_field.length"].contains(v):
        raise SceneError(f"{key}: must be {allowed}, got {shown(value)}")
    return v


def validate(scene: dict) -> dict:
    """
    Return a complete, checked copy of a scene, its defaults filled in.

    Parameters
    ----------
    scene : dict
        A scene as read from YAML: sections ``model``, ``parcel``, ``zones``,
        ``friction``, ``solver`` ... (``DEFAULTS`` lists every key).

    Returns
    -------
    dict
        The scene with every key, each checked against the cell description.

    Raises
    ------
    SceneError
        A key unknown or a value out of its range, naming the key and what is allowed.

    """
    if not isinstance(scene, dict):
        raise SceneError(f"a scene must be a mapping of sections, got {type(scene).__name__}")
    out = copy.deepcopy(DEFAULTS)
    for section, body in scene.items():
        if section not in DEFAULTS:
            raise SceneError(f"unknown section {shown(section)}; allowed: {', '.join(DEFAULTS)}")
        if body is None:
            continue
        if not isinstance(body, dict):
            raise SceneError(f"{section}: must be a mapping of keys, got {shown(body)}")
        for key, value in body.items():
            full = f"{section}.{key}"
            if full not in _RULES:
                allowed = ", ".join(f"{section}.{k}" for k in DEFAULTS[section])
                raise SceneError(f"unknown key {shown(full)}; allowed in {section}: {allowed}")
            out[section][key] = _check(full, value)
    # cross-checks: every law, selected or not, must build and stay >= 0 over the slip
    # speeds of this cell (a law chosen later by --set or a sweep is then already sound);
    # the selected one's reference value must be positive to scale
    v_slip = math.ceil(4.0 * abs(out["belt"]["v"])) / 2.0  # 2 v, up to the next 0.5 m/s
    for name in LAW_DEFAULTS:
        problem = law_problem(name, out["friction"][name], v_slip)
        if problem is not None:
            raise SceneError(f"friction.{name}: {problem}")
    model = out["friction"]["model"]
    law = FrictionLaw(model, tuple(out["friction"][model]))
    ref = mu_kinetic(law.law_id, law.row(), out["friction"]["v_ref"])
    if any(out["zones"][k] is not None for k in ("mu_a", "mu_b", "mu_c")) and not ref > 0.0:
        raise SceneError(
            f"friction.{model}: the law is 0 at friction.v_ref, so zones.mu_* cannot "
            "scale it; set zones.mu_* to null or change the law"
        )
    return out


def load_scene(path: str | Path) -> dict:
    """
    Read and validate a scene YAML file, strictly (``sorter_ros.strict_yaml``).

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    dict
        The validated scene (``validate``).

    Raises
    ------
    SceneError
        The file unreadable or not a scene, in one line naming what is wrong.

    """
    try:
        data = read_yaml_file(path, "scene file")
    except StrictYamlError as exc:
        raise SceneError(str(exc)) from None
    if data is None:
        raise SceneError(f"scene file {shown(str(path))} is empty")
    return validate(data)


def apply_overrides(scene: dict, overrides: list[str]) -> dict:
    """
    Apply ``section.key=value`` strings (values in YAML syntax) and validate again.

    Parameters
    ----------
    scene : dict
        A validated scene.
    overrides : list of str
        ``section.key=value`` each, as ``sorter run --set`` takes them.

    Returns
    -------
    dict
        A new validated scene; ``scene`` is not changed.

    """
    raw = copy.deepcopy(scene)
    for item in overrides:
        if "=" not in item:
            raise SceneError(f"--set {shown(item)}: expected key=value, e.g. parcel.A=0.4")
        key, _, text = item.partition("=")
        key = key.strip()
        if key.count(".") != 1:
            raise SceneError(f"--set {shown(key)}: keys have the form section.key, e.g. belt.v")
        section, name = key.split(".")
        if section not in DEFAULTS or name not in DEFAULTS[section]:
            allowed = ", ".join(sorted(_RULES))
            raise SceneError(f"--set: unknown key {shown(key)}; allowed: {allowed}")
        try:
            value = load_yaml_text(text, f"--set {key}")
        except StrictYamlError as exc:
            raise SceneError(str(exc)) from None
        # each value is checked as it is given: a later --set of the same key does not
        # hide a bad one
        _check(key, value)
        raw.setdefault(section, {})[name] = value
    return validate(raw)


def _zone_law(scene: dict, zone: str) -> FrictionLaw:
    fr = scene["friction"]
    return zone_law(fr["model"], scene["zones"][f"mu_{zone}"], fr[fr["model"]], fr["v_ref"])


def scene_parcel(scene: dict) -> Parcel:
    """
    Return a scene's parcel.

    Parameters
    ----------
    scene : dict
        A validated scene.

    Returns
    -------
    Parcel
        Its box.

    """
    p = scene["parcel"]
    return Parcel(p["A"], p["B"], p["m"])


def scene_strips(scene: dict):
    """
    Return a scene's three zones (Fig. 6).

    Parameters
    ----------
    scene : dict
        A validated scene.

    Returns
    -------
    list of Strip
        Zones a, b, c with their laws, the disks at the scene's angle and stroke.

    """
    fr, zones = scene["friction"], scene["zones"]
    return cell_strips(
        scene["belt"]["v"],
        scene["diverter"]["alpha_deg"],
        zones["b"],
        zones["mu_a"],
        zones["mu_b"],
        zones["mu_c"],
        fr["model"],
        scene["diverter"]["stroke"],
        fr[fr["model"]],
        fr["v_ref"],
    )


def scene_initial_state(scene: dict) -> np.ndarray:
    """
    Return a scene's start: leading edge on the zone a/b border, moving with the belt.

    Parameters
    ----------
    scene : dict
        A validated scene.

    Returns
    -------
    ndarray, shape (6,)
        The state (φ̇ = 0).

    """
    return entry_state(scene_parcel(scene), scene["belt"]["v"], scene["parcel"]["phi0_deg"])


MAX_RECORDS = 5_000_000  # records of a scene's trajectory kept at most


def run_scene(scene: dict) -> tuple[SimResult, dict]:
    """
    Run a validated scene.

    Parameters
    ----------
    scene : dict
        A scene from ``validate``, ``load_scene`` or ``apply_overrides``.

    Returns
    -------
    (SimResult, dict)
        The core's result, and the JSON-ready summary ``sorter run --json`` prints
        (t_scrap, x_scrap, φ at the scrap line, the stages, the capacity, the events).

    """
    solver = scene["solver"]
    y0 = scene_initial_state(scene)
    s = scene["belt"]["s"]
    sign = 1.0 if scene["diverter"]["alpha_deg"] >= 0 else -1.0
    strips = scene_strips(scene)
    # the scrap line lies s across the belt on the side the disks push to; the core
    # watches +y, so a negative α is run mirrored (the model is mirror-symmetric)
    if sign < 0:
        y0 = y0 * np.array([1, -1, -1, 1, -1, -1])
        strips = [
            type(st)(st.x_lo, st.x_hi, st.vx, -st.vy, st.law, st.weight, st.name) for st in strips
        ]
    res = simulate(
        scene_parcel(scene),
        strips,
        y0,
        (0.0, solver["t_max"]),
        solver["method"],
        rtol=solver["rtol"],
        atol=solver["atol"],
        dt=solver["dt"],
        v_min=scene["model"]["v_min"],
        y_target=y0[1] + s,
        rotation=scene["model"]["rotation"],
        stick=scene["model"]["stick"],
        reductions=solver["reductions"],
        n_quad=solver["n_quad"],
        g=scene["model"]["g"],
        # a fixed-step method records every step: room for all of them (up to 5 million
        # records, 280 MB), and beyond that a message in the scene's own keys
        max_points=min(
            MAX_RECORDS,
            max(200_000, int(math.ceil(solver["t_max"] / solver["dt"])) + 10),
        )
        if solver["method"] != "accurate"
        else 200_000,
    )
    if res.status == ST_MAX_STEPS:
        res.message = (
            "ran out of output capacity (a scene keeps at most "
            f"{MAX_RECORDS if solver['method'] != 'accurate' else 200_000} records): shorten "
            "solver.t_max, or lengthen solver.dt (implicit, threshold) or loosen solver.rtol "
            "(accurate)"
        )
    if sign < 0:
        res.y = res.y * np.array([1, -1, -1, 1, -1, -1])
    return res, summarize(scene, res, y0)


def stage_starts(res: SimResult, belt_surface: int = 0, disk_surface: int | None = 1) -> dict:
    """
    Start times of the stages of Fig. 10 from the run's events.

    E1: steady motion I (stuck on the belt while the disks rub); E2: transient
    (sliding on both), from the break-away off the belt; E3: steady motion II (stuck
    on the disks), from the stick on them. A run without those events (a parcel
    released sliding) takes them from its mode history.

    Parameters
    ----------
    res : SimResult
        A run.
    belt_surface : int
        The belt's surface id.
    disk_surface : int, optional
        The disks' surface id (None: no disks).

    Returns
    -------
    dict
        The start time of each stage [s] by name (E1, E2, E3); None for one that did
        not occur.

    """
    stages: dict[str, float | None] = {"E1": None, "E2": None, "E3": None}
    if len(res.mode) and res.mode[0] == belt_surface:
        stages["E1"] = float(res.t[0])
    # the break event is where the parcel leaves the belt: the record there still
    # carries the belt's mode (the step it ends), the first sliding record comes a
    # step later, so the mode history alone would start E2 one step late
    for t, kind, info in res.events:
        if kind == "break" and info == belt_surface and stages["E2"] is None:
            stages["E2"] = float(t)
        if kind == "stick" and disk_surface is not None and info == disk_surface:
            if stages["E3"] is None:
                stages["E3"] = float(t)
    for t, m in zip(res.t, res.mode):
        if m == -1 and stages["E2"] is None:
            stages["E2"] = float(t)
        if disk_surface is not None and m == disk_surface and stages["E3"] is None:
            stages["E3"] = float(t)
    return stages


def summarize(scene: dict, res: SimResult, y0) -> dict:
    """
    Return the JSON-ready summary of a run.

    Parameters
    ----------
    scene : dict
        The scene it ran.
    res : SimResult
        Its result.
    y0 : ndarray, shape (6,)
        Its start.

    Returns
    -------
    dict
        t_scrap, x_scrap, φ at the scrap line, the stages of Fig. 10, the capacity, the
        events and the final state.

    """
    t_scrap = res.t_target
    final = res.y[-1]
    disk = None
    alpha = math.radians(scene["diverter"]["alpha_deg"])
    v = scene["belt"]["v"]
    for k, (vx, vy) in enumerate(res.surfaces):
        if (
            math.isclose(vx, v * math.cos(alpha), abs_tol=1e-12)
            and math.isclose(abs(vy), abs(v * math.sin(alpha)), abs_tol=1e-12)
            and k != 0
        ):
            disk = k
    return {
        "t_scrap": t_scrap,
        "x_scrap": float(final[0] - y0[0]) if t_scrap is not None else None,
        "phi_scrap_deg": math.degrees(final[2]) if t_scrap is not None else None,
        "capacity_pcs_h": 3600.0 / t_scrap if t_scrap else None,
        "stages": stage_starts(res, 0, disk),
        "final_state": {
            "t": float(res.t[-1]),
            "x": float(final[0]),
            "y": float(final[1]),
            "phi_deg": math.degrees(final[2]),
            "vx": float(final[3]),
            "vy": float(final[4]),
            "omega": float(final[5]),
        },
        "status": res.status,
        "message": res.message,
        "success": res.success,
        "method": res.method,
        "n_steps": res.n_steps,
        "n_rhs": res.n_rhs,
        "n_events": res.n_events,
        "events": [{"t": t, "kind": k, "info": i} for t, k, i in res.events],
        "reductions": res.reductions,
        "wall_s": res.wall_s,
    }
