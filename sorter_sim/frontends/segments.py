"""
A line across processes: parcels handed from one segment of the line to the next over ROS 2.

A line node may own only some of the line's stations (``first_station``,
``line_stations``): a segment. ``SegmentLink`` joins it to its neighbours. A parcel
that leaves the segment's last station over its straight exit is published on
``line/handover/<next station>`` (the next segment's first station, e.g.
``line/handover/S04``) with everything the next station needs to go on integrating
it exactly: its time (the end of the period it crossed the exit in), id, label,
pose and twist, contact mode, stick-gauge warm start and dimensions, every float
as its exact hexadecimal form (``float.hex``), so the next segment continues from
bit-identical numbers. After each slice the segment publishes a horizon on the same
topic: every parcel it handed over up to that time has been sent (one reliable
topic, one writer: the order holds). A fast segment running on says one every
``HORIZON_STRIDE - 1`` slices, and the newest as soon as it stops: each carries the
ones before it.

Time, conservatively: a segment with a neighbour downstream in ``lockstep`` or
``fast`` mode does not start before that neighbour reads its hand-overs (a parcel
sent to nobody would be lost), and a segment downstream never advances past its
upstream neighbour's horizon, so it takes each parcel at the
period it left upstream, and the line's result does not depend on how it is split
(tested against one process). A segment depends only on the one upstream; the
first one runs freely, the others follow as a pipeline, each at most one slice
behind. In ``realtime`` mode every segment runs on the wall clock and does not
wait: a parcel that arrives after its period is taken at once, in the state it left
with (it is late by the hand-over's latency, which ``stats`` reports).

Custody, so that a segment can restart: a segment keeps every parcel it handed on
(its *outbox*) until the parcel has left the segment downstream: into a chute, off
the line's end, jammed, or handed on again and left the one after (each segment tells
its upstream neighbour, on ``line/handover/<its first station>/left``, the ids that
left it, forwarding those its own downstream neighbour reports). A segment that
starts says ``hello`` there with an identity of its own (its process and start
time), again every ``HELLO_MIN_S`` until answered; the segment upstream answers a
``hello`` by sending its whole outbox again, then its horizon, then ``answered`` naming
the hello (a hello said again after its answer is answered again: the answer was
lost). In lock-step and fast mode a segment runs only once its hello is answered. A
segment restarted after a crash thus
gets back every parcel it held or was being handed, each in the state it was handed
over in, before it runs again from t = 0 (its stations empty, the time
up to the present quickly) and takes each at the period it first came: the parcels
leave it as they did before, into the same chutes at the same times, except where
one of them had met a parcel that had already left (which is not re-sent). A
segment takes a parcel once: one it has taken (by id) is dropped as a duplicate, so
the segment downstream of a restarted one drops what the restarted one hands it
again. The first segment's stream is its own state: restarting it starts the
stream over. In ``realtime`` mode a restarted segment's clock starts at 0 again and
the parcels sent back wait for their time: restart a real-time line whole.

Ownership (``segment_owners.Ownership``): every segment says on ``line/owners``
(latched) which stations it owns, with its identity and node name, every half second.
A second segment claiming a station is refused: the one that started later holds
(takes nothing, runs nothing), and both say so in one line. A claim lapses when its
segment has not been heard for ``CLAIM_LEASE_S`` (it died): one restarted in its place
takes over then, or at once when it is the same node come back (its name and stations,
started later: a node name is one node of the ROS graph), and the old one, were it
still alive, holds. A segment answers a ``hello`` only from the owner of the stations
downstream, at most once a second (``HELLO_MIN_S``), and takes ``left`` and horizons
only from the owners next to it.

The messages are ``diagnostic_msgs/DiagnosticStatus``: ``name`` ``parcel``,
``horizon`` or ``answered`` downstream, ``left`` or ``hello`` upstream, ``owns`` and
``progress`` to all, ``values`` the fields. Each is read whole before it touches anything
(``runtime.handover``: the fields, their ranges, the parcel's physics); a horizon moves
forward by at most ``HORIZON_STRIDE`` slices once the first one is in; a parcel id this
segment has taken is not taken again, nor one for a time its upstream has closed, nor
one further ahead of the horizon than its upstream runs, nor a second parcel at the
same place and time; a claim from an identity older than the host is refused. A message that
fails is refused in one line, counted (``stats['refused']``) and changes nothing; it
never stops the segment. A parcel handed here that is not taken for want of room, or a
different parcel under an id taken from the same owner upstream, is said lost
(``on_lost``: the line node's exit ``lost``, with the cause), never dropped silently.

With a line key (``sorter_ros.line_key``, ``SORTER_LINE_KEY``) every message is sealed
as it is sent and its seal checked before anything above: one without a good seal,
or a replay, is refused the same way (``sorter_ros.line_seal``).
"""

