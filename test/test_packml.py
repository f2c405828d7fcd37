"""
The cell's machine state: the PackML state model, the cell's conditions on it, its faces.

The transitions are checked against ISA-TR88.00.02's state model written out here pair
by pair (not derived from the module's table), the numbers against PackTags'
StateCurrent and CntrlCmd. The cell's conditions (e-stop, jam, watchdog, starved,
blocked, a batch done, stop) are driven through the real cell; the ROS face through the
real node's topic and services; the OPC UA face with asyncua's client, as a SCADA
calls it.
"""

from __future__ import annotations

import math

import pytest

from sorter_sim.model import packml
from sorter_sim.model.packml import Conditions, PackMLMachine
from sorter_sim.runtime.cell import Cell, ParcelSpec
from sorter_sim.runtime.faults import apply_fault
from sorter_sim.runtime.params import CellParams

# ISA-TR88.00.02 (2015), figure 7: the commanded transitions, pair by pair
STANDARD = {
    ('Stopped', 'reset'): 'Resetting',
    ('Complete', 'reset'): 'Resetting',
    ('Idle', 'start'): 'Starting',
    ('Execute', 'hold'): 'Holding',
    ('Held', 'unhold'): 'Unholding',
    ('Execute', 'suspend'): 'Suspending',
    ('Suspended', 'unsuspend'): 'Unsuspending',
    ('Aborted', 'clear'): 'Clearing',
}
for _s in (
    'Idle',
    'Starting',
    'Execute',
    'Completing',
    'Complete',
    'Resetting',
    'Holding',
    'Held',
    'Unholding',
    'Suspending',
    'Suspended',
    'Unsuspending',
):
    STANDARD[(_s, 'stop')] = 'Stopping'
for _s in (
    'Stopped',
    'Stopping',
    'Clearing',
    'Idle',
    'Starting',
    'Execute',
    'Completing',
    'Complete',
    'Resetting',
    'Holding',
    'Held',
    'Unholding',
    'Suspending',
    'Suspended',
    'Unsuspending',
):
    STANDARD[(_s, 'abort')] = 'Aborting'
# this cell's documented addition: a hold from the Suspended group and from Unholding
EXTENSION = {
    (s, 'hold'): 'Holding' for s in ('Suspending', 'Suspended', 'Unsuspending', 'Unholding')
}
# PackTags StateCurrent and CntrlCmd
STATE_NUMBERS = dict(
    Undefined=0,
    Clearing=1,
    Stopped=2,
    Starting=3,
    Idle=4,
    Suspended=5,
    Execute=6,
    Stopping=7,
    Aborting=8,
    Aborted=9,
    Holding=10,
    Held=11,
    Unholding=12,
    Suspending=13,
    Unsuspending=14,
    Resetting=15,
    Completing=16,
    Complete=17,
)
COMMAND_NUMBERS = dict(
    reset=1, start=2, stop=3, hold=4, unhold=5, suspend=6, unsuspend=7, abort=8, clear=9
)


def _in(state: str, auto: bool = False) -> PackMLMachine:
    m = PackMLMachine(auto=auto)
    m.state = state
    return m


def test_every_command_in_every_state_follows_the_standard():
    expected = {**STANDARD, **EXTENSION}
    assert len(packml.STATES) == 17
    for state in packml.STATES:
        for command in packml.COMMANDS:
            m = _in(state)
            ok, text = m.command(command, 0)
            target = expected.get((state, command))
            if target is None:
                assert not ok and m.state == state, (state, command)
                assert text.startswith(f'{state} does not take {command}: PackML takes it in')
            else:
                assert ok and m.state == target, (state, command, m.state)
    m = _in('Execute')
    assert m.command('jump', 0) == (
        False,
        "unknown PackML command 'jump'; one of reset, start, stop, hold, unhold, suspend, "
        'unsuspend, abort, clear',
    )
    assert m.state == 'Execute' and m.counts['refused'] == 1


