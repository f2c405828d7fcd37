"""
The cell's I/O image over S7 (ISO-on-TCP), with python-snap7's server.

A Siemens PLC reads and writes the cell as two data blocks (PUT/GET, or any S7
client): DB1 holds the inputs (the cell to the PLC, read only), DB2 the outputs (the
PLC to the cell), at the byte and bit offsets the I/O map declares
(``Signal.s7``; the README's table lists them). Each S7 byte is the Modbus image's:
bits first (discrete inputs, coils), then the registers as big-endian words, so the
three protocols serve one image.

python-snap7's ``Server`` (pure Python since 3.0) handles the connection, the
communication set-up and the S7 framing; this subclass answers the data requests
from the ``IOImage`` itself, not from a copy: a read is built from the image's raw
tables at the moment it is served (one lock, so it is one period's image), and a
write is checked and applied whole through the image, as a Modbus or OPC UA write
is. The base server keeps no bit of the write request's address and copies write
data into its buffers unchecked; both are done here instead (its request parsing is
kept, its read and write handlers replaced; the version is pinned in setup.py).

Bad requests get S7's own return codes and change nothing: 0x03 (object access not
allowed) for a write to DB1, 0x0A (object does not exist) for another data block
or area, 0x05 (invalid address) for bytes no output has or beyond the block,
0x07 (data type inconsistent) for a value outside its output's range, a word
written in halves, or a bit write of more than one bit. Program upload or
download, PLC stop and start are refused with error class 0x81 code 0x04
(function not available in this context): the emulated PLC's program is the
cell. Every refusal is counted in the image (``fieldbus_writes_refused``). The CPU's
operating mode (SZL W#16#0424, what S7 tools show as the CPU state) is RUN.
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time

from snap7.datatypes import S7Area, S7WordLen
from snap7.s7protocol import S7Function, S7PDUType
from snap7.server import Server

from sorter_sim.model.io_map import (
    COIL,
    DI,
    HR,
    IR,
    S7_INPUT_BITS_BYTES,
    S7_INPUT_DB,
    S7_OUTPUT_BITS_BYTES,
    S7_OUTPUT_DB,
    WriteRefused,
    s7_size,
)

# S7 data item return codes (the S7comm "return code" of a read or write item)
OK = 0xFF
ACCESS_DENIED = 0x03
INVALID_ADDRESS = 0x05
TYPE_INCONSISTENT = 0x07
NO_OBJECT = 0x0A
NOT_AVAILABLE = 0x8104  # header error: function not available in this context
SZL_MODE = 0x0424  # SZL id of the CPU's current operating mode
SZL_MODE_RECORD = 20  # bytes of its data record
CPU_RUN = 0x08  # the mode byte (bzu-id) of a CPU in RUN

_WORD_BYTES = {
    S7WordLen.BYTE: 1,
    S7WordLen.CHAR: 1,
    S7WordLen.WORD: 2,
    S7WordLen.INT: 2,
    S7WordLen.DWORD: 4,
    S7WordLen.DINT: 4,
    S7WordLen.REAL: 4,
}


SLOTS = 16  # clients served at once
# s without a byte after which a connection gives its slot to a new client (when all
# are taken): a PLC polls every few hundred ms, so one silent this long has stopped
IDLE_S = 5.0


class CellS7Server(Server):
    """
    python-snap7's S7 server over one ``IOImage`` (see the module).

    Parameters
    ----------
    image : IOImage
        The cell's I/O image.
    host : str
        The IPv4 address to listen on.
    port : int
        The TCP port (S7's own is 102).
    slots : int
        Clients served at once.
    idle_s : float
        A connection that sent nothing for this long [s] is closed when every slot is
        taken and a new client comes: idle clients never lock the others out.

    """

    def __init__(self, image, host: str, port: int, *, slots: int = SLOTS, idle_s: float = IDLE_S):
        # the slots are kept here (``_handle_client``): a new client finds an idle one to
        # close or is closed itself. The base server's own limit is a backstop against a
        # flood of threads, with room for the new client and for the handlers of
        # connections just closed: each counts until its thread has finished, and under
        # load that can be after the next client comes (with room for one only, the base
        # server turned that client away while a slot was free)
        super().__init__(log=False, max_clients=2 * slots + 1)
        logging.getLogger('snap7').setLevel(logging.CRITICAL)  # failures are answered
        self.image = image
        self.host = host
        self.listen_port = port
        self.slots = slots
        self.idle_s = idle_s
        self.sizes = {db: s7_size(image.signals, db) for db in (S7_INPUT_DB, S7_OUTPUT_DB)}
        self._sockets: dict = {}  # each client's socket -> when it last sent a request
        self._by_address: dict = {}  # a client's address -> its socket
        self.closed_idle = 0  # idle connections closed for a new client
        self.refused_busy = 0  # new clients refused: every slot busy with a talking one

    def _handle_client(self, client_socket, address) -> None:
        with self.client_lock:
            if len(self._sockets) >= self.slots and not self._close_idlest():
                self.refused_busy += 1
                client_socket.close()
                # the base server counted this client in: it never runs its handler
                if threading.current_thread() in self.clients:
                    self.clients.remove(threading.current_thread())
                self.client_count = max(0, self.client_count - 1)
                return
            self._sockets[client_socket] = time.monotonic()
            self._by_address[address] = client_socket
        try:
            super()._handle_client(client_socket, address)
        finally:
            with self.client_lock:
                self._sockets.pop(client_socket, None)
                if self._by_address.get(address) is client_socket:
                    del self._by_address[address]

    def _close_idlest(self) -> bool:
        """Close the connection silent longest, if past ``idle_s``; return whether one was."""
        if not self._sockets:
            return False
        sock, last = min(self._sockets.items(), key=lambda kv: kv[1])
        if time.monotonic() - last < self.idle_s:
            return False
        del self._sockets[sock]  # its slot is the new client's now
        try:
            sock.shutdown(socket.SHUT_RDWR)  # its handler's receive ends; it cleans up
        except OSError:
            pass
        self.closed_idle += 1
        return True

    def _process_request(self, request_data, client_address):
        with self.client_lock:
            sock = self._by_address.get(client_address)
            if sock in self._sockets:
                self._sockets[sock] = time.monotonic()
        return super()._process_request(request_data, client_address)

    def serve(self) -> int:
        """Start listening; return the port. ValueError naming the address if it cannot."""
        try:
            self.start(tcp_port=self.listen_port)
        except Exception as exc:
            cause = exc.__cause__ or exc
            text = str(cause).splitlines()[0] if str(cause) else type(cause).__name__
            raise ValueError(
                f'cannot serve S7 on {self.host}:{self.listen_port}: {text}'
            ) from None
        return self.server_socket.getsockname()[1]

    # -------------------------------------------------------------- the image as S7 bytes
    def _block(self, db: int) -> bytes:
        """Return a data block's bytes now, from the image's raw tables (one lock)."""
        if db == S7_INPUT_DB:
            bits_table, regs_table, n_bits = DI, IR, S7_INPUT_BITS_BYTES
        else:
            bits_table, regs_table, n_bits = COIL, HR, S7_OUTPUT_BITS_BYTES
        raw = self.image.snapshot_tables((bits_table, regs_table))
        out = bytearray(n_bits)
        for i, b in enumerate(raw[bits_table]):
            if b:
                out[i // 8] |= 1 << (i % 8)
        for r in raw[regs_table]:
            out += struct.pack('>H', r & 0xFFFF)
        return bytes(out[: self.sizes[db]])

    # -------------------------------------------------------------- requests
    def _parse_address_specification(self, addr_spec: bytes) -> dict:
        spec = super()._parse_address_specification(addr_spec)
        if spec and len(addr_spec) >= 12:
            address = int.from_bytes(addr_spec[9:12], 'big')
            spec['bit'] = address % 8  # the base parser keeps only the byte
        return spec

    def _item(self, spec: dict) -> tuple[int, bytes, int]:
        """Read one item: (return code, data, transport size of the answer)."""
        if not spec:
            return INVALID_ADDRESS, b'', 0
        if spec.get('area') != S7Area.DB or spec.get('db_number') not in self.sizes:
            return NO_OBJECT, b'', 0
        block = self._block(spec['db_number'])
        start, count, word_len = spec['start'], spec['count'], spec['word_len']
        if word_len == S7WordLen.BIT:
            if count != 1 or start >= len(block):
                return INVALID_ADDRESS, b'', 0
            return OK, bytes([(block[start] >> spec['bit']) & 1]), 0x03
        size = _WORD_BYTES.get(word_len)
        if size is None:
            return TYPE_INCONSISTENT, b'', 0
        n = count * size
        if start + n > len(block):
            return INVALID_ADDRESS, b'', 0
        return OK, block[start : start + n], 0x04

    def _handle_read_area(self, request: dict, client_address) -> bytes:
        params = request.get('parameters', {})
        specs = params.get('address_specs') or [params.get('address_spec') or {}]
        data = bytearray()
        for i, spec in enumerate(specs):
            code, payload, size = self._item(spec)
            if code != OK:
                self.image.count('reads_refused')
                data += struct.pack('>BBH', code, 0x00, 0)
                continue
            bits = len(payload) if size == 0x03 else 8 * len(payload)
            data += struct.pack('>BBH', OK, size, bits) + payload
            if i < len(specs) - 1 and len(payload) % 2:
                data.append(0)  # fill byte between items
        header = struct.pack(
            '>BBHHHHBB', 0x32, S7PDUType.ACK_DATA, 0, request['sequence'], 2, len(data), 0, 0
        )
        return header + struct.pack('>BB', S7Function.READ_AREA, len(specs)) + bytes(data)

    def _handle_write_area(self, request: dict, client_address) -> bytes:
        params = request.get('parameters', {})
        if params.get('item_count', 1) != 1:
            self.image.count()
            return self._build_error_response(request, NOT_AVAILABLE)
        spec = params.get('address_spec') or {}
        payload = bytes(request.get('data', {}).get('data', b''))
        code = self._write(spec, payload)
        if code != OK:
            self.image.count()
        header = struct.pack(
            '>BBHHHHBB', 0x32, S7PDUType.ACK_DATA, 0, request['sequence'], 2, 1, 0, 0
        )
        return header + struct.pack('>BB', S7Function.WRITE_AREA, 1) + bytes([code])

    def _write(self, spec: dict, payload: bytes) -> int:
        """Apply one write item through the image; return its S7 return code."""
        if not spec or not payload:
            return INVALID_ADDRESS
        if spec.get('area') != S7Area.DB or spec.get('db_number') not in self.sizes:
            return NO_OBJECT
        if spec['db_number'] == S7_INPUT_DB:
            return ACCESS_DENIED  # the inputs are the cell's
        start, word_len = spec['start'], spec['word_len']
        writes = []
        if word_len == S7WordLen.BIT:
            if spec['count'] != 1 or len(payload) != 1 or payload[0] > 1:
                return TYPE_INCONSISTENT
            if start >= S7_OUTPUT_BITS_BYTES:
                return INVALID_ADDRESS  # a bit of a register: write the word
            writes.append((COIL, 8 * start + spec['bit'], [payload[0]]))
        else:
            end = start + len(payload)
            if end > self.sizes[S7_OUTPUT_DB]:
                return INVALID_ADDRESS
            for byte in range(start, min(end, S7_OUTPUT_BITS_BYTES)):
                value = payload[byte - start]
                coils = [(value >> b) & 1 for b in range(8)]
                writes.append((COIL, 8 * byte, coils))
            if end > S7_OUTPUT_BITS_BYTES:
                lo = max(start, S7_OUTPUT_BITS_BYTES)
                if (lo - S7_OUTPUT_BITS_BYTES) % 2 or (end - S7_OUTPUT_BITS_BYTES) % 2:
                    return TYPE_INCONSISTENT  # a register is written whole
                words = payload[lo - start :]
                regs = [int.from_bytes(words[i : i + 2], 'big') for i in range(0, len(words), 2)]
                writes.append((HR, (lo - S7_OUTPUT_BITS_BYTES) // 2, regs))
        # coils no output has must stay 0 in a byte written whole
        checked = []
        for table, address, values in writes:
            if table == COIL and len(values) == 8:
                owned = [self.image.owns(COIL, address + b) for b in range(8)]
                if any(v and not own for v, own in zip(values, owned)):
                    return INVALID_ADDRESS
                checked += [(COIL, address + b, [v]) for b, v in enumerate(values) if owned[b]]
            else:
                checked.append((table, address, values))
        try:
            self.image.write_raw_many(checked)
        except WriteRefused as exc:
            return INVALID_ADDRESS if exc.code == 'address' else TYPE_INCONSISTENT
        return OK

    # the emulated PLC's program and run state are the cell's: not for a client to change
    def _refuse(self, request: dict, client_address) -> bytes:
        self.image.count('illegal_functions')
        return self._build_error_response(request, NOT_AVAILABLE)

    _handle_plc_control = _refuse
    _handle_plc_stop = _refuse
    _handle_start_upload = _refuse
    _handle_request_download = _refuse

    def _get_szl_data(self, szl_id: int, szl_index: int) -> bytes | None:
        """
        Answer SZL W#16#0424 (the CPU's operating mode) as a CPU in RUN does; others as the base.

        The emulated PLC runs while the cell is served (stop and start are refused
        above), so its mode is RUN. The record is the one a CPU in RUN sends: event
        W#16#5144, ae 0xFF, then bzu-id 0x08 (RUN), which S7 clients read as the CPU
        state (Snap7's GetPlcStatus takes that byte: 0x08 RUN, 0x04 STOP).
        """
        if szl_id == SZL_MODE:
            record = struct.pack('>HBB', 0x5144, 0xFF, CPU_RUN).ljust(SZL_MODE_RECORD, b'\0')
            return struct.pack('>HH', SZL_MODE_RECORD, 1) + record
        data = super()._get_szl_data(szl_id, szl_index)
        if szl_id == 0x0000 and data is not None:
            data += struct.pack('>H', SZL_MODE)  # the list of SZL ids names this one too
        return data
