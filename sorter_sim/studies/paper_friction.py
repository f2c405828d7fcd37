"""
Figs. 3-5 of the seed (section 3): the friction laws as used and the stick-slip body of eq. (3.1).

Fig. 3 draws each law with where its parameters come from; Figs. 4 and 5 run the
mass-spring body with eq. (3.1)'s threshold method against the exact Coulomb solution.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from sorter_sim.model.build import BSPLINE_DEFAULT, LAW_DEFAULTS
from sorter_sim.model.core.friction import mu_kinetic_array, mu_static
from sorter_sim.model.core.oscillator import (
    Oscillator,
    exact_solution,
    run_oscillator,
    static_stage_durations,
)
from sorter_sim.model.core.simulate import FrictionLaw
from sorter_sim.studies.paper_support import (
    figure_parameters,
    SEED_MU,
    SEED_MU0,
    SEED_MUG,
    FigureResult,
    _decimate,
    _figure,
    _loglog_slope,
    _monotone,
    _save,
    _write_csv,
)


# ---------------------------------------------------------------------------- Fig. 3
# Where each drawn law's parameters come from. The seed names its sources for the
# shapes (a)-(f) but gives values only for μ_0, μ_G (section 6) and μ = 0.6 (section 5);
# every other value below is this project's assumption, declared in model/build.py.
FIG3_LAWS = (
    ("(a) const2: μ_0 0.65, μ_G 0.46", "const2", (SEED_MU0, SEED_MUG), "the seed (section 6)"),
    ("(b) const1: μ 0.6", "const1", (SEED_MU,), "the seed (section 5)"),
    (
        "(b) const1: μ 0.46 (model 3)",
        "const1",
        (SEED_MUG,),
        "assumption: model 3 takes μ = μ_G (the seed names no value)",
    ),
    (
        "(c) linear",
        "linear",
        tuple(LAW_DEFAULTS["linear"]),
        "assumption (LAW_DEFAULTS): μ_0 0.65 falling 0.15 per m/s",
    ),
    (
        "(d) polynomial",
        "polynomial",
        tuple(LAW_DEFAULTS["polynomial"]),
        "assumption (LAW_DEFAULTS): shaped to rise steeply towards 1 m/s, as the seed says",
    ),
    (
        "(e) Stribeck",
        "stribeck",
        tuple(LAW_DEFAULTS["stribeck"]),
        "assumption (LAW_DEFAULTS): the seed's formula, values made up",
    ),
    (
        "(f) b-spline (model 1)",
        "bspline",
        tuple(BSPLINE_DEFAULT),
        "assumption (BSPLINE_DEFAULT): μ_0 0.65 from the seed, the other points made up",
    ),
)


@figure_parameters
def fig3(out: Path | None = None, quick: bool = False, stick: str = "seed") -> FigureResult:
    """
    Draw the friction laws of Fig. 3 as this project uses them, each with its source.

    The laws' own parameters (``friction.<law>`` in a scene; a zone's μ scales the
    curve to that value at 1 m/s). The seed draws them over v_o = 0..1 m/s; here up
    to 2.5 m/s, the rubbing speeds sorting reaches.

    Parameters
    ----------
    out : Path, optional
        Where the CSV and PNG go (None: nothing written).
    quick : bool
        Fewer speeds.
    stick : str
        Unused: a friction law does not depend on the stick law.

    Returns
    -------
    FigureResult
        The curves, and the seed's statements about them.

    """
    t0 = time.perf_counter()
    speeds = np.linspace(0.0, 2.5, 51 if quick else 501)
    curves = {}
    for label, model, values, source in FIG3_LAWS:
        law = FrictionLaw(model, values)
        mu = mu_kinetic_array(law.law_id, law.row(), np.maximum(speeds, 1e-9))
        curves[label] = (mu, mu_static(law.law_id, law.row()), source)
    r = FigureResult("3", "the friction laws as used: μ against the rubbing speed", stick=None)
    at1 = {}
    for label, (mu, mu_s, source) in curves.items():
        at1[label] = float(np.interp(1.0, speeds, mu))
        r.headline[f"{label}: μ_s ; μ(1 m/s)"] = f"{mu_s:.3f} ; {at1[label]:.3f}"
    r.seed = [
        "(a)-(c): a logical and real range of the friction coefficient",
        "(d), (e): towards v_o = 1 m/s the coefficient reaches an unbelievably high value",
        "(f): the b-spline law, valid over 0.2-2.5 m/s, the one the seed prefers",
    ]
    names = list(curves)
    upto1 = speeds <= 1.0
    plain = [n for n in names if n[:3] in ("(a)", "(b)", "(c)")]
    r.check(
        "3-range",
        "(a)-(c) stay within 0.3..0.7 over 0..1 m/s; (d), (e) exceed 1 at 1 m/s",
        all(0.3 <= curves[n][0][upto1].min() and curves[n][0][upto1].max() <= 0.7 for n in plain)
        and at1[names[4]] > 1.0
        and at1[names[5]] > 1.0,
        f"μ(1 m/s) = {at1[names[4]]:.2f} (d), {at1[names[5]]:.2f} (e); by assumed parameters",
    )
    r.data = {"speeds": speeds, "curves": curves}
    if out is not None:
        cols = {"v_o_m_s": speeds}
        for label, (mu, _, _) in curves.items():
            cols["mu " + label.split(":")[0]] = mu
        r.files.append(_write_csv(out / "fig3.csv", cols))
        fig, ax = _figure(1, 1, (8.0, 6.8))
        a = ax[0, 0]
        for label, (mu, mu_s, source) in curves.items():
            style = "--" if source.startswith("assumption") else "-"
            (line,) = a.plot(speeds, mu, style, label=f"{label} — {source}")
            # the static limit μ_s, the value as v_o -> 0+ (eq. 3.1's F_stat)
            a.plot([0.0], [mu_s], "o", ms=4, color=line.get_color())
        a.axvline(1.0, color="0.6", lw=0.8, ls=":")
        a.text(1.0, 0.05, " the seed draws 0..1 m/s", fontsize=7, color="0.4")
        a.set(
            xlabel="rubbing speed v_o [m/s] (dots: μ_s at rest)",
            ylabel="μ",
            ylim=(0.0, 1.8),
            title="Fig. 3: friction laws as used (solid: the seed's values, dashed: assumed)",
        )
        a.legend(fontsize=6.5, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=1)
        _save(fig, out, "fig3.png", r.files)
    r.wall_s = time.perf_counter() - t0
    return r


# ---------------------------------------------------------------------------- Fig. 4
@figure_parameters
def fig4(out: Path | None = None, quick: bool = False, stick: str = "seed") -> FigureResult:
    """
    Stick-slip of the mass-spring body with eq. (3.1) (threshold method, v_min = 1 mm/s).

    Trajectories of the body and of the spring end B, the friction force, the
    external force P_ext = k (x_s - x_p), the rubbing speed, and the active row
    of eq. (3.1) over time; compared with the exact Coulomb solution.

    """
    t0 = time.perf_counter()
    osc = Oscillator()  # the seed's m = 1 kg, F_kin = 1 N, F_stat = 1.5 N, k = 2 N/m, 0.1 m/s
    v_min = 1e-3
    t_end = 25.0
    dt = 1e-4 if quick else 1e-5
    res = run_oscillator(osc, t_end, "threshold", dt=dt, v_min=v_min)
    exact = exact_solution(osc, t_end, t_eval=res.t)
    slips_exact = [t for t, k in exact.events if k == "slip"]
    row3_starts = [t for t, k in res.events if k == "row3"]
    durations = static_stage_durations(res)
    t_first_exact = osc.F_stat / (osc.k * osc.v_drive)
    # in F(3) the body starts from rest with P - F_stat = k v_s τ, so v = k v_s τ²/(2m)
    # reaches v_min after τ = sqrt(2 m v_min / (k v_s)): the closed form of t_I
    t_I_closed = math.sqrt(2 * osc.m * v_min / (osc.k * osc.v_drive))
    # eq. (3.1) holds the body until |v| > v_min, so each break-away comes late by
    # about t_I and the cycles drift against the exact ones: compare periods, and
    # positions over the first slide only
    first_stick = next((t for t, k in exact.events if k == "stick"), t_end)
    err = float(np.max(np.abs(res.x - exact.x)[res.t <= first_stick]))
    period = float(np.mean(np.diff(row3_starts))) if len(row3_starts) > 1 else math.nan
    period_exact = float(np.mean(np.diff(slips_exact))) if len(slips_exact) > 1 else math.nan
    # one body on one surface: eq. (3.1) is its stick law, the same under both of the cell's
    r = FigureResult("4", "stick-slip body, eq. (3.1) with v_min = 0.001 m/s", stick=None)
    r.headline = {
        "first break-away (row 3 starts) [s]": row3_starts[0] if row3_starts else math.nan,
        "first break-away, exact Coulomb [s]": t_first_exact,
        "t_I, duration of F(3) in cycle I [s]": durations[0] if durations else math.nan,
        "t_I closed form sqrt(2 m v_min/(k v_s)) [s]": t_I_closed,
        "stick-slip cycles in 25 s (threshold/exact)": f"{len(row3_starts)}/{len(slips_exact)}",
        "stick-slip period, threshold / exact [s]": f"{period:.4f} / {period_exact:.4f}",
        "max |x_p - x_p exact| up to the first stick [m]": err,
        "integration step dt [s]": dt,
    }
    r.seed = [
        "rows F(1) kinetic, F(2) holding, F(3) breaking away take turns (Fig. 4b-d)",
        "t_I: duration of F(3) in the first cycle",
    ]
    rows_seen = set(int(x) for x in np.unique(res.row))
    r.check(
        "4-rows",
        "all three rows of eq. (3.1) become active, in turn",
        rows_seen == {1, 2, 3},
        f"rows seen {sorted(rows_seen)}; {len(row3_starts)} break-aways in 25 s",
    )
    r.check(
        "4-break",
        "first break-away where P_ext reaches F_stat (7.5 s)",
        bool(row3_starts) and abs(row3_starts[0] - t_first_exact) <= 2 * dt,
        f"row 3 starts at {row3_starts[0]:.4f} s" if row3_starts else "no break-away",
    )
    r.data = {
        "t": res.t,
        "x": res.x,
        "x_spring": res.x_spring,
        "v": res.v,
        "F": res.F,
        "P": res.P,
        "row": res.row,
        "x_exact": exact.x,
        "durations": durations,
        "period": period,
        "period_exact": period_exact,
    }
    if out is not None:
        keep = _decimate(res.t, res.row, 6000)
        r.files.append(
            _write_csv(
                out / "fig4.csv",
                {
                    "t_s": res.t[keep],
                    "x_body_m": res.x[keep],
                    "x_spring_end_m": res.x_spring[keep],
                    "v_rubbing_m_s": res.v[keep],
                    "F_friction_N": res.F[keep],
                    "P_ext_N": res.P[keep],
                    "row_eq_3_1": res.row[keep],
                    "x_body_exact_m": exact.x[keep],
                },
            )
        )
        fig, ax = _figure(3, 1, (7.5, 8.5))
        a = ax[0, 0]
        a.plot(res.t, res.x, label="body x_p (eq. 3.1, threshold)")
        a.plot(res.t, exact.x, "k:", lw=1, label="body, exact Coulomb")
        a.plot(res.t, res.x_spring, label="spring end B, x_s")
        a.set(ylabel="position [m]", title="(b) trajectories")
        a.legend(fontsize=8)
        a = ax[1, 0]
        a.plot(res.t, res.F, label="friction F")
        a.plot(res.t, res.P, label="external P_ext")
        a.set(ylabel="force [N]", title="(c) forces, rubbing speed and active row")
        a2 = a.twinx()
        a2.plot(res.t, res.v, "g", lw=0.8, label="rubbing speed v_o")
        a2.set_ylabel("v_o [m/s]")
        a.legend(loc="upper left", fontsize=8)
        a2.legend(loc="upper right", fontsize=8)
        a = ax[2, 0]
        w = (res.t > t_first_exact - 0.1) & (res.t < t_first_exact + 0.25)
        a.plot(res.t[w], res.F[w], label="F")
        a.plot(res.t[w], res.P[w], label="P_ext")
        a.set(
            xlabel="t [s]",
            ylabel="force [N]",
            title="(d) detail A: leaving rest, row of eq. (3.1)",
        )
        a3 = a.twinx()
        a3.step(res.t[w], res.row[w], "r", where="post", label="row F(1..3)")
        a3.set(ylabel="row", yticks=[1, 2, 3])
        a.legend(loc="upper left", fontsize=8)
        a3.legend(loc="lower right", fontsize=8)
        _save(fig, out, "fig4.png", r.files)
    r.wall_s = time.perf_counter() - t0
    return r


# ---------------------------------------------------------------------------- Fig. 5
@figure_parameters
def fig5(out: Path | None = None, quick: bool = False, stick: str = "seed") -> FigureResult:
    """Duration of the static stage F(3) of the first three stick-slip cycles against v_min."""
    t0 = time.perf_counter()
    osc = Oscillator()
    v_mins = np.array([1e-5, 1e-4, 1e-3]) if quick else np.logspace(-6, -1, 11)
    # the step must resolve t_I = sqrt(10 v_min) s (3 ms at 1e-6 m/s); 40 s hold three cycles
    dt = 1e-4 if quick else 2e-5
    t_end = 40.0
    table = np.full((len(v_mins), 3), np.nan)
    for i, vm in enumerate(v_mins):
        res = run_oscillator(
            osc, t_end, "threshold", dt=dt, v_min=float(vm), max_points=int(t_end / dt) + 10
        )
        d = static_stage_durations(res, 3)
        table[i, : len(d)] = d
    closed = np.sqrt(2 * osc.m * v_mins / (osc.k * osc.v_drive))
    slopes = [_loglog_slope(v_mins, table[:, j]) for j in range(3)]
    r = FigureResult(
        "5", "duration of the static stage F(3) against the threshold speed v_min", stick=None
    )
    r.headline = {
        "v_min range [m/s]": f"{v_mins[0]:.0e} .. {v_mins[-1]:.0e}",
        "t_I range [s]": f"{np.nanmin(table[:, 0]):.4g} .. {np.nanmax(table[:, 0]):.4g}",
        "t_II range [s]": f"{np.nanmin(table[:, 1]):.4g} .. {np.nanmax(table[:, 1]):.4g}",
        "t_III range [s]": f"{np.nanmin(table[:, 2]):.4g} .. {np.nanmax(table[:, 2]):.4g}",
        "log-log slope d ln t / d ln v_min: t_I, t_II, t_III": ", ".join(
            f"{x:.3f}" for x in slopes
        ),
        "t_I vs sqrt(2 m v_min/(k v_s)), worst rel. dev.": float(
            np.nanmax(np.abs(table[:, 0] / closed - 1)[v_mins <= 1e-2])
        ),
        "integration step dt [s]": dt,
    }
    r.seed = [
        "t_I depends strictly on v_min; t_II and t_III do not show such a dependence",
        "cause: cycle I leaves rest from ẋ_p = 0, later cycles from |ẋ_p| <= v_min",
    ]
    r.check(
        "5-tI",
        "t_I grows with v_min (as sqrt(v_min): slope 0.5)",
        _monotone(table[:, 0], True) and abs(slopes[0] - 0.5) < 0.05,
        f"log-log slope {slopes[0]:.3f}",
    )
    r.check(
        "5-tII",
        "t_II and t_III show no trend with v_min (|slope| < 0.2)",
        abs(slopes[1]) < 0.2 and abs(slopes[2]) < 0.2,
        f"slopes {slopes[1]:.3f}, {slopes[2]:.3f}",
    )
    r.data = {"v_min": v_mins, "durations": table, "t_I_closed": closed}
    if out is not None:
        r.files.append(
            _write_csv(
                out / "fig5.csv",
                {
                    "v_min_m_s": v_mins,
                    "t_I_s": table[:, 0],
                    "t_II_s": table[:, 1],
                    "t_III_s": table[:, 2],
                    "t_I_closed_form_s": closed,
                },
            )
        )
        fig, ax = _figure(1, 1, (6.5, 4.2))
        a = ax[0, 0]
        for j, lab in enumerate(("t_I", "t_II", "t_III")):
            a.loglog(v_mins, table[:, j], "o-", label=lab)
        a.loglog(v_mins, closed, "k:", label="sqrt(2 m v_min / (k ẋ_s))")
        a.set(
            xlabel="v_min [m/s]",
            ylabel="duration of F(3) [s]",
            title=f"Fig. 5: static stage F(3) against v_min (RK4, dt = {dt:g} s)",
        )
        a.legend(fontsize=8)
        _save(fig, out, "fig5.png", r.files)
    r.wall_s = time.perf_counter() - t0
    return r
