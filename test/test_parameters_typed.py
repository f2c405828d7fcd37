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


def _controller_from_args(args: list[str]) -> list[str]:
    """Start a controller in a context of its own from ``args``; return its routing rules."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx, args=['--ros-args', *args])
    try:
        ctl = ControllerNode(context=ctx)
        try:
            got = ctl.get_parameter('routing.rules')
            assert got.type_ == Parameter.Type.STRING_ARRAY, got.type_
            assert ctl.values['routing.rules'] == list(got.value)
            return list(got.value)
        finally:
            ctl.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_an_empty_list_is_an_empty_array_of_the_declared_type(ros, tmp_path):
    """
    Take ``routing.rules: []`` as an empty table however it is given.

    rclpy would read the command line's ``[]`` as a byte array, and rcl hands a params
    file's empty list over unset, which kept the default rules (``A*=left; ...``).
    """
    # the overrides a program passes (and the command line's ``-p routing.rules:=[]``)
    ctl = ros.add(
        ControllerNode(
            context=ros.context,
            parameter_overrides=[Parameter('routing.rules', value=[])],
        )
    )
    got = ctl.get_parameter('routing.rules')
    assert got.type_ == Parameter.Type.STRING_ARRAY and list(got.value) == []
    assert ctl.values['routing.rules'] == []
    assert _controller_from_args(['-p', 'routing.rules:=[]']) == []
    # a params file, as docs/controller.md starts a line's station controllers
    params = tmp_path / 'p.yaml'
    params.write_text('sorter_controller:\n  ros__parameters:\n    routing:\n      rules: []\n')
    assert _controller_from_args(['--params-file', str(params)]) == []
    # and the same file with rules in it still gives them (the file is read at all)
    params.write_text(
        'sorter_controller:\n  ros__parameters:\n    routing:\n      rules: ["Z*=left"]\n'
    )
    assert _controller_from_args(['--params-file', str(params)]) == ['Z*=left']


def test_an_empty_list_set_at_run_time_empties_the_table(ros):
    """``ros2 param set /sorter_controller routing.rules "[]"``: rclpy's parameter client."""
    ctl = ros.add(ControllerNode(context=ros.context))
    assert ctl.values['routing.rules'], 'the default table has rules'
    client = AsyncParameterClient(ros.make_node('ros2_param'), 'sorter_controller')
    ros.spin_until(lambda: client.services_are_ready(), 10.0, 'the parameter services')
    empty = Parameter('routing.rules', Parameter.Type.STRING_ARRAY, [])
    (ok,) = _done(ros, client.set_parameters([empty]), 'set').results
    assert ok.successful, ok.reason
    got = _done(ros, client.get_parameters(['routing.rules']), 'get').values[0]
    assert got.type == Parameter.Type.STRING_ARRAY.value and list(got.string_array_value) == []
    assert ctl.values['routing.rules'] == []


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
