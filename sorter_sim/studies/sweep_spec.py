"""
A design study's spec: read, checked and expanded into its design points.

``load_study`` reads the YAML spec ``sorter sweep`` takes (its keys are in
``sweep``'s docstring), checks every key with a one-line ``SpecError`` naming it,
samples the design (a grid, or seeded random draws) and validates each point as a
scene up front; a ``Study`` keeps each point as its values alone. ``point_key``
is a point's key in the results table, which a resumed study matches.
"""

from __future__ import annotations

import copy
import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sorter_ros.strict_yaml import StrictYamlError, read_yaml_file
from sorter_sim.model.description import shown
from sorter_sim.runtime.scene import DEFAULTS, SceneError, load_scene, validate

SPEC_KEYS = ("scene", "set", "parameters", "sampling", "samples", "seed", "outputs", "out")
# what each point reports (from the scene summary)
OUTPUTS = (
    "success",
    "status",
    "message",
    "t_scrap",
    "x_scrap",
    "phi_scrap_deg",
    "capacity_pcs_h",
    "E1",
    "E2",
    "E3",
    "n_steps",
    "n_rhs",
    "n_events",
    "wall_s",
)
FORMATS = (".csv", ".parquet")


class SpecError(ValueError):
    """A study spec is malformed; the message names the key and what is allowed."""


# ---------------------------------------------------------------------------- the design
@dataclass
class Study:
    """
    A parsed spec: base scene, varied keys, the design points (each validated).

    A point is kept as its values only (a few numbers, not a scene of a few kB);
    ``scene`` builds its scene again when it runs.
    """

    keys: list
    points: list  # [values tuple], in design order, repeats removed
    outputs: list
    out: Path | None
    sampling: str
    base: dict

    @property
    def columns(self) -> list:
        return ["point"] + list(self.keys) + list(self.outputs)

    def scene(self, values) -> dict:
        """
        Return the validated scene of the design point with these values.

        Parameters
        ----------
        values : tuple
            The point's values, one per key of the study, in its order.

        Returns
        -------
        dict
            The scene.

        """
        return _point_scene(self.base, self.keys, values)


MAX_POINTS = 100_000  # a larger design is several studies (each resumable)


def _point_scene(base: dict, keys, values) -> dict:
    scene = copy.deepcopy(base)
    for key, value in zip(keys, values):
        _set_key(scene, key, value)
    return validate(scene)


def _split_key(key) -> tuple[str, str]:
    if not isinstance(key, str) or key.count(".") != 1:
        raise SpecError(
            f"parameters: keys have the form section.key (e.g. belt.v), got {shown(key)}"
        )
    section, name = key.split(".")
    if section not in DEFAULTS or name not in DEFAULTS[section]:
        allowed = ", ".join(f"{s}.{k}" for s in DEFAULTS for k in DEFAULTS[s])
        raise SpecError(f"parameters: unknown scene key {shown(key)}; allowed: {allowed}")
    return section, name


def _is_int_key(key: str) -> bool:
    section, name = key.split(".")
    d = DEFAULTS[section][name]
    return isinstance(d, int) and not isinstance(d, bool)


def _number(where: str, v, *, integer=False) -> float:
    if isinstance(v, str):
        try:
            v = float(v)  # YAML 1.1 reads 1e-6 as a string
        except ValueError:
            pass
    if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v):
        raise SpecError(f"{where}: must be a number, got {shown(v)}")
    if integer and v != int(v):
        raise SpecError(f"{where}: must be a whole number, got {shown(v)}")
    return float(v)


def _grid_values(key: str, spec) -> list:
    where = f"parameters.{key}"
    if isinstance(spec, list):
        values = spec
    elif isinstance(spec, dict) and set(spec) == {"values"}:
        values = spec["values"]
    elif isinstance(spec, dict) and {"min", "max"} <= set(spec) <= {"min", "max", "num", "log"}:
        num = spec.get("num")
        if num is None:
            raise SpecError(f"{where}: grid sampling needs num (how many values) with min/max")
        num = _number(f"{where}.num", num, integer=True)
        if not 1 <= num <= 100000:
            raise SpecError(f"{where}.num: must be in [1, 100000], got {num:g}")
        lo, hi = _number(f"{where}.min", spec["min"]), _number(f"{where}.max", spec["max"])
        if spec.get("log"):
            if not (lo > 0 and hi > 0):
                raise SpecError(f"{where}: log spacing needs min and max > 0, got {lo:g}, {hi:g}")
            values = list(np.geomspace(lo, hi, int(num)))
        else:
            values = list(np.linspace(lo, hi, int(num)))
        # 12 significant digits: 0.6, not linspace's 0.6000000000000001, in tables and keys
        values = [float(f"{v:.12g}") for v in values]
        if _is_int_key(key):
            values = sorted({int(round(v)) for v in values})
    else:
        raise SpecError(
            f"{where}: must be a list of values, {{values: [...]}} or "
            f"{{min: .., max: .., num: ..}}, got {shown(spec)}"
        )
    if not isinstance(values, list) or not values:
        raise SpecError(f"{where}: needs at least one value, got {shown(values)}")
    return [float(v) if isinstance(v, np.floating) else v for v in values]


