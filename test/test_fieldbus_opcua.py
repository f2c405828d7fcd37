"""
The OPC UA server of the I/O image, checked with asyncua's own clients.

The warehouse link (its methods, typed and bounded), access control (no identity buys
more than anonymous access; inputs and the address space are read-only), writes
answered item by item, subscriptions as a SCADA makes them, and engineering units.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import pytest
from asyncua import ua
from asyncua.sync import Client as OpcClient
from rclpy.parameter import Parameter
from ros_harness import free_port
import fieldbus_helpers as fb
from fieldbus_helpers import diagnostics, refused_login

from sorter_sim.frontends.node import SimNode
from sorter_sim.model.core import cell_kernels as ck

pytestmark = pytest.mark.ros
# the fixtures: a cell serving Modbus TCP and OPC UA, and an OPC UA client
cell, opcua = fb.cell, fb.opcua


def test_the_warehouse_link_over_opc_ua_routes_and_confirms(ros):
    from sorter_cell.demo import _controller_values
    from sorter_control.parameters import config_from_values
    from sorter_control.soft_plc import OpcUaIO, SoftPLC

    config = Path(__file__).resolve().parents[1] / 'config'
    # the default cell (config/cell.yaml), as the PLC's configuration (controller.yaml) knows it
    cell = ros.add(
        SimNode(
            context=ros.context,
            cli_args=['--ros-args', '--params-file', str(config / 'cell.yaml')],
            parameter_overrides=[
                Parameter('time_mode', value='lockstep'),
                Parameter('opcua_port', value=free_port()),
            ],
        )
    )
    cfg = config_from_values(
        {**_controller_values(config), 'routing.rules': ['A*=left', 'B*=right', 'C*=straight']}
    )
    plc = SoftPLC(cfg, OpcUaIO(cell.fieldbus.opcua_endpoint, 'cell', cell.cell.sensor_names))
    wms = OpcClient(cell.fieldbus.opcua_endpoint, timeout=10)
    wms.connect()
    try:
        idx = wms.get_namespace_index('urn:sorter_cell')
        wh = wms.nodes.objects.get_child([f'{idx}:cell', f'{idx}:Warehouse'])

        def read(name):
            return wh.get_child([f'{idx}:{name}']).read_value()

        def request(pattern, destination):
            return wh.call_method(f'{idx}:RequestRoute', pattern, destination)

        assert request('C*', 'left') == 1  # the C parcels now go left
        assert request('Z*', '') == 2  # removing a rule there is not: refused by the PLC
        for bad in (('C=1', 'left'), ('C*', 'up'), ('C;1', 'left')):
            with pytest.raises(ua.UaStatusCodeError) as err:
                request(*bad)
            assert type(err.value).__name__ == 'BadInvalidArgument'
        while cell.cell.t < 14.0:
            cell.advance(10)
            plc.scan()
        results = read('RouteResults')
        assert results[0].startswith('1|C*=left: accepted'), results
        assert results[1].startswith('2|Z*=: refused'), results
        assert read('PendingRoutes') == [] and read('RouteRequests') == 2
        assert 'C*=left' in read('RoutingTable') and 'C*=straight' not in read('RoutingTable')
        lines = read('Confirmations')
        assert read('ConfirmationCount') == len(lines) >= 4
        by_label = {line.split(';')[0]: line.split(';')[1:] for line in lines}
        assert by_label['C00003'] == ['left', 'left', 'sorted'], by_label
        assert by_label['A00001'] == ['left', 'left', 'sorted']
        assert by_label['B00002'] == ['right', 'right', 'sorted']
    finally:
        wms.disconnect()
        plc.io.close()


# ---------------------------------------------------------------- OPC UA access control
async def _activate_with(endpoint: str, token) -> str:
    """Open a session and activate it with ``token`` as sent by any client; the outcome."""
    from asyncua import Client

    client = Client(endpoint, timeout=10)
    await client.connect_socket()
    try:
        await client.send_hello()
        await client.open_secure_channel()
        await client.create_session()
        params = ua.ActivateSessionParameters()
        params.UserIdentityToken = token
        try:
            await client.uaclient.activate_session(params)
        except ua.UaStatusCodeError as exc:
            return type(exc).__name__
        return 'activated'
    finally:
        client.disconnect_socket()


def _self_signed_certificate() -> bytes:
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, 'admin')])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(now + datetime.timedelta(days=1))
        .sign(key, hashes.SHA256())
    )
    return cert.public_bytes(serialization.Encoding.DER)


def test_no_identity_a_client_offers_buys_more_than_anonymous_access(cell):
    import asyncio

    endpoint = cell.fieldbus.opcua_endpoint
    # through an ordinary client: 'admin' with any password, other names
    for user, password in (('admin', 'x'), ('admin', ''), ('Admin', 'admin'), ('root', 'root')):
        assert refused_login(endpoint, user, password) is not None, user
    # and as raw tokens, past whatever a client library checks on its own side
    names = [
        ua.UserNameIdentityToken(PolicyId='anonymous', UserName='admin', Password=b'x'),
        ua.UserNameIdentityToken(PolicyId='username', UserName='operator', Password=b'1234'),
        ua.X509IdentityToken(PolicyId='certificate', CertificateData=_self_signed_certificate()),
    ]
    for token in names:
        outcome = asyncio.run(_activate_with(endpoint, token))
        assert outcome in ('BadIdentityTokenRejected', 'BadUserAccessDenied'), (token, outcome)
    assert asyncio.run(_activate_with(endpoint, ua.AnonymousIdentityToken())) == 'activated'


def test_an_anonymous_client_cannot_write_inputs_nor_add_or_delete_nodes(cell, opcua):
    cell.advance(10)
    t_input = opcua('cell.time')
    for node, value in (
        (t_input, ua.Variant(123.0, ua.VariantType.Double)),
        (opcua('status.estop'), ua.Variant(True, ua.VariantType.Boolean)),
    ):
        with pytest.raises(ua.UaStatusCodeError) as err:
            node.write_value(value)
        assert type(err.value).__name__ == 'BadUserAccessDenied'
    # a write to another attribute (the name) of an output is refused too
    popup = opcua('diverter.popup')
    with pytest.raises(ua.UaStatusCodeError):
        popup.write_attribute(
            ua.AttributeIds.DisplayName, ua.DataValue(ua.Variant(ua.LocalizedText('x')))
        )
    with pytest.raises(ua.UaStatusCodeError):
        popup.delete()
    folder = popup.get_parent()
    with pytest.raises(ua.UaStatusCodeError):
        folder.add_variable(2, 'intruder', 1.0)
    # the inputs stay live, the output stays where it was
    cell.advance(100)
    assert t_input.read_value() == pytest.approx(cell.cell.t, abs=1e-9)
    assert popup.read_display_name().Text == 'diverter.popup'
    assert popup.read_value() is False
    assert not cell.cell.estop


def test_a_mixed_write_request_is_answered_item_by_item(cell, opcua):
    """Part 4, 5.10.4: one status code per item; the good items applied, the bad refused."""
    cell.advance(5)
    popup, alpha, t_input = (
        opcua('diverter.popup'),
        opcua('diverter.alpha_setpoint'),
        opcua('cell.time'),
    )

    def item(node, variant):
        return ua.WriteValue(
            NodeId=node.nodeid,
            AttributeId=ua.AttributeIds.Value,
            Value=ua.DataValue(variant),
        )

    params = ua.WriteParameters(
        NodesToWrite=[
            item(alpha, ua.Variant(95.0, ua.VariantType.Double)),
            item(popup, ua.Variant(True, ua.VariantType.Boolean)),
            item(alpha, ua.Variant('up', ua.VariantType.String)),
            item(t_input, ua.Variant(1.0, ua.VariantType.Double)),
            item(alpha, ua.Variant(30.0, ua.VariantType.Double)),
        ]
    )
    import asyncio

    from asyncua import Client

    async def write():
        async with Client(cell.fieldbus.opcua_endpoint, timeout=10) as client:
            return await client.uaclient.write(params)

    names = [r.name for r in asyncio.run(write())]
    assert names == ['BadOutOfRange', 'Good', 'BadTypeMismatch', 'BadUserAccessDenied', 'Good']
    cell.advance(1)
    assert cell.get_parameter('alpha_deg').value == 30.0
    assert float(cell.cell.act[ck.A_STROKE_TARGET]) == 1.0


def test_the_soft_plcs_outputs_of_a_scan_go_in_one_write_answered_output_by_output(cell):
    """The soft PLC's output image: one Write request a scan, each output with its status."""
    from sorter_control.soft_plc import OpcUaIO

    io = OpcUaIO(cell.fieldbus.opcua_endpoint, 'cell', cell.cell.sensor_names)
    try:
        out = {s.name: s for s in io.signals if s.direction == 'output'}
        cell.advance(5)
        before = io.requests
        errors = io.write_many(
            [
                (out['diverter.alpha_setpoint'], 95.0),  # beyond the disks' +-90 deg
                (out['diverter.popup'], True),
                (out['diverter.alpha_setpoint'], 30.0),
            ]
        )
        assert io.requests == before + 1
        assert errors[0] == 'OPC UA BadOutOfRange writing diverter.alpha_setpoint', errors
        assert errors[1:] == [None, None]
        cell.advance(1)
        assert cell.get_parameter('alpha_deg').value == 30.0
        assert float(cell.cell.act[ck.A_STROKE_TARGET]) == 1.0
    finally:
        io.close()


