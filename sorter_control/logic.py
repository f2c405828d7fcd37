"""
The sorter PLC: scan cycle, tracking, routing, divert timing and faults, with no ROS.

``SorterLogic.scan(image)`` is one PLC scan. The input image holds what a PLC
reads once per scan: the latest bit of every presence sensor, the time-stamped
edges a fast input card latched since the last scan, scanner labels, the
diverter's reported state, service replies and routing updates. Edges are
detected against the previous scan's bits; a latched time stamp, when one
matches, replaces the scan time (exact to the physics), and a pulse shorter
than a scan still counts when the latched edges show it. The scan returns the
service calls to make (pop-up raise/lower, disk angle, e-stop, reset), the sort
confirmations and log lines; it never waits for anything.

Tracking: a parcel is born at the scanner photo-eye (``scan_eye``), which also
measures its length (blocked time x belt speed), gets its label from the
scanner, and is then followed by encoder distance (belt speed x time while the
belt runs). Every other photo-eye is a checkpoint with a transit window: the
parcel must block it within ``tracking_tolerance`` of the distance tracking
predicts (else the eye is "stuck off"), and re-synchronises the tracking when it
does. The eye just upstream of the disk field is ``divert_eye``.

Decisions are taken as late as the actuators allow (so a routing update that
arrives after the scan still counts): the destination comes from the routing
table (exact label, longest prefix, default; unknown labels and no-reads go to
the reject destination), and the divert is checked against its neighbours with
``timing.GapModel``: if the gap to the parcel ahead, or to the one behind, is too
short for the disks to serve both, the parcel is sent straight and flagged
rather than mis-sorted. The disks go up so that the stroke ends as the leading
edge reaches the field (stroke time, one scan period and the service latency
ahead), and down only after the model core's predicted commit time t_commit.

Faults (each a state of its own, a diagnostic, and no diverts until
``request_reset``): ``jam`` (an eye blocked by a tracked parcel longer than the
parcel explains), ``stuck_on`` (an eye blocked with no parcel due), ``stuck_off``
(a parcel's transit window passed with the eye clear; a scanner label with no
blocking), ``missed_divert`` (no chute sensor in time), ``diverter_timeout`` (a
service call unanswered: not retried, so nothing can actuate twice),
``diverter_refused`` and ``estop``. A reset clears tracking: parcels already on
the belt are let through straight ("flush") until the belt has carried them out.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from .timing import (
    DESTINATIONS,
    Actuators,
    CellModel,
    DivertPredictor,
    GapModel,
    Prediction,
    side_of,
)

STATES = (
    "running",
    "jam",
    "stuck_on",
    "stuck_off",
    "missed_divert",
    "diverter_timeout",
    "diverter_refused",
    "estop",
    "resetting",
)
FAULT_STATES = STATES[1:8]

# results in sort confirmations
R_SORTED = "sorted"  # reached what the routing asked for
R_REJECTED = "rejected"  # unknown label or no read: sent to the reject destination
R_GAP = "gap_too_short"  # a divert refused for spacing: sent straight
R_CANNOT = "cannot_divert"  # the model says the disks cannot bring it to the chute
R_LATE = "late"  # length not known in time to act: sent straight
R_FAULT = "fault"  # the controller was in a fault state: sent straight
R_MISSORT = "mis-sorted"  # reached somewhere else than planned
R_MISSED = "missed"  # planned divert, no chute sensor in time
R_ABORTED = "aborted"  # tracking dropped (e-stop or reset) before the outcome


class RoutingError(ValueError):
    """A routing rule or destination that is not allowed."""


class RoutingTable:
    """
    Destination per label: exact labels, prefixes (``ABC*``, longest wins), a default.

    Labels that match nothing (with no default) and missing reads go to the
    reject destination. Rules are ``pattern=destination`` strings; a pattern
    ending in ``*`` is a prefix, ``*`` alone is the default. Destinations are
    ``left``, ``right`` or ``straight``.
    """

    def __init__(self, rules=(), default: str = "", reject: str = "straight"):
        self.exact: dict[str, str] = {}
        self.prefixes: dict[str, str] = {}
        self.default = self._dest(default, "routing default", allow_empty=True) or None
        self.reject = self._dest(reject, "reject destination")
        for rule in rules:
            pattern, dest = self.parse_rule(rule)
            self.set(pattern, dest)

    @staticmethod
    def _dest(dest, what, allow_empty=False) -> str:
        if not isinstance(dest, str):
            raise RoutingError(
                f"{what} must be a string, one of {', '.join(DESTINATIONS)}; got {dest!r}"
            )
        dest = dest.strip()
        if dest == "" and allow_empty:
            return ""
        if dest not in DESTINATIONS:
            allowed = ", ".join(DESTINATIONS) + (" or empty" if allow_empty else "")
            raise RoutingError(f"{what} must be one of {allowed}; got {dest!r}")
        return dest

    @staticmethod
    def parse_rule(rule) -> tuple[str, str]:
        if not isinstance(rule, str) or "=" not in rule:
            raise RoutingError(
                f"routing rule {rule!r}: expected 'label=destination' or 'prefix*=destination'"
            )
        pattern, _, dest = rule.rpartition("=")
        return pattern.strip(), dest.strip()

    def set(self, pattern: str, destination: str) -> str:
        """Add, change or (destination '') remove a rule; returns what was done."""
        if not isinstance(pattern, str) or pattern.strip() == "":
            raise RoutingError(
                f"routing pattern must be a non-empty label, 'prefix*' or '*'; got {pattern!r}"
            )
        pattern = pattern.strip()
        if "*" in pattern[:-1]:
            raise RoutingError(
                f"routing pattern {pattern!r}: '*' is allowed only at the end (a prefix)"
            )
        dest = self._dest(destination, f"destination for {pattern!r}", allow_empty=True)
        if pattern == "*":
            self.default = dest or None
            return f"default -> {dest or '(none: reject)'}"
        table, key = (
            (self.prefixes, pattern[:-1]) if pattern.endswith("*") else (self.exact, pattern)
        )
        if dest == "":
            table.pop(key, None)
            return f"{pattern} removed"
        table[key] = dest
        return f"{pattern} -> {dest}"

    def lookup(self, label: str | None) -> tuple[str, str]:
        """(destination, how) with how in exact | prefix | default | unknown | no_read."""
        if label is None or label == "":
            return self.reject, "no_read"
        if label in self.exact:
            return self.exact[label], "exact"
        best = None
        for prefix, dest in self.prefixes.items():
            if label.startswith(prefix) and (best is None or len(prefix) > len(best[0])):
                best = (prefix, dest)
        if best is not None:
            return best[1], "prefix"
        if self.default is not None:
            return self.default, "default"
        return self.reject, "unknown"

    def rules(self) -> list[str]:
        out = [f"{k}={v}" for k, v in sorted(self.exact.items())]
        out += [f"{k}*={v}" for k, v in sorted(self.prefixes.items())]
        if self.default:
            out.append(f"*={self.default}")
        return out


@dataclass(frozen=True)
class ControllerConfig:
    """
    Everything the PLC is configured with (SI units; angles in degrees).

    Photo-eyes: ``photo_eyes`` maps names to x [m] in the conveyor frame (origin on
    the upstream edge of the disk field); ``scan_eye`` is at the scanner line and
    ``divert_eye`` just upstream of the disk field. ``chute_sensors`` maps a side
    (left/right) to its sensor name.
    """

    scan_period: float = 0.01
    belt_speed: float = 1.5
    photo_eyes: tuple = (("pe_scan", -2.0), ("pe_divert", -0.3), ("pe_exit", 2.0))
    scan_eye: str = "pe_scan"
    divert_eye: str = "pe_divert"
    chute_sensors: tuple = (("left", "chute_left"), ("right", "chute_right"))
    divert_alpha_deg: float = 90.0
    popup_stroke_time: float = 0.1
    alpha_slew_rate_deg_s: float = 360.0
    service_latency: float = 0.005
    timing_margin: float = 0.02
    routing_rules: tuple = ()
    routing_default: str = ""
    reject_destination: str = "straight"
    tracking_tolerance: float = 0.05
    label_window: float = 0.1
    jam_margin: float = 0.5
    max_parcel_length: float = 1.2
    missed_divert_margin: float = 0.3
    clearance: float = 0.02
    estop_on_jam: bool = True
    open_chains: bool = False
    cell: CellModel = field(default_factory=CellModel)

    def __post_init__(self):
        def positive(name):
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not math.isfinite(v)
                or v <= 0
            ):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")

        for name in (
            "scan_period",
            "belt_speed",
            "popup_stroke_time",
            "alpha_slew_rate_deg_s",
            "tracking_tolerance",
            "label_window",
            "jam_margin",
            "max_parcel_length",
            "missed_divert_margin",
        ):
            positive(name)
        for name in ("service_latency", "clearance", "timing_margin"):
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not math.isfinite(v)
                or v < 0
            ):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if not (0 < abs(self.divert_alpha_deg) <= 90):
            raise ValueError(f"divert_alpha_deg must be in (0, 90], got {self.divert_alpha_deg!r}")
        eyes = dict(self.photo_eyes)
        if len(eyes) != len(self.photo_eyes):
            raise ValueError(f"photo_eyes: names must be unique, got {list(self.photo_eyes)}")
        for name, x in eyes.items():
            if not isinstance(name, str) or not name or not math.isfinite(x):
                raise ValueError(
                    f"photo_eyes: each needs a name and a finite x, got {name!r}: {x!r}"
                )
        for name in (self.scan_eye, self.divert_eye):
            if name not in eyes:
                raise ValueError(f"photo-eye {name!r} is not among photo_eyes {sorted(eyes)}")
        if not eyes[self.scan_eye] < eyes[self.divert_eye] <= 0.0:
            raise ValueError(
                f"photo-eyes must sit scanner < divert eye <= 0 (the disk field's upstream "
                f"edge); got {self.scan_eye} at {eyes[self.scan_eye]} m, "
                f"{self.divert_eye} at {eyes[self.divert_eye]} m"
            )
        chutes = dict(self.chute_sensors)
        if set(chutes) - {"left", "right"}:
            raise ValueError(f"chute_sensors: sides must be left/right, got {sorted(chutes)}")
        # the routing rules must parse
        RoutingTable(self.routing_rules, self.routing_default, self.reject_destination)

    @property
    def eyes(self) -> dict[str, float]:
        return dict(self.photo_eyes)

    @property
    def chutes(self) -> dict[str, str]:
        return dict(self.chute_sensors)

    def actuators(self) -> Actuators:
        return Actuators(
            self.popup_stroke_time,
            self.alpha_slew_rate_deg_s,
            self.scan_period,
            self.service_latency,
            self.timing_margin,
        )


# ----------------------------------------------------------------------------- input image


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
    cell_status_t: float | None = None  # the report's time stamp [s]


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


# ----------------------------------------------------------------------------- tracking


@dataclass
class Tracked:
    """One parcel followed along the belt."""

    seq: int
    enc_rise: float  # encoder reading when the leading edge was at the scanner line
    t_scan: float
    label: str | None = None
    length: float | None = None
    asked: str | None = None  # destination the routing gave at decision time
    how: str | None = None
    plan: str | None = None  # where the controller sends it
    result: str | None = None  # flag set at decision time (None: normal)
    committed: bool = False
    bound: str | None = None  # destination fixed early by the parcel ahead (disks kept up)
    prediction: Prediction | None = None
    alpha: float | None = None
    confirmed: dict = field(default_factory=dict)  # eye -> t of its rising edge
    cleared: dict = field(default_factory=dict)  # eye -> t of its falling edge
    reached: str | None = None
    done: bool = False


@dataclass
class EyeState:
    blocked: bool | None = None
    since: float = 0.0
    by: int | None = None  # seq of the tracked parcel blocking it
    unexpected: bool = False
    labels_while_blocked: int = 0
    cleared_at: float | None = None  # time of the last falling edge


class SorterLogic:
    """The PLC program. Feed it one ``InputImage`` per scan; act on what ``scan`` returns."""

    def __init__(self, config: ControllerConfig, predictor: DivertPredictor | None = None):
        self.config = config
        self.routing = RoutingTable(
            config.routing_rules, config.routing_default, config.reject_destination
        )
        self.predictor = predictor or DivertPredictor(config.cell)
        self.gaps = GapModel(
            self.predictor,
            config.actuators(),
            divert_alpha_deg=abs(config.divert_alpha_deg),
            clearance=config.clearance,
        )
        self.eye_x = config.eyes
        self.x_scan = self.eye_x[config.scan_eye]
        self.chute_of = config.chutes  # side -> sensor
        self.side_of_sensor = {s: side for side, s in self.chute_of.items()}
        self.sensors = list(self.eye_x) + list(self.side_of_sensor)
        self.state = "running"
        self.fault: dict | None = None
        self.t: float | None = None
        self.encoder = 0.0
        self.belt_running = True
        self.bits: dict[str, bool | None] = {s: None for s in self.sensors}
        self.eyes = {s: EyeState() for s in self.sensors}
        self.parcels: list[Tracked] = []
        self.last_decided: Tracked | None = None
        self.pending_labels: deque = deque()
        self.seq = 0
        self.flush_until: float = self.flush_distance()  # encoder reading
        self.cmd_id = 0
        self.in_flight: dict[int, Command] = {}
        self.commanded_up: bool | None = None
        self.commanded_alpha: float | None = None
        self.alpha_ready_at: float | None = None  # when the commanded angle should be reached [s]
        self.diverter_silent = False  # a diverter call timed out (until reset)
        self.reset_t = -math.inf  # when the last reset cleared a fault [s]
        self.diverter: DiverterState | None = None
        self._reset_requested = False
        self._estop_requested = False
        self.counts = {
            "inducted": 0,
            "left": 0,
            "right": 0,
            "straight": 0,
            "rejected": 0,
            "no_read": 0,
            "gap_too_short": 0,
            "cannot_divert": 0,
            "late": 0,
            "mis_sorted": 0,
            "missed": 0,
            "aborted": 0,
            "untracked": 0,
            "unexpected_chute": 0,
            "labels_without_parcel": 0,
            "scans": 0,
            "overruns": 0,
            "late_scans": 0,
            "routing_updates": 0,
            "routing_rejected": 0,
            "commands": 0,
            "replies": 0,
            "timeouts": 0,
        }
        self.fault_counts = {k: 0 for k in FAULT_STATES}
        self.scan_wall: deque = deque(maxlen=1000)
        self.log_history: deque = deque(maxlen=50)

    # --- configuration facts --------------------------------------------------------------
    @property
    def v(self) -> float:
        return self.config.belt_speed

    def flush_distance(self) -> float:
        """Return the encoder travel after which nothing untracked is left before the field end."""
        return (
            self.encoder
            + (self.config.cell.disk_field_length - self.x_scan)
            + self.config.max_parcel_length
            + self.config.tracking_tolerance
        )

    def warm_lengths(self, lo: float, hi: float) -> list[float]:
        """Return the prediction grid's lengths in [lo, hi] m."""
        step = self.predictor.cell.length_step
        n = int(math.floor((hi - lo) / step + 1e-9)) + 1
        return [lo + i * step for i in range(max(n, 1))]

    def warm_up(self, lengths) -> None:
        """Predict ahead for these lengths [m] (outside the scan), so scans find them ready."""
        self.gaps.warm(lengths, self.v)

    def min_gap(self, length: float) -> dict:
        """Return the least gap [m] for parcels of ``length`` m at the configured belt speed."""
        return self.gaps.min_gap(length, self.v)

    def lookahead_ok(self, length: float) -> bool:
        """Whether the scanner sits far enough upstream to see the follower before a decision."""
        lead = self.gaps.act.stroke_total + self.config.scan_period
        distance = -self.x_scan - self.v * lead
        need = length + self.min_gap(length)["worst"]
        return distance >= need

    # --- operator requests -----------------------------------------------------------------
    def request_reset(self) -> str:
        self._reset_requested = True
        return f"reset requested in state {self.state}"

    def request_estop(self) -> str:
        self._estop_requested = True
        return "e-stop requested"

    def record_scan_wall(self, seconds: float) -> None:
        """
        Record how long a scan took in wall time, as the node measured it.

        Longer than a period is an overrun.
        """
        self.scan_wall.append(seconds)
        if seconds > self.config.scan_period:
            self.counts["overruns"] += 1

    def update_route(self, pattern: str, destination: str) -> str:
        """
        Return a routing change from a warehouse controller.

        Raises RoutingError if not allowed.
        """
        done = self.routing.set(pattern, destination)
        self.counts["routing_updates"] += 1
        return done

    # --- helpers ----------------------------------------------------------------------------
    def _log(self, out: ScanOutput, level: str, text: str) -> None:
        out.log.append((level, text))
        self.log_history.append((self.t, level, text))

    def _command(self, out: ScanOutput, kind: str, value) -> Command:
        self.cmd_id += 1
        cmd = Command(self.cmd_id, kind, value, self.t)
        self.in_flight[cmd.id] = cmd
        out.commands.append(cmd)
        self.counts["commands"] += 1
        return cmd

    def _busy(self, kind: str) -> bool:
        return any(c.kind == kind for c in self.in_flight.values())

    def _enc_at(self, t: float) -> float:
        """Return the encoder reading at an edge time inside (or just before) the current scan."""
        if not self.belt_running:
            return self.encoder
        return self.encoder - self.v * (self.t - t)

    def lead_x(self, p: Tracked, enc: float | None = None) -> float:
        """Position of the parcel's leading edge [m, conveyor frame]."""
        return self.x_scan + ((self.encoder if enc is None else enc) - p.enc_rise)

    def t_enter(self, p: Tracked) -> float:
        """When the leading edge reaches (reached) the disk field, x = 0 [s]."""
        return self.t + (0.0 - self.lead_x(p)) / self.v

    def _enter_fault(
        self, out: ScanOutput, kind: str, message: str, sensor: str | None = None
    ) -> None:
        if self.state in FAULT_STATES or self.state == "resetting":
            # the first fault defines the state; later ones are logged
            self._log(out, "error", f"{kind}: {message} (while in {self.state})")
            return
        self.state = kind
        self.fault = {"kind": kind, "sensor": sensor, "message": message, "t": self.t}
        self.fault_counts[kind] += 1
        self._log(out, "error", f"{kind}: {message}; no diverts until reset")
        if kind == "jam" and self.config.estop_on_jam:
            self._command(out, "estop", True)

    def _finish(
        self, out: ScanOutput, p: Tracked, reached: str, result: str | None = None
    ) -> None:
        if p.done:
            return
        p.done = True
        p.reached = reached
        asked = p.asked if p.asked is not None else self.routing.lookup(p.label)[0]
        if result is None:
            if reached != p.plan:
                result = R_MISSORT
            elif p.result is not None:
                result = p.result
            else:
                result = R_REJECTED if p.how in ("unknown", "no_read") else R_SORTED
        if result == R_MISSORT:
            self.counts["mis_sorted"] += 1
        if reached in ("left", "right", "straight"):
            self.counts[reached] += 1
        if result == R_REJECTED:
            self.counts["rejected"] += 1
        if result == R_ABORTED:
            self.counts["aborted"] += 1
        out.confirmations.append(
            Confirmation(p.label or "", asked, reached, result, p.seq, self.t)
        )

    def _drop_tracking(self, out: ScanOutput, why: str) -> None:
        for p in self.parcels:
            if not p.done:
                self._finish(out, p, "unknown", R_ABORTED)
        self.parcels = []
        self.last_decided = None
        self.pending_labels.clear()
        for e in self.eyes.values():
            e.by = None
            e.unexpected = False
        self.flush_until = self.flush_distance()
        self._log(out, "warn", f"tracking cleared ({why}); flushing the belt")

    # --- the scan ----------------------------------------------------------------------------
    def scan(self, image: InputImage) -> ScanOutput:
        out = ScanOutput()
        t = float(image.t)
        if not math.isfinite(t):
            self._log(out, "error", f"scan ignored: time {image.t!r} is not finite")
            return out
        if self.t is not None:
            dt = t - self.t
            if dt < 0:
                self._log(out, "error", f"scan ignored: time went back from {self.t} to {t} s")
                return out
            if dt > self.config.scan_period + self.config.timing_margin + 1e-9:
                # later than the timing budget absorbs: an action may have come late
                self.counts["late_scans"] += 1
            if self.belt_running:
                self.encoder += self.v * dt
        self.t = t
        self.counts["scans"] += 1

        self._apply_routing(out, image.routing_updates)
        self._apply_replies(out, image.replies)
        if image.diverter is not None:
            self.diverter = image.diverter
        self._apply_cell_status(out, image)
        self._apply_operator(out)
        for edge in self._detect_edges(image):
            self._on_edge(out, edge)
        self._apply_labels(out, image.labels)
        self._check_windows(out)
        if self.state == "running":
            self._decide(out)
        else:
            self._decide_faulted(out)
        self._write_outputs(out)
        self.parcels = [p for p in self.parcels if not self._retired(p)]
        return out

    def _retired(self, p: Tracked) -> bool:
        """Done, and no longer needed for the disk schedule or the photo-eyes."""
        if not p.done:
            return False
        if self.belt_running and p.reached == "straight" and p.plan == "straight":
            # still expected at the photo-eyes downstream of the field
            tol = self.config.tracking_tolerance + self.v * self.config.scan_period
            if any(
                x > 0.0 and name not in p.confirmed and self.lead_x(p) <= x + tol
                for name, x in self.eye_x.items()
            ):
                return False
        if side_of(p.plan or "straight") != 0 and p.prediction is not None and p.reached == p.plan:
            if self.belt_running and self.t < self.t_enter(p) + p.prediction.t_commit:
                return False
        return all(e.by != p.seq for e in self.eyes.values())

    # --- inputs -------------------------------------------------------------------------------
    def _apply_routing(self, out, updates) -> None:
        for item in updates:
            try:
                pattern, dest = item
                done = self.update_route(pattern, dest)
            except (RoutingError, TypeError, ValueError) as exc:
                self.counts["routing_rejected"] += 1
                self._log(out, "warn", f"routing update {item!r} rejected: {exc}")
            else:
                self._log(out, "info", f"routing update: {done}")

    def _apply_replies(self, out, replies) -> None:
        for r in replies:
            cmd = self.in_flight.pop(r.command_id, None)
            if cmd is None:
                continue
            self.counts["replies"] += 1
            what = f"{cmd.kind} {cmd.value!r}"
            if r.timed_out:
                self.counts["timeouts"] += 1
                if cmd.kind in ("popup", "alpha"):
                    # not retried: a late answer could still be acted on, and a second call
                    # would actuate twice; the diverter's state is unknown until reset
                    self.commanded_up = None if cmd.kind == "popup" else self.commanded_up
                    self.commanded_alpha = None if cmd.kind == "alpha" else self.commanded_alpha
                    self.diverter_silent = True
                    self._enter_fault(
                        out,
                        "diverter_timeout",
                        f"{what}: no answer from the cell in time; not retried",
                    )
                elif cmd.kind == "reset":
                    self._restore_fault_state(out, "reset: no answer from the cell in time")
                else:
                    self._log(out, "error", f"{what}: no answer from the cell in time")
                continue
            if r.accepted:
                if cmd.kind == "reset":
                    self._cleared(out)
                elif cmd.kind == "estop":
                    self.belt_running = False
                continue
            reason = r.message or "no reason given"
            if cmd.kind == "reset":
                self._restore_fault_state(out, f"reset refused by the cell: {reason}")
            elif any(w in reason.lower() for w in ("e-stop", "estop", "emergency")):
                self._enter_estop(out, f"{what} refused: {reason}")
            elif cmd.kind in ("popup", "alpha"):
                if cmd.kind == "popup":
                    self.commanded_up = None
                else:
                    self.commanded_alpha = None
                self._enter_fault(out, "diverter_refused", f"{what} refused by the cell: {reason}")
            else:
                self._log(out, "error", f"{what} refused by the cell: {reason}")

    def _restore_fault_state(self, out, message) -> None:
        if self.fault is not None:
            self.state = self.fault["kind"]
        self._log(out, "error", message)

    def _enter_estop(self, out, message) -> None:
        if self.state == "estop":
            return
        if self.state in FAULT_STATES:
            self._log(out, "error", f"e-stop while in {self.state}: {message}")
        self.state = "estop"
        self.fault = {"kind": "estop", "sensor": None, "message": message, "t": self.t}
        self.fault_counts["estop"] += 1
        self.belt_running = False
        self.commanded_up = False  # the cell drops the disks on e-stop
        self._log(out, "error", f"estop: {message}; no diverts until reset")
        self._drop_tracking(out, "e-stop")

    def _apply_cell_status(self, out, image: InputImage) -> None:
        if image.cell_status_t is not None and image.cell_status_t < self.reset_t:
            return  # reported before the last reset: stale
        if image.cell_estop:
            # a jam the controller stopped the belt for stays a jam; anything else becomes an
            # e-stop
            self.belt_running = False
            if self.state not in ("estop", "resetting", "jam"):
                self._enter_estop(out, "the cell reports an e-stop")
        if image.cell_jam and self.state == "running":
            self._enter_fault(out, "jam", "the cell reports a jam")

    def _apply_operator(self, out) -> None:
        if self._estop_requested:
            self._estop_requested = False
            self._command(out, "estop", True)
            self._enter_estop(out, "requested by the operator")
        if self._reset_requested:
            self._reset_requested = False
            if self.state == "running":
                self._log(out, "info", "reset: nothing to clear")
            elif self.state == "resetting":
                self._log(out, "info", "reset already under way")
            elif self.state in ("estop", "jam") and not self._busy("reset"):
                # the cell holds these faults too (belt stopped): it must reset first
                self.state = "resetting"
                self._command(out, "reset", None)
                self._log(out, "info", "reset: asking the cell to reset")
            else:
                self._cleared(out)

    def _cleared(self, out) -> None:
        was = self.fault["kind"] if self.fault else self.state
        self.state = "running"
        self.fault = None
        self.belt_running = True
        if was in ("diverter_timeout", "diverter_refused") or self.diverter_silent:
            # the operator has looked at the diverter: its state is unknown, so write it afresh
            self.commanded_up = None
            self.commanded_alpha = None
        self.diverter_silent = False
        self.reset_t = self.t
        self._drop_tracking(out, f"reset after {was}")
        for name, e in self.eyes.items():
            e.since = self.t
            e.unexpected = bool(e.blocked)
        self._log(out, "info", f"reset: {was} cleared, running")

    def _detect_edges(self, image: InputImage) -> list[Edge]:
        """Edges of this scan in time order: bit changes, timed by the latched edges."""
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
        for s in self.sensors:
            prev = self.bits[s]
            cur = image.bits.get(s, prev)
            if cur is None:
                continue
            cur = bool(cur)
            marks = sorted(stamped.get(s, ()), key=lambda e: e.t)
            if prev is None:
                self.bits[s] = cur
                self.eyes[s].blocked = cur
                self.eyes[s].since = self.t
                self.eyes[s].unexpected = cur
                continue
            alternating = (
                bool(marks)
                and marks[0].rising != prev
                and marks[-1].rising == cur
                and all(a.rising != b.rising for a, b in zip(marks, marks[1:]))
            )
            if alternating:
                found.extend(Edge(s, min(e.t, self.t), e.rising) for e in marks)
            elif cur != prev:
                match = [e for e in marks if e.rising == cur]
                found.append(Edge(s, min(match[-1].t, self.t) if match else self.t, cur))
            self.bits[s] = cur
        found.sort(key=lambda e: e.t)
        return found

    # --- tracking --------------------------------------------------------------------------------
    def _on_edge(self, out, edge: Edge) -> None:
        s = edge.sensor
        eye = self.eyes[s]
        eye.blocked = edge.rising
        eye.since = edge.t
        if not edge.rising:
            eye.cleared_at = edge.t
        if s in self.side_of_sensor:
            eye.unexpected = False
            if edge.rising:
                self._on_chute(out, self.side_of_sensor[s], edge.t)
            return
        if s == self.config.scan_eye:
            self._on_scan_eye(out, edge)
            return
        if edge.rising:
            p = self._expected_at(s, edge.t)
            if p is None:
                eye.by = None
                eye.unexpected = True
                if self.encoder < self.flush_until:
                    self.counts["untracked"] += 1
                else:
                    self._log(out, "warn", f"{s}: blocked at {edge.t:.3f} s with no parcel due")
                return
            eye.by = p.seq
            eye.unexpected = False
            p.confirmed[s] = edge.t
            # re-synchronise: the leading edge is exactly at the eye now
            p.enc_rise = self._enc_at(edge.t) - (self.eye_x[s] - self.x_scan)
        else:
            p = self._by_seq(eye.by)
            if p is not None:
                p.cleared[s] = edge.t
            eye.by = None
            eye.unexpected = False

    def _on_scan_eye(self, out, edge: Edge) -> None:
        eye = self.eyes[self.config.scan_eye]
        if edge.rising:
            self.seq += 1
            p = Tracked(self.seq, self._enc_at(edge.t), edge.t)
            self.parcels.append(p)
            self.counts["inducted"] += 1
            eye.by = p.seq
            eye.unexpected = False
            eye.labels_while_blocked = 0
            # a label read just before the photo-eye latched belongs to this parcel
            while self.pending_labels:
                t_l, label = self.pending_labels[0]
                self.pending_labels.popleft()
                if abs(t_l - edge.t) <= self.config.label_window:
                    p.label = label
                    break
                self.counts["labels_without_parcel"] += 1
        else:
            p = self._by_seq(eye.by)
            if p is not None and p.length is None:
                p.length = self.v * (edge.t - p.t_scan) if self.belt_running else None
            eye.by = None

    def _apply_labels(self, out, labels) -> None:
        for item in labels:
            try:
                t_l, label = item
                t_l = float(t_l)
            except (TypeError, ValueError):
                continue
            if not isinstance(label, str) or not math.isfinite(t_l):
                continue
            eye = self.eyes[self.config.scan_eye]
            if eye.blocked:
                eye.labels_while_blocked += 1
            target = None
            for p in reversed(self.parcels):
                if p.label is None and abs(t_l - p.t_scan) <= self.config.label_window:
                    target = p
                    break
            if target is not None:
                target.label = label
            else:
                self.pending_labels.append((t_l, label))
        # labels that found no photo-eye edge within the window: the eye on the scanner's line
        # should have been blocked by the parcel just read (one blocking it since before the
        # controller started has no rising edge, and is not the eye's fault)
        eye = self.eyes[self.config.scan_eye]
        while (
            self.pending_labels and self.t - self.pending_labels[0][0] > self.config.label_window
        ):
            t_l, label = self.pending_labels.popleft()
            self.counts["labels_without_parcel"] += 1
            seen = eye.blocked or (
                eye.cleared_at is not None and eye.cleared_at >= t_l - self.config.label_window
            )
            if self.state == "running" and not seen:
                self._enter_fault(
                    out,
                    "stuck_off",
                    f"{self.config.scan_eye}: the scanner read {label!r} at "
                    f"{t_l:.3f} s but the photo-eye never blocked",
                    self.config.scan_eye,
                )

    def _by_seq(self, seq) -> Tracked | None:
        if seq is None:
            return None
        for p in self.parcels:
            if p.seq == seq:
                return p
        return None

    def _checkpoint(self, p: Tracked, eye: str) -> bool:
        """Return whether the parcel should pass this photo-eye (diverted ones miss later eyes)."""
        x = self.eye_x[eye]
        if eye == self.config.scan_eye:
            return False
        if x <= 0.0:
            return True
        return p.committed and side_of(p.plan) == 0

    def _expected_at(self, eye: str, t: float) -> Tracked | None:
        """Return the oldest parcel whose transit window at ``eye`` holds time t."""
        enc = self._enc_at(t)
        tol = self.config.tracking_tolerance + self.v * self.config.scan_period
        for p in self.parcels:
            if eye in p.confirmed or not self._checkpoint(p, eye):
                continue
            if abs(self.lead_x(p, enc) - self.eye_x[eye]) <= tol:
                return p
        return None

    def _on_chute(self, out, dest: str, t: float) -> None:
        side = side_of(dest)
        b = self.config.cell.disk_field_length
        tol = self.config.tracking_tolerance / self.v + self.config.scan_period
        for p in self.parcels:
            if (
                not p.done
                and p.committed
                and side_of(p.plan) == side
                and self.t_enter(p) <= t + tol
            ):
                self._finish(out, p, dest)
                return
        # a parcel that was not meant for this chute: the one over the field
        for p in self.parcels:
            if p.done or p.length is None:
                continue
            te = self.t_enter(p)
            if te - tol <= t <= te + (p.length + b) / self.v + tol:
                self._finish(out, p, dest)
                self._log(
                    out,
                    "error",
                    f"parcel {p.seq} ({p.label}) entered the {dest} chute; planned {p.plan}",
                )
                return
        self.counts["unexpected_chute"] += 1
        self._log(out, "warn", f"{self.chute_of[dest]}: a parcel entered with none tracked there")

    def _expected_clear(self, p: Tracked, eye: str, t_rise: float) -> float:
        """When a parcel that blocked ``eye`` at t_rise should clear it [s]."""
        length = p.length if p.length is not None else self.config.max_parcel_length
        t_clear = t_rise + length / self.v
        x_e = self.eye_x[eye]
        if p.committed and p.prediction is not None and x_e < 0.0 and length > -x_e:
            # its tail is still over the eye when the disks take it: it slows along x and
            # leaves sideways (Fig. 7), as the prediction tells
            rel = p.prediction.t_clear_of(
                x_e, self.config.cell.belt_width, self.config.cell.parcel_width
            )
            t_clear = max(t_clear, t_rise + (-x_e) / self.v + rel)
        return t_clear

    def _check_windows(self, out) -> None:
        cfg = self.config
        v = self.v
        tol_x = cfg.tracking_tolerance + v * cfg.scan_period
        b = cfg.cell.disk_field_length
        # photo-eyes blocked too long: jam (a parcel that should have passed) or stuck on
        for name in self.eye_x:
            eye = self.eyes[name]
            if not eye.blocked or not self.belt_running:
                continue
            held = self.t - eye.since
            p = self._by_seq(eye.by)
            if p is not None:
                limit = self._expected_clear(p, name, eye.since) - eye.since + cfg.jam_margin
                if held > limit and self.state == "running":
                    if name == cfg.scan_eye and eye.labels_while_blocked >= 2:
                        self._enter_fault(
                            out,
                            "stuck_on",
                            f"{name}: blocked for {held:.2f} s while "
                            f"{eye.labels_while_blocked} labels were read",
                            name,
                        )
                    else:
                        self._enter_fault(
                            out,
                            "jam",
                            f"{name}: blocked for {held:.2f} s by parcel "
                            f"{p.seq} ({p.label}), which should have cleared it after "
                            f"{limit - cfg.jam_margin:.2f} s",
                            name,
                        )
            else:
                limit = cfg.max_parcel_length / v + cfg.jam_margin
                if held > limit and self.state == "running":
                    self._enter_fault(
                        out,
                        "stuck_on",
                        f"{name}: blocked for {held:.2f} s with no parcel due "
                        f"(longest parcel: {cfg.max_parcel_length / v:.2f} s)",
                        name,
                    )
        for name in self.side_of_sensor:
            eye = self.eyes[name]
            if (
                eye.blocked
                and self.belt_running
                and self.t - eye.since > cfg.max_parcel_length / v + cfg.jam_margin
                and self.state == "running"
            ):
                self._enter_fault(
                    out,
                    "jam",
                    f"{name}: blocked for {self.t - eye.since:.2f} s: a parcel stuck "
                    "at the chute entry",
                    name,
                )
        if not self.belt_running:
            return
        for p in self.parcels:
            x_lead = self.lead_x(p)
            # transit windows at the checkpoints (a straight parcel is done before the eyes
            # downstream of the field see it, and still checked there)
            for name, x_e in self.eye_x.items():
                if name in p.confirmed or not self._checkpoint(p, name):
                    continue
                if x_lead > x_e + tol_x:
                    eye = self.eyes[name]
                    if eye.blocked:
                        # merged with the parcel ahead (or the eye is stuck on): the blocked-time
                        # check decides
                        p.confirmed[name] = None
                    else:
                        p.confirmed[name] = None
                        if self.state == "running":
                            self._enter_fault(
                                out,
                                "stuck_off",
                                f"{name}: parcel {p.seq} ({p.label}) should have "
                                f"blocked it {(x_lead - x_e) / v:.2f} s ago",
                                name,
                            )
            if p.done:
                continue
            # outcomes the controller infers from time
            length = p.length if p.length is not None else cfg.max_parcel_length
            if not p.committed:
                if x_lead > length + b + tol_x:
                    # never decided (fault state or unknown length): it went through with the disks
                    # down
                    self._finish(
                        out, p, "straight", R_FAULT if self.state != "running" else R_LATE
                    )
                continue
            side = side_of(p.plan)
            if side == 0:
                if x_lead > length + b + tol_x:
                    self._finish(out, p, "straight")
            elif p.prediction is not None:
                deadline = self.t_enter(p) + p.prediction.t_chute + cfg.missed_divert_margin
                if self.t > deadline:
                    chute = self.chute_of["left" if side > 0 else "right"]
                    if self.state != "running":
                        # the disks were dropped by the fault: its fate is not the divert's doing
                        self._finish(out, p, "unknown", R_FAULT)
                        continue
                    self._finish(out, p, "unknown", R_MISSED)
                    self.counts["missed"] += 1
                    self._enter_fault(
                        out,
                        "missed_divert",
                        f"parcel {p.seq} ({p.label}) did not reach {chute} by {deadline:.3f} s",
                        chute,
                    )

    # --- decisions -------------------------------------------------------------------------------
    def _alpha_end(self) -> float | None:
        """Return the disk angle the committed plan ends with [deg]."""
        for p in reversed(self.parcels):
            if p.committed and p.alpha is not None:
                return p.alpha
        return self.commanded_alpha

    def _lead_needed(self, dest: str) -> float:
        """
        How long before its entry a parcel for ``dest`` must be decided [s].

        The stroke only: the disk angle is set ahead for the next divert in line
        whenever no committed divert holds it (see ``desired_outputs``), so it does
        not force decisions early; ``_alpha_ready`` checks it made it in time.
        """
        return 0.0 if side_of(dest) == 0 else self.gaps.act.stroke_total

    def _alpha_ready(self, dest: str) -> float:
        """When the disks can be at the angle for ``dest`` if nothing committed holds them [s]."""
        act = self.gaps.act
        target = self.gaps.alpha_for(dest)
        if self.commanded_alpha == target:
            # under way since the command: the reported angle may be a scan or two old
            return self.alpha_ready_at if self.alpha_ready_at is not None else self.t
        # not commanded yet: this scan's outputs will
        start = (
            math.degrees(self.diverter.alpha)
            if self.diverter is not None
            else self.commanded_alpha
        )
        if start is None:
            start = -target
        return self.t + act.latency + act.slew_time(start, target)

    def _decide(self, out) -> None:
        pending = [p for p in self.parcels if not p.committed and not p.done]
        if not pending:
            return
        # latest moment each must be decided; a parcel ahead is decided no later than one behind it
        deadlines = []
        for p in pending:
            dest = p.bound or self.routing.lookup(p.label)[0]
            deadlines.append(self.t_enter(p) - self._lead_needed(dest) - self.config.scan_period)
        for i in range(len(deadlines) - 2, -1, -1):
            deadlines[i] = min(deadlines[i], deadlines[i + 1])
        act = self.gaps.act
        for p, dl in zip(pending, deadlines):
            if self.t < dl:
                break
            if (
                p.length is None
                and self.t + act.popup_stroke_time + act.latency + act.scan_period
                <= self.t_enter(p)
            ):
                # its trailing edge is still at the scanner: wait for the length while the
                # stroke can still make it (the margin is spent first)
                break
            self._commit(out, p)

    def _decide_faulted(self, out) -> None:
        for p in self.parcels:
            if not p.committed and not p.done:
                p.committed = True
                p.plan = "straight"
                p.asked = self.routing.lookup(p.label)[0]
                p.result = R_FAULT
                self.last_decided = p

    def _commit(self, out, p: Tracked) -> None:
        """Decide parcel p for good: its destination and whether the disks can serve it."""
        v = self.v
        asked, how = self.routing.lookup(p.label)
        p.asked, p.how = asked, how
        if how == "no_read":
            self.counts["no_read"] += 1
        p.committed = True
        p.plan, p.result = "straight", None
        # decisions are taken in belt order, so the last one is the parcel ahead (it may
        # have left the tracking list already, its disks not)
        prev, self.last_decided = self.last_decided, p
        if p.bound is not None:
            # the parcel ahead keeps the disks up for this one: it goes with them
            if asked != p.bound:
                self._log(
                    out,
                    "warn",
                    f"parcel {p.seq} ({p.label}): routing now says {asked}, but the disks "
                    f"were already kept up for it to go {p.bound}",
                )
            self._divert(out, p, p.bound, forced=True)
            return
        if p.length is None:
            p.result = R_LATE
            self.counts["late"] += 1
            self._log(
                out,
                "warn",
                f"parcel {p.seq} ({p.label}): length unknown at decision time; straight",
            )
            return
        if side_of(asked) == 0:
            if prev is not None and prev.length is not None and side_of(prev.plan) != 0:
                headway = self.t_enter(p) - self.t_enter(prev)
                if headway < self.gaps.headway(prev.length, prev.plan, p.length, "straight", v):
                    self._log(
                        out,
                        "error",
                        f"parcel {p.seq} ({p.label}) follows parcel {prev.seq} too closely "
                        f"to pass the raised disks straight",
                    )
            return
        pred = self.gaps.prediction(p.length, v, asked)
        if not pred.feasible:
            p.result = R_CANNOT
            self.counts["cannot_divert"] += 1
            self._log(
                out,
                "warn",
                f"parcel {p.seq} ({p.label}): the model cannot bring a {p.length:.2f} m parcel "
                f"to the {asked} chute within the disk field; straight",
            )
            return
        if prev is not None and prev.length is not None:
            headway = self.t_enter(p) - self.t_enter(prev)
            need = self.gaps.headway(
                prev.length, prev.plan, p.length, asked, v, alpha_before_deg=self._alpha_end()
            )
            if headway < need:
                self._refuse(
                    out,
                    p,
                    asked,
                    f"{(headway * v - prev.length):.3f} m behind parcel {prev.seq} "
                    f"({prev.plan}); {(need * v - prev.length):.3f} m needed",
                )
                return
        # late only if even without the margins the stroke cannot end before the entry
        act = self.gaps.act
        late = self.t + act.popup_stroke_time + act.latency > self.t_enter(p) + 1e-9
        if not late and not self._alpha_held():
            late = self._alpha_ready(asked) > self.t_enter(p) + 1e-9
        if late:
            p.result = R_LATE
            self.counts["late"] += 1
            self._log(
                out,
                "warn",
                f"parcel {p.seq} ({p.label}): decided too late to divert (stroke or disk "
                "angle); straight",
            )
            return
        self._divert(out, p, asked, forced=False)

    def _divert(self, out, p: Tracked, dest: str, forced: bool) -> None:
        """
        Divert p unless a parcel behind it could then neither pass straight nor follow.

        Parcels too close behind to go straight past raised disks must follow p to
        the same side (a chain, each bound to it); a chain that breaks refuses p.
        A bound p (forced) cannot be refused: a break behind it binds the next one.
        """
        v = self.v
        length = p.length if p.length is not None else self.config.max_parcel_length
        pred = self.gaps.prediction(length, v, dest)
        chain = []
        cur, cur_len, cur_te = p, length, self.t_enter(p)
        while True:
            nxt = self._next_after(cur)
            if nxt is None:
                # nobody seen behind: a parcel not yet at the scanner is at least this far back
                tail = self.lead_x(cur) - (cur.length if cur.length is not None else math.inf)
                open_gap = max(0.0, tail - self.x_scan) if math.isfinite(tail) else 0.0
                need = self.gaps.headway(
                    cur_len, dest, self.config.max_parcel_length, "straight", v
                )
                if (cur_len + open_gap) / v < need and not self.config.open_chains:
                    if not forced:
                        self._refuse(
                            out,
                            p,
                            dest,
                            f"the scanner cannot see far enough behind parcel "
                            f"{cur.seq}: a parcel arriving {open_gap:.3f} m behind it could "
                            "neither "
                            "pass the raised disks straight nor be refused",
                        )
                        return
                break
            nxt_len = nxt.length if nxt.length is not None else self.config.max_parcel_length
            headway = self.t_enter(nxt) - cur_te
            if headway >= self.gaps.headway(cur_len, dest, nxt_len, "straight", v):
                break
            follow = self.routing.lookup(nxt.label)[0]
            if (
                follow != dest
                or nxt.length is None
                or headway < self.gaps.headway(cur_len, dest, nxt_len, dest, v)
            ):
                if not forced:
                    self._refuse(
                        out,
                        p,
                        dest,
                        f"parcel {nxt.seq} ({nxt.label}, {follow}) follows "
                        f"{headway * v - cur_len:.3f} m behind parcel {cur.seq} and could neither "
                        "pass "
                        "the raised disks straight nor follow to the same side",
                    )
                    return
                self._log(
                    out,
                    "error",
                    f"parcel {nxt.seq} ({nxt.label}) follows {headway * v - cur_len:.3f} m "
                    f"behind a parcel the disks are already committed to; it goes {dest} with it",
                )
            chain.append(nxt)
            cur, cur_len, cur_te = nxt, nxt_len, self.t_enter(nxt)
        for q in chain:
            q.bound = dest
        p.plan = dest
        p.prediction = pred
        p.alpha = self.gaps.alpha_for(dest)

    def _refuse(self, out, p: Tracked, asked: str, why: str) -> None:
        p.plan = "straight"
        p.result = R_GAP
        self.counts["gap_too_short"] += 1
        self._log(
            out,
            "warn",
            f"parcel {p.seq} ({p.label}) for {asked}: gap too short, sent straight: {why}",
        )

    def _next_after(self, p: Tracked) -> Tracked | None:
        seen = False
        for q in self.parcels:
            if seen:
                return q
            seen = seen or q is p
        return None

    def _alpha_held(self) -> bool:
        """Whether a committed divert still needs the disk angle it set."""
        for p in self.parcels:
            if (
                p.committed
                and side_of(p.plan) != 0
                and p.prediction is not None
                and self.t < self.t_enter(p) + p.prediction.t_commit
            ):
                return True
        return False

    # --- outputs ---------------------------------------------------------------------------------
    def desired_outputs(self) -> tuple[bool, float | None]:
        """
        (disks up, disk angle in deg or None to keep) as the committed plan wants them now.

        The disk angle follows the first committed divert not yet handed to its chute;
        with none, it is set ahead for the next parcel in line that routing sends to a
        chute (swinging the lowered disks moves nothing).
        """
        act = self.gaps.act
        up = False
        alpha = None
        for p in self.parcels:
            if not p.committed or side_of(p.plan) == 0 or p.prediction is None:
                continue
            if p.done and p.reached != p.plan:
                continue
            te = self.t_enter(p)
            t_down = te + p.prediction.t_commit
            if self.t >= t_down:
                continue
            if alpha is None:
                alpha = p.alpha
            if alpha == p.alpha and self.t >= te - act.stroke_total:
                up = True
        if alpha is None:
            for p in self.parcels:
                if p.committed or p.done:
                    continue
                dest = p.bound or self.routing.lookup(p.label)[0]
                if side_of(dest) != 0:
                    alpha = self.gaps.alpha_for(dest)
                    break
        return up, alpha

    def _write_outputs(self, out) -> None:
        if self.diverter_silent:
            return  # the diverter did not answer: leave it alone until reset, whatever the state
        if self.state == "resetting":
            return
        if self.state != "running":
            up, alpha = False, None
            if self.state == "estop":
                return  # the cell has dropped the disks and refuses commands
        else:
            up, alpha = self.desired_outputs()
        if alpha is not None and alpha != self.commanded_alpha and not self._busy("alpha"):
            self._command(out, "alpha", alpha)
            start = self.commanded_alpha
            if self.diverter is not None:
                start = math.degrees(self.diverter.alpha)
            act = self.gaps.act
            self.alpha_ready_at = (
                self.t + act.latency + act.slew_time(-alpha if start is None else start, alpha)
            )
            self.commanded_alpha = alpha
        if up != self.commanded_up and not self._busy("popup"):
            self._command(out, "popup", up)
            self.commanded_up = up

    # --- diagnostics ---------------------------------------------------------------------------
    def status(self) -> dict:
        """Counters, state and scan statistics for the node's diagnostics."""
        walls = sorted(self.scan_wall)

        def q(f):
            return walls[min(len(walls) - 1, int(f * len(walls)))] if walls else 0.0

        return {
            "state": self.state,
            "fault": dict(self.fault) if self.fault else None,
            "counts": dict(self.counts),
            "faults": dict(self.fault_counts),
            "tracked": sum(1 for p in self.parcels if not p.done),
            "scan_wall_p50_ms": q(0.5) * 1e3,
            "scan_wall_p99_ms": q(0.99) * 1e3,
            "scan_wall_max_ms": (walls[-1] if walls else 0.0) * 1e3,
            "predictions": self.predictor.n_runs,
            "prediction_wall_s": self.predictor.wall_s,
            "routing": self.routing.rules(),
            "commanded_up": self.commanded_up,
            "commanded_alpha_deg": self.commanded_alpha,
        }
