"""
The sorter's PLC program as a soft PLC on the fieldbus: what a real PLC would do.

The same ``SorterLogic`` the controller node runs, scanning the cell's I/O image
over Modbus TCP (``ModbusIO``, pymodbus client), OPC UA (``OpcUaIO``, asyncua
client) or S7 (``S7IO``, python-snap7's client) instead of ROS topics and
services: each scan reads every input at once (sensor bits, the latched edge
times, the scanner's label with its ready/ack handshake, the diverter's
feedback, the status bits and PackML state, the cell's clock), runs the logic,
and writes the outputs (pop-up coil, α setpoint, e-stop and reset pulses, PackML
commands, the heartbeat the cell's watchdog expects). Only the declared I/O map
(``sorter_sim.model.io_map``, part of the cell description) is shared with the cell.

A write the server refuses (a Modbus exception, an OPC UA bad status, an S7 return code) comes back
to the logic as a refused command, as a refused service call does in the node.
"""

from __future__ import annotations

import math
import time

from sorter_sim.model.io_map import (
    COIL,
    DI,
    INPUT,
    IR,
    OUTPUT,
    S7_INPUT_DB,
    Signal,
    decode,
    io_map,
    s7_size,
)
from sorter_sim.model.packml import COMMAND_NUMBERS as PACKML_COMMAND_NUMBERS
from sorter_sim.model.packml import STATE_BY_NUMBER as PACKML_STATE_BY_NUMBER

from sorter_control.logic import SorterLogic
from sorter_control.logic.config import ControllerConfig
from sorter_control.logic.image import DiverterState, Edge, InputImage, Reply
from sorter_control.logic.routing import RoutingError


class FieldbusError(Exception):
    """A fieldbus read or write failed (connection lost, refused by the server)."""


class ModbusIO:
    """The I/O image over Modbus TCP: one request per input table, one per output write."""

    warehouse = False  # the warehouse link is on the OPC UA server only

    def __init__(self, host: str, port: int, sensor_names, timeout: float = 2.0):
        import logging

        from pymodbus.client import ModbusTcpClient

        logging.getLogger('pymodbus').setLevel(logging.CRITICAL)  # failures are raised here
        self.signals = io_map(sensor_names)
        self.client = ModbusTcpClient(host, port=port, timeout=timeout, retries=0)
        if not self.client.connect():
            raise FieldbusError(f'cannot connect to Modbus TCP {host}:{port}')
        self._inputs = [s for s in self.signals if s.direction == INPUT]
        self._spans = {
            t: (
                min(s.address for s in self._inputs if s.table == t),
                max(s.address + s.words for s in self._inputs if s.table == t),
            )
            for t in (DI, IR)
        }
        self.requests = 0

    def read_inputs(self) -> dict:
        lo, hi = self._spans[DI]
        r = self.client.read_discrete_inputs(lo, count=hi - lo)
        self.requests += 1
        if r.isError():
            raise FieldbusError(f'reading discrete inputs: {r}')
        bits = r.bits
        lo_r, hi_r = self._spans[IR]
        regs = []
        # at most 125 registers a request (the protocol's limit)
        for a in range(lo_r, hi_r, 125):
            rr = self.client.read_input_registers(a, count=min(125, hi_r - a))
            self.requests += 1
            if rr.isError():
                raise FieldbusError(f'reading input registers: {rr}')
            regs += rr.registers
        values = {}
        for s in self._inputs:
            if s.table == DI:
                values[s.name] = bool(bits[s.address - lo])
            else:
                values[s.name] = decode(s, regs[s.address - lo_r : s.address - lo_r + s.words])
        return values

    def write(self, s: Signal, value) -> str | None:
        """
        Write one output; return None, or why the server refused it.

        Parameters
        ----------
        s : Signal
            An output signal.
        value : object
            Its engineering value.

        Returns
        -------
        str or None
            None, or why the server refused it.

        """
        if s.table == COIL:
            r = self.client.write_coil(s.address, bool(value))
        else:
            r = self.client.write_register(s.address, s.raw(value))
        self.requests += 1
        if r.isError():
            return f'Modbus exception {getattr(r, "exception_code", "?")} writing {s.name}'
        return None

    def close(self) -> None:
        self.client.close()


