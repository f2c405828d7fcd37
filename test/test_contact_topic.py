"""
The contacts seen and heard: the ``contacts`` topic, the live view and the recording.

Two parcels queued end to end against a stopper across the running belt: at rest,
the floor pushes each downstream with μ m_i g (const1: μ at any slip), so the
contact between them carries μ m_behind g and the stopper Σ μ m_i g (the closed
form ``test_contact.py`` checks on the cell itself). Here the same numbers must come
out of what a subscriber receives over ROS 2 (in-process, a fresh Context), what a
Foxglove client receives from the live view, and what a recording's reader reads
back; a cell under ``contact: jam`` has no such topic and builds nothing.
"""

from __future__ import annotations

import math
import socket

import numpy as np
import pytest
from rclpy.parameter import Parameter
from test_sim_node import SHORT_CELL
from visualization_msgs.msg import Marker, MarkerArray

from sorter_cell.live_snapshot import _client_scene, draw_scene
from sorter_cell.replay import read_recording, summarize
from sorter_ros.interface import STREAM_QOS
from sorter_ros.outcomes import parse_contact_text
from sorter_sim.frontends.live_view import CONTACT_FORCE_SCALE
from sorter_sim.frontends.node import SimNode
from sorter_sim.runtime.cell_contacts import place_parcel

pytestmark = pytest.mark.ros

G = 9.81
MU = 0.6
A, B = 0.3, 0.2  # the parcels' footprint [m]
MASSES = (2.0, 3.5)  # [kg]: unequal, so an equal split of the load would fail
STOPPER_X = -0.6  # the stopper's upstream face [m]
RAIL_T = 0.02
TOL = 1e-3  # relative, as test_contact's queue at a stopper


def _sim(ros, **overrides) -> SimNode:
    values = {
        **SHORT_CELL,
        'contact': 'rigid',
        'jam_time': 60.0,
        'mu_belt': MU,
        'marker_rate_hz': 100.0,
        **overrides,
    }
    node = SimNode(
        context=ros.context,
        parameter_overrides=[Parameter(k, value=v) for k, v in values.items()],
    )
    return ros.add(node)


# the stopper as the cell's ``rails`` parameter declares it: its segment, 2 cm thick
HW = 0.35  # half the belt's width [m] (SHORT_CELL's belt_width)
STOPPER = [STOPPER_X + 0.5 * RAIL_T, -HW, STOPPER_X + 0.5 * RAIL_T, HW]


def _queue_at_a_stopper(sim: SimNode) -> None:
    """Put a stopper across the belt (unless the node declares it) and the two parcels at rest."""
    cell = sim.cell
    assert 0.5 * cell.params.belt_width == HW
    if not cell.params.rails:
        cell.add_rail(*STOPPER, RAIL_T)
    for i, m in enumerate(MASSES):
        place_parcel(cell, i, (STOPPER_X - 0.5 * A - i * A, 0.0, 0.0), (A, B, m))


def _forces(markers) -> dict:
    """Return {(first, second): summed normal force [N]} of one contacts MarkerArray."""
    out: dict = {}
    for m in markers:
        if m.action == Marker.ADD:
            first, second, force = parse_contact_text(m.text)
            out[first, second] = out.get((first, second), 0.0) + force
    return out


def _check_queue_forces(forces: dict) -> None:
    """Check the closed forms: the stopper carries Σ μ m_i g, the parcels' contact μ m_behind g."""
    stopper = MU * G * sum(MASSES)
    between = MU * G * MASSES[1]
    assert set(forces) == {('parcel 100', 'rail'), ('parcel 100', 'parcel 101')}, forces
    assert abs(forces['parcel 100', 'rail'] - stopper) <= TOL * stopper, (forces, stopper)
    got = forces['parcel 100', 'parcel 101']
    assert abs(got - between) <= TOL * between, (forces, between)


def test_contacts_topic_carries_the_stoppers_closed_form_load_only_when_read(ros):
    sim = _sim(ros)
    _queue_at_a_stopper(sim)
    probe = ros.make_node('contact_probe')
    got: list = []
    sim.advance(300)  # the queue settles; nobody reads the contacts: nothing is built
    assert sim.publisher_set.n_contact_arrays == 0
    sub = probe.create_subscription(MarkerArray, 'contacts', got.append, STREAM_QOS)
    pub = sim.publisher_set.pub_contacts
    ros.spin_until(lambda: pub.get_subscription_count() > 0, 5.0, 'the contacts subscriber')
    ros.spin_until(lambda: sub.get_publisher_count() > 0, 5.0, 'the contacts publisher')
    sim.advance(50)  # 5 marker periods at 100 Hz
    ros.spin_until(lambda: len(got) >= 5, 5.0, 'five contact marker arrays')
    assert sim.publisher_set.n_contact_arrays == 5
    msg = got[-1]
    clear, *arrows = msg.markers
    assert clear.action == Marker.DELETEALL and clear.ns == 'contacts'
    # stamped on the simulation clock: the period it was built at
    t_ns = sim.cell.t_ns
    assert (clear.header.stamp.sec, clear.header.stamp.nanosec) == divmod(t_ns, 10**9)
    assert clear.header.frame_id == 'conveyor'
    _check_queue_forces(_forces(arrows))
    for m in arrows:
        assert m.type == Marker.ARROW
        _, second, force = parse_contact_text(m.text)
        p0, p1 = m.points
        # the force on the first parcel, force x scale long: the stopper pushes it
        # upstream (-x) on the stopper's face, the parcel behind downstream (+x) on theirs
        sign, face = (-1.0, STOPPER_X) if second == 'rail' else (1.0, STOPPER_X - A)
        assert p1.x - p0.x == pytest.approx(sign * CONTACT_FORCE_SCALE * force, rel=1e-9)
        assert abs(p1.y - p0.y) < 1e-9
        # found before the period's overlap is taken out: within μ g h² (5.9e-6 m)
        assert p0.x == pytest.approx(face, abs=MU * G * 1e-6)


