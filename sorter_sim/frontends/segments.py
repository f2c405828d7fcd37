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
topic, one writer: the order holds).

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
time); the segment upstream answers a ``hello`` it has not heard before by sending
its whole outbox again, then its horizon. A segment restarted after a crash thus
gets back every parcel it held or was being handed, each in the state it was handed
over in, and in lock-step it runs again from t = 0 (its stations empty, the time
up to the present quickly) and takes each at the period it first came: the parcels
leave it as they did before, into the same chutes at the same times, except where
one of them had met a parcel that had already left (which is not re-sent). A
segment takes a parcel once: one it has taken (by id) is dropped as a duplicate, so
the segment downstream of a restarted one drops what the restarted one hands it
again. The first segment's stream is its own state: restarting it starts the
stream over. In ``realtime`` mode a restarted segment's clock starts at 0 again and
the parcels sent back wait for their time: restart a real-time line whole.

The messages are ``diagnostic_msgs/DiagnosticStatus``: ``name`` ``parcel`` or
``horizon`` downstream, ``left`` or ``hello`` upstream, ``values`` the fields. A
malformed one is counted and dropped with a warning; it never stops the segment.
"""

from __future__ import annotations

import os
import time

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy._rclpy_pybind11 import RCLError
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sorter_sim.runtime.cell import Handoff

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


def parse_handover(msg: DiagnosticStatus) -> tuple[Handoff, int]:
    """
    Return the hand-over a message carries and its send time; ValueError naming what is wrong.

    Parameters
    ----------
    msg : DiagnosticStatus
        A ``parcel`` message.

    Returns
    -------
    (Handoff, int)
        The parcel and the wall-clock time it was sent [ns].

    """
    v = {kv.key: kv.value for kv in msg.values}
    try:
        state = tuple(float.fromhex(x) for x in v['state'].split())
        gauge = tuple(float.fromhex(x) for x in v['gauge'].split())
        dims = tuple(float.fromhex(x) for x in v['dims'].split())
        h = Handoff(
            t_ns=int(v['t_ns']),
            parcel_id=int(v['id']),
            label=v['label'],
            state=state,
            mode=int(v['mode']),
            gauge=gauge,
            dims=dims,
        )
        wall_ns = int(v.get('wall_ns', '0'))
    except KeyError as exc:
        raise ValueError(f'a hand-over without {exc.args[0]!r}') from None
    except ValueError as exc:
        raise ValueError(f'a hand-over with a bad field: {exc}') from None
    if len(state) != 6 or len(dims) != 3 or h.t_ns < 0 or not all(d > 0 for d in dims):
        raise ValueError(
            'a hand-over must carry 6 state values, 3 positive dimensions and a time >= 0'
        )
    return h, wall_ns


class SegmentLink:
    """
    A line node's links to the segments up- and downstream (see the module).

    Parameters
    ----------
    node : rclpy.node.Node
        The line node.
    upstream, downstream : str or None
        The station whose hand-over topic this segment reads (its own first one) and
        writes (the next segment's first one); None at the line's ends.
    dx : float
        The upstream station's origin minus this segment's first one's [m].
    dt_ns : int
        The control period [ns].
    barrier : (int, int, int), optional
        With ``segment_sync`` ``barrier``: this segment's first station (0-based), its
        stations and the line's; every segment then says its time on ``line/progress``
        and none runs more than a slice past the one furthest behind.

    """

    def __init__(self, node, *, upstream, downstream, dx: float, dt_ns: int, barrier=None):
        self.node = node
        self.upstream = upstream
        self.downstream = downstream
        self.dx = dx
        self.dt_ns = dt_ns
        self.inbox: list[Handoff] = []
        # the period up to which the segment upstream has handed over everything
        self.horizon_k = 0 if upstream else None
        self.stats = {
            'sent': 0,
            'received': 0,
            'refused': 0,
            'late': 0,
            'messages': 0,
            'resent': 0,
            'duplicates': 0,
            'waits': 0,
        }
        self.latencies_ns: list[int] = []  # wall time from sending to receiving
        # this segment's identity for its neighbours: a restart is a new one
        self.identity = f'{os.getpid()}-{time.time_ns()}'
        # custody (see the module): what this segment handed on and still answers for
        self.outbox: dict[int, Handoff] = {}
        self._downstream_identity = None
        self._last_horizon_ns = None
        self._taken: set[int] = set()  # every parcel id taken, to drop a second copy
        self._left: list[int] = []  # ids that left this segment, to tell upstream
        self._hello_said = False
        self._queue: list[DiagnosticStatus] = []  # to the segment downstream, in order
        self._pub = self._pub_left = None
        if downstream:
            self._pub = node.create_publisher(
                DiagnosticStatus, f'line/handover/{downstream}', HANDOVER_QOS
            )
            node.create_subscription(
                DiagnosticStatus,
                f'line/handover/{downstream}/left',
                self._on_custody,
                HANDOVER_QOS,
            )
        self._barrier = barrier
        self._progress: dict[int, tuple[int, int]] = {}  # first station -> (stations, k)
        if barrier is not None:
            self._pub_progress = node.create_publisher(
                DiagnosticStatus, 'line/progress', PROGRESS_QOS
            )
            node.create_subscription(
                DiagnosticStatus, 'line/progress', self._on_progress, PROGRESS_QOS
            )
            self._progress[barrier[0]] = (barrier[1], 0)
        if upstream:
            node.create_subscription(
                DiagnosticStatus, f'line/handover/{upstream}', self._on_message, HANDOVER_QOS
            )
            self._pub_left = node.create_publisher(
                DiagnosticStatus, f'line/handover/{upstream}/left', HANDOVER_QOS
            )

    def connected(self) -> bool:
        """Return True when a segment downstream reads this one's hand-overs."""
        return self._pub is not None and self._pub.get_subscription_count() > 0

    def hand_on(self, handoffs: list) -> None:
        """Send the parcels the segment handed on (in order, behind any not yet sent)."""
        if self._pub is None:
            return
        now = time.time_ns()
        for h in handoffs:
            self.outbox[h.parcel_id] = h
            self._queue.append(handover_message(h, now))
            self.stats['sent'] += 1
        self._flush()

    def horizon(self, t_ns: int) -> None:
        """Say that every parcel handed on up to ``t_ns`` has been sent."""
        if self._pub is None:
            return
        self._last_horizon_ns = t_ns
        self._queue.append(
            DiagnosticStatus(name='horizon', values=[KeyValue(key='t_ns', value=str(t_ns))])
        )
        self._flush()

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
        self._pub_progress.publish(
            DiagnosticStatus(
                name='progress',
                values=[
                    KeyValue(key='first', value=str(first)),
                    KeyValue(key='stations', value=str(n)),
                    KeyValue(key='k', value=str(k)),
                ],
            )
        )

    def line_k(self) -> int:
        """Return the time of the segment furthest behind; 0 until every one has spoken."""
        covered = sum(n for n, _ in self._progress.values())
        if covered < self._barrier[2]:
            return 0
        return min(k for _, k in self._progress.values())

    def _on_progress(self, msg: DiagnosticStatus) -> None:
        v = {kv.key: kv.value for kv in msg.values}
        try:
            first, n, k = int(v['first']), int(v['stations']), int(v['k'])
        except (KeyError, ValueError):
            self._refuse('a progress message without integer first, stations and k', 'progress')
            return
        old = self._progress.get(first, (n, 0))[1]
        self._progress[first] = (n, max(old, k))

    def left(self, parcel_id: int) -> None:
        """Note that a parcel left this segment (a chute, the line's end, jammed)."""
        if self._pub_left is not None:
            self._left.append(int(parcel_id))

    def service(self) -> None:
        """Say hello upstream once it listens, and tell it which parcels left (each slice)."""
        if self._pub_left is None:
            return
        if not self._hello_said and self._pub_left.get_subscription_count() > 0:
            self._pub_left.publish(
                DiagnosticStatus(
                    name='hello', values=[KeyValue(key='identity', value=self.identity)]
                )
            )
            self._hello_said = True
        if self._left and self._hello_said:
            ids, self._left = self._left, []
            self._pub_left.publish(
                DiagnosticStatus(
                    name='left', values=[KeyValue(key='ids', value=' '.join(map(str, ids)))]
                )
            )

    def _on_custody(self, msg: DiagnosticStatus) -> None:
        """Take what the segment downstream says: parcels that left it, or its hello."""
        values = {kv.key: kv.value for kv in msg.values}
        if msg.name == 'left':
            try:
                ids = [int(x) for x in values.get('ids', '').split()]
            except ValueError:
                self._refuse('a left message whose ids are not integers', self.downstream)
                return
            for pid in ids:
                if self.outbox.pop(pid, None) is not None:
                    self.left(pid)  # it has left this segment's custody too
            return
        if msg.name != 'hello' or not values.get('identity'):
            self._refuse(
                f"a message named {msg.name[:40]!r}: 'left' or 'hello' with an identity expected",
                self.downstream,
            )
            return
        if values['identity'] == self._downstream_identity:
            return
        self._downstream_identity = values['identity']
        # a segment that (re)started: everything it answers for, again, in time order
        now = time.time_ns()
        for h in sorted(self.outbox.values(), key=lambda h: (h.t_ns, h.parcel_id)):
            self._queue.append(handover_message(h, now))
            self.stats['resent'] += 1
        if self._last_horizon_ns is not None:
            self.horizon(self._last_horizon_ns)
        if self.outbox:
            self.node.get_logger().info(
                f'the segment at {self.downstream} (re)started: sent it again the '
                f'{len(self.outbox)} parcel(s) it answers for'
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
        if msg.name == 'horizon':
            try:
                t_ns = int({kv.key: kv.value for kv in msg.values}['t_ns'])
            except (KeyError, ValueError):
                self._refuse('a horizon without an integer t_ns')
                return
            self.horizon_k = max(self.horizon_k, t_ns // self.dt_ns)
            return
        if msg.name != 'parcel':
            self._refuse(f"a message named {msg.name[:40]!r}: 'parcel' or 'horizon' expected")
            return
        try:
            h, sent_ns = parse_handover(msg)
        except ValueError as exc:
            self._refuse(str(exc))
            return
        if h.parcel_id in self._taken:
            self.stats['duplicates'] += 1  # sent again to a segment that has it
            return
        self._taken.add(h.parcel_id)
        self.stats['received'] += 1
        if sent_ns:
            self.latencies_ns.append(time.time_ns() - sent_ns)
        if h.t_ns // self.dt_ns < self.node.line.k:
            self.stats['late'] += 1  # on the wall clock: taken at once, as it left
        self.inbox.append(h)

    def _refuse(self, why: str, station: str | None = None) -> None:
        self.stats['refused'] += 1
        topic = (
            'line/progress'
            if station == 'progress'
            else f'line/handover/{station}/left'
            if station
            else f'line/handover/{self.upstream}'
        )
        self.node.get_logger().warning(f'{topic}: {why}; dropped', throttle_duration_sec=5.0)
