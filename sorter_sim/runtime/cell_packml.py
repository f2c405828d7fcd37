"""
The timers behind a cell's PackML Suspended state: starved and blocked.

PackML suspends a machine for causes outside it: starved (no parcel on the cell and
none coming in for ``packml_starved_s``) and blocked (a chute's eye held blocked for
``packml_blocked_s``, the chute full). ``PackMLTimers`` keeps when each began, in
control periods, and tells the cell how far ahead these conditions cannot change, so
that the state moves at the same period however the caller slices time.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

from sorter_sim.runtime.cell_records import NEVER
from sorter_sim.runtime.params import CellParams


class PackMLTimers:
    """When the cell last produced, and since when each chute's eye shows blocked."""

    def __init__(self, chutes: Iterable[tuple[str, int]]):
        self.chutes = list(chutes)  # (sensor name, sensor index) of each chute's eye
        self.busy_k = 0  # last period with a parcel on the cell or an induct
        self.on_cell = False  # a parcel on the belt or the disks, at the last look
        self._inducted_seen = 0
        self._blocked_since: dict[str, int] = {}  # chute eye -> period it was seen blocked

    def observe(
        self,
        k: int,
        on_cell: bool,
        n_inducted: int,
        producing: bool,
        shows_blocked: Callable[[int, str], bool],
    ) -> None:
        """Take the cell's look at period ``k``; ``producing``: its infeed is open."""
        self.on_cell = on_cell
        # time not spent producing (stopped, held, ...) is not time starving
        if on_cell or n_inducted != self._inducted_seen or not producing:
            self.busy_k, self._inducted_seen = k, n_inducted
        since = self._blocked_since
        for name, s in self.chutes:
            if shows_blocked(s, name):
                since.setdefault(name, k)
            elif since:
                since.pop(name, None)

    def blocked(self, k: int, dt: float, p: CellParams) -> bool:
        """Return whether a chute's eye has shown blocked for ``packml_blocked_s``."""
        return p.packml_blocked_s > 0 and any(
            (k - k0) * dt >= p.packml_blocked_s - 1e-12 for k0 in self._blocked_since.values()
        )

    def starved(self, k: int, dt: float, p: CellParams) -> bool:
        """Return whether the cell has been empty, nothing coming, for ``packml_starved_s``."""
        return (
            p.packml_starved_s > 0
            and not self.on_cell
            and (k - self.busy_k) * dt >= p.packml_starved_s - 1e-12
        )

    def horizon(self, k: int, dt: float, p: CellParams, executing: bool) -> int:
        """Return the periods before a timer can fall due (NEVER: none runs)."""
        out = NEVER
        if not executing:
            return out
        if p.packml_starved_s > 0 and not self.on_cell:
            due = self.busy_k + math.ceil(p.packml_starved_s / dt - 1e-9)
            out = min(out, max(1, due - k))
        if p.packml_blocked_s > 0:
            for k0 in self._blocked_since.values():
                due = k0 + math.ceil(p.packml_blocked_s / dt - 1e-9)
                out = min(out, max(1, due - k))
        return out