class OpcUaIO:
    """The I/O image over OPC UA: one Read of every input a scan, one Write per output."""

    def __init__(self, endpoint: str, cell_name: str, sensor_names, timeout: float = 4.0):
        from asyncua import ua
        from asyncua.sync import Client

        self.ua = ua
        self.signals = io_map(sensor_names)
        self.client = Client(endpoint, timeout=timeout)
        try:
            self.client.connect()
        except Exception as exc:
            raise FieldbusError(f'cannot connect to OPC UA {endpoint}: {exc}') from None
        idx = self.client.get_namespace_index('urn:sorter_cell')
        cell = self.client.nodes.objects.get_child([f'{idx}:{cell_name}'])
        self._inputs = [s for s in self.signals if s.direction == INPUT]
        folder = {
            INPUT: cell.get_child([f'{idx}:Inputs']),
            OUTPUT: cell.get_child([f'{idx}:Outputs']),
        }
        self.nodes = {
            s.name: folder[s.direction].get_child([f'{idx}:{s.name}']) for s in self.signals
        }
        self._wh_folder = cell.get_child([f'{idx}:Warehouse'])
        self._wh = {
            name: self._wh_folder.get_child([f'{idx}:{name}'])
            for name in (
                'RouteRequests',
                'PendingRoutes',
                'TakeRoutes',
                'Confirm',
                'PublishRoutingTable',
            )
        }
        # the warehouse's request counter is read with the inputs, in the same request
        self._input_nodes = [self.nodes[s.name] for s in self._inputs] + [
            self._wh['RouteRequests']
        ]
        self.requests = 0

    warehouse = True

    def read_inputs(self) -> dict:
        values = self.client.read_values(self._input_nodes)
        self.requests += 1
        out = {s.name: v for s, v in zip(self._inputs, values)}
        out['warehouse.requests'] = values[-1]
        return out

    def pending_routes(self) -> list[tuple[str, str]]:
        """Return the routing changes the warehouse asked for and the PLC has not taken."""
        lines = self._wh['PendingRoutes'].read_value() or []
        self.requests += 1
        out = []
        for line in lines:
            rule = line.split('|', 1)[1]
            pattern, _, destination = rule.partition('=')
            out.append((pattern, destination))
        return out

    def take_routes(self, results: list[str]) -> None:
        """
        Report the PLC's results for the routing requests it took.

        Parameters
        ----------
        results : list of str
            The PLC's result line for each request taken.

        """
        ua = self.ua
        self._wh_folder.call_method(
            self._wh['TakeRoutes'],
            ua.Variant(len(results), ua.VariantType.UInt32),
            ua.Variant(results, ua.VariantType.String, is_array=True),
        )
        self.requests += 1

    def confirm(self, lines: list[str]) -> None:
        """
        Send sort confirmations.

        Parameters
        ----------
        lines : list of str
            Sort confirmations.

        """
        ua = self.ua
        self._wh_folder.call_method(
            self._wh['Confirm'], ua.Variant(lines, ua.VariantType.String, is_array=True)
        )
        self.requests += 1

    def publish_table(self, rules: list[str]) -> None:
        """
        Publish the live routing table.

        Parameters
        ----------
        rules : list of str
            Routing rules.

        """
        ua = self.ua
        self._wh_folder.call_method(
            self._wh['PublishRoutingTable'],
            ua.Variant(rules, ua.VariantType.String, is_array=True),
        )
        self.requests += 1

    def write(self, s: Signal, value) -> str | None:
        """
        Write one output; return None, or why the server refused it.

        Parameters
        ----------
        s : Signal
            An output signal.
        value : object
            Its engineering value.

        Returns
        -------
        str or None
            None, or why the server refused it.

        """
        try:
            self.nodes[s.name].write_value(self._variant(s, value))
        except Exception as exc:  # asyncua raises the server's bad status code
            return f'OPC UA {type(exc).__name__} writing {s.name}'
        finally:
            self.requests += 1
        return None

    def write_many(self, writes: list) -> list:
        """
        Write several outputs in one Write request; return each one's error or None.

        The server applies them in order, as one write each would be, and answers each
        with its own status: the scan's outputs cost one round trip, not one each.

        Parameters
        ----------
        writes : list of (Signal, object)
            The outputs and their engineering values, in order.

        Returns
        -------
        list of (str or None)
            For each write: None, or why the server refused it.

        """
        if len(writes) == 1:
            return [self.write(*writes[0])]
        try:
            results = self.client.write_values(
                [self.nodes[s.name] for s, _ in writes],
                [self._variant(s, value) for s, value in writes],
                raise_on_partial_error=False,
            )
        except Exception as exc:  # the request itself failed: every write in it did
            return [f'OPC UA {type(exc).__name__} writing {s.name}' for s, _ in writes]
        finally:
            self.requests += 1
        return [
            None if r.is_good() else f'OPC UA {r.name} writing {s.name}'
            for (s, _), r in zip(writes, results)
        ]

    def _variant(self, s: Signal, value):
        ua = self.ua
        if s.type == 'bool':
            return ua.Variant(bool(value), ua.VariantType.Boolean)
        if s.opcua_type == 'Double':
            return ua.Variant(float(value), ua.VariantType.Double)
        return ua.Variant(int(value), getattr(ua.VariantType, s.opcua_type))

    def close(self) -> None:
        self.client.disconnect()


