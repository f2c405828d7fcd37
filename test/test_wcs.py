"""
The line's warehouse side (``sorter_control.wcs``) and the line demo end to end.

The logic is checked on its own (the plan's rules, the routing it writes, the
tracking queues, every disposition code); the demo runs a three-station line with
its controllers and the warehouse node over DDS.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from sorter_cell.testing.domains import DomainClaim, campaign_domains
from sorter_control.wcs import LineWcs, PlanError

CHUTES = [('S01L', 'S01R'), ('S02L', 'S02R'), ('S03L', 'S03R')]


def wcs_with_plan() -> LineWcs:
    w = LineWcs(CHUTES)
    w.set_plan('v1', [('D1', 'S01L'), ('D2', 'S02R'), ('D3', 'S03L'), ('R', 'straight_end')])
    return w


@pytest.mark.parametrize(
    'entries, message',
    [
        ([('D1', 'S09L')], "no chute 'S09L'"),
        ([('D1', 'S01L'), ('D1', 'S02L')], "'D1' is in two chutes"),
        ([('', 'S01L')], 'a destination must be'),
        ([('D=1', 'S01L')], 'without "="'),
        ([('D1', 'S01L')] * 10_001, 'at most 10000'),
    ],
)
def test_a_bad_plan_is_refused_and_the_old_one_stays(entries, message):
    w = wcs_with_plan()
    with pytest.raises(PlanError, match=message):
        w.set_plan('v2', entries)
    assert w.version == 'v1' and w.plan['D2'] == 'S02R'


def test_requests_become_rules_at_the_station_of_their_chute_and_move_with_the_plan():
    w = wcs_with_plan()
    assert w.request('P1', 'D2') == [(1, 'P1', 'right')]
    assert w.request('P2', 'D3') == [(2, 'P2', 'left')]
    assert w.request('P3', 'R') == []  # the straight end: no station diverts it
    assert w.request('P4', 'nowhere') == []
    # a label outside the labels' grammar would be refused by the stations' routing
    for bad in ('P 5', 'P*', 'x' * 65):
        with pytest.raises(PlanError, match='a label is'):
            w.request(bad, 'D2')
    # a new plan while P1, P2 are on their way: their rules move, at once
    updates = w.set_plan('v2', [('D2', 'S01R'), ('D3', 'S03R')])
    assert sorted(updates) == [(0, 'P1', 'right'), (1, 'P1', ''), (2, 'P2', 'right')]
    # a full chute sends its parcels on; emptied, they are diverted again
    assert w.chute_full('S01R', True) == [(0, 'P1', '')]
    assert w.chute_full('S01R', False) == [(0, 'P1', 'right')]
    # a disposed parcel's rule goes
    w.exited('P1', 'S01R', 0, 5.0)
    assert w.rebuild() == [(0, 'P1', '')]


def test_tracking_hands_labels_downstream_first_in_first_out():
    w = wcs_with_plan()
    w.confirmed(0, 'A', 'straight', 'sorted')
    w.confirmed(0, 'B', 'left', 'sorted')  # diverted at station 1: not passed on
    w.confirmed(0, '', 'straight', 'rejected')  # a no-read keeps its place
    w.confirmed(0, 'C', 'straight', 'rejected')
    assert [w.arriving(1) for _ in range(4)] == ['A', None, 'C', None]
    w.confirmed(2, 'A', 'straight', 'sorted')  # the last station: no queue after it
    assert all(not q for q in w.queues)


def test_a_station_that_runs_its_time_again_gets_the_labels_it_was_given_and_nothing_shifts():
    """A segment restarted from t = 0 says its edges and confirmations again (replayed)."""
    w = wcs_with_plan()
    for label in 'ABC':
        w.confirmed(0, label, 'straight', 'sorted')
    assert [w.arriving(1, t) for t in (10, 20)] == ['A', 'B']
    w.confirmed(1, 'A', 'straight', 'sorted')
    # station 2 restarts: its time runs from 0 again, the parcels it held come back
    assert [w.arriving(1, t) for t in (10, 20)] == ['A', 'B']
    w.confirmed(1, 'A', 'straight', 'sorted')  # said again: A is in station 3's queue once
    assert w.arriving(1, 30) == 'C'  # past the time it had reached: the queue goes on
    w.confirmed(1, 'B', 'straight', 'sorted')
    assert [w.arriving(2, t) for t in (40, 50, 60)] == ['A', 'B', None]
    assert w.n_replayed == 3


def test_every_disposition_code():
    w = wcs_with_plan()
    for label, dest in (
        ('OK', 'D2'),
        ('MIS', 'D2'),
        ('GAP', 'D3'),
        ('FULL', 'D1'),
        ('JAM', 'D1'),
        ('LOST', 'D3'),
        ('NOREAD', 'D3'),
    ):
        w.request(label, dest)
    assert w.exited('OK', 'S02R', 1, 1.0).code == 'sorted'
    assert w.exited('MIS', 'S02L', 1, 1.0).code == 'mis_sorted'
    w.confirmed(2, 'GAP', 'straight', 'gap_too_short')
    assert w.exited('GAP', 'straight_end', 2, 1.0).code == 'gap_too_short'
    w.chute_full('S01L', True)
    w.confirmed(0, 'FULL', 'straight', 'sorted')
    w.chute_full('S01L', False)  # emptied since: the reason stays
    assert w.exited('FULL', 'straight_end', 2, 1.0).code == 'chute_full'
    assert w.exited('JAM', 'jammed', 0, 1.0).code == 'jammed'
    assert w.exited('JAM2', 'jammed', 0, 1.0, 'chute full').code == 'chute_full'
    assert w.exited('LOST', 'straight_end', 2, 1.0).code == 'lost'
    w.confirmed(2, 'NOREAD', 'straight', 'rejected')
    assert w.exited('NOREAD', 'straight_end', 2, 1.0).code == 'no_read'
    assert w.exited('NEVER-ASKED', 'straight_end', 2, 1.0).code == 'no_destination'
    assert w.exited('', 'straight_end', 2, 1.0).code == 'no_read'
    # a parcel nobody asked for that still reached a chute was sent somewhere wrong
    d = w.exited('OK2', 'S03L', 2, 2.5)
    assert (d.code, d.chute, d.station, d.t) == ('mis_sorted', 'S03L', 'S03', 2.5)


class _LineDemo:
    """A line demo (three stations over 25 simulated seconds unless told), started at once."""

    def __init__(self, tmp_path, executor, *, record=False, domain=None, run=None, stations=3):
        self.path = tmp_path / f'{executor}.jsonl'
        self.bag = tmp_path / f'{executor}.mcap' if record else None
        env = dict(os.environ) if domain is None else dict(os.environ, ROS_DOMAIN_ID=str(domain))
        cmd = [sys.executable, '-m', 'sorter_cell', 'demo', '--stations', str(stations)]
        cmd += [*(run or ('--sim-time', '25')), '--json', '--executor', executor]
        cmd += ['--dispositions', str(self.path)]
        if record:
            cmd += ['--record', str(self.bag)]
        self.proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
        )

    def result(self):
        """Return the demo's summary and disposition records once it has ended."""
        try:
            out, err = self.proc.communicate(timeout=240)
        finally:
            self.stop()
        assert self.proc.returncode == 0, out[-2000:] + err[-2000:]
        s = json.loads(out.strip().splitlines()[-1])
        return s, [json.loads(line) for line in self.path.read_text().splitlines()]

    def stop(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


@pytest.fixture(scope='module')
def events_line(tmp_path_factory):
    """Return the recorded line demo under the events executor: summary, records, bag."""
    run = _LineDemo(tmp_path_factory.mktemp('events_line'), 'events', record=True)
    s, records = run.result()
    return s, records, run.bag


@pytest.mark.ros
def test_the_line_demo_sorts_through_three_stations_with_their_plcs_and_the_wcs(events_line):
    from collections import Counter

    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    s, records, bag = events_line
    # the recording holds the warehouse's side too: every disposition, and where each left
    topics = Counter()
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, _ in reader.messages():
            topics[conn.topic] += 1
    assert topics['/wcs/dispositions'] == topics['/line/exits'] == len(records)
    assert topics['/wcs/sort_plan/active'] == 1
    assert s['stations'] == 3 and s['mis_sorted'] == 0 and s['jams'] == 0
    assert s['executor'] == 'EventsExecutor'
    # the line runs empty after the timed span: every parcel inducted has its disposition
    assert s['in_cell_at_end'] == 0
    assert sum(s['dispositions'].values()) == s['inducted'] == len(records) > 10
    assert s['dispositions'].get('sorted', 0) >= 10
    assert set(s['exits']) <= {'S01L', 'S01R', 'S02L', 'S02R', 'S03L', 'S03R', 'straight_end'}
    assert sum(1 for k in s['exits'] if k.startswith('S03')) >= 1  # tracked two stations on
    assert all(
        set(r) >= {'label', 'code', 'destination', 'chute', 'station', 't'} for r in records
    )
    # each sorted parcel reached the chute its destination has in the plan (D01 -> S01L, ...)
    sorted_ = [r for r in records if r['code'] == 'sorted']
    chutes = ['S01L', 'S01R', 'S02L', 'S02R', 'S03L', 'S03R']
    assert all(r['chute'] == chutes[int(r['destination'][1:]) - 1] for r in sorted_)
    assert all(r['station'] == r['chute'][:3] for r in sorted_)


@pytest.mark.ros
def test_the_line_sorts_every_parcel_alike_under_either_executor(tmp_path):
    """
    The same batch under rclpy's events executor and its single-threaded one: the same.

    A line in one process runs in lock-step on the run loop, so the executor only
    changes how the callbacks of a slice are served, not when: every parcel leaves
    by the same chute at the same station at the same simulated time. The runs go side
    by side (the single-threaded one, about ten times the slower, on a ROS domain of
    its own, claimed as a campaign claims one).
    """
    batch = ('--parcels', '6')
    with DomainClaim(campaign_domains()) as domain:
        runs = {
            'events': _LineDemo(tmp_path, 'events', run=batch, stations=2),
            'single': _LineDemo(tmp_path, 'single', run=batch, stations=2, domain=domain),
        }
        try:
            (s_events, events), (s_single, single) = (r.result() for r in runs.values())
        finally:
            for run in runs.values():
                run.stop()
    assert s_events['executor'] == 'EventsExecutor'
    assert s_single['executor'] == 'SingleThreadedExecutor'
    assert len(events) == 6 and {r['code'] for r in events} == {'sorted'}
    assert any(r['station'] == 'S02' for r in events)  # tracked to the second station
    key = lambda r: (r['label'], r['code'], r['chute'], r['station'], r['t'])  # noqa: E731
    assert sorted(map(key, events)) == sorted(map(key, single))


@pytest.mark.ros
def test_the_wcs_node_refuses_a_bad_plan_in_one_message_and_keeps_the_good_one(ros):
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    from rclpy.parameter import Parameter
    from std_msgs.msg import String

    from sorter_control.wcs_node import WcsNode
    from sorter_ros.interface import EVENT_QOS, SENSOR_QOS

    node = ros.add(
        WcsNode(context=ros.context, parameter_overrides=[Parameter('stations', value=2)])
    )
    probe = ros.make_node('wms')
    refused, active, routing = [], [], []
    probe.create_subscription(String, 'wcs/sort_plan/refused', refused.append, EVENT_QOS)
    probe.create_subscription(DiagnosticStatus, 'wcs/sort_plan/active', active.append, SENSOR_QOS)
    probe.create_subscription(KeyValue, 'S02/routing/updates', routing.append, EVENT_QOS)
    plan = probe.create_publisher(DiagnosticStatus, 'wcs/sort_plan', EVENT_QOS)
    req = probe.create_publisher(KeyValue, 'wcs/requests', EVENT_QOS)
    ros.spin_until(lambda: plan.get_subscription_count() and req.get_subscription_count(), 10.0)
    ros.spin_until(lambda: len(node.unmatched()) < 7, 10.0)
    # no station yet: every topic a station shares with it is named, but the one the
    # probe reads (a line opens its infeed once the list is empty)
    assert sorted(node.unmatched()) == [
        '/S01/routing/updates',
        '/S01/sort/confirmations',
        '/S02/scanner/label',
        '/S02/sensors/edges',
        '/S02/sort/confirmations',
        '/line/exits',
    ]
    plan.publish(DiagnosticStatus(name='v1', values=[KeyValue(key='D1', value='S02R')]))
    ros.spin_until(lambda: active, 5.0)
    plan.publish(DiagnosticStatus(name='v2', values=[KeyValue(key='D1', value='S07L')]))
    plan.publish(
        DiagnosticStatus(
            name='v3', values=[KeyValue(key='D1', value='S01L'), KeyValue(key='D1', value='S02L')]
        )
    )
    ros.spin_until(lambda: len(refused) == 2, 5.0)
    assert "no chute 'S07L'" in refused[0].data and 'in two chutes' in refused[1].data
    assert node.wcs.version == 'v1' and node.n_refused == 2
    req.publish(KeyValue(key='P1', value='D1'))
    ros.spin_until(lambda: any(m.key == 'P1' for m in routing), 5.0)
    assert [(m.key, m.value) for m in routing if m.key == 'P1'] == [('P1', 'right')]


def test_a_name_of_a_megabyte_is_refused_naming_its_size_and_the_limit():
    w = wcs_with_plan()
    huge = 'D' * 1_000_000
    for call, args in (
        (w.set_plan, (huge, [('D1', 'S01L')])),
        (w.set_plan, ('v2', [(huge, 'S01L')])),
        (w.set_plan, ('v2', [('D1', huge)])),
        (w.request, ('P1', huge)),
    ):
        with pytest.raises(PlanError) as exc:
            call(*args)
        said = str(exc.value)
        assert 'is 1000000 characters, more than the 64 allowed' in said and len(said) < 200
    assert w.version == 'v1' and 'P1' not in w.requests


def _wcs_and_wms(ros, stations: int):
    """
    Start a warehouse node of ``stations`` and a probe ``wms`` writing requests to it.

    Returns the node, the probe, the requests' publisher and the answers as they come,
    once the two are matched both ways.
    """
    from diagnostic_msgs.msg import KeyValue
    from rclpy.parameter import Parameter

    from sorter_control.wcs_node import REQUEST_QOS, WcsNode

    node = ros.add(
        WcsNode(context=ros.context, parameter_overrides=[Parameter('stations', value=stations)])
    )
    probe = ros.make_node('wms')
    answers = []
    probe.create_subscription(KeyValue, 'wcs/requests/answers', answers.append, REQUEST_QOS)
    req = probe.create_publisher(KeyValue, 'wcs/requests', REQUEST_QOS)
    ros.spin_until(lambda: req.get_subscription_count(), 10.0)
    ros.spin_until(lambda: node._pub_answers.get_subscription_count(), 10.0)
    return node, probe, req, answers


def test_a_flood_of_refusals_is_logged_cut_short_once_a_second(ros, capfd):
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    from std_msgs.msg import String

    from sorter_control.wcs_node import MAX_REFUSAL, RefusalLog
    from sorter_ros.interface import EVENT_QOS

    node, probe, req, answers = _wcs_and_wms(ros, 2)
    refused = []
    probe.create_subscription(String, 'wcs/sort_plan/refused', refused.append, EVENT_QOS)
    plan = probe.create_publisher(DiagnosticStatus, 'wcs/sort_plan', EVENT_QOS)
    ros.spin_until(lambda: plan.get_subscription_count(), 10.0)
    capfd.readouterr()
    # the log's clock stands still: every refusal after the first falls in its second
    node.log_refusal = RefusalLog(node.get_logger().warning, clock=lambda: 0.0)
    plan.publish(DiagnosticStatus(name='v' * 1_000_000, values=[KeyValue(key='D1', value='S01L')]))
    for i in range(300):
        req.publish(KeyValue(key=f'P{i}', value='D' * 100_000))
    ros.spin_until(lambda: len(answers) == 300 and refused, 60.0)
    assert node.n_refused == 301
    assert '1000000 characters, more than the 64 allowed' in refused[0].data
    assert (
        all(len(a.value) <= MAX_REFUSAL for a in answers) and len(refused[0].data) <= MAX_REFUSAL
    )
    assert '100000 characters, more than the 64 allowed' in answers[-1].value
    logged = [x for x in capfd.readouterr().err.splitlines() if 'refused' in x]
    assert len(logged) == 1 and len(logged[0]) < MAX_REFUSAL + 200, logged
    # a second later the next line counts the refusals not logged
    lines = []
    log = RefusalLog(lines.append, clock=iter([0.0, 0.5, 0.7, 1.2]).__next__)
    for k in range(4):
        log(f'refusal {k}')
    assert lines == ['refusal 0', 'refusal 3 (2 more refused since the last line)']


def test_the_wcs_node_options_are_fixed_once_it_runs_and_say_so(ros):
    from rclpy.parameter import Parameter
    from ros_harness import refused_at_run_time

    from sorter_control.wcs_node import WcsNode

    wcs = ros.add(
        WcsNode(context=ros.context, parameter_overrides=[Parameter('stations', value=2)])
    )
    reasons = refused_at_run_time(
        ros, wcs, {'stations': 0, 'chute_names': ['a', 'b'], 'use_sim_time': True}
    )
    assert all(r and 'read-only' in r for r in reasons.values()), reasons
    assert wcs.get_parameter('stations').value == 2
    assert not wcs.get_parameter('use_sim_time').value
    assert 'read at start-up' in wcs.describe_parameter('chute_names').description


def test_the_line_demo_refuses_bad_options_in_one_line(capsys, tmp_path):
    from sorter_cell.cli import main

    assert main(['demo', '--stations', '3', '--io', 'modbus']) == 2
    assert "the line's controllers talk ROS" in capsys.readouterr().err
    for extra, message in (
        (['--rtf', '0'], '--rtf must be a number in [0.01, 100]'),
        (['--foxglove', '70000'], '--foxglove PORT must be in'),
        (['--sim-time', '-1'], '--sim-time must be in (0, 3600]'),
        (['--dispositions', str(tmp_path)], '--dispositions'),
        (['--sync', 'barrier'], '--sync is how segments keep time together'),
        (['--restart', '1'], '--restart starts a segment process again'),
        (['--segments', '3', '--restart', '-1'], '--restart must be an integer in [0, 100]'),
    ):
        assert main(['demo', '--stations', '3', *extra]) == 2
        assert message in capsys.readouterr().err
    assert main(['demo', '--stations', '0']) == 2
    assert '--stations must be in [1, 64]' in capsys.readouterr().err
    for extra in (['--executor', 'single'], ['--sync', 'barrier'], ['--restart', '2']):
        assert main(['demo', *extra]) == 2
        assert "the line's: use them with --stations N > 1" in capsys.readouterr().err


@pytest.mark.ros
def test_the_warehouse_over_opc_ua_is_the_warehouse_over_ros(ros):
    """An asyncua client sets the plan, asks a destination and subscribes to dispositions."""
    import time

    from asyncua import ua
    from asyncua.sync import Client
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    from fieldbus_helpers import refused_login
    from rclpy.parameter import Parameter
    from ros_harness import free_port

    from sorter_control.wcs_node import WcsNode
    from sorter_ros.interface import EVENT_QOS, SENSOR_QOS

    node = ros.add(
        WcsNode(
            context=ros.context,
            parameter_overrides=[
                Parameter('stations', value=2),
                Parameter('opcua_port', value=free_port()),
            ],
        )
    )
    probe = ros.make_node('scada')
    active, routing, disp = [], [], []
    probe.create_subscription(DiagnosticStatus, 'wcs/sort_plan/active', active.append, SENSOR_QOS)
    probe.create_subscription(KeyValue, 'S02/routing/updates', routing.append, EVENT_QOS)
    probe.create_subscription(DiagnosticStatus, 'wcs/dispositions', disp.append, EVENT_QOS)
    plan = probe.create_publisher(DiagnosticStatus, 'wcs/sort_plan', EVENT_QOS)
    exits = probe.create_publisher(DiagnosticStatus, 'line/exits', EVENT_QOS)
    ros.spin_until(lambda: plan.get_subscription_count() and exits.get_subscription_count(), 10.0)

    class Seen:
        def __init__(self):
            self.values = []

        def datachange_notification(self, node, val, data):
            self.values.append(val)

    seen = Seen()
    client = Client(node.opcua.endpoint, timeout=10)
    client.connect()
    try:
        idx = client.get_namespace_index('urn:sorter_cell:line')
        wh = client.nodes.objects.get_child([f'{idx}:sorter_line', f'{idx}:Warehouse'])
        var = {
            n: wh.get_child(f'{idx}:{n}') for n in ('SortPlanVersion', 'SortPlan', 'LastRefusal')
        }
        sub = client.create_subscription(20, seen)
        sub.subscribe_data_change(wh.get_child(f'{idx}:LastDisposition'))

        def call(name, *args):
            try:
                return wh.call_method(f'{idx}:{name}', *args)
            except ua.UaStatusCodeError as exc:
                return type(exc).__name__

        S = ua.VariantType.String
        assert (
            call('SetSortPlan', 'v1', ua.Variant(['D1=S02R', 'D2=S01L'], S, is_array=True)) is None
        )
        ros.spin_until(lambda: active, 5.0)
        assert active[-1].name == 'v1'
        assert [(kv.key, kv.value) for kv in active[-1].values] == [('D1', 'S02R'), ('D2', 'S01L')]
        assert var['SortPlanVersion'].read_value() == 'v1'
        refusals = {
            'no such chute': ('SetSortPlan', 'v2', ua.Variant(['D1=S07L'], S, is_array=True)),
            'no =': ('SetSortPlan', 'v2', ua.Variant(['D1S02R'], S, is_array=True)),
            'numbers': (
                'SetSortPlan',
                'v2',
                ua.Variant([1, 2], ua.VariantType.Int32, is_array=True),
            ),
            'one argument': ('SetSortPlan', 'v2'),
            'bad label': ('RequestDestination', 'P 1', 'D1'),
        }
        got = {why: call(*args) for why, args in refusals.items()}
        assert got == {
            'no such chute': 'BadInvalidArgument',
            'no =': 'BadInvalidArgument',
            'numbers': 'BadTypeMismatch',
            'one argument': 'BadArgumentsMissing',
            'bad label': 'BadInvalidArgument',
        }
        assert node.wcs.version == 'v1' and var['SortPlanVersion'].read_value() == 'v1'
        assert 'label' in var['LastRefusal'].read_value()
        assert call('RequestDestination', 'P1', 'D1') is None
        ros.spin_until(lambda: any(m.key == 'P1' for m in routing), 5.0)
        assert [(m.key, m.value) for m in routing if m.key == 'P1'] == [('P1', 'right')]
        # a plan over ROS is the plan OPC UA shows
        plan.publish(DiagnosticStatus(name='v2', values=[KeyValue(key='D1', value='S02L')]))
        ros.spin_until(lambda: node.wcs.version == 'v2', 5.0)
        deadline = time.monotonic() + 5.0
        while var['SortPlanVersion'].read_value() != 'v2' and time.monotonic() < deadline:
            time.sleep(0.02)
        assert var['SortPlan'].read_value() == ['D1=S02L']
        # the line says where P1 left: the disposition reaches ROS and the OPC UA subscription
        values = {'id': '1', 'label': 'P1', 'exit': 'S02L', 'station': 'S02', 't': '3.5'}
        exits.publish(
            DiagnosticStatus(
                name='parcel/1',
                message='S02L',
                values=[KeyValue(key=k, value=v) for k, v in values.items()],
            )
        )
        ros.spin_until(lambda: disp and any('P1;' in v for v in seen.values), 5.0)
        assert disp[-1].name == 'P1' and disp[-1].message == 'sorted'
        assert [v for v in seen.values if v] == ['P1;sorted;D1;S02L;S02;3.500000']
        assert wh.get_child(f'{idx}:DispositionCount').read_value() == 1
    finally:
        client.disconnect()
    # no identity buys more than an anonymous session: a login is refused
    assert refused_login(node.opcua.endpoint, 'admin', 'admin') is not None


@pytest.mark.ros
def test_the_line_sorts_through_a_plan_change_in_flight_and_a_chute_that_fills(ros):
    """Two stations with their PLCs and the WCS: v2 moves D1 while B1 rides station 1."""
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    from rclpy.parameter import Parameter

    from sorter_control.node import ControllerNode
    from sorter_control.wcs_node import WcsNode
    from sorter_ros.interface import EVENT_QOS
    from sorter_sim.frontends.line_node import LineNode
    from sorter_sim.runtime.cell import ParcelSpec

    line = LineNode(
        context=ros.context,
        parameter_overrides=[
            Parameter('stations', value=2),
            Parameter('time_mode', value='fast'),
            Parameter('fast_slice', value=0.005),
            Parameter('chute_capacity', value=1),
            Parameter('chute_drain_per_s', value=0.0),
        ],
        # the stream's spacing (above the controller's least gap for these parcels)
        station_params={'arrival': 'none', 'arrival_gap': [1.5, 1.6]},
    )
    for n in line.nodes:
        ros.add(n)
    ctls = [
        ros.add(
            ControllerNode(
                context=ros.context,
                namespace=f'/S0{k}',
                parameter_overrides=[
                    Parameter('use_sim_time', value=True),
                    # a station's table is the WCS's: none of the single cell's own rules
                    Parameter('routing.rules', Parameter.Type.STRING_ARRAY, []),
                ],
            )
        )
        for k in (1, 2)
    ]
    wcs = ros.add(
        WcsNode(context=ros.context, parameter_overrides=[Parameter('stations', value=2)])
    )
    probe = ros.make_node('wms')
    disp = {}
    probe.create_subscription(
        DiagnosticStatus,
        'wcs/dispositions',
        lambda m: disp.__setitem__(m.name, {kv.key: kv.value for kv in m.values}),
        EVENT_QOS,
    )
    plan = probe.create_publisher(DiagnosticStatus, 'wcs/sort_plan', EVENT_QOS)
    req = probe.create_publisher(KeyValue, 'wcs/requests', EVENT_QOS)
    ros.spin_until(
        lambda: all(c.logic is not None and c.logic.state == 'running' for c in ctls), 60.0
    )
    ros.spin_until(lambda: plan.get_subscription_count() and req.get_subscription_count(), 10.0)
    ros.spin_until(lambda: not wcs.unmatched(), 10.0)  # the line and its PLCs, every topic

    def send_plan(version, entries):
        plan.publish(
            DiagnosticStatus(
                name=version, values=[KeyValue(key=d, value=c) for d, c in entries.items()]
            )
        )
        ros.spin_until(lambda: wcs.wcs.version == version, 5.0)

    send_plan('v1', {'D1': 'S02L', 'D2': 'S01L'})
    wanted = {'A1': 'D2', 'B1': 'D1', 'A2': 'D2', 'B2': 'D1'}
    for label, dest in wanted.items():
        req.publish(KeyValue(key=label, value=dest))
    ros.spin_until(lambda: len(wcs.wcs.requests) == 4, 5.0)
    ros.spin_for(0.2)  # the routing updates reach the stations
    for label in wanted:
        line.stations[0].cell.induct(ParcelSpec(0.4, 0.3, 4.0, label=label))

    def riding(k, label):
        return label in line.stations[k].cell.parcel_motion()['label']

    # B1 is read and on its way (station 1 sends it on to station 2): D1 moves to S02R
    ros.spin_until(
        lambda: riding(0, 'B1') and line.stations[0].cell.parcels()['x'].max() > 0, 60.0
    )
    send_plan('v2', {'D1': 'S02R', 'D2': 'S01L'})
    ros.spin_until(lambda: len(disp) == 4, 120.0)
    got = {label: (d['code'], d['chute'], d['station']) for label, d in disp.items()}
    assert got == {
        'A1': ('sorted', 'S01L', 'S01'),
        'B1': ('sorted', 'S02R', 'S02'),  # the plan changed while it rode station 1
        'A2': ('chute_full', '', 'S02'),  # S01L holds one parcel and does not drain
        'B2': ('chute_full', '', 'S02'),  # nor does S02R, which B1 filled
    }
    assert {c.name: c.level for c in line.line.chutes} == {
        'S01L': 1,
        'S01R': 0,
        'S02L': 0,
        'S02R': 1,
    }


@pytest.mark.parametrize(
    'given, said',
    [
        ('stations:=0', "parameter 'stations' must be an integer in [1, 64], got 0"),
        # another type: what is allowed, not rclpy's type error and its traceback
        ('stations:=x', "parameter 'stations' must be an integer in [1, 64], got 'x' (string)"),
        ('chute_names:=3', "parameter 'chute_names' must be a list of names, got 3 (integer)"),
    ],
)
def test_the_wcs_executable_refuses_a_bad_parameter_in_one_line(given, said):
    from pathlib import Path

    done = subprocess.run(
        [str(Path(sys.executable).parent / 'wcs_node'), '--ros-args', '-p', given],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f'wcs_node: {said}']


def test_a_request_costs_the_same_however_many_are_held():
    """Each request rewrites only its parcel's rule (the benchmark prints the figures)."""
    sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[1]))
    from benchmarks.bench_wcs_requests import per_request_s

    few = per_request_s(0, leave=False)
    many = per_request_s(20_000, leave=False)
    assert many < 4.0 * few + 20e-6, (few, many)  # was linear: a rebuild of every rule


