"""
The cell's fieldbus: one I/O image, served over Modbus TCP and OPC UA.

``IOImage`` is the cell's process image, generic over the declared I/O map
(``sorter_sim.model.io_map``): the simulation node refreshes its inputs at the end of
every physics period and takes the outputs clients wrote at the start of the next
one, the way a PLC's I/O image is exchanged once per cycle. ``FieldbusServers``
serves it in one background thread (an asyncio loop): Modbus TCP
(``modbus_server``: discrete inputs, coils, input and holding registers at the map's
addresses and scaling) and OPC UA with asyncua (a folder per cell, ``Inputs`` and
``Outputs`` with typed variables in engineering units; only outputs are writable,
and only by anonymous sessions: no identity a client offers makes it an
administrator).

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
from collections import deque
from datetime import datetime, timedelta, timezone

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
from sorter_sim.model.packml import COMMAND_NUMBERS, STATE_BY_NUMBER, TRANSITIONS
from sorter_sim.model.packml import COMMANDS as PACKML_COMMANDS

_TABLES = (DI, COIL, IR, HR)
LABEL_QUEUE = 64  # labels the scanner keeps while the PLC has not acknowledged them
PUSH_S = 0.02  # s between hand-overs of changed inputs to OPC UA subscriptions
_UNSET = object()


class IOImage:
    """
    The process image: inputs (cell -> PLC) and outputs (PLC -> cell) of one cell.

    Thread-safe: the node and the servers' thread meet here under one lock.
    """

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
        with self._lock:
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


class MethodRefused(Exception):
    """A warehouse method call refused: ``status`` is the OPC UA status code to answer."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


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
        # simulated time t [s] is served as the UtcTime time_origin + t (SourceTimestamp)
        self.time_origin = datetime.now(timezone.utc) - timedelta(
            seconds=float(image.inputs.get('cell.time', 0.0) or 0.0)
        )
        self._opc_inputs: list = []
        self._outputs: set[str] = set()  # keys of opcua_nodes that are outputs
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
    async def _add_warehouse(self, cell, idx, aspace) -> None:
        """Add the ``Warehouse`` folder: routing requests, their results, confirmations."""
        from asyncua import ua

        wh = self.warehouse
        folder = await cell.add_folder(idx, 'Warehouse')
        String, UInt32 = ua.VariantType.String, ua.VariantType.UInt32
        readers = {
            'RouteRequests': (UInt32, lambda: wh.requested, 'routing changes asked so far'),
            'PendingRoutes': (String, wh.pending, "requests the PLC has not taken: 'seq|rule'"),
            'RouteResults': (String, lambda: list(wh.results), "'seq|rule: accepted/refused'"),
            'Confirmations': (
                String,
                lambda: list(wh.confirmations),
                "the PLC's sort confirmations: 'label;asked;reached;result'",
            ),
            'ConfirmationCount': (UInt32, lambda: wh.confirmed, 'confirmations so far'),
            'RoutingTable': (String, lambda: list(wh.table), "the PLC's live routing table"),
        }
        for name, (vtype, get, meaning) in readers.items():
            initial = ua.Variant(get(), vtype, is_array=vtype == String)
            var = await folder.add_variable(idx, name, initial)
            await var.write_attribute(
                ua.AttributeIds.Description, ua.DataValue(ua.LocalizedText(meaning))
            )
            aspace.set_attribute_value_callback(
                var.nodeid,
                ua.AttributeIds.Value,
                lambda nodeid, attr, get=get, vtype=vtype: ua.DataValue(
                    ua.Variant(get(), vtype, is_array=vtype == String)
                ),
            )
            self.opcua_nodes[f'Warehouse.{name}'] = var.nodeid

        Bad = ua.StatusCodes

        def method(arity, body):
            """
            Wrap a method: its argument count checked, a refusal counted and answered.

            MethodRefused carries its own status; a ValueError of the warehouse (the
            arguments' content) is BadInvalidArgument.
            """

            def call(parent, *args):
                if len(args) != arity:
                    wh.refused += 1
                    return ua.StatusCode(
                        Bad.BadArgumentsMissing if len(args) < arity else Bad.BadTooManyArguments
                    )
                try:
                    return body(*args)
                except MethodRefused as exc:
                    wh.refused += 1
                    return ua.StatusCode(exc.status)
                except ValueError:
                    wh.refused += 1
                    return ua.StatusCode(Bad.BadInvalidArgument)

            return call

        def strings(arg, what, most):
            """Return the String array an argument must be, else raise MethodRefused (why)."""
            if arg.VariantType != String or not isinstance(arg.Value, list):
                raise MethodRefused(Bad.BadTypeMismatch, f'{what} must be a String array')
            if len(arg.Value) > most:
                raise MethodRefused(Bad.BadInvalidArgument, f'{what}: at most {most} entries')
            return arg.Value

        def request_route(pattern, destination):
            if pattern.VariantType != String or destination.VariantType != String:
                raise MethodRefused(Bad.BadTypeMismatch, 'pattern and destination are Strings')
            return [ua.Variant(wh.request(pattern.Value, destination.Value), UInt32)]

        def take_routes(count, results):
            if count.VariantType != UInt32:
                raise MethodRefused(Bad.BadTypeMismatch, 'count must be a UInt32')
            wh.take(count.Value, strings(results, 'results', Warehouse.MAX_PENDING))
            return []

        def confirm(lines):
            wh.confirm(strings(lines, 'lines', Warehouse.KEEP))
            return []

        def publish_table(rules):
            wh.set_table(strings(rules, 'rules', Warehouse.MAX_RULES))
            return []

        methods = {
            'RequestRoute': (request_route, [String, String], [UInt32]),
            'TakeRoutes': (take_routes, [UInt32, String], []),
            'Confirm': (confirm, [String], []),
            'PublishRoutingTable': (publish_table, [String], []),
        }
        for name, (func, inputs, outputs) in methods.items():
            node = await folder.add_method(idx, name, method(len(inputs), func), inputs, outputs)
            self.opcua_nodes[f'Warehouse.{name}'] = node.nodeid

    async def _start_opcua(self, host: str, port: int) -> None:
        server, endpoint = await new_server(host, port, 'sorter_cell', 'sorter_cell')
        idx = await server.register_namespace('urn:sorter_cell')
        cell = await server.nodes.objects.add_folder(idx, self.cell_name)
        aspace = server.iserver.aspace
        if self.stations is None:
            await self._add_image(cell, idx, aspace, self.image, '')
            await self._add_machine(cell, idx, aspace, self.image, '', self.cell_name)
            await self._add_warehouse(cell, idx, aspace)
        else:
            for name, image in self.stations:
                folder = await cell.add_folder(idx, name)
                await self._add_image(folder, idx, aspace, image, f'{name}.')
                await self._add_machine(
                    folder, idx, aspace, image, f'{name}.', f'{self.cell_name}/{name}'
                )
        writable = {self.opcua_nodes[key] for key in self._outputs}
        _answer_writes_per_item(server, writable)
        try:
            await server.start()
        except (OSError, RuntimeError) as exc:
            raise ValueError(
                f'cannot serve OPC UA on {host}:{port}: {getattr(exc, "strerror", None) or exc}'
            ) from None
        self._opcua = server
        self.opcua_endpoint = endpoint
        self._pusher = asyncio.ensure_future(self._push_inputs(aspace))

    async def _add_machine(self, parent, idx, aspace, image: IOImage, prefix: str, serial):
        """
        Add ``Identification`` (OPC 40001-1) and ``PackML`` (OPC 30050) under ``parent``.

        Identification carries Manufacturer, Model, SerialNumber, SoftwareRevision and
        ProductInstanceUri with the names of OPC 40001-1's MachineIdentificationType (as
        plain properties in this server's namespace: the companion specification's
        nodeset is not loaded). PackML carries CurrentState (the state's name),
        StateCurrent (its PackTags number) and one method per command, named as OPC
        30050's state machine names them (Reset, Start, Stop, Hold, Unhold, Suspend,
        Unsuspend, Abort, Clear). A method the current state does not take answers
        BadInvalidState and changes nothing; one it takes is issued through the image's
        ``packml.command`` output, applied at the cell's next period as a PLC's write.
        """
        from asyncua import ua

        ident = await parent.add_object(idx, 'Identification')
        for name, value in machine_identification(serial).items():
            text = name in ('Manufacturer', 'Model')
            variant = ua.Variant(
                ua.LocalizedText(value) if text else value,
                ua.VariantType.LocalizedText if text else ua.VariantType.String,
            )
            await ident.add_property(idx, name, variant)
        packml = await parent.add_object(idx, 'PackML')

        def state():
            return STATE_BY_NUMBER.get(int(image.inputs['packml.state']), 'Undefined')

        readers = {
            'CurrentState': (
                ua.VariantType.LocalizedText,
                lambda n: ua.LocalizedText(STATE_BY_NUMBER.get(n, 'Undefined')),
                "the cell's PackML state",
            ),
            'StateCurrent': (
                ua.VariantType.Int32,
                int,
                'the state as PackTags StateCurrent numbers it (6 Execute)',
            ),
        }
        for name, (vtype, shown, meaning) in readers.items():
            number = int(image.inputs['packml.state'])
            var = await packml.add_variable(idx, name, ua.Variant(shown(number), vtype))
            await var.write_attribute(
                ua.AttributeIds.Description, ua.DataValue(ua.LocalizedText(meaning))
            )

            def read(nodeid, attr, shown=shown, vtype=vtype):
                number, t = image.input_values(('packml.state', 'cell.time'))  # one period
                return ua.DataValue(
                    ua.Variant(shown(int(number)), vtype),
                    SourceTimestamp=self.time_origin + timedelta(seconds=float(t)),
                    ServerTimestamp=datetime.now(timezone.utc),
                )

            aspace.set_attribute_value_callback(var.nodeid, ua.AttributeIds.Value, read)
            self._opc_inputs.append((var.nodeid, read))
            self.opcua_nodes[f'{prefix}PackML.{name}'] = var.nodeid

        def command(name):
            def call(parent_node, *args):
                if args:
                    image.count()
                    return ua.StatusCode(ua.StatusCodes.BadTooManyArguments)
                if state() not in TRANSITIONS[name]:
                    image.count()
                    return ua.StatusCode(ua.StatusCodes.BadInvalidState)
                image.write_value('packml.command', COMMAND_NUMBERS[name])
                return []

            return call

        for name in PACKML_COMMANDS:
            node = await packml.add_method(idx, name.capitalize(), command(name), [], [])
            self.opcua_nodes[f'{prefix}PackML.{name.capitalize()}'] = node.nodeid

    async def _add_image(self, parent, idx, aspace, image: IOImage, prefix: str) -> None:
        """Add an image's ``Inputs`` and ``Outputs`` under ``parent`` (node ids: prefix + name)."""
        from asyncua import ua

        folders = {
            INPUT: await parent.add_folder(idx, 'Inputs'),
            OUTPUT: await parent.add_folder(idx, 'Outputs'),
        }
        for s in image.signals:
            vtype = getattr(ua.VariantType, s.opcua_type)
            initial = image.inputs[s.name] if s.direction == INPUT else image.outputs[s.name]
            var = await folders[s.direction].add_variable(
                idx, s.name, ua.Variant(_opc_value(s, initial), vtype)
            )
            await var.write_attribute(
                ua.AttributeIds.Description, ua.DataValue(ua.LocalizedText(s.meaning))
            )
            if s.unit:
                await var.add_property(idx, 'EngineeringUnits', _eu_information(s.unit))
            if s.direction == INPUT:
                reader = _input_reader(image, s, vtype, self.time_origin)
                aspace.set_attribute_value_callback(var.nodeid, ua.AttributeIds.Value, reader)
                self._opc_inputs.append((var.nodeid, reader))
            else:
                if s.lo is not None:
                    await var.add_property(idx, 'EURange', ua.Range(Low=s.lo, High=s.hi))
                await var.set_writable()
                aspace.set_attribute_value_setter(
                    var.nodeid, ua.AttributeIds.Value, _output_writer(image, s)
                )
                self._outputs.add(prefix + s.name)
            self.opcua_nodes[prefix + s.name] = var.nodeid

    async def _push_inputs(self, aspace) -> None:
        """
        Hand every input that changed to the OPC UA subscriptions, every PUSH_S.

        A read is answered from the image at once (a value callback), which asyncua's
        subscriptions never see change: here each input a client monitors is written
        through the address space when its value changed, so that its MonitoredItems
        report it at their sampling interval (OPC UA Part 4, 5.12), stamped as a read is.
        """
        from asyncua import ua

        value_attr = ua.AttributeIds.Value
        # the value holders (asyncua keeps no public accessor for them)
        holders = [
            (nodeid, read, aspace._nodes[nodeid].attributes[value_attr])
            for nodeid, read in self._opc_inputs
        ]
        last: dict = {}
        while True:
            await asyncio.sleep(PUSH_S)
            for nodeid, read, attval in holders:
                if not attval.datachange_callbacks:
                    continue
                dv = read(nodeid, value_attr)
                value = dv.Value.Value
                if last.get(nodeid, _UNSET) == value:
                    continue
                last[nodeid] = value
                try:
                    await aspace.write_attribute_value(nodeid, value_attr, dv)
                finally:
                    # the write replaces the callback with a stored value: reads stay live
                    attval.value_callback = read


