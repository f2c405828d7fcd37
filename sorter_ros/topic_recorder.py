"""
Recording every topic of a domain into a run's file, as ``ros2 bag record -a`` would.

The cell (and a line's nodes) write what they publish into their recording as they
publish it (``recording.publish_recorded``); what other nodes publish (the user's
controller's confirmations and heartbeat, its parameter changes, a warehouse's labels
for the stations after the first) reaches the file through a ``TopicRecorder``: a node
that looks at the graph every ``SCAN_S`` of its clock, subscribes (as CDR bytes) to
each topic the file's own nodes do not write, and writes each message it receives
into the same file, stamped with its clock (the simulation's: ``use_sim_time``). A
topic is subscribed with the reliability and durability all its publishers offer
(rosbag2's adaptation), so latched values sent before it looked are still recorded.
A topic whose type this Python does not have is left out (its message could not be
subscribed to), as ``ros2 bag`` leaves out a type it cannot load.
"""

from __future__ import annotations

import importlib

from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from sorter_ros.recording import open_recorder, release_recorder

SCAN_S = 0.1  # s of the node's clock between looks at the graph
DEPTH = 100  # messages a subscription keeps: a whole slice's worth of events
_INTERNAL = '/parameter_events'  # every rclpy node has its publisher, none records it


def message_class(type_name: str):
    """Return the rosidl class of ``pkg/msg/Type``, or None when this Python has none."""
    parts = type_name.split('/')
    if len(parts) != 3 or parts[1] != 'msg':
        return None
    try:
        return getattr(importlib.import_module(f'{parts[0]}.msg'), parts[2])
    except (ImportError, AttributeError):
        return None


def adapted_qos(endpoints) -> QoSProfile:
    """Return a subscription's QoS that matches every publisher in ``endpoints`` (as rosbag2)."""
    profiles = [e.qos_profile for e in endpoints]
    reliable = all(p.reliability == ReliabilityPolicy.RELIABLE for p in profiles)
    latched = all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in profiles)
    return QoSProfile(
        depth=DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


class TopicRecorder(Node):
    """
    Record into ``path`` every topic of the domain that the file's own nodes do not.

    A topic the nodes write as they publish it (``Recorder.published``) is left to
    them, also when it turns out to be one only after this node subscribed to it.

    Parameters
    ----------
    path : str
        The recording, open in this process (``open_recorder`` shares it).
    context : rclpy.context.Context
        The run's.

    """

    def __init__(self, path: str, context):
        super().__init__(
            'sorter_topic_recorder',
            context=context,
            parameter_overrides=[Parameter('use_sim_time', value=True)],
        )
        self.recorder = open_recorder(path, self.get_logger().error)
        self._subscribed: dict[str, object] = {}
        self._left_out: set[str] = set()
        self.create_timer(SCAN_S, self.scan)
        self.scan()

    def scan(self) -> None:
        """Subscribe to each topic that appeared and the file's nodes do not write."""
        own = self.recorder.published
        for topic in [t for t in self._subscribed if t in own]:
            self.destroy_subscription(self._subscribed.pop(topic))
        for topic, types in self.get_topic_names_and_types():
            if topic in self._subscribed or topic in self._left_out or topic in own:
                continue
            if any(part.startswith('_') for part in topic.split('/')):
                continue  # a hidden topic (the run loop's marker): ros2 bag record -a skips them
            endpoints = self.get_publishers_info_by_topic(topic)
            if not endpoints:
                continue  # only readers so far: nothing to record
            msg_class = message_class(types[0]) if len(types) == 1 else None
            if msg_class is None:
                self._left_out.add(topic)
                continue
            offered = endpoints[0].qos_profile

            def write(data, topic=topic, msg_type=types[0], offered=offered):
                rec = self.recorder
                if rec is not None and not rec.closed and topic not in rec.published:
                    now = self.get_clock().now().nanoseconds
                    rec.write(topic, data, now, msg_type, offered)

            self._subscribed[topic] = self.create_subscription(
                msg_class, topic, write, adapted_qos(endpoints), raw=True
            )

    @property
    def topics(self) -> list[str]:
        """Return the topics recorded through this node so far."""
        return sorted(self._subscribed)

    def destroy_node(self):
        """Give the recording back (the last of its users finishes the file), then go."""
        if self.recorder is not None:
            release_recorder(self.recorder)
            self.recorder = None
        return super().destroy_node()


def record_the_domain(run, path: str | None):
    """
    Add a ``TopicRecorder`` of ``path`` to a lock-step run (a cell, a line), when it records.

    Parameters
    ----------
    run : sorter_cell.testing.lockstep.LockStep
        Its ``context`` and ``add_node``.
    path : str or None
        The run's recording; nothing is added without one.

    Returns
    -------
    TopicRecorder or None
        The node, spun and destroyed with the run's.

    """
    if not path:
        return None
    return run.add_node(TopicRecorder(path, run.context))
