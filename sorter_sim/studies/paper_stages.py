"""
Figs. 10-11 of the seed (section 5): the stages of a sort and the minimal disk-field width.

The stages E1-E3 of a sort and the rubbing-speed components (Fig. 10), and the
narrowest field that still scrapes, found by brentq per point (Fig. 11).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from sorter_sim.runtime.scene import run_scene, scene_parcel, scene_strips
from sorter_sim.studies.paper_support import (
    figure_parameters,
    ALPHAS,
    FigureResult,
    _alpha_v_A_table,
    _figure,
    _save,
    _write_csv,
    densify,
    law_folder,
    minimal_disk_width,
    sorting_scene,
    zone_rubbing,
)


ACC_WINDOW = 0.05  # s, the start of E2 over which the lateral acceleration is taken


@figure_parameters
def fig10(out: Path | None = None, quick: bool = False, stick: str = "seed") -> FigureResult:
    """Components of the rubbing speed in zones a and b over time, stages E1-E3 marked."""
    t0 = time.perf_counter()
    out = law_folder(out, stick)
    runs = {}
    for al in ALPHAS:
        scene = sorting_scene(A=0.7, B=0.2, v=1.5, alpha_deg=al, stick=stick)
        res, summ = run_scene(scene)
        res = densify(res)
        rub = zone_rubbing(res, scene_strips(scene), scene_parcel(scene))
        runs[al] = (res, summ, rub)
    e2 = {al: runs[al][1]["stages"]["E3"] - runs[al][1]["stages"]["E2"] for al in ALPHAS}
    # |η_b| / |ξ_b| while the disks rub, per stage: E1 (parcel held by the belt) and E2
    ratio = {}
    for al, (res, summ, rub) in runs.items():
        xi_b, eta_b = rub["b"]
        st = summ["stages"]
        ok = np.isfinite(xi_b) & (np.abs(xi_b) > 1e-6)
        for name, lo, hi in (("E1", st["E1"], st["E2"]), ("E2", st["E2"], st["E3"])):
            m = ok & (res.t >= lo) & (res.t < hi)
            ratio[al, name] = float(np.median(np.abs(eta_b[m]) / np.abs(xi_b[m])))
    # the lateral acceleration towards the chute (the seed's section 5 and its second
    # conclusion): mean ÿ over the first ACC_WINDOW of E2, and over the whole of E2
    acc_early, acc_e2, share = {}, {}, {}
    for al, (res, summ, _) in runs.items():
        st = summ["stages"]
        vy = lambda t: float(np.interp(t, res.t, res.y[:, 4]))  # noqa: E731
        acc_early[al] = (vy(st["E2"] + ACC_WINDOW) - vy(st["E2"])) / ACC_WINDOW
        acc_e2[al] = (vy(st["E3"]) - vy(st["E2"])) / e2[al]
        share[al] = e2[al] / summ["t_scrap"]
    r = FigureResult(
        "10", "rubbing-speed components in zones a and b (0.7 x 0.2 m, v = 1.5 m/s)", stick=stick
    )
    for al in ALPHAS:
        st = runs[al][1]["stages"]
        r.headline[f"α = {al:.0f}°: E2 starts ; E3 starts ; E2 lasts [s]"] = (
            f"{st['E2']:.3f} ; {st['E3']:.3f} ; {e2[al]:.3f}"
        )
    for al in ALPHAS:
        r.headline[f"α = {al:.0f}°: median |η_b|/|ξ_b| in E1 ; in E2"] = (
            f"{ratio[al, 'E1']:.3f} ; {ratio[al, 'E2']:.3f}"
        )
    ms = f"{1e3 * ACC_WINDOW:.0f} ms"
    for al in ALPHAS:
        r.headline[f"α = {al:.0f}°: mean ÿ, first {ms} of E2 ; all of E2 [m/s²]"] = (
            f"{acc_early[al]:.3f} ; {acc_e2[al]:.3f}"
        )
    r.seed = [
        "a substantial part of the time of translocation onto the chute is E2",
        "α = 45°, 30°: the load stays in transient motion E2 much shorter than at α = 90°",
        "α = 45°, 30°: η_b is much greater than ξ_b; α = 90°: ξ_b = η_b",
        "hence a greater acceleration towards the chute at α = 45°, 30°",
    ]
    each = lambda d, f: ", ".join(f(d[al]) for al in ALPHAS)  # noqa: E731
    r.check(
        "10-share",
        "E2 takes at least a fifth of t_c (every α)",
        min(share.values()) >= 1 / 5,
        f"E2 / t_c = {each(share, lambda x: f'{100 * x:.0f} %')} at 90°, 45°, 30°",
    )
    r.check(
        "10-E2",
        "E2 shorter at 45° and 30° than at 90°",
        e2[45.0] < e2[90.0] and e2[30.0] < e2[90.0],
        f"E2 = {each(e2, lambda x: f'{x:.3f}')} s at 90°, 45°, 30°",
    )
    r.check(
        "10-eta90",
        "ξ_b = η_b at α = 90° (E1 exactly, E2 within 10 % in the median)",
        abs(ratio[90.0, "E1"] - 1) < 1e-9 and abs(ratio[90.0, "E2"] - 1) < 0.10,
        f"median |η_b|/|ξ_b| {ratio[90.0, 'E1']:.3f} in E1, {ratio[90.0, 'E2']:.3f} in E2",
    )
    r.check(
        "10-eta",
        "η_b much greater than ξ_b at α = 45° and 30° (median ratio > 1.5, E1 and E2)",
        min(ratio[a, e] for a in (45.0, 30.0) for e in ("E1", "E2")) > 1.5,
        f"45°: {ratio[45.0, 'E1']:.2f} / {ratio[45.0, 'E2']:.2f}, 30°: "
        f"{ratio[30.0, 'E1']:.2f} / {ratio[30.0, 'E2']:.2f} (E1 / E2)",
    )
    r.check(
        "10-acc",
        f"the acceleration towards the chute is greater at lower α (first {ms} of E2)",
        acc_early[90.0] < acc_early[45.0] < acc_early[30.0],
        f"ÿ = {each(acc_early, lambda x: f'{x:.2f}')} m/s² at 90°, 45°, 30° (over all of "
        f"E2: {each(acc_e2, lambda x: f'{x:.2f}')})",
    )
    r.check(
        "C2c",
        "a larger α: less acceleration towards the chute, a longer transient E2",
        acc_early[90.0] < acc_early[45.0] < acc_early[30.0] and e2[90.0] > e2[45.0] > e2[30.0],
        f"early ÿ {each(acc_early, lambda x: f'{x:.2f}')} m/s², E2 "
        f"{each(e2, lambda x: f'{x:.3f}')} s at 90°, 45°, 30°",
    )
    r.data = {
        "runs": runs,
        "E2_duration": e2,
        "eta_over_xi_b": ratio,
        "acc_early": acc_early,
        "acc_E2": acc_e2,
        "E2_share": share,
    }
    if out is not None:
        cols = {
            "alpha_deg": [],
            "t_s": [],
            "xi_a": [],
            "eta_a": [],
            "xi_b": [],
            "eta_b": [],
            "stage": [],
        }
        for al, (res, summ, rub) in runs.items():
            st = summ["stages"]
            stage = np.where(res.t >= st["E3"], "E3", np.where(res.t >= st["E2"], "E2", "E1"))
            cols["alpha_deg"] += [al] * len(res.t)
            cols["t_s"] += list(res.t)
            for z in ("a", "b"):
                cols[f"xi_{z}"] += list(rub[z][0])
                cols[f"eta_{z}"] += list(rub[z][1])
            cols["stage"] += list(stage)
        r.files.append(_write_csv(out / "fig10.csv", cols))
        fig, ax = _figure(1, 3, (14, 4.3))
        for k, al in enumerate(ALPHAS):
            res, summ, rub = runs[al]
            a = ax[0, k]
            for z, ls in (("a", "--"), ("b", "-")):
                a.plot(res.t, rub[z][0], ls, label=f"ξ_{z}")
                a.plot(res.t, rub[z][1], ls, label=f"η_{z}")
            st = summ["stages"]
            for name in ("E2", "E3"):
                a.axvline(st[name], color="k", lw=0.7, ls=":")
            ymax = a.get_ylim()[1]
            for name, ta, tb in (
                ("E1", st["E1"], st["E2"]),
                ("E2", st["E2"], st["E3"]),
                ("E3", st["E3"], res.t[-1]),
            ):
                a.text(0.5 * (ta + tb), 0.92 * ymax, name, ha="center", fontsize=9)
            a.set(
                xlabel="t [s]",
                ylabel="rubbing speed [m/s]",
                title=f"Fig. 10{'abc'[k]}: α = {al:.0f}°",
            )
            a.legend(fontsize=7, loc="lower right")
        _save(fig, out, "fig10.png", r.files)
    r.wall_s = time.perf_counter() - t0
    return r


@figure_parameters
def fig11(out: Path | None = None, quick: bool = False, stick: str = "seed") -> FigureResult:
    """Minimal disk-field width b against v and A for α = 90°, 45°, 30° (brentq per point)."""
    t0 = time.perf_counter()
    out = law_folder(out, stick)
    As = [0.4] if quick else [0.2, 0.4, 0.6, 0.8, 1.0, 1.2]
    vs = [1.5] if quick else [0.5, 1.0, 1.5]
    xtol = 5e-3 if quick else 1e-3
    bmin = np.full((3, len(vs), len(As)), np.nan)
    evals = 0
    for k, al in enumerate(ALPHAS):
        for i, v in enumerate(vs):
            for j, A in enumerate(As):
                mw = minimal_disk_width(A=A, v=v, alpha_deg=al, xtol=xtol, stick=stick)
                bmin[k, i, j] = mw.b_min
                evals += mw.n_evals
    r = FigureResult(
        "11",
        "minimal disk-field width b that still scrapes (μ_a = μ_b = μ_c = 0.6, φ = 0, B = 0.2 m)",
        stick=stick,
    )
    for k, al in enumerate(ALPHAS):
        r.headline[f"b_min range at α = {al:.0f}° [m]"] = (
            f"{np.nanmin(bmin[k]):.3f} .. {np.nanmax(bmin[k]):.3f}"
        )
    iv, jA = len(vs) - 1, min(1, len(As) - 1)
    for k, al in enumerate(ALPHAS):
        r.headline[f"b_min at v = {vs[iv]}, A = {As[jA]}, α = {al:.0f}° [m]"] = float(
            bmin[k, iv, jA]
        )
    # the seed took its width estimates from the model with the moment neglected
    for k, al in enumerate(ALPHAS):
        simple = minimal_disk_width(
            A=As[jA], v=vs[iv], alpha_deg=al, xtol=xtol, stick=stick, rotation=False
        )
        r.headline[f"  same, moment neglected (the seed's model), α = {al:.0f}° [m]"] = (
            simple.b_min
        )
        evals += simple.n_evals
    r.headline["criterion evaluations (runs) in total"] = evals
    r.headline["root finder"] = f"scipy brentq, xtol {xtol:g} m"
    gap = (bmin[2] - bmin[0]) / bmin[0]
    r.seed = [
        "α = 90° needs a narrower field than α = 45° and 30°",
        "the disadvantage of 45° and 30° is largest at low v and short A",
    ]
    r.check(
        "11-a",
        "b_min falls as α rises (every v, A)",
        bool(np.all(bmin[0] < bmin[1]) and np.all(bmin[1] < bmin[2])),
        f"v = {vs[iv]}, A = {As[jA]}: "
        + ", ".join(f"{bmin[k, iv, jA]:.3f}" for k in range(3))
        + " m at 90°, 45°, 30°",
    )
    if not quick:
        i, j = np.unravel_index(np.nanargmax(gap), gap.shape)
        r.check(
            "11-lowv",
            "the 30°-vs-90° excess is largest at the lowest v and the shortest A",
            bool(np.nanargmax(gap) == 0),
            f"largest at v = {vs[i]} m/s, A = {As[j]} m (+{100 * gap[i, j]:.0f} %)",
        )
    r.data = {"A": As, "v": vs, "alpha": ALPHAS, "b_min": bmin, "excess_30_over_90": gap}
    if out is not None:
        fig, _ = _alpha_v_A_table(out, "11", vs, As, bmin, "b_min_m", "minimal b [m]", r.files)
        _save(fig, out, "fig11.png", r.files)
    r.wall_s = time.perf_counter() - t0
    return r
