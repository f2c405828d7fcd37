"""
The fieldbus I/O image, checked with the protocols' own clients (pymodbus, asyncua).

The cell runs in lock-step in this process with its Modbus TCP and OPC UA servers;
the tests are the PLC side: they read the declared inputs against what the cell
knows, write outputs and see the cell act on them one physics period later, and
send every kind of bad write the issue names. A refused write must come back with
the protocol's own error, change nothing in the cell, and leave the node serving.
"""

from __future__ import annotations

import json
import math
import socket
import subprocess
import sys
import threading
from datetime import datetime, timezone
from pathlib import Path

import pytest
from asyncua import ua
from asyncua.sync import Client as OpcClient
from pymodbus.client import ModbusTcpClient
from rclpy.parameter import Parameter
from ros_harness import free_port
from test_sim_node import SHORT_CELL

from sorter_sim.frontends.node import SimNode
from sorter_sim.model.core import cell_kernels as ck
from sorter_sim.model.io_map import by_name, io_map
from sorter_sim.runtime.params import ParamError

pytestmark = pytest.mark.ros
BIN = Path(sys.executable).parent
SENSORS = ['pe_scan', 'pe_divert', 'pe_exit', 'chute_left', 'chute_right']
MAP = by_name(io_map(SENSORS))


@pytest.fixture
def cell(ros):
    node = SimNode(
        context=ros.context,
        parameter_overrides=[
            Parameter(k, value=v)
            for k, v in {
                **SHORT_CELL,
                'arrival': 'gap',
                'arrival_gap': [1.0, 1.0],
                'alpha_deg': 60.0,
                'modbus_port': free_port(),
                'opcua_port': free_port(),
            }.items()
        ],
    )
    ros.add(node)
    return node


@pytest.fixture
def modbus(cell):
    client = ModbusTcpClient('127.0.0.1', port=cell.fieldbus.modbus_port, timeout=5, retries=0)
    assert client.connect()
    yield client
    client.close()


@pytest.fixture
def opcua(cell):
    client = OpcClient(cell.fieldbus.opcua_endpoint, timeout=10)
    client.connect()
    idx = client.get_namespace_index('urn:sorter_cell')
    root = client.nodes.objects.get_child([f'{idx}:cell'])

    def node(name):
        folder = 'Outputs' if MAP[name].direction == 'output' else 'Inputs'
        return root.get_child([f'{idx}:{folder}', f'{idx}:{name}'])

    yield node
    client.disconnect()


def _u32(regs, address):
    return (regs[address] << 16) | regs[address + 1]


def test_the_inputs_are_what_the_cell_knows(cell, modbus, opcua):
    cell.advance(2600)  # the first parcel past the scanner, on to pe_divert
    c = cell.cell
    bits = modbus.read_discrete_inputs(0, count=23).bits
    for name, blocked in c.sensor_states().items():
        assert bits[MAP[f'sensor.{name}'].address] == blocked, name
    regs = modbus.read_input_registers(0, count=40).registers
    t = MAP['cell.time']
    assert _u32(regs, t.address) * t.scale == pytest.approx(c.t, abs=1e-4)
    enc = MAP['belt.encoder']
    assert _u32(regs, enc.address) * enc.scale == pytest.approx(1.5 * c.t, abs=2e-4)
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
            latched = _u32(regs, 0 if blocked else 2) * rise.scale
            # the edge lies inside the physics period after which the bit changed
            assert t_before - 1e-4 <= latched <= cell.cell.t + 1e-9, (t_before, latched)
            if not blocked:
                assert _u32(regs, 0) * rise.scale < latched  # it rose before it fell
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


def _state(cell):
    c = cell.cell
    return (
        cell.get_parameter('alpha_deg').value,
        float(c.act[ck.A_STROKE_TARGET]),
        c.estop,
        c.belt_run,
        c.watchdog_armed,
        c.packml.state,
    )


def test_bad_writes_are_refused_with_the_protocols_errors_and_change_nothing(cell, modbus, opcua):
    cell.advance(5)
    before = _state(cell)
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
    assert _state(cell) == before
    # the Modbus writes refused and the OPC UA writes refused for their value, apart
    # from the reads refused
    diag = _diag(cell)
    assert int(diag['fieldbus_writes_refused']) == 4 + 2
    assert int(diag['fieldbus_reads_refused']) == 2
    assert int(diag['fieldbus_illegal_functions']) == 0


