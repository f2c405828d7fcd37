"""
The cell's OPC UA address space, typed as OPC UA Part 3 and Part 8 lay it out.

``CellAddressSpace`` adds, under a cell's folder (or a line station's): ``Inputs`` and
``Outputs`` with one variable per signal of the I/O map, ``Identification`` (OPC
40001-1's names), ``PackML`` (OPC 30050's state and commands) and, for a single cell,
``Warehouse`` (the routing mailbox). What a generic client looks for is where the
specifications put it: a value in engineering units is an ``AnalogItemType`` variable
with the standard properties ``0:EURange`` (Range: the range in normal operation),
on an input ``0:InstrumentRange`` (what its register can carry) and
``0:EngineeringUnits`` (EUInformation with the UNECE common code, Part 8, 5.6.3);
every method argument has a name and a description; an array is declared
one-dimensional (ValueRank 1), the methods' ``InputArguments`` and
``OutputArguments`` too (``sorter_ros.opcua.add_method``).

A value read is the image's, stamped with the wall-clock time the cell sampled it
(SourceTimestamp, the end of the physics period that produced it) and the time the
server read it (ServerTimestamp); the cell's simulated time is the variable
``cell.time``. Inputs a client monitors are handed to its subscriptions when they
change (``push_inputs``), and a WriteRequest is answered item by item
(``answer_writes_per_item``).
"""

from __future__ import annotations

import asyncio
from datetime import datetime, timezone

from sorter_ros.opcua import add_method, add_variable, argument, build_identity
from sorter_sim.model.io_map import INPUT, OUTPUT, WriteRefused
from sorter_sim.model.packml import COMMAND_NUMBERS, STATE_BY_NUMBER, TRANSITIONS
from sorter_sim.model.packml import COMMANDS as PACKML_COMMANDS

PUSH_S = 0.02  # s between hand-overs of changed inputs to OPC UA subscriptions
_UNSET = object()
# the raw range of each register type: what an input's encoding can carry (InstrumentRange)
_RAW_RANGE = {'int16': (-32768, 32767), 'uint16': (0, 65535), 'uint32': (0, 2**32 - 1)}
# UNECE Recommendation 20 common codes of the map's units (OPC UA Part 8, 5.6.3)
UNECE = {
    'm': ('MTR', 'metre'),
    's': ('SEC', 'second [unit of time]'),
    'deg': ('DD', 'degree [unit of angle]'),
    'm/s': ('MTS', 'metre per second'),
    'deg/s': ('E96', 'degree per second'),
}
CEFACT_URI = 'http://www.opcfoundation.org/UA/units/un/cefact'