from __future__ import annotations

import math
import os
import time

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy._rclpy_pybind11 import RCLError
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sorter_sim.model.description import shown
from sorter_ros.line_key import SealError
from sorter_ros.line_seal import LineSeal
from sorter_sim.runtime.cell import Handoff
from sorter_sim.frontends.segment_owners import (  # noqa: F401 (the names this module gave)
    CLAIM_LEASE_S,
    CLAIM_PERIOD_S,
    CLAIM_SETTLE_S,
    OWNERS_QOS,
    Ownership,
    pairs,
)
from sorter_sim.runtime.handover import (
    HandoverError,
    HandoverLimits,
    MAX_IDS,
    message_fields,
    parse_answer_fields,
    parse_handover_fields,
    parse_horizon_fields,
    parse_identity,
    parse_left_fields,
    parse_progress_fields,
)

# every hand-over kept until delivered: a parcel must never be lost between segments
HANDOVER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
# each segment's time for a barrier: only the newest of each matters
PROGRESS_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
HELLO_MIN_S = 1.0  # s between two answers to a hello (each re-sends the whole outbox)
# slices a fast segment runs on between two horizons it says. A horizon says only "all
# sent up to t": the newest carries every earlier one, and the pass it stops in says it.
# Each message stays in the reliable writer until every reader took it; a downstream
# segment killed counts as a reader until DDS drops its participant (20 s), and a
# horizon every slice (hundreds a second) filled the writer before then, so the segment
# restarted in its place waited that long for its answer
HORIZON_STRIDE = 8
MAX_REMEMBERED = 4096  # parcels taken kept whole, to tell a copy from another parcel


def _same_handoff(a: Handoff, b: Handoff) -> bool:
    """Return True when two hand-overs are one parcel sent twice (a hello's answer)."""
    return (a.t_ns, a.label, a.state, a.mode, a.dims) == (b.t_ns, b.label, b.state, b.mode, b.dims)


def handover_message(h: Handoff, wall_ns: int) -> DiagnosticStatus:
    """
    Return the message of one hand-over, every float in its exact hexadecimal form.

    Parameters
    ----------
    h : Handoff
        The parcel as the segment's last station gave it.
    wall_ns : int
        The wall-clock time it is sent [ns], for the latency.

    Returns
    -------
    DiagnosticStatus
        The message.

    """
    values = {
        't_ns': str(int(h.t_ns)),
        'id': str(int(h.parcel_id)),
        'label': h.label,
        'state': ' '.join(float(v).hex() for v in h.state),
        'mode': str(int(h.mode)),
        'gauge': ' '.join(float(v).hex() for v in h.gauge),
        'dims': ' '.join(float(v).hex() for v in h.dims),
        'wall_ns': str(int(wall_ns)),
    }
    return DiagnosticStatus(
        name='parcel', values=[KeyValue(key=k, value=v) for k, v in values.items()]
    )


def parse_handover(msg: DiagnosticStatus, limits: HandoverLimits) -> tuple[Handoff, int]:
    """
    Return the hand-over a message carries and its send time; HandoverError naming what is wrong.

    Parameters
    ----------
    msg : DiagnosticStatus
        A ``parcel`` message.
    limits : HandoverLimits
        What the receiving segment's first station can be handed (``runtime.handover``).

    Returns
    -------
    (Handoff, int)
        The parcel and the wall-clock time it was sent [ns].

    """
    return parse_handover_fields(pairs(msg), limits)


