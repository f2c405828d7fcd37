"""
A Modbus TCP server of the cell's I/O image, as the Modbus Application Protocol v1.1b3 says.

Why not pymodbus's server: its simulator device answered a write single coil with an
illegal value (0x1234) by setting the coil and echoing 0xFF00, dropped the second of two
requests that arrived in one TCP segment, wedged a connection on a frame with a non-zero
protocol id, and answered function codes 17 and 24 with its own built-in data. A server
over one image with nine function codes is small enough to own and test byte by byte;
the project's clients (the soft PLC, the tests) still use pymodbus and other stacks.

A line's stations share one server: the unit id of a request picks the station's
image (``units``), and a unit id no station has is exception 0x0B (gateway target
device failed to respond). A single cell is unit 1 (the unit id Modbus clients send
unless told otherwise, and station S01's in a line) and answers 255 too, the unit id
the Modbus TCP implementation guide (4.4.1.2) gives a device addressed by its IP
address alone; any other unit id is exception 0x0B, as on a line.

Function codes: 1, 2 (read coils / discrete inputs), 3, 4 (read holding / input
registers), 5, 6 (write single coil / register), 15, 16 (write multiple coils /
registers), 22 (mask write register), 23 (read/write multiple registers), 17 (report
server id) and 43/14 (read device identification): the device is this project. Anything
else is exception 1 (illegal function). Every request is answered in the order it came,
also when several arrive in one segment; a frame whose protocol id is not 0 is dropped
(its length says where the next one starts) and the connection goes on; a frame whose
length field cannot be a Modbus frame ends the connection, since nothing in the stream
says where the next frame would start. Each is counted.
"""

from __future__ import annotations

import asyncio
import struct

from sorter_sim.model.io_map import COIL, DI, HR, IR, WriteRefused

ILLEGAL_FUNCTION = 1
ILLEGAL_ADDRESS = 2
ILLEGAL_VALUE = 3
GATEWAY_TARGET_FAILED = 0x0B
CELL_UNITS = (1, 0xFF)  # the unit ids a single cell answers

VENDOR = 'sorter_cell'
PRODUCT = 'sorter_cell emulated pivot diverter'
VERSION = '0.1.0'
# read device identification: basic objects, streamed and individually (code 4)
CONFORMITY = 0x81

_READS = {1: COIL, 2: DI, 3: HR, 4: IR}
_MAX_READ = {1: 2000, 2: 2000, 3: 125, 4: 125}
_IDLE_S = 600.0  # a connection that sends nothing this long is closed


class ModbusRefusal(Exception):
    """A request answered with a Modbus exception ``code``; ``kind`` is what is counted."""

    def __init__(self, code: int, kind: str):
        super().__init__(kind)
        self.code = code
        self.kind = kind


