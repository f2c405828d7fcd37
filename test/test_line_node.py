"""
The line node over real rclpy and DDS: stations in namespaces, one clock, line exits.

A parcel inducted at station 1 passes stations 1 and 2 straight and is diverted by
station 3, commanded only through station 3's own service and parameter; each
station reports on its own topics, the line on ``line/exits``; a station whose
heartbeat stops trips only its own watchdog.
"""

from __future__ import annotations

import time

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.time import Time
from ros_harness import refused_at_run_time
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Bool, UInt32
from std_srvs.srv import SetBool

from sorter_ros.interface import SENSOR_QOS
from sorter_sim.frontends.line_node import LineNode
from sorter_sim.runtime.cell import ParcelSpec
from sorter_sim.runtime.params import ParamError

pytestmark = pytest.mark.ros


def make_line(ros, node_name='sorter_line', **values):
    node = LineNode(
        node_name=node_name,
        context=ros.context,
        parameter_overrides=[
            Parameter(k, value=v) for k, v in {'time_mode': 'lockstep', **values}.items()
        ],
        station_params={'arrival': 'none'},
    )
    for n in node.nodes:
        ros.add(n)
    return node


def run(ros, line, seconds):
    """Advance a lock-step line ``seconds``, what it published taken every 25 ms."""
    for _ in range(round(seconds / 0.025)):
        line.advance(25)
        ros.drain()


def test_a_parcel_goes_through_two_stations_and_is_diverted_by_the_third(ros):
    line = make_line(ros, stations=3)
    probe = ros.make_node('probe')
    got = {'exits': [], 'S01': [], 'S03': [], 'clock': [], 'edges2': 0}
    probe.create_subscription(DiagnosticStatus, '/line/exits', got['exits'].append, 100)
    probe.create_subscription(DiagnosticStatus, '/S01/sort/outcomes', got['S01'].append, 100)
    probe.create_subscription(DiagnosticStatus, '/S03/sort/outcomes', got['S03'].append, 100)
    probe.create_subscription(Clock, '/clock', got['clock'].append, 100)
    pop = probe.create_client(SetBool, '/S03/diverter/popup')
    alpha = probe.create_client(SetParameters, '/S03/sorter_sim/set_parameters')
    ros.spin_until(lambda: pop.service_is_ready() and alpha.service_is_ready(), 10.0)
    # station 3's disks at -60 deg (its own parameter), raised (its own service)
    req = SetParameters.Request(
        parameters=[
            ParameterMsg(
                name='alpha_deg',
                value=ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=-60),
            )
        ]
    )
    fut = alpha.call_async(req)
    ros.spin_until(fut.done, 10.0)
    assert fut.result().results[0].successful
    fut = pop.call_async(SetBool.Request(data=True))
    ros.spin_until(fut.done, 10.0)
    assert fut.result().success
    line.stations[0].cell.induct(ParcelSpec(0.4, 0.3, 4.0, label='L-1'))
    run(ros, line, 18.0)
    t_end = line.line.t_ns
    ros.spin_until(
        lambda: (
            got['exits']
            and got['S03']
            and got['clock']
            and Time.from_msg(got['clock'][-1].clock).nanoseconds == t_end
        ),
        5.0,
    )
    (exit_msg,) = got['exits']
    v = {kv.key: kv.value for kv in exit_msg.values}
    assert (v['label'], v['exit'], v['station']) == ('L-1', 'S03R', 'S03')
    assert [m.message for m in got['S01']] == ['straight']  # passed on
    assert [m.message for m in got['S03']] == ['right']
    assert line.stations[1].cell.n_parcels == 0 and line.line.n_handed == 2
    # one clock: the line's, monotonic
    stamps = [m.clock.sec + 1e-9 * m.clock.nanosec for m in got['clock']]
    assert stamps == sorted(stamps) and stamps[-1] == pytest.approx(line.line.t)
    assert ros.context.ok()
    names = {n for n, _ in probe.get_topic_names_and_types()}
    assert {'/S02/sensors/edges', '/line/chutes/S02L/full', '/clock'} <= names


