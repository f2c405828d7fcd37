"""
What scenario files of a cell and of a line share: the error, a key check, an expectation's result.

Kept apart from ``scenario`` so that ``line_scenario`` uses them without importing the
module that runs it.
"""

from __future__ import annotations

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


__all__ = ['Check', 'ScenarioError', 'refuse_unknown']
