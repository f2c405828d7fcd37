"""
What the seed's figures share: the sorting scene, its measures, the result object, plotting.

``paper`` computes the figures; here are the pieces they are built from: the seed's
constants, ``FigureResult``, the sorting scene of section 5 and the measures taken on
its runs (x_o, the capacity W_t, the zones' rubbing speeds, the minimal disk-field
width, two-belt positioning, the friction forces of Figs. 14-16), and CSV and PNG
output.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from sorter_sim.model.core.common import n_surf_of
from sorter_sim.model.core.geometry import (
    MAX_VERTS,
    box_corners,
    clip_to_strip,
    polygon_area_centroid,
)
from sorter_sim.model.core.layout import Contact
from sorter_sim.model.core.simulate import (
    FrictionLaw,
    Parcel,
    Strip,
    parcel_array,
    simulate,
    strip_array,
)
from sorter_sim.model.core.wrench import evaluate_surfaces, gauss_legendre_01
from sorter_sim.runtime.scene import run_scene, validate

SEED_S = 0.7  # m, conveyor width the centre of gravity must cross (seed: s)
SEED_MU = 0.6  # the seed's μ_a = μ_b (= μ_c) of section 5
SEED_MU0, SEED_MUG = 0.65, 0.46  # section 6: μ_0, μ_G of models 2 and 3
ALPHAS = (90.0, 45.0, 30.0)  # the seed's disk angles, deg
B_LIMIT = 10.0  # m, the longest disk field a scene takes (``disk_field.length``)


# ---------------------------------------------------------------------------- results
STICK_LAWS = ("seed", "exact")  # the seed's decoupled stick test, the patch's limit set


@dataclass
class Check:
    """
    One statement of the seed as this run measures it.

    label: the statement in this project's words; holds: whether the run shows it;
    measured: the numbers that decide it, formatted.
    """

    label: str
    holds: bool
    measured: str = ""
    timed: bool = False  # decided by a measured time: reported, never a test or a failure


@dataclass
class FigureResult:
    """
    What one figure produced, scipy-result style.

    headline: the figures to compare with the seed (name -> value);
    seed: the seed's statements this figure is about, verbatim in spirit;
    checks: each qualitative statement of the seed, by its key in
    ``paper_statements.STATEMENTS`` -> how this run measures it (``claims`` is the
    same as label -> holds); data: the arrays behind the plot; files: CSV/PNG
    written; stick: the stick law it ran under (None where the figure has no
    stick between surfaces); wall_s: run time.
    """

    figure: str
    title: str
    headline: dict = field(default_factory=dict)
    seed: list = field(default_factory=list)
    checks: dict = field(default_factory=dict)
    data: dict = field(default_factory=dict)
    files: list = field(default_factory=list)
    stick: str | None = "seed"
    wall_s: float = 0.0

    def check(self, key: str, label: str, holds, measured: str = "", timed: bool = False) -> None:
        """
        Record how this run measures one statement of the seed.

        Parameters
        ----------
        key : str
            The statement's key in ``paper_statements.STATEMENTS``.
        label : str
            The statement in this project's words.
        holds : bool
            Whether the run shows it.
        measured : str
            The numbers that decide it.
        timed : bool
            Decided by a measured run time: reported, but the figure does not fail on
            it (the machine's load moves it).

        """
        self.checks[key] = Check(label, bool(holds), measured, timed)

    @property
    def claims(self) -> dict:
        """Return each checked statement's label -> whether it holds on this run."""
        return {c.label: c.holds for c in self.checks.values()}

    @property
    def success(self) -> bool:
        """Return True when every qualitative claim of the seed holds on this run."""
        return all(c.holds for c in self.checks.values() if not c.timed)

    def report(self) -> str:
        """Return the figure's printed report: headline, the seed's words, the checks."""
        law = "" if self.stick is None else f" [stick: {self.stick}]"
        lines = [f"Fig. {self.figure}: {self.title}{law}"]
        for k, v in self.headline.items():
            lines.append(f"  {k:<46} {_fmt(v)}")
        for s in self.seed:
            lines.append(f"  seed: {s}")
        for c in self.checks.values():
            tail = f": {c.measured}" if c.measured else ""
            verdict = "holds" if c.holds else ("not seen" if c.timed else "FAILS")
            lines.append(f"  [{verdict}] {c.label}{tail}")
        for f in self.files:
            lines.append(f"  wrote {f}")
        lines.append(f"  ({self.wall_s:.1f} s)")
        return "\n".join(lines)


FIGURE_PARAMETERS = """
    Parameters
    ----------
    out : Path, optional
        Where the CSV and PNG go (None: nothing written).
    quick : bool
        Coarse grids, for tests and quick looks.
    stick : str
        The stick law: "seed" (the seed's decoupled test, its own computations) or
        "exact" (the patch's limit set).

    Returns
    -------
    FigureResult
        The figure's data and headline figures.
"""


def figure_parameters(fn):
    """
    Append the parameters every figure function shares to its docstring.

    Parameters
    ----------
    fn : callable
        A figure function ``(out, quick, stick) -> FigureResult``.

    Returns
    -------
    callable
        The same function.

    """
    fn.__doc__ = (fn.__doc__ or "").rstrip() + "\n" + FIGURE_PARAMETERS
    return fn


def law_folder(out: Path | None, stick: str | None) -> Path | None:
    """
    Return where a figure run under ``stick`` writes: ``out``, or ``out/exact``.

    The seed's law is the figures' default, so its files keep their plain names;
    the exact law's go to a subfolder, and one folder holds both runs.

    Parameters
    ----------
    out : Path, optional
        The folder the user named (None: nothing written).
    stick : str, optional
        The stick law.

    Returns
    -------
    Path or None
        The folder for this law's files.

    """
    if out is None or stick in (None, "seed"):
        return out
    return out / stick


def _fmt(v) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (float, np.floating)):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.5g}"
    return str(v)