def test_a_station_whose_heartbeat_stops_trips_alone(ros):
    line = make_line(ros, stations=3)
    probe = ros.make_node('probe')
    beats = {
        k: probe.create_publisher(UInt32, f'/S0{k}/controller/heartbeat', 10) for k in (1, 2, 3)
    }
    status = {}
    for k in (1, 2, 3):
        probe.create_subscription(
            Bool,
            f'/S0{k}/status/watchdog',
            lambda m, k=k: status.__setitem__(k, m.data),
            SENSOR_QOS,  # latched: the initial False too
        )
    ros.spin_until(lambda: all(p.get_subscription_count() for p in beats.values()), 10.0)
    for s in line.stations:  # every station's disks up: the watchdog must lower only its own
        assert s.cell.popup(True)[0]
    for counter in range(1, 60):
        for k, pub in beats.items():
            if k != 2 or counter < 10:  # station 2's controller stops at 0.5 s
                pub.publish(UInt32(data=counter))
        for _ in range(10):  # 5 ms, and as long on the wall: the beats arrive in time
            line.advance(5)
            for _ in range(5):
                ros.executor.spin_once(timeout_sec=0.0)
    ros.spin_until(lambda: status.get(2) is True and len(status) == 3, 5.0)
    assert [s.cell.watchdog_tripped for s in line.stations] == [False, True, False]
    assert status == {1: False, 2: True, 3: False}
    assert [round(s.cell.stroke, 6) for s in line.stations] == [1.0, 0.0, 1.0]


@pytest.mark.parametrize(
    'values, message',
    [
        ({'stations': 0}, "'stations' must be an integer in \\[1, 64\\]"),
        ({'stations': 65}, "'stations'"),
        ({'station_gap': -1.0}, "'station_gap'"),
        ({'chute_names': ['a', 'b', 'c']}, '2 chutes per station'),
        ({'stations': 2, 'chute_names': ['a', 'b', 'c', 'a']}, "chute 'a' named twice"),
        ({'time_mode': 'slow'}, "'time_mode'"),
        ({'segment_sync': 'optimistic'}, "'segment_sync' must be one of conservative, barrier"),
        # a value of another type: named with what is allowed, not rclpy's type error
        ({'fast_slice': 'x'}, r"'fast_slice' must be a number in \(0, 1\] s, got 'x' \(string\)"),
        ({'chute_names': 3}, r"'chute_names' must be a list of chute names.*got 3 \(integer\)"),
        ({'wait_for_warehouse': 1}, r"'wait_for_warehouse' must be true or false.*got 1"),
    ],
)
def test_bad_line_parameters_stop_the_node_naming_them(ros, values, message):
    with pytest.raises(ParamError, match=message):
        make_line(ros, **values)


def test_the_line_options_are_fixed_once_it_runs_and_say_so(ros):
    """``ros2 param set`` of a line's option or its use_sim_time changes nothing, and says so."""
    line = make_line(ros, stations=2)
    before = {n: line.get_parameter(n).value for n in ('stations', 'time_mode', 'use_sim_time')}
    reasons = refused_at_run_time(
        ros,
        line,
        # 500 stations and a mode that is none were taken, and dumped, before; use_sim_time
        # true froze a fast line, its timers waiting for the /clock only it publishes
        {'stations': 500, 'time_mode': 'bogus', 'use_sim_time': True, 'fast_slice': 0.002},
    )
    assert all(r and 'read-only' in r for r in reasons.values()), reasons
    assert {n: line.get_parameter(n).value for n in before} == before
    desc = line.describe_parameter('stations')
    assert desc.read_only and desc.description == 'an integer in [1, 64]; read at start-up'
    run(ros, line, 0.1)
    assert line.line.k == 100 and len(line.stations) == 2