def test_a_client_that_leaves_mid_request_and_two_writers_at_once(cell, modbus):
    # half a Modbus frame, then gone
    s = socket.create_connection(('127.0.0.1', cell.fieldbus.modbus_port))
    s.sendall(bytes([0, 1, 0, 0, 0, 6, 1]))
    s.close()
    # two clients writing the α setpoint at once, 200 times each: each write whole
    port = cell.fieldbus.modbus_port
    alpha = MAP['diverter.alpha_setpoint']
    errors = []

    def writer(value):
        c = ModbusTcpClient('127.0.0.1', port=port, timeout=5, retries=0)
        c.connect()
        for _ in range(200):
            if c.write_register(alpha.address, alpha.raw(value)).isError():
                errors.append(value)
        c.close()

    threads = [threading.Thread(target=writer, args=(v,)) for v in (12.5, -40.0)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors
    cell.advance(1)
    assert cell.get_parameter('alpha_deg').value in (12.5, -40.0)
    assert modbus.read_holding_registers(alpha.address, count=1).registers[0] in (
        alpha.raw(12.5),
        alpha.raw(-40.0),
    )
    assert int(_diag(cell)['fieldbus_outputs_lost']) > 0  # many writes, one period
    cell.advance(10)
    assert cell.context.ok()


def _diag(cell):
    return cell.fieldbus_bridge.diagnostics()


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


@pytest.mark.parametrize('io', ['modbus', 'opcua', 's7'])
def test_the_soft_plc_sorts_the_demo_stream_as_the_ros_controller_does(io, tmp_path):
    runs = {}
    for how in ('ros', io):
        out = subprocess.run(
            [
                str(BIN / 'sorter'),
                'demo',
                '--sim-time',
                '20',
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
        runs[how] = json.loads(out.stdout)
    plc, ros_run = runs[io], runs['ros']
    assert plc['mis_sorted'] == 0 and plc['jams'] == 0 and plc['io_write_errors'] == 0
    assert plc['sorted_left'] >= 3 and plc['sorted_right'] >= 3
    assert (
        abs(plc['throughput_pcs_h'] - ros_run['throughput_pcs_h'])
        <= 0.05 * (ros_run['throughput_pcs_h'])
    )
    for key in ('sorted_left', 'sorted_right', 'straight', 'inducted'):
        assert plc[key] == ros_run[key], key


def test_the_warehouse_link_over_opc_ua_routes_and_confirms(ros):
    from sorter_cell.demo import _controller_values
    from sorter_control.parameters import config_from_values
    from sorter_control.soft_plc import OpcUaIO, SoftPLC

    config = Path(__file__).resolve().parents[1] / 'config'
    # the default cell (config/cell.yaml), as the PLC's configuration (controller.yaml) knows it
    cell = ros.add(
        SimNode(
            context=ros.context,
            cli_args=['--ros-args', '--params-file', str(config / 'cell.yaml')],
            parameter_overrides=[
                Parameter('time_mode', value='lockstep'),
                Parameter('opcua_port', value=free_port()),
            ],
        )
    )
    cfg = config_from_values(
        {**_controller_values(config), 'routing.rules': ['A*=left', 'B*=right', 'C*=straight']}
    )
    plc = SoftPLC(cfg, OpcUaIO(cell.fieldbus.opcua_endpoint, 'cell', cell.cell.sensor_names))
    wms = OpcClient(cell.fieldbus.opcua_endpoint, timeout=10)
    wms.connect()
    try:
        idx = wms.get_namespace_index('urn:sorter_cell')
        wh = wms.nodes.objects.get_child([f'{idx}:cell', f'{idx}:Warehouse'])

        def read(name):
            return wh.get_child([f'{idx}:{name}']).read_value()

        def request(pattern, destination):
            return wh.call_method(f'{idx}:RequestRoute', pattern, destination)

        assert request('C*', 'left') == 1  # the C parcels now go left
        assert request('Z*', '') == 2  # removing a rule there is not: refused by the PLC
        for bad in (('C=1', 'left'), ('C*', 'up'), ('C;1', 'left')):
            with pytest.raises(ua.UaStatusCodeError) as err:
                request(*bad)
            assert type(err.value).__name__ == 'BadInvalidArgument'
        while cell.cell.t < 14.0:
            cell.advance(10)
            plc.scan()
        results = read('RouteResults')
        assert results[0].startswith('1|C*=left: accepted'), results
        assert results[1].startswith('2|Z*=: refused'), results
        assert read('PendingRoutes') == [] and read('RouteRequests') == 2
        assert 'C*=left' in read('RoutingTable') and 'C*=straight' not in read('RoutingTable')
        lines = read('Confirmations')
        assert read('ConfirmationCount') == len(lines) >= 4
        by_label = {line.split(';')[0]: line.split(';')[1:] for line in lines}
        assert by_label['C00003'] == ['left', 'left', 'sorted'], by_label
        assert by_label['A00001'] == ['left', 'left', 'sorted']
        assert by_label['B00002'] == ['right', 'right', 'sorted']
    finally:
        wms.disconnect()
        plc.io.close()


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


# ---------------------------------------------------------------- OPC UA access control
async def _activate_with(endpoint: str, token) -> str:
    """Open a session and activate it with ``token`` as sent by any client; the outcome."""
    from asyncua import Client

    client = Client(endpoint, timeout=10)
    await client.connect_socket()
    try:
        await client.send_hello()
        await client.open_secure_channel()
        await client.create_session()
        params = ua.ActivateSessionParameters()
        params.UserIdentityToken = token
        try:
            await client.uaclient.activate_session(params)
        except ua.UaStatusCodeError as exc:
            return type(exc).__name__
        return 'activated'
    finally:
        client.disconnect_socket()


def _self_signed_certificate() -> bytes:
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, 'admin')])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(now + datetime.timedelta(days=1))
        .sign(key, hashes.SHA256())
    )
    return cert.public_bytes(serialization.Encoding.DER)


