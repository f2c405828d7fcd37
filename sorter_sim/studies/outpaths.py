"""
Output paths, checked before any work starts.

A run that computes for minutes and then cannot write its result has lost the
minutes: every command that writes checks its ``--out`` first, by creating what
it needs and writing (then removing) a probe file there, and says in one line
what is wrong.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def _probe(folder: Path) -> str | None:
    try:
        fd, name = tempfile.mkstemp(prefix='.probe-', dir=folder)
    except OSError as exc:
        return f'cannot write in {str(folder)!r} ({exc.strerror or exc})'
    os.close(fd)
    os.unlink(name)
    return None


def dir_problem(path: str | Path, flag: str = '--out') -> str | None:
    """
    Make sure ``path`` is a folder this process can write in; else say why.

    Parameters
    ----------
    path : str or Path
        The path.
    flag : str
        The option that names it, for the message.

    Returns
    -------
    str or None
        What is wrong, or None.

    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        return f'{flag} {str(p)!r} exists and is not a folder'
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return f'{flag} {str(p)!r}: cannot create the folder ({exc.strerror or exc})'
    problem = _probe(p)
    return f'{flag} {problem}' if problem else None


def file_problem(path: str | Path, flag: str = '--out') -> str | None:
    """
    Make sure the file ``path`` can be written (its folder made if need be); else say why.

    Parameters
    ----------
    path : str or Path
        The path.
    flag : str
        The option that names it, for the message.

    Returns
    -------
    str or None
        What is wrong, or None.

    """
    p = Path(path)
    if p.exists() and p.is_dir():
        return f'{flag} {str(p)!r} is a folder, not a file'
    if p.exists() and not os.access(p, os.W_OK):
        return f'{flag} {str(p)!r}: the file is not writable'
    return dir_problem(p.parent if str(p.parent) else Path('.'), flag)