def test_a_line_that_waits_for_its_warehouse_runs_once_the_edges_after_station_1_are_read(ros):
    from sensor_msgs.msg import TimeReference

    from sorter_ros.interface import EVENT_QOS

    line = make_line(ros, stations=2, wait_for_warehouse=True)
    edges = [s.publisher_set.pub_edges for s in line.stations]
    probe = ros.make_node('warehouse')
    probe.create_subscription(TimeReference, '/S01/sensors/edges', lambda m: None, EVENT_QOS)
    ros.spin_until(lambda: edges[0].get_subscription_count() > 0, 10.0)
    for _ in range(3):
        line.advance(25)
        ros.drain()
    # station 1's label is its own scanner's; station 2's edges have no reader yet
    assert line.line.k == 0
    scans = []  # station 2's scanner edges, as the warehouse hears them
    probe.create_subscription(
        TimeReference,
        '/S02/sensors/edges',
        lambda m: scans.append(m) if m.header.frame_id.endswith('/pe_scan') else None,
        EVENT_QOS,
    )
    ros.spin_until(lambda: edges[1].get_subscription_count() > 0, 10.0)
    line.advance(25)
    # read, but nobody answers station 2's scanner edges yet: an edge would not wait
    assert line.line.k == 0
    answered = probe.create_publisher(TimeReference, '/S02/scanner/answered', EVENT_QOS)
    ros.spin_until(lambda: answered.get_subscription_count() > 0, 10.0)
    line.advance(25)
    assert line.line.k == 25
    # a parcel reaches station 2's scanner eye: the line stops after that pass until the
    # warehouse answers that edge (its label out), and runs on once it has
    line.stations[0].cell.induct(ParcelSpec(0.4, 0.3, 4.0, label='W-1'))
    while not any(m.source == 'rising' for m in scans) and line.line.t < 15.0:
        line.advance(25)
        ros.drain()
    (edge,) = [m for m in scans if m.source == 'rising']
    t_edge = edge.time_ref.sec + edge.time_ref.nanosec * 1e-9
    k = line.line.k
    assert t_edge <= line.line.t < t_edge + 0.025
    for _ in range(3):
        line.advance(25)
        ros.drain()
    assert line.line.k == k
    answered.publish(TimeReference(header=edge.header, time_ref=edge.time_ref, source='label'))
    ros.spin_until(lambda: not line._answers.pending, 10.0)
    line.advance(25)
    assert line.line.k == k + 25


def test_a_station_refuses_the_outputs_a_line_does_not_have_yet(ros, tmp_path):
    with pytest.raises(ParamError, match='modbus_port: a station of a line'):
        LineNode(
            context=ros.context,
            parameter_overrides=[Parameter('time_mode', value='lockstep')],
            station_params={'modbus_port': 15020},
        )
    # a line records into one file: stations told another one are refused
    with pytest.raises(ParamError, match='a line records into one file'):
        LineNode(
            context=ros.context,
            parameter_overrides=[
                Parameter('time_mode', value='lockstep'),
                Parameter('record_path', value=str(tmp_path / 'line.mcap')),
            ],
            station_params={'record_path': str(tmp_path / 'other.mcap')},
        )


def test_integers_are_taken_for_doubles(ros):
    line = make_line(ros, stations=2, station_gap=1)
    assert line.values['station_gap'] == 1.0
    assert line.line.positions[1] - line.line.positions[0] == pytest.approx(7.0)


def test_the_executable_refuses_a_bad_parameter_in_one_line():
    import subprocess
    import sys

    done = subprocess.run(
        [
            sys.executable,
            '-m',
            'sorter_sim.frontends.line_node',
            '--ros-args',
            '-p',
            'stations:=0',
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].startswith("line_node: parameter 'stations'")


def test_a_sorter_sim_rule_on_the_command_line_reaches_every_station():
    """``-p sorter_sim:mu_disks:=0.45`` matched no station (they are /S01/sorter_sim ...)."""
    import rclpy
    from rclpy.context import Context

    from sorter_sim.frontends.line_node import station_rules

    given = ['line_node', '--ros-args', '-p', 'stations:=2', '-p', 'time_mode:=lockstep']
    given += ['-p', 'sorter_sim:mu_disks:=0.45', '--param', '/sorter_sim:alpha_deg:=30']
    args, refused = station_rules(given)
    assert refused is None
    context = Context()
    rclpy.init(args=args, context=context)  # rcl parses the rewritten rules
    try:
        line = LineNode(context=context)
        for station in line.stations:
            assert station.get_parameter('mu_disks').value == 0.45, station.get_namespace()
            assert station.get_parameter('alpha_deg').value == 30.0, station.get_namespace()
        line.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    # past a '--' the arguments are the program's, not ROS's: left as they are
    assert station_rules(['x', '--ros-args', '--', '-p', 'sorter_sim:a:=1'])[0][-1] == (
        'sorter_sim:a:=1'
    )


@pytest.mark.parametrize(
    'rule, said',
    [
        (
            'sorter_sim:time_mode:=fast',
            "line_node: -p sorter_sim:time_mode:=fast: 'time_mode' is the line's option, and "
            "its stations take the line's: give it as -p time_mode:=VALUE",
        ),
        (  # rcl cannot parse it: refused before rcl reads the command line
            'sorter_sim:sorter_sim:alpha_deg:=60',
            'line_node: -p sorter_sim:sorter_sim:alpha_deg:=60: a rule names one node, then '
            'the parameter: give it as -p sorter_sim:alpha_deg:=VALUE',
        ),
    ],
)
def test_a_sorter_sim_rule_for_a_line_option_is_refused_in_one_line(rule, said):
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, '-m', 'sorter_sim.frontends.line_node', '--ros-args', '-p', rule],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [said]


