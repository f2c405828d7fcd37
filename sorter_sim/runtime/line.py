"""
A sorter line without ROS: diverter stations in a row on one belt, parcels handed on.

``Line`` holds one ``Cell`` per station. Each station is the seed's three-zone cell
in a frame of its own (x = 0 at its disk field), laid along the line at
``positions[k]``; the belt runs from station 0's induction to the straight end
behind the last station. A parcel that leaves station k over its straight exit
is handed to station k + 1 in the state it left with (pose, velocity, contact
mode, stick-gauge warm start, id and label), at the period boundary it left at,
so the line integrates exactly what one long cell would (``test_line.py`` checks
it against a single cell). Stations are advanced upstream first over the same
periods: a station only ever receives from the one before it, so each receives
every parcel before it advances past the period the parcel arrives in.

Chutes fill and drain: each holds ``capacity`` parcels and empties at
``drain_per_s`` (parcels per second, as a take-away belt clears it); its full
sensor is blocked while it holds ``capacity`` or more. A parcel diverted into a
full chute cannot go in: it is reported jammed at the chute entry (cause ``chute
full``) and the station's jam fault is set (the chute itself is not modelled
beyond its entry line, so the parcel is not drawn stuck there).

Layout rules (``check_layout``): stations in order, none closer to the next than
its span (the induct point to the straight exit: the hand-over point must lie
upstream of the next station's first sensor), all within the belt's length, and
every chute named once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from sorter_sim.model.description import chute_pairs, shown
from sorter_sim.runtime.cell import Cell, Handoff, Outcome, SensorEdge
from sorter_sim.runtime.params import CellParams, ParamError


@dataclass
class Chute:
    """
    One chute: its name, the station and side it is on, its fill and its take-away.

    The take-away removes one parcel every 1/drain_per_s seconds while the chute holds
    any (the first one that long after it came in, or after the take-away started).
    """

    name: str
    station: int
    side: str  # left | right
    capacity: int = 20
    drain_per_s: float = 1.0
    level: int = 0  # parcels in it
    received: int = 0
    t_ns: int = 0  # the time ``level`` is for
    next_out_ns: int | None = None  # when the take-away removes the next parcel

    @property
    def full(self) -> bool:
        return self.level >= self.capacity

    def _period_ns(self) -> int | None:
        return round(1e9 / self.drain_per_s) if self.drain_per_s > 0.0 else None

    def drain_to(self, t_ns: int) -> list:
        """
        Run the take-away up to ``t_ns``.

        Parameters
        ----------
        t_ns : int
            The time to run to [ns].

        Returns
        -------
        list of SensorEdge
            The full sensor's edge if it cleared.

        """
        edges = []
        period = self._period_ns()
        if period is None:
            self.next_out_ns = None
        elif self.level > 0 and self.next_out_ns is None:
            self.next_out_ns = self.t_ns + period
        while self.next_out_ns is not None and self.next_out_ns <= t_ns and self.level > 0:
            if self.full:
                edges.append(SensorEdge(self.next_out_ns, f'{self.name}.full', False))
            self.level -= 1
            self.next_out_ns = self.next_out_ns + period if self.level > 0 else None
        self.t_ns = max(self.t_ns, t_ns)
        return edges

    def receive(self, t_ns: int) -> list:
        """
        Take one parcel in at ``t_ns`` (the caller has run the take-away to then).

        Parameters
        ----------
        t_ns : int
            When it came in [ns].

        Returns
        -------
        list of SensorEdge
            The full sensor's edge if the chute is full now.

        """
        self.level += 1
        self.received += 1
        period = self._period_ns()
        if self.level == 1 and period is not None:
            self.next_out_ns = t_ns + period
        return [SensorEdge(t_ns, f'{self.name}.full', True)] if self.level == self.capacity else []


@dataclass(frozen=True)
class StationEvent:
    """Something a station reported (a ``Cell`` event), with the station's index."""

    station: int
    event: object

    @property
    def t_ns(self) -> int:
        return self.event.t_ns


