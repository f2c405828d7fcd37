"""
A kinematic stand-in for the sorter cell, for testing the PLC logic without ROS.

``PlantStub`` moves rectangular parcels (φ = 0) along a belt at speed v and,
while the pop-up is more than half up and a parcel's centre of gravity is over
the disk field, at the disks' velocity v(cos α, sin α) instead; no friction
transient, so it diverts faster than the model core predicts. It has
photo-eyes across the belt, chute-entry sensors on the lines y = ±w/2 inside the
field's x range, a scanner on the scanner eye's line, a pop-up with a stroke
time and a disk angle with a slew rate. Parcels that touch stop (a jam).

It serves the controller's commands the way the simulation node's services
would (e-stop refuses diverter commands), and can be told to misbehave: force a
sensor's bit, withhold or refuse a service's answers, hold a parcel where it is.

``run_cell(plant, logic, until)`` is the scan loop the node would run: advance
the plant one scan period, hand the logic its input image, carry out the
commands; it returns everything the logic said.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from sorter_sim.model.packml import Conditions, PackMLMachine
from sorter_control.logic import (
    Command,
    ControllerConfig,
    DiverterState,
    Edge,
    InputImage,
    Reply,
    SorterLogic,
)


@dataclass
class StubParcel:
    id: int
    label: str | None
    A: float
    B: float
    x: float  # centre of gravity [m]
    y: float = 0.0
    held: bool = False
    jammed: bool = False
    exit: str | None = None
    t_exit: float | None = None
    gone: bool = False  # on a chute: slid past the entry line
    vx: float = 0.0
    vy: float = 0.0
    scanned: bool = False
    path: list = field(default_factory=list)


class PlantStub:
    """Kinematic belt + pop-up diverter + sensors; times in seconds of its own clock."""

    def __init__(
        self,
        config: ControllerConfig,
        *,
        dt: float = 0.0005,
        service_timeout: float = 0.2,
        end_x: float | None = None,
    ):
        cell = config.cell
        self.v = config.belt_speed
        self.w = cell.belt_width
        self.b = cell.disk_field_length
        self.opening = cell.opening
        self.eyes = dict(config.photo_eyes)
        self.scan_eye = config.scan_eye
        self.chutes = dict(config.chute_sensors)  # side -> sensor
        self.stroke_time = config.popup_stroke_time
        self.slew_rate = config.alpha_slew_rate_deg_s
        self.dt = dt
        self.service_timeout = service_timeout
        self.end_x = end_x if end_x is not None else self.b + 1.5
        self.t = 0.0
        self.parcels: list[StubParcel] = []
        self.stroke = 0.0
        self.stroke_target = 0.0
        self.alpha_deg = 0.0
        self.alpha_target = 0.0
        self.estop = False
        # the cell's PackML state machine, when this plant reports one (None: it does not,
        # as a cell before PackML; the controller then sorts regardless)
        self.packml: PackMLMachine | None = None
        self.watchdog: bool | None = None  # the cell's watchdog bit as reported (None: not)
        self.forced: dict[str, bool] = {}
        self.withheld: set[str] = set()
        self.refused: dict[str, str] = {}
        self.pending: list[tuple[float, Reply]] = []
        self.calls: list[tuple[float, str, object]] = []
        self.edges: list[Edge] = []
        self.labels: list[tuple[float, str]] = []
        self.collisions = 0
        self._next_id = 0
        self._bits = self._sense()
        self.stroke_at_entry: dict[int, float] = {}

    # --- set-up ---------------------------------------------------------------------------
    def add_parcel(
        self, label: str | None, A: float, lead_x: float, B: float = 0.3, y: float = 0.0
    ) -> StubParcel:
        """
        Put a parcel on the belt.

        Parameters
        ----------
        label : str
            Its label.
        A : float
            A parcel's length [m].
        lead_x : float
            Its leading edge's x [m].
        B : float
            Its width [m].
        y : float
            Its lateral offset [m].

        Returns
        -------
        StubParcel
            The parcel.

        """
        self._next_id += 1
        p = StubParcel(self._next_id, label, A, B, lead_x - 0.5 * A, y)
        self.parcels.append(p)
        return p

    def add_stream(
        self, items, first_lead_x: float | None = None, B: float = 0.3
    ) -> list[StubParcel]:
        """
        items: (label, A, gap before it [m]); placed upstream of the scanner, nose to tail.

        Parameters
        ----------
        items : list of (str, float, float)
            (label, A, gap before it [m]) each.
        first_lead_x : float
            The first parcel's leading edge [m].
        B : float
            Its width [m].

        Returns
        -------
        list of StubParcel
            The parcels.

        """
        lead = first_lead_x if first_lead_x is not None else self.eyes[self.scan_eye] - 0.05
        out = []
        for label, A, gap in items:
            lead -= gap
            out.append(self.add_parcel(label, A, lead, B))
            lead -= A
        return out

    # --- sensors ------------------------------------------------------------------------
    def _on_belt(self, p: StubParcel) -> bool:
        return p.exit is None and abs(p.y) - 0.5 * p.B < 0.5 * self.w

    def _sense(self) -> dict[str, bool]:
        bits = {}
        for name, x in self.eyes.items():
            bits[name] = any(
                self._on_belt(p) and p.x - 0.5 * p.A <= x <= p.x + 0.5 * p.A for p in self.parcels
            )
        lo, hi = self.opening
        for side, name in self.chutes.items():
            line = 0.5 * self.w * (1 if side == "left" else -1)
            bits[name] = any(
                p.exit in (None, side)
                and not p.gone
                and p.y - 0.5 * p.B <= line <= p.y + 0.5 * p.B
                and p.x + 0.5 * p.A >= lo
                and p.x - 0.5 * p.A <= hi
                for p in self.parcels
            )
        for name, value in self.forced.items():
            bits[name] = value
        return bits

    def force(self, sensor: str, value: bool | None) -> None:
        """
        Force a sensor's bit (None releases it).

        Parameters
        ----------
        sensor : str
            The sensor.
        value : bool or None
            The bit, or None to release it.

        """
        if value is None:
            self.forced.pop(sensor, None)
        else:
            self.forced[sensor] = bool(value)

    # --- physics -------------------------------------------------------------------------
    def _step(self) -> None:
        dt = self.dt
        rate = dt / self.stroke_time
        self.stroke = (
            min(self.stroke_target, self.stroke + rate)
            if self.stroke_target > self.stroke
            else max(self.stroke_target, self.stroke - rate)
        )
        d = self.slew_rate * dt
        self.alpha_deg = (
            min(self.alpha_target, self.alpha_deg + d)
            if self.alpha_target > self.alpha_deg
            else max(self.alpha_target, self.alpha_deg - d)
        )
        if not self.estop:
            a = math.radians(self.alpha_deg)
            for p in self.parcels:
                if p.exit in ("left", "right") and not p.gone:
                    # on a chute: slides off at the velocity it left with
                    p.x += p.vx * dt
                    p.y += p.vy * dt
                    p.gone = abs(p.y) - 0.5 * p.B > 0.5 * self.w
                    continue
                if p.exit is not None or p.held or p.jammed:
                    continue
                lead_before = p.x + 0.5 * p.A
                if self.stroke >= 0.5 and 0.0 <= p.x <= self.b:
                    p.vx, p.vy = self.v * math.cos(a), self.v * math.sin(a)
                else:
                    p.vx, p.vy = self.v, 0.0
                p.x += p.vx * dt
                p.y += p.vy * dt
                if lead_before < 0.0 <= p.x + 0.5 * p.A:
                    self.stroke_at_entry[p.id] = self.stroke
                if lead_before < self.eyes[self.scan_eye] <= p.x + 0.5 * p.A and not p.scanned:
                    p.scanned = True
                    if p.label is not None:
                        self.labels.append((self.t + dt, p.label))
                if abs(p.y) >= 0.5 * self.w:
                    p.exit, p.t_exit = ("left" if p.y > 0 else "right"), self.t + dt
                elif p.x - 0.5 * p.A > self.end_x:
                    p.exit, p.t_exit = "straight", self.t + dt
            live = [p for p in self.parcels if p.exit is None]
            for i, p in enumerate(live):
                for q in live[i + 1 :]:
                    if (
                        abs(p.x - q.x) < 0.5 * (p.A + q.A)
                        and abs(p.y - q.y) < 0.5 * (p.B + q.B)
                        and not (p.jammed and q.jammed)
                    ):
                        p.jammed = q.jammed = True
                        self.collisions += 1
        self.t += dt
        for p in self.parcels:
            if p.exit is None:
                p.path.append((self.t, p.x, p.y))
        bits = self._sense()
        for name, value in bits.items():
            if value != self._bits[name] and name not in self.forced:
                self.edges.append(Edge(name, self.t, value))
        self._bits = bits

    def advance(self, seconds: float) -> None:
        """
        Advance the plant.

        Parameters
        ----------
        seconds : float
            The time [s].

        """
        n = max(1, int(round(seconds / self.dt)))
        for _ in range(n):
            self._step()

    # --- the controller's view ---------------------------------------------------------------
    def image(self) -> InputImage:
        replies = [r for t, r in self.pending if t <= self.t + 1e-12]
        self.pending = [(t, r) for t, r in self.pending if t > self.t + 1e-12]
        img = InputImage(
            t=self.t,
            bits=dict(self._bits),
            edges=self.edges,
            labels=self.labels,
            diverter=DiverterState(math.radians(self.alpha_deg), self.stroke),
            replies=replies,
            cell_estop=self.estop,
            cell_watchdog=self.watchdog,
            cell_packml=None if self.packml is None else self.packml.state,
        )
        self.edges, self.labels = [], []
        return img

    def handle(self, cmd: Command) -> None:
        """
        Serve a command as the simulation node's services would (answered by the next scan).

        Parameters
        ----------
        cmd : Command
            A service call of the controller.

        """
        self.calls.append((self.t, cmd.kind, cmd.value))
        if cmd.kind in self.withheld:
            self.pending.append(
                (self.t + self.service_timeout, Reply(cmd.id, False, "", timed_out=True))
            )
            return
        ok, msg = True, ""
        if cmd.kind in self.refused:
            self.pending.append((self.t, Reply(cmd.id, False, self.refused[cmd.kind])))
            return
        if cmd.kind == "popup":
            if self.estop:
                ok, msg = False, "e-stop active: use reset"
            else:
                self.stroke_target = 1.0 if cmd.value else 0.0
        elif cmd.kind == "alpha":
            if self.estop:
                ok, msg = False, "e-stop active: use reset"
            elif not (isinstance(cmd.value, (int, float)) and -90.0 <= cmd.value <= 90.0):
                ok, msg = False, f"alpha_deg must be in [-90, 90], got {cmd.value!r}"
            else:
                self.alpha_target = float(cmd.value)
        elif cmd.kind == "estop":
            self.estop = True
            self.stroke_target = 0.0
        elif cmd.kind == "reset":
            self.estop = False
            for p in self.parcels:
                p.jammed = False
        elif cmd.kind == "packml":
            if self.packml is None:
                ok, msg = False, "this plant has no PackML state"
            else:
                ok, msg = self.packml.command(cmd.value, round(self.t * 1e9))
                self.packml.update(Conditions(), round(self.t * 1e9))
        self.pending.append((self.t, Reply(cmd.id, ok, msg)))

    def outcomes(self) -> dict[int, str | None]:
        return {p.id: ("jammed" if p.jammed else p.exit) for p in self.parcels}


@dataclass
class CellRun:
    confirmations: list = field(default_factory=list)
    commands: list = field(default_factory=list)
    log: list = field(default_factory=list)
    states: list = field(default_factory=list)  # (t, state) on every change


def run_cell(
    plant: PlantStub, logic: SorterLogic, until: float, run: CellRun | None = None, on_scan=None
) -> CellRun:
    """
    Scan the logic against the plant until plant time ``until``; returns (and extends) ``run``.

    on_scan(plant, logic), if given, runs after every scan (to watch, or to make trouble).

    Parameters
    ----------
    plant : PlantStub
        The plant.
    logic : SorterLogic
        The PLC program.
    until : float
        The plant time to run to [s].
    run : CellRun, optional
        A run to extend.
    on_scan : callable, optional
        Called after every scan.

    Returns
    -------
    CellRun
        The run.

    """
    run = run or CellRun()
    period = logic.config.scan_period
    while plant.t < until - 1e-9:
        plant.advance(period)
        img = plant.image()
        out = logic.scan(img)
        if on_scan is not None:
            on_scan(plant, logic)
        for cmd in out.commands:
            plant.handle(cmd)
        run.commands.extend((plant.t, c.kind, c.value) for c in out.commands)
        run.confirmations.extend(out.confirmations)
        run.log.extend((plant.t, lvl, text) for lvl, text in out.log)
        if not run.states or run.states[-1][1] != logic.state:
            run.states.append((plant.t, logic.state))
    return run
