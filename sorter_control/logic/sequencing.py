"""
Diverter sequencing: decisions, spacing, and the pop-up and disk-angle outputs.

Decisions are taken as late as the actuators allow (so a routing update that
arrives after the scan still counts): the destination comes from the routing
table, and the divert is checked against its neighbours with
``timing.GapModel``: if the gap to the parcel ahead, or to the one behind, is
too short for the disks to serve both, the parcel is sent straight and flagged
rather than mis-sorted (unless ``gap_rules`` is off: then every divert the model
allows is made, whatever the spacing, to show what the rules prevent). The disks
go up so that the stroke ends as the leading edge reaches the field (stroke time,
one scan period and the service latency ahead), and down only after the model
core's predicted commit time t_commit.

Every service call the program makes goes through here (``command``), so that
one kind of call is never in flight twice.
"""

from __future__ import annotations

import math

from sorter_control.timing import GapModel, side_of
from sorter_control.logic.image import Command, DiverterState, ScanIO, ScanOutput
from sorter_control.logic.routing import RoutingTable
from sorter_control.logic.tracking import (
    R_CANNOT,
    R_FAULT,
    R_GAP,
    R_LATE,
    R_NOT_EXECUTING,
    Tracked,
    Tracker,
)


class DiverterSequencer:
    """What the disks do and when, for the parcels the tracker follows."""

    def __init__(self, config, gaps: GapModel, routing: RoutingTable, tracker: Tracker, counts):
        self.config = config
        self.gaps = gaps
        self.routing = routing
        self.tr = tracker
        self.counts = counts
        self.last_decided: Tracked | None = None
        self.cmd_id = 0
        self.in_flight: dict[int, Command] = {}
        self.commanded_up: bool | None = None
        self.commanded_alpha: float | None = None
        self.alpha_ready_at: float | None = None  # when the commanded angle should be reached [s]
        self.diverter: DiverterState | None = None  # as the cell last reported it
        self.diverter_silent = False  # a diverter call timed out (until reset)

    # --- service calls -------------------------------------------------------------------------
    def command(self, out: ScanOutput, kind: str, value, t: float) -> Command:
        """
        Queue a diverter command.

        Parameters
        ----------
        out : ScanOutput
            This scan's outputs.
        kind : str
            The command (popup, alpha).
        value : object
            Its value.
        t : float
            The scan time [s].

        Returns
        -------
        Command
            The queued call.

        """
        self.cmd_id += 1
        cmd = Command(self.cmd_id, kind, value, t)
        self.in_flight[cmd.id] = cmd
        out.commands.append(cmd)
        self.counts["commands"] += 1
        return cmd

    def busy(self, kind: str) -> bool:
        """
        Return whether a call of that kind is under way.

        Parameters
        ----------
        kind : str
            The command (popup, alpha).

        Returns
        -------
        bool
            Whether a call of that kind is under way.

        """
        return any(c.kind == kind for c in self.in_flight.values())

    def forget_outputs(self) -> None:
        """Forget what was commanded: the diverter's state is unknown, write both afresh."""
        self.commanded_up = None
        self.commanded_alpha = None

    # --- the disk angle ------------------------------------------------------------------------
    def alpha_end(self) -> float | None:
        """Return the disk angle the committed plan ends with [deg]."""
        for p in reversed(self.tr.parcels):
            if p.committed and p.alpha is not None:
                return p.alpha
        return self.commanded_alpha

    def lead_needed(self, dest: str) -> float:
        """
        How long before its entry a parcel for ``dest`` must be decided [s].

        The stroke only: the disk angle is set ahead for the next divert in line
        whenever no committed divert holds it (see ``desired_outputs``), so it does
        not force decisions early; ``alpha_ready`` checks it made it in time.

        Parameters
        ----------
        dest : str
            A destination.

        Returns
        -------
        float
            The lead [s].

        """
        return 0.0 if side_of(dest) == 0 else self.gaps.act.stroke_total

    def alpha_ready(self, dest: str) -> float:
        """
        When the disks can be at the angle for ``dest`` if nothing committed holds them [s].

        Parameters
        ----------
        dest : str
            A destination.

        Returns
        -------
        float
            The time [s].

        """
        act = self.gaps.act
        target = self.gaps.alpha_for(dest)
        t = self.tr.t
        if self.commanded_alpha == target:
            # under way since the command: the reported angle may be a scan or two old
            return self.alpha_ready_at if self.alpha_ready_at is not None else t
        # not commanded yet: this scan's outputs will
        start = (
            math.degrees(self.diverter.alpha)
            if self.diverter is not None
            else self.commanded_alpha
        )
        if start is None:
            start = -target
        return t + act.latency + act.slew_time(start, target)

    def alpha_held(self) -> bool:
        """Whether a committed divert still needs the disk angle it set."""
        tr = self.tr
        for p in tr.parcels:
            if (
                p.committed
                and side_of(p.plan) != 0
                and p.prediction is not None
                and tr.t < tr.t_enter(p) + p.prediction.t_commit
            ):
                return True
        return False

    # --- decisions -----------------------------------------------------------------------------
    def decide(self, io: ScanIO, executing: bool = True) -> None:
        """
        Commit every parcel whose last moment to decide has come.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        executing : bool
            The cell is in PackML Execute (or does not say). Not executing, a parcel whose
            moment has come goes straight (``not_executing``): the controller sorts only
            in Execute, and decides each parcel as late as it would have.

        """
        tr = self.tr
        pending = [p for p in tr.parcels if not p.committed and not p.done]
        if not pending:
            return
        # latest moment each must be decided; a parcel ahead is decided no later than one behind it
        deadlines = []
        for p in pending:
            dest = p.bound or self.routing.lookup(p.label)[0]
            deadlines.append(tr.t_enter(p) - self.lead_needed(dest) - self.config.scan_period)
        for i in range(len(deadlines) - 2, -1, -1):
            deadlines[i] = min(deadlines[i], deadlines[i + 1])
        act = self.gaps.act
        for p, dl in zip(pending, deadlines):
            if tr.t < dl:
                break
            if (
                p.length is None
                and tr.t + act.popup_stroke_time + act.latency + act.scan_period <= tr.t_enter(p)
            ):
                # its trailing edge is still at the scanner: wait for the length while the
                # stroke can still make it (the margin is spent first)
                break
            if executing:
                self.commit(io, p)
            else:
                self._send_straight(p, R_NOT_EXECUTING)
                self.counts["not_executing"] += 1

    def decide_faulted(self) -> None:
        """In a fault every parcel goes straight (the disks are down)."""
        for p in self.tr.parcels:
            if not p.committed and not p.done:
                self._send_straight(p, R_FAULT)

    def _send_straight(self, p: Tracked, result: str) -> None:
        p.committed = True
        p.plan = "straight"
        p.asked = self.routing.lookup(p.label)[0]
        p.result = result
        self.last_decided = p

    def commit(self, io: ScanIO, p: Tracked) -> None:
        """
        Decide parcel p for good: its destination and whether the disks can serve it.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        p : Tracked
            A tracked parcel.

        """
        tr = self.tr
        v = tr.v
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
                io.log(
                    "warn",
                    f"parcel {p.seq} ({p.label}): routing now says {asked}, but the disks "
                    f"were already kept up for it to go {p.bound}",
                )
            self.divert(io, p, p.bound, forced=True)
            return
        if p.length is None:
            p.result = R_LATE
            self.counts["late"] += 1
            io.log(
                "warn", f"parcel {p.seq} ({p.label}): length unknown at decision time; straight"
            )
            return
        if side_of(asked) == 0:
            if prev is not None and prev.length is not None and side_of(prev.plan) != 0:
                headway = tr.t_enter(p) - tr.t_enter(prev)
                if headway < self.gaps.headway(prev.length, prev.plan, p.length, "straight", v):
                    io.log(
                        "error",
                        f"parcel {p.seq} ({p.label}) follows parcel {prev.seq} too closely "
                        f"to pass the raised disks straight",
                    )
            return
        pred = self.gaps.prediction(p.length, v, asked)
        if not pred.feasible:
            p.result = R_CANNOT
            self.counts["cannot_divert"] += 1
            io.log(
                "warn",
                f"parcel {p.seq} ({p.label}): the model cannot bring a {p.length:.2f} m parcel "
                f"to the {asked} chute within the disk field; straight",
            )
            return
        if prev is not None and prev.length is not None and self.config.gap_rules:
            headway = tr.t_enter(p) - tr.t_enter(prev)
            need = self.gaps.headway(
                prev.length, prev.plan, p.length, asked, v, alpha_before_deg=self.alpha_end()
            )
            if headway < need:
                self.refuse(
                    io,
                    p,
                    asked,
                    f"{(headway * v - prev.length):.3f} m behind parcel {prev.seq} "
                    f"({prev.plan}); {(need * v - prev.length):.3f} m needed",
                )
                return
        # late only if even without the margins the stroke cannot end before the entry
        act = self.gaps.act
        late = tr.t + act.popup_stroke_time + act.latency > tr.t_enter(p) + 1e-9
        if not late and not self.alpha_held():
            late = self.alpha_ready(asked) > tr.t_enter(p) + 1e-9
        if late:
            p.result = R_LATE
            self.counts["late"] += 1
            io.log(
                "warn",
                f"parcel {p.seq} ({p.label}): decided too late to divert (stroke or disk "
                "angle); straight",
            )
            return
        self.divert(io, p, asked, forced=False)

    def divert(self, io: ScanIO, p: Tracked, dest: str, forced: bool) -> None:
        """
        Divert p unless a parcel behind it could then neither pass straight nor follow.

        Parcels too close behind to go straight past raised disks must follow p to
        the same side (a chain, each bound to it); a chain that breaks refuses p.
        A bound p (forced) cannot be refused: a break behind it binds the next one.
        Without ``gap_rules`` nothing behind p is looked at.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        p : Tracked
            A tracked parcel.
        dest : str
            A destination.
        forced : bool
            Divert whatever follows.

        """
        tr = self.tr
        v = tr.v
        cfg = self.config
        length = p.length if p.length is not None else cfg.max_parcel_length
        pred = self.gaps.prediction(length, v, dest)
        chain = []
        cur, cur_len, cur_te = p, length, tr.t_enter(p)
        while cfg.gap_rules:
            nxt = tr.next_after(cur)
            if nxt is None:
                # nobody seen behind: a parcel not yet at the scanner is at least this far back
                tail = tr.lead_x(cur) - (cur.length if cur.length is not None else math.inf)
                open_gap = max(0.0, tail - tr.x_scan) if math.isfinite(tail) else 0.0
                need = self.gaps.headway(cur_len, dest, cfg.max_parcel_length, "straight", v)
                if (cur_len + open_gap) / v < need and not cfg.open_chains:
                    if not forced:
                        self.refuse(
                            io,
                            p,
                            dest,
                            f"the scanner cannot see far enough behind parcel "
                            f"{cur.seq}: a parcel arriving {open_gap:.3f} m behind it could "
                            "neither pass the raised disks straight nor be refused",
                        )
                        return
                break
            nxt_len = nxt.length if nxt.length is not None else cfg.max_parcel_length
            headway = tr.t_enter(nxt) - cur_te
            if headway >= self.gaps.headway(cur_len, dest, nxt_len, "straight", v):
                break
            follow = self.routing.lookup(nxt.label)[0]
            if (
                follow != dest
                or nxt.length is None
                or headway < self.gaps.headway(cur_len, dest, nxt_len, dest, v)
            ):
                if not forced:
                    self.refuse(
                        io,
                        p,
                        dest,
                        f"parcel {nxt.seq} ({nxt.label}, {follow}) follows "
                        f"{headway * v - cur_len:.3f} m behind parcel {cur.seq} and could "
                        "neither pass the raised disks straight nor follow to the same side",
                    )
                    return
                io.log(
                    "error",
                    f"parcel {nxt.seq} ({nxt.label}) follows {headway * v - cur_len:.3f} m "
                    f"behind a parcel the disks are already committed to; it goes {dest} with it",
                )
            chain.append(nxt)
            cur, cur_len, cur_te = nxt, nxt_len, tr.t_enter(nxt)
        for q in chain:
            q.bound = dest
        p.plan = dest
        p.prediction = pred
        p.alpha = self.gaps.alpha_for(dest)

    def refuse(self, io: ScanIO, p: Tracked, asked: str, why: str) -> None:
        """
        Refuse a parcel's destination, with the reason.

        Parameters
        ----------
        io : ScanIO
            This scan's inputs and outputs.
        p : Tracked
            A tracked parcel.
        asked : str
            The destination asked for.
        why : str
            The reason.

        """
        p.plan = "straight"
        p.result = R_GAP
        self.counts["gap_too_short"] += 1
        io.log(
            "warn", f"parcel {p.seq} ({p.label}) for {asked}: gap too short, sent straight: {why}"
        )

    # --- outputs -------------------------------------------------------------------------------
    def desired_outputs(self) -> tuple[bool, float | None]:
        """
        (disks up, disk angle in deg or None to keep) as the committed plan wants them now.

        The disk angle follows the first committed divert not yet handed to its chute;
        with none, it is set ahead for the next parcel in line that routing sends to a
        chute (swinging the lowered disks moves nothing).
        """
        tr = self.tr
        act = self.gaps.act
        up = False
        alpha = None
        for p in tr.parcels:
            if not p.committed or side_of(p.plan) == 0 or p.prediction is None:
                continue
            if p.done and p.reached != p.plan:
                continue
            te = tr.t_enter(p)
            t_down = te + p.prediction.t_commit
            if tr.t >= t_down:
                continue
            if alpha is None:
                alpha = p.alpha
            if alpha == p.alpha and tr.t >= te - act.stroke_total:
                up = True
        if alpha is None:
            for p in tr.parcels:
                if p.committed or p.done:
                    continue
                dest = p.bound or self.routing.lookup(p.label)[0]
                if side_of(dest) != 0:
                    alpha = self.gaps.alpha_for(dest)
                    break
        return up, alpha

    def write_outputs(self, out: ScanOutput, state: str) -> None:
        """
        Call the services that bring the diverter to what the plan (or the fault) wants.

        Parameters
        ----------
        out : ScanOutput
            This scan's outputs.
        state : str
            The controller's state.

        """
        t = self.tr.t
        if self.diverter_silent:
            return  # the diverter did not answer: leave it alone until reset, whatever the state
        if state == "resetting":
            return
        if state != "running":
            up, alpha = False, None
            if state == "estop":
                return  # the cell has dropped the disks and refuses commands
        else:
            up, alpha = self.desired_outputs()
        if alpha is not None and alpha != self.commanded_alpha and not self.busy("alpha"):
            self.command(out, "alpha", alpha, t)
            start = self.commanded_alpha
            if self.diverter is not None:
                start = math.degrees(self.diverter.alpha)
            act = self.gaps.act
            self.alpha_ready_at = (
                t + act.latency + act.slew_time(-alpha if start is None else start, alpha)
            )
            self.commanded_alpha = alpha
        if up != self.commanded_up and not self.busy("popup"):
            self.command(out, "popup", up, t)
            self.commanded_up = up
