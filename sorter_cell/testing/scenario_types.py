"""
What scenario files of a cell and of a line share: the error, a key check, an expectation's result.

Kept apart from ``scenario`` so that ``line_scenario`` uses them without importing the
module that runs it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


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
    refuses; the run's own process imports it.
    """
    import importlib.util
    import sys

    if not isinstance(spec, str) or spec.count(':') != 1 or not all(spec.split(':')):
        return f'must be "module:callable", got {str(spec)[:200]!r}'
    top = spec.split(':')[0].split('.')[0]
    added = folder is not None and str(folder) not in sys.path
    if added:
        sys.path.insert(0, str(folder))
    try:
        found = top in sys.modules or importlib.util.find_spec(top) is not None
    except (ImportError, ValueError):
        found = False
    finally:
        if added:
            sys.path.remove(str(folder))
    if not found:
        return f'cannot import {top!r} (from {folder or "sys.path"}): no such module'
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
