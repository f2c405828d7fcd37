"""
Faults: the controller's state, and the supervision of the photo-eyes that raises them.

Each fault is a state of its own, a diagnostic, and no diverts until a reset:
``jam`` (an eye blocked by a tracked parcel longer than the parcel explains),
``stuck_on`` (an eye blocked with no parcel due), ``stuck_off`` (a parcel's
transit window passed with the eye clear; a scanner label with no blocking),
``missed_divert`` (no chute sensor in time), ``diverter_timeout`` (a service call
unanswered), ``diverter_refused``, ``clock`` (simulated time went back or jumped ahead, or
more than one node publishes /clock) and ``estop``. The first fault defines the
state; later ones are logged.
"""

from __future__ import annotations

import math

from sorter_control.timing import side_of
from sorter_control.logic.image import ScanIO
from sorter_control.logic.tracking import R_FAULT, R_LATE, R_MISSED, Tracked, Tracker

STATES = (
    "running",
    "jam",
    "stuck_on",
    "stuck_off",
    "missed_divert",
    "diverter_timeout",
    "diverter_refused",
    "clock",
    "estop",
    "resetting",
)
FAULT_STATES = STATES[1:9]
# faults a trip of the cell's watchdog brings about by itself (see Faults.enter)
WATCHDOG_CONSEQUENCES = ("stuck_off", "missed_divert")


class Faults:
    """The controller's state: running, one of the faults, or resetting."""

    def __init__(self, estop_on_jam: bool = True):
        self.estop_on_jam = estop_on_jam
        self.state = "running"
        self.fault: dict | None = None
        self.counts = {k: 0 for k in FAULT_STATES}
        self.counts["after_cell_watchdog"] = 0
        self.reset_t = -math.inf  # when the last reset cleared a fault [s]
        # the cell's watchdog: tripped now, or cleared less than a grace time ago [s]
        self.cell_watchdog = False
        self.cell_watchdog_grace_until = -math.inf

    @property
    def running(self) -> bool:
        return self.state == "running"

    def after_cell_watchdog(self, t: float) -> bool:
        """
        Return True while the cell's watchdog holds, or its consequences may still show.

        Parameters
        ----------
        t : float
            The scan time [s, simulated].

        Returns
        -------
        bool
            True while the watchdog holds or its consequences may show.

        """
        return self.cell_watchdog or t < self.cell_watchdog_grace_until

    def cell_watchdog_report(self, tripped: bool, t: float, grace: float) -> None:
        """
        Take the cell's watchdog bit; when it clears, its consequences last ``grace`` s.

        Parameters
        ----------
        tripped : bool
            The cell's watchdog bit.
        t : float
            The scan time [s, simulated].
        grace : float
            How long its consequences may still show after it clears [s].

        """
        if tripped:
            self.cell_watchdog = True
        elif self.cell_watchdog:
            self.cell_watchdog = False
            self.cell_watchdog_grace_until = t + grace

    def enter(self, io: ScanIO, kind: str, message: str, sensor: str | None = None) -> None:
        """
        Enter fault ``kind``, unless a fault (or a reset) is already under way.

        A transit or divert the cell's own watchdog spoiled (it dropped the disks, or the
        cell's clock ran a burst the controller could not follow) is logged and counted
        as that trip's consequence, not latched: the trip is the cell's to report, and
        once heartbeats return nothing is left for a person to reset.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        kind : str
            The fault's kind.
        message : str
            What happened, for the log.
        sensor : str, optional
            The sensor concerned.

        """
        if kind in WATCHDOG_CONSEQUENCES and self.after_cell_watchdog(io.t):
            self.counts["after_cell_watchdog"] += 1
            io.log("warn", f"{kind}: {message} (after the cell's watchdog trip: not latched)")
            return
        if self.state in FAULT_STATES or self.state == "resetting":
            io.log("error", f"{kind}: {message} (while in {self.state})")
            return
        self.state = kind
        self.fault = {"kind": kind, "sensor": sensor, "message": message, "t": io.t}
        self.counts[kind] += 1
        io.log("error", f"{kind}: {message}; no diverts until reset")
        if kind == "jam" and self.estop_on_jam:
            io.command("estop", True)

    def enter_estop(self, io: ScanIO, message: str) -> bool:
        """
        Enter the e-stop state (over any fault); False if already in it.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        message : str
            What happened, for the log.

        Returns
        -------
        bool
            False if already in it.

        """
        if self.state == "estop":
            return False
        if self.state in FAULT_STATES:
            io.log("error", f"e-stop while in {self.state}: {message}")
        self.state = "estop"
        self.fault = {"kind": "estop", "sensor": None, "message": message, "t": io.t}
        self.counts["estop"] += 1
        io.log("error", f"estop: {message}; no diverts until reset")
        return True

    def restore(self, io: ScanIO, message: str) -> None:
        """
        Go back to the fault a failed reset was to clear.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        message : str
            What happened, for the log.

        """
        if self.fault is not None:
            self.state = self.fault["kind"]
        io.log("error", message)

    def clear(self, t: float) -> str:
        """
        Back to running at time t [s]; returns what was cleared.

        Parameters
        ----------
        t : float
            The scan time [s, simulated].

        Returns
        -------
        str
            What was cleared.

        """
        was = self.fault["kind"] if self.fault else self.state
        self.state = "running"
        self.fault = None
        self.reset_t = t
        return was