def test_the_numbers_are_packtags():
    for name, number in STATE_NUMBERS.items():
        if name != 'Undefined':
            assert packml.STATE_NUMBERS[name] == number
    assert packml.COMMAND_NUMBERS == COMMAND_NUMBERS


def test_acting_states_complete_into_their_wait_states():
    done = {
        'Resetting': 'Idle',
        'Starting': 'Execute',
        'Holding': 'Held',
        'Unholding': 'Execute',
        'Suspending': 'Suspended',
        'Unsuspending': 'Execute',
        'Completing': 'Complete',
        'Stopping': 'Stopped',
        'Aborting': 'Aborted',
        'Clearing': 'Stopped',
    }
    for acting, wait in done.items():
        m = _in(acting)
        m.update(Conditions(), 5)
        assert m.state == wait, acting
        assert m.transitions[0].cause == 'state complete' and m.transitions[0].t_ns == 5
    # work not done keeps them acting
    for acting, c in (
        ('Aborting', Conditions(estop=True, disks_down=False)),
        ('Clearing', Conditions(estop=True)),
        ('Stopping', Conditions(empty=False)),
        ('Resetting', Conditions(hold_cause='jam')),
    ):
        m = _in(acting)
        m.update(c, 0)
        assert m.state == acting


def test_automatic_mode_starts_and_recovers_but_never_undoes_an_operator():
    m = PackMLMachine(auto=True)
    m.update(Conditions(), 0)
    assert [t.state for t in m.take_transitions()] == ['Resetting', 'Idle', 'Starting', 'Execute']
    # its own hold clears with its cause; an operator's does not
    m.update(Conditions(hold_cause='watchdog'), 1)
    assert m.state == 'Held' and m.cause == 'state complete'
    m.update(Conditions(), 2)
    assert m.state == 'Execute'
    assert m.command('hold', 3)[0]
    m.update(Conditions(), 4)
    assert m.state == 'Held'
    assert m.command('unhold', 5)[0]
    m.update(Conditions(), 6)
    assert m.state == 'Execute'
    # an operator's stop stays stopped
    assert m.command('stop', 7)[0]
    m.update(Conditions(), 8)
    assert m.state == 'Stopped'
    # an e-stop aborts from anywhere; released, automatic mode clears, resets and starts
    m.update(Conditions(estop=True, disks_down=False), 9)
    assert m.state == 'Aborting'
    m.update(Conditions(estop=True), 10)
    assert m.state == 'Aborted'
    m.update(Conditions(), 11)
    assert m.state == 'Execute'
    off = PackMLMachine(auto=False)
    off.update(Conditions(), 0)
    assert off.state == 'Stopped' and not off.infeed_open


def make_cell(**over) -> Cell:
    values = {
        'arrival': 'none',
        'induct_x': -1.5,
        'scanner_x': -1.0,
        'photo_eyes.names': ['pe_scan', 'pe_divert', 'pe_exit'],
        'photo_eyes.x': [-1.0, -0.3, 1.6],
        'exit_x': 2.0,
        'popup_stroke_time': 0.1,
        **over,
    }
    return Cell(CellParams.from_values(values))


def _states(cell):
    return [(t.t_ns, t.state, t.cause) for t in cell.packml.take_transitions()]


def test_an_estop_aborts_until_the_disks_are_down_and_a_clear_releases_it():
    cell = make_cell(packml_auto=False)
    assert cell.packml.state == 'Stopped'
    assert cell.packml_command('reset')[0] and cell.packml_command('start')[0]
    assert cell.packml.state == 'Execute'
    cell.popup(True)
    cell.advance(200)  # the disks are up
    _states(cell)
    cell.engage_estop()
    cell.update_packml()
    assert cell.packml.state == 'Aborting'
    cell.advance(150)
    (aborting, aborted) = _states(cell)
    assert aborting[1:] == ('Aborting', 'e-stop') and aborted[1] == 'Aborted'
    # the disks drop over popup_stroke_time (0.1 s); the state follows at the next boundary
    assert 0.1 <= (aborted[0] - aborting[0]) * 1e-9 <= 0.1 + 0.002
    assert cell.packml_command('start')[0] is False and cell.estop
    assert cell.packml_command('clear')[0]
    assert not cell.estop and cell.packml.state == 'Stopped'


