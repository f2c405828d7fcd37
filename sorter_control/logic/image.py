"""
The PLC's input image and what one scan hands back, and edge detection on the bits.

A PLC reads its inputs once per scan into an image: the latest bit of every
presence sensor, the time-stamped edges a fast input card latched since the
last scan, scanner labels, the diverter's reported state, service replies,
routing updates and the cell's status bits. ``EdgeDetector`` turns consecutive
images into edges: a bit change is an edge; a latched time stamp, when one
matches, replaces the scan time (exact to the physics), and a pulse shorter than
a scan still counts when the latched edges show it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol


@dataclass(frozen=True)
class Edge:
    """A latched edge: sensor name, time [s, sim clock], rising (became blocked) or falling."""

    sensor: str
    t: float
    rising: bool


@dataclass(frozen=True)
class DiverterState:
    alpha: float  # disk angle [rad]
    stroke: float  # pop-up position 0 (down) .. 1 (up)
    alpha_rate: float = 0.0
    stroke_rate: float = 0.0


@dataclass(frozen=True)
class Reply:
    """The outcome of a service call: accepted, refused (with message) or timed out."""

    command_id: int
    accepted: bool
    message: str = ""
    timed_out: bool = False


@dataclass
class InputImage:
    t: float
    bits: dict = field(default_factory=dict)
    edges: list = field(default_factory=list)
    labels: list = field(default_factory=list)  # (t_received, label)
    diverter: DiverterState | None = None
    replies: list = field(default_factory=list)
    routing_updates: list = field(default_factory=list)  # (pattern, destination)
    cell_estop: bool | None = None  # as the cell reports it, if known
    cell_jam: bool | None = None
    cell_watchdog: bool | None = None  # the cell's watchdog bit, if known
    cell_status_t: float | None = None  # the report's time stamp [s]
    clock_sources: int | None = None  # publishers of the simulated clock, if it is used
    cell_packml: str | None = None  # the cell's PackML state, if it says (sorts in Execute)


@dataclass(frozen=True)
class Command:
    """A service call to make: kind popup (bool), alpha (deg), estop (True) or reset."""

    id: int
    kind: str
    value: object
    t: float


@dataclass(frozen=True)
class Confirmation:
    label: str
    destination_asked: str
    destination_reached: str
    result: str
    seq: int
    t: float


@dataclass
class ScanOutput:
    commands: list = field(default_factory=list)
    confirmations: list = field(default_factory=list)
    log: list = field(default_factory=list)  # (level, text) with level info | warn | error


class ScanIO(Protocol):
    """
    What the parts of the program may do during a scan, besides changing their own state.

    ``SorterLogic`` provides it; a part's unit test provides a recorder.
    """

    t: float

    def log(self, level: str, text: str) -> None:
        """
        Add a log line (level info | warn | error).

        Parameters
        ----------
        level : str
            info, warn or error.
        text : str
            The line.

        """

    def fault(self, kind: str, message: str, sensor: str | None = None) -> None:
        """
        Report a fault of this kind (the first one defines the state).

        Parameters
        ----------
        kind : str
            The command (popup, alpha) or the fault's kind.
        message : str
            What happened, for the log.
        sensor : str, optional
            The sensor concerned.

        """

    def command(self, kind: str, value) -> Command:
        """
        Queue a service call to the cell.

        Parameters
        ----------
        kind : str
            The command (popup, alpha) or the fault's kind.
        value : object
            The command's value.

        Returns
        -------
        Command
            The queued call.

        """

    def finish(self, parcel, reached: str, result: str | None = None) -> None:
        """
        Record a parcel's outcome (a sort confirmation).

        Parameters
        ----------
        parcel : int
            The parcel's sequence number.
        reached : str
            Where it went.
        result : str
            The outcome's code.

        """


class EdgeDetector:
    """
    The bits of the previous scan, and the edges of this one.

    A sensor's first known bit is not an edge (nothing says when it changed):
    ``detect`` reports it in ``first`` instead, for the caller to take as the
    sensor's starting state.
    """

    def __init__(self, sensors):
        self.sensors = list(sensors)
        self.bits: dict[str, bool | None] = {s: None for s in self.sensors}

    def detect(self, image: InputImage, t: float) -> tuple[list[Edge], dict[str, bool]]:
        """
        Return (edges of this scan in time order, first known bits) for a scan at t [s].

        Parameters
        ----------
        image : InputImage
            The inputs of this scan.
        t : float
            The scan time [s].

        Returns
        -------
        (list of Edge, dict)
            The edges of this scan in time order, and the first known bits.

        """
        stamped: dict[str, list[Edge]] = {}
        for e in image.edges:
            if (
                isinstance(e, Edge)
                and e.sensor in self.bits
                and isinstance(e.t, (int, float))
                and math.isfinite(e.t)
            ):
                stamped.setdefault(e.sensor, []).append(e)
        found: list[Edge] = []
        first: dict[str, bool] = {}
        for s in self.sensors:
            prev = self.bits[s]
            cur = image.bits.get(s, prev)
            if cur is None:
                continue
            cur = bool(cur)
            marks = sorted(stamped.get(s, ()), key=lambda e: e.t)
            if prev is None:
                self.bits[s] = cur
                first[s] = cur
                continue
            alternating = (
                bool(marks)
                and marks[0].rising != prev
                and marks[-1].rising == cur
                and all(a.rising != b.rising for a, b in zip(marks, marks[1:]))
            )
            if alternating:
                # a latched edge is never later than the scan that reads it
                found.extend(Edge(s, min(e.t, t), e.rising) for e in marks)
            elif cur != prev:
                match = [e for e in marks if e.rising == cur]
                found.append(Edge(s, min(match[-1].t, t) if match else t, cur))
            self.bits[s] = cur
        found.sort(key=lambda e: e.t)
        return found, first
