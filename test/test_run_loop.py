"""
The run loop's settle checks: every node on simulated time caught up before time moves on.

``RunLoop._unsettled`` looks again only at what its last look left, and at the timers
``_periods_to_next_timer`` found due in the slice: these tests hold it to the rule
that a timer on simulated time runs in the slice it falls due, whatever joined when.
"""

from __future__ import annotations

import pytest
import rclpy
from rclpy.parameter import Parameter

from sorter_cell.testing import SorterCell

pytestmark = pytest.mark.ros

MS = 1_000_000  # ns


@pytest.mark.parametrize('events', [True, False], ids=['events', 'single-threaded'])
def test_a_node_that_joins_a_running_cell_has_its_timer_run_in_the_slice_it_falls_due(events):
    """Its clock is behind until the next slice's tick; its overdue timer runs in that slice."""
    with SorterCell(events=events) as cell:
        cell.run(1.0)
        node = rclpy.create_node(
            'late',
            context=cell.context,
            parameter_overrides=[Parameter('use_sim_time', value=True)],
        )
        calls = []  # (the node's time, the loop's) at each call
        node.create_timer(
            0.05, lambda: calls.append((node.get_clock().now().nanoseconds, cell.t_ns))
        )
        cell.add_node(node)
        cell.run(0.2)
    # overdue at the first tick (its clock read 0 until then), then every 50 ms on time
    assert [now for now, _ in calls] == [1005 * MS, 1050 * MS, 1100 * MS, 1150 * MS, 1200 * MS]
    assert all(now == loop for now, loop in calls), calls


def test_a_topics_publishers_are_counted_once_a_simulated_second_per_context(ros):
    """One walk of the graph serves every node of a Context for the rest of that second."""
    from rclpy.context import Context
    from std_msgs.msg import Empty

    from sorter_ros.graph_counts import publisher_count

    topic = '/graph_counts_probe'
    asker, other = ros.make_node('asker'), ros.make_node('other')
    walks = []
    for node in (asker, other):
        count = node.count_publishers
        node.count_publishers = lambda t, count=count, node=node: walks.append(node) or count(t)
    ros.make_node('talker').create_publisher(Empty, topic, 10)
    ros.spin_until(lambda: asker.count_publishers(topic) == 1, 5.0, 'the first publisher')
    walks.clear()
    assert publisher_count(asker, topic, 5 * 10**8) == 1
    assert publisher_count(other, topic, 9 * 10**8) == 1  # the same second: no walk
    assert walks == [asker]
    ros.make_node('talker_2').create_publisher(Empty, topic, 10)
    ros.spin_until(lambda: asker.count_publishers(topic) == 2, 5.0, 'the second publisher')
    walks.clear()
    assert publisher_count(other, topic, 999_999_999) == 1  # at most a second old
    assert publisher_count(other, topic, 10**9) == 2 and walks == [other]
    # another Context is another graph: counted on its own
    context = Context()
    rclpy.init(context=context, domain_id=ros.context.get_domain_id())
    try:
        alone = rclpy.create_node('alone', context=context)
        count = alone.count_publishers
        alone.count_publishers = lambda t: walks.append(alone) or count(t)
        publisher_count(alone, topic, 10**9)  # (its discovery of the others: not awaited)
        assert walks == [other, alone]
        alone.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    assert publisher_count(asker, topic, 10**9) == 2 and walks == [other, alone, asker]