def test_a_jam_and_a_watchdog_trip_hold_and_automatic_mode_unholds_when_they_clear():
    # contact: jam, the rule under which a touch of the side wall is a jam at once
    cell = make_cell(disk_field_length=0.3, chute_margin=0.0, popup_stroke_time=0.0, contact='jam')
    assert [s for _, s, _ in _states(cell)] == ['Resetting', 'Idle', 'Starting', 'Execute']
    cell.popup(True)
    cell.induct(ParcelSpec(0.4, 0.2, 5.0, 0.0, 0.2, 'W'))  # into the side wall: a jam
    cell.advance(3000)
    assert cell.faults == ['jam'] and cell.packml.state == 'Held'
    assert [s for _, s, _ in _states(cell)] == ['Holding', 'Held']
    assert cell.packml.cause == 'state complete'
    cell.reset()  # the jam taken off
    cell.advance(1)
    assert cell.packml.state == 'Execute'
    cell.heartbeat(1)
    cell.advance(400)  # 0.4 s without a heartbeat > watchdog_timeout 0.3 s
    assert cell.watchdog_tripped and cell.packml.state == 'Held'
    cell.heartbeat(2)
    cell.advance(1)
    assert cell.packml.state == 'Execute'


def test_starved_and_blocked_suspend_and_parcels_or_an_empty_chute_unsuspend():
    cell = make_cell(packml_starved_s=0.5, packml_blocked_s=0.2)
    _states(cell)
    cell.advance(499)
    assert cell.packml.state == 'Execute'
    cell.advance(1)
    assert cell.packml.state == 'Suspended'
    assert [(s, c) for _, s, c in _states(cell)] == [
        ('Suspending', 'starved'),
        ('Suspended', 'state complete'),
    ]
    cell.induct(ParcelSpec(0.4, 0.3, 4.0, label='P'))  # the infeed stays open: it comes in
    cell.advance(1)
    assert cell.n_inducted == 1 and cell.packml.state == 'Execute'
    cell.advance(3000)  # out at the straight end, and starved again
    assert cell.outcome_counts['straight'] == 1 and cell.packml.state == 'Suspended'
    cell = make_cell(packml_starved_s=0.0, packml_blocked_s=0.2)
    cell.advance(10_000)
    assert cell.packml.state == 'Execute'  # never starved with packml_starved_s 0
    _states(cell)
    apply_fault(cell, 'chute_full', {'chute': 'left'})
    cell.advance(199)
    assert cell.packml.state == 'Execute'
    cell.advance(1)
    assert cell.packml.state == 'Suspended' and cell.packml.transitions[0].cause == 'blocked'
    apply_fault(cell, 'chute_full', {'chute': 'left', 'full': 'false'})
    cell.advance(1)
    assert cell.packml.state == 'Execute'


def test_stop_closes_the_infeed_and_waits_for_the_cell_to_run_empty():
    cell = make_cell(arrival='gap', arrival_gap=[1.0, 1.0])
    cell.advance(1000)
    n, on = cell.n_inducted, cell.n_parcels
    assert on > 0
    assert cell.packml_command('stop') == (True, 'stop: Stopping')
    cell.advance(1)
    assert cell.packml.state == 'Stopping'
    cell.advance(5000)
    assert cell.packml.state == 'Stopped' and cell.n_parcels == 0 and cell.n_inducted == n
    cell.advance(5000)
    assert cell.packml.state == 'Stopped' and cell.n_inducted == n  # automatic mode waits
    assert cell.packml_command('reset')[0] and cell.packml_command('start')[0]
    cell.advance(1000)
    assert cell.packml.state == 'Execute' and cell.n_inducted > n