class S7IO:
    """The I/O image over S7 with python-snap7's client: one GET of DB1, a PUT per write."""

    warehouse = False  # the warehouse link is on the OPC UA server only

    def __init__(self, host: str, port: int, sensor_names):
        import logging

        import snap7

        logging.getLogger('snap7').setLevel(logging.CRITICAL)  # failures are raised here
        self.signals = io_map(sensor_names)
        self.client = snap7.client.Client()
        try:
            self.client.connect(host, 0, 1, port)
        except Exception as exc:
            raise FieldbusError(f'cannot connect to S7 {host}:{port}: {exc}') from None
        self._inputs = [s for s in self.signals if s.direction == INPUT]
        self._size = s7_size(self.signals, S7_INPUT_DB)
        self.requests = 0

    def read_inputs(self) -> dict:
        try:
            data = self.client.db_read(S7_INPUT_DB, 0, self._size)
        except Exception as exc:
            raise FieldbusError(f'reading DB{S7_INPUT_DB}: {exc}') from None
        self.requests += 1
        values = {}
        for s in self._inputs:
            _, byte, bit, _ = s.s7
            if s.type == 'bool':
                values[s.name] = bool((data[byte] >> bit) & 1)
            else:
                words = data[byte : byte + 2 * s.words]
                regs = [int.from_bytes(words[i : i + 2], 'big') for i in range(0, len(words), 2)]
                values[s.name] = decode(s, regs)
        return values

    def write(self, s: Signal, value) -> str | None:
        """
        Write one output; return None, or why the server refused it.

        Parameters
        ----------
        s : Signal
            An output signal.
        value : object
            Its engineering value.

        Returns
        -------
        str or None
            None, or why the server refused it.

        """
        from snap7.type import Area, WordLen

        db, byte, bit, _ = s.s7
        try:
            if s.type == 'bool':
                self.client.write_area(
                    Area.DB, db, 8 * byte + bit, bytearray([1 if value else 0]), WordLen.Bit
                )
            else:
                self.client.db_write(db, byte, bytearray(s.raw(value).to_bytes(2, 'big')))
        except Exception as exc:
            return f'S7 refused {s.name}: {exc}'
        finally:
            self.requests += 1
        return None

    def close(self) -> None:
        try:
            self.client.disconnect()
        except Exception:  # already gone with the server
            pass


