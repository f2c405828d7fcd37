"""
The cell's fieldbus: one I/O image, served over Modbus TCP and OPC UA.

``IOImage`` is the cell's process image, generic over the declared I/O map
(``sorter_sim.model.io_map``): the simulation node refreshes its inputs at the end of
every physics period and takes the outputs clients wrote at the start of the next
one, the way a PLC's I/O image is exchanged once per cycle. ``FieldbusServers``
serves it in one background thread (an asyncio loop): Modbus TCP
(``modbus_server``: discrete inputs, coils, input and holding registers at the map's
addresses and scaling) and OPC UA with asyncua (the address space of
``opcua_model``: a folder per cell, ``Inputs`` and ``Outputs`` with typed variables in
engineering units; only outputs are writable, and only by anonymous sessions: no
identity a client offers makes it an administrator).

Bad writes change nothing and get the protocol's own error: Modbus exception 2
(illegal data address) for an address no output has, 3 (illegal data value) for
a value outside the output's range; OPC UA ``BadUserAccessDenied`` for inputs,
``BadTypeMismatch`` for a wrong type and ``BadOutOfRange`` for NaN or a value out
of range. Every write is checked and applied whole, under the image's lock, so two
clients writing at once each see their write applied or refused as a unit. No ROS
here: the node hands the image what the cell reports and applies what it returns.
"""

from __future__ import annotations

import asyncio
import math
import re
import threading
import time
from collections import deque

from sorter_ros.opcua import close_server, new_server
from sorter_sim.model.description import LABEL_RE
from sorter_sim.model.io_map import (
    COIL,
    DI,
    HR,
    INPUT,
    IR,
    OUTPUT,
    WriteRefused,
    by_name,
    table_size,
)

_TABLES = (DI, COIL, IR, HR)
LABEL_QUEUE = 64  # labels the scanner keeps while the PLC has not acknowledged them