@pytest.mark.parametrize('t_ns', [0, 1_000_000, 7 * 10**9 + 123, 2**31 * 10**9 - 1])
@pytest.mark.parametrize('frame_id', ['conveyor', 'ä_frame_with_a_longer_name'])
def test_a_period_without_contacts_is_the_bytes_rclpy_serializes_its_delete_all_to(t_ns, frame_id):
    from builtin_interfaces.msg import Time
    from rclpy.serialization import deserialize_message, serialize_message

    from sorter_sim.frontends.contact_markers import contact_marker_array, no_contacts_cdr

    none = {k: np.zeros(0) for k in ('x', 'y', 'nx', 'ny', 'force', 'a')} | {'second': []}
    stamp = Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    expected = serialize_message(contact_marker_array(none, frame_id, stamp))
    assert no_contacts_cdr(frame_id, t_ns) == expected
    (clear,) = deserialize_message(no_contacts_cdr(frame_id, t_ns), MarkerArray).markers
    assert clear.action == Marker.DELETEALL and clear.header.stamp == stamp


def test_a_subscriber_gets_each_period_without_contacts_stamped_on_the_simulation_clock(ros):
    sim = _sim(ros)  # an empty belt: nothing touches
    probe = ros.make_node('contact_probe')
    got: list = []
    sub = probe.create_subscription(MarkerArray, 'contacts', got.append, STREAM_QOS)
    pub = sim.publisher_set.pub_contacts
    ros.spin_until(lambda: pub.get_subscription_count() > 0, 5.0, 'the contacts subscriber')
    ros.spin_until(lambda: sub.get_publisher_count() > 0, 5.0, 'the contacts publisher')
    t0 = sim.cell.t_ns
    sim.advance(30)  # 3 marker periods at 100 Hz
    ros.spin_until(lambda: len(got) >= 3, 5.0, 'three contact marker arrays')
    step = (sim.cell.t_ns - t0) // 3  # one marker period
    assert step > 0 and t0 + 3 * step == sim.cell.t_ns
    for i, msg in enumerate(got[-3:]):
        (clear,) = msg.markers
        assert clear.action == Marker.DELETEALL and clear.ns == 'contacts'
        assert clear.header.frame_id == 'conveyor'
        t_ns = t0 + (i + 1) * step
        assert (clear.header.stamp.sec, clear.header.stamp.nanosec) == divmod(t_ns, 10**9)


def test_the_rails_parameter_declares_the_cells_rails_read_only(ros):
    from rcl_interfaces.msg import ParameterType

    sim = _sim(ros, rails=[*STOPPER, -1.0, -HW, -0.8, 0.0])
    assert sim.params.rail_segments == (tuple(STOPPER), (-1.0, -HW, -0.8, 0.0))
    # the contact step's obstacles: the side walls, then the two rails as add_rail
    # makes them
    from sorter_sim.model.core.contact import OB_KIND, OBK_RAIL, OBK_WALL
    from sorter_sim.runtime.cell_contacts import rail_row

    obstacles = sim.cell.contacts.obstacles
    kinds = list(obstacles[:, OB_KIND])
    assert kinds == [OBK_WALL] * (len(kinds) - 2) + [OBK_RAIL] * 2
    assert obstacles[-2, : OB_KIND + 1] == pytest.approx(rail_row(*STOPPER, RAIL_T))
    assert obstacles[-1, : OB_KIND + 1] == pytest.approx(rail_row(-1.0, -HW, -0.8, 0.0, RAIL_T))
    d = sim.describe_parameter('rails')
    assert d.read_only and d.type == ParameterType.PARAMETER_DOUBLE_ARRAY
    result = sim.set_parameters([Parameter('rails', value=[*STOPPER])])[0]
    assert not result.successful and 'read-only' in result.reason
    assert sim.params.rail_segments == (tuple(STOPPER), (-1.0, -HW, -0.8, 0.0))
    assert len(sim.cell.rails) == 2