def test_a_namespace_for_the_line_puts_each_station_under_it():
    """``-r __ns:=/line2`` put every station at /line2/sorter_sim: two publishers a topic."""
    import rclpy
    from rclpy.context import Context

    from sorter_sim.frontends.line_node import station_rules

    given = ['line_node', '--ros-args', '-p', 'stations:=2', '-p', 'time_mode:=lockstep']
    args, refused = station_rules(given + ['-r', '__ns:=/line2'])
    assert refused is None
    context = Context()
    rclpy.init(args=args, context=context)
    try:
        line = LineNode(context=context)
        names = [s.get_fully_qualified_name() for s in line.stations]
        assert line.get_namespace() == '/line2'
        assert names == ['/line2/S01/sorter_sim', '/line2/S02/sorter_sim'], names
        line.destroy_node()
    finally:
        rclpy.shutdown(context=context)


@pytest.mark.parametrize(
    'rule, said',
    [
        (
            ['-p', 'sorter_sim:sorter_sim:alpha_deg:=60'],
            'give it as -p sorter_sim:alpha_deg:=VALUE',
        ),
        (
            ['--param', '/sorter_sim:S01:alpha_deg:=60'],
            'a rule names one node, then the parameter',
        ),
        (['-r', 'sorter_sim:__ns:=/x'], 'it would give every station the same name'),
        (['--remap', '__node:=cell'], 'it would give every station the same name'),
    ],
)
def test_a_rule_the_line_cannot_give_each_station_is_refused_in_one_line(rule, said):
    from sorter_sim.frontends.line_node import station_rules

    _, refused = station_rules(['line_node', '--ros-args', *rule])
    assert refused is not None and said in refused and '\n' not in refused, refused


def test_the_whole_line_records_into_one_file_that_rosbags_reads(ros, tmp_path):
    from collections import Counter

    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from sorter_cell.cli import main

    path = tmp_path / 'line.mcap'
    line = LineNode(
        context=ros.context,
        parameter_overrides=[
            Parameter('time_mode', value='lockstep'),
            Parameter('stations', value=2),
            Parameter('record_path', value=str(path)),
        ],
        station_params={'arrival': 'none'},
    )
    for n in line.nodes:
        ros.add(n)
    line.stations[1].cell.popup(True)
    line.stations[0].cell.induct(ParcelSpec(0.4, 0.3, 4.0, label='R-1'))
    run(ros, line, 12.0)
    published = Counter()
    for node in line.stations:
        published.update(node.published)
    for n in line.nodes:
        ros.executor.remove_node(n)
        ros.nodes.remove(n)
    line.destroy_node()  # the stations, then the line: the last user finishes the file
    store = get_typestore(Stores.ROS2_JAZZY)
    decoded, refused = Counter(), Counter()
    with AnyReader([path], default_typestore=store) as reader:
        for conn, _, raw in reader.messages():
            try:
                reader.deserialize(raw, conn.msgtype)
                decoded[conn.topic] += 1
            except Exception:  # rosbags' own refusal of rclpy's JointState size, see
                refused[conn.topic] += 1  # test_recordings.py
    got = decoded + refused
    for topic, count in published.items():
        assert got[topic] == count, topic
    assert set(refused) <= {'/S01/diverter/state', '/S02/diverter/state'}
    # the line says its time at the end of each advance, and at least once a pose period
    assert got['/line/exits'] == 1 and got['/clock'] > 12.0 / 0.010
    assert got['/S02/sort/outcomes'] == 1 and got['/S01/sort/outcomes'] == 1
    assert main(['replay', str(path), '--json', '--out', str(tmp_path / 'paths.png')]) == 0


