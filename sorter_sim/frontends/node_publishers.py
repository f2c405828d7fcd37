"""
What the simulation node publishes: the cell's topics, recorded, and the live view.

``CellPublishers`` creates the publishers of the interface contract (README,
"Simulation node") once and turns what the cell reports into messages on them:
sensor edges, scanner reads, outcomes, poses, markers, the contacts (``contact:
rigid``), the diverter's state, the latched status bits and PackML state, and
``/clock``. Every message goes out through
``publish``, which counts it per topic and hands the same bytes to the node's
recording, so a recording is exactly what subscribers saw; the node's live view is
fed from the same periods. The node's other collaborators (fieldbus bridge,
commands, diagnostics) publish through it too.
"""

from __future__ import annotations

import math
from collections import Counter

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseArray
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Bool, String, UInt32MultiArray
from visualization_msgs.msg import Marker, MarkerArray

from sorter_ros.interface import EVENT_QOS, SENSOR_QOS, STREAM_QOS, quiet_publisher_events
from sorter_ros.outcomes import outcome_msg
from sorter_ros.recording import prepare_channel, publish_recorded
from sorter_sim.frontends.cdr import (
    JointStateCdr,
    bool_cdr,
    clock_cdr,
    pose_array_cdr,
    stamp,
    uint32_array_cdr,
)
from sorter_sim.frontends.contact_markers import contact_marker_array, no_contacts_cdr
from sorter_sim.frontends.live_view import PARCEL_HEIGHT, STATE_COLOURS
from sorter_sim.runtime import cell_view
from sorter_sim.runtime.cell import STATE_NAMES, LabelRead, Outcome, SensorEdge, WatchdogTrip

# status/<bit>: std_msgs/Bool each; fault = estop or jam or watchdog
STATUS_BITS = ('estop', 'jam', 'watchdog', 'fault')


def time_msg(t_ns: int) -> Time:
    """
    Return simulated time ``t_ns`` as a message stamp.

    Parameters
    ----------
    t_ns : int
        The time [ns].

    Returns
    -------
    Time
        The stamp.

    """
    sec, nsec = stamp(t_ns)
    return Time(sec=sec, nanosec=nsec)


