"""
The fieldbus bridge as every protocol shares it: one I/O image, latched and applied per period.

The cell runs in lock-step in this process with its Modbus TCP and OPC UA servers;
the tests are the PLC side: they read the declared inputs against what the cell
knows, write outputs and see the cell act on them one physics period later, and
send every kind of bad write the issue names. A refused write must come back with
the protocol's own error, change nothing in the cell, and leave the node serving.
Here: what holds whatever the protocol (Modbus, OPC UA, S7): the image's timing, the
refusals, the watchdog, the soft PLC over each protocol, the servers' process.
"""

from __future__ import annotations

import json
import math
import socket
import subprocess

import pytest
from asyncua import ua
from asyncua.sync import Client as OpcClient
from pymodbus.client import ModbusTcpClient
from rclpy.parameter import Parameter
from ros_harness import free_port
from test_sim_node import SHORT_CELL
import fieldbus_helpers as fb
from fieldbus_helpers import BIN, MAP, cell_state, diagnostics, u32

from sorter_sim.frontends.node import SimNode
from sorter_sim.model.core import cell_kernels as ck
from sorter_sim.runtime.params import ParamError

pytestmark = pytest.mark.ros
# the fixtures: a cell serving Modbus TCP and OPC UA, and a client of each
cell, modbus, opcua = fb.cell, fb.modbus, fb.opcua


def test_the_inputs_are_what_the_cell_knows(cell, modbus, opcua):
    cell.advance(2600)  # the first parcel past the scanner, on to pe_divert
    c = cell.cell
    bits = modbus.read_discrete_inputs(0, count=23).bits
    for name, blocked in c.sensor_states().items():
        assert bits[MAP[f'sensor.{name}'].address] == blocked, name
    regs = modbus.read_input_registers(0, count=40).registers
    t = MAP['cell.time']
    assert u32(regs, t.address) * t.scale == pytest.approx(c.t, abs=1e-4)
    enc = MAP['belt.encoder']
    assert u32(regs, enc.address) * enc.scale == pytest.approx(1.5 * c.t, abs=2e-4)
    assert MAP['diverter.alpha'].value(regs[4]) == pytest.approx(60.0)
    # the scanner's label waits with its ready bit until the PLC acknowledges it
    label = bytes(b for r in regs[8:40] for b in (r >> 8, r & 0xFF)).rstrip(b'\0').decode()
    assert bits[MAP['scanner.ready'].address] and label == 'A00001'
    assert opcua('scanner.label').read_value() == 'A00001'
    assert opcua('belt.encoder').read_value() == pytest.approx(1.5 * c.t, abs=2e-4)
    # acknowledged, the label goes; the next one read meanwhile (if any) takes its place
    n_read = regs[MAP['scanner.sequence'].address]
    assert n_read >= 1
    assert not modbus.write_coil(MAP['scanner.ack'].address, True).isError()
    cell.advance(1)
    ready = modbus.read_discrete_inputs(16, count=1).bits[0]
    assert ready == (n_read >= 2)
    if ready:
        assert opcua('scanner.label').read_value() == 'B00002'


def test_edge_times_are_latched_inside_the_period_that_shows_the_edge(cell, modbus):
    rise = MAP['sensor.pe_scan.rise_time']
    fall = MAP['sensor.pe_scan.fall_time']
    seen = []
    for _ in range(3000):
        t_before = cell.cell.t
        cell.advance(1)
        blocked = modbus.read_discrete_inputs(0, count=1).bits[0]
        if seen and blocked != seen[-1][1]:
            regs = modbus.read_input_registers(rise.address, count=4).registers
            latched = u32(regs, 0 if blocked else 2) * rise.scale
            # the edge lies inside the physics period after which the bit changed
            assert t_before - 1e-4 <= latched <= cell.cell.t + 1e-9, (t_before, latched)
            if not blocked:
                assert u32(regs, 0) * rise.scale < latched  # it rose before it fell
                break
        seen.append((cell.cell.t, blocked))
    else:
        pytest.fail('pe_scan never saw a parcel pass')
    assert fall.address == rise.address + 2


