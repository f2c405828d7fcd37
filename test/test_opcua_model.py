"""
The OPC UA servers as a generic client meets them (asyncua's client, browsing).

A SCADA, a historian or an OPC UA browser knows nothing of this project: it finds
units and ranges by the standard browse names (``0:EngineeringUnits``,
``0:EURange``) under variables whose type definition is AnalogItemType (OPC UA Part
8), reads method arguments' names and array ranks from ``0:InputArguments`` (Part 3),
tells servers apart by ApplicationUri and the product by BuildInfo (Part 5), and files
values at their SourceTimestamp (Part 4). Each is checked here on the cell's server,
the line's and the warehouse node's.
"""

from __future__ import annotations

import time
from datetime import datetime, timedelta, timezone
from importlib.metadata import version

import pytest
from asyncua import ua
from asyncua.sync import Client
from rclpy.parameter import Parameter
from ros_harness import free_port
import fieldbus_helpers


pytestmark = pytest.mark.ros
MAP = fieldbus_helpers.MAP
cell = fieldbus_helpers.cell  # the fixture: a cell serving Modbus TCP and OPC UA
ANALOG_ITEM = ua.NodeId(ua.ObjectIds.AnalogItemType)
UNECE = {'m': 'MTR', 's': 'SEC', 'deg': 'DD'}


@pytest.fixture
def wcs(ros):
    from sorter_control.wcs_node import WcsNode

    return ros.add(
        WcsNode(
            context=ros.context,
            parameter_overrides=[
                Parameter('stations', value=2),
                Parameter('opcua_port', value=free_port()),
            ],
        )
    )


@pytest.fixture
def client(cell):
    c = Client(cell.fieldbus.opcua_endpoint, timeout=10)
    c.connect()
    yield c
    c.disconnect()


def _code(text: str) -> int:
    """Return a UNECE common code as OPC UA Part 8 (5.6.3) packs it: 8 bits a character."""
    value = 0
    for c in text:
        value = (value << 8) | ord(c)
    return value


def _variables(folder):
    return {
        v.read_browse_name().Name: v for v in folder.get_children(refs=ua.ObjectIds.HasComponent)
    }


def test_analog_values_are_analog_items_with_the_standard_units_and_range(client):
    idx = client.get_namespace_index('urn:sorter_cell')
    root = client.nodes.objects.get_child([f'{idx}:cell'])
    found, instrument = {}, {}
    for folder in ('Inputs', 'Outputs'):
        for name, var in _variables(root.get_child([f'{idx}:{folder}'])).items():
            if var.read_type_definition() != ANALOG_ITEM:
                # not analog: no Part 8 properties to find
                with pytest.raises(ua.UaStatusCodeError):
                    var.get_child(['0:EURange'])
                continue
            eu_range = var.get_child(['0:EURange'])
            assert eu_range.read_type_definition() == ua.NodeId(ua.ObjectIds.PropertyType)
            assert eu_range.read_data_type() == ua.NodeId(ua.ObjectIds.Range)
            rng = eu_range.read_value()
            if MAP[name].direction == 'input':
                # what the register can carry: the instrument's range (Part 8, 5.3.2)
                node = var.get_child(['0:InstrumentRange'])
                assert node.read_data_type() == ua.NodeId(ua.ObjectIds.Range)
                instrument[name] = node.read_value()
            else:
                with pytest.raises(ua.UaStatusCodeError):
                    var.get_child(['0:InstrumentRange'])
            units = None
            if MAP[name].unit:
                node = var.get_child(['0:EngineeringUnits'])
                assert node.read_data_type() == ua.NodeId(ua.ObjectIds.EUInformation)
                units = node.read_value()
            found[name] = (rng, units)
    # every value in engineering units is analog, and nothing else is
    expected = {
        s.name
        for s in MAP.values()
        if s.type not in ('bool', 'string') and (s.scale != 1.0 or s.unit)
    }
    assert set(found) == expected and len(found) == 15
    for name, (rng, units) in found.items():
        s = MAP[name]
        if s.unit:
            assert units.NamespaceUri == 'http://www.opcfoundation.org/UA/units/un/cefact'
            assert units.UnitId == _code(UNECE[s.unit]), name
        assert rng.Low < rng.High
    assert (found['diverter.alpha_setpoint'][0].Low, found['diverter.alpha_setpoint'][0].High) == (
        -90.0,
        90.0,
    )
    # an input's EURange is its range in normal operation, its InstrumentRange what its
    # register carries: alpha is int16 in 0.01 deg and within the setpoint's ±90 deg,
    # the stroke uint16 in 0.001 and 0 (down) .. 1 (up)
    ranges = {
        n: ((found[n][0].Low, found[n][0].High), (instrument[n].Low, instrument[n].High))
        for n in ('diverter.alpha', 'diverter.stroke')
    }
    assert ranges['diverter.alpha'] == ((-90.0, 90.0), pytest.approx((-327.68, 327.67)))
    assert ranges['diverter.stroke'] == ((0.0, 1.0), pytest.approx((0.0, 65.535)))
    # a time or a counter covers its whole encoding in normal operation: both the same
    t = found['cell.time'][0]
    assert (t.Low, t.High) == (instrument['cell.time'].Low, instrument['cell.time'].High)
    assert set(instrument) == {n for n in found if MAP[n].direction == 'input'}


