"""
``sorter paper statements``: the seed's general claims judged over their ranges.

Runs the grid of ``claims_grid`` (every point once, progress on stderr), judges each
claim of ``claims.CLAIMS`` under each stick law with the moment on and off, and
prints the table, or with ``--json`` the object
``{"rows": [{"id", "claim", "models": {"<law>/<full|simplified>": {"verdict", "where",
"points"}}}]}``. ``--doc DIR`` also saves the grid's values to
DIR/data/statement_grid.json and writes the table into DIR/paper.md (its first
section); ``sorter paper all --doc`` draws the same section from that saved grid, so
both commands give one page. ``--grid FILE`` starts from a saved grid and runs only
the points it lacks.
"""

from __future__ import annotations

import json
from pathlib import Path

from sorter_sim.studies.claims import CLAIMS, DEPENDS, HOLDS, PAPER_ONLY, table
from sorter_sim.studies.claims_grid import BEYOND, FULL, MODELS, PAPER, GridStore, load_table
from sorter_sim.studies.claims_grid import stderr_progress
from sorter_sim.studies.markdown import replace_block

GRID_FILE = Path("data") / "statement_grid.json"  # under the docs folder
BLOCK = ("<!-- generated: claims -->", "<!-- end: claims -->")
REPO_DOCS = Path(__file__).resolve().parents[2] / "docs"
SOURCE = f"its grid saved in docs/{GRID_FILE.as_posix()}"
WORDS = {
    HOLDS: "holds",
    PAPER_ONLY: "holds at the seed's points only",
    DEPENDS: "depends",
    "fails": "FAILS",
}


def _verdict_cell(v: dict) -> str:
    word = WORDS[v["verdict"]]
    # a row at one point says its number even when it holds (Fig. 9a's W_t per model)
    holds_at_a_point = v["verdict"] == HOLDS and v["points"] <= 3
    if v["verdict"] != HOLDS or holds_at_a_point:
        where = v["where"].split("closest: ", 1)[-1] if holds_at_a_point else v["where"]
        text = f"**{word}**: {where}"
    else:
        text = f"**{word}**"
    text = f"{text} ({v['points']} pts)"
    if "beyond" in v:
        b = v["beyond"]
        text += f"; beyond, v to 2.5 m/s: {b['verdict']}" + (
            f" ({b['where']})" if b["verdict"] != HOLDS else ""
        )
    return text.replace("|", "\\|")


def markdown_block(result: dict, source: str) -> str:
    """
    Return the statement table as markdown (the block docs/paper.md holds first).

    Parameters
    ----------
    result : dict
        ``claims.table``'s result.
    source : str
        Where its grid came from, said above the table.

    Returns
    -------
    str
        The block.

    """
    keys = [m.key for m in MODELS]
    lines = [
        f"Written by `sorter paper statements --doc docs` ({source}); `sorter paper "
        "statements --json` prints the same. Each general claim is judged on the seed's "
        f"own points ({_grid_words(PAPER)}) and over the ranges it states "
        f"({_grid_words(FULL)}), under each stick law with the moment of friction forces on "
        "(full) and neglected (simplified, the seed's model for its width estimates). "
        "**holds**: every case of the ranges; **holds at the seed's points only**: the "
        "seed's points pass, the first failures between or beyond them are named; "
        "**FAILS**: a case at the seed's own points fails; **depends**: the verdict changes "
        "within the stated range of a parameter of the judging (a detection threshold), "
        "each value's verdict given. The same test beyond the stated ranges "
        f"({_grid_words(BEYOND)}) is reported after the verdict as *beyond*, an "
        "extrapolation that never enters it. A case is one curve (over α, A, "
        "v or μ) at one setting of the other parameters; pts: the grid points the verdict "
        "reads. Cells that hold over a range name no numbers (`sorter paper statements` "
        "prints the closest case); those at one point give its value.",
        "",
        "| id | where | the seed's words | test | " + " | ".join(keys) + " |",
        "|---|---|---|---|" + "---|" * len(keys),
    ]
    for row in result["rows"]:
        cells = [row["id"], row["where"], row["claim"], row["test"]]
        cells += [_verdict_cell(row["models"][k]) for k in keys]
        lines.append(
            "| "
            + " | ".join(c.replace("|", "\\|") if i < 4 else c for i, c in enumerate(cells))
            + " |"
        )
    return "\n".join(lines) + "\n"