class IOImage:
    """
    The process image: inputs (cell -> PLC) and outputs (PLC -> cell) of one cell.

    Thread-safe: the node and the servers' thread meet here under one lock.
    """

    # latched every period of a one-period cycle: a read here cannot ask the node for a
    # latch (``fieldbus_process.NodeImage`` can: it is latched when a read asks)
    on_demand = False

    def __init__(self, signals, initial_outputs: dict):
        self.signals = tuple(signals)
        self.by_name = by_name(self.signals)
        self._lock = threading.Lock()
        self.raw = {t: [0] * table_size(self.signals, t) for t in _TABLES}
        # which output signal owns each coil / holding register
        self._owner = {COIL: {}, HR: {}}
        for s in self.signals:
            if s.direction == OUTPUT:
                for a in range(s.address, s.address + s.words):
                    self._owner[s.table][a] = s
        self.inputs = {s.name: _zero(s) for s in self.signals if s.direction == INPUT}
        self.outputs = {}
        for name, value in initial_outputs.items():
            self._store_output(self.by_name[name], value)
        self._pending: dict[str, object] = {}
        self._rises: set[str] = set()
        # when the cell last sampled the inputs [ns since the epoch, wall clock]: what a
        # value's OPC UA SourceTimestamp says, whatever the simulated clock reads
        self.sampled_ns = 0
        self.stats = {
            'writes': 0,
            'refused': 0,  # writes refused
            'reads_refused': 0,
            'illegal_functions': 0,
            'frames_dropped': 0,
            'overwritten': 0,
            'refreshes': 0,
        }

    # ---------------------------------------------------------------- the cell's side
    def refresh_inputs(self, values: dict) -> None:
        """
        Set input signals (engineering values) and their raw registers.

        Parameters
        ----------
        values : dict
            {signal name: engineering value}.

        """
        inputs = self.inputs
        sampled = time.time_ns()
        with self._lock:
            self.sampled_ns = sampled
            for name, value in values.items():
                if inputs[name] == value and type(inputs[name]) is type(value):
                    continue  # most inputs hold still from one period to the next
                inputs[name] = value
                self._encode(self.by_name[name], value)
            self.stats['refreshes'] += 1

    def take_outputs(self) -> tuple[dict, set]:
        """
        Return the outputs written since the last call and the bits that rose meanwhile.

        ({name: engineering value}, {names of bool outputs that went 0 -> 1}): a pulse a
        client writes within one physics period (1 then 0) still counts as a rising edge.
        """
        with self._lock:
            out, self._pending = self._pending, {}
            rises, self._rises = self._rises, set()
        return out, rises

    # ---------------------------------------------------------------- the clients' side
    def snapshot(self, table: str) -> list[int]:
        """
        Return a copy of a Modbus table's raw values.

        Parameters
        ----------
        table : str
            The Modbus table.

        Returns
        -------
        list of int
            Its raw values.

        """
        with self._lock:
            return list(self.raw[table])

    def write_raw(self, table: str, address: int, values: list[int]) -> None:
        """
        Write raw coils or holding registers; all of it is applied, or none.

        Raises WriteRefused('address') when an address holds no output (inputs are read
        only), WriteRefused('value') when a value is outside its output's range.

        Parameters
        ----------
        table : str
            ``coil`` or ``holding_register``.
        address : int
            The first address.
        values : list of int
            The raw values.

        """
        self._apply(self._checked(table, address, values))

    def write_raw_many(self, writes) -> None:
        """
        Write several raw runs (coils and holding registers at once) all or none.

        Parameters
        ----------
        writes : list of (table, address, values)
            The runs, as ``write_raw`` takes one; WriteRefused for the first bad one,
            and then nothing is applied.

        """
        changes = {}
        for table, address, values in writes:
            changes.update(self._checked(table, address, values))
        if changes:
            self._apply(changes)

    def input_values(self, names) -> tuple:
        """Return several inputs' engineering values, all of the same period."""
        with self._lock:
            return tuple(self.inputs[n] for n in names)

    def input_sample(self, names) -> tuple[tuple, int]:
        """
        Return several inputs' engineering values, of one period, and when it was sampled.

        Returns
        -------
        (tuple, int)
            The values, and the wall-clock time the cell sampled them [ns since the epoch;
            0 before the first period].

        """
        with self._lock:
            return tuple(self.inputs[n] for n in names), self.sampled_ns

    def owns(self, table: str, address: int) -> bool:
        """Return whether an output owns that coil or holding register."""
        return address in self._owner.get(table, {})

    def snapshot_tables(self, tables) -> dict[str, list[int]]:
        """Return copies of several Modbus tables' raw values, taken under one lock."""
        with self._lock:
            return {t: list(self.raw[t]) for t in tables}

    def _checked(self, table: str, address: int, values) -> dict:
        """Return {output: engineering value} of a raw run, or raise WriteRefused."""
        owners = self._owner.get(table)
        if owners is None:
            raise WriteRefused('address', f'{table} is read-only')
        changes = {}
        for i, raw in enumerate(values):
            s = owners.get(address + i)
            if s is None:
                raise WriteRefused('address', f'no output at {table} {address + i}')
            if s.words != 1:
                raise WriteRefused('address', f'{s.name} spans {s.words} registers')
            value = bool(raw) if s.type == 'bool' else s.value(int(raw))
            if not s.accepts(value):
                raise WriteRefused('value', f'{s.name} = {value} outside [{s.lo}, {s.hi}]')
            changes[s.name] = value
        return changes

    def write_value(self, name: str, value) -> None:
        """
        Write one output by name in engineering units (OPC UA); WriteRefused if not.

        Parameters
        ----------
        name : str
            The output.
        value : object
            Its engineering value.

        """
        s = self.by_name.get(name)
        if s is None or s.direction != OUTPUT:
            raise WriteRefused('address', f'{name} is not an output')
        if s.type != 'bool' and isinstance(value, float) and not math.isfinite(value):
            raise WriteRefused('value', f'{name} must be finite')
        if not s.accepts(value):
            raise WriteRefused('value', f'{name} = {value} outside [{s.lo}, {s.hi}]')
        self._apply({name: bool(value) if s.type == 'bool' else float(value)})

    def count(self, key: str = 'refused') -> None:
        """
        Count one refusal in ``stats``: 'refused' (a write), or a Modbus server's kind.

        Parameters
        ----------
        key : str
            The counter (one of the image's declared ``stats`` keys).

        """
        with self._lock:
            self.stats[key] += 1

    def _apply(self, changes: dict) -> None:
        with self._lock:
            for name, value in changes.items():
                if name in self._pending and self._pending[name] != value:
                    # a newer write before the cell took the older one: the older is lost
                    self.stats['overwritten'] += 1
                if value is True and self.outputs[name] is False:
                    self._rises.add(name)
                self._store_output(self.by_name[name], value)
                self._pending[name] = value
            self.stats['writes'] += 1

    # ---------------------------------------------------------------- encoding
    def _store_output(self, s, value) -> None:
        self.outputs[s.name] = value
        self._encode(s, value)

    def _encode(self, s, value) -> None:
        regs = self.raw[s.table]
        a = s.address
        if s.type == 'bool':
            regs[a] = 1 if value else 0
        elif s.type == 'string':
            data = value.encode('ascii', 'replace')[: 2 * s.words].ljust(2 * s.words, b'\0')
            regs[a : a + s.words] = [(data[2 * i] << 8) | data[2 * i + 1] for i in range(s.words)]
        elif s.type == 'uint32':
            raw = s.raw(value)
            regs[a], regs[a + 1] = raw >> 16, raw & 0xFFFF
        else:
            regs[a] = s.raw(value)


