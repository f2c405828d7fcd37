"""
The warehouse's answers to a line's scanner edges: the line holds until each is in.

A station after the line's first has no scanner of its own: its label comes from the
warehouse (``sorter_control.wcs_node``), which hears the station's scanner eye rise on
``Sk/sensors/edges`` and sends the label on ``Sk/scanner/label``, then says it answered
that edge on ``Sk/scanner/answered`` (``sensor_msgs/TimeReference``: the edge's time,
``source`` ``label`` or ``none``). A line that runs as fast as it can does not wait for
anyone: when the warehouse is in another process (a line in segments), a loaded
machine delays the label by more wall time than the line takes to run the station's
``label_window`` of simulated time, and the program finds no label for the parcel
(it goes straight on, or the scanner eye is faulted): the chutes then depend on the
machine's load. With ``wait_for_warehouse``, a line in ``lockstep`` or ``fast`` mode
stops after the slice in which such an edge rose until the warehouse answered it, so
the label reaches the station's program at the same simulated time in every run.

A warehouse that never answers (one of the user's own, on another ``scan_eye``) holds
the line ``ANSWER_WAIT_S`` of wall time per edge: the line then runs on, says so in
one line and counts it (``unanswered``).
"""

from __future__ import annotations

import time

from sensor_msgs.msg import TimeReference

from sorter_ros.interface import EVENT_QOS
from sorter_sim.runtime.cell import SensorEdge

SCAN_EYE = 'pe_scan'  # the eye on the scanner line (CellParams checks every cell has it)
ANSWER_WAIT_S = 5.0  # s of wall time an edge waits for its answer before the line runs on


def answered_topic(edges_topic: str) -> str:
    """Return a station's ``scanner/answered`` topic from its ``sensors/edges`` one."""
    return edges_topic.rsplit('sensors/edges', 1)[0] + 'scanner/answered'


class ScanAnswers:
    """
    The scanner edges a line's stations sent the warehouse and it has not answered yet.

    Parameters
    ----------
    node : rclpy.node.Node
        The line node, which subscribes to the answers.
    stations : list
        Its station nodes (``SimNode``), in order.
    first : int
        The line's 0-based number of its first station (station 0 reads its own labels).
    on_answer : callable or None
        Called after each answer: a held fast line's cue to run again.

    """

    def __init__(self, node, stations: list, first: int, on_answer=None):
        self.node = node
        self.on_answer = on_answer
        self.pending: dict[tuple[int, int], float] = {}  # (station, edge t_ns) -> sent at
        self.unanswered = 0
        self.subs = {
            j: node.create_subscription(
                TimeReference,
                answered_topic(st.publisher_set.pub_edges.topic_name),
                lambda msg, j=j: self._on_answer(j, msg),
                EVENT_QOS,
            )
            for j, st in enumerate(stations)
            if first + j > 0
        }

    def silent(self) -> list[str]:
        """Return the answer topics no warehouse publishes on yet."""
        return [s.topic_name for s in self.subs.values() if s.get_publisher_count() == 0]

    def sent(self, per_station: list) -> bool:
        """Note the scanner edges just published (each station's events); True when any."""
        now = time.monotonic()
        new = False
        for j, events in enumerate(per_station):
            if j not in self.subs:
                continue
            for e in events:
                if isinstance(e, SensorEdge) and e.blocked and e.sensor == SCAN_EYE:
                    self.pending[(j, e.t_ns)] = now
                    new = True
        return new

    def waiting(self) -> bool:
        """Return True while an edge waits for its answer (one waiting too long is given up)."""
        if not self.pending:
            return False
        now = time.monotonic()
        for key, sent in list(self.pending.items()):
            if now - sent > ANSWER_WAIT_S:
                del self.pending[key]
                self.unanswered += 1
                topic = self.subs[key[0]].topic_name
                self.node.get_logger().warning(
                    f'no answer on {topic} for the scanner edge at {key[1] * 1e-9:.9f} s '
                    f'within {ANSWER_WAIT_S:g} s of wall time: the line runs on without it '
                    '(wait_for_warehouse)'
                )
        return bool(self.pending)

    def _on_answer(self, j: int, msg: TimeReference) -> None:
        t_ns = msg.time_ref.sec * 1_000_000_000 + msg.time_ref.nanosec
        if self.pending.pop((j, t_ns), None) is not None and self.on_answer is not None:
            self.on_answer()