def test_a_refused_command_changes_nothing_in_the_cell():
    cell = make_cell(packml_auto=False)
    cell.advance(10)
    before = (cell.packml.state, cell.estop, cell.k, cell.n_inducted)
    for command in ('start', 'hold', 'unhold', 'suspend', 'unsuspend', 'clear', 'stop'):
        ok, text = cell.packml_command(command)
        assert not ok and 'Stopped does not take' in text
    assert (cell.packml.state, cell.estop, cell.k, cell.n_inducted) == before
    assert cell.packml.counts['refused'] == 7
    # abort is the e-stop
    assert cell.packml_command('abort')[0] and cell.estop and cell.packml.state == 'Aborted'
    assert math.isclose(cell.belt_velocity, 0.0)


def _logic_and_plant(**kw):
    from sorter_control.logic import ControllerConfig, SorterLogic
    from sorter_control.plant_stub import PlantStub

    cfg = ControllerConfig(routing_rules=('L*=left', 'R*=right'), **kw)
    return SorterLogic(cfg), PlantStub(cfg)


def test_the_controller_sorts_only_in_execute_and_resumes_the_cell_on_its_reset():
    from sorter_control.plant_stub import run_cell

    logic, plant = _logic_and_plant()
    g = logic.min_gap(0.4)['worst'] + 0.05
    plant.add_stream([('L1', 0.4, 0.0), ('R1', 0.4, g), ('L2', 0.4, g)])
    plant.packml = PackMLMachine(auto=False)  # a cell that waits for its commands
    for command in ('reset', 'start'):
        assert plant.packml.command(command, 0)[0]
        plant.packml.update(Conditions(), 0)
    assert plant.packml.state == 'Execute'

    def hold_after_the_first(plant, logic):
        if plant.packml.state == 'Execute' and any(c.label == 'L1' for c in run.confirmations):
            if not held:
                plant.packml.command('hold', round(plant.t * 1e9))
                plant.packml.update(Conditions(), round(plant.t * 1e9))
                held.append(plant.t)

    from sorter_control.plant_stub import CellRun

    run, held = CellRun(), []
    run_cell(plant, logic, 14.0, run, on_scan=hold_after_the_first)
    results = {c.label: (c.destination_reached, c.result) for c in run.confirmations}
    assert results['L1'] == ('left', 'sorted')
    # held: the next two go straight, flagged, and no pop-up is raised for them
    assert results['R1'] == ('straight', 'not_executing')
    assert results['L2'] == ('straight', 'not_executing')
    assert logic.counts['not_executing'] == 2 and logic.counts['mis_sorted'] == 0
    assert not [c for c in run.commands if c[0] > held[0] and c[1] == 'popup' and c[2]]
    assert plant.packml.state == 'Held'
    # the operator's reset walks the cell back: unhold (Held), then it is in Execute
    logic.request_reset()
    run_cell(plant, logic, 14.5, run)
    assert plant.packml.state == 'Execute'
    assert [c[2] for c in run.commands if c[1] == 'packml'] == ['unhold']
    # from Stopped: reset, then start
    plant.packml.command('stop', round(plant.t * 1e9))
    plant.packml.update(Conditions(), round(plant.t * 1e9))
    assert plant.packml.state == 'Stopped'
    run_cell(plant, logic, 15.0, run)
    assert plant.packml.state == 'Stopped'  # nobody asked: it stays stopped
    logic.request_reset()
    run_cell(plant, logic, 15.5, run)
    assert plant.packml.state == 'Execute'
    assert [c[2] for c in run.commands if c[1] == 'packml'] == ['unhold', 'reset', 'start']
    plant.add_stream([('R9', 0.4, 0.0)])
    run_cell(plant, logic, 22.0, run)
    assert run.confirmations[-1].label == 'R9'
    assert run.confirmations[-1].destination_reached == 'right'


# ----------------------------------------------------------------------------- the faces


def _sim(ros, **over):
    from rclpy.parameter import Parameter
    from test_sim_node import SHORT_CELL

    from sorter_sim.frontends.node import SimNode

    node = SimNode(
        context=ros.context,
        parameter_overrides=[Parameter(k, value=v) for k, v in {**SHORT_CELL, **over}.items()],
    )
    return ros.add(node)


