"""
The cell's infeed: the parcels waiting to come onto the belt, and when the next may.

Two sources feed one induct point, as at a real sorter's induction: parcels asked for
from outside (``Cell.induct``, a WCS or a test), queued in order, and the configured
stream (``arrival``): 'gap' puts each parcel a drawn belt gap behind the last, 'rate'
draws Poisson interarrival times, 'none' streams nothing. A parcel from outside goes
first. The stream can be a batch (``arrival_count``) or a span of simulated time
(``arrival_duration_s``); either is the same parcels however the run is sliced.

``Infeed`` decides only which parcel is next and the belt gap it needs; the cell
checks the room in front of the induct point and places it.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from sorter_sim.model.description import PENDING_INDUCTS_MAX
from sorter_sim.runtime.cell_records import NEVER, ParcelSpec
from sorter_sim.runtime.params import CellParams, ParamError


class Infeed:
    """The parcels waiting at the induct point: queued ones from outside and the stream."""

    def __init__(self, params: CellParams, dt: float):
        self.params = params
        self.dt = dt
        self.rng = np.random.Generator(np.random.PCG64(params.seed))
        self.external: deque[ParcelSpec] = deque()
        self.n_streamed = 0  # parcels placed from the stream (arrival_count counts these)
        self.n_refused = 0  # inducts refused because too many were waiting
        self._next: tuple[ParcelSpec, float] | None = None  # the stream's next, its gap
        self._due_k: int | None = None  # 'rate': the period the next one is due
        # the period the stream opened in (arrival_duration_s counts from it); None: off
        self._open_k: int | None = None if params.arrival == 'none' else 0

    def update_params(self, params: CellParams, k: int) -> None:
        """Take a changed stream at period ``k``: one switched on opens its span now."""
        if params.arrival == 'none':
            self._open_k = None
        elif self.params.arrival == 'none':
            self._open_k = k
        if params.arrival != 'rate':
            self._due_k = None
        self.params = params

    def queue(self, spec: ParcelSpec) -> None:
        """Queue a checked parcel from outside; refuse it when PENDING_INDUCTS_MAX wait."""
        if len(self.external) >= PENDING_INDUCTS_MAX:
            self.n_refused += 1
            raise ParamError(
                f'{PENDING_INDUCTS_MAX} inducts already wait for room on the belt; '
                'this one is refused'
            )
        self.external.append(spec)

    def end_k(self) -> int | None:
        """Return the period the stream's span (``arrival_duration_s``) ends at, or None."""
        span = self.params.arrival_duration_s
        if not span or self._open_k is None:
            return None
        return self._open_k + math.ceil(span / self.dt - 1e-9)

    def closed(self, k: int) -> bool:
        """Return True once the stream has given all it will: its batch, or its span."""
        p = self.params
        if p.arrival_count and self.n_streamed >= p.arrival_count:
            return True
        end = self.end_k()
        return end is not None and k >= end

    def candidate(self, k: int) -> tuple[str, ParcelSpec, float] | None:
        """
        Return the parcel to place next at period ``k``, or None.

        As ('external' or 'stream', its spec, the belt gap it needs behind the last
        parcel [m]). The stream's next parcel is drawn once and kept until placed, so
        the draws do not depend on how often the cell asks.
        """
        p = self.params
        if self.external:
            return 'external', self.external[0], p.arrival_gap[0]
        if self.closed(k):
            return None
        if p.arrival == 'gap':
            if self._next is None:
                spec = self._draw_parcel()
                self._next = (spec, self.rng.uniform(*p.arrival_gap))
        elif p.arrival == 'rate':
            if self._due_k is None:
                self._due_k = k + self._draw_interarrival()
            if k < self._due_k:
                return None
            if self._next is None:
                self._next = (self._draw_parcel(), p.arrival_gap[0])
        else:
            return None
        return 'stream', self._next[0], self._next[1]

    def taken(self, source: str, k: int) -> None:
        """Take the candidate from ``source`` off the infeed: the cell placed it at ``k``."""
        if source == 'external':
            self.external.popleft()
            return
        self._next = None
        self.n_streamed += 1
        if self.params.arrival == 'rate':
            self._due_k = k + self._draw_interarrival()

    def periods_until_due(self, k: int) -> int:
        """With no candidate at ``k``: periods before a 'rate' stream's next is due."""
        if self.params.arrival == 'rate' and self._due_k is not None and not self.external:
            return max(1, self._due_k - k)
        return NEVER

    def _draw_parcel(self) -> ParcelSpec:
        p = self.params
        u = self.rng.uniform
        A = u(*p.parcel_A)
        B = u(*p.parcel_B)
        m = u(*p.parcel_m)
        phi0 = math.radians(u(*p.parcel_phi0_deg))
        y0 = u(*p.parcel_y0)
        return ParcelSpec(A, B, m, phi0, y0)

    def _draw_interarrival(self) -> int:
        dt_s = self.rng.exponential(1.0 / self.params.arrival_rate)
        return max(1, math.ceil(dt_s / self.dt))