def test_method_arguments_are_named_and_arrays_are_one_dimensional(client):
    idx = client.get_namespace_index('urn:sorter_cell')
    wh = client.nodes.objects.get_child([f'{idx}:cell', f'{idx}:Warehouse'])
    args = {}
    for method in wh.get_children(nodeclassmask=ua.NodeClass.Method):
        name = method.read_browse_name().Name
        for prop in ('InputArguments', 'OutputArguments'):
            try:
                node = method.get_child([f'0:{prop}'])
            except ua.UaStatusCodeError:
                continue  # a method without outputs has no OutputArguments
            values = node.read_value()
            # the property is an array of Argument, declared as the standard's methods'
            # are: ValueRank 1, ArrayDimensions the number of arguments
            assert node.read_value_rank() == 1, (name, prop)
            assert node.read_array_dimensions() == [len(values)], (name, prop)
            for a in values:
                assert a.Name and a.Description.Text, (name, a)
                args[f'{name}.{a.Name}'] = (a.ValueRank, list(a.ArrayDimensions or []))
    assert set(args) == {
        'RequestRoute.pattern',
        'RequestRoute.destination',
        'RequestRoute.sequence',
        'TakeRoutes.count',
        'TakeRoutes.results',
        'Confirm.lines',
        'PublishRoutingTable.rules',
    }
    for arrays in ('TakeRoutes.results', 'Confirm.lines', 'PublishRoutingTable.rules'):
        assert args[arrays] == (1, [0]), arrays
    assert args['RequestRoute.pattern'][0] == -1
    # String[] variables say so, empty or not
    for name in ('PendingRoutes', 'RouteResults', 'Confirmations', 'RoutingTable'):
        var = wh.get_child([f'{idx}:{name}'])
        assert var.read_value_rank() == 1 and var.read_array_dimensions() == [0], name
        assert var.read_description().Text
    # a call with the declared array is taken
    seq = wh.call_method(f'{idx}:RequestRoute', 'A1*', 'left')
    assert seq == 1


def _identity(endpoint: str) -> dict:
    """Return what a client learns of a server once it connects."""
    c = Client(endpoint, timeout=10)
    c.connect()
    try:
        (found,) = c.find_servers()
        build = c.get_node(ua.ObjectIds.Server_ServerStatus_BuildInfo).read_value()
        namespaces = c.get_namespace_array()
    finally:
        c.disconnect()
    return {
        'uri': found.ApplicationUri,
        'product': found.ProductUri,
        'build': build,
        'ns1': namespaces[1],
    }