# ---------------------------------------------------------------------------- helpers
@dataclass(frozen=True)
class SortingScene:
    """
    The seed's sorting cell as the figures vary it; zone c takes μ_a unless told.

    The figures reproduce the seed's computations, so its decoupled stick test is the
    default here (``stick="exact"`` for the limit-set stick every other part uses).

    Attributes
    ----------
    A : float
        The parcel's length [m].
    B : float
        Its width [m].
    m : float
        The parcel's mass [kg].
    v : float
        The belt speed [m/s].
    alpha_deg : float
        The disk angle [deg].
    b : float
        The disk field's length [m].
    mu_a : float
        μ of the belt before the disks.
    mu_b : float
        μ of the disks.
    mu_c : float
        μ of the belt after them (``"mu_a"``: μ_a's).
    model : str
        The friction law's name.
    law : FrictionLaw
        The friction law.
    rotation : bool
        The moment of friction forces on.
    t_max : float
        The longest run [s].
    s : float
        The scrap distance across the belt [m].
    stick : str
        The stick law, exact or seed.

    """

    A: float = 0.7
    B: float = 0.2
    m: float = 5.0
    v: float = 1.5
    alpha_deg: float = 90.0
    b: float = math.inf
    mu_a: float | None = SEED_MU
    mu_b: float | None = SEED_MU
    mu_c: float | str | None = "mu_a"
    model: str = "const1"
    law: FrictionLaw | None = None
    rotation: bool = True
    t_max: float = 20.0
    s: float = SEED_S
    stick: str = "seed"

    def scene(self) -> dict:
        """
        Return the scene, validated.

        Returns
        -------
        dict
            The scene.

        """
        fr = {"model": self.model}
        if self.law is not None:
            fr[self.model] = list(self.law)
        return validate(
            {
                "parcel": {"A": self.A, "B": self.B, "m": self.m, "phi0_deg": 0.0},
                "belt": {"v": self.v, "s": self.s},
                "zones": {
                    "b": self.b,
                    "mu_a": self.mu_a,
                    "mu_b": self.mu_b,
                    "mu_c": self.mu_a if self.mu_c == "mu_a" else self.mu_c,
                },
                "diverter": {"alpha_deg": self.alpha_deg},
                "friction": fr,
                "model": {"rotation": self.rotation, "stick": self.stick},
                "solver": {"t_max": self.t_max},
            }
        )