def test_no_identity_a_client_offers_buys_more_than_anonymous_access(cell):
    import asyncio

    endpoint = cell.fieldbus.opcua_endpoint
    # through an ordinary client: 'admin' with any password, other names
    for user, password in (('admin', 'x'), ('admin', ''), ('Admin', 'admin'), ('root', 'root')):
        client = OpcClient(endpoint, timeout=10)
        client.set_user(user)
        client.set_password(password)
        with pytest.raises(Exception):
            client.connect()
        client.disconnect_socket() if hasattr(client, 'disconnect_socket') else None
    # and as raw tokens, past whatever a client library checks on its own side
    names = [
        ua.UserNameIdentityToken(PolicyId='anonymous', UserName='admin', Password=b'x'),
        ua.UserNameIdentityToken(PolicyId='username', UserName='operator', Password=b'1234'),
        ua.X509IdentityToken(PolicyId='certificate', CertificateData=_self_signed_certificate()),
    ]
    for token in names:
        outcome = asyncio.run(_activate_with(endpoint, token))
        assert outcome in ('BadIdentityTokenRejected', 'BadUserAccessDenied'), (token, outcome)
    assert asyncio.run(_activate_with(endpoint, ua.AnonymousIdentityToken())) == 'activated'


def test_an_anonymous_client_cannot_write_inputs_nor_add_or_delete_nodes(cell, opcua):
    cell.advance(10)
    t_input = opcua('cell.time')
    for node, value in (
        (t_input, ua.Variant(123.0, ua.VariantType.Double)),
        (opcua('status.estop'), ua.Variant(True, ua.VariantType.Boolean)),
    ):
        with pytest.raises(ua.UaStatusCodeError) as err:
            node.write_value(value)
        assert type(err.value).__name__ == 'BadUserAccessDenied'
    # a write to another attribute (the name) of an output is refused too
    popup = opcua('diverter.popup')
    with pytest.raises(ua.UaStatusCodeError):
        popup.write_attribute(
            ua.AttributeIds.DisplayName, ua.DataValue(ua.Variant(ua.LocalizedText('x')))
        )
    with pytest.raises(ua.UaStatusCodeError):
        popup.delete()
    folder = popup.get_parent()
    with pytest.raises(ua.UaStatusCodeError):
        folder.add_variable(2, 'intruder', 1.0)
    # the inputs stay live, the output stays where it was
    cell.advance(100)
    assert t_input.read_value() == pytest.approx(cell.cell.t, abs=1e-9)
    assert popup.read_display_name().Text == 'diverter.popup'
    assert popup.read_value() is False
    assert not cell.cell.estop


