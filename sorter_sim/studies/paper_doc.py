"""
``docs/paper.md``, written from one run of every figure under both stick laws.

``sorter paper all --doc DIR`` runs each figure of ``paper_cli.FIGURES`` under the
seed's stick law and the exact one (once where a figure has no stick between
surfaces: Figs. 3-5), prints their reports, and writes DIR/paper.md with the
pictures in DIR/img. Every number on the page is one the command printed: the
statement table takes the figures' checks (``FigureResult.checks``) by the keys
``paper_statements.STATEMENTS`` lists, the tables take their headlines, and the
prose between them takes its numbers from the same results. What the page says
in words without a number (the set-up of each figure, the meaning of a measure)
does not depend on the run.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

from sorter_sim.studies.claims_cli import BLOCK as CLAIMS_BLOCK
from sorter_sim.studies.claims_cli import saved_block
from sorter_sim.studies.markdown import CONTENTS_END, CONTENTS_START, with_contents
from sorter_sim.studies.paper_statements import STATEMENTS
from sorter_sim.studies.paper_support import STICK_LAWS, FigureResult, _fmt
from sorter_sim.studies.workprecision import machine_info

# each figure's heading and its set-up in words (inputs, not results)
SECTIONS = {
    "3": (
        "Fig. 3: the friction laws as used",
        "`sorter paper 3` — μ against the rubbing speed for each law a scene can name "
        "(`friction.model`), with the parameters it takes when the scene gives none. A "
        "zone's μ scales a law to that value at 1 m/s (the law keeps its shape). Solid: "
        "values from the seed; dashed: assumed, with the source in the legend.",
    ),
    "4": (
        "Fig. 4: stick-slip body and eq. (3.1)",
        "`sorter paper 4` — m = 1 kg, F_kin = 1 N, F_stat = 1.5 N, k = 2 N/m, ẋ_s = 0.1 m/s, "
        "v_min = 0.001 m/s, the threshold model of eq. (3.1) with RK4, beside the exact "
        "Coulomb solution. One body on one surface: the cell's two stick laws do not apply.",
    ),
    "5": (
        "Fig. 5: static stage F(3) against v_min",
        "`sorter paper 5` — v_min from 10⁻⁶ to 10⁻¹ m/s, RK4, three stick-slip cycles. Cycle "
        "I leaves rest from ẋ_p = 0; later cycles stick with a residual |ẋ_p| ≤ v_min whose "
        "value depends on where the step fell, so t_II and t_III scatter (and depend on dt) "
        "instead of following v_min.",
    ),
    "7": (
        "Fig. 7: moment of friction forces",
        "`sorter paper 7` — 0.4 x 0.2 m, v = 1 m/s, α = 90°, b = ∞, with the moment of "
        "friction forces (line 1) and without it (line 2).",
    ),
    "8": (
        "Fig. 8: distance x_o",
        "`sorter paper 8` — grids A 0.2…1.2 m, B 0.2…0.8 m, v 0.5…1.5 m/s, α 30…90°, "
        "μ_a, μ_b 0.3…0.9; elsewhere 0.7 x 0.2 m, v = 1.5 m/s, α = 90°, μ = 0.6. Panel (d) "
        "keeps each run's capacity as well, for the seed's third conclusion.",
    ),
    "9": (
        "Fig. 9: capacity W_t",
        "`sorter paper 9` — v 0.5…1.5 m/s, A 0.2…1.2 m, α = 90°, 45°, 30°. W_t = 3600/t_c "
        "with t_c from the leading edge on the belt/disk border (t = 0) to the centre of "
        "gravity crossing s = 0.7 m; the seed does not write the formula nor say when t_c "
        "starts.",
    ),
    "10": (
        "Fig. 10: rubbing-speed components and stages",
        "`sorter paper 10` — 0.7 x 0.2 m, v = 1.5 m/s. ξ_i = v_surface,x − v_q,x and "
        "η_i = v_q,y − v_surface,y at the centroid q of the footprint part over zone i (the "
        "seed's eq. 4.7 signs). E1 held by the belt, E2 from the break-away off the belt "
        "(the break event), E3 from the stick on the disks. In E1 the parcel moves at "
        "(v, 0), so |η_b|/|ξ_b| is exactly cot(α/2) there. The lateral acceleration is the "
        "mean ÿ over the first 50 ms of E2, and over all of E2.",
    ),
    "11": (
        "Fig. 11: minimal disk-field width b",
        "`sorter paper 11` — finite b with zone c present (μ_a = μ_b = μ_c = 0.6), v "
        "0.5…1.5 m/s, A 0.2…1.2 m. Criterion (the seed's “rubbing against the disks "
        "disappears”, v_ob = 0): the parcel reaches the scrap line while stuck on the "
        "disks. It is a yes/no step in b; scipy's `brentq` finds the step to 1 mm from a "
        "sign-changing bracket, no grid scan.",
    ),
    "13": (
        "Fig. 13: positioning between two opposite belts",
        "`sorter paper 13` — belt x < 0 at +0.37 m/s, belt x > 0 at −0.37 m/s, 0.4 x 0.3 m, "
        "5 kg, released at rest 0.05 m off the border (the seed gives no offset: an "
        "assumption), 12 s. Model 1 is the b-spline law with the assumed points of Fig. 3f. "
        "With a constant μ both belts slide all the time and the parcel is a harmonic "
        "oscillator with ω² = 2 μ g / A (checked in `test/test_paper.py`).",
    ),
    "14": (
        "Figs. 14-16: friction models in sorting",
        "`sorter paper 14` — α = 45°, v = 1.5 m/s, m = 5 kg, 0.4 x 0.26 m, s = 0.7 m, b = ∞; "
        "every zone takes the law as given. Model 3 is taken as μ = μ_G = 0.46 (the seed "
        "gives only μ_0 and μ_G). L is the distance x_o (the length Fig. 8 sizes the field "
        "by). Forces: kinetic ones from the wrench kernels; the surface the parcel is stuck "
        "to carries minus the sum of the others. The rise of F_b is the largest rise of "
        "|F_b| within the last quarter of E2 (a value over the least one before it).",
    ),
    "two-stage": (
        "Beyond the seed: two-stage sorting",
        "`sorter paper two-stage` — the seed's fourth conclusion: a preliminary field "
        "upstream shifts the parcel towards the chute's border, the final field then has "
        "less to do. Two disk fields in series (`two_stage.DiskField`, each with its own "
        "position, width and α). The preliminary field (α_1 = 90°) is sized by `brentq` so "
        "the parcel leaves it shifted by d and settles back on the belt; the final field "
        "starts 0.1 m past the settled parcel and its minimal width is found with the "
        "Fig. 11 criterion. 0.7 x 0.2 m, v = 1.5 m/s, μ = 0.6.",
    ),
}


def run_figures(figures: dict, out: Path, quick: bool, log=print) -> dict:
    """
    Run every figure under both stick laws (once where it has no stick law).

    Parameters
    ----------
    figures : dict
        {name: figure function} in page order (``paper_cli.FIGURES``).
    out : Path
        Where the figures write their CSV and PNG files.
    quick : bool
        Coarse grids.
    log : callable
        Each report goes here as it is done.

    Returns
    -------
    dict
        {(name, law): FigureResult}; law None for a figure without a stick law.

    """
    results = {}
    for name, fn in figures.items():
        for law in STICK_LAWS:
            res = fn(out, quick=quick, stick=law)
            log(res.report())
            if res.stick is None:
                results[name, None] = res
                break
            results[name, law] = res
    return results


def _laws(results: dict, name: str) -> list:
    return [law for (n, law) in results if n == name]


def _pngs(res: FigureResult) -> list:
    return [Path(f) for f in res.files if str(f).endswith(".png")]


def _image_name(png: Path, law) -> str:
    return png.name if law in (None, "seed") else f"{png.stem}_{law}.png"


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _verdict(checks: list) -> str:
    """Return one statement's verdict from its checks under each law [(law, holds, timed)]."""
    held = {law: holds for law, holds, _ in checks}
    timed = any(t for _, _, t in checks)
    if all(held.values()):
        word = "holds"
    elif not any(held.values()):
        word = "**does not hold**"
    else:
        word = "holds under the " + " and ".join(k for k, v in held.items() if v) + " law only"
    return word + (" (a run time)" if timed else "")


