"""
The runs the seed's claims are judged on, over the ranges the seed states, cached per run.

A claim of the seed ("capacity rises with α over 30-90°") is checked on a grid that
covers the range it is made over, under each stick law and with the moment of
friction forces on (``full``) or neglected (``simplified``, the seed's own model for
its field-width estimates). ``GridStore`` runs each grid point once per process and
keeps what the claims read of it (t_c, x_o, the stages, the lateral accelerations,
the minimal field width b), so that every claim reads the same runs. Its values can
be saved to and read from a JSON table: ``sorter paper statements --doc docs``
writes ``docs/data/statement_grid.json``, and the tests recompute a few random
points of it on each run.

Symbols as in the seed: A x B parcel [m], v belt speed [m/s], α disk angle [deg].
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sorter_sim.model.build import BSPLINE_DEFAULT
from sorter_sim.model.core.simulate import FrictionLaw
from sorter_sim.runtime.scene import run_scene, scene_parcel, scene_strips
from sorter_sim.studies.two_stage import final_min_width, size_pre_field
from sorter_sim.studies.paper_models import FINAL_PART
from sorter_sim.studies.paper_support import (
    SEED_S,
    densify,
    friction_forces,
    SEED_MU,
    SEED_MU0,
    SEED_MUG,
    minimal_disk_width,
    sorting_scene,
    swing_peaks,
    two_belt_positioning,
)

ACC_WINDOW = 0.05  # s, the start of E2 over which the lateral acceleration is taken
BMIN_XTOL = 1e-3  # m, the minimal field width's tolerance (as Fig. 11)
BMIN_XTOL_FINE = 1e-4  # m, b_min located again where a rise is within a few BMIN_XTOL
# the break-away detection thresholds over which C2c's window start is varied: a slip
# of the parcel's centre off the belt a reader of the records would call "sliding"
BREAK_THRESHOLDS = (3e-4, 1e-3, 3e-3)  # m/s
FIG13_T_END = 12.0  # s, the two-belt runs of Fig. 13 (as ``paper_models.fig13``)


@dataclass(frozen=True)
class Grid:
    """
    The points a claim is checked at: disk angles, belt speeds, lengths and widths.

    alphas [deg], vs [m/s], As [m], Bs [m]; mus the friction coefficients Fig. 8d
    spans.
    """

    name: str
    alphas: tuple
    vs: tuple
    As: tuple
    Bs: tuple
    mus: tuple
    offsets: tuple = (0.05,)  # m, Fig. 13's release offsets off the belts' border


# the seed's own sample points: α = 90°, 45°, 30° (Figs. 8c-11), v 0.5-1.5 m/s, A and B
# over the ranges section 5 states; Fig. 13 released 5 cm off (the seed gives no offset)
PAPER = Grid(
    "the seed's points",
    (30.0, 45.0, 90.0),
    (0.5, 1.0, 1.5),
    (0.2, 0.4, 0.6, 0.8, 1.0, 1.2),
    (0.2, 0.4, 0.6, 0.8),
    (0.3, 0.6, 0.9),
)
# the ranges the seed states (section 5: v 0.5-1.5 m/s, A 0.2-1.2 m, B 0.2-0.8 m; α
# 30-90°), finer in α: 5° steps; Fig. 13 released 2.5-10 cm off
FULL = Grid(
    "the stated ranges",
    tuple(float(a) for a in range(30, 91, 5)),
    (0.5, 1.0, 1.5),
    (0.2, 0.4, 0.6, 0.8, 1.0, 1.2),
    (0.2, 0.4, 0.6, 0.8),
    (0.3, 0.45, 0.6, 0.75, 0.9),
    (0.025, 0.05, 0.075, 0.10),
)
# beyond them: v to 2.5 m/s, the rubbing speed section 3 says sorting lines reach,
# reported apart as an extrapolation of the claim, never in its verdict
BEYOND = Grid(
    "beyond the stated ranges (v to 2.5 m/s)",
    FULL.alphas,
    (0.5, 1.0, 1.5, 2.0, 2.5),
    FULL.As,
    FULL.Bs,
    FULL.mus,
    FULL.offsets,
)


@dataclass(frozen=True)
class Model:
    """A stick law and whether the moment of friction forces is on."""

    stick: str
    rotation: bool

    @property
    def key(self) -> str:
        """Return ``<stick law>/<full|simplified>``, the key of the statement table."""
        return f"{self.stick}/{'full' if self.rotation else 'simplified'}"


MODELS = tuple(Model(s, r) for s in ("seed", "exact") for r in (True, False))

# friction laws of section 6 by the seed's model number; "3@0.6" is model 3 with the
# section-5 value of μ instead of μ_G, "1@flat" model 1 on other points (sensitivities)
FRICTION_MODELS = {
    "1": ("bspline", tuple(BSPLINE_DEFAULT)),
    "2": ("const2", (SEED_MU0, SEED_MUG)),
    "3": ("const1", (SEED_MUG,)),
    "3@0.6": ("const1", (SEED_MU,)),
    # model 1 with its assumed sliding points all at μ_G (μ_0 kept): how far the verdict
    # on Figs. 15-16 rests on the b-spline points the seed does not give
    "1@flat": ("bspline", tuple(BSPLINE_DEFAULT[:6]) + (SEED_MU0,) + (SEED_MUG,) * 5),
}


def _key(kind: str, model: Model, **params) -> str:
    body = "|".join(f"{k}={_num(v)}" for k, v in sorted(params.items()))
    return f"{kind}|{model.key}|{body}"


def _num(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _stage_e2(summary: dict) -> tuple:
    """Return t_c, the start of E2 and its end (the stick on the disks, else t_c) of a run."""
    st = summary["stages"]
    t_c = summary["t_scrap"] if summary["t_scrap"] is not None else math.nan
    e2 = st["E2"] if st["E2"] is not None else math.nan
    e2_end = st["E3"] if st["E3"] is not None else t_c
    return t_c, e2, e2_end


def sort_record(res, summary: dict) -> dict:
    """
    Return what the claims read of one sorting run.

    t: t_c [s]; x: x_o [m]; e2, e2_end: start and end of stage E2 [s] (its end is the
    stick on the disks, or the scrap line when the parcel is scrapped still sliding);
    ay_early, ax_early: mean ÿ and ẍ over the first ``ACC_WINDOW`` of E2 [m/s²];
    ay_e2, ax_e2: mean ÿ and ẍ over E2 (at α = 90° these are equal and opposite by
    construction: E2 takes (v, 0) to (0, v)); ay_peak: the largest ÿ within E2;
    transitions: stick and break-away events.

    Parameters
    ----------
    res : SimResult
        The run.
    summary : dict
        Its summary (``run_scene``).

    Returns
    -------
    dict
        The record (NaN where the run has no such stage).

    """
    t_c, e2, e2_end = _stage_e2(summary)

    def vel(t, col):
        # stuck stretches are records at both ends with one velocity: linear is exact
        return float(np.interp(t, res.t, res.y[:, col])) if math.isfinite(t) else math.nan

    span = e2_end - e2
    # the largest lateral acceleration within E2, from the velocity between records
    in_e2 = (res.t >= e2) & (res.t <= e2_end) if span > 0 else np.zeros(len(res.t), bool)
    t2, vy2 = res.t[in_e2], res.y[in_e2, 4]
    dt = np.diff(t2)
    ok = dt > 1e-9
    ay_peak = float(np.max(np.diff(vy2)[ok] / dt[ok])) if ok.any() else math.nan
    return {
        "t": t_c,
        "x": summary["x_scrap"] if summary["x_scrap"] is not None else math.nan,
        "e2": e2,
        "e2_end": e2_end,
        "ay_early": (vel(e2 + ACC_WINDOW, 4) - vel(e2, 4)) / ACC_WINDOW,
        "ax_early": (vel(e2 + ACC_WINDOW, 3) - vel(e2, 3)) / ACC_WINDOW,
        "ay_peak": ay_peak,
        "ay_e2": (vel(e2_end, 4) - vel(e2, 4)) / span if span > 0 else math.nan,
        "ax_e2": (vel(e2_end, 3) - vel(e2, 3)) / span if span > 0 else math.nan,
        "transitions": float(sum(1 for e in summary["events"] if e["kind"] in ("stick", "break"))),
    }


def detail_record(res, summary: dict, v: float, alpha_deg: float) -> dict:
    """
    Return what the newer claims read of one sorting run, beyond ``sort_record``.

    ay_thr<i>: mean ÿ over the ``ACC_WINDOW`` from where the centre's slip off the belt
    first exceeds ``BREAK_THRESHOLDS[i]`` (E2 as a reader of the records would find it)
    [m/s²]; phi: φ at the scrap line [deg]; eta_b, xi_b: the mean |η_b| and |ξ_b| of
    eq. 4.7 at the centre of gravity over E2 [m/s]; rhs: the run's right-hand-side
    evaluations.

    Parameters
    ----------
    res : SimResult
        The run.
    summary : dict
        Its summary (``run_scene``).
    v : float
        The belt speed [m/s].
    alpha_deg : float
        The disk angle [deg].

    Returns
    -------
    dict
        The record (NaN where the run has no such stage).

    """
    d = densify(res)
    t, y = d.t, d.y
    slip = np.hypot(y[:, 3] - v, y[:, 4])
    out = {}
    for i, thr in enumerate(BREAK_THRESHOLDS):
        over = np.flatnonzero(slip > thr)
        t0 = math.nan
        if len(over) and over[0] > 0:
            k = over[0]
            # the crossing between records k-1 and k, linear in the slip
            t0 = t[k - 1] + (thr - slip[k - 1]) / (slip[k] - slip[k - 1]) * (t[k] - t[k - 1])
        if math.isfinite(t0) and t0 + ACC_WINDOW <= t[-1]:
            vy = np.interp([t0, t0 + ACC_WINDOW], t, y[:, 4])
            out[f"ay_thr{i}"] = float((vy[1] - vy[0]) / ACC_WINDOW)
        else:
            out[f"ay_thr{i}"] = math.nan
    _, e2, e2_end = _stage_e2(summary)
    al = math.radians(alpha_deg)
    inside = (t >= e2) & (t <= e2_end) if math.isfinite(e2) and e2_end > e2 else None
    if inside is not None and inside.sum() >= 2:
        tt = t[inside]
        xi = np.abs(v * math.cos(al) - y[inside, 3])
        eta = np.abs(-v * math.sin(al) + y[inside, 4])
        span = tt[-1] - tt[0]
        out["xi_b"] = float(np.trapezoid(xi, tt) / span)
        out["eta_b"] = float(np.trapezoid(eta, tt) / span)
    else:
        out["xi_b"] = out["eta_b"] = math.nan
    out["phi"] = summary["phi_scrap_deg"] if summary["phi_scrap_deg"] is not None else math.nan
    out["rhs"] = float(res.n_rhs)
    return out


class GridStore:
    """
    Each grid point's run, computed once per process (or read from a saved table).

    ``touched`` collects the keys read since it was last cleared, so a claim can say
    how many grid points its verdict rests on.

    Parameters
    ----------
    table : dict, optional
        Saved values (key -> record) to start from.
    compute : bool
        Run points the table lacks (False: a missing point is an error).
    progress : callable, optional
        Called with the number of points run so far (for a line on stderr).

    """

    def __init__(self, table: dict | None = None, compute: bool = True, progress=None):
        self.values = dict(table or {})
        self.compute = compute
        self.progress = progress
        self.n_run = 0
        self.touched: set = set()
        self._pre: dict = {}  # the preliminary field sized once per model (two_stage)

    def _get(self, key: str, run):
        self.touched.add(key)
        if key not in self.values:
            if not self.compute:
                raise KeyError(f"the grid table has no point {key}: regenerate it")
            self.values[key] = run()
            self.n_run += 1
            if self.progress is not None:
                self.progress(self.n_run)
        return self.values[key]

    def sort(self, model: Model, *, A, v, alpha, B=0.2, mu_a=SEED_MU, mu_b=SEED_MU) -> dict:
        """
        Return the record of one sort on an endless field (b -> ∞), the seed's Figs. 8-10.

        Parameters
        ----------
        model : Model
            Stick law and moment.
        A, B : float
            The parcel [m].
        v : float
            The belt speed [m/s].
        alpha : float
            The disk angle [deg].
        mu_a, mu_b : float
            Belt and disk friction coefficients (const1, the seed's section 5).

        Returns
        -------
        dict
            ``sort_record`` of the run.

        """

        def run():
            scene = sorting_scene(
                A=A,
                B=B,
                v=v,
                alpha_deg=alpha,
                mu_a=mu_a,
                mu_b=mu_b,
                stick=model.stick,
                rotation=model.rotation,
            )
            return sort_record(*run_scene(scene))

        return self._get(
            _key("sort", model, A=A, B=B, v=v, alpha=alpha, mu_a=mu_a, mu_b=mu_b), run
        )

    def detail(self, model: Model, *, A, v, alpha) -> dict:
        """
        Return ``detail_record`` of one sort on an endless field (B 0.2 m, μ 0.6).

        Parameters
        ----------
        model : Model
            Stick law and moment.
        A : float
            The parcel's length [m].
        v : float
            The belt speed [m/s].
        alpha : float
            The disk angle [deg].

        Returns
        -------
        dict
            The record.

        """

        def run():
            scene = sorting_scene(
                A=A, B=0.2, v=v, alpha_deg=alpha, mu_a=SEED_MU, mu_b=SEED_MU,
                stick=model.stick, rotation=model.rotation,
            )  # fmt: skip
            res, summary = run_scene(scene)
            return detail_record(res, summary, v, alpha)

        return self._get(_key("detail", model, A=A, v=v, alpha=alpha), run)

    def positioning(self, model: Model, friction: str, *, x0) -> dict:
        """
        Return the Fig. 13 two-belt positioning of one friction model from one release.

        v = 0.37 m/s, 0.4 x 0.3 m, released at rest x0 off the border, ``FIG13_T_END``
        long (as ``paper_models.fig13``; the parcel is symmetric about the border's
        normal, so the moment stays at round-off: one run serves both keys of a law).

        Parameters
        ----------
        model : Model
            Stick law (the moment does not enter, see above).
        friction : str
            The seed's model number, a key of ``FRICTION_MODELS``.
        x0 : float
            The release offset [m].

        Returns
        -------
        dict
            decay: last/first swing height; sticks: stick events.

        """

        def run():
            law, values = FRICTION_MODELS[friction]
            res = two_belt_positioning(
                FrictionLaw(law, values), x0=x0, t_end=FIG13_T_END, stick=model.stick
            )
            _, pk = swing_peaks(res.t, res.y[:, 0])
            return {
                "decay": float(pk[-1] / pk[0]) if len(pk) >= 2 else math.nan,
                "sticks": float(sum(1 for _, k, _ in res.events if k == "stick")),
            }

        return self._get(_key("pos", Model(model.stick, True), f=friction, x0=x0), run)

    def sort_law(self, model: Model, friction: str, *, A, B, v, alpha) -> dict:
        """
        Return the record of one sort with a section-6 friction model in every zone.

        Parameters
        ----------
        model : Model
            Stick law and moment.
        friction : str
            The seed's model number, a key of ``FRICTION_MODELS``.
        A, B, v, alpha : float
            Parcel [m], belt speed [m/s], disk angle [deg].

        Returns
        -------
        dict
            ``sort_record`` of the run.

        """

        def run():
            law, values = FRICTION_MODELS[friction]
            scene = sorting_scene(
                A=A,
                B=B,
                v=v,
                alpha_deg=alpha,
                mu_a=None,
                mu_b=None,
                mu_c=None,
                model=law,
                law=values,
                stick=model.stick,
                rotation=model.rotation,
            )
            return sort_record(*run_scene(scene))

        return self._get(_key("law", model, f=friction, A=A, B=B, v=v, alpha=alpha), run)

    def fig14_force(self, model: Model, friction: str) -> dict:
        """
        Return |F_b| over the final quarter of E2 at the seed's Fig. 14 point.

        α = 45°, v = 1.5 m/s, 0.4 x 0.26 m, 5 kg, every zone on the friction model.

        Parameters
        ----------
        model : Model
            Stick law and moment.
        friction : str
            The seed's model number, a key of ``FRICTION_MODELS``.

        Returns
        -------
        dict
            end: |F_b| at the end of E2 [N]; low, high: its least and largest value in
            the final quarter of E2 [N].

        """

        def run():
            law, values = FRICTION_MODELS[friction]
            scene = sorting_scene(
                A=0.4, B=0.26, v=1.5, alpha_deg=45.0, mu_a=None, mu_b=None, mu_c=None,
                model=law, law=values, stick=model.stick, rotation=model.rotation,
            )  # fmt: skip
            res, summ = run_scene(scene)
            res = densify(res)
            f = friction_forces(
                res, scene_strips(scene), scene_parcel(scene), rotation=model.rotation
            )
            st = summ["stages"]
            e2, e3 = st["E2"], st["E3"] if st["E3"] is not None else summ["t_scrap"]
            mag = np.hypot(f[:, 1, 0], f[:, 1, 1])
            last = mag[(res.t >= e3 - FINAL_PART * (e3 - e2)) & (res.t < e3)]
            return {"end": float(last[-1]), "low": float(last.min()), "high": float(last.max())}

        return self._get(_key("f14", model, f=friction), run)

    def b_min(self, model: Model, *, A, v, alpha, fine: bool = False) -> float:
        """
        Return the minimal disk-field width [m] that still scrapes (Fig. 11's criterion).

        Parameters
        ----------
        model : Model
            Stick law and moment.
        A : float
            The parcel's length [m] (B = 0.2 m).
        v : float
            The belt speed [m/s].
        alpha : float
            The disk angle [deg].

        fine : bool
            Locate it to ``BMIN_XTOL_FINE`` instead.

        Returns
        -------
        float
            b_min to ``BMIN_XTOL`` (or ``BMIN_XTOL_FINE``), on the side that scrapes.

        """
        xtol = BMIN_XTOL_FINE if fine else BMIN_XTOL

        def run():
            mw = minimal_disk_width(
                A=A,
                v=v,
                alpha_deg=alpha,
                xtol=xtol,
                stick=model.stick,
                rotation=model.rotation,
            )
            return {"b": mw.b_min}

        kind = "bminfine" if fine else "bmin"
        return self._get(_key(kind, model, A=A, v=v, alpha=alpha), run)["b"]

    def two_stage(self, model: Model, *, alpha2) -> dict:
        """
        Return the final field's least width behind a preliminary one, and the single one's.

        The seed's conclusion 4 as ``two_stage`` runs it: 0.7 x 0.2 m, v = 1.5 m/s, a
        preliminary field at 90° sized to shift the parcel by half the belt (0.35 m).

        Parameters
        ----------
        model : Model
            Stick law and moment.
        alpha2 : float
            The final field's disk angle [deg].

        Returns
        -------
        dict
            single: b_min of one field [m]; final: of the final field behind the other.

        """
        kw = dict(A=0.7, B=0.2, v=1.5, stick=model.stick, rotation=model.rotation)

        def run():
            if model.key not in self._pre:
                self._pre[model.key] = size_pre_field(0.5 * SEED_S, **kw)
            _, mw = final_min_width(self._pre[model.key], alpha2_deg=alpha2, xtol=BMIN_XTOL, **kw)
            single = minimal_disk_width(alpha_deg=alpha2, xtol=BMIN_XTOL, **kw)
            return {"single": single.b_min, "final": mw.b_min}

        return self._get(_key("two", model, alpha2=alpha2), run)

    def save(self, path: Path) -> Path:
        """
        Write the values as a JSON table (floats to 7 significant digits).

        Parameters
        ----------
        path : Path
            The file.

        Returns
        -------
        Path
            The file written.

        """
        path.parent.mkdir(parents=True, exist_ok=True)
        rounded = {
            k: {f: (None if not math.isfinite(x) else float(f"{x:.7g}")) for f, x in rec.items()}
            for k, rec in sorted(self.values.items())
        }
        path.write_text(json.dumps(rounded, indent=0, sort_keys=True) + "\n")
        return path


TABLE_MAX_BYTES = 64 * 1024 * 1024  # the saved grid is 2.4 MB
_TIME = (0.0, 1e3, "a time [s]")
_LENGTH = (0.0, 1e3, "a length [m]")
_ACCEL = (-1e4, 1e4, "an acceleration [m/s²]")
_SORT_FIELDS = {
    "t": _TIME,
    "x": (-1e3, 1e3, "a position [m]"),
    "e2": _TIME,
    "e2_end": _TIME,
    "ay_early": _ACCEL,
    "ax_early": _ACCEL,
    "ay_peak": _ACCEL,
    "ay_e2": _ACCEL,
    "ax_e2": _ACCEL,
    "transitions": (0.0, 1e6, "a count"),
}
# what each kind of record holds, and the range each value may take: (low, high, what);
# a time, a length or a force is above ``low`` (the claims divide by them), the rest within
TABLE_FIELDS = {
    "sort": _SORT_FIELDS,
    "law": _SORT_FIELDS,
    "f14": {f: (0.0, 1e6, "a force [N]") for f in ("end", "low", "high")},
    "two": {"single": _LENGTH, "final": _LENGTH},
    "bmin": {"b": _LENGTH},
    "bminfine": {"b": _LENGTH},
    "pos": {"decay": (0.0, 1e6, "a ratio of swings"), "sticks": (0.0, 1e6, "a count")},
    "detail": {
        "ay_thr0": _ACCEL,
        "ay_thr1": _ACCEL,
        "ay_thr2": _ACCEL,
        "eta_b": (-1e3, 1e3, "a length [m]"),
        "xi_b": (-1e3, 1e3, "a length [m]"),
        "phi": (-1e5, 1e5, "an angle [°]"),
        "rhs": (0.0, 1e9, "a count"),
    },
}
_OPEN_BELOW = {"t", "e2_end", "end", "low", "high", "single", "final", "b"}
_KEY_PARAMS = {"A", "B", "alpha", "alpha2", "f", "mu_a", "mu_b", "v", "x0"}


def _key_problem(key) -> str | None:
    if not isinstance(key, str) or len(key) > 200:
        return f"a key {str(key)[:60]!r}... is longer than 200 characters"
    kind, _, rest = key.partition("|")
    model, _, body = rest.partition("|")
    if kind not in TABLE_FIELDS:
        return f"key {key!r}: its kind {kind!r} is none of {', '.join(TABLE_FIELDS)}"
    if model not in {m.key for m in MODELS}:
        return f"key {key!r}: model {model!r} is none of {', '.join(m.key for m in MODELS)}"
    for item in body.split("|"):
        name, _, value = item.partition("=")
        if name not in _KEY_PARAMS:
            return f"key {key!r}: {name!r} is none of {', '.join(sorted(_KEY_PARAMS))}"
        if name != "f":
            try:
                ok = math.isfinite(float(value))
            except ValueError:
                ok = False
            if not ok:
                return f"key {key!r}: {name}={value!r} is not a finite number"
    return None


def table_problem(raw) -> str | None:
    """
    Say what is wrong with a table read from JSON (None when ``GridStore`` may read it).

    Every key names a kind of run, a model and its parameters; every record holds
    exactly the values of its kind, each a number in its range or null (no such stage),
    so that a claim judged on it never meets a value it cannot take (a time of 0, a
    force of 1e300).

    Parameters
    ----------
    raw : object
        What ``json.loads`` made of the file.

    Returns
    -------
    str or None
        One line: the first key or value that is wrong, and what is allowed.

    """
    if not isinstance(raw, dict):
        return f"the table must be a JSON object (key -> record), not a {type(raw).__name__}"
    for key, rec in raw.items():
        problem = _key_problem(key)
        if problem:
            return problem
        fields = TABLE_FIELDS[key.partition("|")[0]]
        if not isinstance(rec, dict) or set(rec) != set(fields):
            got = sorted(rec)[:12] if isinstance(rec, dict) else type(rec).__name__
            return f"key {key!r}: its record must hold {', '.join(fields)}, got {got}"
        for f, x in rec.items():
            if x is None:
                continue
            low, high, what = fields[f]
            num = isinstance(x, (int, float)) and not isinstance(x, bool)
            above = num and (x > low if f in _OPEN_BELOW else x >= low)
            if not (num and math.isfinite(x) and above and x <= high):
                bound = "above" if f in _OPEN_BELOW else "from"
                return (
                    f"key {key!r}: {f} = {str(x)[:40]} is not {what} {bound} {low:g} "
                    f"to {high:g} (or null)"
                )
    return None


def load_table(path: Path) -> dict:
    """
    Read a table ``GridStore.save`` wrote (None back to NaN).

    Parameters
    ----------
    path : Path
        The file.

    Returns
    -------
    dict
        key -> record.

    Raises
    ------
    ValueError
        With one line, when the file is too large, no JSON, or not such a table
        (``table_problem``).

    """
    path = Path(path)
    size = path.stat().st_size
    if size > TABLE_MAX_BYTES:
        raise ValueError(f"{size} bytes, more than the {TABLE_MAX_BYTES} a grid table may have")
    try:
        raw = json.loads(path.read_bytes())
    except RecursionError:
        raise ValueError("nested too deep for a grid table (key -> record of numbers)") from None
    except ValueError as exc:  # UnicodeDecodeError too
        raise ValueError(f"not JSON: {str(exc).splitlines()[0][:120]}") from None
    problem = table_problem(raw)
    if problem:
        raise ValueError(problem[:400])
    return {
        k: {f: (math.nan if x is None else float(x)) for f, x in rec.items()}
        for k, rec in raw.items()
    }


def recompute(key: str) -> dict:
    """
    Run one point of a saved table afresh (for the tests' spot checks).

    Parameters
    ----------
    key : str
        A key of the table.

    Returns
    -------
    dict
        Its record, computed now.

    """
    kind, model_key, body = key.split("|", 2)
    stick, which = model_key.split("/")
    model = Model(stick, which == "full")
    params = {}
    for item in body.split("|"):
        name, value = item.split("=")
        params[name] = value if name == "f" else float(value)
    store = GridStore()
    if kind == "pos":
        return store.positioning(model, params.pop("f"), **params)
    if kind == "sort":
        return store.sort(model, **params)
    if kind == "detail":
        return store.detail(model, **params)
    if kind == "bminfine":
        return {"b": store.b_min(model, fine=True, **params)}
    if kind == "law":
        return store.sort_law(model, params.pop("f"), **params)
    if kind == "f14":
        return store.fig14_force(model, params["f"])
    if kind == "two":
        return store.two_stage(model, **params)
    return {"b": store.b_min(model, **params)}


def stderr_progress(every: int = 50):
    """Return a progress callback writing the count of runs to stderr every ``every`` runs."""

    def tick(n):
        if n % every == 0:
            print(f"  statements: {n} grid points run", file=sys.stderr, flush=True)

    return tick
