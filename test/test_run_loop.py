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