def test_requests_over_the_bound_are_refused_and_counted_and_answered_ones_pruned(monkeypatch):
    import sorter_control.wcs as wcs_module

    monkeypatch.setattr(wcs_module, 'MAX_PENDING', 3)
    w = wcs_with_plan()
    for label in ('A', 'B', 'C'):
        w.request(label, 'D2')
    with pytest.raises(PlanError, match='3 requests wait for their parcels already'):
        w.request('D', 'D2')
    assert 'D' not in w.requests and w.rules[1] == {'A': 'right', 'B': 'right', 'C': 'right'}
    w.request('A', 'D3')  # a change of a held request is not a new one
    # a parcel that left: its request, rule and results go, and room is made
    w.confirmed(1, 'B', 'right', 'sorted')
    w.exited('B', 'S02R', 1, 3.0)
    assert w.forget('B') == [(1, 'B', '')]
    assert 'B' not in w.requests and 'B' not in w.results and 'B' in w.dispositions
    w.request('D', 'D2')
    assert w.n_taken == 5


@pytest.mark.parametrize(
    'values, named',
    [
        ({'t': 'nan'}, 't must be a decimal number'),
        ({'t': 'inf'}, 't must be a decimal number'),
        ({'t': '-1.0'}, 't must be a decimal number'),
        ({'station': 'S\u0663'}, 'station must be one of S01..S03'),
        ({'station': 'S09'}, 'station must be one of S01..S03'),
        ({'label': 'x' * 100_000}, 'a label is'),
        ({'label': ''}, 'a label is'),
        ({'label': 'P\x1b[2J'}, 'a label is'),
        ({'exit': 'S07L'}, 'exit must be a chute of the line'),
        ({'id': '-4'}, 'id must be'),
        ({'extra': '1'}, 'once'),
    ],
)
def test_a_forged_line_exit_is_refused_naming_what_is_wrong(values, named):
    from sorter_control.wcs import parse_exit

    good = {'id': '7', 'label': 'P7', 'exit': 'S02R', 'station': 'S02', 't': '12.500000000'}
    assert parse_exit(good.items(), CHUTES) == ('P7', 'S02R', 1, 12.5, '')
    with pytest.raises(PlanError, match=named):
        parse_exit({**good, **values}.items(), CHUTES)
    with pytest.raises(PlanError, match='without'):
        parse_exit([], CHUTES)