def statement_table(results: dict) -> str:
    """
    Return the table of the seed's statements: words, what each law gives, verdict, test.

    Parameters
    ----------
    results : dict
        {(name, law): FigureResult} from ``run_figures``.

    Returns
    -------
    str
        A Markdown table, one row per ``STATEMENTS`` entry.

    """
    by_key = {}
    for (_, law), res in results.items():
        for key, c in res.checks.items():
            by_key.setdefault(key, {})[law] = c
    rows = [
        "| # | where | the seed's words | seed stick | exact stick | verdict | test |",
        "|---|---|---|---|---|---|---|",
    ]
    for k, st in enumerate(STATEMENTS, 1):
        per_law = {}
        verdicts = []
        for key in st.checks:
            got = by_key.get(key, {})
            for law, c in got.items():
                verdicts.append((law or "either", c.holds, c.timed))
                mark = "" if c.holds else " (fails)"
                per_law.setdefault(law, []).append(c.measured + mark)
        if not verdicts:
            seed = exact = "not measured on this run"
            verdict = "not decided"
        else:
            both = per_law.get(None)
            seed = "; ".join(both or per_law.get("seed", ["—"]))
            exact = "the same (no stick law)" if both else "; ".join(per_law.get("exact", ["—"]))
            verdict = _verdict(verdicts)
        if st.note:
            verdict += f"; {st.note}"
        test = f"`{st.test}`" if st.test else "—"
        rows.append(
            f"| {k} | {st.where} | {_cell(st.words)} | {_cell(seed)} | {_cell(exact)} | "
            f"{_cell(verdict)} | {test} |"
        )
    return "\n".join(rows)


