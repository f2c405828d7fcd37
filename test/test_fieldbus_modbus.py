"""
The Modbus TCP server of the I/O image, checked with pymodbus, pyModbusTCP and raw frames.

A client that leaves mid-request, two writers at once, every frame the specification
names at byte level (exceptions, pipelined requests, dropped frames), a stack this
project neither wrote nor serves with, and the unit ids a line's gateway asks at.
"""

from __future__ import annotations

import socket
import threading

import pytest
from pymodbus.client import ModbusTcpClient
import fieldbus_helpers as fb
from fieldbus_helpers import MAP, SENSORS, cell_state, diagnostics

from sorter_sim.model.core import cell_kernels as ck

pytestmark = pytest.mark.ros
# the fixtures: a cell serving Modbus TCP and OPC UA, and a Modbus client
cell, modbus = fb.cell, fb.modbus


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
    assert int(diagnostics(cell)['fieldbus_outputs_lost']) > 0  # many writes, one period
    cell.advance(10)
    assert cell.context.ok()


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
        before = cell_state(cell)
        # write single coil with anything but 0x0000 / 0xFF00: exception 3, nothing set
        for value in (0x1234, 0x0001, 0xFFFF):
            s.sendall(_frame(1, struct.pack('>BHH', 5, popup, value)))
            assert _replies(s, 1) == [(1, bytes([0x85, 3]))]
        cell.advance(2)
        assert cell_state(cell) == before
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
    diag = diagnostics(cell)
    assert int(diag['fieldbus_illegal_functions']) == 5
    assert int(diag['fieldbus_frames_dropped']) == 2
    assert int(diag['fieldbus_writes_refused']) == 3
    assert int(diag['fieldbus_reads_refused']) == 1
    r = ModbusTcpClient('127.0.0.1', port=cell.fieldbus.modbus_port, timeout=5, retries=0)
    assert r.connect() and r.read_holding_registers(beat, count=1).registers == [0x17]
    r.close()


def _device_id(server, code: int, first: int) -> tuple:
    """Ask 43/14 and parse the answer as § 6.21 lays it out; an exception as (code,)."""
    pdu = server.answer(bytes([43, 14, code, first]))
    if pdu[0] == 43 | 0x80:
        return (pdu[1],)
    assert pdu[:3] == bytes([43, 14, code])  # the request's read device id code echoed
    conformity, more, next_id, n = pdu[3:7]
    objects, at = {}, 7
    for _ in range(n):
        oid, size = pdu[at], pdu[at + 1]
        objects[oid] = pdu[at + 2 : at + 2 + size].decode()
        at += 2 + size
    assert at == len(pdu)
    return conformity, more, next_id, objects


def test_read_device_identification_answers_every_code_at_the_devices_conformity_level():
    """Modbus Application Protocol v1.1b3 § 6.21, byte by byte, on the server alone."""
    from fieldbus_helpers import modbus_image

    from sorter_sim.frontends.modbus_server import ModbusTcpImageServer

    server = ModbusTcpImageServer(modbus_image(), '127.0.0.1', 0)
    basic = {0: 'sorter_cell', 1: 'sorter_cell emulated pivot diverter', 2: '0.1.0'}
    # basic, regular and extended stream requests: a basic device answers each with its
    # basic objects, its level saying individual access (code 4) is served too: 0x81
    for code in (1, 2, 3):
        assert _device_id(server, code, 0) == (0x81, 0, 0, basic)
        # a stream from an object the device has; from one it has not: from object 0
        assert _device_id(server, code, 1) == (0x81, 0, 0, {1: basic[1], 2: basic[2]})
        assert _device_id(server, code, 0x80) == (0x81, 0, 0, basic)
    # individual access: the object asked for, or exception 2 for one it does not have
    assert _device_id(server, 4, 2) == (0x81, 0, 0, {2: basic[2]})
    assert _device_id(server, 4, 3) == (2,)
    # a read device id code the protocol has not: exception 3
    assert _device_id(server, 0, 0) == (3,) and _device_id(server, 5, 0) == (3,)


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
        # a regular stream request, answered at the device's level
        regular = client.read_device_identification(read_code=2)
        assert regular is not None, client.last_error_as_txt
        assert regular.conformity_level == 0x81 and regular.vendor_name == b'sorter_cell'
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
