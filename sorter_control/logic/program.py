"""
The PLC program: one scan reads the input image and runs the parts in order.

``SorterLogic.scan(image)`` is one PLC scan. It takes the scan's time (refusing
one that goes back), applies routing updates, service replies, the cell's status
bits and the operator's requests, then the edges (``image.EdgeDetector``) and
labels to the tracking (``tracking.Tracker``), lets the supervision check the
eyes and the transit windows (``faults.Supervisor``), decides and writes the
diverter's outputs (``sequencing.DiverterSequencer``). It returns the service
calls to make, the sort confirmations and log lines; it never waits for
anything.

A reset clears tracking: parcels already on the belt are let through straight
("flush") until the belt has carried them out.
"""

from __future__ import annotations

import math
from collections import deque

from sorter_control.timing import DivertPredictor, GapModel
from sorter_control.logic.config import ControllerConfig
from sorter_control.logic.faults import FAULT_STATES, Faults, Supervisor
from sorter_control.logic.image import (
    Command,
    Confirmation,
    Edge,
    EdgeDetector,
    InputImage,
    ScanOutput,
)
from sorter_control.logic.routing import RoutingError, RoutingTable
from sorter_control.logic.sequencing import DiverterSequencer
from sorter_control.logic.tracking import (
    R_ABORTED,
    R_MISSORT,
    R_REJECTED,
    R_SORTED,
    Tracked,
    Tracker,
)

MAX_CLOCK_LAG = 0.5  # [s] how far this node's clock may lag the cell's latched stamps

# the command the operator's reset issues in each PackML rest state on the way to Execute
PACKML_RESUME = {"Aborted": "clear", "Stopped": "reset", "Idle": "start", "Held": "unhold"}
PACKML_SETTLE_S = 0.05  # s the cell's state holds before the program issues a command

COUNTS = (
    "inducted",
    "left",
    "right",
    "straight",
    "rejected",
    "no_read",
    "gap_too_short",
    "not_executing",
    "packml_commands",
    "cannot_divert",
    "late",
    "mis_sorted",
    "missed",
    "aborted",
    "untracked",
    "unexpected_chute",
    "labels_without_parcel",
    "scans",
    "overruns",
    "late_scans",
    "routing_updates",
    "routing_rejected",
    "commands",
    "replies",
    "timeouts",
    "clock_jumps",
)


class _Scan:
    """The ``ScanIO`` of one scan: the parts log, fault, command and finish through it."""

    def __init__(self, logic: SorterLogic, out: ScanOutput):
        self.logic = logic
        self.out = out
        self.t = logic.t

    def log(self, level: str, text: str) -> None:
        self.out.log.append((level, text))
        self.logic.log_history.append((self.t, level, text))

    def fault(self, kind: str, message: str, sensor: str | None = None) -> None:
        self.logic.faults.enter(self, kind, message, sensor)

    def command(self, kind: str, value) -> Command:
        return self.logic.sequencer.command(self.out, kind, value, self.t)

    def finish(self, p: Tracked, reached: str, result: str | None = None) -> None:
        self.logic.finish(self, p, reached, result)