def test_outputs_act_on_the_cell_one_period_later(cell, modbus, opcua):
    assert not modbus.write_coil(MAP['diverter.popup'].address, True).isError()
    assert not modbus.write_register(0, MAP['diverter.alpha_setpoint'].raw(-30.0)).isError()
    assert cell.get_parameter('alpha_deg').value == 60.0  # not before the next period
    cell.advance(1)
    assert cell.get_parameter('alpha_deg').value == -30.0
    cell.advance(300)
    assert cell.cell.stroke == 1.0 and math.degrees(cell.cell.alpha) == pytest.approx(-30.0)
    opcua('diverter.alpha_setpoint').write_value(ua.Variant(45.5, ua.VariantType.Double))
    opcua('diverter.popup').write_value(ua.Variant(False, ua.VariantType.Boolean))
    cell.advance(1)
    assert cell.get_parameter('alpha_deg').value == 45.5
    cell.advance(200)
    assert cell.cell.stroke == 0.0
    assert modbus.read_discrete_inputs(17, count=2).bits[:2] == [False, True]
    # e-stop and reset as pulses; the heartbeat arms and feeds the watchdog
    modbus.write_coil(MAP['cell.estop'].address, True)
    cell.advance(1)
    assert cell.cell.estop and cell.cell.belt_velocity == 0.0
    modbus.write_coil(MAP['cell.estop'].address, False)
    modbus.write_coil(MAP['cell.reset'].address, True)
    modbus.write_coil(MAP['cell.reset'].address, False)  # a pulse inside one period counts
    cell.advance(1)
    assert not cell.cell.estop and cell.cell.belt_velocity == 1.5
    modbus.write_register(MAP['plc.heartbeat'].address, 1)
    cell.advance(1)
    assert cell.cell.watchdog_armed
    cell.advance(400)  # no heartbeat for 0.4 s > 0.3 s: fail safe
    assert cell.cell.watchdog_tripped and modbus.read_discrete_inputs(21, count=1).bits[0]


def test_bad_writes_are_refused_with_the_protocols_errors_and_change_nothing(cell, modbus, opcua):
    cell.advance(5)
    before = cell_state(cell)
    alpha = MAP['diverter.alpha_setpoint']
    cases = [
        # out-of-range α: illegal data value
        (lambda: modbus.write_register(alpha.address, alpha.raw(90.5)), 3),
        # runs past the outputs (HR 0-2): nothing of it is applied, not even HR 2's command
        (lambda: modbus.write_registers(0, [alpha.raw(10.0), 0, 7, 0]), 2),
        (lambda: modbus.write_register(7, 1), 2),  # no output there (an input's address)
        (lambda: modbus.write_coil(40, True), 2),
        (lambda: modbus.read_input_registers(500, count=2), 2),  # unknown address
        (lambda: modbus.read_discrete_inputs(0, count=200), 2),
    ]
    for call, code in cases:
        r = call()
        assert r.isError() and r.exception_code == code, r
    for value, status in (
        (ua.Variant(math.nan, ua.VariantType.Double), 'BadOutOfRange'),
        (ua.Variant(-91.0, ua.VariantType.Double), 'BadOutOfRange'),
        (ua.Variant('up', ua.VariantType.String), 'BadTypeMismatch'),
    ):
        with pytest.raises(ua.UaStatusCodeError) as err:
            opcua('diverter.alpha_setpoint').write_value(value)
        assert type(err.value).__name__ == status
    with pytest.raises(ua.UaStatusCodeError) as err:  # inputs are not writable
        opcua('sensor.pe_scan').write_value(ua.Variant(True, ua.VariantType.Boolean))
    assert type(err.value).__name__ in ('BadUserAccessDenied', 'BadNotWritable')
    cell.advance(5)
    assert cell_state(cell) == before
    # the Modbus writes refused and the OPC UA writes refused for their value, apart
    # from the reads refused
    diag = diagnostics(cell)
    assert int(diag['fieldbus_writes_refused']) == 4 + 2
    assert int(diag['fieldbus_reads_refused']) == 2
    assert int(diag['fieldbus_illegal_functions']) == 0


def test_a_busy_fieldbus_port_is_refused_in_one_line(ros):
    with socket.socket() as busy:
        busy.bind(('127.0.0.1', 0))
        busy.listen()
        for key in ('modbus_port', 'opcua_port', 's7_port'):
            with pytest.raises(ParamError) as err:
                SimNode(
                    context=ros.context,
                    parameter_overrides=[
                        Parameter('time_mode', value='lockstep'),
                        Parameter(key, value=busy.getsockname()[1]),
                    ],
                )
            assert key in str(err.value) and '\n' not in str(err.value)