def _answer_writes_per_item(server, writable: set) -> None:
    """
    Make the server answer a WriteRequest item by item, as OPC UA Part 4 (5.10.4) says.

    A value the image refuses raises inside asyncua's value setter, which would fail
    the whole request with a ServiceFault after the items before it were applied; here
    each item gets its own status code (BadOutOfRange, BadTypeMismatch, ...). A client's
    write to anything but an output's Value is BadUserAccessDenied, whatever its role.
    """
    from asyncua import ua
    from asyncua.crypto.permission_rules import UserRole

    service = server.iserver.attribute_service
    write_one = service.write

    async def write(params, user=None):
        if user is None or user.role == UserRole.Admin:  # the server's own session
            return await write_one(params) if user is None else await write_one(params, user)
        results = []
        for item in params.NodesToWrite:
            if item.AttributeId != ua.AttributeIds.Value or item.NodeId not in writable:
                results.append(ua.StatusCode(ua.StatusCodes.BadUserAccessDenied))
                continue
            try:
                (code,) = await write_one(ua.WriteParameters(NodesToWrite=[item]), user)
            except ua.UaStatusCodeError as exc:
                code = ua.StatusCode(exc.code)
            except Exception:  # a malformed value asyncua's setter cannot take
                code = ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
            results.append(code)
        return results

    service.write = write