def test_every_server_has_its_own_application_uri_and_the_products_build_info(ros, cell, wcs):
    from test_line_node import make_line

    line = make_line(ros, stations=2, opcua_port=free_port())
    seen = {
        'cell': _identity(cell.fieldbus.opcua_endpoint),
        'line': _identity(line.fieldbus.opcua_endpoint),
        'wcs': _identity(wcs.opcua.endpoint),
    }
    uris = {what: got['uri'] for what, got in seen.items()}
    assert len(set(uris.values())) == 3, uris
    assert uris['cell'].endswith(':sorter_cell:cell:cell')
    assert uris['line'].endswith(':sorter_cell:line:sorter_line')
    assert uris['wcs'].endswith(':sorter_cell:wcs')
    for what, got in seen.items():
        assert got['ns1'] == got['uri'], what  # OPC UA Part 5, 6.3.1
        assert got['product'] == got['build'].ProductUri == 'urn:sorter_cell:product'
        b = got['build']
        assert (b.ProductName, b.ManufacturerName) == ('sorter_cell', 'sorter_cell'), what
        assert b.SoftwareVersion == version('sorter_cell'), what
        # built when the package was installed: before this test, not the server's start
        assert b.BuildDate < datetime.now(timezone.utc) - timedelta(seconds=1), what


def test_wcs_method_arguments_are_named_and_the_plan_is_an_array(wcs):
    c = Client(wcs.opcua.endpoint, timeout=10)
    c.connect()
    try:
        idx = c.get_namespace_index('urn:sorter_cell:line')
        wh = c.nodes.objects.get_child([f'{idx}:sorter_line', f'{idx}:Warehouse'])
        args = {}
        for name in ('SetSortPlan', 'RequestDestination'):
            node = wh.get_child([f'{idx}:{name}', '0:InputArguments'])
            values = node.read_value()
            # an array of Argument, declared as the standard's methods' (and the cell's) are
            assert node.read_value_rank() == 1, name
            assert node.read_array_dimensions() == [len(values)], name
            for a in values:
                assert a.Description.Text, (name, a.Name)
                args[f'{name}.{a.Name}'] = (a.ValueRank, list(a.ArrayDimensions or []))
        assert args == {
            'SetSortPlan.version': (-1, []),
            'SetSortPlan.entries': (1, [0]),
            'RequestDestination.label': (-1, []),
            'RequestDestination.destination': (-1, []),
        }
        for name in ('SortPlan', 'FullChutes', 'Dispositions'):
            var = wh.get_child([f'{idx}:{name}'])
            assert var.read_value_rank() == 1 and var.read_array_dimensions() == [0], name
    finally:
        c.disconnect()


def test_source_timestamps_are_wall_clock_when_simulated_time_falls_behind(cell, client):
    """
    The cell drops simulated time on purpose (it is not stepped for 3 s of wall time).

    SourceTimestamp is when the value was sampled, on the wall clock: it does not fall
    behind with the simulated time, which the variable ``cell.time`` still gives.
    """
    idx = client.get_namespace_index('urn:sorter_cell')
    inputs = client.nodes.objects.get_child([f'{idx}:cell', f'{idx}:Inputs'])
    sim_time = inputs.get_child([f'{idx}:cell.time'])
    encoder = inputs.get_child([f'{idx}:belt.encoder'])
    cell.advance(100)
    t0 = sim_time.read_value()
    time.sleep(3.0)  # 3 s of wall time, none simulated: the cell falls 3 s behind
    before = datetime.now(timezone.utc)
    cell.advance(100)
    after = datetime.now(timezone.utc)
    time.sleep(0.3)
    for node in (sim_time, encoder):
        dv = node.read_data_value()
        # sampled while advance() ran, read later: Source inside the step, Server after it
        assert before - timedelta(milliseconds=5) <= dv.SourceTimestamp <= after, dv
        assert dv.ServerTimestamp >= dv.SourceTimestamp + timedelta(milliseconds=250)
    t1 = sim_time.read_value()
    assert t1 - t0 == pytest.approx(0.1, abs=1e-3)  # the simulated clock moved 0.1 s only
