"""
The cell's controller watchdog, as a diverter's safety relay watches its PLC.

The first heartbeat arms it; it trips when the next one is later than
``watchdog_timeout`` of simulated time, and a heartbeat clears the trip. Only a changed
counter feeds it: a frozen controller that keeps sending or rewriting its last value is
a stopped one. The line can be cut as an injected fault: heartbeats are counted then,
but do not reach it. What a trip does to the actuators is the cell's business
(``Cell``: the disks down, α to its safe value).
"""

from __future__ import annotations

import math


class Watchdog:
    """Heartbeat bookkeeping and the period the watchdog trips at; times in periods."""

    def __init__(self):
        self.tripped = False
        self.trips = 0
        self.cut = False  # an injected fault: heartbeats no longer reach the watchdog
        self.lost = 0  # heartbeats sent while cut
        self.frozen = 0  # heartbeats that repeated the last counter: not fed
        self.fed_k: int | None = None  # the period the last feeding heartbeat came in
        self._value: int | None = None  # the last counter that fed it

    def feed(self, counter: int, k: int) -> bool:
        """Take a heartbeat carrying ``counter`` at period ``k``; True if it cleared a trip."""
        if self.cut:
            self.lost += 1
            return False
        if self._value is not None and counter == self._value:
            self.frozen += 1
            return False
        self._value = counter
        self.fed_k = k
        if self.tripped:
            self.tripped = False
            return True
        return False

    def armed(self, timeout: float) -> bool:
        """Return whether a heartbeat came in and a timeout is set (0 switches it off)."""
        return self.fed_k is not None and timeout > 0.0

    def deadline(self, timeout: float, dt: float) -> int | None:
        """Return the period it trips at, or None when it cannot."""
        if not self.armed(timeout) or self.tripped:
            return None
        late = math.ceil(timeout / dt - 1e-9)
        return self.fed_k + max(1, late)

    def trip(self, k: int, dt: float) -> float:
        """Trip at period ``k``; return how long the last heartbeat is ago [s]."""
        self.tripped = True
        self.trips += 1
        return (k - self.fed_k) * dt