@pytest.mark.ros
def test_the_wcs_node_answers_every_request_of_a_burst_and_refuses_forged_exits(ros):
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

    from sorter_ros.interface import EVENT_QOS

    node, probe, req, answers = _wcs_and_wms(ros, 3)
    disp = []
    probe.create_subscription(DiagnosticStatus, 'wcs/dispositions', disp.append, EVENT_QOS)
    exits = probe.create_publisher(DiagnosticStatus, 'line/exits', EVENT_QOS)
    ros.spin_until(lambda: exits.get_subscription_count(), 10.0)
    burst = 1000
    for i in range(burst):
        req.publish(KeyValue(key=f'P{i:05d}', value='D1'))
    req.publish(KeyValue(key='bad label', value='D1'))
    ros.spin_until(lambda: len(answers) == burst + 1, 40.0)
    assert len(answers) == burst + 1 and node.wcs.n_taken == burst
    assert [a.value for a in answers[:burst]] == [''] * burst  # taken, none dropped
    assert answers[-1].key == 'bad label' and 'refused' in answers[-1].value
    # forged exits: refused, counted, no disposition
    for values in (
        {'t': 'nan'},
        {'t': 'inf'},
        {'station': 'S\u0663'},
        {'label': 'x' * 100_000},
    ):
        good = {'id': '1', 'label': 'P00001', 'exit': 'S01L', 'station': 'S01', 't': '1.0'}
        exits.publish(
            DiagnosticStatus(
                name='parcel/1',
                values=[KeyValue(key=k, value=v) for k, v in {**good, **values}.items()],
            )
        )
    exits.publish(DiagnosticStatus())
    ros.spin_until(lambda: node.n_refused_exits == 5, 10.0)
    assert node.n_refused_exits == 5 and disp == []
    assert 'P00001' in node.wcs.requests