def _grid_words(g) -> str:
    a = g.alphas
    al = (
        f"α {a[0]:.0f}-{a[-1]:.0f}° in {a[1] - a[0]:.0f}° steps"
        if len(a) > 3
        else "α " + ", ".join(f"{x:.0f}°" for x in a)
    )
    return (
        f"{al}; v {', '.join(f'{x:g}' for x in g.vs)} m/s; A {g.As[0]:g}-{g.As[-1]:g} m; "
        f"B {g.Bs[0]:g}-{g.Bs[-1]:g} m; μ {', '.join(f'{x:g}' for x in g.mus)}"
    )


def saved_block(doc_dir: Path) -> str:
    """
    Return the block judged from the saved grid of ``doc_dir`` (else the project's docs).

    Parameters
    ----------
    doc_dir : Path
        The page's folder.

    Returns
    -------
    str
        The block, or a line saying how to make it when no grid is saved.

    """
    for base in (doc_dir, REPO_DOCS):
        path = base / GRID_FILE
        if path.is_file():
            store = GridStore(load_table(path), compute=False)
            return markdown_block(table(store), SOURCE)
    return "No saved grid: run `sorter paper statements --doc DIR`.\n"


def text_report(result: dict) -> str:
    """
    Return the table as plain lines: each claim, then its verdict per model.

    Parameters
    ----------
    result : dict
        ``claims.table``'s result.

    Returns
    -------
    str
        The report.

    """
    out = []
    for row in result["rows"]:
        out.append(f"{row['id']} ({row['where']}): {row['claim']}")
        out.append(f"  test: {row['test']}")
        for key, v in row["models"].items():
            out.append(f"  {key:<17} {WORDS[v['verdict']]:<32} {v['where']} [{v['points']} pts]")
            if "beyond" in v:
                b = v["beyond"]
                out.append(f"  {'':<17} beyond: {WORDS[b['verdict']]:<24} {b['where']}")
    return "\n".join(out)


def _judged_on_file(store: GridStore) -> dict | str:
    """
    Judge every claim on a table read from a file; a claim its values leave undecidable is said.

    Each value of the file is in its range (``claims_grid.table_problem``), yet values
    no run gives together (every time alike, so a difference the claim divides by is
    0) can leave a claim without an answer: that is said in one line, naming the claim.

    Parameters
    ----------
    store : GridStore
        The table read from the file.

    Returns
    -------
    dict or str
        ``claims.table``'s result, or the line that says which claim has no answer.

    """
    import warnings

    rows = []
    for claim in CLAIMS:
        try:
            with warnings.catch_warnings():
                # a 0/0 of numpy's warns (the grid saved has none); here it is an answer
                warnings.simplefilter("error", RuntimeWarning)
                rows += table(store, [claim])["rows"]
        except (ArithmeticError, ValueError, RuntimeWarning) as exc:
            return (
                f"its values leave claim {claim.id} undecidable ({type(exc).__name__}: "
                f"{str(exc)[:80]}): not a grid these runs make"
            )
    return {"rows": rows}


def run(args) -> int | str:
    """
    Run ``sorter paper statements``.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``sorter paper`` (json, doc, grid).

    Returns
    -------
    int or str
        0, or a message for a refused input.

    """
    if args.grid:
        path = Path(args.grid)
        if not path.is_file():
            return f"--grid: {path} is not a file (a table `--doc DIR` saved in DIR/{GRID_FILE})"
        try:
            saved = load_table(path)
        except (OSError, ValueError) as exc:
            return f"--grid: {str(path)[:200]}: {getattr(exc, 'strerror', None) or exc}"
        # points the saved grid lacks are run (a grid extended by a new claim)
        store = GridStore(saved, progress=None if args.quiet else stderr_progress())
    else:
        store = GridStore(progress=None if args.quiet else stderr_progress())
    page = None
    if args.doc is not None:
        page = Path(args.doc) / "paper.md"
        if not page.is_file() or BLOCK[0] not in page.read_text():
            return (
                f"--doc: {page} has no {BLOCK[0]} block (write it first: sorter paper all --doc)"
            )
    result = table(store) if not args.grid else _judged_on_file(store)
    if isinstance(result, str):
        return f"--grid: {str(args.grid)[:200]}: {result}"
    print(json.dumps(result, ensure_ascii=False) if args.json else text_report(result))
    if page is not None:
        saved = store.save(Path(args.doc) / GRID_FILE)
        # the page is judged on the grid as saved (7 digits), as the tests and
        # `sorter paper all --doc` read it
        block = markdown_block(table(GridStore(load_table(saved), compute=False)), SOURCE)
        page.write_text(replace_block(page.read_text(), block, BLOCK))
    return 0
