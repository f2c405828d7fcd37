"""
The I/O image over S7, checked with python-snap7's client as a Siemens PLC's PUT/GET.

The cell runs in lock-step in this process with its S7 server; the tests read the
declared data blocks against what the cell knows, write outputs as bits, words and a
whole block and see the cell act one period later, and send the bad requests a careless
or hostile client sends: each gets S7's own return code, changes nothing, and the node
keeps serving.
"""

from __future__ import annotations

import math
import socket
import time

import pytest
import snap7
from ros_harness import free_port
from snap7.type import Area, WordLen
from fieldbus_helpers import MAP, SENSORS, cell_state, serving_cell

from sorter_sim.model.io_map import io_map, s7_size

pytestmark = pytest.mark.ros


@pytest.fixture
def cell(ros):
    return serving_cell(ros, s7_port=free_port(), modbus_port=free_port())


@pytest.fixture
def plc(cell):
    client = snap7.client.Client()
    client.connect('127.0.0.1', 0, 1, cell.fieldbus.s7_port)
    yield client
    client.disconnect()


def _value(block: bytes, name: str):
    """Decode a signal from a DB1/DB2 image by its declared S7 place (the map's, not ours)."""
    s = MAP[name]
    _, byte, bit, kind = s.s7
    if kind == 'BOOL':
        return bool((block[byte] >> bit) & 1)
    if kind == 'INT':
        return int.from_bytes(block[byte : byte + 2], 'big', signed=True) * s.scale
    if kind == 'WORD':
        return int.from_bytes(block[byte : byte + 2], 'big') * s.scale
    if kind == 'UDINT':
        return int.from_bytes(block[byte : byte + 4], 'big') * s.scale
    return block[byte : byte + 2 * s.words].rstrip(b'\0').decode('ascii')


def test_the_data_blocks_are_what_the_cell_knows(cell, plc):
    cell.advance(1234)
    c = cell.cell
    db1 = plc.db_read(1, 0, s7_size(io_map(SENSORS), 1))
    assert _value(db1, 'cell.time') == pytest.approx(c.t, abs=1e-4)
    assert _value(db1, 'belt.encoder') == pytest.approx(1.5 * c.t, abs=2e-4)
    for name, blocked in c.sensor_states().items():
        assert _value(db1, f'sensor.{name}') == blocked
        # a single bit, as STEP 7's DB1.DBX reads it
        _, byte, bit, _ = MAP[f'sensor.{name}'].s7
        assert plc.read_area(Area.DB, 1, 8 * byte + bit, 1, WordLen.Bit) == bytearray([blocked])
    assert _value(db1, 'diverter.alpha') == pytest.approx(math.degrees(c.alpha), abs=0.01)
    assert _value(db1, 'packml.state') == 6  # Execute
    assert _value(db1, 'status.estop') is False
    # the same bytes the Modbus image holds, register for register
    from pymodbus.client import ModbusTcpClient

    mb = ModbusTcpClient('127.0.0.1', port=cell.fieldbus.modbus_port, timeout=5, retries=0)
    assert mb.connect()
    try:
        regs = mb.read_input_registers(0, count=8).registers
    finally:
        mb.close()
    assert list(db1[8:24]) == [b for r in regs for b in r.to_bytes(2, 'big')]


def test_outputs_written_as_bits_words_and_a_whole_block_act_one_period_later(cell, plc):
    popup, alpha = MAP['diverter.popup'], MAP['diverter.alpha_setpoint']
    _, byte, bit, _ = popup.s7
    plc.write_area(Area.DB, 2, 8 * byte + bit, bytearray([1]), WordLen.Bit)
    plc.db_write(2, alpha.s7[1], bytearray(alpha.raw(-30.0).to_bytes(2, 'big')))
    assert cell.get_parameter('alpha_deg').value == 60.0  # not before the next period
    cell.advance(1)
    assert cell.get_parameter('alpha_deg').value == -30.0
    cell.advance(300)
    assert cell.cell.stroke == 1.0 and math.degrees(cell.cell.alpha) == pytest.approx(-30.0)
    # the whole output block in one PUT, as a PLC writes its process image: disks down,
    # belt on, α 45, a heartbeat and a PackML hold (4)
    db2 = bytearray(s7_size(io_map(SENSORS), 2))
    db2[0] = 1 << MAP['belt.run'].s7[2]
    for name, value in (
        ('diverter.alpha_setpoint', 45.0),
        ('plc.heartbeat', 7),
        ('packml.command', 4),
    ):
        s = MAP[name]
        db2[s.s7[1] : s.s7[1] + 2] = s.raw(value).to_bytes(2, 'big')
    plc.db_write(2, 0, db2)
    cell.advance(1)
    assert cell.get_parameter('alpha_deg').value == 45.0
    assert cell.cell.watchdog_armed and cell.cell.packml.state == 'Held'
    cell.advance(200)
    assert cell.cell.stroke == 0.0
    assert plc.db_read(2, 0, len(db2)) == db2  # the outputs read back as written


