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

The messages are ``diagnostic_msgs/DiagnosticStatus``: ``name`` ``parcel`` or
``horizon``, ``values`` the fields. A malformed one is counted and dropped with a
warning; it never stops the segment.
"""

from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sorter_sim.runtime.cell import Handoff

# every hand-over kept until delivered: a parcel must never be lost between segments
HANDOVER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
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

    """

    def __init__(self, node, *, upstream, downstream, dx: float, dt_ns: int):
        self.node = node
        self.upstream = upstream
        self.downstream = downstream
        self.dx = dx
        self.dt_ns = dt_ns
        self.inbox: list[Handoff] = []
        # the period up to which the segment upstream has handed over everything
        self.horizon_k = 0 if upstream else None
        self.stats = {'sent': 0, 'received': 0, 'refused': 0, 'late': 0, 'messages': 0}
        self.latencies_ns: list[int] = []  # wall time from sending to receiving
        self._pub = None
        if downstream:
            self._pub = node.create_publisher(
                DiagnosticStatus, f'line/handover/{downstream}', HANDOVER_QOS
            )
        if upstream:
            node.create_subscription(
                DiagnosticStatus, f'line/handover/{upstream}', self._on_message, HANDOVER_QOS
            )

    def connected(self) -> bool:
        """Return True when a segment downstream reads this one's hand-overs."""
        return self._pub is not None and self._pub.get_subscription_count() > 0

    def hand_on(self, handoffs: list, t_ns: int) -> None:
        """Send the parcels the segment handed on, then the horizon ``t_ns``."""
        if self._pub is None:
            return
        now = time.time_ns()
        for h in handoffs:
            self.node._publish(self._pub, handover_message(h, now))
            self.stats['sent'] += 1
        self.node._publish(
            self._pub,
            DiagnosticStatus(name='horizon', values=[KeyValue(key='t_ns', value=str(t_ns))]),
        )
        self.stats['messages'] += len(handoffs) + 1

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
        self.stats['received'] += 1
        if sent_ns:
            self.latencies_ns.append(time.time_ns() - sent_ns)
        if h.t_ns // self.dt_ns < self.node.line.k:
            self.stats['late'] += 1  # on the wall clock: taken at once, as it left
        self.inbox.append(h)

    def _refuse(self, why: str) -> None:
        self.stats['refused'] += 1
        self.node.get_logger().warning(
            f'line/handover/{self.upstream}: {why}; dropped', throttle_duration_sec=5.0
        )