def sorting_scene(**kw) -> dict:
    """
    Return a validated scene of the seed's sorting cell; zone c takes μ_a unless told.

    Parameters
    ----------
    **kw
        ``SortingScene``'s fields (the parcel, the belt, the zones' μ, the friction law,
        the stick law, the run's length), each defaulting to the seed's section 5.

    Returns
    -------
    dict
        The scene.

    """
    return SortingScene(**kw).scene()


def sort_once(**kw) -> dict:
    """
    Run one parcel through ``sorting_scene(**kw)``.

    The scene summary (t_scrap, x_scrap, ...).
    """
    _, summary = run_scene(sorting_scene(**kw))
    return summary


def _x_o(**kw) -> float:
    s = sort_once(**kw)
    return s["x_scrap"] if s["x_scrap"] is not None else math.nan


def _capacity(**kw) -> float:
    s = sort_once(**kw)
    return s["capacity_pcs_h"] if s["capacity_pcs_h"] is not None else math.nan


def _write_csv(path: Path, columns: dict) -> Path:
    """Columns of equal length (name -> sequence) as one CSV with a header row."""
    names = list(columns)
    n = len(next(iter(columns.values()))) if columns else 0
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for i in range(n):
            w.writerow([_cell(columns[c][i]) for c in names])
    return path


def _cell(v):
    if isinstance(v, (float, np.floating)):
        return "" if math.isnan(v) else repr(float(v))
    if isinstance(v, np.integer):
        return int(v)
    return v


def _figure(nrows=1, ncols=1, size=(7.0, 4.5)):
    """Return a matplotlib Figure on the Agg canvas (no pyplot state, no display needed)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes


def _save(fig, out: Path | None, name: str, files: list) -> None:
    if out is None:
        return
    out.mkdir(parents=True, exist_ok=True)
    path = out / name
    fig.savefig(path, dpi=110)
    files.append(path)


def _alpha_v_A_table(out: Path, fig_no: str, vs, As, arr, column: str, ylabel: str, files: list):
    """CSV and three panels (α = 90°, 45°, 30°) of a quantity arr[α, v, A], lines per v."""
    kk, ii, jj = np.meshgrid(range(3), range(len(vs)), range(len(As)), indexing="ij")
    files.append(
        _write_csv(
            out / f"fig{fig_no}.csv",
            {
                "alpha_deg": [ALPHAS[k] for k in kk.ravel()],
                "v_m_s": [vs[i] for i in ii.ravel()],
                "A_m": [As[j] for j in jj.ravel()],
                column: arr.ravel(),
            },
        )
    )
    fig, ax = _figure(1, 3, (13, 4.2))
    for k, al in enumerate(ALPHAS):
        a = ax[0, k]
        for i, v in enumerate(vs):
            a.plot(As, arr[k, i], "o-", ms=3, label=f"v = {v:.2f} m/s")
        a.set(
            xlabel="A [m]",
            ylabel=ylabel,
            title=f"Fig. {fig_no}{'abc'[k]}: α = {al:.0f}°",
            ylim=(0, 1.05 * np.nanmax(arr)),
        )
        a.legend(fontsize=7)
    return fig, ax


def _monotone(values, increasing=True, tol=0.0) -> bool:
    d = np.diff(np.asarray(values, float))
    return bool(np.all(d > -tol) if increasing else np.all(d < tol))


def disk_surface(res, v: float, alpha: float) -> int | None:
    """
    Surface id of the disks (velocity v(cos α, sin α)) in a run's surface list.

    Parameters
    ----------
    res : SimResult
        A run.
    v : float
        The belt speed [m/s].
    alpha : float
        The disk angle [rad].

    Returns
    -------
    int or None
        The disks' surface id, or None.

    """
    want = (v * math.cos(alpha), v * math.sin(alpha))
    for k, (vx, vy) in enumerate(res.surfaces):
        if (
            k > 0
            and math.isclose(vx, want[0], abs_tol=1e-12)
            and math.isclose(vy, want[1], abs_tol=1e-12)
        ):
            return k
    return None


def _loglog_slope(x, y) -> float:
    """Least-squares slope of ln y against ln x over the finite points."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    m = np.isfinite(y) & (y > 0)
    return float(np.polyfit(np.log(x[m]), np.log(y[m]), 1)[0]) if m.sum() >= 2 else math.nan