@dataclass(frozen=True)
class LineExit:
    """
    Where a parcel left the line: a chute (by name), the straight end, or jammed.

    station: the station it left at (the last one for the straight end).
    """

    t_ns: int
    parcel_id: int
    label: str
    exit: str  # a chute's name | straight_end | jammed
    station: int
    cause: str = ''


@dataclass
class LineLayout:
    """
    Where the stations are and what their chutes are called.

    positions: each station's disk-field start along the line [m], increasing;
    chutes: per station (left name, right name); capacity, drain_per_s: each chute's;
    length: the belt from the first induction point to the straight end [m] (None: just
    long enough).
    """

    positions: list
    chutes: list
    capacity: int = 20
    drain_per_s: float = 1.0
    length: float | None = None
    overrides: list = field(default_factory=list)  # per station: CellParams changes
    # a segment of a longer line (``Line.advance``'s ``incoming``, ``take_outgoing``):
    # the first station's index on the whole line, and whether its last station hands
    # its straight exits on to the next segment rather than to the straight end
    first: int = 0
    hand_on: bool = False


def default_layout(n: int, params: CellParams, gap: float = 0.0) -> LineLayout:
    """
    Return n stations one span apart (+ ``gap``), chutes S01L, S01R, S02L, ...

    Parameters
    ----------
    n : int
        The number of stations, 1..64.
    params : CellParams
        The stations' parameters.
    gap : float
        Belt between one station's exit and the next one's induct point [m].

    Returns
    -------
    LineLayout
        The layout.

    """
    if not (isinstance(n, int) and 1 <= n <= 64):
        raise ParamError(f'stations must be an integer in [1, 64], got {shown(n)}')
    span = params.exit_x - params.induct_x
    # the belt starts at station 1's induct point: x = 0 of the line
    return LineLayout(
        positions=[-params.induct_x + k * (span + gap) for k in range(n)],
        chutes=chute_pairs(n),
    )


def check_layout(layout: LineLayout, params: CellParams) -> None:
    """
    Raise ParamError naming what is wrong with a line's layout; return None when it is sound.

    Parameters
    ----------
    layout : LineLayout
        The layout.
    params : CellParams
        The stations' parameters (their span: induct point to straight exit).

    Raises
    ------
    ParamError
        Stations out of order or overlapping, a station outside the belt, a chute named
        twice or badly, a bad capacity or drain rate.

    """
    pos = layout.positions
    n = len(pos)
    if not 1 <= n <= 64:
        raise ParamError(f'a line has 1 to 64 stations, got {n}')
    if len(layout.chutes) != n:
        raise ParamError(f'chutes: {len(layout.chutes)} pairs of names for {n} stations')
    for k, x in enumerate(pos):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise ParamError(f'station {k + 1}: position must be a finite number, got {shown(x)}')
    span = params.exit_x - params.induct_x
    for k in range(n - 1):
        if pos[k + 1] - pos[k] < span - 1e-9:
            raise ParamError(
                f'stations {k + 1} and {k + 2} overlap: {pos[k + 1] - pos[k]:g} m apart, a '
                f'station needs {span:g} m (induct_x to exit_x) before the next one starts'
            )
    start = pos[0] + params.induct_x
    if layout.first == 0 and start < -1e-9:
        raise ParamError(
            f'station 1 lies outside the belt: its induct point is at {start:g} m, the belt '
            'starts at 0'
        )
    end = pos[-1] + params.exit_x
    if layout.length is not None and end > layout.length + 1e-9:
        k = next(k for k in range(n) if pos[k] + params.exit_x > layout.length + 1e-9)
        raise ParamError(
            f'station {k + 1} lies outside the belt: it ends at {pos[k] + params.exit_x:g} m, '
            f'the belt at {layout.length:g} m'
        )
    seen: dict[str, int] = {}
    for k, pair in enumerate(layout.chutes):
        if not (isinstance(pair, (list, tuple)) and len(pair) == 2):
            raise ParamError(f'station {k + 1}: chutes must be a pair (left, right) of names')
        for name in pair:
            if not (isinstance(name, str) and 1 <= len(name) <= 64 and name.isprintable()):
                raise ParamError(
                    f'station {k + 1}: a chute name must be 1-64 printable '
                    f'characters, got {shown(name)}'
                )
            if name == 'straight_end':
                raise ParamError('chute name straight_end is the line\'s own end')
            if name in seen:
                raise ParamError(
                    f'chute {name!r} named twice: stations {seen[name] + 1} and {k + 1}'
                )
            seen[name] = k
    if not (isinstance(layout.capacity, int) and 1 <= layout.capacity <= 10_000):
        raise ParamError(
            f'chute capacity must be an integer in [1, 10000], got {shown(layout.capacity)}'
        )
    d = layout.drain_per_s
    if isinstance(d, bool) or not isinstance(d, (int, float)) or not (0.0 <= d <= 100.0):
        raise ParamError(f'chute drain_per_s must be in [0, 100] parcels/s, got {shown(d)}')


