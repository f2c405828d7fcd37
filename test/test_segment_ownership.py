"""
Who owns a station of a split line, and in what order its messages may come.

Two segments claiming one station: the one that started later holds and both say so;
horizons come from the owner upstream only and a few slices at a time; hellos from anyone
but the owner downstream re-send nothing; a parcel id a segment has taken is never
taken again, the real parcel stays.
"""

from __future__ import annotations

import time
from dataclasses import replace

import pytest
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.parameter import Parameter

from sorter_sim.frontends.segments import HANDOVER_QOS, HORIZON_STRIDE, handover_message
from test_handover import REAL

pytestmark = pytest.mark.ros


def segment(ros, name, **values):
    from sorter_sim.frontends.line_node import LineNode

    node = LineNode(
        node_name=name,
        context=ros.context,
        parameter_overrides=[
            Parameter(k, value=v) for k, v in {'time_mode': 'lockstep', **values}.items()
        ],
        station_params={'arrival': 'none'},
    )
    for n in node.nodes:
        ros.add(n)
    return node


def step(ros, *lines, n=50):
    for line in lines:
        line.advance(n)
        for _ in range(30):
            ros.executor.spin_once(timeout_sec=0.0)


def test_a_second_claimant_of_a_station_holds_and_both_say_so(ros):
    first = segment(ros, 'sorter_line_a', stations=1, first_station=2)
    time.sleep(0.01)  # started later
    second = segment(ros, 'sorter_line_b', stations=1, first_station=2)
    ros.spin_until(
        lambda: first.segment.owners.conflicts and second.segment.owners.conflicts, 10.0
    )
    assert first.segment.owners.conflicts == 1 == second.segment.owners.conflicts
    ros.spin_for(1.2)  # past the claim's settling time
    assert second.segment.holds() and second.segment.owners.refused()
    assert not first.segment.holds()
    # the one that holds takes nothing from upstream
    msg = DiagnosticStatus(
        name='horizon',
        values=[KeyValue(key='t_ns', value='0'), KeyValue(key='identity', value='1-1')],
    )
    refused = second.segment.stats['refused']
    callback = next(
        s.callback for s in second.subscriptions if s.topic_name == '/line/handover/S02'
    )
    callback(msg)
    assert second.segment.stats['refused'] == refused + 1


def test_forged_horizons_hellos_and_parcel_ids_change_nothing(ros):
    up = segment(ros, 'sorter_line_a', stations=1, line_stations=2, fast_slice=0.05)
    down = segment(ros, 'sorter_line_b', stations=1, first_station=2, fast_slice=0.05)
    # two parcels half a metre before the exit of S01 (as a station upstream hands them
    # in): S02 has them within a second of simulated time
    for i in (1, 2):
        up.stations[0].cell.hand_in(replace(REAL[0], parcel_id=i, label=f'P{i}'), -0.3 * i)
    forger = ros.make_node('forger')
    to_down = forger.create_publisher(DiagnosticStatus, '/line/handover/S02', HANDOVER_QOS)
    to_up = forger.create_publisher(DiagnosticStatus, '/line/handover/S02/left', HANDOVER_QOS)
    ros.spin_until(
        lambda: (
            up.segment.connected()
            and to_down.get_subscription_count()
            and to_up.get_subscription_count()
        ),
        10.0,
    )
    deadline = time.monotonic() + 45.0
    while down.segment.stats['received'] < 1:
        assert time.monotonic() < deadline, 'no parcel handed over'
        step(ros, up, down)
    taken = down.segment.inbox[0] if down.segment.inbox else None
    k_before = down.segment.horizon_k
    refused = down.segment.stats['refused']
    # a horizon far ahead, even in the owner's name: refused
    to_down.publish(
        DiagnosticStatus(
            name='horizon',
            values=[
                KeyValue(key='t_ns', value=str(10**18)),
                KeyValue(key='identity', value=up.segment.identity),
            ],
        )
    )
    # 200 hellos from segments that own nothing: nothing is sent again
    resent = up.segment.stats['resent']
    for i in range(200):
        to_up.publish(
            DiagnosticStatus(name='hello', values=[KeyValue(key='identity', value=f'{i}-{i}')])
        )
    # a parcel with the id of one already taken, in a plausible state: not taken again
    h = up.segment.outbox[next(iter(up.segment.outbox))]
    to_down.publish(handover_message(h, time.time_ns()))
    ros.spin_for(1.0)
    assert down.segment.horizon_k <= k_before + up._slice
    assert down.segment.stats['refused'] >= refused + 1
    assert up.segment.stats['resent'] == resent  # none of them owns S02
    assert down.segment.stats['duplicates'] >= 1 and down.segment.stats['received'] == 1
    if taken is not None:
        assert down.segment.inbox[0] is taken