class SegmentLink:
    """
    A line node's links to the segments up- and downstream (see the module).

    Parameters
    ----------
    node : rclpy.node.Node
        The line node; its ``seal`` (a ``LineSeal``), when it has one, seals and checks
        every line message (else ``SORTER_LINE_KEY``'s key, or an open line).
    upstream, downstream : str or None
        The station whose hand-over topic this segment reads (its own first one) and
        writes (the next segment's first one); None at the line's ends.
    dx : float
        The upstream station's origin minus this segment's first one's [m].
    dt_ns : int
        The control period [ns].
    owned : (int, int, int)
        This segment's first station (0-based), its stations and the line's.
    limits : HandoverLimits
        What its first station can be handed.
    max_step_k : int
        The most periods the segment upstream advances between two horizons (a slice).
    room : callable
        Returns how many more parcels the first station can take.
    barrier : bool
        With ``segment_sync`` ``barrier``: every segment then says its time on
        ``line/progress`` and none runs more than a slice past the one furthest behind.

    """

    def __init__(
        self,
        node,
        *,
        upstream,
        downstream,
        dx: float,
        dt_ns: int,
        owned: tuple,
        limits: HandoverLimits,
        max_step_k: int,
        room=lambda: 1,
        barrier: bool = False,
    ):
        self.node = node
        # the line key's seal on every message (an open line: none, see line_seal)
        self.seal = getattr(node, 'seal', None) or LineSeal()
        self.upstream = upstream
        self.downstream = downstream
        self.dx = dx
        self.dt_ns = dt_ns
        self.limits = limits
        self.max_step_k = max_step_k
        self._room = room
        self.inbox: list[Handoff] = []
        # the period up to which the segment upstream has handed over everything
        self.horizon_k = 0 if upstream else None
        self._horizon_heard = False
        # a segment with one upstream runs once its hello is answered (the answer ends
        # with ``answered``): every parcel it answers for is in its inbox by then
        self.answered = upstream is None
        self._pending_answer = None  # the sender of an answer waiting for its claim
        self.stats = {
            'sent': 0,
            'received': 0,
            'refused': 0,
            'late': 0,
            'messages': 0,
            'resent': 0,
            'duplicates': 0,
            'waits': 0,
            'claim_conflicts': 0,
            'lost': 0,
        }
        self.latencies_ns: list[int] = []  # wall time from sending to receiving
        # called after each message from a neighbour: a held line's cue to look again
        self.on_heard = None
        # this segment's identity for its neighbours: a restart is a new one
        self.identity = f'{os.getpid()}-{time.time_ns()}'
        self._owned = owned
        self.owners = (
            Ownership(
                node, self.identity, owned, lambda why: self._refuse(why, 'owners'), self.seal
            )
            if upstream or downstream
            else None
        )
        # custody (see the module): what this segment handed on and still answers for
        self.outbox: dict[int, Handoff] = {}
        self._downstream_identity = None
        self._pending_hello = None  # a hello waiting for its sender's claim or its turn
        self._pending_horizon = None  # (t_ns, sender): a horizon waiting for its owner's claim
        self._last_resend = -math.inf
        self._last_horizon_ns = None  # the newest horizon (said, or waiting to be)
        self._said_horizon_ns = None  # the newest one said
        self._taken: set[int] = set()  # every parcel id taken, to drop a second copy
        # the newest parcels taken, by id and by time: a copy is told from another parcel
        self._recent: dict[int, tuple[Handoff, str | None]] = {}  # and its owner upstream
        self._at_time: dict[int, list[Handoff]] = {}
        # called with (Handoff, why) for a parcel handed here that is lost (LineNode: an exit)
        self.on_lost = None
        self._left: list[int] = []  # ids that left this segment, to tell upstream
        self._hello_said = -math.inf  # when the hello was last said (monotonic s)
        self._queue: list[DiagnosticStatus] = []  # to the segment downstream, in order
        self._pub = self._pub_left = None
        if downstream:
            self._pub = node.create_publisher(
                DiagnosticStatus, f'line/handover/{downstream}', HANDOVER_QOS
            )
            node.create_subscription(
                DiagnosticStatus,
                f'line/handover/{downstream}/left',
                self._guarded(self._on_custody, downstream, f'line/handover/{downstream}/left'),
                HANDOVER_QOS,
            )
        self._barrier = owned if barrier else None
        self._progress: dict[int, tuple[int, int]] = {}  # first station -> (stations, k)
        if barrier:
            self._pub_progress = node.create_publisher(
                DiagnosticStatus, 'line/progress', PROGRESS_QOS
            )
            node.create_subscription(
                DiagnosticStatus,
                'line/progress',
                self._guarded(self._on_progress, 'progress', 'line/progress'),
                PROGRESS_QOS,
            )
            self._progress[owned[0]] = (owned[1], 0)
        if upstream:
            node.create_subscription(
                DiagnosticStatus,
                f'line/handover/{upstream}',
                self._guarded(self._on_message, None, f'line/handover/{upstream}'),
                HANDOVER_QOS,
            )
            self._pub_left = node.create_publisher(
                DiagnosticStatus, f'line/handover/{upstream}/left', HANDOVER_QOS
            )

    def _guarded(self, callback, station, topic: str):
        """Return ``callback`` refusing, in one line, any message it cannot read or not sealed."""
        topic = self.node.resolve_topic_name(topic)

        def guarded(msg):
            try:
                callback(self.seal.opened(topic, msg))
            except (HandoverError, SealError) as exc:
                self._refuse(str(exc), station)
            if self.on_heard is not None:
                self.on_heard()

        return guarded

    def connected(self) -> bool:
        """Return True when a segment downstream reads this one's hand-overs."""
        return self._pub is not None and self._pub.get_subscription_count() > 0

    def holds(self) -> bool:
        """Return True while the segment may not run: its stations are another's, or unsettled."""
        return self.owners is not None and not self.owners.runs()

    def hand_on(self, handoffs: list) -> None:
        """Send the parcels the segment handed on (in order, behind any not yet sent)."""
        if self._pub is None:
            return
        now = time.time_ns()
        for h in handoffs:
            self.outbox[h.parcel_id] = h
            self._enqueue(handover_message(h, now))
            self.stats['sent'] += 1
        self._flush()

    def horizon(self, t_ns: int, coalesce: bool = False) -> None:
        """
        Say that every parcel handed on up to ``t_ns`` has been sent.

        Parameters
        ----------
        t_ns : int
            The time [ns].
        coalesce : bool
            Say it only once it is ``HORIZON_STRIDE - 1`` slices past the last one said
            (the next pass cannot take it past ``HORIZON_STRIDE``, the most a segment
            downstream takes); until then it waits for a later one or for
            ``flush_horizon`` (a fast segment running on).

        """
        if self._pub is None:
            return
        self._last_horizon_ns = t_ns
        said = self._said_horizon_ns
        if coalesce and said is not None:
            if t_ns - said < (HORIZON_STRIDE - 1) * self.max_step_k * self.dt_ns:
                return
        self._said_horizon_ns = t_ns
        self._enqueue(
            DiagnosticStatus(
                name='horizon',
                values=[
                    KeyValue(key='t_ns', value=str(t_ns)),
                    KeyValue(key='identity', value=self.identity),
                ],
            )
        )
        self._flush()

    def flush_horizon(self) -> None:
        """Say the newest horizon if it is still waiting (the segment stopped running)."""
        if self._last_horizon_ns is not None and self._last_horizon_ns != self._said_horizon_ns:
            self.horizon(self._last_horizon_ns)

    def _enqueue(self, msg: DiagnosticStatus) -> None:
        """Queue a message downstream, sealed now: its counter rises in the queue's order."""
        self._queue.append(self.seal.sealed(self._pub.topic_name, msg))

    def _send(self, pub, msg: DiagnosticStatus) -> None:
        """Publish a message on ``pub`` at once, sealed."""
        pub.publish(self.seal.sealed(pub.topic_name, msg))

    def backlogged(self) -> bool:
        """Return True while messages wait for the segment downstream to take them."""
        self._flush()
        return bool(self._queue)

    def _flush(self) -> None:
        # one queue, in order: a horizon never overtakes a parcel. A reliable writer that
        # keeps every message refuses more while the reader has not taken the ones it has
        # (a segment downstream stalled): what it refuses waits here, and the segment
        # stops advancing until it goes (LineNode.advance), rather than losing a parcel
        while self._queue:
            try:
                self.node._publish(self._pub, self._queue[0])
            except RCLError:
                self.stats['waits'] += 1
                return
            self._queue.pop(0)
            self.stats['messages'] += 1

    def progress(self, k: int) -> None:
        """Say this segment's time to the others (``segment_sync`` ``barrier``)."""
        first, n, _ = self._barrier
        self._progress[first] = (n, k)
        self._send(
            self._pub_progress,
            DiagnosticStatus(
                name='progress',
                values=[
                    KeyValue(key='identity', value=self.identity),
                    KeyValue(key='first', value=str(first)),
                    KeyValue(key='stations', value=str(n)),
                    KeyValue(key='k', value=str(k)),
                ],
            ),
        )

    def line_k(self) -> int:
        """Return the time of the segment furthest behind; 0 until every one has spoken."""
        covered = sum(n for n, _ in self._progress.values())
        if covered < self._barrier[2]:
            return 0
        return min(k for _, k in self._progress.values())

    def _on_progress(self, msg: DiagnosticStatus) -> None:
        identity, first, n, k = parse_progress_fields(pairs(msg), self._barrier[2])
        if identity == self.identity:
            return
        claim = self.owners.claim_of(identity) if self.owners is not None else None
        # its claim, or (said before its claim reached here, or lapsed in a stalled
        # reader) a part of the line no other segment's times cover: never a second
        # entry for stations already timed, which would hold the barrier back for good
        other = [(f, m) for f, (m, _) in self._progress.items() if (f, m) != (first, n)] + [
            (self._barrier[0], self._barrier[1])
        ]
        if (claim is not None and claim != (first, n)) or any(
            f < first + n and first < f + m for f, m in other
        ):
            raise HandoverError(
                f'progress for stations {first + 1}-{first + n} from {identity!r}, which '
                'does not own them'
            )
        self.owners.heard_from(identity)
        # only the newest of each segment's is kept on the way (a reader behind loses
        # some): forward, by whatever it ran since
        old = self._progress.get(first, (n, 0))[1]
        self._progress[first] = (n, max(old, k))

    def left(self, parcel_id: int) -> None:
        """Note that a parcel left this segment (a chute, the line's end, jammed)."""
        if self._pub_left is not None:
            self._left.append(int(parcel_id))

    def service(self) -> None:
        """Keep the claim, say hello upstream once it listens, tell it which parcels left."""
        if self.owners is not None:
            self.owners.service()
        self._serve_hello()
        pending, self._pending_horizon = self._pending_horizon, None
        if pending is not None:
            try:
                self._take_horizon(*pending)
            except HandoverError as exc:
                self._refuse(str(exc))
        if self._pending_answer is not None:
            self._take_answer(self._pending_answer)
        if self._pub_left is None:
            return
        now = time.monotonic()
        if (
            not self.answered
            and now - self._hello_said >= HELLO_MIN_S
            and self._pub_left.get_subscription_count() > 0
        ):
            # said again until answered: the segment upstream keeps one hello waiting,
            # which another's may have taken the place of
            self._send(
                self._pub_left,
                DiagnosticStatus(
                    name='hello', values=[KeyValue(key='identity', value=self.identity)]
                ),
            )
            self._hello_said = now
        if self._left and self._hello_said > -math.inf:
            ids, self._left = self._left, []
            for j in range(0, len(ids), MAX_IDS):
                self._send(
                    self._pub_left,
                    DiagnosticStatus(
                        name='left',
                        values=[
                            KeyValue(key='ids', value=' '.join(map(str, ids[j : j + MAX_IDS]))),
                            KeyValue(key='identity', value=self.identity),
                        ],
                    ),
                )

    def _upstream_owner(self) -> str | None:
        return self.owners.owner_of(self._owned[0] - 1) if self.owners is not None else None

    def _downstream_owner(self) -> str | None:
        return self.owners.owner_of(self._owned[0] + self._owned[1])

    def _on_custody(self, msg: DiagnosticStatus) -> None:
        """Take what the segment downstream says: parcels that left it, or its hello."""
        if msg.name == 'left':
            ids, sender = parse_left_fields(pairs(msg))
            # from the owner downstream, or the restarted one whose hello was answered
            if sender not in (self._downstream_owner(), self._downstream_identity):
                raise HandoverError(
                    f'a left message from {sender!r}, not the owner of {self.downstream}'
                )
            self.owners.heard_from(sender)
            for pid in ids:
                if self.outbox.pop(pid, None) is not None:
                    self.left(pid)  # it has left this segment's custody too
            return
        if msg.name != 'hello':
            raise HandoverError(
                f"a message named {shown(msg.name, 40)}: 'left' or 'hello' expected"
            )
        v = message_fields(pairs(msg), 'hello', ('identity',))
        identity = parse_identity(v['identity'])
        if identity == self._pending_hello:
            return  # said again: it waits for its turn already
        # The one answered, said again: the answer did not reach it. A restarted segment's
        # subscription may match this one's publisher after its own hello got here, and a
        # volatile topic keeps nothing for a late reader: answered again (at most once a
        # second, as any hello), it drops as duplicates what it had taken already.
        owner = self._downstream_owner()
        if self._pending_hello == owner and identity != owner:
            return  # the owner's hello waits for its turn: another's does not take its place
        self._pending_hello = identity
        self._serve_hello()

    def _serve_hello(self) -> None:
        """Answer a pending hello once its sender owns the stations and a second has passed."""
        identity = self._pending_hello
        if identity is None or self.owners is None:
            return
        if identity != self._downstream_owner():
            return  # not (yet) the owner of the stations downstream: it waits
        if time.monotonic() - self._last_resend < HELLO_MIN_S:
            return  # at most one answer a second, whoever asks
        if identity == self._downstream_identity and self._queue:
            return  # its last answer is not all sent yet: a second one would only pile up
        self._pending_hello = None
        self._downstream_identity = identity
        self._last_resend = time.monotonic()
        # a segment that (re)started: everything it answers for, again, in time order
        now = time.time_ns()
        for h in sorted(self.outbox.values(), key=lambda h: (h.t_ns, h.parcel_id)):
            self._enqueue(handover_message(h, now))
            self.stats['resent'] += 1
        if self._last_horizon_ns is not None:
            self.horizon(self._last_horizon_ns)
        # the answer's end: behind every parcel on the one ordered topic, so the segment
        # downstream has them all before it runs
        self._enqueue(
            DiagnosticStatus(
                name='answered',
                values=[
                    KeyValue(key='identity', value=self.identity),
                    KeyValue(key='hello', value=identity),
                ],
            )
        )
        self._flush()
        if self.outbox:
            self.node.get_logger().info(
                f'the segment at {self.downstream} (re)started, or missed its answer: sent '
                f'it again the {len(self.outbox)} parcel(s) it answers for',
                throttle_duration_sec=5.0,
            )

    def due(self, k_end: int) -> list:
        """Return (Handoff, dx) of the parcels that enter by period ``k_end``, in time order."""
        if not self.inbox:
            return []
        now, later = [], []
        for h in self.inbox:
            (now if h.t_ns // self.dt_ns <= k_end else later).append(h)
        self.inbox = later
        return [(h, self.dx) for h in now]

    def _on_message(self, msg: DiagnosticStatus) -> None:
        if self.owners is not None and self.owners.refused():
            raise HandoverError('this segment holds: another segment owns its stations')
        if msg.name == 'horizon':
            self._take_horizon(*parse_horizon_fields(pairs(msg)))
            return
        if msg.name == 'answered':
            sender, hello = parse_answer_fields(pairs(msg))
            if hello == self.identity:
                self._take_answer(sender)
            return  # the answer to another segment's hello (one that holds, or a forger's)
        if msg.name != 'parcel':
            raise HandoverError(
                f"a message named {shown(msg.name, 40)}: 'parcel', 'horizon' or 'answered' "
                'expected'
            )
        h, sent_ns = parse_handover(msg, self.limits)
        self._check_ahead(h)
        if h.parcel_id in self._taken:
            first, sender = self._recent.get(h.parcel_id, (None, None))
            if first is None or _same_handoff(first, h) or sender != self._upstream_owner():
                # sent again to a segment that has it: a hello's answer, or a restarted
                # segment upstream handing its parcels on again (one that met a parcel
                # which had already left may differ: the first one taken stays)
                self.stats['duplicates'] += 1
                return
            # a second, different parcel under an id taken, from the same owner upstream:
            # one of the two is not its; the later one is refused, and said lost
            self._lose(h, 'handed over twice, differently')
            raise HandoverError(
                f'parcel {h.parcel_id}: a different parcel under this id was taken already; '
                'said lost'
            )
        self._check_place(h)
        if len(self.inbox) >= self._room():
            self._lose(h, f'no room at {self.upstream}')
            raise HandoverError(
                f'parcel {h.parcel_id}: station {self.upstream} has no room for another '
                '(max_parcels); said lost'
            )
        self._taken.add(h.parcel_id)
        self._remember(h)
        self.stats['received'] += 1
        if sent_ns:
            self.latencies_ns.append(max(0, time.time_ns() - sent_ns))
        if h.t_ns // self.dt_ns < self.node.line.k:
            self.stats['late'] += 1  # on the wall clock: taken at once, as it left
        self.inbox.append(h)

    def _check_ahead(self, h: Handoff) -> None:
        """
        Refuse a parcel further ahead of its upstream's horizon than that segment runs.

        Every parcel handed on is sent before the horizon that covers its time, and a
        segment runs at most ``HORIZON_STRIDE`` passes past its last horizon: a parcel
        further ahead is not its upstream's (HandoverError).
        """
        k = h.t_ns // self.dt_ns
        lead = HORIZON_STRIDE * self.max_step_k
        if self._horizon_heard and k > self.horizon_k + lead:
            raise HandoverError(
                f'parcel {h.parcel_id} at period {k}: ahead of its upstream\'s horizon (period '
                f'{self.horizon_k}) by more than the {lead} periods it runs between two'
            )

    def _check_place(self, h: Handoff) -> None:
        """Refuse a parcel whose inner circle (half its shorter side) meets one at its time."""
        r = 0.5 * min(h.dims[0], h.dims[1])
        for other in self._at_time.get(h.t_ns, ()):
            gap = math.hypot(h.state[0] - other.state[0], h.state[1] - other.state[1])
            if gap < r + 0.5 * min(other.dims[0], other.dims[1]):
                raise HandoverError(
                    f'parcel {h.parcel_id}: at the same place and time (t_ns {h.t_ns}, '
                    f'{gap:.3g} m apart) as parcel {other.parcel_id}, taken already'
                )

    def _remember(self, h: Handoff) -> None:
        """Keep a parcel taken, by id (with its owner upstream) and by time: the newest few."""
        self._recent[h.parcel_id] = (h, self._upstream_owner())
        self._at_time.setdefault(h.t_ns, []).append(h)
        while len(self._recent) > MAX_REMEMBERED:
            old, _ = self._recent.pop(next(iter(self._recent)))
            same = self._at_time.get(old.t_ns, [])
            if old in same:
                same.remove(old)
            if not same:
                self._at_time.pop(old.t_ns, None)

    def _lose(self, h: Handoff, why: str) -> None:
        """Say a parcel handed to this segment lost, with why: never dropped silently."""
        self.stats['lost'] += 1
        if self.on_lost is not None:
            self.on_lost(h, why)
        self.left(h.parcel_id)  # out of the custody upstream too: it has its end

    def _take_answer(self, sender: str) -> None:
        if sender != self.owners.owner_of(self._owned[0] - 1):
            # as a horizon: it counts once its sender owns the station upstream
            self._pending_answer = sender
            return
        self._pending_answer = None
        self.answered = True
        self.owners.heard_from(sender)

    def _take_horizon(self, t_ns: int, sender: str) -> None:
        if sender != self.owners.owner_of(self._owned[0] - 1):
            # not (yet) the owner upstream: its claim has not come, or it restarted and
            # the old claim has not lapsed. The newest waits; it counts only once its
            # sender owns the station (a forger's never does)
            self._pending_horizon = (t_ns, sender)
            return
        k = t_ns // self.dt_ns
        if self._horizon_heard and k <= self.horizon_k:
            # said again (the answer to a hello ends with the last one), or a restarted
            # upstream segment running up to the present: nothing new
            self.owners.heard_from(sender)
            return
        # the first horizon brings the upstream's present (it may have run before this
        # segment listened, or this one restarted); after it, a few slices at a time
        step = HORIZON_STRIDE * self.max_step_k
        if self._horizon_heard and k > self.horizon_k + step:
            raise HandoverError(
                f'a horizon moves forward by at most {HORIZON_STRIDE} slices ({step} '
                f'periods) from period {self.horizon_k}, got period {k}'
            )
        self._horizon_heard = True
        self.horizon_k = k
        self.owners.heard_from(sender)

    def _refuse(self, why: str, station: str | None = None) -> None:
        self.stats['refused'] += 1
        topic = (
            f'line/{station}'
            if station in ('progress', 'owners')
            else f'line/handover/{station}/left'
            if station
            else f'line/handover/{self.upstream}'
        )
        self.node.get_logger().warning(f'{topic}: {why}; refused', throttle_duration_sec=1.0)