class Supervisor:
    """
    The checks a scan makes on the tracking: eyes blocked too long, transit windows passed.

    It also infers outcomes from time: a parcel never decided went straight; a
    straight one past the field is done; a divert with no chute sensor by its
    deadline is missed.
    """

    def __init__(self, config, counts: dict):
        self.config = config
        self.counts = counts

    def check(self, io: ScanIO, tr: Tracker, faults: Faults) -> None:
        """
        Report the faults this scan shows: eyes blocked too long, parcels missing their eyes.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        tr : Tracker
            The parcel tracker.
        faults : Faults
            The fault state.

        """
        self._check_held_eyes(io, tr, faults)
        self._check_chute_sensors(io, tr, faults)
        if not tr.belt_running:
            return
        for p in tr.parcels:
            x_lead = tr.lead_x(p)
            self._check_transit(io, tr, faults, p, x_lead)
            if p.done:
                continue
            self._infer_outcome(io, tr, faults, p, x_lead)

    def _check_held_eyes(self, io: ScanIO, tr: Tracker, faults: Faults) -> None:
        """Report the photo-eyes blocked too long: jam (a parcel due to have passed), stuck on."""
        cfg = self.config
        v = tr.v
        for name in tr.eye_x:
            eye = tr.eyes[name]
            if not eye.blocked or not tr.belt_running:
                continue
            held = tr.t - eye.since
            p = tr.by_seq(eye.by)
            if p is not None:
                limit = tr.expected_clear(p, name, eye.since) - eye.since + cfg.jam_margin
                if held > limit and faults.running:
                    if name == cfg.scan_eye and eye.labels_while_blocked >= 2:
                        io.fault(
                            "stuck_on",
                            f"{name}: blocked for {held:.2f} s while "
                            f"{eye.labels_while_blocked} labels were read",
                            name,
                        )
                    else:
                        io.fault(
                            "jam",
                            f"{name}: blocked for {held:.2f} s by parcel "
                            f"{p.seq} ({p.label}), which should have cleared it after "
                            f"{limit - cfg.jam_margin:.2f} s",
                            name,
                        )
            else:
                limit = cfg.max_parcel_length / v + cfg.jam_margin
                if held > limit and faults.running:
                    io.fault(
                        "stuck_on",
                        f"{name}: blocked for {held:.2f} s with no parcel due "
                        f"(longest parcel: {cfg.max_parcel_length / v:.2f} s)",
                        name,
                    )

    def _check_chute_sensors(self, io: ScanIO, tr: Tracker, faults: Faults) -> None:
        """Report a chute sensor blocked longer than the longest parcel takes: a jam."""
        cfg = self.config
        v = tr.v
        for name in tr.side_of_sensor:
            eye = tr.eyes[name]
            if (
                eye.blocked
                and tr.belt_running
                and tr.t - eye.since > cfg.max_parcel_length / v + cfg.jam_margin
                and faults.running
            ):
                io.fault(
                    "jam",
                    f"{name}: blocked for {tr.t - eye.since:.2f} s: a parcel stuck "
                    "at the chute entry",
                    name,
                )

    def _check_transit(
        self, io: ScanIO, tr: Tracker, faults: Faults, p: Tracked, x_lead: float
    ) -> None:
        """
        Report an eye a parcel's transit window passed without blocking: stuck off.

        A straight parcel is done before the eyes downstream of the field see it, and is
        still checked there.
        """
        v = tr.v
        tol_x = self.config.tracking_tolerance + v * self.config.scan_period
        for name, x_e in tr.eye_x.items():
            if name in p.confirmed or not tr.checkpoint(p, name):
                continue
            if x_lead > x_e + tol_x:
                # a blocked eye means merged with the parcel ahead (or the eye is stuck
                # on): the blocked-time check decides
                p.confirmed[name] = None
                if not tr.eyes[name].blocked and faults.running:
                    io.fault(
                        "stuck_off",
                        f"{name}: parcel {p.seq} ({p.label}) should have "
                        f"blocked it {(x_lead - x_e) / v:.2f} s ago",
                        name,
                    )

    def _infer_outcome(
        self, io: ScanIO, tr: Tracker, faults: Faults, p: Tracked, x_lead: float
    ) -> None:
        """
        Finish a parcel whose outcome time tells: gone straight, or a divert missed.

        A parcel never decided went straight; a straight one past the field is done; a
        divert with no chute sensor by its deadline is missed (a fault), unless the disks
        were dropped by a fault or the cell's watchdog first.
        """
        cfg = self.config
        tol_x = cfg.tracking_tolerance + tr.v * cfg.scan_period
        b = cfg.cell.disk_field_length
        length = p.length if p.length is not None else cfg.max_parcel_length
        if not p.committed:
            if x_lead > length + b + tol_x:
                # never decided (fault state or unknown length): it went through with the
                # disks down
                io.finish(p, "straight", R_FAULT if not faults.running else R_LATE)
            return
        side = side_of(p.plan)
        if side == 0:
            if x_lead > length + b + tol_x:
                io.finish(p, "straight")
        elif p.prediction is not None:
            deadline = tr.t_enter(p) + p.prediction.t_chute + cfg.missed_divert_margin
            if tr.t > deadline:
                chute = tr.chute_of["left" if side > 0 else "right"]
                if not faults.running or faults.after_cell_watchdog(tr.t):
                    # the disks were dropped by the fault (or by the cell's watchdog): its
                    # fate is not the divert's doing
                    if faults.running:
                        faults.counts["after_cell_watchdog"] += 1
                        io.log(
                            "warn",
                            f"parcel {p.seq} ({p.label}) did not reach {chute}: after "
                            "the cell's watchdog trip, not latched",
                        )
                    io.finish(p, "unknown", R_FAULT)
                    return
                io.finish(p, "unknown", R_MISSED)
                self.counts["missed"] += 1
                io.fault(
                    "missed_divert",
                    f"parcel {p.seq} ({p.label}) did not reach {chute} by {deadline:.3f} s",
                    chute,
                )