def test_the_line_runs_on_the_wall_clock_in_realtime_mode(ros):
    import time

    line = make_line(ros, stations=2, time_mode='realtime', real_time_factor=2.0)
    wall0 = time.monotonic()
    while time.monotonic() - wall0 < 1.0:
        ros.executor.spin_once(timeout_sec=0.01)
    # twice the wall time since the first tick anchored the clock, to a tick or a burst
    assert 1.2 < line.line.t < 2.2
    assert line.line.t_ns == line.stations[1].cell.t_ns


def test_every_station_is_a_modbus_unit_and_an_opc_ua_folder_of_the_line(ros):
    """Drive stations 1 and 2 with pyModbusTCP and asyncua, stacks this project did not write."""
    from asyncua.sync import Client
    from pyModbusTCP.client import ModbusClient
    from ros_harness import free_port

    from sorter_sim.model.core import cell_kernels as ck
    from sorter_sim.model.io_map import by_name, io_map

    line = make_line(ros, stations=2, modbus_port=free_port(), opcua_port=free_port())
    s1, s2 = (s.cell for s in line.stations)
    signals = by_name(io_map(s1.sensor_names))
    popup, t = signals['diverter.popup'], signals['cell.time']
    line.advance(200)
    units = {
        k: ModbusClient(host='127.0.0.1', port=line.fieldbus.modbus_port, unit_id=k, timeout=5.0)
        for k in (1, 2, 3)
    }
    opc = Client(line.fieldbus.opcua_endpoint, timeout=10)
    opc.connect()
    try:
        for k in (1, 2):  # each station's own image, at the single cell's addresses
            regs = units[k].read_input_registers(t.address, 2)
            assert regs is not None, units[k].last_error_as_txt
            assert ((regs[0] << 16) | regs[1]) * t.scale == pytest.approx(0.2, abs=1e-3)
        assert units[2].write_single_coil(popup.address, True)
        line.advance(1)
        assert float(s2.act[ck.A_STROKE_TARGET]) == 1.0
        assert float(s1.act[ck.A_STROKE_TARGET]) == 0.0  # station 1 untouched
        # a unit id no station has: exception 0x0B (gateway target device failed to respond)
        assert units[3].read_input_registers(t.address, 2) is None
        assert units[3].last_except == 0x0B
        assert line.fieldbus._modbus.units_refused == 1
        idx = opc.get_namespace_index('urn:sorter_cell')
        root = opc.nodes.objects.get_child(f'{idx}:sorter_line')
        assert sorted(n.read_browse_name().Name for n in root.get_children()) == ['S01', 'S02']
        out1 = root.get_child([f'{idx}:S01', f'{idx}:Outputs', f'{idx}:diverter.popup'])
        out1.write_value(True)
        line.advance(1)
        assert float(s1.act[ck.A_STROKE_TARGET]) == 1.0
        up2 = root.get_child([f'{idx}:S02', f'{idx}:Inputs', f'{idx}:diverter.stroke'])
        line.advance(300)
        assert up2.read_value() == pytest.approx(line.stations[1].cell.stroke)
        assert up2.read_value() > 0.5
        # an input is not writable over OPC UA, in any station's folder
        from asyncua import ua

        with pytest.raises(ua.UaStatusCodeError):
            up2.write_value(0.0)
        # each station its own machine state: station 2 held from its folder, 1 runs on
        pm2 = root.get_child([f'{idx}:S02', f'{idx}:PackML'])
        assert pm2.get_child([f'{idx}:StateCurrent']).read_value() == 6
        pm2.call_method(f'{idx}:Hold')
        line.advance(1)
        assert line.stations[1].cell.packml.state == 'Held'
        assert line.stations[0].cell.packml.state == 'Execute'
        assert pm2.get_child([f'{idx}:CurrentState']).read_value().Text == 'Held'
        serial = root.get_child([f'{idx}:S01', f'{idx}:Identification', f'{idx}:SerialNumber'])
        assert serial.read_value() == 'sorter_line/S01'
    finally:
        opc.disconnect()
        for c in units.values():
            c.close()