def _opc_value(s, value):
    if s.type == 'bool':
        return bool(value)
    if s.type == 'string':
        return str(value)
    if s.opcua_type == 'Double':
        return float(value)
    return int(round(value)) & (0xFFFFFFFF if s.type == 'uint32' else 0xFFFF)


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


def machine_identification(serial: str) -> dict:
    """Return the OPC 40001-1 identification of a cell named ``serial``."""
    try:
        from importlib.metadata import version

        revision = version('sorter_cell')
    except Exception:  # not installed as a distribution (a source tree on sys.path)
        revision = 'unknown'
    return {
        'Manufacturer': 'sorter_cell',
        'Model': 'torsional-disk pivot diverter cell (emulated)',
        'SerialNumber': serial,
        'SoftwareRevision': revision,
        'ProductInstanceUri': f'urn:sorter_cell:{serial}',
    }


def _input_reader(image: IOImage, s, vtype, origin: datetime):
    from asyncua import ua

    def read(nodeid, attr):
        # SourceTimestamp: when the cell produced the value, on the simulated clock mapped
        # to UtcTime (origin + simulated time); ServerTimestamp: when the server read it
        value, t = image.input_values((s.name, 'cell.time'))  # of one period
        return ua.DataValue(
            ua.Variant(_opc_value(s, value), vtype),
            SourceTimestamp=origin + timedelta(seconds=float(t)),
            ServerTimestamp=datetime.now(timezone.utc),
        )

    return read


