"""
Property-based fuzzing of every input the project takes: each one works or is refused.

For command-line ``--set`` values, scene files, the simulation node's parameter
sets, induct messages, routing rules and updates, controller scans and the
nodes' parameter services, hypothesis draws values of every type and size
(numbers out of range, NaN, inf, huge and tiny ones, strings, lists, nesting,
YAML syntax, unicode). The properties: the input is taken and the result is
valid, or it is refused with the project's own error and a one-line message of
bounded length; what was there before is unchanged; no other exception, and a
node keeps serving. The runs are derandomized (the same cases every run), so CI
is repeatable; a few thousand cases in all, in the slow set.
"""

from __future__ import annotations

import copy
import math

import pytest
import yaml
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from sorter_control.logic import (
    ControllerConfig,
    InputImage,
    RoutingError,
    RoutingTable,
    SorterLogic,
)
from sorter_sim.frontends.node_commands import induct_spec
from sorter_sim.runtime.cell import Cell, ParcelSpec, check_parcel
from sorter_sim.runtime.params import SPECS, CellParams, ParamError
from sorter_sim.runtime.scene import _RULES, SceneError, apply_overrides, load_scene, validate

pytestmark = pytest.mark.slow

FUZZ = settings(
    # no shrinking: a failure is reported as found (shrinking can outlast the test's limit)
    phases=[Phase.explicit, Phase.reuse, Phase.generate],
    max_examples=600,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)

numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-2.0, max_value=12.0),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.sampled_from([0, -0.0, 1e-300, -1e-300, 1e300, 5e-324, 0.5, 1.0, 90.0, 90.0000001]),
)
texts = st.one_of(
    st.text(max_size=40),
    st.sampled_from(['', 'nan', '.inf', 'null', '~', 'true', '[', '{a: 1}', '*a', '&a 1', '\x00']),
)
scalars = st.one_of(numbers, texts, st.booleans(), st.none())
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=14), st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=30,
)


def _one_line(exc: Exception) -> None:
    text = str(exc)
    assert text and '\n' not in text and len(text) < 600, text[:1000]


BASE = validate({})


# --------------------------------------------------------------------------- scenes
@FUZZ
@given(key=st.sampled_from(sorted(_RULES) + ['parcel.C', 'belt', 'x.y.z']), value=values)
def test_set_values_work_or_are_refused_in_one_line(key, value):
    before = copy.deepcopy(BASE)
    try:
        text = yaml.safe_dump(value, default_flow_style=True).strip()
    except yaml.YAMLError:
        text = str(value)
    if text.endswith('...'):
        text = text[:-3].strip()
    try:
        scene = apply_overrides(BASE, [f'{key}={text}'])
    except SceneError as exc:
        _one_line(exc)
    else:
        assert validate(scene) == scene  # what was taken is valid as it stands
    assert BASE == before


def _scene_docs(sections):
    return st.dictionaries(
        st.sampled_from(sections),
        st.one_of(
            st.dictionaries(st.sampled_from([k.split('.')[1] for k in _RULES]), values),
            values,
        ),
        max_size=4,
    )