def test_bad_requests_get_s7_return_codes_and_change_nothing(cell, plc):
    cell.advance(5)
    before = cell_state(cell)
    alpha = MAP['diverter.alpha_setpoint']
    a = alpha.s7[1]
    cases = [
        (lambda: plc.db_write(1, 0, bytearray([1])), '0x03'),  # the inputs are the cell's
        (lambda: plc.db_write(9, 0, bytearray([1])), '0x0a'),  # no such block
        (lambda: plc.write_area(Area.MK, 0, 0, bytearray([1])), '0x0a'),  # no merker area
        (lambda: plc.db_write(2, a, bytearray(alpha.raw(90.5).to_bytes(2, 'big'))), '0x07'),
        (lambda: plc.db_write(2, a + 1, bytearray([1])), '0x07'),  # half a word
        (lambda: plc.db_write(2, 6, bytearray([0, 1, 0, 0])), '0x05'),  # past the block
        (lambda: plc.db_write(2, 1, bytearray([0x80])), '0x05'),  # a coil nobody has
        (lambda: plc.write_area(Area.DB, 2, 8 * a, bytearray([1]), WordLen.Bit), '0x05'),
        (lambda: plc.db_write(2, MAP['packml.command'].s7[1], bytearray([0, 10])), '0x07'),
    ]
    for call, code in cases:
        with pytest.raises(Exception) as err:
            call()
        assert code in str(err.value), str(err.value)
    with pytest.raises(Exception) as err:
        plc.read_area(Area.DB, 1, 10_000, 4)  # beyond DB1
    assert '0x05' in str(err.value)
    # the emulated PLC's run state and program are not a client's to change
    for call in (plc.plc_stop, plc.plc_hot_start):
        with pytest.raises(Exception) as err:
            call()
        assert 'class=0x81, code=0x04' in str(err.value)
    cell.advance(5)
    assert cell_state(cell) == before
    diag = cell.fieldbus_bridge.diagnostics()
    assert int(diag['fieldbus_writes_refused']) == len(cases)
    assert int(diag['fieldbus_reads_refused']) == 1
    assert int(diag['fieldbus_illegal_functions']) == 2
    # and it still serves
    assert plc.db_read(2, a, 2) == bytearray(alpha.raw(60.0).to_bytes(2, 'big'))


def test_a_stalled_or_garbage_speaking_client_does_not_stop_the_others(cell, plc):
    port = cell.fieldbus.s7_port
    stalled = socket.create_connection(('127.0.0.1', port))
    stalled.sendall(b'\x03\x00\x00\x16\x11')  # half a connection request, then nothing
    garbage = socket.create_connection(('127.0.0.1', port))
    garbage.sendall(bytes(range(256)))
    try:
        t0 = time.monotonic()
        for _ in range(20):
            cell.advance(10)
            assert plc.db_read(1, 0, 8) is not None
        assert time.monotonic() - t0 < 5.0
        assert plc.get_connected()
    finally:
        stalled.close()
        garbage.close()
    t0 = time.monotonic()
    cell.fieldbus.stop()
    assert time.monotonic() - t0 < 2.0  # a node stopping never waits on its clients


