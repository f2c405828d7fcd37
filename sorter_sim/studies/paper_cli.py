"""
``sorter paper FIG``: the seed's figures from the command line.

The figures live in ``paper`` (the seed's own) and ``two_stage`` (the two-stage
design built on them); this module only picks and runs them, so that neither
figure module imports the other's caller. The exit code is 1 when any figure
does not reproduce what the seed states.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sorter_sim.studies.outpaths import dir_problem
from sorter_sim.studies.paper import fig4, fig5, fig7, fig8, fig9, fig10, fig11, fig13, fig14
from sorter_sim.studies.progress import progress_bar
from sorter_sim.studies.two_stage import two_stage_figure

FIGURES = {
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
        set(FIGURES) | set(ALIASES) | {"all"}, key=lambda s: (not s[0].isdigit(), len(s), s)
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
    out = Path(args.out)
    problem = dir_problem(out)
    if problem:
        return problem
    which = ALIASES.get(args.figure, args.figure)
    names = list(FIGURES) if which == "all" else [which]
    failed = []
    bar = progress_bar(len(names), "sorter paper", "fig", quiet=args.quiet or len(names) == 1)
    for name in names:
        bar.set_postfix_str(f"Fig. {name}")
        res = FIGURES[name](out, quick=args.quick)
        bar.write(res.report())
        bar.update(1)
        if not res.success:
            failed.append(name)
    bar.close()
    if failed:
        print(f"seed statements not reproduced in: Fig. {', '.join(failed)} (see [FAILS] above)")
        return 1
    return 0
