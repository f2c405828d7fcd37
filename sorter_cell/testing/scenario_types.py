"""
What scenario files of a cell and of a line share: the error, a key check, an expectation's result.

Kept apart from ``scenario`` so that ``line_scenario`` uses them without importing the
module that runs it.
"""

from __future__ import annotations

import importlib
import sys
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path


class ScenarioError(ValueError):
    """A scenario file that cannot run: the message names the key and what is allowed."""


@dataclass
class Check:
    """One expectation and how the run met it."""

    text: str
    passed: bool
    detail: str = ''


def refuse_unknown(entry: dict, allowed, key: str, context: str = '') -> None:
    """Raise ``ScenarioError`` naming the keys of ``entry`` that ``allowed`` does not hold."""
    extra = sorted(set(entry) - set(allowed))
    if extra:
        raise ScenarioError(
            f'{key}: unknown key(s) {", ".join(extra)}{context} (allowed: '
            f'{", ".join(sorted(allowed))})'
        )


@contextmanager
def _on_path(folders: list[str]):
    added = [f for f in folders if f not in sys.path]
    sys.path[:0] = added
    try:
        yield
    finally:
        for f in added:
            if f in sys.path:
                sys.path.remove(f)


def load_user_factory(spec, folder):
    """
    Return the callable a scenario's ``module:callable`` names, as ``load_node_factory``.

    The module is looked for in the scenario file's folder, then in the directory the
    command runs in (where the user's own modules are, as pytest finds them from
    there), then on ``sys.path``; when it does not import, the message says where it
    was looked for.

    Parameters
    ----------
    spec : str
        ``module:callable``, as the scenario's ``controller.node`` or a line's program.
    folder : Path or None
        The scenario file's folder (None: a scenario not read from a file).

    Returns
    -------
    callable
        What ``load_node_factory`` returns; its ``FactoryError`` for a bad spec or name.

    """
    from sorter_cell.testing.lockstep import FactoryError, load_node_factory

    here = Path.cwd()
    places = [(str(folder), str(folder))] if folder is not None else []
    if folder is None or Path(folder).resolve() != here.resolve():
        places.append((str(here), f'{here} (the current directory)'))
    with _on_path([p for p, _ in places]):
        if isinstance(spec, str) and spec.count(':') == 1 and all(spec.split(':')):
            module_name = spec.split(':')[0]
            try:
                importlib.import_module(module_name)
            except Exception as exc:  # noqa: BLE001 - any import error is the user's to see
                looked = ', '.join(name for _, name in places)
                raise FactoryError(
                    f'cannot import {module_name!r} (looked in {looked}, then sys.path): '
                    f'{type(exc).__name__}: {exc}'
                ) from None
        # a malformed spec is refused there, in its own words
        return load_node_factory(spec)


__all__ = ['Check', 'ScenarioError', 'load_user_factory', 'refuse_unknown']