def test_a_killed_server_process_leaves_the_cell_running_and_says_so(cell, plc):
    import os
    import signal

    pid = cell.fieldbus.pid
    assert pid and cell.fieldbus_bridge.diagnostics()['fieldbus_servers'] == 'running'
    os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 5.0
    while cell.fieldbus.alive and time.monotonic() < deadline:
        time.sleep(0.05)
    k = cell.cell.k
    cell.advance(500)  # the image is still exchanged with nobody: the cell runs on
    assert cell.cell.k == k + 500
    assert cell.fieldbus_bridge.diagnostics()['fieldbus_servers'] == 'ended'
    with pytest.raises(Exception):
        plc.db_read(1, 0, 8)


def test_the_cpu_reports_run_as_s7_tools_read_it(cell, plc):
    # the operating mode as Snap7's GetPlcStatus reads it: SZL W#16#0424, its record's
    # fourth byte (after the SZL header, LENTHDR and N_DR), 0x08 RUN, 0x04 STOP
    szl = plc.read_szl(0x0424, 0)
    data = bytes(szl.Data[: szl.Header.LengthDR])
    length, records = int.from_bytes(data[0:2], 'big'), int.from_bytes(data[2:4], 'big')
    assert (length, records) == (20, 1) and len(data) == 4 + length
    assert data[7] == 0x08, data.hex()
    assert plc.get_cpu_state() == 'S7CpuStatusRun'
    # the list of SZL ids names it, and the data blocks are served as before
    assert b'\x04\x24' in plc.read_szl_list()
    assert len(plc.db_read(1, 0, 8)) == 8


def _disconnect(clients) -> None:
    """Disconnect each client, those the server has closed already too."""
    for c in clients:
        try:
            c.disconnect()
        except Exception:  # noqa: BLE001 - closed by the server already
            pass


def test_sixteen_idle_clients_never_lock_a_new_one_out(cell):
    """Every slot taken by a client that says nothing: a new client gets the idlest's slot."""
    from sorter_sim.frontends.s7_server import IDLE_S, SLOTS

    port = cell.fieldbus.s7_port
    idle = []
    try:
        for _ in range(SLOTS):
            c = snap7.client.Client()
            c.connect('127.0.0.1', 0, 1, port)
            idle.append(c)
        t_full = time.monotonic()
        # once they have been silent for the idle time, a newcomer is always served
        time.sleep(max(0.0, IDLE_S + 0.5 - (time.monotonic() - t_full)))
        for _ in range(3):
            fresh = snap7.client.Client()
            fresh.connect('127.0.0.1', 0, 1, port)
            assert fresh.db_read(1, 0, 8) is not None
            idle.append(fresh)
        # the ones it displaced were the idle ones, closed: the newest still serve
        assert all(c.db_read(1, 0, 8) is not None for c in idle[-3:])
        closed = 0
        for c in idle[:SLOTS]:
            try:
                c.db_read(1, 0, 8)
            except Exception:  # noqa: BLE001 - a closed connection raises in the client
                closed += 1
        assert closed >= 3
    finally:
        _disconnect(idle)


def test_a_new_client_is_served_while_a_closed_idle_ones_handler_still_finishes(cell, monkeypatch):
    """
    A connection closed for a new client counts in the base server until its thread ends.

    On a loaded machine that thread can still be finishing when the next client comes:
    the server must take that client (closing the next idle one for it), not turn it
    away as if every place were held. Here the closed connections' handlers take 0.5 s
    to finish, and one slot turns over twice within it.
    """
    import snap7.server

    from sorter_sim.frontends.s7_server import CellS7Server

    receive = snap7.server.ServerISOConnection.receive_data

    def slow_to_finish(self):
        try:
            return receive(self)
        except socket.timeout:
            raise
        except Exception:
            time.sleep(0.5)  # a closed connection's handler, late to its clean-up
            raise

    monkeypatch.setattr(snap7.server.ServerISOConnection, 'receive_data', slow_to_finish)
    server = CellS7Server(cell.fieldbus.image, '127.0.0.1', free_port(), slots=1, idle_s=0.1)
    port = server.serve()
    clients = []
    try:
        for _ in range(3):  # each one idle past 0.1 s before the next comes
            c = snap7.client.Client()
            c.connect('127.0.0.1', 0, 1, port)
            assert c.db_read(1, 0, 8) is not None
            clients.append(c)
            time.sleep(0.2)
        assert server.closed_idle == 2 and server.refused_busy == 0
    finally:
        _disconnect(clients)
        server.stop()
