"""
The line's warehouse side (``sorter_control.wcs``) and the line demo end to end.

The logic is checked on its own (the plan's rules, the routing it writes, the
tracking queues, every disposition code); the demo runs a three-station line with
its controllers and the warehouse node over DDS.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

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


@pytest.mark.ros
def test_the_line_demo_sorts_through_three_stations_with_their_plcs_and_the_wcs():
    done = subprocess.run(
        [
            sys.executable,
            '-m',
            'sorter_cell',
            'demo',
            '--stations',
            '3',
            '--sim-time',
            '25',
            '--json',
        ],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    s = json.loads(done.stdout.strip().splitlines()[-1])
    assert s['stations'] == 3 and s['mis_sorted'] == 0 and s['jams'] == 0
    assert sum(s['dispositions'].values()) + s['in_cell_at_end'] == s['inducted'] > 10
    assert s['dispositions'].get('sorted', 0) >= 10
    assert set(s['exits']) <= {'S01L', 'S01R', 'S02L', 'S02R', 'S03L', 'S03R', 'straight_end'}
    assert sum(1 for k in s['exits'] if k.startswith('S03')) >= 1  # tracked two stations on


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


def test_the_line_demo_refuses_what_it_does_not_have_yet(capsys):
    from sorter_cell.cli import main

    for extra in (['--rtf', '1'], ['--io', 'modbus'], ['--foxglove']):
        assert main(['demo', '--stations', '3', *extra]) == 2
        assert 'no --rtf, --foxglove or --io' in capsys.readouterr().err
    assert main(['demo', '--stations', '0']) == 2
    assert '--stations must be in [1, 64]' in capsys.readouterr().err