def _zero(s):
    return False if s.type == 'bool' else '' if s.type == 'string' else 0.0


class ScannerQueue:
    """The scanner's labels waiting for the PLC's acknowledgement (bounded; oldest first)."""

    def __init__(self):
        self.waiting: deque[str] = deque()
        self.sequence = 0
        self.dropped = 0

    def read(self, label: str) -> None:
        """
        Take a label the scanner read.

        Parameters
        ----------
        label : str
            A label the scanner read.

        """
        self.sequence = (self.sequence + 1) & 0xFFFF
        if len(self.waiting) >= LABEL_QUEUE:
            self.waiting.popleft()
            self.dropped += 1
        self.waiting.append(label)

    def ack(self) -> None:
        if self.waiting:
            self.waiting.popleft()


class Warehouse:
    """
    The warehouse link's mailbox on the cell's OPC UA server (thread-safe).

    A warehouse controller asks for routing changes (``request``: pattern and
    destination in the routing grammar; an empty destination removes a rule); the PLC
    takes them in order (``pending``, ``take`` with one result line each), reports what
    it sorted (``confirm``) and its live table (``set_table``). The same exchange as
    ``routing/updates`` and ``sort/confirmations`` on ROS, with the same grammar: the
    cell checks the form, the PLC's routing table decides (duplicates, removals).
    """

    MAX_PENDING = 1000  # requests the PLC has not taken yet
    KEEP = 200  # result and confirmation lines kept
    MAX_RULES = 1000  # rules of a routing table the PLC publishes

    def __init__(self):
        self._lock = threading.Lock()
        self._pending: deque[tuple[int, str, str]] = deque()
        self.requested = 0
        self.results: deque[str] = deque(maxlen=self.KEEP)
        self.confirmations: deque[str] = deque(maxlen=self.KEEP)
        self.confirmed = 0
        self.table: list[str] = []
        self.refused = 0  # method calls refused (bad arguments)

    def request(self, pattern, destination) -> int:
        """
        Queue a routing change; return its sequence number, or raise ValueError (why).

        Parameters
        ----------
        pattern : str
            A label pattern of the routing grammar.
        destination : str
            Where its parcels go.

        Returns
        -------
        int
            The request's sequence number.

        """
        if not isinstance(pattern, str) or not isinstance(destination, str):
            raise ValueError('pattern and destination must be strings')
        if not _is_pattern(pattern):
            raise ValueError('pattern must be a label, a label followed by * or * alone')
        if destination not in DESTINATIONS + ('',):
            raise ValueError("destination must be left, right, straight or '' (remove)")
        with self._lock:
            if len(self._pending) >= self.MAX_PENDING:
                raise ValueError(f'{self.MAX_PENDING} requests wait already')
            self.requested += 1
            self._pending.append((self.requested, pattern, destination))
            return self.requested

    def pending(self) -> list[str]:
        """Return the waiting requests, oldest first, as 'seq|pattern=destination'."""
        with self._lock:
            return [f'{n}|{p}={d}' for n, p, d in self._pending]

    def take(self, count: int, results: list[str]) -> None:
        """
        Drop the ``count`` oldest requests, keeping the PLC's result line for each.

        Raises ValueError, changing nothing, unless there is one result line per request
        taken, each 'accepted: ...' or 'refused: ...' (printable, at most LINE_MAX
        characters), and ``count`` requests wait.

        Parameters
        ----------
        count : int
            How many requests the PLC took.
        results : list of str
            Its result line for each.

        """
        if len(results) != count:
            raise ValueError(
                f'{count} requests taken need {count} result lines, got {len(results)}'
            )
        for line in results:
            _check_line(line, 'a result line')
            if not line.startswith(('accepted', 'refused')):
                raise ValueError(
                    f"a result line starts 'accepted' or 'refused', got {line[:40]!r}"
                )
        with self._lock:
            if count > len(self._pending):
                raise ValueError(f'{count} requests taken, but {len(self._pending)} wait')
            for why in results:
                n, p, d = self._pending.popleft()
                self.results.append(f'{n}|{p}={d}: {why}')

    def confirm(self, lines: list[str]) -> None:
        """
        Keep the PLC's sort confirmations; ValueError, changing nothing, on a bad line.

        Parameters
        ----------
        lines : list of str
            The PLC's sort confirmations.

        """
        for line in lines:
            _check_line(line, 'a confirmation')
            if not _CONFIRMATION_RE.fullmatch(line):
                raise ValueError(
                    "a confirmation is 'label;asked;reached;result' (label empty for no "
                    f'read, the others words), got {line[:40]!r}'
                )
        with self._lock:
            self.confirmations.extend(lines)
            self.confirmed += len(lines)

    def set_table(self, rules: list[str]) -> None:
        """
        Keep the PLC's live routing table; ValueError, changing nothing, on a bad rule.

        Parameters
        ----------
        rules : list of str
            The PLC's live routing rules.

        """
        for rule in rules:
            _check_line(rule, 'a rule')
            pattern, sep, destination = rule.partition('=')
            if not sep or destination not in DESTINATIONS or not _is_pattern(pattern):
                raise ValueError(
                    "a rule is 'pattern=destination' (a label, label* or *; left, right "
                    f'or straight), got {rule[:40]!r}'
                )
        with self._lock:
            self.table = list(rules)


