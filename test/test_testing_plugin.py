"""
The pytest plugin ``sorter_cell`` (``sorter_cell.testing``), used as a user would.

The fixtures come from the installed entry point (not from this suite's
conftest); one test runs pytest on a test file in a temporary folder outside the
project, as a third party's project would.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from std_msgs.msg import UInt32

REPO = Path(__file__).resolve().parents[1]


def _pytest_in(folder: Path, *args: str, env=None) -> subprocess.CompletedProcess:
    """Run pytest on a folder outside the project, as its own user would."""
    return subprocess.run(
        [sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider', *args],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_the_plugin_is_registered_by_the_installed_package(pytestconfig):
    assert pytestconfig.pluginmanager.has_plugin('sorter_cell')


def test_a_parcel_without_a_controller_goes_straight(sorter_cell):
    sorter_cell.induct('P-1', length=0.5, width=0.3)
    sorter_cell.run(5.0)
    (out,) = sorter_cell.outcomes
    assert (out.label, out.exit) == ('P-1', 'straight')
    # it travelled from the induct point (leading edge at -3 m) to the exit (centre at
    # +3 m) on the belt at 1.5 m/s: (3 + 3 + 0.25) / 1.5 s, to the control period
    assert out.t == pytest.approx(6.25 / 1.5, abs=2 * sorter_cell.dt)


def test_the_controller_sorts_by_its_routing(sorter_cell, sorter_controller):
    for label in ('A-1', 'B-1', 'C-1', 'X-1'):
        sorter_cell.induct(label, length=0.4, width=0.3)
    assert sorter_cell.run_until(lambda: len(sorter_cell.outcomes) == 4, timeout_s=30.0)
    exits = {o.label: o.exit for o in sorter_cell.outcomes}
    assert exits == {'A-1': 'left', 'B-1': 'right', 'C-1': 'straight', 'X-1': 'straight'}
    sorter_cell.run(1.0)
    confirmations = sorter_cell.confirmations
    results = {c.label: c.result for c in confirmations}
    assert results == {'A-1': 'sorted', 'B-1': 'sorted', 'C-1': 'sorted', 'X-1': 'rejected'}
    reached = {c.label: c.destination_reached for c in confirmations}
    assert reached == exits
    # a confirmation is an object as an outcome is, its numbers numbers; the message's
    # strings stay readable by key, as they were when a confirmation was a dict
    for c in confirmations:
        assert isinstance(c.seq, int) and c['seq'] == str(c.seq)
        assert 0.0 < c.t <= sorter_cell.t and c['t'] == f'{c.t:.6f}'
        assert (c['label'], c.get('result'), c.get('no such key', '-')) == (c.label, c.result, '-')
        assert set(c.keys()) >= {'label', 'result', 'destination_asked', 'destination_reached'}
        with pytest.raises(dataclasses.FrozenInstanceError):
            c.result = 'sorted'
    assert [c.seq for c in confirmations] == sorted({c.seq for c in confirmations})


@pytest.mark.sorter_cell(params={'belt_speed': 1.0, 'watchdog_timeout': 0.3})
def test_markers_set_parameters_and_a_third_party_node_runs_in_the_cell(sorter_cell):
    import rclpy

    assert sorter_cell.params['belt_speed'] == 1.0
    # a node of the test's own, on the cell's clock: it feeds the watchdog, then stops
    node = rclpy.create_node('my_plc', context=sorter_cell.context)
    pub = node.create_publisher(UInt32, 'controller/heartbeat', 10)
    sorter_cell.add_node(node)
    for beat in range(20):
        pub.publish(UInt32(data=beat))
        sorter_cell.run(0.05)
    assert not sorter_cell.sim.cell.watchdog_tripped
    sorter_cell.run(0.5)
    assert sorter_cell.sim.cell.watchdog_tripped


def test_parameters_and_faults_through_the_fixture(sorter_cell):
    sorter_cell.set_params(alpha_deg=30)
    assert sorter_cell.params['alpha_deg'] == 30.0
    with pytest.raises(ValueError, match='alpha_deg'):
        sorter_cell.set_params(alpha_deg=120.0)
    assert sorter_cell.params['alpha_deg'] == 30.0
    assert 'held blocked' in sorter_cell.inject('eye', sensor='pe_divert', mode='blocked')
    sorter_cell.run(0.1)
    assert sorter_cell.sensor('pe_divert') is True
    with pytest.raises(ValueError, match='unknown fault'):
        sorter_cell.inject('lightning')
    sorter_cell.inject('estop')
    assert sorter_cell.sim.cell.estop
    sorter_cell.reset()
    assert not sorter_cell.sim.cell.estop
    with pytest.raises(ValueError, match='A must be'):
        sorter_cell.induct('BAD', length=-1.0)
    with pytest.raises(ValueError, match='seconds'):
        sorter_cell.run(math.nan)


def test_a_test_outside_the_project_uses_only_the_installed_package(tmp_path):
    (tmp_path / 'test_mine.py').write_text(
        textwrap.dedent(
            """
            def test_my_controller_and_the_cell(sorter_cell, sorter_controller):
                sorter_cell.induct('A-7', length=0.4, width=0.3)
                sorter_cell.induct('B-7', length=0.4, width=0.3)
                assert sorter_cell.run_until(lambda: len(sorter_cell.outcomes) == 2, 20.0)
                assert {o.label: o.exit for o in sorter_cell.outcomes} == {
                    'A-7': 'left', 'B-7': 'right'}
            """
        )
    )
    done = _pytest_in(tmp_path, 'test_mine.py')
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert '1 passed' in done.stdout


def test_the_example_third_party_controller_passes_its_own_tests(tmp_path):
    import os

    # examples/ is a third party's project: copied out of the tree and run there, as its
    # user did: ROS_DOMAIN_ID exported (as the ROS tutorials teach) and two xdist
    # workers, whose cells shared that domain (the watchdog test heard the other
    # worker's controller) until each test claimed one of its own
    for name in ('minimal_controller.py', 'test_minimal_controller.py'):
        (tmp_path / name).write_text((REPO / 'examples' / name).read_text())
    done = _pytest_in(tmp_path, '-n', '2', env=dict(os.environ, ROS_DOMAIN_ID='7'))
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert '2 passed' in done.stdout


DOMAINS = """
import fcntl
import os