def test_a_station_fieldbus_port_taken_stops_the_line_naming_it(ros):
    import socket

    with socket.socket() as busy:
        busy.bind(('127.0.0.1', 0))
        busy.listen()
        with pytest.raises(ParamError, match="parameter 'modbus_port'"):
            make_line(ros, stations=2, modbus_port=busy.getsockname()[1])


def test_the_live_view_shows_the_whole_line_to_a_foxglove_client(ros):
    """A websocket client speaking Foxglove's protocol sees every station in its place."""
    import base64
    import json
    import struct
    import time

    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from ros_harness import free_port
    from websockets.sync.client import connect

    port = free_port()
    line = make_line(ros, stations=3, station_gap=0.5, foxglove_port=port, foxglove_rate_hz=500.0)
    line.stations[0].cell.induct(ParcelSpec(0.4, 0.3, 5.0, label='L1'))
    with connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1']) as ws:
        channels, deadline = {}, time.monotonic() + 5.0
        while len(channels) < 5 and time.monotonic() < deadline:
            msg = json.loads(ws.recv(timeout=5.0))
            if msg.get('op') == 'advertise':
                channels.update({c['topic']: c for c in msg['channels']})
        assert set(channels) == {
            '/live/scene',
            '/live/tf',
            '/live/S01/values',
            '/live/S02/values',
            '/live/S03/values',
        }
        subs = {1: '/live/scene', 2: '/live/tf', 3: '/live/S02/values'}
        ws.send(
            json.dumps(
                {
                    'op': 'subscribe',
                    'subscriptions': [
                        {'id': i, 'channelId': channels[t]['id']} for i, t in subs.items()
                    ],
                }
            )
        )
        ros.spin_until(line.live_view.listening, 5.0)

        def protobuf(topic):
            c = channels[topic]
            fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(c['schema']))
            pool = descriptor_pool.DescriptorPool()
            for f in fds.file:
                pool.Add(f)
            return message_factory.GetMessageClass(pool.FindMessageTypeByName(c['schemaName']))

        # run until the parcel rides station 2, then take the frames of that moment
        while not line.stations[1].cell.n_parcels:
            line.advance(20)
        # the view's process asks for each frame when its client can take one: a loaded
        # machine may leave it waiting a while, so wait for its ask in wall time, not by
        # running the line on (which would carry the parcel past station 2)
        deadline = time.monotonic() + 10.0
        while not line.live_view.due() and time.monotonic() < deadline:
            time.sleep(0.002)
        sent = line.live_view.frames_sent
        while line.live_view.frames_sent == sent:
            line.advance(line.stations[0].params.pose_stride)
        assert line.stations[1].cell.n_parcels == 1
        t_ns, got = line.line.t_ns, {}
        deadline = time.monotonic() + 10.0
        while len(got) < 3 and time.monotonic() < deadline:
            frame = ws.recv(timeout=5.0)
            if isinstance(frame, bytes):
                op, sub_id, log_time = struct.unpack_from('<BIQ', frame)
                if log_time == t_ns:
                    got[subs[sub_id]] = frame[13:]
    scene = protobuf('/live/scene').FromString(got['/live/scene'])
    ids = {e.id for e in scene.entities}
    for s in ('S01', 'S02', 'S03'):
        assert {f'{s}/belt', f'{s}/chutes', f'{s}/disk_field', f'{s}/sensors'} <= ids
    (parcel,) = [e for e in scene.entities if '/parcel/' in e.id]
    assert parcel.id.startswith('S02/') and parcel.frame_id == line.stations[1].frame_id
    tf = protobuf('/live/tf').FromString(got['/live/tf'])
    placed = {t.child_frame_id: t.translation.x for t in tf.transforms}
    assert placed == {s.frame_id: x for s, x in zip(line.stations, line.line.positions)}
    assert placed[line.stations[1].frame_id] - placed[line.stations[0].frame_id] == pytest.approx(
        line.stations[0].params.exit_x - line.stations[0].params.induct_x + 0.5
    )
    values = json.loads(got['/live/S02/values'])
    assert [p['label'] for p in values['parcels']] == ['L1']