def _random_sampler(key: str, spec):
    """Return a function rng -> one value of ``key``."""
    where = f"parameters.{key}"
    if isinstance(spec, list) or (isinstance(spec, dict) and set(spec) == {"values"}):
        values = spec if isinstance(spec, list) else spec["values"]
        if not isinstance(values, list) or not values:
            raise SpecError(f"{where}: needs at least one value, got {shown(values)}")
        return lambda rng: values[int(rng.integers(len(values)))]
    if isinstance(spec, dict) and {"min", "max"} <= set(spec) <= {"min", "max", "num", "log"}:
        lo, hi = _number(f"{where}.min", spec["min"]), _number(f"{where}.max", spec["max"])
        if hi < lo:
            raise SpecError(f"{where}: max must be >= min, got {lo:g}, {hi:g}")
        if _is_int_key(key):
            return lambda rng: int(rng.integers(int(math.ceil(lo)), int(math.floor(hi)) + 1))
        if spec.get("log"):
            if not (lo > 0 and hi > 0):
                raise SpecError(f"{where}: log sampling needs min and max > 0, got {lo:g}, {hi:g}")
            return lambda rng: float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        return lambda rng: float(rng.uniform(lo, hi))
    raise SpecError(
        f"{where}: must be a list of values, {{values: [...]}} or {{min: .., max: ..}}, "
        f"got {shown(spec)}"
    )


def _set_key(scene: dict, key: str, value) -> None:
    section, name = key.split(".")
    scene.setdefault(section, {})[name] = value


def load_study(path: str | Path, out: str | None = None) -> Study:
    """
    Read and check a study spec; every design point is validated as a scene up front.

    Parameters
    ----------
    path : str or Path
        The study file.
    out : str or Path, optional
        Where the results go.

    Returns
    -------
    Study
        The study.

    """
    p = Path(path)
    raw = _read_spec(p)
    base = _base_scene(raw, p)
    params = raw.get("parameters")
    if not isinstance(params, dict) or not params:
        raise SpecError("parameters: must map at least one scene key (e.g. belt.v) to its values")
    keys = list(params)
    for key in keys:
        _split_key(key)
    sampling = raw.get("sampling", "grid")
    if sampling not in ("grid", "random"):
        raise SpecError(f"sampling: must be grid or random, got {shown(sampling)}")
    if sampling == "grid":
        combos = _grid_design(raw, keys)
    else:
        combos = _random_design(raw, keys)
    outputs = raw.get("outputs", list(OUTPUTS))
    if not isinstance(outputs, list) or not outputs:
        raise SpecError(f"outputs: must be a list, a subset of {', '.join(OUTPUTS)}")
    for o in outputs:
        if o not in OUTPUTS:
            raise SpecError(f"outputs: unknown output {shown(o)}; allowed: {', '.join(OUTPUTS)}")
    points = _design_points(base, keys, combos)
    out_path = _out_path(raw, out, p)
    return Study(keys, points, list(outputs), out_path, sampling, base)


def _read_spec(p: Path) -> dict:
    """Read a study spec's YAML; refuse anything but a mapping of the spec's keys."""
    try:
        raw = read_yaml_file(p, "study spec")
    except StrictYamlError as exc:
        raise SpecError(str(exc)) from None
    if not isinstance(raw, dict):
        raise SpecError(
            f"study spec {shown(str(p))} must be a mapping with keys {', '.join(SPEC_KEYS)}"
        )
    for k in raw:
        if k not in SPEC_KEYS:
            raise SpecError(f"unknown spec key {shown(k)}; allowed: {', '.join(SPEC_KEYS)}")
    return raw