def test_warehouse_methods_take_typed_bounded_arguments_and_change_nothing_on_refusal(cell):
    import asyncio

    from asyncua import Client

    U32, I64, B, S, I32 = (
        ua.VariantType.UInt32,
        ua.VariantType.Int64,
        ua.VariantType.Boolean,
        ua.VariantType.String,
        ua.VariantType.Int32,
    )

    def strings(values):  # an array of strings, as the methods take their lists
        return ua.Variant(values, S, is_array=True)

    async def run():
        async with Client(cell.fieldbus.opcua_endpoint, timeout=10) as client:
            idx = await client.get_namespace_index('urn:sorter_cell')
            folder = await client.nodes.objects.get_child([f'{idx}:cell', f'{idx}:Warehouse'])
            # the warehouse's state as a client reads it (the servers run in their own
            # process): pending routes, results, confirmations, the routing table, count
            names = ('PendingRoutes', 'RouteResults', 'Confirmations', 'RoutingTable')
            state_nodes = [await folder.get_child([f'{idx}:{n}']) for n in names]
            count_node = await folder.get_child([f'{idx}:ConfirmationCount'])

            async def warehouse():
                return await client.read_values(state_nodes)

            async def call(name, *args):
                try:
                    return await folder.call_method(f'{idx}:{name}', *args)
                except ua.UaStatusCodeError as exc:
                    return type(exc).__name__

            assert await call('RequestRoute', 'A*', 'left') == 1
            assert await call('RequestRoute', 'B*', 'right') == 2
            state = await warehouse()
            refusals = {
                'take all with no results': (
                    'TakeRoutes',
                    ua.Variant(4294967295, U32),
                    strings([]),
                ),
                'take more than wait': (
                    'TakeRoutes',
                    ua.Variant(3, U32),
                    strings(['accepted: a', 'accepted: b', 'accepted: c']),
                ),
                'Int64 count': ('TakeRoutes', ua.Variant(1, I64), strings(['accepted: x'])),
                'Boolean count': ('TakeRoutes', ua.Variant(True, B), strings(['accepted: x'])),
                'garbage result': ('TakeRoutes', ua.Variant(1, U32), strings(['\x00'])),
                'empty confirmation': ('Confirm', strings(['', '\x00', ';;;;'])),
                'int table': ('PublishRoutingTable', ua.Variant([1, 2, 3], I32, is_array=True)),
                'bad rule': ('PublishRoutingTable', strings(['A*=up'])),
                'huge table': ('PublishRoutingTable', strings(['A*=left'] * 1001)),
                'long line': ('Confirm', strings(['A1;left;left;' + 's' * 300])),
            }
            got = {why: await call(*args) for why, args in refusals.items()}
            for why, outcome in got.items():
                assert outcome in ('BadInvalidArgument', 'BadTypeMismatch'), (why, outcome)
            assert got['Int64 count'] == got['Boolean count'] == 'BadTypeMismatch'
            assert await warehouse() == state
            # the wrong number of arguments: the protocol's own codes
            assert await call('RequestRoute', 'A*') == 'BadArgumentsMissing'
            assert await call('RequestRoute', 'A*', 'left', 'x') == 'BadTooManyArguments'
            # well-formed calls still work
            assert (
                await call(
                    'TakeRoutes',
                    ua.Variant(2, U32),
                    strings(['accepted: A*=left', 'refused: no']),
                )
                is None
            )
            lines = ['A1;left;left;sorted', ';straight;straight;rejected']
            assert await call('Confirm', strings(lines)) is None
            table = ['A*=left', '*=straight']
            assert await call('PublishRoutingTable', strings(table)) is None
            pending, results, _, live_table = await warehouse()
            assert not pending and len(results) == 2 and live_table == table
            assert await count_node.read_value() == 2
        return len(refusals) + 2

    refused = asyncio.run(run())
    assert int(diagnostics(cell)['fieldbus_calls_refused']) == refused
    assert int(diagnostics(cell)['fieldbus_writes_refused']) == 0