@pytest.mark.ros
def test_the_state_is_latched_on_ros_and_each_command_is_a_trigger_service(ros):
    from rclpy.qos import QoSProfile
    from std_msgs.msg import String
    from std_srvs.srv import SetBool, Trigger

    from sorter_ros.interface import SENSOR_QOS

    sim = _sim(ros, packml_auto=False)
    sim.advance(10)
    probe = ros.make_node('packml_probe')
    seen = []
    # subscribed after the cell published: the latched state still arrives
    # (latched as the cell's QoS, but deep enough to keep every transition a burst brings)
    qos = QoSProfile(
        depth=50, reliability=SENSOR_QOS.reliability, durability=SENSOR_QOS.durability
    )
    probe.create_subscription(String, 'status/packml', lambda m: seen.append(m.data), qos)
    clients = {c: probe.create_client(Trigger, f'packml/{c}') for c in packml.COMMANDS}
    estop = probe.create_client(SetBool, 'estop')
    reset = probe.create_client(Trigger, 'reset')
    ros.spin_until(lambda: seen == ['Stopped'], 10.0, 'the latched state')
    ros.spin_until(lambda: all(c.service_is_ready() for c in clients.values()), 10.0, 'services')

    def call(command):
        return ros.call(clients[command], Trigger.Request())

    r = call('start')
    assert not r.success
    assert r.message == 'refused: Stopped does not take start: PackML takes it in Idle only'
    assert call('reset').success and call('start').success
    ros.spin_until(lambda: seen[-1] == 'Execute', 5.0, 'Execute')
    assert seen == ['Stopped', 'Resetting', 'Idle', 'Starting', 'Execute']
    r = call('hold')
    assert r.success and r.message == 'hold: Holding (now Held)'
    r = call('suspend')
    assert not r.success and 'Held does not take suspend' in r.message
    assert call('unhold').success and call('suspend').success
    assert call('unsuspend').success
    ros.spin_until(lambda: seen[-1] == 'Execute', 5.0, 'Execute again')
    # the cell's own e-stop service aborts; its reset releases the e-stop, clear is asked
    assert ros.call(estop, SetBool.Request(data=True)).success
    sim.advance(150)  # the disks are down
    ros.spin_until(lambda: seen[-1] == 'Aborted', 5.0, 'Aborted')
    assert ros.call(reset, Trigger.Request()).success
    sim.advance(1)
    assert sim.cell.packml.state == 'Aborted'  # not automatic: it waits for clear
    assert call('clear').success and sim.cell.packml.state == 'Stopped'
    assert call('abort').success and sim.cell.estop
    ros.spin_until(lambda: seen[-1] in ('Aborting', 'Aborted'), 5.0, 'abort')
    diag = {kv.key: kv.value for kv in _diagnostics(ros, sim).values}
    assert diag['packml_refused'] == '2' and diag['packml_state'] in ('Aborting', 'Aborted')


def _diagnostics(ros, sim):
    from diagnostic_msgs.msg import DiagnosticArray

    probe = ros.make_node('packml_diag_probe')
    got = []
    probe.create_subscription(DiagnosticArray, '/diagnostics', got.append, 10)
    ros.spin_until(lambda: probe.count_publishers('/diagnostics') > 0, 5.0, 'diagnostics')
    sim.diagnostics.publish()
    ros.spin_until(lambda: got, 5.0, 'a diagnostics message')
    return got[-1].status[0]