def _base_scene(raw: dict, p: Path) -> dict:
    """
    Return the study's base scene, validated: ``scene`` (a file or a mapping) with ``set``.

    A path is relative to the spec at ``p``; no ``scene`` is the default scene.
    """
    base_spec = raw.get("scene")
    if base_spec is None:
        base = validate({})
    elif isinstance(base_spec, str):
        base = load_scene(p.parent / base_spec)
    elif isinstance(base_spec, dict):
        try:
            base = validate(base_spec)
        except SceneError as exc:
            raise SpecError(f"scene: {exc}") from None
    else:
        raise SpecError(
            f"scene: must be a path to a scene file or a scene mapping, got {shown(base_spec)}"
        )
    fixed = raw.get("set") or {}
    if not isinstance(fixed, dict):
        raise SpecError(f"set: must be a mapping of section.key: value, got {shown(fixed)}")
    base = copy.deepcopy(base)
    for key, value in fixed.items():
        _split_key(key)
        _set_key(base, key, value)
    try:
        return validate(base)
    except SceneError as exc:
        raise SpecError(f"set: {exc}") from None


def _grid_design(raw: dict, keys: list):
    """Return the grid's points: every combination of the keys' values, lazily."""
    if "samples" in raw or "seed" in raw:
        raise SpecError("samples/seed: only for sampling: random")
    params = raw["parameters"]
    axes = [_grid_values(k, params[k]) for k in keys]
    size = math.prod(len(a) for a in axes)
    if size > MAX_POINTS:
        raise SpecError(
            f"parameters: the grid has {size} points, more than {MAX_POINTS} a study may "
            "have; split it into several studies"
        )
    return itertools.product(*axes)


def _random_design(raw: dict, keys: list):
    """Return ``samples`` random points, lazily, drawn from a generator seeded with ``seed``."""
    if "samples" not in raw:
        raise SpecError(
            "samples: random sampling needs samples (how many points), e.g. samples: 100"
        )
    n = _number("samples", raw["samples"], integer=True)
    if not 1 <= n <= MAX_POINTS:
        raise SpecError(
            f"samples: must be in [1, {MAX_POINTS}] (split a larger design into several "
            f"studies), got {n:g}"
        )
    seed = raw.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SpecError(f"seed: must be a whole number >= 0, got {shown(seed)}")
    params = raw["parameters"]
    samplers = [_random_sampler(k, params[k]) for k in keys]
    rng = np.random.default_rng(seed)
    # point-major draws: a larger `samples` keeps the first points (and their results)
    return (tuple(s(rng) for s in samplers) for _ in range(int(n)))


def _design_points(base: dict, keys: list, combos) -> list:
    """
    Validate each design point as a scene; return the distinct points' values.

    A value is kept as the scene has it (after validation); a point repeated (a grid
    may repeat a value) is run once.
    """
    points = []
    seen = {}
    for i, combo in enumerate(combos):
        try:
            scene = _point_scene(base, keys, combo)
        except SceneError as exc:
            desc = ", ".join(f"{k}={shown(v)}" for k, v in zip(keys, combo))
            raise SpecError(f"parameters: point {i} ({desc}): {exc}") from None
        values = tuple(scene[k.split(".")[0]][k.split(".")[1]] for k in keys)
        key = point_key(values)
        if key in seen:
            continue
        seen[key] = i
        points.append(values)
    return points


def _out_path(raw: dict, out, p: Path) -> Path:
    """
    Return where the results go: ``out`` as given, else the spec's ``out``, else ``<stem>.csv``.

    The spec's ``out`` is relative to the spec; the default is in the current folder.
    """
    out_path = out if out is not None else raw.get("out")
    if out_path is not None:
        if not isinstance(out_path, str):
            raise SpecError(
                f"out: must be a file path ending in .csv or .parquet, got {shown(out_path)}"
            )
        out_path = Path(out_path) if out is not None else p.parent / out_path
    else:
        out_path = Path(p.stem + ".csv")
    if out_path.suffix.lower() not in FORMATS:
        raise SpecError(f"out: must end in .csv or .parquet, got {shown(str(out_path))}")
    return out_path


# ---------------------------------------------------------------------------- a point's key
def param_text(v) -> str:
    """
    Return a parameter value as written in the table and used in the resume key.

    Parameters
    ----------
    v : object
        A parameter value.

    Returns
    -------
    str
        The text.

    """
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float, np.floating, np.integer)):
        return repr(float(v))
    if isinstance(v, (list, tuple)):
        return json.dumps([float(x) for x in v])
    return str(v)


def point_key(values) -> tuple:
    """
    Return a point's key: its values as the results file writes them.

    Parameters
    ----------
    values : tuple
        The point's values, one per key of the study, in its order.

    Returns
    -------
    tuple
        The key.

    """
    return tuple(param_text(v) for v in values)
