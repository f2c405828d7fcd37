"""
What scenario files of a cell and of a line share: the error, a key check, the results.

Kept apart from ``scenario`` so that ``line_scenario`` uses them without importing the
module that runs it.
"""

from __future__ import annotations

import importlib
import math
import sys
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path


class ScenarioError(ValueError):
    """A scenario file that cannot run: the message names the key and what is allowed."""


@dataclass
class Check:
    """One expectation and how the run met it."""

    text: str
    passed: bool
    detail: str = ''


@dataclass
class ScenarioResult:
    """What a scenario's run gave: the checks, the outcomes, the times."""

    name: str
    checks: list = field(default_factory=list)
    outcomes: list = field(default_factory=list)
    confirmations: list = field(default_factory=list)
    sim_s: float = 0.0
    wall_s: float = 0.0
    record: str = ''
    error: str = ''
    state: str = ''  # the cell at the end of the run (LockStep.explain)
    dispositions: list = field(default_factory=list)  # a line's, per parcel
    properties: dict = field(default_factory=dict)  # JUnit properties (a campaign's domain)
    refused: bool = False  # the user's controller could not be made: error says why (exit 2)
    notes: list = field(default_factory=list)  # what slowed the run (a callback that blocked)

    @property
    def passed(self) -> bool:
        return not self.error and all(c.passed for c in self.checks)


def refuse_unknown(entry: dict, allowed, key: str, context: str = '') -> None:
    """Raise ``ScenarioError`` naming the keys of ``entry`` that ``allowed`` does not hold."""
    extra = sorted(set(entry) - set(allowed))
    if extra:
        raise ScenarioError(
            f'{key}: unknown key(s) {", ".join(extra)}{context} (allowed: '
            f'{", ".join(sorted(allowed))})'
        )


def factory_problem(factory, keywords: tuple) -> str | None:
    """
    Say why ``factory`` cannot make a node when called with ``keywords`` (None if it may).

    A callable that takes none of them (``os:getcwd``) is refused before anything runs;
    one whose signature Python cannot tell (some built-ins) is tried, and what it raises
    is said then.
    """
    import inspect

    try:
        sig = inspect.signature(factory)
    except (TypeError, ValueError):
        return None
    params = sig.parameters.values()
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
        return None
    takes = {p.name for p in params if p.kind is not inspect.Parameter.POSITIONAL_ONLY}
    missing = [k for k in keywords if k not in takes]
    if missing:
        return (
            f'is not a node factory: it takes no {", ".join(k + "=" for k in missing)} '
            f'(its signature: {str(sig)[:120]})'
        )
    return None


def module_problem(spec, folder) -> str | None:
    """
    Say why ``"module:callable"`` cannot be found, without importing anything (None if it can).

    A campaign checks its files this way before any of them runs: no user module is
    imported (and its top level run) in the campaign's process for a file it then
    refuses; the run's own process imports it. The module is looked for where
    ``load_user_factory`` looks: the file's folder, the current directory, ``sys.path``.
    """
    import importlib.util

    if not isinstance(spec, str) or spec.count(':') != 1 or not all(spec.split(':')):
        return f'must be "module:callable", got {str(spec)[:200]!r}'
    top = spec.split(':')[0].split('.')[0]
    places = _user_places(folder)
    with _on_path([p for p, _ in places]):
        try:
            found = top in sys.modules or importlib.util.find_spec(top) is not None
        except (ImportError, ValueError):
            found = False
    if not found:
        looked = ', '.join(name for _, name in places)
        return f'cannot import {top!r} (looked in {looked}, then sys.path): no such module'
    return None


def number(value, key: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    """
    Return ``value`` as a float when it is a finite number in [lo, hi].

    The one check of a number in a scenario, of a cell or of a line alike: a bool,
    a string, NaN (``.nan``) or an infinity is refused by the same line.

    Raises
    ------
    ScenarioError
        Naming ``key``, the value and what is allowed.

    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ScenarioError(f'{key} must be a finite number, got {repr(value)[:80]}')
    if not lo <= value <= hi:
        raise ScenarioError(f'{key} must be in [{lo:g}, {hi:g}], got {value!r}')
    return float(value)


__all__ = [
    'Check',
    'ScenarioError',
    'factory_problem',
    'module_problem',
    'number',
    'refuse_unknown',
]


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


def _user_places(folder) -> list[tuple[str, str]]:
    """Return where a user's module is looked for, (folder, its name in a message), in order."""
    here = Path.cwd()
    places = [(str(folder), str(folder))] if folder is not None else []
    if folder is None or Path(folder).resolve() != here.resolve():
        places.append((str(here), f'{here} (the current directory)'))
    return places


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

    places = _user_places(folder)
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


__all__ = [
    'Check',
    'ScenarioError',
    'factory_problem',
    'load_user_factory',
    'module_problem',
    'number',
    'refuse_unknown',
]