@pytest.mark.parametrize('sync', ['conservative', 'barrier'])
def test_a_line_split_into_segments_gives_every_parcel_the_same_exit_at_the_same_time(ros, sync):
    """Stations 1-2 and 3-4 as two segments joined over DDS against one line of four."""
    labels = [f'P{i}' for i in range(1, 5)]

    def induct_and_raise(first_node, s3):
        hand_into_s02(first_node, labels)
        s3.set_parameters([Parameter('alpha_deg', value=60.0)])
        assert s3.cell.popup(True)[0]

    # one process, one line
    one = make_line(ros, stations=4)
    induct_and_raise(one, one.stations[2])
    while len(one.line.exits) < len(labels) and one.line.t < 60.0:
        one.advance(50)
    ref = sorted((e.label, e.exit, e.station, e.t_ns) for e in one.line.exits)
    for n in one.nodes:
        ros.executor.remove_node(n)
        ros.nodes.remove(n)
    one.destroy_node()
    assert len(ref) == len(labels) and {e[2] for e in ref} == {2}  # all diverted at S03
    # the same line as two segments, handing over on line/handover/S03
    # a barrier lets each run a slice past the one behind: 50 periods a call here
    timing = {'segment_sync': sync, 'fast_slice': 0.05}
    up = make_line(ros, stations=2, line_stations=4, node_name='sorter_line_a', **timing)
    down = make_line(ros, stations=2, first_station=3, node_name='sorter_line_b', **timing)
    assert up.hand_on and not down.hand_on and down.segment.upstream == 'S03'
    assert [s.get_namespace() for s in down.stations] == ['/S03', '/S04']
    induct_and_raise(up, down.stations[0])
    ros.spin_until(lambda: up.segment._pub.get_subscription_count() > 0, 10.0)
    deadline = time.monotonic() + 50.0
    while len(down.line.exits) < len(labels) and time.monotonic() < deadline:
        up.advance(50)
        ros.drain()  # the hand-overs and the horizon that reached the segment downstream
        down.advance(50)
        assert down.line.k <= up.line.k  # never past the upstream's horizon
        if sync == 'barrier':
            assert up.line.k - down.line.k <= 50  # never more than a slice apart
    split = sorted((e.label, e.exit, e.station + 2, e.t_ns) for e in down.line.exits)
    assert split == ref  # every parcel, the same chute, the same nanosecond
    assert up.segment.stats['sent'] == len(labels) == down.segment.stats['received']
    assert down.segment.stats['refused'] == 0 and not up.line.exits


def hand_into_s02(line, labels, ahead: float = 0.0) -> None:
    """Put parcels on station S02 one behind the other, ``ahead`` m past its entry [m]."""
    from dataclasses import replace

    from test_handover import REAL

    pitch = line.line.positions[1] - line.line.positions[0]
    for i, label in enumerate(labels):
        parcel = replace(REAL[0], parcel_id=i + 1, label=label)
        line.stations[1].cell.hand_in(parcel, -pitch + ahead + 0.8 * i)


def _drop(ros, line) -> None:
    """Take a line node out of the test's executor and destroy it (a segment that dies)."""
    for n in line.nodes:
        ros.executor.remove_node(n)
        ros.nodes.remove(n)
    line.destroy_node()


