"""
``sorter paper FIG``: the seed's figures from the command line.

The figures live in ``paper`` (the seed's own) and ``two_stage`` (the two-stage
design built on them); this module only picks and runs them, so that neither
figure module imports the other's caller. ``--stick`` picks the stick law (the
seed's by default, ``both`` for each in turn); ``all --doc DIR`` writes
DIR/paper.md from a run under both (``paper_doc``). ``statements`` judges the
seed's general claims over their ranges (``claims_cli``). The exit code is 1 when any
figure does not reproduce what the seed states.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sorter_sim.studies import claims_cli
from sorter_sim.studies.outpaths import dir_problem
from sorter_sim.studies.paper import (
    fig3,
    fig4,
    fig5,
    fig7,
    fig8,
    fig9,
    fig10,
    fig11,
    fig13,
    fig14,
)
from sorter_sim.studies.paper_doc import write_doc
from sorter_sim.studies.paper_support import STICK_LAWS
from sorter_sim.studies.progress import progress_bar
from sorter_sim.studies.two_stage import two_stage_figure

FIGURES = {
    "3": fig3,
    "4": fig4,
    "5": fig5,
    "7": fig7,
    "8": fig8,
    "9": fig9,
    "10": fig10,
    "11": fig11,
    "13": fig13,
    "14": fig14,
    "two-stage": two_stage_figure,
}
ALIASES = {"14-16": "14", "15": "14", "16": "14", "two_stage": "two-stage"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """
    Add the verb's arguments to its parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's parser.

    """
    choices = sorted(
        set(FIGURES) | set(ALIASES) | {"all", "statements"},
        key=lambda s: (not s[0].isdigit(), len(s), s),
    )
    parser.add_argument(
        "figure", metavar="FIG", choices=choices, help=f"which figure: {', '.join(choices)}"
    )
    parser.add_argument(
        "--out",
        default="paper_figures",
        metavar="DIR",
        help="folder for the CSV and PNG files (default: ./paper_figures)",
    )
    parser.add_argument(
        "--quick", action="store_true", help="coarse grids and shorter runs (seconds per figure)"
    )
    parser.add_argument(
        "--stick",
        choices=(*STICK_LAWS, "both"),
        default="seed",
        help="stick law: seed (the seed's decoupled test, its own computation; default), "
        "exact (the patch's limit set; files in DIR/exact), or both in turn",
    )
    parser.add_argument(
        "--doc",
        metavar="DOCDIR",
        help="with FIG all: run every figure under both stick laws and write "
        "DOCDIR/paper.md with its pictures in DOCDIR/img (docs/paper.md is `--doc docs`)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="with FIG statements: print the statement table as one JSON object",
    )
    parser.add_argument(
        "--grid",
        metavar="FILE",
        help="with FIG statements: start from a saved grid (DOCDIR/data/statement_grid.json) "
        "and run only the points it lacks",
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no progress bar (there is none either when stderr is not a terminal)",
    )


def run(args) -> int | str:
    """
    ``sorter paper FIG``: compute, write and print one figure (or all of them).

    Parameters
    ----------
    args : argparse.Namespace
        The verb's parsed arguments.

    Returns
    -------
    int or str
        The exit code, or a message for a refused input.

    """
    if args.figure == "statements":
        return claims_cli.run(args)
    if args.json or args.grid:
        return "--json and --grid go with `sorter paper statements`"
    out = Path(args.out)
    problem = dir_problem(out)
    if problem:
        return problem
    which = ALIASES.get(args.figure, args.figure)
    if args.doc is not None:
        if which != "all":
            return f"--doc writes every figure's page: use `sorter paper all --doc {args.doc}`"
        if args.stick != "seed":
            return "--doc runs both stick laws itself: leave out --stick"
        doc = Path(args.doc)
        problem = dir_problem(doc, "--doc")
        if problem:
            return problem
        reports = []
        path = write_doc(FIGURES, doc, out, args.quick, log=lambda text: reports.append(text))
        print("\n".join(reports))
        print(f"wrote {path}")
        return _verdict(reports)
    names = list(FIGURES) if which == "all" else [which]
    laws = STICK_LAWS if args.stick == "both" else (args.stick,)
    failed = []
    bar = progress_bar(len(names), "sorter paper", "fig", quiet=args.quiet or len(names) == 1)
    for name in names:
        bar.set_postfix_str(f"Fig. {name}")
        for law in laws:
            res = FIGURES[name](out, quick=args.quick, stick=law)
            bar.write(res.report())
            if not res.success:
                failed.append(name if res.stick is None else f"{name} ({law} stick)")
            if res.stick is None:
                break  # the figure has no stick law: once is all
        bar.update(1)
    bar.close()
    if failed:
        print(f"seed statements not reproduced in: Fig. {', '.join(failed)} (see [FAILS] above)")
        return 1
    return 0


def _verdict(reports: list) -> int:
    """Exit code of a run whose reports are ``reports``: 1 when any statement FAILS."""
    failed = [text.splitlines()[0] for text in reports if "[FAILS]" in text]
    if failed:
        print("seed statements not reproduced in:\n  " + "\n  ".join(failed))
        return 1
    return 0