class MethodRefused(Exception):
    """A warehouse method call refused: ``status`` is the OPC UA status code to answer."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


class CellAddressSpace:
    """
    The nodes of one server's cells (see the module), and the bookkeeping they need.

    ``nodes`` maps a key (``prefix + signal``, ``PackML.Start``, ``Warehouse.Confirm``)
    to its node id; ``outputs`` holds the keys clients may write.
    """

    def __init__(self, server, idx: int):
        self.server = server
        self.idx = idx
        self.aspace = server.iserver.aspace
        self.nodes: dict[str, object] = {}
        self.outputs: set[str] = set()
        self._readers: list = []  # (node id, value callback) of what subscriptions watch

    def writable(self) -> set:
        """Return the node ids of the outputs' variables."""
        return {self.nodes[key] for key in self.outputs}

    # ---------------------------------------------------------------- the I/O image
    async def add_image(self, parent, image, prefix: str) -> None:
        """Add an image's ``Inputs`` and ``Outputs`` under ``parent`` (keys: prefix + name)."""
        from asyncua import ua

        idx, aspace = self.idx, self.aspace
        folders = {
            INPUT: await parent.add_folder(idx, 'Inputs'),
            OUTPUT: await parent.add_folder(idx, 'Outputs'),
        }
        for s in image.signals:
            vtype = getattr(ua.VariantType, s.opcua_type)
            initial = image.inputs[s.name] if s.direction == INPUT else image.outputs[s.name]
            analog = _is_analog(s)
            var = await add_variable(
                folders[s.direction],
                idx,
                s.name,
                ua.Variant(opc_value(s, initial), vtype),
                s.meaning,
                ua.ObjectIds.AnalogItemType if analog else None,
            )
            if analog:
                await _add_analog_properties(var, idx, s)
            if s.direction == INPUT:
                reader = _input_reader(image, s, vtype)
                aspace.set_attribute_value_callback(var.nodeid, ua.AttributeIds.Value, reader)
                self._readers.append((var.nodeid, reader))
            else:
                await var.set_writable()
                aspace.set_attribute_value_setter(
                    var.nodeid, ua.AttributeIds.Value, _output_writer(image, s)
                )
                self.outputs.add(prefix + s.name)
            self.nodes[prefix + s.name] = var.nodeid

    # ---------------------------------------------------------------- the machine
    async def add_machine(self, parent, image, prefix: str, serial: str) -> None:
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

        idx = self.idx
        ident = await parent.add_object(idx, 'Identification')
        for name, value in machine_identification(serial).items():
            text = name in ('Manufacturer', 'Model')
            variant = ua.Variant(
                ua.LocalizedText(value) if text else value,
                ua.VariantType.LocalizedText if text else ua.VariantType.String,
            )
            await ident.add_property(idx, name, variant)
        packml = await parent.add_object(idx, 'PackML')
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
            var = await add_variable(packml, idx, name, ua.Variant(shown(number), vtype), meaning)

            def read(nodeid, attr, shown=shown, vtype=vtype):
                (number,), sampled = image.input_sample(('packml.state',))
                return _stamped(ua.Variant(shown(int(number)), vtype), sampled)

            self.aspace.set_attribute_value_callback(var.nodeid, ua.AttributeIds.Value, read)
            self._readers.append((var.nodeid, read))
            self.nodes[f'{prefix}PackML.{name}'] = var.nodeid

        def state():
            return STATE_BY_NUMBER.get(int(image.inputs['packml.state']), 'Undefined')

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
            node = await add_method(packml, idx, name.capitalize(), command(name), [], [])
            self.nodes[f'{prefix}PackML.{name.capitalize()}'] = node.nodeid

    # ---------------------------------------------------------------- the warehouse
    async def add_warehouse(self, parent, wh) -> None:
        """
        Add the ``Warehouse`` folder of mailbox ``wh``: requests, results, confirmations.

        Variables (read-only) show the mailbox; methods (named, described arguments)
        fill it. A call with bad arguments changes nothing and is counted in
        ``wh.refused``: a wrong count BadArgumentsMissing / BadTooManyArguments, a
        wrong type BadTypeMismatch, content the routing grammar refuses
        BadInvalidArgument.
        """
        from asyncua import ua

        idx = self.idx
        folder = await parent.add_folder(idx, 'Warehouse')
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
            var = await add_variable(folder, idx, name, initial, meaning)
            self.aspace.set_attribute_value_callback(
                var.nodeid,
                ua.AttributeIds.Value,
                lambda nodeid, attr, get=get, vtype=vtype: ua.DataValue(
                    ua.Variant(get(), vtype, is_array=vtype == String),
                    ServerTimestamp=datetime.now(timezone.utc),
                ),
            )
            self.nodes[f'Warehouse.{name}'] = var.nodeid
        for name, (func, inputs, outputs) in _warehouse_methods(wh).items():
            node = await add_method(
                folder, idx, name, _method(wh, len(inputs), func), inputs, outputs
            )
            self.nodes[f'Warehouse.{name}'] = node.nodeid

    # ---------------------------------------------------------------- subscriptions
    async def push_inputs(self) -> None:
        """
        Hand every input that changed to the OPC UA subscriptions, every PUSH_S.

        A read is answered from the image at once (a value callback), which asyncua's
        subscriptions never see change: here each input a client monitors is written
        through the address space when its value changed, so that its MonitoredItems
        report it at their sampling interval (OPC UA Part 4, 5.12), stamped as a read is.
        """
        from asyncua import ua

        aspace = self.aspace
        value_attr = ua.AttributeIds.Value
        # the value holders (asyncua keeps no public accessor for them)
        holders = [
            (nodeid, read, aspace._nodes[nodeid].attributes[value_attr])
            for nodeid, read in self._readers
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


def _warehouse_methods(wh) -> dict:
    """Return the warehouse's methods: {name: (body, input arguments, output arguments)}."""
    from asyncua import ua

    Bad = ua.StatusCodes
    String, UInt32 = ua.VariantType.String, ua.VariantType.UInt32

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
        wh.take(count.Value, strings(results, 'results', wh.MAX_PENDING))
        return []

    def confirm(lines):
        wh.confirm(strings(lines, 'lines', wh.KEEP))
        return []

    def publish_table(rules):
        wh.set_table(strings(rules, 'rules', wh.MAX_RULES))
        return []

    pattern = argument('pattern', String, 'a label, a label followed by *, or * alone')
    destination = argument(
        'destination', String, "left, right or straight; '' removes the pattern's rule"
    )
    return {
        'RequestRoute': (
            request_route,
            [pattern, destination],
            [argument('sequence', UInt32, "the request's number, as PendingRoutes shows it")],
        ),
        'TakeRoutes': (
            take_routes,
            [
                argument('count', UInt32, 'how many of the oldest pending requests the PLC took'),
                argument(
                    'results',
                    String,
                    "one line per request taken: 'accepted: ...' or 'refused: ...'",
                    array=True,
                ),
            ],
            [],
        ),
        'Confirm': (
            confirm,
            [argument('lines', String, "sort confirmations 'label;asked;reached;result'", True)],
            [],
        ),
        'PublishRoutingTable': (
            publish_table,
            [argument('rules', String, "the live routing table, 'pattern=destination'", True)],
            [],
        ),
    }


def _method(wh, arity: int, body):
    """
    Wrap a warehouse method: its argument count checked, a refusal counted and answered.

    MethodRefused carries its own status; a ValueError of the warehouse (the
    arguments' content) is BadInvalidArgument.
    """
    from asyncua import ua

    Bad = ua.StatusCodes

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


def answer_writes_per_item(server, writable: set) -> None:
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


def opc_value(s, value):
    """Return a signal's engineering value as its OPC UA variable holds it."""
    if s.type == 'bool':
        return bool(value)
    if s.type == 'string':
        return str(value)
    if s.opcua_type == 'Double':
        return float(value)
    return int(round(value)) & (0xFFFFFFFF if s.type == 'uint32' else 0xFFFF)


def machine_identification(serial: str) -> dict:
    """Return the OPC 40001-1 identification of a cell named ``serial``."""
    return {
        'Manufacturer': 'sorter_cell',
        'Model': 'torsional-disk pivot diverter cell (emulated)',
        'SerialNumber': serial,
        'SoftwareRevision': build_identity()[0],
        'ProductInstanceUri': f'urn:sorter_cell:{serial}',
    }


def _is_analog(s) -> bool:
    """Return whether a signal is analog: in engineering units (scaled, or with a unit)."""
    return s.type not in ('bool', 'string') and (s.scale != 1.0 or bool(s.unit))


def eu_range(s) -> tuple[float, float]:
    """
    Return a signal's EURange: its range in normal operation (OPC UA Part 8, 5.3.2).

    What an output accepts; for an input, its range in normal operation where the map
    gives one (α within ±90 deg, the stroke 0 .. 1), else what its register carries
    (a counter or a time covers its whole encoding before it wraps).

    Parameters
    ----------
    s : Signal
        An analog signal of the I/O map.

    Returns
    -------
    (float, float)
        Low and high, in engineering units.

    """
    if s.lo is not None and s.hi is not None:
        return float(s.lo), float(s.hi)
    if s.normal is not None:
        return float(s.normal[0]), float(s.normal[1])
    return instrument_range(s)


def instrument_range(s) -> tuple[float, float]:
    """Return what a signal's register can carry, in engineering units (InstrumentRange)."""
    lo, hi = _RAW_RANGE[s.type]
    return lo * s.scale, hi * s.scale


async def _add_analog_properties(var, idx: int, s) -> None:
    """
    Add Part 8's properties: ``0:EURange``, ``0:InstrumentRange``, ``0:EngineeringUnits``.

    InstrumentRange (what the register can carry) on the inputs, what the instrument
    returns; EngineeringUnits where the signal has a unit.
    """
    from asyncua import ua

    ranges = [('EURange', eu_range(s))]
    if s.direction == INPUT:
        ranges.append(('InstrumentRange', instrument_range(s)))
    for name, (lo, hi) in ranges:
        await var.add_property(
            ua.NodeId(0, idx), ua.QualifiedName(name, 0), ua.Range(Low=lo, High=hi)
        )
    if s.unit:
        await var.add_property(
            ua.NodeId(0, idx), ua.QualifiedName('EngineeringUnits', 0), eu_information(s.unit)
        )


def eu_information(unit: str):
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


def _stamped(variant, sampled_ns: int):
    """
    Return a DataValue stamped as OPC UA Part 4 (7.11) says.

    SourceTimestamp: the wall-clock time the cell sampled the value (the end of the
    physics period that produced it), whatever the simulated clock reads; a cell that
    falls behind real time stamps its values late, never in the past.
    ServerTimestamp: when the server read it.
    """
    from asyncua import ua

    now = datetime.now(timezone.utc)
    source = datetime.fromtimestamp(sampled_ns / 1e9, timezone.utc) if sampled_ns else now
    return ua.DataValue(variant, SourceTimestamp=source, ServerTimestamp=now)


def _input_reader(image, s, vtype):
    from asyncua import ua

    def read(nodeid, attr):
        (value,), sampled = image.input_sample((s.name,))
        return _stamped(ua.Variant(opc_value(s, value), vtype), sampled)

    return read


def _output_writer(image, s):
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
