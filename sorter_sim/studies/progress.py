"""
Progress bars for long commands (``sorter paper all``, ``sweep``, ``bench precision``, ``demo``).

One place decides when a bar shows: on a terminal, unless the command was asked to be
quiet (``--quiet``). Output that goes to a file or a pipe (CI logs, ``--json`` runs
captured by a program) gets no bar, so it holds only what the command prints.
"""

from __future__ import annotations

import sys


def progress_bar(total: float, desc: str, unit: str, *, quiet: bool = False, **kw):
    """
    Return a tqdm bar on stderr; disabled with ``quiet`` or when stderr is no terminal.

    Parameters
    ----------
    total : float
        The amount the bar counts to.
    desc : str
        What the bar counts.
    unit : str
        Its unit.
    quiet : bool
        No bar.

    """
    from tqdm import tqdm

    return tqdm(
        total=total, desc=desc, unit=unit, file=sys.stderr, disable=True if quiet else None, **kw
    )
