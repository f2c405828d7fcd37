"""
``sorter study NAME``: design studies beyond the seed, one sub-verb each.

``best-alpha`` (``best_alpha``): the disk angle of the largest capacity and of the
narrowest disk field for one scene, or (``--map``) over v x A for the seed's
parameters. Each study module exposes ``add_arguments(parser)`` and ``run(args)``
like the top-level verbs.
"""

from __future__ import annotations

import argparse

from sorter_sim.studies import best_alpha

STUDIES = {
    "best-alpha": (best_alpha, "the disk angle of the largest capacity and the narrowest field"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """
    Add one sub-parser per study.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's parser.

    """
    sub = parser.add_subparsers(dest="study", metavar="STUDY", parser_class=type(parser))
    sub.required = True
    for name, (module, help_text) in STUDIES.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(p)
        p.set_defaults(_study_main=module.run)


def run(args) -> int | str:
    """
    Run the chosen study.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments.

    Returns
    -------
    int or str
        The study's exit code or refusal.

    """
    return args._study_main(args)
