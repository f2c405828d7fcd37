"""
The options of a verb that runs a scene: ``--set KEY=VALUE`` and ``--json``.

``sorter run`` and ``sorter study best-alpha`` take the same scene keys and say the
same of them; both add their options here, below the command line so a study can too.
"""

from __future__ import annotations

import argparse


def add_scene_options(parser: argparse.ArgumentParser) -> None:
    """
    Add ``--set KEY=VALUE`` (repeatable, into ``overrides``) and ``--json`` to a parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        A verb's parser that takes a scene.

    """
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a scene key, e.g. --set parcel.A=0.4",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
