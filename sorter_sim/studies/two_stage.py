"""
Two-stage sorting, the seed's conclusion: a preliminary disk field, then the final one.

The seed (section 7) proposes to shorten the manipulator's working space by a
preliminary field at the head of the stream that shifts each parcel towards the
border of its future chute, so the final field has less lateral distance to
cover. Here that is two disk fields in series on one belt, each a band of the
conveyor with its own position, width b and disk angle α (``DiskField`` ->
``disk_field_strips``), run through the same core as every other study.

The study: the preliminary field (α_1 = 90°) is sized by brentq so that the
parcel leaves it shifted by d across the belt and settles back on the belt; the
final field starts a small margin past the settled parcel, and its minimal width
is found as for the seed's Fig. 11 (the parcel reaches the scrap line stuck on
the final disks, ``paper.step_root``). The shrink is that width against the
single-stage minimal width for the same parcel, speed and α.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from sorter_sim.model.core.simulate import FrictionLaw, Parcel, Strip, simulate
from sorter_sim.studies.paper_support import (
    SEED_MU,
    SEED_S,
    FigureResult,
    _figure,
    _save,
    _write_csv,
    disk_surface,
    law_folder,
    minimal_disk_width,
    step_root,
)

GAP_MARGIN = 0.1  # m between the settled parcel's leading corner and the final field (assumption)


@dataclass(frozen=True)
class DiskField:
    """
    One field of driven disks across the belt.

    A field of driven disks across the belt: x from ``start`` to start + ``width`` [m],
    disk surface velocity v(cos α, sin α) with α = ``alpha_deg``; width may be inf.
    """

    start: float
    width: float
    alpha_deg: float
    name: str = ""

    def __post_init__(self):
        if not math.isfinite(self.start):
            raise ValueError(f"disk field start must be finite, got {self.start}")
        if not (self.width > 0):
            raise ValueError(f"disk field width must be > 0 m (or inf), got {self.width}")
        if not (-90.0 <= self.alpha_deg <= 90.0):
            raise ValueError(f"disk field alpha_deg must be in [-90, 90], got {self.alpha_deg}")

    @property
    def end(self) -> float:
        return self.start + self.width


def disk_field_strips(
    v: float, fields: list[DiskField], law_belt: FrictionLaw, law_disks: FrictionLaw | None = None
) -> list[Strip]:
    """
    Belt at (v, 0) everywhere, with disk fields in series (sorted, not overlapping).

    Parameters
    ----------
    v : float
        The belt speed [m/s].
    fields : list of DiskField
        The disk fields, upstream first.
    law_belt : FrictionLaw
        The belt's law.
    law_disks : FrictionLaw
        The disks' law.

    Returns
    -------
    list of Strip
        The strips.

    """
    law_disks = law_disks or law_belt
    fields = sorted(fields, key=lambda f: f.start)
    for f, g in zip(fields, fields[1:]):
        if g.start < f.end:
            raise ValueError(
                f"disk fields overlap: {f.name or f.start} ends at {f.end} m, "
                f"{g.name or g.start} starts at {g.start} m"
            )
    strips = []
    x = -math.inf
    for k, f in enumerate(fields):
        if f.start > x:
            strips.append(Strip(x, f.start, v, 0.0, law_belt, name="belt" if k else "a"))
        a = math.radians(f.alpha_deg)
        strips.append(
            Strip(
                f.start,
                f.end,
                v * math.cos(a),
                v * math.sin(a),
                law_disks,
                name=f.name or f"field{k + 1}",
            )
        )
        x = f.end
    if math.isfinite(x):
        strips.append(Strip(x, math.inf, v, 0.0, law_belt, name="c"))
    return strips


def _run(strips, A, B, m, v, t_end, y_target, stick, rotation=True):
    parcel = Parcel(A, B, m)
    y0 = [-0.5 * A, 0.0, 0.0, v, 0.0, 0.0]  # leading edge on x = 0, moving with the belt
    return simulate(
        parcel, strips, y0, (0.0, t_end), "accurate", y_target=y_target, stick=stick,
        rotation=rotation,
    )  # fmt: skip


@dataclass
class PreShift:
    """
    Run the preliminary stage alone.

    The preliminary stage alone: lateral shift d [m], angle φ [deg] and the x [m] of the
    settled parcel's leading corner; ``settled`` false when the field kept it.
    """

    b1: float
    d: float
    phi_deg: float
    x_front: float
    settled: bool


@dataclass(frozen=True)
class StageSetup:
    """
    What the two fields of a study share: the parcel, the belt, the first field's angle.

    Attributes
    ----------
    A : float
        The parcel's length [m].
    B : float
        Its width [m].
    m : float
        Its mass [kg].
    v : float
        The belt speed [m/s].
    alpha1_deg : float
        The first field's disk angle [deg].
    mu : float
        The friction coefficient.
    s : float
        The scrap distance across the belt [m].
    stick : str
        The stick law (seed or exact).
    rotation : bool
        The moment of friction forces on.

    """

    A: float = 0.7
    B: float = 0.2
    m: float = 5.0
    v: float = 1.5
    alpha1_deg: float = 90.0
    mu: float = SEED_MU
    s: float = SEED_S
    stick: str = "seed"
    rotation: bool = True


def pre_shift(b1: float, **setup) -> PreShift:
    """
    Run the parcel over a preliminary field of width b1 until it rides the belt again.

    Parameters
    ----------
    b1 : float
        The first field's length [m].
    **setup
        ``StageSetup``'s fields: the parcel, the belt, the field's angle, μ.

    Returns
    -------
    PreShift
        The shift.

    """
    st = StageSetup(**setup)
    A, B, v, s = st.A, st.B, st.v, st.s
    law = FrictionLaw("const1", (st.mu,))
    strips = disk_field_strips(v, [DiskField(0.0, b1, st.alpha1_deg, "pre")], law)
    res = _run(strips, A, B, st.m, v, 4.0 + 8.0 * s / v, s, st.stick, st.rotation)
    x, y, phi, vx, vy, om = res.y[-1]
    settled = res.t_target is None and int(res.mode[-1]) == 0 and x - 0.5 * A > b1
    # the leading corner when it settled: the belt stick after the field was left
    t_settle = max((t for t, k, i in res.events if k == "stick" and i == 0), default=res.t[-1])
    k = int(np.searchsorted(res.t, t_settle))
    k = min(k, len(res.t) - 1)
    c, sn = abs(math.cos(res.y[k, 2])), abs(math.sin(res.y[k, 2]))
    x_front = res.y[k, 0] + 0.5 * (A * c + B * sn)
    return PreShift(b1, float(y), math.degrees(phi), float(x_front), bool(settled))


def size_pre_field(d_target: float, *, b1_hi=None, xtol=1e-4, **kw) -> PreShift:
    """
    Width b1 of the preliminary field that shifts the parcel by d_target (brentq on d(b1)).

    Parameters
    ----------
    d_target : float
        The lateral shift wanted [m].
    b1_hi : float
        The longest first field tried [m].
    xtol : float
        The bracket's tolerance [m].

    Returns
    -------
    PreShift
        The sized field.

    """
    if d_target <= 0.0:
        return PreShift(0.0, 0.0, 0.0, 0.5 * kw.get("A", 0.7), True)
    if b1_hi is None:
        # the field must let the parcel go: stay below the width at which the disks keep it
        b1_hi = 0.5 * kw.get("A", 0.7)
        while pre_shift(b1_hi, **kw).settled and b1_hi < 5.0:
            b1_hi *= 1.5
    f = lambda b1: pre_shift(b1, **kw).d - d_target  # noqa: E731
    lo = 1e-3
    hi = b1_hi
    # shrink the upper end onto widths that still release the parcel
    while not pre_shift(hi, **kw).settled and hi > lo:
        hi *= 0.9
    if f(hi) < 0:
        raise ValueError(
            f"a preliminary field cannot shift this parcel by {d_target:.3f} m and "
            f"release it (at most {pre_shift(hi, **kw).d:.3f} m)"
        )
    b1 = brentq(f, lo, hi, xtol=xtol)
    return pre_shift(b1, **kw)


def final_min_width(pre: PreShift, *, alpha2_deg=30.0, xtol=1e-3, **setup):
    """
    Minimal width of the final field behind a preliminary one (the Fig. 11 criterion).

    Parameters
    ----------
    pre : PreShift
        The first field's result.
    alpha2_deg : float
        The final field's disk angle [deg].
    xtol : float
        The bracket's tolerance [m].
    **setup
        ``StageSetup``'s fields: the parcel, the belt, the first field's angle, μ.

    Returns
    -------
    (float, MinimalWidth)
        Where the final field starts [m], and its least width.

    """
    st = StageSetup(**setup)
    A, B, v, s = st.A, st.B, st.v, st.s
    law = FrictionLaw("const1", (st.mu,))
    x2 = pre.x_front + GAP_MARGIN

    def scrapes(b2):
        fields = [DiskField(x2, b2, alpha2_deg, "final")]
        if pre.b1 > 0.0:
            fields.insert(0, DiskField(0.0, pre.b1, st.alpha1_deg, "pre"))
        strips = disk_field_strips(v, fields, law)
        res = _run(strips, A, B, st.m, v, 6.0 + 8.0 * s / v, s, st.stick, st.rotation)
        disk = disk_surface(res, v, math.radians(alpha2_deg))
        return res.t_target is not None and disk is not None and int(res.mode[-1]) == disk

    return x2, step_root(scrapes, 0.005, 2.0, xtol)


def two_stage_figure(
    out: Path | None = None, quick: bool = False, stick: str = "seed"
) -> FigureResult:
    """
    Compute how much a preliminary field (α_1 = 90°) shortens the final one (Fig. 9a parcel).

    Parameters
    ----------
    out : Path, optional
        Where the CSV and PNG go.
    quick : bool
        Coarse grids, for tests and quick looks.
    stick : str
        The stick law: "seed" or "exact".

    Returns
    -------
    FigureResult
        The figure.

    """
    t0 = time.perf_counter()
    out = law_folder(out, stick)
    kw = dict(A=0.7, B=0.2, v=1.5, stick=stick)
    alphas = (30.0,) if quick else (90.0, 45.0, 30.0)
    fracs = (0.0, 0.4) if quick else (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
    xtol = 5e-3 if quick else 1e-3
    rows = []
    pres = {fr: size_pre_field(fr * SEED_S, **kw) for fr in fracs}
    for al in alphas:
        single = minimal_disk_width(alpha_deg=al, xtol=xtol, **kw).b_min
        for fr in fracs:
            pre = pres[fr]
            x2, mw = final_min_width(pre, alpha2_deg=al, xtol=xtol, **kw)
            rows.append(
                {
                    "alpha2_deg": al,
                    "d_over_s": fr,
                    "d_m": pre.d,
                    "b1_m": pre.b1,
                    "phi_after_pre_deg": pre.phi_deg,
                    "x_final_start_m": x2,
                    "b2_min_m": mw.b_min,
                    "b_single_m": single,
                    "final_shrink_pct": 100 * (1 - mw.b_min / single),
                }
            )
    r = FigureResult(
        "two-stage",
        "preliminary field (α_1 = 90°) + final field: minimal final width "
        "(0.7 x 0.2 m, v = 1.5 m/s, μ = 0.6)",
        stick=stick,
    )
    r.headline[f"pre-shift d = {fracs[-1]:g} s: d [m] ; b_1 [m]"] = (
        f"{pres[fracs[-1]].d:.3f} ; {pres[fracs[-1]].b1:.3f}"
    )
    for row in rows:
        if row["d_over_s"] == fracs[-1] or row["d_over_s"] == 0.0:
            r.headline[
                f"α_2 = {row['alpha2_deg']:.0f}°, d = {row['d_over_s']:g} s: b_2 min [m]"
            ] = row["b2_min_m"]
    for al in alphas:
        last = [x for x in rows if x["alpha2_deg"] == al][-1]
        r.headline[f"α_2 = {al:.0f}°: final field shorter by [%] (d = {fracs[-1]:g} s)"] = last[
            "final_shrink_pct"
        ]
    r.seed = [
        "preliminary sorting shifts the load towards one border and so decreases the "
        "length of the final manipulator's working space (section 7)"
    ]
    by = {(x["alpha2_deg"], x["d_over_s"]): x for x in rows}
    r.check(
        "C4-same",
        "without a pre-shift the final field equals the single field (±2 xtol)",
        all(
            abs(by[al, 0.0]["b2_min_m"] - by[al, 0.0]["b_single_m"]) <= 2 * xtol + 1e-12
            for al in alphas
        ),
        ", ".join(
            f"{al:.0f}°: {by[al, 0.0]['b2_min_m']:.3f} / {by[al, 0.0]['b_single_m']:.3f} m"
            for al in alphas
        ),
    )
    r.check(
        "C4",
        "a preliminary field shortens the final one at α_2 = 30°",
        by[30.0, fracs[-1]]["b2_min_m"] < by[30.0, 0.0]["b2_min_m"],
        f"{by[30.0, 0.0]['b2_min_m']:.3f} -> {by[30.0, fracs[-1]]['b2_min_m']:.3f} m behind a "
        f"{by[30.0, fracs[-1]]['d_m']:.2f} m pre-shift",
    )
    r.data = {"rows": rows, "pre": pres}
    if out is not None:
        r.files.append(
            _write_csv(out / "two_stage.csv", {k: [x[k] for x in rows] for k in rows[0]})
        )
        fig, ax = _figure(1, 2, (12, 4.5))
        a = ax[0, 0]
        for al in alphas:
            sel = [x for x in rows if x["alpha2_deg"] == al]
            a.plot(
                [x["d_m"] for x in sel],
                [x["b2_min_m"] for x in sel],
                "o-",
                label=f"α_2 = {al:.0f}°",
            )
        a.set(
            xlabel="pre-shift d across the belt [m]",
            ylabel="minimal final field width b_2 [m]",
            title="final field behind a preliminary one",
            ylim=(0, None),
        )
        a.legend(fontsize=8)
        a = ax[0, 1]
        fr = fracs[-1]
        pre = pres[fr]
        al = alphas[-1]
        x2 = by[al, fr]["x_final_start_m"]
        b2 = by[al, fr]["b2_min_m"]
        law = FrictionLaw("const1", (SEED_MU,))
        fields = [DiskField(x2, b2, al, "final")] + (
            [DiskField(0.0, pre.b1, 90.0, "pre")] if pre.b1 > 0 else []
        )
        res = _run(disk_field_strips(1.5, fields, law), 0.7, 0.2, 5.0, 1.5, 10.0, SEED_S, stick)
        a.plot(res.y[:, 0], res.y[:, 1], label=f"two-stage, α_2 = {al:.0f}°")
        for f, col in ((DiskField(0.0, pre.b1, 90.0), "C1"), (DiskField(x2, b2, al), "C2")):
            a.axvspan(f.start, f.end, color=col, alpha=0.15)
        a.axhline(SEED_S, color="k", ls=":", lw=0.8)
        a.set(
            xlabel="x [m]",
            ylabel="y [m]",
            title=f"CoG path: pre field b_1 = {pre.b1:.3f} m, final b_2 = {b2:.3f} m",
        )
        a.legend(fontsize=8)
        _save(fig, out, "two_stage.png", r.files)
    r.wall_s = time.perf_counter() - t0
    return r