def _headline_table(results: dict, name: str) -> str:
    laws = _laws(results, name)
    cols = ["this run"] if laws == [None] else [f"{law} stick" for law in laws]
    keys = []
    for law in laws:
        keys += [k for k in results[name, law].headline if k not in keys]
    lines = ["| | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for key in keys:
        vals = [_fmt(results[name, law].headline.get(key, "—")) for law in laws]
        lines.append(f"| {_cell(key.strip())} | " + " | ".join(_cell(v) for v in vals) + " |")
    return "\n".join(lines)


def _checks_list(results: dict, name: str) -> str:
    laws = _laws(results, name)
    lines = []
    keys = []
    for law in laws:
        keys += [k for k in results[name, law].checks if k not in keys]
    for key in keys:
        parts = []
        label = ""
        for law in laws:
            c = results[name, law].checks.get(key)
            if c is None:
                continue
            label = c.label
            verdict = "holds" if c.holds else "FAILS"
            who = "" if law is None else f"{law}: "
            parts.append(f"{who}{verdict}, {c.measured}")
        lines.append(f"- {label} — " + "; ".join(parts))
    return "\n".join(lines)


def _images(results: dict, name: str) -> str:
    laws = _laws(results, name)
    title = SECTIONS[name][0].split(":")[0]
    if laws == [None]:
        return "\n".join(
            f"![{title}](img/{_image_name(p, None)})" for p in _pngs(results[name, None])
        )
    head = "| " + " | ".join(f"{law} stick" for law in laws) + " |"
    rule = "|" + "---|" * len(laws)
    cells = [
        " ".join(f"![{title}, {law} stick](img/{_image_name(p, law)})" for p in _pngs(res))
        for law in laws
        for res in [results[name, law]]
    ]
    return "\n".join([head, rule, "| " + " | ".join(cells) + " |"])


def _notes(results: dict, name: str) -> str:
    """Return the prose after a figure's tables, its numbers taken from the results."""
    get = results.get
    if name == "4":
        r = get(("4", None))
        p, pe = r.data["period"], r.data["period_exact"]
        return (
            "The threshold model holds the body at rest until |v| > v_min, so it breaks away "
            f"about t_I late each cycle: its period is {100 * (p / pe - 1):.1f} % longer than "
            "the exact one, and its trajectory drifts from the exact one (panel b, dotted)."
        )
    if name == "9":
        s, e = get(("9", "seed")), get(("9", "exact"))
        s10, e10 = get(("10", "seed")), get(("10", "exact"))
        text = (
            f"Timed from the centre of gravity on the border instead, the reference reads "
            f"{s.data['ref_from_cog']:.0f} pcs/h (seed stick) and {e.data['ref_from_cog']:.0f} "
            f"pcs/h (exact): the seed's ≈ 3600 fits the leading-edge start. With the moment "
            f"of friction forces neglected (the simplified model the seed used for its "
            f"estimates of the field width) the reference is {s.data['ref_simple']:.0f} pcs/h."
        )
        if s10 and e10:
            st_s, st_e = s10.data["runs"][90.0][1]["stages"], e10.data["runs"][90.0][1]["stages"]
            text += (
                "\n\nA stuck patch cannot supply the seed's F_max and T_max at once, so the "
                f"exact stick releases the parcel from the belt at {st_e['E2']:.3f} s against "
                f"{st_s['E2']:.3f} s (α = 90°, A = 0.7 m): W_t {e.data['ref_full']:.0f} against "
                f"{s.data['ref_full']:.0f} pcs/h."
            )
        agree = [law for law, res in (("seed", s), ("exact", e)) if res.checks["9b"].holds]
        verdict = {
            2: "the model agrees in both laws",
            1: f"the model agrees under the {agree[0] if agree else ''} law only",
            0: "the model does not agree in either law",
        }[len(agree)]
        text += (
            "\n\nThe seed's sentence on α = 45° (“slightly deteriorates … especially in the "
            "case of longer objects”) reads two ways: the loss is slight, slightest for longer "
            "objects (row 9b of the statement table), or the loss is larger for longer objects "
            "(row 9b-longer). Its next sentence (30°: “similar … more significant in the case "
            "of short loads”) and its conclusion 2b (the gain from a larger α “is more "
            "pronounced in the case of short loads”) side with the first; read so, "
            f"{verdict} (Fig. 9b); the statement table judges both readings."
        )
        return text
    if name == "13":
        return (
            "Released farther out (0.10 m) the parcel reaches belt speed and sticks; model 1 "
            "then keeps swinging: last/first swing ; sticks = "
            + ", ".join(
                f"{results['13', law].headline['model 1 released 0.10 m off: last/first swing ; sticks']}"  # noqa: E501
                f" ({law} stick)"
                for law in _laws(results, "13")
            )
            + ". The damping of Fig. 13a depends on the assumed release offset as well as on "
            "the assumed b-spline points."
        )
    if name == "14":
        r = get(("14", "seed"))
        end = r.data["F_b_end"]
        return (
            "Near the stick on the disks the parcel's rubbing there is mostly rotation, so "
            "the net force of a constant μ falls (its parts pull in turning directions): "
            f"|F_b| ends E2 at {end['2']:.1f} N for models 2 and 3 (seed stick), "
            f"{end['2'] / (5.0 * 9.81 * 0.46):.0%} of μ_G m g. The b-spline μ rises towards "
            f"μ_0 = 0.65 as the rubbing speed falls and holds model 1 at {end['1']:.1f} N."
        )
    if name == "two-stage":
        lines = [
            "| stick | α_2 | single field b_min | d (pre-shift) | b_1 | final field b_2 min "
            "| shorter by |",
            "|---|---|---|---|---|---|---|",
        ]
        for law in _laws(results, "two-stage"):
            rows = results["two-stage", law].data["rows"]
            last = max(x["d_over_s"] for x in rows)
            for x in rows:
                if x["d_over_s"] == last:
                    lines.append(
                        f"| {law} | {x['alpha2_deg']:.0f}° | {x['b_single_m']:.3f} m | "
                        f"{x['d_m']:.3f} m | {x['b1_m']:.3f} m | {x['b2_min_m']:.3f} m | "
                        f"{x['final_shrink_pct']:.1f} % |"
                    )
        return "\n".join(lines)
    return ""


def render(
    results: dict, *, quick: bool, elapsed: float, command: str, claims_block: str = ""
) -> str:
    """
    Return docs/paper.md from the figures' results.

    Parameters
    ----------
    results : dict
        {(name, law): FigureResult} from ``run_figures``.
    quick : bool
        Whether the grids were the coarse ones (said on the page).
    elapsed : float
        The run's wall time [s].
    command : str
        The command that made it.
    claims_block : str
        The table of the seed's general claims over their ranges (``claims_cli``).

    Returns
    -------
    str
        The page.

    """
    info = machine_info()
    names = list(dict.fromkeys(n for n, _ in results))
    out = [
        "# The seed's numerical experiments, reproduced",
        "",
        f"Written by `{command}`, which ran every figure under both stick laws in "
        f"{elapsed:.0f} s on {info['cores']} cores ({info['cpu']}); every number on this "
        "page is one that command printed"
        + (" (coarse grids: `--quick`)" if quick else "")
        + ". Run `sorter paper FIG --stick seed|exact` for one figure under one law. "
        "“Seed” is T. Piątkowski, *Model and analysis of the process of unit-load stream "
        "sorting by a manipulator with torsional disks*, JTAM 47(4), 2009. Its own pictures "
        "are not reproduced here; its statements are quoted, so the two can be laid side "
        "by side.",
        "",
        "Common to the sorting figures unless said otherwise: the full planar model "
        "(moment of friction forces on), the accurate method (Dormand–Prince 5(4), sticks "
        "located as events), μ_a = μ_b = μ_c = 0.6 (const1, the seed's section 5), B = 0.2 m, "
        "m = 5 kg, s = 0.7 m, φ_0 = 0, the parcel starting with its leading edge on the "
        "zone a/b border, moving with the belt. x_o is the distance the centre of gravity "
        "travels along the belt until it has crossed s = 0.7 m.",
        "",
        "Two stick laws, side by side wherever a figure has surfaces to stick to: the "
        "seed's (`--stick seed`, `model.stick: seed`: each zone's kinetic force and moment "
        "within the other's static limit, eqs. 4.2-4.5 — the seed's own computation, the "
        "default of `sorter paper`) and the exact one (`--stick exact`, `model.stick: "
        "exact`: the patch's limit set, the default everywhere else in the project).",
        "",
        CONTENTS_START,
        CONTENTS_END,
        "",
        "## The seed's claims over their ranges",
        "",
        CLAIMS_BLOCK[0],
        claims_block.rstrip(),
        CLAIMS_BLOCK[1],
        "",
        "## The seed's statements, checked",
        "",
        "One row per statement the seed makes about its figures and in its conclusions; "
        "its words, what each stick law gives, the verdict and the test in "
        "`test/test_paper.py` that asserts it. Where a statement is qualitative (“much "
        "shorter”, “substantial”) the threshold this project reads it by is in the check's "
        "words in the figure's section; where the verdict rests on an assumed parameter, "
        "the verdict says which. These are verdicts at the seed's own points; the general "
        "claims among them are judged over their whole ranges in the section above, where "
        "several hold at these points only.",
        "",
        statement_table(results),
    ]
    for name in names:
        title, setup = SECTIONS[name]
        out += ["", f"## {title}", "", setup, "", _images(results, name), ""]
        out += [_headline_table(results, name), ""]
        out += ["The seed's statements, as measured:", "", _checks_list(results, name)]
        notes = _notes(results, name)
        if notes:
            out += ["", notes]
    return with_contents("\n".join(out) + "\n")


def write_doc(figures: dict, doc_dir: Path, out: Path, quick: bool, log=print) -> Path:
    """
    Run every figure under both laws, write DOC_DIR/paper.md and its pictures in DOC_DIR/img.

    Parameters
    ----------
    figures : dict
        {name: figure function} in page order.
    doc_dir : Path
        The page's folder (``docs`` for the project's own).
    out : Path
        Where the figures write their CSV and PNG files first.
    quick : bool
        Coarse grids.
    log : callable
        Reports go here.

    Returns
    -------
    Path
        The page.

    """
    t0 = time.perf_counter()
    results = run_figures(figures, out, quick, log)
    img = doc_dir / "img"
    img.mkdir(parents=True, exist_ok=True)
    for (_, law), res in results.items():
        for png in _pngs(res):
            shutil.copyfile(png, img / _image_name(png, law))
    command = "sorter paper all --doc " + str(doc_dir) + (" --quick" if quick else "")
    page = render(
        results,
        quick=quick,
        elapsed=time.perf_counter() - t0,
        command=command,
        claims_block=saved_block(doc_dir),
    )
    path = doc_dir / "paper.md"
    path.write_text(page)
    return path