class SorterLogic:
    """The PLC program. Feed it one ``InputImage`` per scan; act on what ``scan`` returns."""

    def __init__(self, config: ControllerConfig, predictor: DivertPredictor | None = None):
        self.config = config
        self.predictor = predictor or DivertPredictor(config.cell)
        self.gaps = GapModel(
            self.predictor,
            config.actuators(),
            divert_alpha_deg=abs(config.divert_alpha_deg),
            clearance=config.clearance,
        )
        self.counts = {k: 0 for k in COUNTS}
        self.tracker = Tracker(config, self.counts)
        self.edges = EdgeDetector(self.tracker.sensors)
        self.faults = Faults(config.estop_on_jam)
        self.supervisor = Supervisor(config, self.counts)
        self.sequencer = DiverterSequencer(
            config,
            self.gaps,
            RoutingTable(config.routing_rules, config.routing_default, config.reject_destination),
            self.tracker,
            self.counts,
        )
        self._reset_requested = False
        self._estop_requested = False
        self.cell_packml: str | None = None  # the cell's PackML state, as last read
        # the operator's reset also resumes the cell: walk its PackML state back to Execute
        self._resume = False
        self._packml_since: float | None = None  # when the cell entered its state [s]
        # a scan this much later than the last one is a jump of the clock, not a late scan
        self._max_jump = max(2.0, 100 * config.scan_period)
        self.clock_lag_max = 0.0  # the most this node's clock lagged the cell's stamps [s]
        self.scan_wall: deque = deque(maxlen=1000)
        self.scan_wall_total = 0.0  # [s] every scan's wall time, summed
        self.log_history: deque = deque(maxlen=50)

    # --- the parts' state, as the node and the tests read it -------------------------------------
    @property
    def t(self) -> float | None:
        return self.tracker.t

    @property
    def state(self) -> str:
        return self.faults.state

    @property
    def fault(self) -> dict | None:
        return self.faults.fault

    @property
    def fault_counts(self) -> dict:
        return self.faults.counts

    @property
    def parcels(self) -> list[Tracked]:
        return self.tracker.parcels

    @property
    def x_scan(self) -> float:
        return self.tracker.x_scan

    @property
    def routing(self) -> RoutingTable:
        """Return the routing table the program sorts by; assigning one replaces it."""
        return self.sequencer.routing

    @routing.setter
    def routing(self, table: RoutingTable) -> None:
        self.sequencer.routing = table

    @property
    def commanded_up(self) -> bool | None:
        """Return the disks' commanded position (True up, False down, None: not known)."""
        return self.sequencer.commanded_up

    @commanded_up.setter
    def commanded_up(self, up: bool | None) -> None:
        self.sequencer.commanded_up = up

    @property
    def v(self) -> float:
        return self.config.belt_speed

    # --- configuration facts -----------------------------------------------------------------
    def warm_lengths(self, lo: float, hi: float) -> list[float]:
        """
        Return the prediction grid's lengths in [lo, hi] m.

        Parameters
        ----------
        lo : float
            The shortest length [m].
        hi : float
            The longest [m].

        Returns
        -------
        list of float
            The lengths [m].

        """
        step = self.predictor.cell.length_step
        n = int(math.floor((hi - lo) / step + 1e-9)) + 1
        return [lo + i * step for i in range(max(n, 1))]

    def warm_up(self, lengths) -> None:
        """
        Predict ahead for these lengths [m] (outside the scan), so scans find them ready.

        Parameters
        ----------
        lengths : sequence of float
            Parcel lengths [m].

        """
        self.gaps.warm(lengths, self.v)

    def min_gap(self, length: float) -> dict:
        """
        Return the least gap [m] for parcels of ``length`` m at the configured belt speed.

        Parameters
        ----------
        length : float
            The parcel's length [m].

        Returns
        -------
        dict
            The least gap [m] by pair of destinations, and the worst.

        """
        return self.gaps.min_gap(length, self.v)

    def lookahead_ok(self, length: float) -> bool:
        """
        Whether the scanner sits far enough upstream to see the follower before a decision.

        Parameters
        ----------
        length : float
            The parcel's length [m].

        Returns
        -------
        bool
            Whether the scanner sits far enough upstream.

        """
        lead = self.gaps.act.stroke_total + self.config.scan_period
        distance = -self.x_scan - self.v * lead
        need = length + self.min_gap(length)["worst"]
        return distance >= need

    # --- operator requests ---------------------------------------------------------------------
    def request_reset(self) -> str:
        self._reset_requested = True
        self._resume = True
        return f"reset requested in state {self.state}"

    def request_estop(self) -> str:
        self._estop_requested = True
        return "e-stop requested"

    def record_scan_wall(self, seconds: float) -> None:
        """
        Record how long a scan took in wall time, as the node measured it.

        Longer than a period is an overrun.

        Parameters
        ----------
        seconds : float
            The time [s].

        """
        self.scan_wall.append(seconds)
        self.scan_wall_total += seconds
        if seconds > self.config.scan_period:
            self.counts["overruns"] += 1

    def update_route(self, pattern: str, destination: str) -> str:
        """
        Return a routing change from a warehouse controller.

        Raises RoutingError if not allowed.

        Parameters
        ----------
        pattern : str
            A label pattern of the routing grammar.
        destination : str
            A destination (left, right, straight, or a chute name).

        Returns
        -------
        str
            What was done.

        """
        done = self.routing.set(pattern, destination)
        self.counts["routing_updates"] += 1
        return done

    # --- the scan ------------------------------------------------------------------------------
    def scan(self, image: InputImage) -> ScanOutput:
        """
        Run one PLC scan.

        Parameters
        ----------
        image : InputImage
            The inputs of this scan.

        Returns
        -------
        ScanOutput
            This scan's outputs: commands, logs, faults, outcomes.

        """
        out = ScanOutput()
        raw = float(image.t)
        if not math.isfinite(raw):
            self._refuse_scan(out, f"scan ignored: time {image.t!r} is not finite")
            return out
        # This node's clock comes from /clock; under load it can lag the cell, whose latched
        # edges carry the cell's own time. The PLC's "now" is never earlier than an edge it
        # has read (else a parcel born at the scanner would be placed ahead of itself by
        # v x lag): the scan time moves up to the newest stamp, within MAX_CLOCK_LAG.
        t = raw
        stamps = [
            e.t
            for e in image.edges
            if isinstance(e, Edge) and isinstance(e.t, (int, float)) and math.isfinite(e.t)
        ]
        if stamps and raw < max(stamps) <= raw + MAX_CLOCK_LAG:
            t = max(stamps)
        if self.t is not None and self.t - MAX_CLOCK_LAG <= raw < self.t:
            t = max(t, self.t)  # still behind the time the last stamps set: no time passes
        self.clock_lag_max = max(self.clock_lag_max, t - raw)
        if self.t is not None:
            dt = t - self.t
            if dt < 0 or dt > self._max_jump:
                return self._clock_jump(out, t, dt)
            if dt > self.config.scan_period + self.config.timing_margin + 1e-9:
                # later than the timing budget absorbs: an action may have come late
                self.counts["late_scans"] += 1
        self.tracker.advance(t)
        self.counts["scans"] += 1
        io = _Scan(self, out)
        if image.clock_sources is not None and image.clock_sources > 1:
            if self.state != "clock":
                self._clock_fault(
                    io,
                    f"{image.clock_sources} nodes publish /clock: simulated time is not one "
                    "clock (two cells on one /clock?); no diverts until reset",
                )
            elif self._reset_requested:
                self._reset_requested = False
                io.log("warn", f"reset refused: {image.clock_sources} nodes still publish /clock")

        self._apply_routing(io, image.routing_updates)
        self._apply_replies(io, image.replies)
        if image.diverter is not None:
            self.sequencer.diverter = image.diverter
        self._apply_cell_status(io, image)
        self._apply_operator(io)
        edges, first = self.edges.detect(image, t)
        self.tracker.first_seen(first)
        for edge in edges:
            self.tracker.on_edge(io, edge)
        labels = image.labels
        if t > raw:
            # labels carry this node's clock at reception: put them on the cell's time too
            shifted = []
            for item in labels:
                try:
                    lt, text = item
                    shifted.append((float(lt) + (t - raw), text))
                except (TypeError, ValueError):
                    shifted.append(item)  # malformed: apply_labels skips it
            labels = shifted
        self.tracker.apply_labels(io, labels, self.faults.running)
        self.supervisor.check(io, self.tracker, self.faults)
        self._drive_packml(io, image.cell_packml)
        if self.faults.running:
            self.sequencer.decide(io, executing=image.cell_packml in (None, "Execute"))
        else:
            self.sequencer.decide_faulted()
        self.sequencer.write_outputs(out, self.state)
        self.tracker.prune()
        return out

    def _drive_packml(self, io: _Scan, state: str | None) -> None:
        """
        Follow the cell's PackML state; after the operator's reset, walk it back to Execute.

        The operator's reset (``request_reset``) clears this program's fault and, as a
        PLC's reset button on a PackML machine does, issues the command the cell's state
        takes on the way back to Execute: clear (Aborted), reset (Stopped), start (Idle),
        unhold (Held), one at a time, each after the state has held for
        ``PACKML_SETTLE_S`` (a cell in automatic mode gets there by itself first). An
        operator's stop, hold or suspend on the cell is left alone otherwise.
        """
        if state != self.cell_packml:
            self.cell_packml, self._packml_since = state, self.t
        if state == "Execute":
            self._resume = False  # there: nothing left to walk
        if state is None or state == "Execute":
            return
        command = PACKML_RESUME.get(state)
        if (
            self._resume
            and command is not None
            and self.faults.running
            and not self.sequencer.busy("packml")
            and self.t - self._packml_since >= PACKML_SETTLE_S
        ):
            io.command("packml", command)
            self.counts["packml_commands"] += 1
            io.log("info", f"resuming the cell: PackML {command} (cell in {state})")
            self._packml_since = self.t  # the next try, if this one does not move it

    def _clock_jump(self, out: ScanOutput, t: float, dt: float) -> ScanOutput:
        """
        Enter the clock fault (once): simulated time went back, or leapt ahead.

        Every time the PLC holds (edges, windows, deadlines) is on the old time base,
        so the scan is not run. A reset re-bases on the new time: tracking is dropped
        and the controller runs on; if the cause remains, the next jump faults again.
        """
        self.counts["clock_jumps"] += 1
        io = _Scan(self, out)
        io.t = t
        if self._reset_requested and self.state == "clock":
            self._reset_requested = False
            self.tracker.t = t
            self._cleared(io)
            io.log("info", f"reset: the time base is now {t:.3f} s")
            return out
        what = "went back" if dt < 0 else "jumped ahead"
        self._clock_fault(
            io, f"simulated time {what} from {self.t:.3f} to {t:.3f} s; no diverts until reset"
        )
        # the disks down, whatever time it is: a fault's outputs need no clock
        self.sequencer.write_outputs(out, self.state)
        return out

    def _clock_fault(self, io: _Scan, message: str) -> None:
        # worse than any other fault: what the PLC holds is on a time base that is gone
        if self.state == "clock":
            return
        if self.state in FAULT_STATES or self.state == "resetting":
            self.faults.state = "running"  # so that the clock fault takes over
        self.faults.enter(io, "clock", message)
        self.sequencer.forget_outputs()
        self._drop_tracking(io, "clock fault")

    def _refuse_scan(self, out: ScanOutput, text: str) -> None:
        out.log.append(("error", text))
        self.log_history.append((self.t, "error", text))

    def finish(self, io: _Scan, p: Tracked, reached: str, result: str | None = None) -> None:
        """
        Record where parcel p went, and how that compares with the plan.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        p : Tracked
            The parcel.
        reached : str
            Where it went.
        result : str
            The outcome's code.

        """
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
        io.out.confirmations.append(
            Confirmation(p.label or "", asked, reached, result, p.seq, self.t)
        )

    def _drop_tracking(self, io: _Scan, why: str) -> None:
        self.sequencer.last_decided = None
        self.tracker.clear(io, why)

    # --- inputs --------------------------------------------------------------------------------
    def _apply_routing(self, io: _Scan, updates) -> None:
        for item in updates:
            try:
                pattern, dest = item
                done = self.update_route(pattern, dest)
            except (RoutingError, TypeError, ValueError) as exc:
                self.counts["routing_rejected"] += 1
                io.log("warn", f"routing update rejected: {exc}")
            else:
                io.log("info", f"routing update: {done}")

    def _apply_replies(self, io: _Scan, replies) -> None:
        seqr = self.sequencer
        for r in replies:
            cmd = seqr.in_flight.pop(r.command_id, None)
            if cmd is None:
                continue
            self.counts["replies"] += 1
            what = f"{cmd.kind} {cmd.value!r}"
            if r.timed_out:
                self.counts["timeouts"] += 1
                if cmd.kind in ("popup", "alpha"):
                    # not retried: a late answer could still be acted on, and a second call
                    # would actuate twice; the diverter's state is unknown until reset
                    if cmd.kind == "popup":
                        seqr.commanded_up = None
                    else:
                        seqr.commanded_alpha = None
                    seqr.diverter_silent = True
                    io.fault(
                        "diverter_timeout", f"{what}: no answer from the cell in time; not retried"
                    )
                elif cmd.kind == "reset":
                    self.faults.restore(io, "reset: no answer from the cell in time")
                else:
                    io.log("error", f"{what}: no answer from the cell in time")
                continue
            if r.accepted:
                if cmd.kind == "reset":
                    self._cleared(io)
                elif cmd.kind == "estop":
                    self.tracker.belt_running = False
                continue
            # the cell says "refused: <why>"; the lines below say refused themselves
            reason = (r.message or "no reason given").removeprefix("refused: ")
            if cmd.kind == "packml":
                # the cell moved on meanwhile (its automatic mode, an operator): the next
                # scan sees its state and issues what that takes
                io.log("warn", f"{what} refused by the cell: {reason}")
            elif cmd.kind == "reset":
                self.faults.restore(io, f"reset refused by the cell: {reason}")
            elif any(w in reason.lower() for w in ("e-stop", "estop", "emergency")):
                self._refused_for_estop(io, cmd, what, reason)
            elif cmd.kind in ("popup", "alpha"):
                if cmd.kind == "popup":
                    seqr.commanded_up = None
                else:
                    seqr.commanded_alpha = None
                io.fault("diverter_refused", f"{what} refused by the cell: {reason}")
            else:
                io.log("error", f"{what} refused by the cell: {reason}")

    def _refused_for_estop(self, io: _Scan, cmd, what: str, reason: str) -> None:
        if self.state == "jam" and self.faults.estop_on_jam:
            # the e-stop is this jam's own (estop_on_jam), served before the disks' command
            # of the same scan: the cell drops the disks on e-stop, and the fault stays the
            # jam (as the cell's e-stop status keeps it), whatever order the cell answered
            # the scan's calls in
            if cmd.kind == "popup":
                self.sequencer.commanded_up = False
            io.log("info", f"{what} refused during the jam's own e-stop: {reason}")
        else:
            self._enter_estop(io, f"{what} refused: {reason}")

    def _enter_estop(self, io: _Scan, message: str) -> None:
        if not self.faults.enter_estop(io, message):
            return
        self.tracker.belt_running = False
        self.sequencer.commanded_up = False  # the cell drops the disks on e-stop
        self._drop_tracking(io, "e-stop")

    def _apply_cell_status(self, io: _Scan, image: InputImage) -> None:
        if image.cell_watchdog is not None:
            # after a trip, the parcels then on their way over the field may still show it
            cfg = self.config
            grace = (
                cfg.max_parcel_length + cfg.cell.disk_field_length
            ) / cfg.belt_speed + cfg.missed_divert_margin
            self.faults.cell_watchdog_report(image.cell_watchdog, io.t, grace)
        if image.cell_status_t is not None and image.cell_status_t < self.faults.reset_t:
            return  # reported before the last reset: stale
        if image.cell_estop:
            # a jam the controller stopped the belt for stays a jam; anything else becomes an
            # e-stop
            self.tracker.belt_running = False
            if self.state not in ("estop", "resetting", "jam"):
                self._enter_estop(io, "the cell reports an e-stop")
        if image.cell_jam and self.state == "running":
            io.fault("jam", "the cell reports a jam")

    def _apply_operator(self, io: _Scan) -> None:
        if self._estop_requested:
            self._estop_requested = False
            io.command("estop", True)
            self._enter_estop(io, "requested by the operator")
        if self._reset_requested:
            self._reset_requested = False
            if self.state == "running":
                io.log("info", "reset: nothing to clear")
            elif self.state == "resetting":
                io.log("info", "reset already under way")
            elif self.state in ("estop", "jam") and not self.sequencer.busy("reset"):
                # the cell holds these faults too (belt stopped): it must reset first
                self.faults.state = "resetting"
                io.command("reset", None)
                io.log("info", "reset: asking the cell to reset")
            else:
                self._cleared(io)

    def _cleared(self, io: _Scan) -> None:
        seqr = self.sequencer
        was = self.faults.clear(self.t)
        self.tracker.belt_running = True
        if was in ("diverter_timeout", "diverter_refused") or seqr.diverter_silent:
            # the operator has looked at the diverter: its state is unknown, so write it afresh
            seqr.forget_outputs()
        seqr.diverter_silent = False
        self._drop_tracking(io, f"reset after {was}")
        self.tracker.restart_eyes()
        io.log("info", f"reset: {was} cleared, running")

    # --- diagnostics ---------------------------------------------------------------------------
    def desired_outputs(self) -> tuple[bool, float | None]:
        """(disks up, disk angle in deg or None to keep) as the committed plan wants them now."""
        return self.sequencer.desired_outputs()

    def status(self) -> dict:
        """Counters, state and scan statistics for the node's diagnostics."""
        walls = sorted(self.scan_wall)

        def q(f):
            return walls[min(len(walls) - 1, int(f * len(walls)))] if walls else 0.0

        return {
            "state": self.state,
            "cell_packml": self.cell_packml,
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
            "commanded_up": self.sequencer.commanded_up,
            "commanded_alpha_deg": self.sequencer.commanded_alpha,
            "clock_lag_max_ms": self.clock_lag_max * 1e3,
        }


__all__ = ["FAULT_STATES", "SorterLogic"]
