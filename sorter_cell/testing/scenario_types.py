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


__all__ = ['Check', 'ScenarioError', 'number', 'refuse_unknown']