# 14 s of the demo's stream: 10 parcels, three or more into each chute (the checks
# below), and a soft PLC's run over OPC UA, two requests every 10 ms scan, well inside
# a minute on a loaded machine
DEMO_SIM_S = '14'


def _demo(how: str, tmp_path) -> dict:
    """Run ``sorter demo`` for DEMO_SIM_S with the controller on ``how``; return its summary."""
    out = subprocess.run(
        [
            str(BIN / 'sorter'),
            'demo',
            '--sim-time',
            DEMO_SIM_S,
            '--io',
            how,
            '--json',
            '--out',
            str(tmp_path / f'{how}.png'),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout)


@pytest.fixture(scope='module')
def ros_demo(tmp_path_factory) -> dict:
    """Return the ROS controller's demo run, the reference each soft PLC is held to."""
    return _demo('ros', tmp_path_factory.mktemp('ros_demo'))


# the three read one reference run (ros_demo): in one worker
@pytest.mark.xdist_group('fieldbus:soft plc against ros')
@pytest.mark.parametrize('io', ['modbus', 'opcua', 's7'])
def test_the_soft_plc_sorts_the_demo_stream_as_the_ros_controller_does(io, ros_demo, tmp_path):
    plc, ros_run = _demo(io, tmp_path), ros_demo
    assert plc['mis_sorted'] == 0 and plc['jams'] == 0 and plc['io_write_errors'] == 0
    assert plc['sorted_left'] >= 3 and plc['sorted_right'] >= 3
    assert (
        abs(plc['throughput_pcs_h'] - ros_run['throughput_pcs_h'])
        <= 0.05 * (ros_run['throughput_pcs_h'])
    )
    for key in ('sorted_left', 'sorted_right', 'straight', 'inducted'):
        assert plc[key] == ros_run[key], key


@pytest.mark.parametrize('way', ['modbus', 'opcua'])
def test_a_frozen_plc_rewriting_its_last_heartbeat_trips_the_watchdog(cell, modbus, opcua, way):
    """A PLC that froze but keeps rewriting its last counter is silence to the watchdog."""
    assert cell.params.watchdog_timeout == 0.3

    def beat(value):
        if way == 'modbus':
            assert not modbus.write_register(MAP['plc.heartbeat'].address, value).isError()
        else:
            opcua('plc.heartbeat').write_value(ua.Variant(value, ua.VariantType.UInt16))

    beat(5)
    cell.advance(1)
    assert cell.cell.watchdog_armed and not cell.cell.watchdog_tripped
    # the same value every 0.1 s for 3 s, each write accepted by the protocol
    for _ in range(30):
        beat(5)
        cell.advance(100)
    assert cell.cell.watchdog_tripped and cell.cell.watchdog_trips == 1
    assert cell.cell.heartbeats_frozen >= 29
    assert modbus.read_discrete_inputs(MAP['status.watchdog'].address, count=1).bits[0]
    # the same value does not clear it; the next counter does
    beat(5)
    cell.advance(1)
    assert cell.cell.watchdog_tripped
    beat(6)
    cell.advance(1)
    assert not cell.cell.watchdog_tripped


def test_the_servers_listen_on_an_ipv6_address(ros):
    node = ros.add(
        SimNode(
            context=ros.context,
            parameter_overrides=[
                Parameter(k, value=v)
                for k, v in {
                    **SHORT_CELL,
                    'opcua_host': '::1',
                    'opcua_port': free_port(),
                    'modbus_host': '::1',
                    'modbus_port': free_port(),
                }.items()
            ],
        )
    )
    assert node.fieldbus.opcua_endpoint.startswith('opc.tcp://[::1]:')
    node.advance(500)
    client = OpcClient(node.fieldbus.opcua_endpoint, timeout=10)
    client.connect()
    try:
        idx = client.get_namespace_index('urn:sorter_cell')
        t = client.nodes.objects.get_child([f'{idx}:cell', f'{idx}:Inputs', f'{idx}:cell.time'])
        assert t.read_value() == pytest.approx(0.5)
    finally:
        client.disconnect()
    modbus = ModbusTcpClient('::1', port=node.fieldbus.modbus_port, timeout=5, retries=0)
    assert modbus.connect() and not modbus.read_input_registers(0, count=2).isError()
    modbus.close()


def test_a_longer_io_cycle_applies_outputs_at_its_start_and_latches_inputs_at_its_end(ros):
    """io_cycle 10 ms: the image moves every 10 periods; the edge times stay the period's."""
    from sorter_sim.runtime.cell import Cell, SensorEdge
    from sorter_sim.runtime.params import CellParams

    values = {**SHORT_CELL, 'arrival': 'gap', 'arrival_gap': [1.0, 1.0], 'alpha_deg': 60.0}
    node = ros.add(
        SimNode(
            context=ros.context,
            parameter_overrides=[
                Parameter(k, value=v)
                for k, v in {**values, 'modbus_port': free_port(), 'io_cycle': 0.01}.items()
            ],
        )
    )
    assert node.params.io_stride == 10
    client = ModbusTcpClient('127.0.0.1', port=node.fieldbus.modbus_port, timeout=5, retries=0)
    assert client.connect()
    try:
        # the same cell without a fieldbus: where its edges fall, period by period
        twin = Cell(CellParams.defaults().with_changes(values, runtime=False))
        edges = [e for e in twin.advance(2603) if isinstance(e, SensorEdge)]
        assert edges, 'no parcel reached a sensor'
        node.advance(2603)
        assert node.cell.t_ns == twin.t_ns
        t, enc = MAP['cell.time'], MAP['belt.encoder']
        regs = client.read_input_registers(0, count=40).registers
        # latched at the end of the last whole cycle, 2.600 s, not at 2.603 s
        assert u32(regs, t.address) * t.scale == pytest.approx(2.600, abs=1e-9)
        assert u32(regs, enc.address) * enc.scale == pytest.approx(1.5 * 2.600, abs=2e-4)
        # each sensor's last edge times are the cell's own, to the register's resolution
        # (inside their period, not rounded to the cycle)
        compared = 0
        for name in node.cell.sensor_names:
            rises = [e.t_ns for e in edges if e.sensor == name and e.blocked]
            rises = [t for t in rises if t <= 2_600_000_000]
            if not rises:
                continue
            rise = MAP[f'sensor.{name}.rise_time']
            raw = client.read_input_registers(rise.address, count=4).registers
            assert u32(raw, 0) * rise.scale == pytest.approx(max(rises) * 1e-9, abs=rise.scale)
            compared += 1
        assert compared >= 2
        # an output written now is applied at the start of the next cycle (period 2610)
        assert not client.write_coil(MAP['diverter.popup'].address, True).isError()
        node.advance(7)
        assert node.cell.k == 2610 and node.cell.act[ck.A_STROKE_TARGET] == 0.0
        node.advance(1)
        assert node.cell.act[ck.A_STROKE_TARGET] == 1.0
    finally:
        client.close()


@pytest.mark.parametrize('io_cycle', [0.001, 0.01])
def test_the_fieldbus_changes_nothing_a_subscriber_receives(ros, io_cycle):
    """With the image on, whatever its cycle, every topic carries what it carries without."""
    values = {**SHORT_CELL, 'arrival': 'gap', 'arrival_gap': [0.5, 0.5]}
    plain = ros.add(
        SimNode(
            context=ros.context,
            namespace='plain',
            parameter_overrides=[Parameter(k, value=v) for k, v in values.items()],
        )
    )
    served = ros.add(
        SimNode(
            context=ros.context,
            namespace='served',
            parameter_overrides=[
                Parameter(k, value=v)
                for k, v in {**values, 'modbus_port': free_port(), 'io_cycle': io_cycle}.items()
            ],
        )
    )
    for node in (plain, served):
        for _ in range(7):
            node.advance(1433)  # slices that end anywhere in a cycle
    strip = {
        t.replace('/plain/', '/').replace('/served/', '/'): n for t, n in plain.published.items()
    }
    assert strip == {t.replace('/served/', '/'): n for t, n in served.published.items()}, (
        'the fieldbus changed what is published'
    )
    assert plain.cell.outcome_counts == served.cell.outcome_counts
    assert sum(plain.cell.outcome_counts.values()) >= 2


def test_ctrl_c_stops_the_node_and_its_fieldbus_process_without_a_traceback(tmp_path):
    """Ctrl-C on a terminal: SIGINT to the whole process group, the servers' process too."""
    import os
    import signal
    import time

    proc = subprocess.Popen(
        [
            str(BIN / 'sim_node'),
            '--ros-args',
            '-p',
            f'modbus_port:={free_port()}',
            '-p',
            f'opcua_port:={free_port()}',
            '-p',
            'arrival:=none',
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a terminal's job is
    )
    try:
        seen = []
        deadline = time.monotonic() + 50.0
        while time.monotonic() < deadline:
            line = proc.stderr.readline()
            if not line:
                break
            seen.append(line)
            if 'sorter cell ready' in line:
                break
        assert any('fieldbus I/O image' in x for x in seen), ''.join(seen)[-2000:]
        time.sleep(0.5)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    err = ''.join(seen) + err
    assert proc.returncode == 0, err[-3000:]
    assert 'Traceback' not in err and 'KeyboardInterrupt' not in err, err[-3000:]


def test_the_inputs_are_latched_when_a_read_asks_and_at_the_end_of_a_run(ros, monkeypatch):
    """
    A cycle of one period: no latch while nobody reads; a read asks and gets one.

    Nobody reading, a run of periods latches the inputs once, at its end, each edge time
    the period's own; a read while the node runs asks for a latch, waits for the end of
    the chunk it came in and sees the cell as it is then.
    """
    import threading
    import time

    from sorter_sim.frontends import fieldbus_process
    from sorter_sim.runtime.cell import Cell, SensorEdge
    from sorter_sim.runtime.params import CellParams

    node = fb.serving_cell(ros, modbus_port=free_port())
    image, bridge = node.fieldbus.image, node.fieldbus_bridge
    assert node.params.io_stride == 1
    latches = image.stats['refreshes']
    node.advance(2603)  # nobody reads: one latch, at the end of the run
    assert image.stats['refreshes'] == latches + 1
    twin = Cell(
        CellParams.defaults().with_changes(
            {**SHORT_CELL, 'arrival': 'gap', 'arrival_gap': [1.0, 1.0], 'alpha_deg': 60.0},
            runtime=False,
        )
    )
    edges = [e for e in twin.advance(2603) if isinstance(e, SensorEdge)]
    client = ModbusTcpClient('127.0.0.1', port=node.fieldbus.modbus_port, timeout=5, retries=0)
    assert client.connect()
    try:
        t = MAP['cell.time']
        regs = client.read_input_registers(0, count=40).registers
        assert u32(regs, t.address) * t.scale == pytest.approx(2.603, abs=1e-9)
        compared = 0
        for name in node.cell.sensor_names:
            rises = [e.t_ns for e in edges if e.sensor == name and e.blocked]
            if rises:
                rise = MAP[f'sensor.{name}.rise_time']
                raw = client.read_input_registers(rise.address, count=2).registers
                assert u32(raw, 0) * rise.scale == pytest.approx(max(rises) * 1e-9, abs=rise.scale)
                compared += 1
        assert compared >= 2
    finally:
        client.close()
    # the servers' side of the image, here; a read waits for its latch whatever the load
    monkeypatch.setattr(fieldbus_process, 'ASK_WAIT_S', 60.0)
    server = fieldbus_process.ServerImage(image.signals, {}, node.fieldbus._shm.buf)
    got = []
    bridge.start_run(1)
    try:
        bridge.advance(10, 1)
        assert image.stats['refreshes'] == latches + 1  # nobody asked
        reader = threading.Thread(target=lambda: got.append(server.input_values(['cell.time'])))
        reader.start()
        deadline = time.monotonic() + 30.0
        while not image.read_asked():
            assert time.monotonic() < deadline, 'the read never asked for a latch'
            time.sleep(0.001)
        assert not got  # it waits for the node
        bridge.advance(10, 1)  # the chunk the read came in: latched at its end
        reader.join(30.0)
        assert image.stats['refreshes'] == latches + 2
        assert got == [(pytest.approx(2.623, abs=1e-9),)]
        assert node.cell.t == pytest.approx(2.623)
    finally:
        bridge.end_run(1)
    assert image.stats['refreshes'] == latches + 2  # nothing run since: nothing to latch
