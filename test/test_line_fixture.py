"""
The line under test: the ``sorter_line`` fixture, line scenarios, the station-program contract.

A line of stations in lock-step with the warehouse node, as a user tests a station
program: parcels inducted by label and destination, dispositions per parcel with
the station, any station's program replaced by the user's (the example in
examples/), and the contract's check naming each clause a program breaks.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from sorter_cell.testing.contract import check_station_program
from sorter_cell.testing.lockstep import load_node_factory
from sorter_cell.testing.scenario import load_scenario, run_scenario

pytestmark = pytest.mark.ros

EXAMPLES = Path(__file__).resolve().parents[1] / 'examples'


def example_program():
    return load_node_factory('station_program:StationProgram', EXAMPLES)


@pytest.mark.sorter_line(stations=3)
def test_parcels_by_destination_get_their_disposition_and_station(sorter_line):
    for label, destination in (('P-1', 'D01'), ('P-2', 'D04'), ('P-3', 'D05'), ('P-4', None)):
        sorter_line.induct(label, destination)
        sorter_line.run(1.5)
    assert sorter_line.run_until(lambda: len(sorter_line.dispositions) == 4, 30.0)
    got = {d.label: (d.code, d.station, d.chute) for d in sorter_line.dispositions}
    assert got == {
        'P-1': ('sorted', 'S01', 'S01L'),
        'P-2': ('sorted', 'S02', 'S02R'),
        'P-3': ('sorted', 'S03', 'S03L'),
        'P-4': ('no_destination', 'S03', ''),
    }


def test_a_stations_program_is_replaced_by_the_users(sorter_line):
    (node,) = sorter_line.station(2).replace_program(example_program())
    assert node.get_namespace() == '/S02' and sorter_line.station(2).program == [node]
    for label, destination in (('U-1', 'D03'), ('U-2', 'D02'), ('U-3', 'D04')):
        sorter_line.induct(label, destination)
        sorter_line.run(2.5)
    assert sorter_line.run_until(lambda: len(sorter_line.dispositions) == 3, 30.0)
    got = {d.label: (d.code, d.chute) for d in sorter_line.dispositions}
    assert got == {'U-1': ('sorted', 'S02L'), 'U-2': ('sorted', 'S01R'), 'U-3': ('sorted', 'S02R')}
    assert node.beats > 0 and sorter_line.station(2).sim.cell.watchdog_trips == 0


def test_a_wait_on_the_line_that_times_out_explains_where_it_is(sorter_line):
    sorter_line.induct('W-1', 'D03')
    done = sorter_line.run_until(lambda: False, 0.5, what='a parcel that never leaves')
    assert not done
    text = str(done)
    for fact in (
        'waited 0.5 s of simulated time for a parcel that never leaves',
        'the line: t = 0.500 s simulated',
        'parcels: 1 inducted, 1 on the line, 0 waiting at the induction, 0 out',
        'dispositions: none',
        'S01: faults none, PackML Execute, program sorter_controller',
        'recording: ',
    ):
        assert fact in text, text
    with pytest.raises(AssertionError, match='W-1 to leave'):
        sorter_line.require(lambda: False, 0.1, what='W-1 to leave')


def test_bad_stations_plans_requests_and_programs_are_refused(sorter_line):
    import rclpy

    with pytest.raises(ValueError, match=r'station must be an integer in \[1, 2\]'):
        sorter_line.station(3)
    with pytest.raises(ValueError, match='refused'):
        sorter_line.set_plan({'D01': 'NOWHERE'})
    with pytest.raises(ValueError, match='request refused'):
        sorter_line.induct('bad label!', 'D01')
    with pytest.raises(ValueError, match='unknown argument'):
        sorter_line.induct('X-1', 'D01', colour='red')
    stray = rclpy.create_node('stray', namespace='/S09', context=sorter_line.context)
    try:
        with pytest.raises(ValueError, match="must be in '/S01'"):
            sorter_line.station(1).replace_program(stray)
    finally:
        stray.destroy_node()


def _program_at_s01(tmp_path, duration: float, parcels: str, expect: str):
    """Return a 2-station line scenario with the example program at S01, beside it."""
    (tmp_path / 'station_program.py').write_text((EXAMPLES / 'station_program.py').read_text())
    path = tmp_path / 'line.yaml'
    path.write_text(
        f'duration: {duration}\n'
        'line: {stations: 2, programs: {1: "station_program:StationProgram"}}\n'
        f'stream: {{parcels: {parcels}}}\nexpect: {expect}\n'
    )
    return load_scenario(path)


def test_two_runs_of_a_line_scenario_give_the_same_dispositions_at_the_same_times(tmp_path):
    sc = _program_at_s01(
        tmp_path,
        12.0,
        '[{label: R-1, at: 0.0, destination: D02}, {label: R-2, at: 2.5, destination: D03}]',
        '[{parcel: R-1, chute: S01R}, {parcel: R-2, chute: S02L}]',
    )
    first, second = run_scenario(sc), run_scenario(sc)
    assert first.passed, first.state
    key = [[(d.label, d.code, d.station, d.t) for d in r.dispositions] for r in (first, second)]
    assert len(key[0]) == 2 and key[0] == key[1]


def test_a_line_scenarios_recording_holds_every_stations_topics(tmp_path):
    from ros_harness import recorded_topic_counts

    sc = _program_at_s01(
        tmp_path,
        8.0,
        '[{label: R-2, at: 0.0, destination: D03}]',
        '[{parcel: R-2, chute: S02L}]',
    )
    record = tmp_path / 'line.mcap'
    res = run_scenario(sc, record=str(record))
    assert res.passed, res.state
    counts = recorded_topic_counts(record)
    # the warehouse hands station 2 the label station 1 read: on the line's record now,
    # as the user's program's own topics are
    assert counts['/S01/scanner/label'] == 1 and counts['/S02/scanner/label'] == 1, counts
    assert counts['/S01/controller/heartbeat'] > 10, counts


def outside(tmp_path, *args) -> subprocess.CompletedProcess:
    """Run ``args`` in a folder outside the project holding the example station program."""
    for name in ('station_program.py', 'test_station_program.py', 'line_scenario.yaml'):
        (tmp_path / name).write_text((EXAMPLES / name).read_text())
    done = subprocess.run(
        [sys.executable, *args], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done


def test_the_example_station_program_on_a_line_with_the_fixture(tmp_path):
    done = outside(
        tmp_path, '-m', 'pytest', '-q', '-p', 'no:cacheprovider', '-k', 'sorts_its_parcels'
    )
    assert '1 passed' in done.stdout


def test_the_example_station_program_through_its_scenario_file(tmp_path):
    done = outside(tmp_path, '-m', 'sorter_cell', 'scenario', 'run', 'line_scenario.yaml')
    assert 'passed' in done.stdout and '[ok] parcel A-1: disposition sorted' in done.stdout


@pytest.mark.parametrize(
    'text, message',
    [
        ('line: {stations: 0}\n', 'line.stations must be'),
        ('line: {stations: 2, speed: 1}\n', 'line: unknown key(s) speed'),
        ('line: {programs: {5: "math:floor"}}\n', 'a station is a number in [1, 2]'),
        ('line: {programs: {1: "nowhere_44:X"}}\n', "cannot import 'nowhere_44'"),
        ('line: {plan: [D01]}\n', 'line.plan must be a mapping'),
        ('line: {}\ncontroller: false\n', 'controller: a line scenario'),
    ],
)
def test_a_bad_line_scenario_is_refused_in_one_line(tmp_path, capsys, text, message):
    from sorter_cell.cli import main

    sc = tmp_path / 'line.yaml'
    sc.write_text('duration: 5\n' + text + 'expect: [{no_jam: true}]\n')
    assert main(['scenario', 'run', str(sc)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err


def test_the_contract_check_names_each_clause_a_program_breaks():
    base = example_program()

    class Mute(base):
        """The example without confirmations."""

        def confirm(self, *args):
            pass

    report = check_station_program(Mute)
    assert not report
    broken = {c.name for c in report.broken}
    assert broken == {'confirmations', 'passes on', 'packml'}, str(report)
    text = str(report)
    assert '[BROKEN] confirmations: no complete confirmation on /S01/sort/confirmations' in text
    assert "[BROKEN] passes on: K-NEXT (to the next station): lost" in text
    assert '[ok] heartbeat' in text and '[ok] sorts' in text


def test_the_contract_check_runs_from_pytest_outside_the_project(tmp_path):
    done = outside(
        tmp_path,
        '-m',
        'pytest',
        '-q',
        '-p',
        'no:cacheprovider',
        '--sorter-station-contract',
        'station_program:StationProgram',
        '-rA',
        '-k',
        'station_contract and not keeps',  # the option's test alone, not the example's own
    )
    assert '1 passed' in done.stdout
    # the passing check's id names the program's file, as its own tests' ids do
    assert (
        'PASSED station_program.py::station_contract[station_program:StationProgram]'
        in done.stdout.splitlines()
    ), done.stdout