def test_a_mixed_write_request_is_answered_item_by_item(cell, opcua):
    """Part 4, 5.10.4: one status code per item; the good items applied, the bad refused."""
    cell.advance(5)
    popup, alpha, t_input = (
        opcua('diverter.popup'),
        opcua('diverter.alpha_setpoint'),
        opcua('cell.time'),
    )

    def item(node, variant):
        return ua.WriteValue(
            NodeId=node.nodeid,
            AttributeId=ua.AttributeIds.Value,
            Value=ua.DataValue(variant),
        )

    params = ua.WriteParameters(
        NodesToWrite=[
            item(alpha, ua.Variant(95.0, ua.VariantType.Double)),
            item(popup, ua.Variant(True, ua.VariantType.Boolean)),
            item(alpha, ua.Variant('up', ua.VariantType.String)),
            item(t_input, ua.Variant(1.0, ua.VariantType.Double)),
            item(alpha, ua.Variant(30.0, ua.VariantType.Double)),
        ]
    )
    import asyncio

    from asyncua import Client

    async def write():
        async with Client(cell.fieldbus.opcua_endpoint, timeout=10) as client:
            return await client.uaclient.write(params)

    names = [r.name for r in asyncio.run(write())]
    assert names == ['BadOutOfRange', 'Good', 'BadTypeMismatch', 'BadUserAccessDenied', 'Good']
    cell.advance(1)
    assert cell.get_parameter('alpha_deg').value == 30.0
    assert float(cell.cell.act[ck.A_STROKE_TARGET]) == 1.0


# ---------------------------------------------------------------- Modbus at byte level
def _frame(tid: int, pdu: bytes, protocol: int = 0, unit: int = 1) -> bytes:
    import struct

    return struct.pack('>HHHB', tid, protocol, len(pdu) + 1, unit) + pdu


def _replies(sock, n: int) -> list[tuple[int, bytes]]:
    """Read ``n`` Modbus TCP answers: (transaction id, PDU) each."""
    import struct

    out, buf = [], b''
    sock.settimeout(5.0)
    while len(out) < n:
        while len(buf) < 6 or len(buf) < 6 + struct.unpack('>H', buf[4:6])[0]:
            chunk = sock.recv(4096)
            assert chunk, f'connection closed after {len(out)} of {n} answers'
            buf += chunk
        tid, _, length = struct.unpack('>HHH', buf[:6])
        out.append((tid, buf[7 : 6 + length]))
        buf = buf[6 + length :]
    return out


def test_modbus_frames_at_byte_level(cell):
    import struct

    popup = MAP['diverter.popup'].address
    alpha = MAP['diverter.alpha_setpoint']
    beat = MAP['plc.heartbeat'].address
    s = socket.create_connection(('127.0.0.1', cell.fieldbus.modbus_port))
    try:
        before = _state(cell)
        # write single coil with anything but 0x0000 / 0xFF00: exception 3, nothing set
        for value in (0x1234, 0x0001, 0xFFFF):
            s.sendall(_frame(1, struct.pack('>BHH', 5, popup, value)))
            assert _replies(s, 1) == [(1, bytes([0x85, 3]))]
        cell.advance(2)
        assert _state(cell) == before
        # three requests in one segment: every one answered, in order
        s.sendall(
            _frame(10, struct.pack('>BHH', 6, beat, 7))
            + _frame(11, struct.pack('>BHH', 6, alpha.address, alpha.raw(20.0)))
            + _frame(12, struct.pack('>BHH', 3, beat, 1))
        )
        got = _replies(s, 3)
        assert [t for t, _ in got] == [10, 11, 12]
        assert got[0][1] == struct.pack('>BHH', 6, beat, 7)
        assert got[2][1] == struct.pack('>BBH', 3, 2, 7)
        cell.advance(1)
        assert cell.get_parameter('alpha_deg').value == pytest.approx(20.0)
        # a frame with a non-zero protocol id is dropped; the next one is served
        s.sendall(_frame(20, struct.pack('>BHH', 6, beat, 99), protocol=5))
        s.sendall(_frame(21, struct.pack('>BHH', 3, beat, 1)))
        assert _replies(s, 1) == [(21, struct.pack('>BBH', 3, 2, 7))]
        # function codes the image does not serve: exception 1
        for fc in (7, 8, 20, 24, 99):
            s.sendall(_frame(30 + fc, bytes([fc, 0, 0])))
            assert _replies(s, 1) == [(30 + fc, bytes([fc | 0x80, 1]))]
        # read/write multiple registers (23): written first, then read back
        s.sendall(_frame(40, struct.pack('>BHHHHBH', 23, beat, 1, beat, 1, 2, 0x12)))
        assert _replies(s, 1) == [(40, struct.pack('>BBH', 23, 2, 0x12))]
        # mask write (22), the specification's example: 0x12, AND 0xF2, OR 0x25 -> 0x17
        s.sendall(_frame(41, struct.pack('>BHHH', 22, beat, 0x00F2, 0x0025)))
        assert _replies(s, 1) == [(41, struct.pack('>BHHH', 22, beat, 0x00F2, 0x0025))]
        s.sendall(_frame(42, struct.pack('>BHH', 3, beat, 1)))
        assert _replies(s, 1) == [(42, struct.pack('>BBH', 3, 2, 0x17))]
        # a truncated request body: exception 3
        s.sendall(_frame(43, bytes([3, 0])))
        assert _replies(s, 1) == [(43, bytes([0x83, 3]))]
        # the device says what it is (17 and 43/14)
        s.sendall(_frame(50, bytes([17])))
        ((_, pdu),) = _replies(s, 1)
        assert pdu[0] == 17 and b'sorter_cell' in pdu
        s.sendall(_frame(51, bytes([43, 14, 1, 0])))
        ((_, pdu),) = _replies(s, 1)
        assert pdu[:2] == bytes([43, 14]) and b'sorter_cell' in pdu
        # a length no Modbus frame can have ends that connection, and only that one
        s.sendall(struct.pack('>HHHB', 60, 0, 4000, 1))
        s.settimeout(5.0)
        assert s.recv(100) == b''
    finally:
        s.close()
    diag = _diag(cell)
    assert int(diag['fieldbus_illegal_functions']) == 5
    assert int(diag['fieldbus_frames_dropped']) == 2
    assert int(diag['fieldbus_writes_refused']) == 3
    assert int(diag['fieldbus_reads_refused']) == 1
    r = ModbusTcpClient('127.0.0.1', port=cell.fieldbus.modbus_port, timeout=5, retries=0)
    assert r.connect() and r.read_holding_registers(beat, count=1).registers == [0x17]
    r.close()


