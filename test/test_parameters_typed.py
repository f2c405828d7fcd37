"""
Parameters as ROS users type them: an integer for a double, at start-up and at run time.

Through rclpy's own parameter client (what ``ros2 param set`` uses), over real services:
``45`` for ``alpha_deg`` is 45.0, ranges are as strict as ever, and a real error at
start-up says what was given and what is allowed.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from test_sim_node import make_sim

from sorter_control.node import ControllerNode

pytestmark = pytest.mark.ros
BIN = Path(sys.executable).parent


def _done(ros, future, what: str):
    ros.spin_until(future.done, 10.0, what)
    assert future.done(), what
    return future.result()


def test_an_integer_for_a_double_is_that_double_at_start_up_and_at_run_time(ros):
    sim = make_sim(ros, alpha_deg=45, arrival_gap=[1, 2])
    assert sim.get_parameter('alpha_deg').value == 45.0
    assert sim.get_parameter('alpha_deg').type_ == Parameter.Type.DOUBLE
    assert list(sim.get_parameter('arrival_gap').value) == [1.0, 2.0]
    assert sim.params.alpha_deg == 45.0
    client = AsyncParameterClient(ros.make_node('ros2_param'), 'sorter_sim')
    ros.spin_until(lambda: client.services_are_ready(), 10.0, 'the parameter services')
    # ros2 param set /sorter_sim alpha_deg 30
    (ok,) = _done(ros, client.set_parameters([Parameter('alpha_deg', value=30)]), 'set').results
    assert ok.successful, ok.reason
    got = _done(ros, client.get_parameters(['alpha_deg']), 'get').values[0]
    assert got.type == Parameter.Type.DOUBLE.value and got.double_value == 30.0
    sim.advance(1)
    assert sim.params.alpha_deg == 30.0
    # the range holds for an integer as for a double, and nothing changes
    (bad,) = _done(ros, client.set_parameters([Parameter('alpha_deg', value=95)]), 'set').results
    assert not bad.successful and '95' in bad.reason
    # other types are still refused
    (text,) = _done(
        ros, client.set_parameters([Parameter('alpha_deg', value='45')]), 'set'
    ).results
    assert not text.successful
    assert sim.get_parameter('alpha_deg').value == 30.0


def test_the_controller_takes_integers_for_its_doubles(ros):
    ctl = ros.add(
        ControllerNode(
            context=ros.context,
            parameter_overrides=[
                Parameter('diagnostics_period', value=2),
                Parameter('photo_eyes.x', value=[-2, 0, 2]),
            ],
        )
    )
    assert ctl.get_parameter('diagnostics_period').value == 2.0
    assert list(ctl.get_parameter('photo_eyes.x').value) == [-2.0, 0.0, 2.0]


def test_an_empty_list_is_an_empty_array_of_the_declared_type(ros, tmp_path):
    """Take ``routing.rules: []`` as an empty table, where rclpy would read a byte array."""
    ctl = ros.add(
        ControllerNode(
            context=ros.context,
            parameter_overrides=[Parameter('routing.rules', value=[])],
        )
    )
    got = ctl.get_parameter('routing.rules')
    assert got.type_ == Parameter.Type.STRING_ARRAY and list(got.value) == []
    assert ctl.values['routing.rules'] == []
    # from a params file, in a process of its own, as a user would start it
    params = tmp_path / 'p.yaml'
    params.write_text('sorter_controller:\n  ros__parameters:\n    routing:\n      rules: []\n')
    done = subprocess.run(
        [
            str(BIN / 'controller_node'),
            '--ros-args',
            '--params-file',
            str(params),
            '-p',
            'scan_period:=-1.0',
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    # it gets past routing.rules and stops at the next bad value, naming that one alone
    assert done.returncode == 2, done.stderr
    assert 'scan_period' in done.stderr and 'routing.rules' not in done.stderr


def test_a_real_start_up_error_says_what_was_given_and_what_is_allowed():
    out = subprocess.run(
        [str(BIN / 'sim_node'), '--ros-args', '-p', 'alpha_deg:=95'],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    (line,) = out.stderr.strip().splitlines()
    assert "'alpha_deg'" in line and '[-90, 90]' in line and 'got 95.0' in line
