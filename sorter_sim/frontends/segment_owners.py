"""
Which segment of a line owns which stations: the claims on ``line/owners``.

Every segment says, every ``CLAIM_PERIOD_S``, the stations it owns with its identity
(its process and start time); ``Ownership`` keeps the claims it hears, refuses a second
segment on a station (the one that started later holds) and lets a claim lapse after
``CLAIM_LEASE_S`` unheard, or at once when the same node claims again, started later.
``segments.SegmentLink`` owns one per segment (the module there says how segments
keep time and custody; this one only who owns what).
"""

from __future__ import annotations

import math
import time

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sorter_ros.line_key import SealError
from sorter_ros.line_seal import LineSeal
from sorter_sim.model.description import station_name
from sorter_sim.runtime.handover import (
    HandoverError,
    MAX_STATIONS,
    check_claim_age,
    parse_claim,
)

# which segment owns which stations: each one's newest claim, for a segment that joins
OWNERS_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
CLAIM_PERIOD_S = 0.5  # s between a segment's claims
CLAIM_LEASE_S = 3.0  # s a claim stands without the segment being heard
CLAIM_SETTLE_S = 1.0  # s a segment's claim stands before it runs


def pairs(msg: DiagnosticStatus) -> list:
    """Return a message's (key, value) pairs."""
    return [(kv.key, kv.value) for kv in msg.values]