def test_an_independent_modbus_client_reads_and_writes_the_image(cell):
    """pyModbusTCP, a Modbus stack this project neither wrote nor serves with."""
    from pyModbusTCP.client import ModbusClient

    client = ModbusClient(host='127.0.0.1', port=cell.fieldbus.modbus_port, timeout=5.0)
    try:
        cell.advance(1500)
        t = MAP['cell.time']
        regs = client.read_input_registers(t.address, 2)
        assert regs is not None, client.last_error_as_txt
        assert ((regs[0] << 16) | regs[1]) * t.scale == pytest.approx(cell.cell.t, abs=1e-3)
        bits = client.read_discrete_inputs(0, 5)
        assert bits == [cell.cell.sensor_states()[n] for n in SENSORS]
        assert client.write_single_coil(MAP['diverter.popup'].address, True)
        alpha = MAP['diverter.alpha_setpoint']
        assert client.write_single_register(alpha.address, alpha.raw(-25.0))
        assert not client.write_single_register(alpha.address, alpha.raw(95.0))
        assert client.last_except == 3  # illegal data value
        cell.advance(1)
        assert cell.get_parameter('alpha_deg').value == pytest.approx(-25.0)
        assert float(cell.cell.act[ck.A_STROKE_TARGET]) == 1.0
        ident = client.read_device_identification()
        assert ident is not None and ident.vendor_name == b'sorter_cell'
    finally:
        client.close()


def test_the_cell_answers_its_unit_id_and_refuses_others_as_the_line_does(cell):
    """Ask at unit ids 0, 1, 17, 247 and 255 with pyModbusTCP: the cell is 1 (and TCP's 255)."""
    from pyModbusTCP.client import ModbusClient

    cell.advance(200)
    t = MAP['cell.time']
    answered, refused = {}, {}
    for unit in (0, 1, 17, 247, 255):
        client = ModbusClient(
            host='127.0.0.1', port=cell.fieldbus.modbus_port, unit_id=unit, timeout=5.0
        )
        try:
            regs = client.read_input_registers(t.address, 2)
            if regs is None:
                refused[unit] = client.last_except
            else:
                answered[unit] = ((regs[0] << 16) | regs[1]) * t.scale
            # a write to a unit that is not there changes nothing
            client.write_single_coil(MAP['diverter.popup'].address, unit not in (1, 255))
        finally:
            client.close()
    assert answered == {1: pytest.approx(0.2, abs=1e-3), 255: pytest.approx(0.2, abs=1e-3)}
    assert refused == {0: 0x0B, 17: 0x0B, 247: 0x0B}  # gateway target failed to respond
    cell.advance(1)
    assert float(cell.cell.act[ck.A_STROKE_TARGET]) == 0.0