def test_a_restarted_segment_gets_back_every_parcel_it_held_and_sorts_them_as_before(ros):
    """S01-S02, S03, S04 as three segments; S03 dies with parcels on it and comes back."""
    labels = [f'P{i}' for i in range(1, 5)]

    def induct_and_raise(first_node, s4):
        hand_into_s02(first_node, labels, ahead=3.0)  # at S02's disk field, disks down
        s4.set_parameters([Parameter('alpha_deg', value=60.0)])
        assert s4.cell.popup(True)[0]

    one = make_line(ros, stations=4)
    induct_and_raise(one, one.stations[3])
    while len(one.line.exits) < len(labels) and one.line.t < 90.0:
        one.advance(50)
    ref = sorted((e.label, e.exit, e.station, e.t_ns) for e in one.line.exits)
    _drop(ros, one)
    assert len(ref) == len(labels) and {e[2] for e in ref} == {3}  # all diverted at S04

    # a slice of a second: the most a segment runs in one pass (1000 periods below), and
    # so the most its neighbour's horizon may move at once
    slice_s = {'fast_slice': 1.0}
    up = make_line(ros, stations=2, line_stations=4, node_name='sorter_line_a', **slice_s)
    mid = make_line(
        ros, stations=1, first_station=3, line_stations=4, node_name='sorter_line_b', **slice_s
    )
    down = make_line(ros, stations=1, first_station=4, node_name='sorter_line_c', **slice_s)
    induct_and_raise(up, down.stations[0])

    def step(*lines, n=50):
        for line in lines:
            line.advance(n)
            ros.drain()

    ros.spin_until(lambda: up.segment.connected() and mid.segment.connected(), 10.0)
    deadline = time.monotonic() + 45.0
    # run until S03 holds a parcel and S04 has been handed some, none sorted yet
    while not (mid.line.n_in_flight and down.segment.stats['received'] >= 2):
        assert time.monotonic() < deadline and not down.line.exits, 'no moment to crash'
        # a fifth of a second at a time: parcels seconds apart on a station 4 s long
        step(up, mid, down, n=200)
    held = mid.line.n_in_flight
    handed = down.segment.stats['received']
    _drop(ros, mid)  # the process dies: its stations, its parcels, its outbox are gone
    for _ in range(5):
        step(up, down)  # upstream waits with nobody to hand to; downstream waits for time
    mid = make_line(
        ros, stations=1, first_station=3, line_stations=4, node_name='sorter_line_b', **slice_s
    )
    assert mid.line.k == 0  # it starts again from t = 0
    # the same node come back: its claim succeeds the old one at once (no lease to wait
    # out); it runs once S01-S02 has answered its hello, every parcel back in its inbox
    deadline = time.monotonic() + 40.0
    while len(down.line.exits) < len(labels):
        assert time.monotonic() < deadline, f'{len(down.line.exits)} of {len(labels)} sorted'
        step(up, mid, down, n=1000)  # the restarted one runs its time up to the present
    split = sorted((e.label, e.exit, e.station + 3, e.t_ns) for e in down.line.exits)
    assert split == ref  # every parcel once, the same chute, the same nanosecond
    # S01-S02 sent back what S03 held and what S04 had not yet sorted; S04 dropped
    # the copies of those it already had
    assert up.segment.stats['resent'] >= held + handed
    assert down.segment.stats['duplicates'] >= handed
    assert down.segment.stats['received'] == len(labels)
    # and once the last exits are told upstream, nobody answers for a parcel any more
    while up.segment.outbox or mid.segment.outbox:
        assert time.monotonic() < deadline, (up.segment.outbox, mid.segment.outbox)
        step(up, mid, down)
    assert all(s.segment.stats['refused'] == 0 for s in (up, mid, down))


def test_a_segment_drops_a_malformed_hand_over_naming_it(ros):
    from sorter_sim.frontends.segments import HANDOVER_QOS

    down = make_line(ros, stations=1, first_station=2)
    probe = ros.make_node('attacker')
    pub = probe.create_publisher(DiagnosticStatus, '/line/handover/S02', HANDOVER_QOS)
    ros.spin_until(lambda: pub.get_subscription_count() > 0, 10.0)
    from diagnostic_msgs.msg import KeyValue

    for msg in (
        DiagnosticStatus(name='parcel'),
        DiagnosticStatus(name='parcel', values=[KeyValue(key='state', value='1 2 x')]),
        DiagnosticStatus(name='horizon', values=[KeyValue(key='t_ns', value='soon')]),
        DiagnosticStatus(name='teleport'),
    ):
        pub.publish(msg)
    ros.spin_until(lambda: down.segment.stats['refused'] == 4, 5.0)
    assert down.segment.inbox == [] and down.segment.horizon_k == 0
    down.advance(10)
    assert down.line.k == 0  # nothing from upstream yet: it waits