# every section a scene has, in two halves (each with a section none has), 300 files
# each: 600 cases in two tests that each stay well inside a test's time on a busy machine
# (drawing the nested values is most of a case's cost)
SECTIONS = sorted({k.split('.')[0] for k in _RULES})
HALVES = [SECTIONS[: len(SECTIONS) // 2], SECTIONS[len(SECTIONS) // 2 :]]


@pytest.mark.parametrize(
    'sections', [[*h, 'extra'] for h in HALVES], ids=['-'.join(h) for h in HALVES]
)
@settings(FUZZ, max_examples=300)
@given(data=st.data())
def test_scene_files_work_or_are_refused_in_one_line(tmp_path_factory, sections, data):
    doc = data.draw(_scene_docs(sections), label='doc')
    path = tmp_path_factory.mktemp('scene') / 'scene.yaml'
    path.write_text(yaml.safe_dump(doc))
    try:
        scene = load_scene(path)
    except SceneError as exc:
        _one_line(exc)
    else:
        assert validate(scene) == scene


@FUZZ
@given(raw=st.binary(max_size=300))
def test_scene_files_of_any_bytes_are_refused_cleanly(tmp_path_factory, raw):
    path = tmp_path_factory.mktemp('scene') / 'scene.yaml'
    path.write_bytes(raw)
    try:
        load_scene(path)
    except SceneError as exc:
        _one_line(exc)


# --------------------------------------------------------------------------- the cell
DEFAULTS = CellParams.defaults()
NAMES = sorted(SPECS)


@FUZZ
@given(changes=st.dictionaries(st.sampled_from(NAMES + ['nonsense', '']), values, max_size=3))
def test_parameter_sets_work_or_are_refused_and_change_nothing(changes):
    for runtime in (True, False):
        try:
            new = DEFAULTS.with_changes(changes, runtime=runtime)
        except ParamError as exc:
            _one_line(exc)
        else:
            # a taken set is itself valid, and a cell can be built from it
            assert new.with_changes({}, runtime=False) == new
    assert DEFAULTS == CellParams.defaults()


@FUZZ
@given(
    pairs=st.lists(
        st.tuples(
            st.sampled_from(['label', 'A', 'B', 'm', 'phi0_deg', 'y', 'C', '']),
            st.one_of(st.text(max_size=30), numbers.map(repr)),
        ),
        max_size=6,
    )
)
def test_induct_messages_work_or_are_refused(pairs):
    cell = Cell(DEFAULTS.with_changes({'arrival': 'none'}, runtime=False))
    try:
        spec = induct_spec(pairs, DEFAULTS)
        cell.induct(spec)
    except ParamError as exc:
        _one_line(exc)
        assert cell.pending_inducts == 0
    else:
        assert cell.pending_inducts == 1
        assert check_parcel(spec, DEFAULTS.belt_width) == spec
        cell.advance(50)  # the queued parcel enters without trouble


@FUZZ
@given(spec=st.builds(ParcelSpec, numbers, numbers, numbers, numbers, numbers, texts))
def test_parcels_work_or_are_refused(spec):
    try:
        checked = check_parcel(spec, DEFAULTS.belt_width)
    except ParamError as exc:
        _one_line(exc)
    else:
        assert all(math.isfinite(v) for v in (checked.A, checked.B, checked.m, checked.y0))


# --------------------------------------------------------------------------- the controller
@FUZZ
@given(rules=st.lists(st.one_of(texts, st.integers(), st.none()), max_size=5), default=texts)
def test_routing_tables_work_or_are_refused(rules, default):
    try:
        table = RoutingTable(rules, default)
    except RoutingError as exc:
        _one_line(exc)
    else:
        # the table it holds reads back as the same table
        again = RoutingTable(table.rules(with_default=False), table.default or '')
        assert again.rules() == table.rules()


LOGIC = SorterLogic(ControllerConfig(routing_rules=('A*=left',)))


@FUZZ
@given(
    updates=st.lists(st.one_of(st.tuples(scalars, scalars), scalars), max_size=6),
    labels=st.lists(st.one_of(st.tuples(numbers, scalars), scalars), max_size=4),
    bits=st.dictionaries(st.sampled_from(['pe_scan', 'pe_divert', 'nope']), scalars, max_size=3),
)
def test_scans_take_any_updates_labels_and_bits(updates, labels, bits):
    t = (LOGIC.t or 0.0) + 0.01
    out = LOGIC.scan(InputImage(t=t, bits=bits, labels=labels, routing_updates=updates))
    for _, text in out.log:
        assert len(text) < 600
    # the live table is still a table the grammar accepts
    RoutingTable(LOGIC.routing.rules(with_default=False), LOGIC.routing.default or '')


# --------------------------------------------------------------------------- the nodes
def _parameter_value(kind, number, text, flag, numbers_, texts_):
    from rcl_interfaces.msg import ParameterValue

    # every type code rclpy knows (an unknown one is raised inside rclpy's own parameter
    # service, which spin_surviving outlives: test_node_survival runs that as a process)
    v = ParameterValue(type=kind)
    v.double_value = float(number)
    v.integer_value = int(max(-(2**63), min(2**63 - 1, number)))  # inf too: clamped first
    v.string_value = text.replace('\x00', '')
    v.bool_value = flag
    v.double_array_value = [float(x) for x in numbers_]
    v.string_array_value = [t.replace('\x00', '') for t in texts_]
    return v


@settings(FUZZ, max_examples=300)
@given(data=st.data())
def test_the_nodes_take_any_parameter_request_induct_and_routing_update(ros, data):
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.srv import GetParameters, SetParameters
    from rclpy.parameter import Parameter

    from sorter_control.node import ControllerNode
    from sorter_ros.interface import EVENT_QOS
    from sorter_sim.frontends.node import SimNode

    # one cell and controller for every example (the fixture lives as long as the test)
    rig = ros.__dict__.setdefault('fuzz_rig', {})
    if not rig:
        sim = ros.add(
            SimNode(
                context=ros.context,
                parameter_overrides=[
                    Parameter('time_mode', value='fast'),
                    Parameter('arrival', value='none'),
                ],
            )
        )
        ctl = ros.add(
            ControllerNode(
                context=ros.context,
                parameter_overrides=[Parameter('use_sim_time', value=True)],
            )
        )
        w = ros.make_node('fuzzer')
        rig.update(
            sim=sim,
            ctl=ctl,
            setp={
                n: w.create_client(SetParameters, f'/{n}/set_parameters')
                for n in ('sorter_sim', 'sorter_controller')
            },
            getp=w.create_client(GetParameters, '/sorter_sim/get_parameters'),
            induct=w.create_publisher(DiagnosticStatus, 'parcels/induct', EVENT_QOS),
            route=w.create_publisher(KeyValue, 'routing/updates', EVENT_QOS),
        )
        ros.spin_until(lambda: ctl.logic is not None, 20.0, 'the controller to start')
    node = data.draw(st.sampled_from(['sorter_sim', 'sorter_controller']))
    name = data.draw(st.sampled_from(NAMES + ['routing.rules', 'scan_period', 'use_sim_time', '']))
    value = _parameter_value(
        data.draw(st.integers(min_value=0, max_value=9)),
        data.draw(st.floats(allow_nan=False)),
        data.draw(st.text(max_size=30)),
        data.draw(st.booleans()),
        data.draw(st.lists(st.floats(), max_size=4)),
        data.draw(st.lists(st.text(max_size=10), max_size=4)),
    )
    future = rig['setp'][node].call_async(
        SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
    )
    ros.spin_until(future.done, 10.0, f'{node} to answer set_parameters {name!r}')
    result = future.result().results[0]
    if not result.successful:
        assert result.reason and len(result.reason) < 600
    pairs = data.draw(
        st.lists(
            st.tuples(
                st.sampled_from(['label', 'A', 'B', 'm', 'phi0_deg', 'y', 'Q']),
                st.text(max_size=20),
            ),
            max_size=4,
        )
    )
    rig['induct'].publish(DiagnosticStatus(values=[KeyValue(key=k, value=v) for k, v in pairs]))
    rig['route'].publish(
        KeyValue(key=data.draw(st.text(max_size=20)), value=data.draw(texts).replace('\x00', ''))
    )
    ros.spin_for(0.01)
    # both still serve, and the cell's parameters still read
    reply = ros.call(rig['getp'], GetParameters.Request(names=['alpha_deg']))
    assert len(reply.values) == 1
    assert rig['sim'].context.ok() and rig['ctl'].context.ok()


# ---------------------------------------------------------------- fieldbus frames and calls
MODBUS_COUNTS = {'tried': 0, 'exceptions': 0, 'writes': 0}


pdus = st.one_of(
    st.binary(min_size=1, max_size=260),
    st.tuples(
        st.sampled_from([1, 2, 3, 4, 5, 6, 15, 16, 17, 22, 23, 43, 0, 7, 8, 24, 127, 128, 255]),
        st.binary(max_size=40),
    ).map(lambda t: bytes([t[0]]) + t[1]),
    st.tuples(
        st.sampled_from([1, 2, 3, 4, 5, 6]),
        st.one_of(st.integers(0, 130), st.integers(0, 65535)),
        st.one_of(st.integers(0, 130), st.sampled_from([0xFF00, 0]), st.integers(0, 65535)),
    ).map(lambda t: bytes([t[0]]) + t[1].to_bytes(2, 'big') + t[2].to_bytes(2, 'big')),
    st.tuples(
        st.sampled_from([15, 16]),
        st.integers(0, 12),
        st.lists(st.integers(0, 65535), min_size=1, max_size=8),
    ).map(
        lambda t: (
            bytes([t[0]])
            + t[1].to_bytes(2, 'big')
            + len(t[2]).to_bytes(2, 'big')
            + (
                bytes([2 * len(t[2])]) + b''.join(v.to_bytes(2, 'big') for v in t[2])
                if t[0] == 16
                else bytes([1, sum(1 << i for i, v in enumerate(t[2]) if v & 1)])
            )
        )
    ),
)


@FUZZ
@given(pdu=pdus)
def test_any_modbus_request_is_answered_by_the_protocol_and_a_refusal_changes_nothing(pdu):
    from fieldbus_helpers import modbus_image

    from sorter_sim.frontends.modbus_server import ModbusTcpImageServer
    from sorter_sim.model.io_map import COIL, DI, HR, IR

    image = modbus_image()
    server = ModbusTcpImageServer(image, '127.0.0.1', 0)
    before = {t: image.snapshot(t) for t in (DI, COIL, IR, HR)}
    writes = image.stats['writes']
    reply = server.answer(pdu)
    MODBUS_COUNTS['tried'] += 1
    assert isinstance(reply, bytes) and 2 <= len(reply) <= 253
    if reply[0] & 0x80:
        # an exception response: the request's code with the high bit, one of codes 1-3
        assert reply[0] == pdu[0] | 0x80 and reply[1] in (1, 2, 3)
        assert {t: image.snapshot(t) for t in (DI, COIL, IR, HR)} == before
        assert image.stats['writes'] == writes
        MODBUS_COUNTS['exceptions'] += 1
    else:
        assert reply[0] == pdu[0]
        if pdu[0] in (1, 2, 3, 4, 17, 43):  # reads change nothing
            assert {t: image.snapshot(t) for t in (DI, COIL, IR, HR)} == before
        MODBUS_COUNTS['writes'] += image.stats['writes'] - writes
    # inputs are never written by a client, whatever it sends
    assert image.snapshot(DI) == before[DI] and image.snapshot(IR) == before[IR]


def test_modbus_fuzz_counts():
    print(f'Modbus requests fuzzed: {MODBUS_COUNTS}')


VARIANTS = None


def _variant_values():
    from asyncua import ua

    V = ua.VariantType
    return [
        ua.Variant(4294967295, V.UInt32),
        ua.Variant(-1, V.Int64),
        ua.Variant(True, V.Boolean),
        ua.Variant(1.5, V.Double),
        ua.Variant(float('nan'), V.Double),
        ua.Variant('', V.String),
        ua.Variant('\x00' * 3, V.String),
        ua.Variant('A*', V.String),
        ua.Variant('x' * 5000, V.String),
        ua.Variant(['A*=left'], V.String, is_array=True),
        ua.Variant(['accepted: ok'], V.String, is_array=True),
        ua.Variant([''], V.String, is_array=True),
        ua.Variant([1, 2, 3], V.Int32, is_array=True),
        ua.Variant(b'\x01\x02', V.ByteString),
        ua.Variant(None, V.Null),
    ]


@pytest.mark.ros
def test_warehouse_methods_take_any_argument_types_and_counts(ros):
    """Every method x every argument count 0-3 x a spread of Variant types: refused or taken."""
    import asyncio
    import itertools

    from asyncua import Client
    from asyncua import ua as _ua
    from rclpy.parameter import Parameter
    from ros_harness import free_port
    from test_sim_node import SHORT_CELL

    from sorter_sim.frontends.node import SimNode

    cell = ros.add(
        SimNode(
            context=ros.context,
            parameter_overrides=[
                Parameter(k, value=v) for k, v in {**SHORT_CELL, 'opcua_port': free_port()}.items()
            ],
        )
    )
    variants = _variant_values()
    counts = {'tried': 0, 'refused': 0, 'taken': 0, 'other': 0}

    async def run():
        async with Client(cell.fieldbus.opcua_endpoint, timeout=10) as client:
            idx = await client.get_namespace_index('urn:sorter_cell')
            folder = await client.nodes.objects.get_child([f'{idx}:cell', f'{idx}:Warehouse'])
            # the warehouse's state as a client reads it (the servers run in their own
            # process): pending routes, results, confirmations, the routing table
            state_nodes = [
                await folder.get_child([f'{idx}:{n}'])
                for n in ('PendingRoutes', 'RouteResults', 'Confirmations', 'RoutingTable')
            ]

            async def warehouse():
                return await client.read_values(state_nodes)

            for name in ('RequestRoute', 'TakeRoutes', 'Confirm', 'PublishRoutingTable'):
                combos = [()] + [(v,) for v in variants]
                combos += list(itertools.product(variants[:8], variants[5:13]))
                combos += [(variants[0], variants[9], variants[5])]
                for args in combos:
                    state = await warehouse()
                    counts['tried'] += 1
                    try:
                        await folder.call_method(f'{idx}:{name}', *args)
                        counts['taken'] += 1
                    except _ua.UaStatusCodeError as exc:
                        counts['refused'] += 1
                        assert type(exc).__name__ in (
                            'BadInvalidArgument',
                            'BadTypeMismatch',
                            'BadArgumentsMissing',
                            'BadTooManyArguments',
                        ), (name, args, exc)
                        assert await warehouse() == state, (name, args)

    asyncio.run(run())
    print(f'warehouse method calls fuzzed: {counts}')
    assert counts['tried'] > 300 and counts['other'] == 0
    cell.advance(10)  # the node serves on