def test_warehouse_methods_take_typed_bounded_arguments_and_change_nothing_on_refusal(cell):
    import asyncio

    from asyncua import Client

    U32, I64, B, S, I32 = (
        ua.VariantType.UInt32,
        ua.VariantType.Int64,
        ua.VariantType.Boolean,
        ua.VariantType.String,
        ua.VariantType.Int32,
    )

    async def run():
        async with Client(cell.fieldbus.opcua_endpoint, timeout=10) as client:
            idx = await client.get_namespace_index('urn:sorter_cell')
            folder = await client.nodes.objects.get_child([f'{idx}:cell', f'{idx}:Warehouse'])
            # the warehouse's state as a client reads it (the servers run in their own
            # process): pending routes, results, confirmations, the routing table, count
            names = ('PendingRoutes', 'RouteResults', 'Confirmations', 'RoutingTable')
            state_nodes = [await folder.get_child([f'{idx}:{n}']) for n in names]
            count_node = await folder.get_child([f'{idx}:ConfirmationCount'])

            async def warehouse():
                return await client.read_values(state_nodes)

            async def call(name, *args):
                try:
                    return await folder.call_method(f'{idx}:{name}', *args)
                except ua.UaStatusCodeError as exc:
                    return type(exc).__name__

            assert await call('RequestRoute', 'A*', 'left') == 1
            assert await call('RequestRoute', 'B*', 'right') == 2
            state = await warehouse()
            refusals = {
                'take all with no results': (
                    'TakeRoutes',
                    ua.Variant(4294967295, U32),
                    ua.Variant([], S, is_array=True),
                ),
                'take more than wait': (
                    'TakeRoutes',
                    ua.Variant(3, U32),
                    ua.Variant(['accepted: a', 'accepted: b', 'accepted: c'], S, is_array=True),
                ),
                'Int64 count': (
                    'TakeRoutes',
                    ua.Variant(1, I64),
                    ua.Variant(['accepted: x'], S, is_array=True),
                ),
                'Boolean count': (
                    'TakeRoutes',
                    ua.Variant(True, B),
                    ua.Variant(['accepted: x'], S, is_array=True),
                ),
                'garbage result': (
                    'TakeRoutes',
                    ua.Variant(1, U32),
                    ua.Variant(['\x00'], S, is_array=True),
                ),
                'empty confirmation': (
                    'Confirm',
                    ua.Variant(['', '\x00', ';;;;'], S, is_array=True),
                ),
                'int table': ('PublishRoutingTable', ua.Variant([1, 2, 3], I32, is_array=True)),
                'bad rule': ('PublishRoutingTable', ua.Variant(['A*=up'], S, is_array=True)),
                'huge table': (
                    'PublishRoutingTable',
                    ua.Variant(['A*=left'] * 1001, S, is_array=True),
                ),
                'long line': (
                    'Confirm',
                    ua.Variant(['A1;left;left;' + 's' * 300], S, is_array=True),
                ),
            }
            got = {why: await call(*args) for why, args in refusals.items()}
            for why, outcome in got.items():
                assert outcome in ('BadInvalidArgument', 'BadTypeMismatch'), (why, outcome)
            assert got['Int64 count'] == got['Boolean count'] == 'BadTypeMismatch'
            assert await warehouse() == state
            # the wrong number of arguments: the protocol's own codes
            assert await call('RequestRoute', 'A*') == 'BadArgumentsMissing'
            assert await call('RequestRoute', 'A*', 'left', 'x') == 'BadTooManyArguments'
            # well-formed calls still work
            assert (
                await call(
                    'TakeRoutes',
                    ua.Variant(2, U32),
                    ua.Variant(['accepted: A*=left', 'refused: no'], S, is_array=True),
                )
                is None
            )
            lines = ['A1;left;left;sorted', ';straight;straight;rejected']
            assert await call('Confirm', ua.Variant(lines, S, is_array=True)) is None
            table = ['A*=left', '*=straight']
            assert await call('PublishRoutingTable', ua.Variant(table, S, is_array=True)) is None
            pending, results, _, live_table = await warehouse()
            assert not pending and len(results) == 2 and live_table == table
            assert await count_node.read_value() == 2
        return len(refusals) + 2

    refused = asyncio.run(run())
    assert int(_diag(cell)['fieldbus_calls_refused']) == refused
    assert int(_diag(cell)['fieldbus_writes_refused']) == 0


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