class CellPublishers:
    """
    The simulation node's publishers, and what the cell's reports become on them.

    Parameters
    ----------
    node : SimNode
        The node the publishers belong to; its ``params``, ``recorder`` and
        ``live_view`` are read at each use (a parameter change replaces the
        parameters; the outputs are closed before the node is destroyed).
    cost : RunCost
        Where each message published is counted for the diagnostics.
    on_watchdog_trip : callable
        Called when the watchdog trips, before it is logged (the node commands the
        safe disk angle).
    clock : bool
        Whether to publish ``/clock`` (a line's station does not: the line does).

    """

    def __init__(self, node, cost, *, on_watchdog_trip, clock: bool):
        self._node = node
        self._cell = node.cell
        self._cost = cost
        self._on_watchdog_trip = on_watchdog_trip
        self.frame_id = node.frame_id
        self.published = Counter()  # messages per topic, counted where they are published
        self.n_messages = 0
        self.n_marker_arrays = 0
        self.n_contact_arrays = 0
        self._topic_names = {}
        self.pub_poses = self.create(PoseArray, 'parcels/poses', STREAM_QOS)
        self.pub_ids = self.create(UInt32MultiArray, 'parcels/ids', STREAM_QOS)
        self.pub_markers = self.create(MarkerArray, 'parcels/markers', STREAM_QOS)
        # the contacts exist only where parcels touch as rigid boxes: a cell under
        # ``contact: jam`` has no such topic and builds nothing
        self.pub_contacts = (
            self.create(MarkerArray, 'contacts', STREAM_QOS)
            if node.params.contact == 'rigid'
            else None
        )
        self.pub_sensor = {
            name: self.create(Bool, f'sensors/{name}', SENSOR_QOS)
            for name in self._cell.sensor_names
        }
        self.pub_edges = self.create(TimeReference, 'sensors/edges', EVENT_QOS)
        self.pub_label = self.create(String, 'scanner/label', EVENT_QOS)
        self.pub_diverter = self.create(JointState, 'diverter/state', STREAM_QOS)
        self.pub_outcomes = self.create(DiagnosticStatus, 'sort/outcomes', EVENT_QOS)
        # the cell's state bits, as a PLC reads them: latched, published when they change
        self.pub_status = {
            name: self.create(Bool, f'status/{name}', SENSOR_QOS) for name in STATUS_BITS
        }
        self._status_sent = None
        self._packml_sent = None
        # the machine state (PackML), latched: a late subscriber gets the state now
        self.pub_packml = self.create(String, 'status/packml', SENSOR_QOS)
        self.pub_clock = self.create(Clock, '/clock', STREAM_QOS) if clock else None
        # the messages of every pose period go out as CDR written here (cdr.py)
        self._joint_state_cdr = JointStateCdr(self.frame_id, ('disk_angle', 'popup_stroke'))

    # ------------------------------------------------------------------ publishing
    def create(self, msg_type, topic: str, qos):
        """
        Return a new publisher of the node, quiet about QoS mismatches.

        Parameters
        ----------
        msg_type : type
            The message type.
        topic : str
            The topic.
        qos : QoSProfile
            Its QoS.

        Returns
        -------
        rclpy.publisher.Publisher
            The publisher.

        """
        if self._node.recorder is not None:
            prepare_channel(msg_type)  # its first message then costs no file reads
        return self._node.create_publisher(
            msg_type, topic, qos, event_callbacks=quiet_publisher_events()
        )

    def publish(self, publisher, msg) -> None:
        """Publish ``msg`` (or its CDR bytes), count it per topic and record it."""
        publish_recorded(publisher, msg, self._node.recorder, self._cell.t_ns)
        self._cost.messages += 1
        self.n_messages += 1
        # rclpy's topic_name asks the C handle every time: once per publisher is enough
        topic = self._topic_names.get(publisher)
        if topic is None:
            topic = self._topic_names[publisher] = publisher.topic_name
        self.published[topic] += 1

    def publish_initial_state(self) -> None:
        """Publish the state at start: every sensor clear, actuators where they are, t = 0."""
        self.publish_status()
        self.publish_sensors()
        self._publish_diverter()
        self._publish_clock()

    def publish_period(self, events) -> None:
        """
        Publish what the periods just run report, and what falls due at the period reached.

        Parameters
        ----------
        events : list
            The cell's events over those periods.

        """
        p = self._node.params
        k = self._cell.k
        self.publish_events(events)
        if k % p.pose_stride == 0:
            if self._poses_wanted():
                self._publish_poses()
            self._publish_diverter()
        if k % p.marker_stride == 0 and self.pub_markers.get_subscription_count() > 0:
            self._publish_markers()
        if k % p.marker_stride == 0 and self._contacts_wanted():
            self._publish_contacts()
        live_view = self._node.live_view
        if live_view is not None and k % p.pose_stride == 0 and live_view.due():
            live_view.update(self._cell.t_ns, state_names=STATE_NAMES, **self._node.live_state())
        if k % p.heartbeat_stride == 0:
            self.publish_sensors()
        self._publish_clock()

    def publish_status(self) -> None:
        """
        Publish the state bits (status/estop, status/jam, status/fault) if one changed.

        Only on change: a reset publishes the cleared bits before its reply, and no
        periodic copy of an old value can follow it.
        """
        bits = {
            'estop': self._cell.estop,
            'jam': self._cell.jam,
            'watchdog': self._cell.watchdog_tripped,
        }
        bits['fault'] = bits['estop'] or bits['jam'] or bits['watchdog']
        if bits != self._status_sent:
            for name in STATUS_BITS:
                self.publish(self.pub_status[name], bool_cdr(bits[name]))
            self._status_sent = bits
        self._publish_packml()

    def _publish_packml(self) -> None:
        """Bring the PackML state up to the cell's conditions; publish each transition."""
        machine = self._cell.packml
        if self._cell.packml_dirty:
            self._cell.update_packml()  # a command or a fault since the cell last looked
        if self._packml_sent is None:
            machine.take_transitions()  # the power-up sequence: the state reached is enough
        else:
            for tr in machine.take_transitions():
                self._node.get_logger().info(
                    f'PackML {tr.previous} -> {tr.state} ({tr.cause}) at t = '
                    f'{tr.t_ns * 1e-9:.3f} s'
                )
                self.publish(self.pub_packml, String(data=tr.state))
                self._packml_sent = tr.state
        if machine.state != self._packml_sent:
            self.publish(self.pub_packml, String(data=machine.state))
            self._packml_sent = machine.state

    def publish_events(self, events) -> None:
        """
        Publish the status bits, then each of the cell's events in order.

        Parameters
        ----------
        events : list
            Sensor edges, label reads, outcomes and watchdog trips.

        """
        self.publish_status()
        for e in events:
            if isinstance(e, SensorEdge):
                self.publish(self.pub_sensor[e.sensor], bool_cdr(e.blocked))
                ref = TimeReference(source='rising' if e.blocked else 'falling')
                ref.header.stamp = time_msg(e.t_ns)
                ref.header.frame_id = f'{self.frame_id}/{e.sensor}'
                ref.time_ref = time_msg(e.t_ns)
                self.publish(self.pub_edges, ref)
            elif isinstance(e, LabelRead):
                self.publish(self.pub_label, String(data=e.label))
            elif isinstance(e, Outcome):
                self.publish(self.pub_outcomes, self._outcome_msg(e))
                if e.jammed:
                    self._node.get_logger().warning(
                        f'jam: parcel {e.parcel_id} ({e.label}) stopped at '
                        f'x = {e.x:.3f} m, y = {e.y:.3f} m ({e.cause})'
                    )
            elif isinstance(e, WatchdogTrip):
                self._on_watchdog_trip()
                self._node.get_logger().error(
                    f'watchdog: no controller heartbeat for {e.silent_s:.3f} s (simulated); '
                    f'disks dropping, disk angle to {self._node.params.safe_alpha_deg:g} deg '
                    f'until heartbeats return'
                )
        if any(isinstance(e, WatchdogTrip) for e in events):
            self.publish_status()

    def _outcome_msg(self, e: Outcome) -> DiagnosticStatus:
        return outcome_msg(e, self._node.get_fully_qualified_name())

    def publish_sensors(self) -> None:
        """Publish every sensor's state (the periodic copy of the latched bits)."""
        for name, blocked in self._cell.sensor_states().items():
            self.publish(self.pub_sensor[name], bool_cdr(blocked))

    def _poses_wanted(self) -> bool:
        # nobody reads them and nothing records them: not built, not serialized (a reader
        # that subscribes later, ``ros2 topic echo``, gets them from the next pose period)
        return (
            self._node.recorder is not None
            or self.pub_poses.get_subscription_count() > 0
            or self.pub_ids.get_subscription_count() > 0
        )

    def _publish_poses(self) -> None:
        parcels = self._cell.parcels()
        self.publish(self.pub_ids, uint32_array_cdr(parcels['id']))
        self.publish(
            self.pub_poses,
            pose_array_cdr(
                self._cell.t_ns, self.frame_id, parcels['x'], parcels['y'], parcels['phi']
            ),
        )

    def _publish_diverter(self) -> None:
        c = self._cell
        msg = self._joint_state_cdr(c.t_ns, (c.alpha, c.stroke), (c.alpha_rate, c.stroke_rate))
        self.publish(self.pub_diverter, msg)

    def _publish_markers(self) -> None:
        parcels = self._cell.parcels()
        stamp_msg = time_msg(self._cell.t_ns)
        clear = Marker(action=Marker.DELETEALL, ns='parcels')
        clear.header.frame_id = self.frame_id
        markers = [clear]
        for pid, x, y, phi, A, B, code in zip(
            *(parcels[k].tolist() for k in ('id', 'x', 'y', 'phi', 'A', 'B', 'state'))
        ):
            m = Marker(ns='parcels', id=int(pid), type=Marker.CUBE, action=Marker.ADD)
            m.header.frame_id = self.frame_id
            m.header.stamp = stamp_msg
            m.pose.position.x = x
            m.pose.position.y = y
            m.pose.position.z = 0.5 * PARCEL_HEIGHT
            m.pose.orientation.z = math.sin(0.5 * phi)
            m.pose.orientation.w = math.cos(0.5 * phi)
            m.scale.x, m.scale.y, m.scale.z = A, B, PARCEL_HEIGHT
            r, g, b = STATE_COLOURS[STATE_NAMES[code]]
            m.color.r, m.color.g, m.color.b, m.color.a = r, g, b, 1.0
            m.text = STATE_NAMES[code]
            markers.append(m)
        self.publish(self.pub_markers, MarkerArray(markers=markers))
        self.n_marker_arrays += 1

    def _contacts_wanted(self) -> bool:
        """Return whether the contacts go out now: someone subscribes, or the node records."""
        if self.pub_contacts is None:
            return False
        recorder = self._node.recorder
        if recorder is not None and not recorder.closed:
            return True
        return self.pub_contacts.get_subscription_count() > 0

    def _publish_contacts(self) -> None:
        t_ns = self._cell.t_ns
        if cell_view.n_contact_points(self._cell):
            contacts = self._cell.contact_points()
            msg = contact_marker_array(contacts, self.frame_id, time_msg(t_ns))
        else:
            msg = no_contacts_cdr(self.frame_id, t_ns)
        self.publish(self.pub_contacts, msg)
        self.n_contact_arrays += 1

    def _publish_clock(self) -> None:
        if self.pub_clock is None:
            return  # a station: the line publishes the clock
        self.publish(self.pub_clock, clock_cdr(self._cell.t_ns))