def test_a_cell_without_rails_declares_them_an_empty_array_of_doubles(ros):
    from rcl_interfaces.msg import ParameterType

    # none given: an empty array of doubles, not rclpy's guess from [] (a byte array)
    bare = _sim(ros)
    assert bare.get_parameter('rails').value == [] and not bare.cell.rails
    assert bare.describe_parameter('rails').type == ParameterType.PARAMETER_DOUBLE_ARRAY
    from sorter_sim.model.core.contact import OB_KIND, OBK_WALL

    assert set(bare.cell.contacts.obstacles[:, OB_KIND]) == {OBK_WALL}  # the side walls alone


def test_a_jam_cell_has_no_contacts_topic_and_builds_nothing(ros):
    sim = _sim(ros, contact='jam')
    assert sim.publisher_set.pub_contacts is None
    assert sim.live_state()['contacts'] is None
    sim.advance(50)
    assert sim.publisher_set.n_contact_arrays == 0
    names = [n for n, _ in sim.get_topic_names_and_types()]
    assert '/contacts' not in names


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def test_the_live_view_draws_each_contact_point_and_its_force(ros, tmp_path):
    port = _free_port()
    # the stopper from the node's own parameter: the live view draws it where it is
    sim = _sim(ros, foxglove_port=port, foxglove_rate_hz=200.0, rails=STOPPER)
    _queue_at_a_stopper(sim)
    sim.advance(300)
    scene = _client_scene(port, lambda: sim.advance(sim.params.pose_stride), frames=3)
    (rails,) = [e for e in scene.entities if e.id == 'rails']
    (cube,) = rails.cubes
    assert (cube.pose.position.x, cube.pose.position.y) == pytest.approx((STOPPER[0], 0.0))
    assert (cube.size.x, cube.size.y) == pytest.approx((2 * HW, RAIL_T))
    q = cube.pose.orientation
    assert abs(math.atan2(2 * q.w * q.z, 1 - 2 * q.z * q.z)) == pytest.approx(math.pi / 2)
    (entity,) = [e for e in scene.entities if e.id == 'contacts']
    assert len(entity.spheres) == len(entity.metadata) >= 4  # two points per face
    # the arrows' lengths are the forces: summed per pair of bodies, the closed forms
    forces: dict = {}
    for kv in entity.metadata:
        first, second = kv.key.split(' | ')
        forces[first, second] = forces.get((first, second), 0.0) + float(kv.value[:-2])
    stopper, between = MU * G * sum(MASSES), MU * G * MASSES[1]
    assert forces['parcel 100', 'rail'] == pytest.approx(stopper, rel=TOL)
    assert forces['parcel 100', 'parcel 101'] == pytest.approx(between, rel=TOL)
    drawn = sum(a.shaft_length + a.head_length for a in entity.arrows)
    assert drawn == pytest.approx(CONTACT_FORCE_SCALE * (stopper + between), rel=TOL)
    assert len(entity.arrows) == len(entity.metadata)  # every point here pushes
    for a, kv in zip(entity.arrows, entity.metadata):
        # the force on the first parcel: the stopper's upstream (yaw π), the one
        # behind's downstream (yaw 0)
        q = a.pose.orientation
        yaw = abs(math.atan2(2 * q.w * q.z, 1 - 2 * q.z * q.z))
        assert yaw == pytest.approx(math.pi if kv.key.endswith('rail') else 0.0, abs=1e-9)
    out = tmp_path / 'contacts.png'
    draw_scene(scene, out, 'two parcels at a stopper')
    assert out.stat().st_size > 10_000


def test_a_recording_carries_the_contacts_and_one_without_them_reads_as_before(ros, tmp_path):
    rigid = tmp_path / 'rigid.mcap'
    sim = _sim(ros, record_path=str(rigid))
    _queue_at_a_stopper(sim)
    sim.advance(400)  # recorded without any subscriber: 40 periods' contacts
    sim.destroy_node()
    ros.nodes.remove(sim)
    rec = read_recording(rigid)
    assert rec['damage'] is None and not rec['undecodable']
    assert rec['topics']['/contacts'] == {
        'type': 'visualization_msgs/msg/MarkerArray',
        'count': 40,
    }
    c = summarize(rec)['contacts']
    assert c['frames'] == 40 and c['most_points'] >= 4
    # the largest load between two bodies: the stopper's, the closed form
    assert c['largest_between'] == 'parcel 100 | rail'
    assert c['largest_force_n'] == pytest.approx(MU * G * sum(MASSES), rel=TOL)
    jam = tmp_path / 'jam.mcap'
    sim = _sim(ros, contact='jam', record_path=str(jam), arrival='gap')
    sim.advance(400)
    sim.destroy_node()
    ros.nodes.remove(sim)
    rec = read_recording(jam)
    assert '/contacts' not in rec['topics'] and rec['contacts'] is None
    assert summarize(rec)['contacts'] is None