class Line:
    """
    Diverter stations in a row on one belt (see the module).

    Parameters
    ----------
    params : CellParams
        Every station's parameters; station 0 inducts the stream, the others take only
        what station 0 hands on.
    layout : LineLayout
        Where the stations are, their chutes.

    """

    def __init__(self, params: CellParams, layout: LineLayout):
        check_layout(layout, params)
        cells = []
        for k in range(len(layout.positions)):
            changes = dict(layout.overrides[k]) if k < len(layout.overrides) else {}
            p = params.with_changes(changes, runtime=False) if changes else params
            cells.append(Cell(p))
        self._setup(cells, layout)

    @classmethod
    def from_cells(cls, cells: list, layout: LineLayout) -> Line:
        """
        Return a line of cells built elsewhere (the simulation node's stations).

        Parameters
        ----------
        cells : list of Cell
            One per station, upstream first, none advanced yet.
        layout : LineLayout
            Where they are.

        Returns
        -------
        Line
            The line; stations after the first take no stream of their own.

        Raises
        ------
        ParamError
            A bad layout, or stations that cannot share one belt and one clock.

        """
        if not cells:
            raise ParamError('a line has 1 to 64 stations, got 0')
        first = cells[0].params
        check_layout(layout, first)
        for k, c in enumerate(cells[1:], 2):
            q = c.params
            for name in ('control_period_ns', 'belt_speed', 'belt_width', 'induct_x', 'exit_x'):
                if getattr(q, name) != getattr(first, name):
                    raise ParamError(
                        f'station {k}: {name} {getattr(q, name)!r} differs from station 1\'s '
                        f'{getattr(first, name)!r}: the stations share one belt and one clock'
                    )
            if c.k != cells[0].k:
                raise ParamError(f'station {k} has run already; a line starts its stations at 0')
        line = cls.__new__(cls)
        line._setup(list(cells), layout)
        return line

    def _setup(self, cells: list, layout: LineLayout) -> None:
        self.layout = layout
        self.positions = [float(x) for x in layout.positions]
        self.stations: list[Cell] = cells
        for k, cell in enumerate(cells):
            if k > 0 and cell.params.arrival != 'none':
                cell.update_params(cell.params.with_changes({'arrival': 'none'}))
            cell.keep_handoffs = k < len(cells) - 1 or layout.hand_on
        self.chutes = [
            Chute(name, k, side, layout.capacity, float(layout.drain_per_s))
            for k, pair in enumerate(layout.chutes)
            for side, name in zip(('left', 'right'), pair)
        ]
        self._chute = {(c.station, c.side): c for c in self.chutes}
        self.exits: list[LineExit] = []
        self.n_handed = 0
        self.first = layout.first
        self.hand_on = layout.hand_on
        self._outgoing: list[Handoff] = []

    # ------------------------------------------------------------------ time
    @property
    def dt(self) -> float:
        return self.stations[0].dt

    @property
    def k(self) -> int:
        return self.stations[0].k

    @property
    def t(self) -> float:
        return self.stations[0].t

    @property
    def t_ns(self) -> int:
        return self.stations[0].t_ns

    # ------------------------------------------------------------------ stepping
    def advance(self, n: int = 1, incoming=()) -> list:
        """
        Advance every station ``n`` control periods, handing parcels on between them.

        Parameters
        ----------
        n : int
            Control periods.
        incoming : sequence of (Handoff, float)
            A segment's parcels from the segment upstream, each with ``dx`` (the
            upstream station's origin minus this segment's first one's [m]), in time
            order, none after the periods run (``t_ns`` at most the end of the last).
            One that belongs to a period already run (it came late: a segment on the
            wall clock) is taken at the first period, in the state it was handed in.

        Returns
        -------
        list
            What happened, in time order: ``StationEvent`` (a station's sensor edges,
            scans, outcomes, watchdog trips), chute-full ``SensorEdge`` records (sensor
            ``<chute>.full``) and ``LineExit`` records.

        """
        if n < 0:
            raise ValueError(f'n must be >= 0, got {n}')
        k0 = self.k
        dt_ns = self.stations[0].params.control_period_ns
        out: list = []
        outcomes: list = []
        if any(h.t_ns // dt_ns > k0 + n for h, _ in incoming):
            raise ValueError('a hand-over after the periods run cannot be taken yet')
        arriving = list(incoming)
        for s, cell in enumerate(self.stations):
            events: list = []
            cursor = k0
            for h, dx in arriving:
                k_h = h.t_ns // dt_ns
                if k_h > cursor:
                    events += cell.advance(k_h - cursor)
                    cursor = k_h
                events += cell.hand_in(h, dx)
                self.n_handed += 1
            events += cell.advance(k0 + n - cursor)
            handed = cell.take_handoffs() if cell.keep_handoffs else []
            if s + 1 < len(self.stations):
                dx = self.positions[s] - self.positions[s + 1]
                arriving = [(h, dx) for h in handed]
            else:
                self._outgoing += handed
            for e in events:
                out.append(StationEvent(s, e))
                if isinstance(e, Outcome):
                    outcomes.append((e.t_ns, s, e))
        # the chutes fill and drain in time order, whichever station each parcel left
        for _, s, e in sorted(outcomes, key=lambda x: (x[0], x[1])):
            out += self._on_outcome(s, e)
        end = (k0 + n) * dt_ns
        for c in self.chutes:
            out += c.drain_to(end)
        out.sort(key=lambda e: e.t_ns)
        return out

    def take_outgoing(self) -> list[Handoff]:
        """Return the parcels the last station handed on to the next segment since last asked."""
        out, self._outgoing = self._outgoing, []
        return out

    def _on_outcome(self, s: int, e: Outcome) -> list:
        last = s == len(self.stations) - 1 and not self.hand_on
        if e.exit == 'straight' and not last:
            return []  # handed on
        if e.exit in ('left', 'right'):
            chute = self._chute[s, e.exit]
            drained = chute.drain_to(e.t_ns)
            if chute.full:
                # it cannot go in: the station is blocked until an operator clears it
                cell = self.stations[s]
                cell.jam = True
                cell.outcome_counts['jammed'] += 1
                x = LineExit(e.t_ns, e.parcel_id, e.label, 'jammed', s, 'chute full')
                self.exits.append(x)
                return [*drained, x]
            x = LineExit(e.t_ns, e.parcel_id, e.label, chute.name, s)
            self.exits.append(x)
            return [*drained, x, *chute.receive(e.t_ns)]
        name = 'straight_end' if e.exit == 'straight' else 'jammed'
        x = LineExit(e.t_ns, e.parcel_id, e.label, name, s, e.cause)
        self.exits.append(x)
        return [x]

    # ------------------------------------------------------------------ observation
    def chute_full(self) -> dict[str, bool]:
        """Return each chute's full sensor by chute name."""
        return {c.name: c.full for c in self.chutes}

    @property
    def n_parcels(self) -> int:
        return sum(c.n_parcels for c in self.stations)

    @property
    def n_in_flight(self) -> int:
        """Return the parcels on the line without an outcome yet (not in a chute, not jammed)."""
        return sum(c.n_in_flight for c in self.stations)

    def line_x(self, station: int, x: float) -> float:
        """
        Return a station's x as a position along the line [m].

        Parameters
        ----------
        station : int
            The station.
        x : float
            The position in its frame [m].

        Returns
        -------
        float
            The position along the line.

        """
        return self.positions[station] + x


__all__ = [
    'Chute',
    'Line',
    'LineExit',
    'LineLayout',
    'StationEvent',
    'check_layout',
    'default_layout',
]
