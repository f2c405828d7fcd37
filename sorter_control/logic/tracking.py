"""
Tracking: where every parcel is, from the encoder, the photo-eyes and the scanner.

A parcel is born at the scanner photo-eye (``scan_eye``), which also measures its
length (blocked time x belt speed), gets its label from the scanner, and is then
followed by encoder distance (belt speed x time while the belt runs). Every other
photo-eye is a checkpoint with a transit window: the parcel must block it within
``tracking_tolerance`` of the distance tracking predicts, and re-synchronises the
tracking when it does. The chute sensors tell which parcel left to which side.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from sorter_control.timing import Prediction, side_of
from sorter_control.logic.image import Edge, ScanIO

# a parcel's result, in its sort confirmation
R_SORTED = "sorted"  # reached what the routing asked for
R_REJECTED = "rejected"  # unknown label or no read: sent to the reject destination
R_GAP = "gap_too_short"  # a divert refused for spacing: sent straight
R_CANNOT = "cannot_divert"  # the model says the disks cannot bring it to the chute
R_LATE = "late"  # length not known in time to act: sent straight
R_FAULT = "fault"  # the controller was in a fault state: sent straight
R_NOT_EXECUTING = "not_executing"  # the cell's PackML state was not Execute: sent straight
R_MISSORT = "mis-sorted"  # reached somewhere else than planned
R_MISSED = "missed"  # planned divert, no chute sensor in time
R_ABORTED = "aborted"  # tracking dropped (e-stop or reset) before the outcome


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


class Tracker:
    """The tracking list and the photo-eyes' state, in one controller's conveyor frame."""

    def __init__(self, config, counts: dict):
        self.config = config
        self.counts = counts
        self.v = config.belt_speed
        self.eye_x = config.eyes
        self.x_scan = self.eye_x[config.scan_eye]
        self.chute_of = config.chutes  # side -> sensor
        self.side_of_sensor = {s: side for side, s in self.chute_of.items()}
        self.sensors = list(self.eye_x) + list(self.side_of_sensor)
        self.t: float | None = None
        self.encoder = 0.0
        self.belt_running = True
        self.eyes = {s: EyeState() for s in self.sensors}
        self.parcels: list[Tracked] = []
        self.pending_labels: deque = deque()
        self.seq = 0
        self.flush_until: float = self.flush_distance()  # encoder reading

    # --- the encoder ---------------------------------------------------------------------------
    def advance(self, t: float) -> None:
        """
        Move to scan time t [s]: the belt carries the encoder on while it runs.

        Parameters
        ----------
        t : float
            The scan time [s, simulated].

        """
        if self.t is not None and self.belt_running:
            self.encoder += self.v * (t - self.t)
        self.t = t

    def flush_distance(self) -> float:
        """Return the encoder travel after which nothing untracked is left before the field end."""
        return (
            self.encoder
            + (self.config.cell.disk_field_length - self.x_scan)
            + self.config.max_parcel_length
            + self.config.tracking_tolerance
        )

    def enc_at(self, t: float) -> float:
        """
        Return the encoder reading at an edge time inside (or just before) the current scan.

        Parameters
        ----------
        t : float
            The scan time [s, simulated].

        Returns
        -------
        float
            The encoder reading [m].

        """
        if not self.belt_running:
            return self.encoder
        return self.encoder - self.v * (self.t - t)

    def lead_x(self, p: Tracked, enc: float | None = None) -> float:
        """
        Position of the parcel's leading edge [m, conveyor frame].

        Parameters
        ----------
        p : Tracked
            A tracked parcel.
        enc : float
            An encoder reading [m].

        Returns
        -------
        float
            The position [m].

        """
        return self.x_scan + ((self.encoder if enc is None else enc) - p.enc_rise)

    def t_enter(self, p: Tracked) -> float:
        """
        When the leading edge reaches (reached) the disk field, x = 0 [s].

        Parameters
        ----------
        p : Tracked
            A tracked parcel.

        Returns
        -------
        float
            The time [s].

        """
        return self.t + (0.0 - self.lead_x(p)) / self.v

    # --- the list ------------------------------------------------------------------------------
    def by_seq(self, seq) -> Tracked | None:
        """
        Return the parcel of a sequence number.

        Parameters
        ----------
        seq : int
            A sequence number.

        Returns
        -------
        Tracked or None
            The parcel, or None.

        """
        if seq is None:
            return None
        for p in self.parcels:
            if p.seq == seq:
                return p
        return None

    def next_after(self, p: Tracked) -> Tracked | None:
        """
        Return the parcel behind p.

        Parameters
        ----------
        p : Tracked
            A tracked parcel.

        Returns
        -------
        Tracked or None
            The next parcel, or None.

        """
        seen = False
        for q in self.parcels:
            if seen:
                return q
            seen = seen or q is p
        return None

    def checkpoint(self, p: Tracked, eye: str) -> bool:
        """
        Return whether the parcel should pass this photo-eye (diverted ones miss later eyes).

        Parameters
        ----------
        p : Tracked
            A tracked parcel.
        eye : str
            A photo-eye's name.

        Returns
        -------
        bool
            Whether it should pass the eye.

        """
        x = self.eye_x[eye]
        if eye == self.config.scan_eye:
            return False
        if x <= 0.0:
            return True
        return p.committed and side_of(p.plan) == 0

    def expected_at(self, eye: str, t: float) -> Tracked | None:
        """
        Return the oldest parcel whose transit window at ``eye`` holds time t.

        Parameters
        ----------
        eye : str
            A photo-eye's name.
        t : float
            The scan time [s, simulated].

        Returns
        -------
        Tracked or None
            The parcel, or None.

        """
        enc = self.enc_at(t)
        tol = self.config.tracking_tolerance + self.v * self.config.scan_period
        for p in self.parcels:
            if eye in p.confirmed or not self.checkpoint(p, eye):
                continue
            if abs(self.lead_x(p, enc) - self.eye_x[eye]) <= tol:
                return p
        return None

    def expected_clear(self, p: Tracked, eye: str, t_rise: float) -> float:
        """
        When a parcel that blocked ``eye`` at t_rise should clear it [s].

        Parameters
        ----------
        p : Tracked
            A tracked parcel.
        eye : str
            A photo-eye's name.
        t_rise : float
            When it blocked the eye [s].

        Returns
        -------
        float
            The time [s].

        """
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

    def retired(self, p: Tracked) -> bool:
        """
        Done, and no longer needed for the disk schedule or the photo-eyes.

        Parameters
        ----------
        p : Tracked
            A tracked parcel.

        Returns
        -------
        bool
            Whether it is no longer needed.

        """
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

    def prune(self) -> None:
        """Drop the retired parcels from the list."""
        self.parcels = [p for p in self.parcels if not self.retired(p)]

    def clear(self, io: ScanIO, why: str) -> None:
        """
        Forget every parcel (their outcome: aborted) and flush the belt of what is left.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        why : str
            The reason.

        """
        for p in self.parcels:
            if not p.done:
                io.finish(p, "unknown", R_ABORTED)
        self.parcels = []
        self.pending_labels.clear()
        for e in self.eyes.values():
            e.by = None
            e.unexpected = False
        self.flush_until = self.flush_distance()
        io.log("warn", f"tracking cleared ({why}); flushing the belt")

    def restart_eyes(self) -> None:
        """After a reset: every eye's blocked time counts from now; one blocked is unexplained."""
        for e in self.eyes.values():
            e.since = self.t
            e.unexpected = bool(e.blocked)

    # --- inputs --------------------------------------------------------------------------------
    def first_seen(self, first: dict) -> None:
        """
        Take each sensor's first known bit as its state (no edge, nothing explains it).

        Parameters
        ----------
        first : dict
            {sensor: first known bit}.

        """
        for s, blocked in first.items():
            eye = self.eyes[s]
            eye.blocked = blocked
            eye.since = self.t
            eye.unexpected = blocked

    def on_edge(self, io: ScanIO, edge: Edge) -> None:
        """
        Take a sensor edge.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        edge : Edge
            A sensor edge.

        """
        s = edge.sensor
        eye = self.eyes[s]
        eye.blocked = edge.rising
        eye.since = edge.t
        if not edge.rising:
            eye.cleared_at = edge.t
        if s in self.side_of_sensor:
            eye.unexpected = False
            if edge.rising:
                self.on_chute(io, self.side_of_sensor[s], edge.t)
            return
        if s == self.config.scan_eye:
            self.on_scan_eye(edge)
            return
        if edge.rising:
            p = self.expected_at(s, edge.t)
            if p is None:
                eye.by = None
                eye.unexpected = True
                if self.encoder < self.flush_until:
                    self.counts["untracked"] += 1
                else:
                    io.log("warn", f"{s}: blocked at {edge.t:.3f} s with no parcel due")
                return
            eye.by = p.seq
            eye.unexpected = False
            p.confirmed[s] = edge.t
            # re-synchronise: the leading edge is exactly at the eye now
            p.enc_rise = self.enc_at(edge.t) - (self.eye_x[s] - self.x_scan)
        else:
            p = self.by_seq(eye.by)
            if p is not None:
                p.cleared[s] = edge.t
            eye.by = None
            eye.unexpected = False

    def on_scan_eye(self, edge: Edge) -> None:
        """
        Take an edge of the scanner's photo-eye.

        Parameters
        ----------
        edge : Edge
            A sensor edge.

        """
        eye = self.eyes[self.config.scan_eye]
        if edge.rising:
            self.seq += 1
            p = Tracked(self.seq, self.enc_at(edge.t), edge.t)
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
            p = self.by_seq(eye.by)
            if p is not None and p.length is None:
                p.length = self.v * (edge.t - p.t_scan) if self.belt_running else None
            eye.by = None

    def apply_labels(self, io: ScanIO, labels, running: bool) -> None:
        """
        Give scanner labels to their parcels; a label with no parcel is the eye's fault.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        labels : list of str
            The labels read this scan.
        running : bool
            The belt runs.

        """
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
            if running and not seen:
                io.fault(
                    "stuck_off",
                    f"{self.config.scan_eye}: the scanner read {label!r} at "
                    f"{t_l:.3f} s but the photo-eye never blocked",
                    self.config.scan_eye,
                )

    def on_chute(self, io: ScanIO, dest: str, t: float) -> None:
        """
        Finish the parcel planned for the chute that blocked, or the one over the field.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        dest : str
            The chute's destination.
        t : float
            The scan time [s, simulated].

        """
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
                io.finish(p, dest)
                return
        # a parcel that was not meant for this chute: the one over the field
        for p in self.parcels:
            if p.done or p.length is None:
                continue
            te = self.t_enter(p)
            if te - tol <= t <= te + (p.length + b) / self.v + tol:
                io.finish(p, dest)
                io.log(
                    "error",
                    f"parcel {p.seq} ({p.label}) entered the {dest} chute; planned {p.plan}",
                )
                return
        self.counts["unexpected_chute"] += 1
        io.log("warn", f"{self.chute_of[dest]}: a parcel entered with none tracked there")