def _decimate(t, row, n_max):
    """Return the indices of ~n_max uniform samples plus every sample where ``row`` changes."""
    n = len(t)
    keep = set(range(0, n, max(1, n // n_max)))
    ch = np.nonzero(np.diff(row) != 0)[0]
    keep.update(ch.tolist())
    keep.update((ch + 1).tolist())
    keep.add(n - 1)
    return np.array(sorted(keep))


# ---------------------------------------------------------------------------- Fig. 10
@dataclass
class Samples:
    """A run's records, resampled for plots: t, y (n x 6), mode (the SimResult fields)."""

    t: np.ndarray
    y: np.ndarray
    mode: np.ndarray


def densify(res, dt: float = 0.005) -> Samples:
    """
    Add samples inside the run's stuck stretches, every ``dt`` [s].

    The accurate method advances a stick in closed form as one record pair; the
    parcel then moves rigidly with a surface (constant velocity, φ̇ = 0), so linear
    interpolation between the pair is exact. Sliding records are kept as they are.

    Parameters
    ----------
    res : SimResult
        A run.
    dt : float
        The sampling step [s].

    Returns
    -------
    Samples
        The dense samples.

    """
    ts, ys, ms = [res.t[:1]], [res.y[:1]], [res.mode[:1]]
    for k in range(len(res.t) - 1):
        t0, t1 = res.t[k], res.t[k + 1]
        y0, y1 = res.y[k], res.y[k + 1]
        if t1 - t0 > dt and y0[5] == 0.0 and np.array_equal(y0[3:6], y1[3:6]):
            tt = np.arange(t0 + dt, t1, dt)
            ts.append(tt)
            ys.append(y0 + np.outer((tt - t0) / (t1 - t0), y1 - y0))
            ms.append(np.full(len(tt), res.mode[k]))
        ts.append(res.t[k + 1 : k + 2])
        ys.append(res.y[k + 1 : k + 2])
        ms.append(res.mode[k + 1 : k + 2])
    return Samples(np.concatenate(ts), np.vstack(ys), np.concatenate(ms))


def zone_rubbing(res, strips: list[Strip], parcel: Parcel, names=("a", "b")) -> dict:
    """
    Rubbing-speed components ξ_i, η_i of zone parts over a run (seed eq. 4.7).

    For zone i the footprint part over it (box ∩ strip) is taken at its centroid q;
    ξ_i = v_surface,x - v_q,x and η_i = v_q,y - v_surface,y with v_q the parcel's
    velocity at q, the seed's sign convention. NaN where the parcel does not touch
    the zone. Returns {name: (ξ, η)} arrays over res.t.

    Parameters
    ----------
    res : SimResult
        A run.
    strips : list of Strip
        The strips.
    parcel : Parcel
        The parcel.
    names : sequence of str
        The zones' names.

    Returns
    -------
    dict
        Each zone's rubbing-speed components.

    """
    out = {}
    corners = np.empty((4, 2))
    poly = np.empty((MAX_VERTS, 2))
    work = np.empty((MAX_VERTS, 2))
    by_name = {s.name: s for s in strips}
    for name in names:
        st = by_name[name]
        xi = np.full(len(res.t), np.nan)
        eta = np.full(len(res.t), np.nan)
        for k, (x, y, phi, vx, vy, om) in enumerate(res.y):
            box_corners(x, y, phi, 0.5 * parcel.A, 0.5 * parcel.B, corners)
            n = clip_to_strip(corners, st.x_lo, st.x_hi, poly, work)
            area, qx, qy = polygon_area_centroid(poly, n)
            if area <= 1e-12:
                continue
            xi[k] = st.vx - (vx - om * (qy - y))
            eta[k] = (vy + om * (qx - x)) - st.vy
        out[name] = (xi, eta)
    return out


# ---------------------------------------------------------------------------- Fig. 11
def scrapes_without_sliding(res, v: float, alpha_deg: float) -> bool:
    """
    Return the seed's criterion for a sufficient disk field (section 5, Fig. 11).

    The disks must make the rubbing against them vanish (v_ob = 0) and keep it so
    until the parcel leaves zone b across the scrap line: the run reaches the
    scrap line while the parcel is stuck on the disk surface. With a finite b the
    belt zone c behind the field takes part, as it drags a parcel that is not yet
    held by the disks (or, at α < 90°, drifts into it) out of the field.

    Parameters
    ----------
    res : SimResult
        A run.
    v : float
        The belt speed [m/s].
    alpha_deg : float
        The disk angle [deg].

    Returns
    -------
    bool
        Whether it does.

    """
    disk = disk_surface(res, v, math.radians(alpha_deg))
    return res.t_target is not None and disk is not None and int(res.mode[-1]) == disk


@dataclass
class MinimalWidth:
    """Result of ``minimal_disk_width``: b_min [m], criterion evaluations, bracket, converged."""

    b_min: float
    n_evals: int
    bracket: tuple
    converged: bool
    flag: str = ""


def step_root(scrapes, b_lo: float, b_hi: float, xtol: float) -> MinimalWidth:
    """
    Smallest b in (b_lo, ...) with ``scrapes(b)`` true, for a yes/no criterion monotone in b.

    The criterion becomes a sign (+1 yes, -1 no) for scipy's brentq, which keeps a
    sign-changing bracket and converges to the step within ``xtol`` (on a step its
    interpolation steps fall back to bisection). The upper end is doubled until
    the criterion holds, up to the longest field a scene takes (``B_LIMIT``).

    Parameters
    ----------
    scrapes : callable
        b -> whether a disk field of length b scrapes the parcel.
    b_lo : float
        The bracket's low end [m].
    b_hi : float
        Its high end [m].
    xtol : float
        The bracket's tolerance [m].

    Returns
    -------
    MinimalWidth
        The bracket and the width.

    """
    n = [0]

    def sign(b):
        n[0] += 1
        return 1.0 if scrapes(b) else -1.0

    if sign(b_lo) > 0:
        return MinimalWidth(b_lo, n[0], (0.0, b_lo), False, "scrapes already at the lower bound")
    hi = b_hi
    while sign(hi) < 0:
        if hi >= B_LIMIT:
            return MinimalWidth(
                math.nan, n[0], (b_lo, hi), False, f"no width up to {B_LIMIT:g} m scrapes"
            )
        hi = min(2.0 * hi, B_LIMIT)
    b_min = brentq(sign, b_lo, hi, xtol=xtol)
    # brentq returns a point within xtol of the step; report the side that scrapes
    if sign(b_min) < 0:
        b_min = b_min + xtol
    return MinimalWidth(float(b_min), n[0], (b_lo, hi), True)


def minimal_disk_width(
    *, A=0.7, B=0.2, v=1.5, alpha_deg=90.0, mu=SEED_MU, xtol=1e-3, b_hi=2.0, b_lo=0.005, **scene_kw
) -> MinimalWidth:
    """
    Smallest disk-field width b that still scrapes (``scrapes_without_sliding``).

    Finite b, zone c present (μ_c = μ_a = μ_b = μ, the seed's Fig. 11 data); found
    by ``step_root`` (scipy brentq), not by a scan.

    Parameters
    ----------
    A : float
        The parcel's length [m].
    B : float
        Its width [m].
    v : float
        The belt speed [m/s].
    alpha_deg : float
        The disk angle [deg].
    mu : float
        The friction coefficient.
    xtol : float
        The bracket's tolerance [m].
    b_hi : float
        Its high end [m].
    b_lo : float
        The bracket's low end [m].

    Returns
    -------
    MinimalWidth
        The least width.

    """

    def scrapes(b):
        scene = sorting_scene(
            A=A,
            B=B,
            v=v,
            alpha_deg=alpha_deg,
            b=b,
            mu_a=mu,
            mu_b=mu,
            mu_c=mu,
            t_max=max(4.0, 8.0 * SEED_S / max(v, 1e-3)),
            **scene_kw,
        )
        res, _ = run_scene(scene)
        return scrapes_without_sliding(res, v, alpha_deg)

    return step_root(scrapes, b_lo, b_hi, xtol)


def two_belt_positioning(
    law: FrictionLaw,
    *,
    v=0.37,
    A=0.4,
    B=0.3,
    m=5.0,
    x0=0.05,
    t_end=10.0,
    method="accurate",
    stick="exact",
):
    """
    Run a parcel on the Fig. 12 two-belt stand.

    The Fig. 12 stand: belt x < 0 runs at +v, belt x > 0 at -v; parcel released at rest
    with its centre x0 off the border. Returns the core result.

    Parameters
    ----------
    law : FrictionLaw
        The friction law.
    v : float
        The belt speed [m/s].
    A : float
        The parcel's length [m].
    B : float
        Its width [m].
    m : float
        The parcel's mass [kg].
    x0 : float
        The start's offset [m].
    t_end : float
        The end [s].
    method : str
        The method.
    stick : str
        The stick law (exact or seed).

    Returns
    -------
    SimResult
        The run.

    """
    strips = [
        Strip(-math.inf, 0.0, +v, 0.0, law, name="forward"),
        Strip(0.0, math.inf, -v, 0.0, law, name="backward"),
    ]
    return simulate(
        Parcel(A, B, m),
        strips,
        [x0, 0.0, 0.0, 0.0, 0.0, 0.0],
        (0.0, t_end),
        method,
        stick=stick,
    )


def swing_peaks(t, x):
    """
    Return the times and heights |x| of the turning points of an oscillation about x = 0.

    Parameters
    ----------
    t : ndarray
        Times [s].
    x : ndarray
        Positions [m].

    """
    t = np.asarray(t)
    ax_ = np.abs(np.asarray(x))
    k = np.nonzero((ax_[1:-1] >= ax_[:-2]) & (ax_[1:-1] >= ax_[2:]) & (ax_[1:-1] > 1e-9))[0] + 1
    return t[k], ax_[k]


def friction_forces(res, strips: list[Strip], parcel: Parcel, rotation=True, g=9.81, n_quad=8):
    """
    Friction force (Fx, Fy) [N] each surface exerts on the parcel along a run.

    Sliding surfaces give their kinetic force (eqs. 4.2-4.3 with μ(v_o)); the surface
    the parcel is stuck to holds it at constant velocity, so it carries minus the
    sum of the others. Returns an array (n, n_surfaces, 2).

    Parameters
    ----------
    res : SimResult
        A run.
    strips : list of Strip
        The strips.
    parcel : Parcel
        The parcel.
    rotation : bool
        The moment of friction forces on.
    g : float
        Gravity [m/s²].
    n_quad : int
        Gauss points per direction.

    """
    arr = strip_array(strips)
    par = parcel_array(parcel, rotation, n_quad, True, g)
    nodes, weights = gauss_legendre_01(n_quad)
    ns = n_surf_of(arr)
    kin = np.zeros((ns, 3))
    stat = np.zeros((ns, 2))
    area = np.zeros(ns)
    slip = np.zeros(ns)
    out = np.zeros((len(res.t), ns, 2))
    for k in range(len(res.t)):
        mode = int(res.mode[k])
        evaluate_surfaces(
            res.y[k], Contact(arr, par, nodes, weights), mode, False, kin, stat, area, slip
        )
        out[k, :, :] = kin[:, :2]
        if mode >= 0:
            out[k, mode, :] = -(kin[:, :2].sum(axis=0) - kin[mode, :2])
    return out
