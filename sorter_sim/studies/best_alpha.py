"""
The best disk angle, a design result beyond the seed: ``sorter study best-alpha``.

The seed concludes that a larger disk angle α gives more capacity and a narrower
disk field (conclusions 2a, 2b) and draws α = 30°, 45° and 90° only. Between them
the capacity peaks below 90° (see the statement table of docs/paper.md). This
study finds, for one scene, the α that maximises the capacity W_t = 3600/t_c on the
scene's field and the α that minimises the disk-field width b that still scrapes
(Fig. 11's criterion), each to 1°: a scan every ``COARSE`` degrees, then every
degree around the best. It reports the curves and how flat they are near their
best (the span of α within 1 % of it), and ``map_doc`` writes the map over v x A
for the seed's parameters into docs/studies.md.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from sorter_sim.runtime.scene import apply_overrides, load_scene, run_scene, validate
from sorter_sim.studies.markdown import replace_block, with_contents
from sorter_sim.studies.paper_support import SEED_S, scrapes_without_sliding, step_root
from sorter_sim.studies.progress import progress_bar
from sorter_sim.studies.scene_args import add_scene_options

ALPHA_LO, ALPHA_HI = 15.0, 90.0  # deg, the scan (below the seed's 30°, to see the curve turn)
COARSE = 5.0  # deg, the first scan's step; the best is then refined to 1°
FLAT = 0.01  # within 1 % of the best counts as flat
XTOL = 1e-3  # m, the field width's tolerance (as Fig. 11)

# the seed's Fig. 9a point: 0.7 x 0.2 m, 5 kg, v = 1.5 m/s, μ = 0.6, b -> ∞, φ = 0
FIG9A = {
    "parcel": {"A": 0.7, "B": 0.2, "m": 5.0, "phi0_deg": 0.0},
    "belt": {"v": 1.5, "s": SEED_S},
    "zones": {"b": math.inf, "mu_a": 0.6, "mu_b": 0.6},
    "diverter": {"alpha_deg": 90.0},
    "friction": {"model": "const1"},
    "model": {"rotation": True},
}


@dataclass
class BestAlpha:
    """
    The study's result for one scene.

    alpha_capacity_deg, capacity_pcs_h: the α of the largest capacity and that
    capacity; capacity_at_90_pcs_h; alpha_width_deg, width_m: the α of the narrowest
    field that still scrapes, and that width; width_at_90_m; flat_*_deg: the span of
    α whose value is within 1 % of the best; curve: α [deg] -> capacity [pcs/h] and
    width [m] at every α computed.
    """

    alpha_capacity_deg: float
    capacity_pcs_h: float
    capacity_at_90_pcs_h: float
    alpha_width_deg: float
    width_m: float
    width_at_90_m: float
    flat_capacity_deg: list
    flat_width_deg: list
    stick: str
    rotation: bool
    curve: dict = field(default_factory=dict)
    runs: int = 0
    wall_s: float = 0.0


def _with(scene: dict, **changes) -> dict:
    s = copy.deepcopy(scene)
    for dotted, value in changes.items():
        sec, key = dotted.split(".")
        s[sec][key] = value
    return validate(s)


def capacity(scene: dict, alpha: float) -> float:
    """
    Return W_t = 3600/t_c [pcs/h] of the scene at disk angle ``alpha`` [deg] (NaN: never).

    Parameters
    ----------
    scene : dict
        A validated scene.
    alpha : float
        The disk angle [deg].

    Returns
    -------
    float
        The capacity.

    """
    _, summary = run_scene(_with(scene, **{"diverter.alpha_deg": alpha}))
    w = summary["capacity_pcs_h"]
    return math.nan if w is None else float(w)


def width(scene: dict, alpha: float) -> float:
    """
    Return the narrowest disk field [m] that scrapes the scene's parcel stuck on the disks.

    Zone c behind the field takes the scene's μ_c (Fig. 11's criterion, brentq to 1 mm).

    Parameters
    ----------
    scene : dict
        A validated scene.
    alpha : float
        The disk angle [deg].

    Returns
    -------
    float
        b_min [m] (NaN when no width up to 50 m scrapes).

    """
    v = scene["belt"]["v"]
    t_max = max(4.0, 8.0 * scene["belt"]["s"] / max(v, 1e-3))

    def scrapes(b):
        res, _ = run_scene(
            _with(scene, **{"zones.b": b, "diverter.alpha_deg": alpha, "solver.t_max": t_max})
        )
        return scrapes_without_sliding(res, v, alpha)

    return step_root(scrapes, 0.005, 2.0, XTOL).b_min


def _best(curve: dict, largest: bool) -> float:
    finite = {a: x for a, x in curve.items() if math.isfinite(x)}
    pick = max if largest else min
    return pick(finite, key=lambda a: (finite[a], a)) if finite else math.nan


def _refine(fn, curve: dict, largest: bool) -> float:
    """Scan every COARSE degrees, then every degree within COARSE of the best; the best α."""
    for a in _grid(ALPHA_LO, ALPHA_HI, COARSE):
        curve.setdefault(a, fn(a))
    a0 = _best(curve, largest)
    if math.isfinite(a0):
        for a in _grid(max(ALPHA_LO, a0 - COARSE + 1), min(ALPHA_HI, a0 + COARSE - 1), 1.0):
            curve.setdefault(a, fn(a))
    return _best(curve, largest)


def _grid(lo: float, hi: float, step: float) -> list:
    n = int(round((hi - lo) / step))
    return [round(lo + k * step, 6) for k in range(n + 1)]


def _flat(curve: dict, best: float, largest: bool) -> list:
    """Return [lo, hi]: the span of computed α whose value is within FLAT of the best one."""
    ok = [
        a
        for a, x in curve.items()
        if math.isfinite(x) and (x >= (1 - FLAT) * best if largest else x <= (1 + FLAT) * best)
    ]
    return [min(ok), max(ok)] if ok else [math.nan, math.nan]


def best_alpha(scene: dict) -> BestAlpha:
    """
    Find the α of the largest capacity and of the narrowest field for one scene, to 1°.

    Parameters
    ----------
    scene : dict
        A validated scene (its α is ignored; its b is the field capacity is taken on).

    Returns
    -------
    BestAlpha
        The two optima, their values at 90°, the curves and their flatness.

    """
    t0 = time.perf_counter()
    cap, wid = {}, {}
    a_cap = _refine(lambda a: capacity(scene, a), cap, True)
    a_wid = _refine(lambda a: width(scene, a), wid, False)
    alphas = sorted(set(cap) | set(wid))
    return BestAlpha(
        alpha_capacity_deg=a_cap,
        capacity_pcs_h=cap.get(a_cap, math.nan),
        capacity_at_90_pcs_h=cap[90.0],
        alpha_width_deg=a_wid,
        width_m=wid.get(a_wid, math.nan),
        width_at_90_m=wid[90.0],
        flat_capacity_deg=_flat(cap, cap.get(a_cap, math.nan), True),
        flat_width_deg=_flat(wid, wid.get(a_wid, math.nan), False),
        stick=scene["model"]["stick"],
        rotation=bool(scene["model"]["rotation"]),
        curve={
            "alpha_deg": alphas,
            "capacity_pcs_h": [cap.get(a, math.nan) for a in alphas],
            "width_m": [wid.get(a, math.nan) for a in alphas],
        },
        runs=len(cap) + len(wid),
        wall_s=time.perf_counter() - t0,
    )


def _json_safe(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_json_safe(v) for v in obj]
    return obj


def report(r: BestAlpha) -> str:
    """
    Return the study's printed lines.

    Parameters
    ----------
    r : BestAlpha
        The result.

    Returns
    -------
    str
        The report.

    """
    gain = 100 * (r.capacity_pcs_h / r.capacity_at_90_pcs_h - 1)
    shrink = 100 * (1 - r.width_m / r.width_at_90_m)
    lines = [
        f"best disk angle [stick: {r.stick}, moment {'on' if r.rotation else 'off'}]",
        f"  capacity: largest at α = {r.alpha_capacity_deg:.0f}°: {r.capacity_pcs_h:.0f} pcs/h "
        f"(90°: {r.capacity_at_90_pcs_h:.0f} pcs/h, {gain:+.1f} %); within 1 % over "
        f"{r.flat_capacity_deg[0]:.0f}-{r.flat_capacity_deg[1]:.0f}°",
        f"  field width: narrowest at α = {r.alpha_width_deg:.0f}°: {r.width_m:.3f} m "
        f"(90°: {r.width_at_90_m:.3f} m, {shrink:.1f} % narrower); within 1 % over "
        f"{r.flat_width_deg[0]:.0f}-{r.flat_width_deg[1]:.0f}°",
        "  α [deg]   W_t [pcs/h]   b_min [m]",
    ]
    c = r.curve
    for a, w, b in zip(c["alpha_deg"], c["capacity_pcs_h"], c["width_m"]):
        cell = lambda x, f: "" if not math.isfinite(x) else format(x, f)  # noqa: E731
        lines.append(f"  {a:7.0f}   {cell(w, '11.0f'):>11}   {cell(b, '9.3f'):>9}")
    lines.append(f"  ({r.runs} angles, {r.wall_s:.1f} s)")
    return "\n".join(lines)


# ---------------------------------------------------------------------------- the map
MAP_V = (0.5, 1.0, 1.5, 2.0, 2.5)  # m/s
MAP_A = (0.2, 0.4, 0.7, 1.0, 1.2)  # m


def map_rows(stick: str, *, vs=MAP_V, As=MAP_A, bar=None) -> list:
    """
    Return the best α over v x A for the seed's parameters under one stick law.

    Parameters
    ----------
    stick : str
        The stick law.
    vs, As : sequence of float
        Belt speeds [m/s] and parcel lengths [m].
    bar : tqdm, optional
        Progress, one tick per point.

    Returns
    -------
    list of BestAlpha
        One per (v, A), v slowest.

    """
    rows = []
    for v in vs:
        for A in As:
            scene = _with(
                validate(copy.deepcopy(FIG9A)),
                **{"belt.v": v, "parcel.A": A, "model.stick": stick},
            )
            rows.append((v, A, best_alpha(scene)))
            if bar is not None:
                bar.update(1)
    return rows


def map_markdown(rows_by_law: dict, elapsed: float) -> str:
    """
    Return the map as markdown: one table per stick law, one row per (v, A).

    Parameters
    ----------
    rows_by_law : dict
        stick law -> ``map_rows``.
    elapsed : float
        The run time [s].

    Returns
    -------
    str
        The block docs/studies.md holds.

    """
    out = [
        f"Written by `sorter study best-alpha --map --doc docs` in {elapsed:.0f} s. The seed's "
        "parameters: B = 0.2 m, m = 5 kg, μ_a = μ_b = μ_c = 0.6, s = 0.7 m, φ = 0, the moment "
        "on; capacity on an endless field (b -> ∞), width by Fig. 11's criterion (zone c "
        f"present), both to 1° over α {ALPHA_LO:.0f}-{ALPHA_HI:.0f}°. “flat” is the span of α "
        "within 1 % of the best. “none”: no field up to 10 m holds the parcel stuck on the "
        "disks up to the scrap line (at α = 90° and 2.5 m/s it reaches the line still "
        "sliding, however long the field).",
        "",
    ]
    for law, rows in rows_by_law.items():
        out += [
            f"**{law} stick**",
            "",
            "| v [m/s] | A [m] | best α for W_t | W_t [pcs/h] | at 90° | flat | best α for b "
            "| b_min [m] | at 90° | flat |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for v, A, r in rows:
            out.append(
                f"| {v:g} | {A:g} | {r.alpha_capacity_deg:.0f}° | {r.capacity_pcs_h:.0f} | "
                f"{r.capacity_at_90_pcs_h:.0f} | {_span(r.flat_capacity_deg)} | "
                f"{r.alpha_width_deg:.0f}° | {r.width_m:.3f} | {_width(r.width_at_90_m)} | "
                f"{_span(r.flat_width_deg)} |"
            )
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def _span(lo_hi) -> str:
    lo, hi = lo_hi
    return f"{lo:.0f}°" if lo == hi else f"{lo:.0f}-{hi:.0f}°"


def _width(b: float) -> str:
    # no field up to the longest a scene takes holds the parcel on the disks to the line
    return f"{b:.3f}" if math.isfinite(b) else "none"


BLOCK = ("<!-- generated: best-alpha -->", "<!-- end: best-alpha -->")


# ---------------------------------------------------------------------------- command
def add_arguments(parser: argparse.ArgumentParser) -> None:
    """
    Add ``sorter study best-alpha``'s arguments to its parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's parser.

    """
    parser.add_argument(
        "scene", nargs="?", default=None, help="scene YAML file (default: the seed's Fig. 9a)"
    )
    add_scene_options(parser)
    parser.add_argument(
        "--map",
        action="store_true",
        help="the map over v x A for the seed's parameters under both stick laws",
    )
    parser.add_argument(
        "--doc", metavar="DOCDIR", help="with --map: write the map into DOCDIR/studies.md"
    )


def run(args) -> int | str:
    """
    Run ``sorter study best-alpha``.

    Parameters
    ----------
    args : argparse.Namespace
        Its parsed arguments.

    Returns
    -------
    int or str
        The exit code, or a message for a refused input (exit 2).

    """
    if args.map:
        return _run_map(args)
    if args.doc:
        return "--doc writes the map: use `sorter study best-alpha --map --doc DOCDIR`"
    scene = load_scene(args.scene) if args.scene else validate(copy.deepcopy(FIG9A))
    if args.overrides:
        scene = apply_overrides(scene, args.overrides)
    r = best_alpha(scene)
    if args.json:
        print(json.dumps(_json_safe(asdict(r)), sort_keys=True))
    else:
        print(report(r))
    return 0


def _run_map(args) -> int | str:
    if args.scene or args.overrides:
        return "--map runs the seed's parameters: leave out SCENE and --set"
    page = None
    if args.doc:
        page = Path(args.doc) / "studies.md"
        if not page.is_file():
            return f"--doc: no {page} to write the map into"
    t0 = time.perf_counter()
    laws = ("seed", "exact")
    bar = progress_bar(len(laws) * len(MAP_V) * len(MAP_A), "best-alpha map", "point")
    rows = {law: map_rows(law, bar=bar) for law in laws}
    bar.close()
    block = map_markdown(rows, time.perf_counter() - t0)
    if args.json:
        print(
            json.dumps(
                _json_safe(
                    {
                        law: [dict(v=v, A=A, **asdict(r)) for v, A, r in rs]
                        for law, rs in rows.items()
                    }
                )
            )
        )
    else:
        print(block)
    if page is not None:
        page.write_text(with_contents(replace_block(page.read_text(), block, BLOCK)))
        print(f"wrote {page}", file=sys.stderr)
    return 0