# UNECE Recommendation 20 common codes of the map's units (OPC UA Part 8, 5.6.3)
UNECE = {
    'm': ('MTR', 'metre'),
    's': ('SEC', 'second [unit of time]'),
    'deg': ('DD', 'degree [unit of angle]'),
    'm/s': ('MTS', 'metre per second'),
    'deg/s': ('E96', 'degree per second'),
}
CEFACT_URI = 'http://www.opcfoundation.org/UA/units/un/cefact'


def _eu_information(unit: str):
    """Return the EUInformation of a unit: its UNECE code as UnitId, in the CEFACT namespace."""
    from asyncua import ua

    code, description = UNECE[unit]
    unit_id = 0
    for c in code:
        unit_id = (unit_id << 8) | ord(c)
    return ua.EUInformation(
        NamespaceUri=CEFACT_URI,
        UnitId=unit_id,
        DisplayName=ua.LocalizedText(unit),
        Description=ua.LocalizedText(description),
    )


def _output_writer(image: IOImage, s):
    from asyncua import ua

    def write(node, attr, value):
        v = value.Value.Value if value.Value is not None else None
        try:
            image.write_value(s.name, v)
        except WriteRefused as exc:
            image.count()
            raise ua.UaStatusCodeError(
                ua.StatusCodes.BadOutOfRange
                if exc.code == 'value'
                else ua.StatusCodes.BadNotWritable
            ) from None
        node.attributes[attr].value = value

    return write