def test_a_fast_segment_says_a_horizon_every_few_slices_and_the_newest_when_it_stops(ros):
    """
    Horizons coalesce on the sender and are bounded on the receiver.

    A segment running on says one horizon in ``HORIZON_STRIDE - 1`` slices (each one
    carries the earlier ones), the newest when it stops; the segment downstream takes
    each, and refuses one more than ``HORIZON_STRIDE`` slices ahead even in the owner's name.
    """
    up = segment(ros, 'sorter_line_a', stations=1, line_stations=2, fast_slice=0.1)
    down = segment(ros, 'sorter_line_b', stations=1, first_station=2, fast_slice=0.1)
    link = up.segment
    ros.spin_until(
        lambda: link.connected() and down.segment.owners.owner_of(0) == link.identity, 10.0
    )
    m, dt = link.max_step_k, link.dt_ns
    assert m == up._slice == 100  # a slice: more than a wall-clock burst
    said = link.stats['messages']
    for i in range(1, 50):  # a pass a slice, as _tick_fast runs them
        link.horizon(i * m * dt, coalesce=True)
    # slices 1, 8, 15, ..., 43: the first, then one every HORIZON_STRIDE - 1
    assert link.stats['messages'] - said == 1 + 42 // (HORIZON_STRIDE - 1)
    ros.spin_until(lambda: down.segment.horizon_k == 43 * m, 10.0)
    link.flush_horizon()  # it stopped: the newest goes out
    link.flush_horizon()  # and only once
    assert link.stats['messages'] - said == 2 + 42 // (HORIZON_STRIDE - 1)
    ros.spin_until(lambda: down.segment.horizon_k == 49 * m, 10.0)
    assert down.segment.stats['refused'] == 0

    forger = ros.make_node('forger')
    to_down = forger.create_publisher(DiagnosticStatus, '/line/handover/S02', HANDOVER_QOS)
    ros.spin_until(lambda: to_down.get_subscription_count(), 10.0)

    def said_by_owner(k):
        to_down.publish(
            DiagnosticStatus(
                name='horizon',
                values=[
                    KeyValue(key='t_ns', value=str(k * dt)),
                    KeyValue(key='identity', value=link.identity),
                ],
            )
        )
        ros.spin_for(0.3)

    top = 49 * m + HORIZON_STRIDE * m
    said_by_owner(top + 1)
    assert down.segment.horizon_k == 49 * m and down.segment.stats['refused'] == 1
    said_by_owner(top)
    assert down.segment.horizon_k == top and down.segment.stats['refused'] == 1


def test_the_same_node_restarted_takes_its_stations_over_at_once(ros):
    """A later claim under the owner's own name and stations succeeds it, lease or not."""
    up = segment(ros, 'sorter_line_a', stations=1, line_stations=2)
    old = segment(ros, 'sorter_line_b', stations=1, first_station=2)
    ros.spin_until(lambda: up.segment.owners.owner_of(1) == old.segment.identity, 10.0)
    new = segment(ros, 'sorter_line_b', stations=1, first_station=2)
    start = time.monotonic()
    ros.spin_until(lambda: up.segment.owners.owner_of(1) == new.segment.identity, 10.0)
    # well within the old claim's lease: the old one is alive and still claiming
    assert time.monotonic() - start < 2.0
    ros.spin_until(lambda: old.segment.owners.refused(), 5.0)
    assert not new.segment.owners.refused() and old.segment.holds()


def test_a_hello_said_again_after_its_answer_is_answered_again(ros):
    """
    The answer to a hello lost on its way (a restarted segment's subscription matched late).

    The segment keeps saying hello: the one upstream answers it again, its parcels with
    it, and the segment runs. Before, a hello it had answered once was never answered
    again, and a restarted segment that missed its answer waited for ever.
    """
    up = segment(ros, 'sorter_line_a', stations=1, line_stations=2, fast_slice=0.05)
    down = segment(ros, 'sorter_line_b', stations=1, first_station=2, fast_slice=0.05)
    up.stations[0].cell.hand_in(replace(REAL[0], parcel_id=1, label='P1'), -0.3)
    ros.spin_until(lambda: up.segment.connected(), 10.0)
    deadline = time.monotonic() + 30.0
    while not (down.segment.answered and down.segment.stats['received'] >= 1):
        assert time.monotonic() < deadline, 'no parcel handed over'
        step(ros, up, down)
    assert up.segment.outbox  # S01 answers for it until it leaves S02
    ros.spin_for(1.2)  # an answer still on its way (the hello said twice) arrives first
    resent = up.segment.stats['resent']
    # the answer, as if lost: the segment downstream did not hear it and says hello again
    down.segment.answered = False
    deadline = time.monotonic() + 10.0
    while not down.segment.answered:
        assert time.monotonic() < deadline, 'a hello said again was never answered'
        for _ in range(30):
            ros.executor.spin_once(timeout_sec=0.01)
        up.segment.service()
        down.segment.service()
    assert up.segment.stats['resent'] > resent  # the parcel it answers for, sent again
    assert down.segment.stats['duplicates'] >= 1 and down.segment.stats['received'] == 1