class SoftPLC:
    """
    ``SorterLogic`` scanning a fieldbus I/O image.

    ``scan()`` is one PLC cycle: read the inputs, run the program, write the outputs.
    Confirmations and log lines of each scan are kept (``confirmations``, ``log``).
    """

    def __init__(self, config: ControllerConfig, io):
        self.config = config
        self.io = io
        self.logic = SorterLogic(config)
        self.out = {s.name: s for s in io.signals if s.direction == OUTPUT}
        self._edge_times: dict[str, float] = {}
        self._replies: list[Reply] = []
        self._pulses: list[str] = []  # pulse outputs (ack, e-stop, reset) back to 0 next scan
        self._beat = 0
        self.confirmations = []
        self.log: list[tuple[str, str]] = []
        self.scans = 0
        self.write_errors = 0
        self._routes_seen = 0  # the warehouse's request counter at the last look
        self._table: list[str] | None = None

    def scan(self) -> float:
        """Run one scan; return the cell time it read [s]."""
        wall0 = time.perf_counter()
        for name in self._pulses:
            self._write(name, False)
        self._pulses = []
        x = self.io.read_inputs()
        t = float(x['cell.time'])
        bits, edges = {}, []
        for s in self.io.signals:
            if s.table == DI and s.name.startswith('sensor.'):
                sensor = s.name[len('sensor.') :]
                bits[sensor] = bool(x[s.name])
                for edge, rising in (('rise', True), ('fall', False)):
                    key = f'{s.name}.{edge}_time'
                    te = float(x[key])
                    if te > 0.0 and te != self._edge_times.get(key):
                        self._edge_times[key] = te
                        edges.append(Edge(sensor, te, rising))
        edges.sort(key=lambda e: e.t)
        labels = []
        if x['scanner.ready']:
            labels.append((t, x['scanner.label']))
            self._write('scanner.ack', True)
            self._pulses.append('scanner.ack')
        image = InputImage(
            t=t,
            bits=bits,
            edges=edges,
            labels=labels,
            diverter=DiverterState(
                alpha=math.radians(x['diverter.alpha']), stroke=x['diverter.stroke']
            ),
            replies=self._replies,
            cell_estop=bool(x['status.estop']),
            cell_jam=bool(x['status.jam']),
            cell_watchdog=bool(x['status.watchdog']),
            cell_status_t=t,
            cell_packml=PACKML_STATE_BY_NUMBER.get(int(x['packml.state'])),
        )
        self._replies = []
        if self.io.warehouse and x['warehouse.requests'] != self._routes_seen:
            self._take_routes(x['warehouse.requests'])
        out = self.logic.scan(image)
        self._beat = (self._beat + 1) & 0xFFFF
        # the scan's outputs go out together at its end, as a PLC's output image does
        writes = [('plc.heartbeat', self._beat)]
        commands = [(cmd, self._command_output(cmd)) for cmd in out.commands]
        writes += [w for _, w in commands if w is not None]
        errors = iter(self._write_all(writes))
        next(errors)  # the heartbeat's: counted in write_errors
        for cmd, w in commands:
            err = next(errors) if w is not None else f'no output for {cmd.kind}'
            self._replies.append(Reply(cmd.id, err is None, err or 'written'))
        self.confirmations += out.confirmations
        self.log += out.log
        if self.io.warehouse:
            self._report(out.confirmations)
        self.scans += 1
        self.logic.record_scan_wall(time.perf_counter() - wall0)
        return t

    def _take_routes(self, seen: int) -> None:
        """Apply the warehouse's routing changes in order, as the ROS topic's updates are."""
        results = []
        for pattern, destination in self.io.pending_routes():
            try:
                done = self.logic.update_route(pattern, destination)
            except (RoutingError, ValueError) as exc:
                self.logic.counts['routing_rejected'] += 1
                results.append(f'refused: {exc}')
            else:
                results.append(f'accepted: {done}')
        self.io.take_routes(results)
        self._routes_seen = seen

    def _report(self, confirmations) -> None:
        if confirmations:
            self.io.confirm(
                [
                    f'{c.label};{c.destination_asked};{c.destination_reached};{c.result}'
                    for c in confirmations
                ]
            )
        table = self.logic.routing.rules()
        if table != self._table:
            self.io.publish_table(table)
            self._table = table

    def _command_output(self, cmd) -> tuple[str, object] | None:
        """Return the output (name, value) a command writes, or None for none."""
        if cmd.kind == 'popup':
            return 'diverter.popup', bool(cmd.value)
        if cmd.kind == 'alpha':
            return 'diverter.alpha_setpoint', float(cmd.value)
        if cmd.kind == 'packml':
            return 'packml.command', PACKML_COMMAND_NUMBERS[cmd.value]
        if cmd.kind in ('estop', 'reset'):
            name = 'cell.estop' if cmd.kind == 'estop' else 'cell.reset'
            self._pulses.append(name)
            return name, True
        return None

    def _write(self, name: str, value) -> str | None:
        return self._write_all([(name, value)])[0]

    def _write_all(self, writes: list[tuple[str, object]]) -> list:
        """Write outputs in order (one request where the fieldbus allows); return errors."""
        signals = [(self.out[name], value) for name, value in writes]
        many = getattr(self.io, 'write_many', None)
        errors = many(signals) if many is not None else [self.io.write(*w) for w in signals]
        self.write_errors += sum(e is not None for e in errors)
        return errors