class Ownership:
    """
    The claims of the line's segments on ``line/owners``: which segment owns which stations.

    Every segment says, every ``CLAIM_PERIOD_S``, the stations it owns with its
    identity (its process and start time). Two claims on a station: the segment that
    started first owns it; the other is refused (it holds: it takes nothing and does
    not run) and both say so in one line. A claim not said again within
    ``CLAIM_LEASE_S`` lapses (its process died): a segment restarted in its place takes
    the stations over then, or at once if it is the same node (name) on the same
    stations. A segment runs once its own claim has stood ``CLAIM_SETTLE_S``
    unchallenged, so that a claim already there reaches it first.
    """

    def __init__(self, node, identity: str, owned: tuple, refuse, seal: LineSeal):
        self.node = node
        self._refuse = refuse
        self._seal = seal
        self.identity = identity
        self.first, self.n, self.line_stations = owned
        self._start = time.monotonic()
        self._said = -math.inf
        self.node_name = node.get_fully_qualified_name()
        # identity -> (first, n, heard, node name)
        self._claims: dict[str, tuple[int, int, float, str]] = {}
        self._reported: set[str] = set()
        self.conflicts = 0
        self._pub = node.create_publisher(DiagnosticStatus, 'line/owners', OWNERS_QOS)
        self._topic = self._pub.topic_name
        node.create_subscription(DiagnosticStatus, 'line/owners', self._on_claim, OWNERS_QOS)
        self.service()
        # said on the wall clock, whether or not the segment runs (lock-step: between steps)
        node.create_timer(
            CLAIM_PERIOD_S, self.service, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )

    def _stations(self, first: int, n: int) -> str:
        return f'{station_name(first)}-{station_name(first + n - 1)}'

    def service(self) -> None:
        """Say the claim again when due; let lapsed claims go."""
        now = time.monotonic()
        if now - self._said >= CLAIM_PERIOD_S:
            self._said = now
            msg = DiagnosticStatus(
                name='owns',
                values=[
                    KeyValue(key='identity', value=self.identity),
                    KeyValue(key='first', value=str(self.first)),
                    KeyValue(key='stations', value=str(self.n)),
                    KeyValue(key='node', value=self.node_name),
                ],
            )
            self._pub.publish(self._seal.sealed(self._topic, msg))
        for identity, (_, _, heard, _) in list(self._claims.items()):
            if now - heard > CLAIM_LEASE_S:
                del self._claims[identity]
                self._reported.discard(identity)

    def _on_claim(self, msg: DiagnosticStatus) -> None:
        try:
            msg = self._seal.opened(self._topic, msg)
            identity, first, n, name = parse_claim(pairs(msg), self.line_stations)
            if identity != self.identity:
                check_claim_age(identity)
        except (HandoverError, SealError) as exc:
            self._refuse(str(exc))
            return
        if identity == self.identity:
            return
        if identity not in self._claims and len(self._claims) >= MAX_STATIONS:
            self._refuse('more claims than a line has stations')
            return
        self._claims[identity] = (first, n, time.monotonic(), name)
        if identity in self._reported or not self._overlaps(first, n):
            return
        if (first, n, name) == (self.first, self.n, self.node_name):
            self._reported.add(identity)
            if _older(self.identity, identity):
                self.node.get_logger().error(
                    f'line/owners: {identity} restarted as this node ({name}): it takes over '
                    f'stations {self._stations(first, n)}; this segment holds'
                )
            return
        self._reported.add(identity)
        self.conflicts += 1
        mine, theirs = self._stations(self.first, self.n), self._stations(first, n)
        if _older(identity, self.identity):
            why = f'{identity} (started first) owns them: this segment holds, refused'
        else:
            why = f'{identity} claims them too and started later: refused'
        self.node.get_logger().error(f'line/owners: stations {mine} overlap {theirs}; {why}')

    def _overlaps(self, first: int, n: int) -> bool:
        return first < self.first + self.n and self.first < first + n

    def _succeeded(self, identity: str, first: int, n: int, name: str) -> bool:
        """
        Return True when a claim has a successor: the same node, restarted, on the same stations.

        A node name is one node of the ROS graph: a later claim under it for the same
        stations is that node come back (its process died and was started again), which
        takes its own stations over at once rather than after the old claim's lease.
        """
        if not name:
            return False
        mine = (self.first, self.n, self.node_name, self.identity)
        return any(
            (f, m, nm) == (first, n, name) and _older(identity, i)
            for f, m, nm, i in [mine] + [(c[0], c[1], c[3], j) for j, c in self._claims.items()]
        )

    def _standing(self):
        """Yield (identity, first, n) of the claims that stand: known and not succeeded."""
        for i, (f, n, _, name) in self._claims.items():
            if not self._succeeded(i, f, n, name):
                yield i, f, n

    def refused(self) -> bool:
        """
        Return True while a segment that started first claims some of this one's stations.

        Or while this segment's own node has restarted: its later claim succeeds this one.
        """
        if self._succeeded(self.identity, self.first, self.n, self.node_name):
            return True
        return any(
            self._overlaps(f, n) and _older(i, self.identity) for i, f, n in self._standing()
        )

    def runs(self) -> bool:
        """Return True when this segment owns its stations (see the class)."""
        return time.monotonic() - self._start >= CLAIM_SETTLE_S and not self.refused()

    def heard_from(self, identity: str) -> None:
        """Keep a segment's claim: a segment that speaks is alive, whenever its claims come."""
        c = self._claims.get(identity)
        if c is not None:
            self._claims[identity] = (c[0], c[1], time.monotonic(), c[3])

    def claim_of(self, identity: str) -> tuple[int, int] | None:
        """Return the (first, stations) a live claim of ``identity`` holds, or None."""
        c = self._claims.get(identity)
        return None if c is None else (c[0], c[1])

    def owner_of(self, station: int) -> str | None:
        """Return the identity owning ``station`` (0-based): the first started of its claims."""
        owners = [i for i, f, n in self._standing() if f <= station < f + n]
        if self.first <= station < self.first + self.n and not self._succeeded(
            self.identity, self.first, self.n, self.node_name
        ):
            owners.append(self.identity)
        return min(owners, key=_start_key) if owners else None


def _start_key(identity: str) -> tuple[int, str]:
    """Order identities by start time, then by name (two started in the same nanosecond)."""
    return int(identity.partition('-')[2]), identity


def _older(a: str, b: str) -> bool:
    return _start_key(a) < _start_key(b)