class ModbusTcpImageServer:
    """
    Serve ``image`` (a ``sorter_sim.frontends.fieldbus.IOImage``) on ``host:port`` over Modbus TCP.

    Counters in ``image.stats``: 'writes', 'refused' (writes refused), 'reads_refused',
    'illegal_functions', 'frames_dropped'.
    """

    def __init__(self, image, host: str, port: int, units: dict | None = None):
        self.image = image
        # a line's stations: unit id -> the server answering for that station's image
        self.units = units
        self.units_refused = 0
        self.host = host
        self.port = port
        self._server: asyncio.base_events.Server | None = None
        self._writers: set[asyncio.StreamWriter] = set()

    async def start(self) -> int:
        """Listen; return the port (OSError when it cannot)."""
        self._server = await asyncio.start_server(self._serve, self.host, self.port)
        return self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        """Stop listening and close every connection at once (no waiting on clients)."""
        if self._server is not None:
            self._server.close()
        for w in list(self._writers):
            w.transport.abort()
        self._writers.clear()
        self._server = None

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        try:
            while True:
                header = await asyncio.wait_for(reader.readexactly(7), _IDLE_S)
                tid, protocol, length, unit = struct.unpack('>HHHB', header)
                if not 2 <= length <= 254:
                    # no way to find the next frame's start: end the connection
                    self.image.count('frames_dropped')
                    return
                pdu = await asyncio.wait_for(reader.readexactly(length - 1), _IDLE_S)
                if protocol != 0:
                    self.image.count('frames_dropped')
                    continue
                if self.units is None and unit in CELL_UNITS:
                    reply = self.answer(pdu)
                elif self.units is not None and unit in self.units:
                    reply = self.units[unit].answer(pdu)
                else:
                    # no device at this unit id: what a gateway answers for a device
                    # that is not there (Modbus Application Protocol 7, code 0x0B)
                    self.units_refused += 1
                    reply = bytes([pdu[0] | 0x80, GATEWAY_TARGET_FAILED])
                writer.write(struct.pack('>HHHB', tid, 0, len(reply) + 1, unit) + reply)
                # a client that does not read its answers is not served further until it
                # does; its socket buffer, not this process, holds the backlog
                await writer.drain()
        except (asyncio.IncompleteReadError, asyncio.TimeoutError, ConnectionError, OSError):
            pass
        finally:
            self._writers.discard(writer)
            writer.transport.abort()

    # ---------------------------------------------------------------- one request
    def answer(self, pdu: bytes) -> bytes:
        """
        Return the response PDU to the request PDU ``pdu`` (an exception response too).

        Parameters
        ----------
        pdu : bytes
            The request PDU (function code and data).

        Returns
        -------
        bytes
            The response PDU.

        """
        fc = pdu[0]
        try:
            return bytes([fc]) + self._handle(fc, pdu[1:])
        except ModbusRefusal as exc:
            self.image.count(exc.kind)
            return bytes([fc | 0x80, exc.code])

    def _handle(self, fc: int, body: bytes) -> bytes:
        if fc in _READS:
            start, qty = _fields(body, '>HH', 'reads_refused')
            if not 1 <= qty <= _MAX_READ[fc]:
                raise ModbusRefusal(ILLEGAL_VALUE, 'reads_refused')
            values = self._read(_READS[fc], start, qty)
            data = _pack_bits(values) if fc in (1, 2) else struct.pack(f'>{qty}H', *values)
            return bytes([len(data)]) + data
        if fc == 5:
            address, raw = _fields(body, '>HH', 'refused')
            if raw not in (0x0000, 0xFF00):
                raise ModbusRefusal(ILLEGAL_VALUE, 'refused')
            self._write(COIL, address, [1 if raw else 0])
            return body
        if fc == 6:
            address, raw = _fields(body, '>HH', 'refused')
            self._write(HR, address, [raw])
            return body
        if fc == 15:
            start, qty, count = _head(body, '>HHB')
            if not 1 <= qty <= 1968 or count != (qty + 7) // 8 or len(body) != 5 + count:
                raise ModbusRefusal(ILLEGAL_VALUE, 'refused')
            bits = [(body[5 + i // 8] >> (i % 8)) & 1 for i in range(qty)]
            self._write(COIL, start, bits)
            return struct.pack('>HH', start, qty)
        if fc == 16:
            start, qty, count = _head(body, '>HHB')
            if not 1 <= qty <= 123 or count != 2 * qty or len(body) != 5 + count:
                raise ModbusRefusal(ILLEGAL_VALUE, 'refused')
            self._write(HR, start, list(struct.unpack(f'>{qty}H', body[5:])))
            return struct.pack('>HH', start, qty)
        if fc == 22:
            address, and_mask, or_mask = _fields(body, '>HHH', 'refused')
            (current,) = self._read(HR, address, 1, refusal='refused')
            self._write(HR, address, [(current & and_mask) | (or_mask & ~and_mask & 0xFFFF)])
            return body
        if fc == 23:
            r_start, r_qty, w_start, w_qty, count = _head(body, '>HHHHB')
            if (
                not 1 <= r_qty <= 125
                or not 1 <= w_qty <= 121
                or count != 2 * w_qty
                or len(body) != 9 + count
            ):
                raise ModbusRefusal(ILLEGAL_VALUE, 'refused')
            # the write first, then the read (the protocol's order); a refused read
            # after an applied write cannot be: both are checked before either is done
            self._read(HR, r_start, r_qty, refusal='reads_refused')
            self._write(HR, w_start, list(struct.unpack(f'>{w_qty}H', body[9:])))
            values = self._read(HR, r_start, r_qty, refusal='reads_refused')
            return bytes([2 * r_qty]) + struct.pack(f'>{r_qty}H', *values)
        if fc == 17:
            if body:
                raise ModbusRefusal(ILLEGAL_VALUE, 'reads_refused')
            text = f'{VENDOR} {VERSION}'.encode()
            return bytes([len(text) + 2, 1, 0xFF]) + text
        if fc == 43 and body[:1] == b'\x0e':
            return self._identification(body)
        raise ModbusRefusal(ILLEGAL_FUNCTION, 'illegal_functions')

    def _identification(self, body: bytes) -> bytes:
        """
        Read Device Identification (43/14), as the protocol's § 6.21 says.

        The device holds the basic objects (0-2) and serves them streamed and one by
        one: conformity level 0x81. A stream request (code 1, 2 or 3) is answered at
        that level whatever level it asks for, from its object id or, when the device
        has no such object, from object 0; an individual request (code 4) for an
        object it does not have is exception 2; any other code is exception 3.
        """
        if len(body) != 3:
            raise ModbusRefusal(ILLEGAL_VALUE, 'reads_refused')
        code, first = body[1], body[2]
        objects = {0: VENDOR, 1: PRODUCT, 2: VERSION}
        if code in (1, 2, 3):
            ids = [i for i in objects if i >= first] if first in objects else list(objects)
        elif code == 4:
            if first not in objects:
                raise ModbusRefusal(ILLEGAL_ADDRESS, 'reads_refused')
            ids = [first]
        else:
            raise ModbusRefusal(ILLEGAL_VALUE, 'reads_refused')
        # the whole answer fits one response: no more follows, next object id 0
        out = bytes([0x0E, code, CONFORMITY, 0x00, 0x00, len(ids)])
        for i in ids:
            value = objects[i].encode()
            out += bytes([i, len(value)]) + value
        return out

    def _read(self, table: str, start: int, qty: int, refusal: str = 'reads_refused') -> list:
        values = self.image.snapshot(table)
        if start + qty > len(values):
            raise ModbusRefusal(ILLEGAL_ADDRESS, refusal)
        return values[start : start + qty]

    def _write(self, table: str, start: int, values: list) -> None:
        try:
            self.image.write_raw(table, start, values)
        except WriteRefused as exc:
            raise ModbusRefusal(
                ILLEGAL_ADDRESS if exc.code == 'address' else ILLEGAL_VALUE, 'refused'
            ) from None


def _fields(body: bytes, fmt: str, kind: str) -> tuple:
    """Unpack a request body of exactly ``fmt``'s size, else exception 3."""
    if len(body) != struct.calcsize(fmt):
        raise ModbusRefusal(ILLEGAL_VALUE, kind)
    return struct.unpack(fmt, body)


def _head(body: bytes, fmt: str) -> tuple:
    """Unpack the fixed head ``fmt`` of a write request body, else exception 3."""
    size = struct.calcsize(fmt)
    if len(body) < size:
        raise ModbusRefusal(ILLEGAL_VALUE, 'refused')
    return struct.unpack(fmt, body[:size])


def _pack_bits(values: list) -> bytes:
    out = bytearray((len(values) + 7) // 8)
    for i, v in enumerate(values):
        if v:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)