DESTINATIONS = ('left', 'right', 'straight')
LINE_MAX = 256  # characters of a result, confirmation or rule line
_CONFIRMATION_RE = re.compile(r'(%s)?(;[a-z_-]{1,32}){3}' % LABEL_RE.pattern)


def _is_pattern(pattern: str) -> bool:
    """Return True for a routing pattern: a label, a label followed by *, or * alone."""
    body = pattern[:-1] if pattern.endswith('*') else pattern
    return pattern == '*' or bool(LABEL_RE.fullmatch(body))


def _check_line(line, what: str) -> None:
    if not isinstance(line, str) or not line or len(line) > LINE_MAX or not line.isprintable():
        raise ValueError(f'{what} must be printable text of 1 to {LINE_MAX} characters')


# ------------------------------------------------------------------------ the servers
class FieldbusServers:
    """
    Modbus TCP and OPC UA servers of one ``IOImage``, in a thread of their own.

    ``modbus`` / ``opcua``: (host, port) or None. ``start()`` returns once both listen
    and raises ValueError with one line when one cannot (port busy, unknown host).

    A line serves its stations' images from one pair of servers: ``stations`` lists
    (name, IOImage) in order along the belt, ``image`` is then the first one's. Over
    Modbus TCP station k (S01 is 1) is unit id k, each with the map's addresses (a
    unit id no station has is exception 0x0B, gateway target device failed to
    respond); over OPC UA each station is a folder ``<cell_name>/<name>`` with its
    ``Inputs`` and ``Outputs`` (the line's warehouse is the warehouse node's server).
    """

    def __init__(
        self,
        image: IOImage | None = None,
        *,
        modbus=None,
        opcua=None,
        s7=None,
        cell_name: str = 'cell',
        stations: list | None = None,
    ):
        if (image is None) == (stations is None):
            raise TypeError('FieldbusServers serves an image or a line\'s stations')
        self.stations = list(stations) if stations is not None else None
        self.image = image if image is not None else self.stations[0][1]
        image = self.image
        self.modbus_addr = modbus
        self.opcua_addr = opcua
        if s7 is not None and self.stations is not None:
            raise TypeError('a line\'s stations are not served over S7')
        self.s7_addr = s7
        self.s7 = None  # the S7 server (its own threads: python-snap7's)
        self.s7_port: int | None = None
        self.cell_name = cell_name or 'cell'
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run, name='fieldbus', daemon=True)
        self._ready = threading.Event()
        self._error: str | None = None
        self._modbus = None
        self._opcua = None
        self.opcua_nodes: dict[str, object] = {}
        self.warehouse = Warehouse()
        self.modbus_port: int | None = None
        self.opcua_endpoint: str | None = None
        self._pusher = None

    def start(self) -> None:
        self._thread.start()
        if not self._ready.wait(60.0):
            raise ValueError('the fieldbus servers did not start within 60 s')
        if self._error:
            self.stop()
            raise ValueError(self._error)
        if self.s7_addr is not None:
            from sorter_sim.frontends.s7_server import CellS7Server

            server = CellS7Server(self.image, *self.s7_addr)
            try:
                self.s7_port = server.serve()
            except ValueError:
                self.stop()
                raise
            self.s7 = server

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_until_complete(self._start_all())
        except Exception as exc:  # reported by start() in one line
            self._error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self._ready.set()
            return
        self._ready.set()
        self.loop.run_forever()

    async def _start_all(self) -> None:
        # the failing server is named first in the message: the node names its parameter
        if self.modbus_addr is not None:
            try:
                await self._start_modbus(*self.modbus_addr)
            except ValueError:
                raise
            except Exception as exc:
                raise ValueError(f'cannot serve Modbus TCP: {exc}') from None
        if self.opcua_addr is not None:
            try:
                await self._start_opcua(*self.opcua_addr)
            except ValueError:
                raise
            except Exception as exc:
                raise ValueError(f'cannot serve OPC UA: {exc}') from None

    def stop(self, wait_s: float = 1.0) -> None:
        """
        Stop both servers and the thread (idempotent), in at most about ``wait_s``.

        Connections are dropped, not waited for: asyncua's stop waits on every session's
        subscriptions and a Modbus client may never close its socket, and a node that is
        shutting down (ros2 launch kills it after 10 s) must not wait on its clients.

        Parameters
        ----------
        wait_s : float
            The most to wait [s, wall].

        """
        if self.s7 is not None:
            server, self.s7 = self.s7, None
            _stop_s7(server, 0.3 * wait_s)
        if self._thread.is_alive() and self.loop.is_running():
            fut = asyncio.run_coroutine_threadsafe(self._stop_all(0.6 * wait_s), self.loop)
            try:
                fut.result(0.8 * wait_s)
            except Exception:  # a server that will not stop cleanly still goes with the loop
                pass
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(0.2 * wait_s)

    async def _stop_all(self, wait_s: float) -> None:
        if self._modbus is not None:
            await self._modbus.stop()
            self._modbus = None
        if self._pusher is not None:
            self._pusher.cancel()
            self._pusher = None
        if self._opcua is not None:
            server, self._opcua = self._opcua, None
            await close_server(server, wait_s)

    # ---------------------------------------------------------------- Modbus TCP
    async def _start_modbus(self, host: str, port: int) -> None:
        from sorter_sim.frontends.modbus_server import ModbusTcpImageServer

        units = None
        if self.stations is not None:
            units = {
                k + 1: ModbusTcpImageServer(image, host, port)
                for k, (_, image) in enumerate(self.stations)
            }
        server = ModbusTcpImageServer(self.image, host, port, units=units)
        try:
            self.modbus_port = await server.start()
        except OSError as exc:
            raise ValueError(
                f'cannot serve Modbus TCP on {host}:{port}: {exc.strerror or exc}'
            ) from None
        self._modbus = server

    # ---------------------------------------------------------------- OPC UA
    async def _start_opcua(self, host: str, port: int) -> None:
        from sorter_sim.frontends.opcua_model import CellAddressSpace, answer_writes_per_item

        line = self.stations is not None
        server, endpoint = await new_server(
            host,
            port,
            'sorter_cell',
            'sorter_cell',
            f'{"line" if line else "cell"}:{self.cell_name}',
        )
        idx = await server.register_namespace('urn:sorter_cell')
        cell = await server.nodes.objects.add_folder(idx, self.cell_name)
        model = CellAddressSpace(server, idx)
        self.opcua_nodes = model.nodes
        if not line:
            await model.add_image(cell, self.image, '')
            await model.add_machine(cell, self.image, '', self.cell_name)
            await model.add_warehouse(cell, self.warehouse)
        else:
            for name, image in self.stations:
                folder = await cell.add_folder(idx, name)
                await model.add_image(folder, image, f'{name}.')
                await model.add_machine(folder, image, f'{name}.', f'{self.cell_name}/{name}')
        answer_writes_per_item(server, model.writable())
        try:
            await server.start()
        except (OSError, RuntimeError) as exc:
            raise ValueError(
                f'cannot serve OPC UA on {host}:{port}: {getattr(exc, "strerror", None) or exc}'
            ) from None
        self._opcua = server
        self.opcua_endpoint = endpoint
        self._pusher = asyncio.ensure_future(model.push_inputs())


def _stop_s7(server, wait_s: float) -> None:
    """
    Stop an S7 server without waiting on its clients.

    python-snap7's stop joins every client thread for a second each; a client that never
    sends keeps its thread in a blocking receive. Their sockets are shut down first, so
    each thread ends at once (the listening socket too), then stop has nothing to wait for.
    """
    import socket as _socket

    server.running = False
    for sock in list(getattr(server, '_sockets', ())):
        try:
            sock.shutdown(_socket.SHUT_RDWR)
        except OSError:
            pass
    listening = server.server_socket
    if listening is not None:
        try:
            listening.close()
        except OSError:
            pass
    if server.server_thread is not None:
        server.server_thread.join(wait_s)
    with server.client_lock:
        threads = list(server.clients)
    for t in threads:
        t.join(max(0.01, wait_s / max(1, len(threads))))
    server.server_socket = None