# ---------------------------------------------------------------- OPC UA as a SCADA uses it
def test_an_opc_ua_subscription_sees_the_cell_move(cell):
    """Subscribe as a SCADA does (asyncua's own client): each change, stamped, in order."""
    import asyncio
    import threading
    import time as _time

    notes = {'cell.time': [], 'belt.encoder': [], 'sensor.pe_scan': []}
    ready, done = threading.Event(), threading.Event()

    class Handler:
        def datachange_notification(self, node, val, data):
            dv = data.monitored_item.Value
            notes[names[node.nodeid]].append((val, dv.SourceTimestamp, dv.ServerTimestamp))

    names = {}

    async def subscribe():
        from asyncua import Client

        async with Client(cell.fieldbus.opcua_endpoint, timeout=10) as client:
            idx = await client.get_namespace_index('urn:sorter_cell')
            inputs = await client.nodes.objects.get_child([f'{idx}:cell', f'{idx}:Inputs'])
            nodes = [await inputs.get_child([f'{idx}:{n}']) for n in notes]
            names.update({n.nodeid: name for n, name in zip(nodes, notes)})
            sub = await client.create_subscription(100, Handler())
            await sub.subscribe_data_change(nodes, sampling_interval=100)
            ready.set()
            while not done.is_set():
                await asyncio.sleep(0.05)
            await sub.delete()

    worker = threading.Thread(target=lambda: asyncio.run(subscribe()), daemon=True)
    worker.start()
    assert ready.wait(20.0), 'no subscription within 20 s'
    started = datetime.now(timezone.utc)
    try:
        # 3 s of simulated time over about 3 s of wall time, as a real-time cell runs
        for _ in range(60):
            cell.advance(50)
            _time.sleep(0.05)
        finished = datetime.now(timezone.utc)
        # the last changes reach the client a publishing interval or two later (more on a
        # loaded machine): wait for the cell's final time, at most 10 s
        t_end, until = cell.cell.t, _time.monotonic() + 10.0
        while _time.monotonic() < until and not (
            notes['cell.time'] and notes['cell.time'][-1][0] >= t_end - 0.2
        ):
            _time.sleep(0.05)
    finally:
        done.set()
        worker.join(20.0)
    times = [v for v, _, _ in notes['cell.time']]
    assert len(times) >= 15, f'{len(times)} notifications of cell.time in about 3 s'
    assert times == sorted(times) and times[-1] > times[0] + 2.0
    enc = [v for v, _, _ in notes['belt.encoder']]
    assert len(enc) >= 15 and enc == sorted(enc)
    assert len(notes['sensor.pe_scan']) >= 2  # the initial value and at least one edge
    stamped = notes['cell.time'][1:]
    for value, source, server in stamped:
        # SourceTimestamp: when the cell sampled the value (wall clock); the server stamps too
        assert source is not None and server is not None and source <= server
        assert started <= source <= finished
    sources = [source for _, source, _ in stamped]
    assert sources == sorted(sources)


def test_engineering_units_carry_their_unece_codes(cell, opcua):
    def info(name):
        props = opcua(name).get_properties()
        (prop,) = [p for p in props if p.read_browse_name().Name == 'EngineeringUnits']
        return prop.read_value()

    def code(text):  # OPC UA Part 8, 5.6.3: the UNECE common code's characters, 8 bits each
        value = 0
        for c in text:
            value = (value << 8) | ord(c)
        return value

    for name, unece in (('belt.encoder', 'MTR'), ('cell.time', 'SEC'), ('diverter.alpha', 'DD')):
        eu = info(name)
        assert eu.NamespaceUri == 'http://www.opcfoundation.org/UA/units/un/cefact'
        assert eu.UnitId == code(unece), name


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
        assert _u32(regs, t.address) * t.scale == pytest.approx(2.600, abs=1e-9)
        assert _u32(regs, enc.address) * enc.scale == pytest.approx(1.5 * 2.600, abs=2e-4)
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
            assert _u32(raw, 0) * rise.scale == pytest.approx(max(rises) * 1e-9, abs=rise.scale)
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