# ---------------------------------------------------------------- OPC UA as a SCADA uses it
def test_an_opc_ua_subscription_sees_the_cell_move(cell):
    """Subscribe as a SCADA does (asyncua's own client): each change, stamped, in order."""
    import asyncio
    import threading
    import time as _time

    notes = {'cell.time': [], 'belt.encoder': [], 'sensor.pe_scan': []}
    ready, done = threading.Event(), threading.Event()

    class Handler:
        def datachange_notification(self, node, val, data):
            dv = data.monitored_item.Value
            notes[names[node.nodeid]].append((val, dv.SourceTimestamp, dv.ServerTimestamp))

    names = {}

    async def subscribe():
        from asyncua import Client

        async with Client(cell.fieldbus.opcua_endpoint, timeout=10) as client:
            idx = await client.get_namespace_index('urn:sorter_cell')
            inputs = await client.nodes.objects.get_child([f'{idx}:cell', f'{idx}:Inputs'])
            nodes = [await inputs.get_child([f'{idx}:{n}']) for n in notes]
            names.update({n.nodeid: name for n, name in zip(nodes, notes)})
            sub = await client.create_subscription(100, Handler())
            await sub.subscribe_data_change(nodes, sampling_interval=100)
            ready.set()
            while not done.is_set():
                await asyncio.sleep(0.05)
            await sub.delete()

    worker = threading.Thread(target=lambda: asyncio.run(subscribe()), daemon=True)
    worker.start()
    assert ready.wait(20.0), 'no subscription within 20 s'
    started = datetime.now(timezone.utc)
    try:
        # 3 s of simulated time over about 3 s of wall time, as a real-time cell runs
        for _ in range(60):
            cell.advance(50)
            _time.sleep(0.05)
        finished = datetime.now(timezone.utc)
        # the last changes reach the client a publishing interval or two later (more on a
        # loaded machine): wait for the cell's final time, at most 10 s
        t_end, until = cell.cell.t, _time.monotonic() + 10.0
        while _time.monotonic() < until and not (
            notes['cell.time'] and notes['cell.time'][-1][0] >= t_end - 0.2
        ):
            _time.sleep(0.05)
    finally:
        done.set()
        worker.join(20.0)
    times = [v for v, _, _ in notes['cell.time']]
    assert len(times) >= 15, f'{len(times)} notifications of cell.time in about 3 s'
    assert times == sorted(times) and times[-1] > times[0] + 2.0
    enc = [v for v, _, _ in notes['belt.encoder']]
    assert len(enc) >= 15 and enc == sorted(enc)
    assert len(notes['sensor.pe_scan']) >= 2  # the initial value and at least one edge
    stamped = notes['cell.time'][1:]
    for value, source, server in stamped:
        # SourceTimestamp: when the cell sampled the value (wall clock); the server stamps too
        assert source is not None and server is not None and source <= server
        assert started <= source <= finished
    sources = [source for _, source, _ in stamped]
    assert sources == sorted(sources)


def test_engineering_units_carry_their_unece_codes(cell, opcua):
    def info(name):
        props = opcua(name).get_properties()
        (prop,) = [p for p in props if p.read_browse_name().Name == 'EngineeringUnits']
        return prop.read_value()

    def code(text):  # OPC UA Part 8, 5.6.3: the UNECE common code's characters, 8 bits each
        value = 0
        for c in text:
            value = (value << 8) | ord(c)
        return value

    for name, unece in (('belt.encoder', 'MTR'), ('cell.time', 'SEC'), ('diverter.alpha', 'DD')):
        eu = info(name)
        assert eu.NamespaceUri == 'http://www.opcfoundation.org/UA/units/un/cefact'
        assert eu.UnitId == code(unece), name