@pytest.mark.ros
def test_packml_and_machinery_over_opc_ua_with_asyncua_and_the_register_over_modbus(ros):
    from asyncua import ua
    from asyncua.sync import Client as OpcClient
    from pymodbus.client import ModbusTcpClient
    from ros_harness import free_port

    from sorter_sim.model.io_map import by_name, io_map

    sim = _sim(ros, modbus_port=free_port(), opcua_port=free_port())
    sim.advance(1)
    client = OpcClient(sim.fieldbus.opcua_endpoint, timeout=10)
    client.connect()
    try:
        idx = client.get_namespace_index('urn:sorter_cell')
        cell = client.nodes.objects.get_child([f'{idx}:cell'])
        ident = cell.get_child([f'{idx}:Identification'])
        values = {
            n: ident.get_child([f'{idx}:{n}']).read_value()
            for n in ('Manufacturer', 'Model', 'SerialNumber', 'SoftwareRevision')
        }
        assert values['Manufacturer'].Text == 'sorter_cell'
        assert 'pivot diverter' in values['Model'].Text
        assert values['SerialNumber'] == 'cell' and values['SoftwareRevision']
        pm = cell.get_child([f'{idx}:PackML'])
        current = pm.get_child([f'{idx}:CurrentState'])
        number = pm.get_child([f'{idx}:StateCurrent'])
        assert current.read_value().Text == 'Execute' and number.read_value() == 6
        pm.call_method(f'{idx}:Hold')
        sim.advance(1)  # applied at the next period, as a PLC's write
        assert sim.cell.packml.state == 'Held'
        assert current.read_value().Text == 'Held' and number.read_value() == 11
        with pytest.raises(ua.UaStatusCodeError) as refused:
            pm.call_method(f'{idx}:Start')
        assert refused.value.code == ua.StatusCodes.BadInvalidState
        sim.advance(1)
        assert sim.cell.packml.state == 'Held'  # nothing changed
        with pytest.raises(ua.UaStatusCodeError) as extra:
            pm.call_method(f'{idx}:Unhold', ua.Variant(1, ua.VariantType.Int32))
        assert extra.value.code == ua.StatusCodes.BadTooManyArguments
        pm.call_method(f'{idx}:Unhold')
        sim.advance(1)
        assert sim.cell.packml.state == 'Execute'
    finally:
        client.disconnect()
    # the same over Modbus: StateCurrent in IR 7, CntrlCmd in HR 2 (1..9, else exception 3)
    signals = by_name(io_map(sim.cell.sensor_names))
    mb = ModbusTcpClient('127.0.0.1', port=sim.fieldbus.modbus_port, timeout=5, retries=0)
    assert mb.connect()
    try:
        state, command = signals['packml.state'], signals['packml.command']
        assert mb.read_input_registers(state.address, count=1).registers == [6]
        assert mb.write_register(command.address, 4).isError() is False  # hold
        sim.advance(1)
        assert mb.read_input_registers(state.address, count=1).registers == [11]
        bad = mb.write_register(command.address, 10)
        assert bad.isError() and bad.exception_code == 3
        assert mb.write_register(command.address, 2).isError() is False  # start: refused
        sim.advance(1)
        assert sim.cell.packml.state == 'Held' and sim.fieldbus_bridge.refused == 1
        assert mb.write_register(command.address, 5).isError() is False  # unhold
        sim.advance(1)
        assert mb.read_input_registers(state.address, count=1).registers == [6]
    finally:
        mb.close()


@pytest.mark.parametrize(
    'stream',
    [
        {'arrival': 'rate', 'arrival_rate': 1.5},  # starved and back, at each arrival
        {'arrival': 'gap', 'arrival_count': 5},  # a batch that completes
    ],
    ids=['rate', 'batch'],
)
def test_the_state_moves_at_the_same_period_however_time_is_sliced(stream):
    """Per period, in slices of 7 or of 1000: the same events and the same transitions."""
    runs = []
    for step in (1, 7, 1000):
        cell = Cell(
            CellParams.defaults().with_changes({**stream, 'packml_starved_s': 0.3}, runtime=False)
        )
        events = []
        for k_stop, up in ((3000, True), (9002, False), (15000, None)):
            while cell.k < k_stop:
                events += cell.advance(min(step, k_stop - cell.k))
            if up is not None:
                cell.popup(up)
        runs.append((events, [(t.t_ns, t.state, t.cause) for t in cell.packml.transitions]))
    assert runs[0] == runs[1] == runs[2]
    states = [s for _, s, _ in runs[0][1]]
    assert ('Suspended' in states) if stream['arrival'] == 'rate' else states[-1] == 'Complete'