import pytest

from sorter_cell.testing.domains import lock_dir


def _held(domain):
    # a lock of this host's claims: a second open file cannot take it while it is held
    fd = os.open(lock_dir() / f'domain-{domain}.lock', os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except BlockingIOError:
        return True
    finally:
        os.close(fd)


@pytest.mark.parametrize('n', range(2))
def test_a_domain_of_its_own(sorter_cell, n):
    assert 120 <= sorter_cell.domain_id <= 123 and _held(sorter_cell.domain_id)
    assert sorter_cell.context.get_domain_id() == sorter_cell.domain_id


@pytest.mark.sorter_ros_domain_id
def test_the_shells_domain_where_the_test_asks_for_it(sorter_cell):
    assert sorter_cell.domain_id == 7
"""


def test_each_test_and_worker_has_a_domain_of_its_own_whatever_the_shell_exports(tmp_path):
    import os

    # ROS_DOMAIN_ID exported, two xdist workers: each test on a domain of the range,
    # claimed on the host while it runs; the shell's only where a test asks for it
    (tmp_path / 'test_domains.py').write_text(DOMAINS)
    env = dict(os.environ, ROS_DOMAIN_ID='7', SORTER_DOMAIN_LOCKS=str(tmp_path / 'locks'))
    done = _pytest_in(tmp_path, '-n', '2', '--sorter-domains', '120-123', env=env)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert '3 passed' in done.stdout


def test_a_domain_range_that_is_none_is_refused_before_any_test_runs(tmp_path):
    (tmp_path / 'test_domains.py').write_text(DOMAINS)
    bad = _pytest_in(tmp_path, '--sorter-domains', '300-301', 'test_domains.py')
    assert bad.returncode == 4, bad.stdout[-2000:] + bad.stderr[-2000:]
    (line,) = bad.stderr.strip().splitlines()
    assert '--sorter-domains must be a ROS domain range' in line and "'300-301'" in line


EVERY_TOPIC = """
import rclpy
from minimal_controller import MinimalController
from std_msgs.msg import String


def test_recorded(sorter_cell):
    sorter_cell.add_node(MinimalController(context=sorter_cell.context))
    mine = sorter_cell.add_node(rclpy.create_node('my_node', context=sorter_cell.context))
    notes = mine.create_publisher(String, '/mine/notes', 10)
    sorter_cell.run(0.5)  # looked at the graph
    for i in range(3):
        notes.publish(String(data=f'note {i}'))
        sorter_cell.run(0.1)
    sorter_cell.induct('L-1', length=0.4, width=0.3)
    sorter_cell.induct('S-1', length=0.4, width=0.3)
    assert sorter_cell.run_until(lambda: len(sorter_cell.outcomes) == 2, 30.0)
    sorter_cell.set_params(alpha_deg=45.0)  # the cell's /parameter_events
    sorter_cell.run(0.5)
"""


def test_a_tests_recording_holds_every_topic_on_its_domain_its_own_nodes_too(tmp_path):
    from ros_harness import recorded_topic_counts

    (tmp_path / 'test_mine.py').write_text(EVERY_TOPIC)
    name = 'minimal_controller.py'
    (tmp_path / name).write_text((REPO / 'examples' / name).read_text())
    base = tmp_path / 'bt'
    done = _pytest_in(tmp_path, f'--basetemp={base}', '--sorter-record=all', 'test_mine.py')
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    (path,) = [p for p in base.glob('*/sorter_cell.mcap') if not p.parent.is_symlink()]
    counts = recorded_topic_counts(path)
    # the test's nodes' topics (the controller's heartbeat every 50 ms, its own notes),
    # as ros2 bag record -a would have them
    assert counts['/mine/notes'] == 3
    assert counts['/controller/heartbeat'] > 40
    assert counts['/parameter_events'] > 0  # alpha_deg's change among them
    # the cell's own topics once each, as it writes them: no second copy
    assert counts['/sort/outcomes'] == 2


def test_a_wait_that_times_out_explains_where_the_cell_is(sorter_cell):
    sorter_cell.induct('P-1', length=0.5, width=0.3)
    sorter_cell.inject('eye', sensor='pe_exit', mode='blocked')
    done = sorter_cell.run_until(lambda: False, timeout_s=0.5, what='P-1 in a chute')
    assert not done
    text = str(done)
    for fact in (
        'waited 0.5 s of simulated time for P-1 in a chute: it did not come',
        'the cell: t = 0.500 s simulated',
        's wall since it started',
        'parcels: 1 inducted, 1 on the cell, 0 waiting at the induction, 0 out: none',
        'faults: none; sensors faulted: pe_exit blocked; PackML: Execute',
        f'recording: {sorter_cell.record_path}',
    ):
        assert fact in text, text
    assert sorter_cell.record_path.endswith('sorter_cell.mcap')
    assert sorter_cell.run_until(lambda: True) is True


FAILING = '''
def test_passes(sorter_cell):
    sorter_cell.run(0.1)


def test_fails(sorter_cell):
    sorter_cell.induct('F-1')
    sorter_cell.run(0.2)
    assert sorter_cell.outcome('F-1') is not None
'''


@pytest.mark.parametrize('mode, kept', [('failed', {'test_fails0'}), ('none', set())])
def test_a_failed_test_reports_the_cell_and_keeps_its_recording(tmp_path, mode, kept):
    import xml.etree.ElementTree as ET

    (tmp_path / 'test_mine.py').write_text(FAILING)
    base, junit = tmp_path / 'bt', tmp_path / 'out.xml'
    done = subprocess.run(
        [
            sys.executable,
            '-m',
            'pytest',
            '-q',
            '-p',
            'no:cacheprovider',
            f'--basetemp={base}',
            f'--junitxml={junit}',
            f'--sorter-record={mode}',
            'test_mine.py',
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 1 and '1 failed, 1 passed' in done.stdout, done.stdout[-3000:]
    # (pytest links the newest test's folder as <name>current too)
    recordings = {
        p.parent.name for p in base.glob('*/sorter_cell.mcap') if not p.parent.is_symlink()
    }
    assert recordings == kept
    for text in (done.stdout, ET.parse(junit).getroot().find('.//failure').text):
        assert text.count('the state when the test failed:') == 1, text
        assert 'parcels: 1 inducted, 1 on the cell, 0 waiting at the induction, 0 out' in text
        assert 'faults: none; PackML: Execute' in text
        assert ('recording: ' in text) == bool(kept)
        for name in kept:
            assert str(base / name / 'sorter_cell.mcap') in text
