"""
A controller run as a process, late in wall time: the watchdog judges it on simulated time.

The cell trips its watchdog when a heartbeat is later than ``watchdog_timeout`` of
simulated time (0.3 s). A process on a loaded machine can lose the core for longer
than the cell takes to run 0.3 s; the scenario then waits (``COMMAND_HEARTBEAT_WAIT_S``
of wall time) for the late heartbeat before it runs the slice that would trip. A
process that stops beating still trips the watchdog, at the simulated moment it
would have without the wait.
"""

from __future__ import annotations

import textwrap

import pytest

from sorter_cell.testing.scenario import COMMAND_HEARTBEAT_WAIT_S, load_scenario, run_scenario

# beats every 50 ms of the cell's clock; at its 20th beat it stalls for STALL wall
# seconds (the core taken away) or, with STALL < 0, never beats again (frozen)
CONTROLLER = """
import sys, time
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import UInt32

STALL = float(sys.argv[1])


class Beating(Node):
    def __init__(self):
        super().__init__('beating', parameter_overrides=[Parameter('use_sim_time', value=True)])
        self.beat = self.create_publisher(UInt32, 'controller/heartbeat', 10)
        self.count = 0
        self.create_timer(0.05, self.on_beat)

    def on_beat(self):
        self.count += 1
        if self.count == 20:
            if STALL < 0:
                self.beat = None
            else:
                time.sleep(STALL)
        if self.beat is not None:
            self.beat.publish(UInt32(data=self.count))


rclpy.init()
try:
    rclpy.spin(Beating())
except (KeyboardInterrupt, ExternalShutdownException):
    pass
finally:
    rclpy.try_shutdown()
"""


@pytest.mark.parametrize('stall, faults', [(1.2, '[]'), (-1.0, '[watchdog]')])
def test_a_controller_process_late_in_wall_time_keeps_the_watchdog_fed(tmp_path, stall, faults):
    """Stalled 1.2 s of wall time (over 0.3 s of the cell's): fed; stopped: tripped."""
    assert 0.0 < stall < COMMAND_HEARTBEAT_WAIT_S or stall < 0
    (tmp_path / 'beating.py').write_text(CONTROLLER)
    sc = tmp_path / 'sc.yaml'
    sc.write_text(
        textwrap.dedent(
            f"""
            duration: 3.0
            controller: {{command: ["{{python}}", beating.py, "{stall}"], start_timeout: 30}}
            expect:
              - {{at: 0.5, faults: []}}
              - {{at: 2.5, faults: {faults}}}
            """
        )
    )
    res = run_scenario(load_scenario(sc))
    assert res.error == '', res.error
    assert res.passed, [(c.text, c.passed, c.detail) for c in res.checks]
