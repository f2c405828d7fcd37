"""
Scenario files and campaigns: ``sorter scenario run`` and ``sorter scenario campaign``.

The shipped examples run and pass; a scenario whose expectation fails exits 1 with
the failure in its JUnit file and its recording kept; a bad file is refused in
one line naming the key, before anything runs.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from sorter_cell.cli import main
from sorter_cell.testing.scenario import ScenarioError, load_scenario, run_scenario

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((REPO / 'config' / 'scenarios').glob('*.yaml'))


def test_the_examples_the_issue_asks_for_are_there():
    names = {load_scenario(p).name for p in EXAMPLES}
    assert {
        'default stream',
        'stuck divert eye',
        'lost controller',
        'e-stop mid divert',
        'dense stream',
    } <= names


@pytest.mark.parametrize('path', EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_each_example_scenario_passes(path):
    result = run_scenario(load_scenario(path))
    assert result.passed, [(c.text, c.detail) for c in result.checks if not c.passed]
    assert result.sim_s == pytest.approx(load_scenario(path).duration, abs=0.01)


def write(tmp_path, text: str, name: str = 'sc.yaml') -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_a_failed_expectation_exits_1_with_junit_and_the_recording(tmp_path, capsys):
    sc = write(
        tmp_path,
        """
        duration: 6.0
        controller: false
        stream:
          parcels: [{label: A-1, at: 0.0}]
        expect:
          - {parcel: A-1, exit: left}
          - {no_jam: true}
        """,
    )
    junit, rec = tmp_path / 'out.xml', tmp_path / 'evidence.mcap'
    assert main(['scenario', 'run', str(sc), '--junit', str(junit), '--record', str(rec)]) == 1
    out = capsys.readouterr().out
    assert '[FAIL] parcel A-1: exit left: got exit straight' in out and '[ok] no jam' in out
    suite = ET.parse(junit).getroot().find('testsuite')
    assert suite.get('tests') == '2' and suite.get('failures') == '1'
    (failure,) = suite.iter('failure')
    assert 'got exit straight' in failure.get('message') and str(rec) in failure.text
    # the evidence: an MCAP file with the cell's outcome in it
    from mcap.reader import make_reader

    with rec.open('rb') as f:
        topics = {ch.topic for _, ch, _ in make_reader(f).iter_messages()}
    assert '/sort/outcomes' in topics and '/sensors/edges' in topics


BAD = [
    ('duration: 5\nexpect: [{no_jam: true}]\nspeed: 3\n', 'unknown key(s) speed'),
    ('expect: [{no_jam: true}]\n', 'duration is missing'),
    ('duration: -1\nexpect: [{no_jam: true}]\n', 'duration must be in'),
    ('duration: 5\n', 'expect must be a non-empty list'),
    ('duration: 5\nexpect: [{no_jam: false}]\n', 'no_jam must be true'),
    ('duration: 5\nexpect: [{parcel: A}]\n', 'needs exit or result'),
    ('duration: 5\nexpect: [{parcel: A, exit: up}]\n', 'exit must be one of'),
    (
        'duration: 5\ncontroller: false\nexpect: [{parcel: A, result: sorted}]\n',
        'needs a controller',
    ),
    ('duration: 5\nexpect: [{at: 1, controller_state: dizzy}]\n', 'controller_state must be'),
    ('duration: 5\nexpect: [{at: 1, faults: [fire]}]\n', 'faults must be a list of'),
    ('duration: 5\ncell: {belt_speed: 99}\nexpect: [{no_jam: true}]\n', 'belt_speed'),
    ('duration: 5\ncell: {time_mode: fast}\nexpect: [{no_jam: true}]\n', 'cell.time_mode'),
    ('duration: 5\ncontroller: {bogus: 1}\nexpect: [{no_jam: true}]\n', 'unknown parameter'),
    (
        'duration: 5\nfaults: [{at: 1, fault: eye, sensor: pe_x}]\nexpect: [{no_jam: true}]\n',
        'needs mode',
    ),
    ('duration: 5\nfaults: [{at: 1, fault: quake}]\nexpect: [{no_jam: true}]\n', 'unknown fault'),
    ('duration: 5\nstream: {parcels: [{at: 1}]}\nexpect: [{no_jam: true}]\n', 'label must be'),
    (
        'duration: 5\nstream: {parcels: [{label: A, at: -1}]}\nexpect: [{no_jam: true}]\n',
        'parcels[0].at must be in',
    ),
    (
        'duration: 5\nstream: {parcels: [{label: A}, {label: A}]}\nexpect: [{no_jam: true}]\n',
        'labels must be unique',
    ),
    ('duration: 5\nstream: {generated: {belt: 1}}\nexpect: [{no_jam: true}]\n', 'generated'),
    (
        'duration: 5\nstream: {generated: {arrival_gap: [3, 1]}}\nexpect: [{no_jam: true}]\n',
        'arrival_gap',
    ),
    ('duration: 5\nduration: 6\nexpect: [{no_jam: true}]\n', 'appears twice'),
    ('duration: [5\n', 'not valid YAML'),
    ('- 1\n- 2\n', 'must be a mapping'),
]


@pytest.mark.parametrize('text, message', BAD, ids=[m for _, m in BAD])
def test_a_bad_scenario_is_refused_in_one_line_naming_the_key(tmp_path, capsys, text, message):
    sc = write(tmp_path, text)
    with pytest.raises(ScenarioError, match='.*'):
        load_scenario(sc)
    assert main(['scenario', 'run', str(sc)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert str(sc) in err and 'Traceback' not in err


def test_a_campaign_runs_each_scenario_per_seed_in_its_own_process(tmp_path):
    folder = tmp_path / 'campaign'
    folder.mkdir()
    write(
        folder,
        """
        name: straight on
        duration: 5.0
        controller: false
        stream: {parcels: [{label: P-1, at: 0.0}]}
        expect: [{parcel: P-1, exit: straight}]
        """,
        'ok.yaml',
    )
    write(
        folder,
        """
        name: wrong wish
        duration: 5.0
        controller: false
        stream: {parcels: [{label: P-1, at: 0.0}]}
        expect: [{parcel: P-1, exit: right}]
        """,
        'fails.yaml',
    )
    junit = tmp_path / 'campaign.xml'
    done = subprocess.run(
        [
            sys.executable,
            '-m',
            'sorter_cell',
            'scenario',
            'campaign',
            str(folder),
            '--workers',
            '2',
            '--seeds',
            '2',
            '--junit',
            str(junit),
            '--quiet',
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 1, done.stderr[-2000:]
    assert '4 runs in' in done.stdout and '2 passed, 2 failed' in done.stdout
    assert (
        'FAILED wrong wish (seed 1)' in done.stdout and 'FAILED wrong wish (seed 2)' in done.stdout
    )
    suites = ET.parse(junit).getroot().findall('testsuite')
    assert sorted(s.get('name') for s in suites) == [
        'straight on [seed 1]',
        'straight on [seed 2]',
        'wrong wish [seed 1]',
        'wrong wish [seed 2]',
    ]


def test_a_campaign_with_a_bad_file_runs_nothing(tmp_path, capsys):
    folder = tmp_path / 'c'
    folder.mkdir()
    write(folder, 'duration: 5\nexpect: [{no_jam: true}]\n', 'a.yaml')
    write(folder, 'duration: 5\n', 'b.yaml')
    assert main(['scenario', 'campaign', str(folder)]) == 2
    err = capsys.readouterr().err
    assert 'b.yaml' in err and 'expect must be' in err
    assert main(['scenario', 'campaign', str(tmp_path / 'nowhere')]) == 2
    assert 'not a folder' in capsys.readouterr().err
    assert main(['scenario', 'campaign', str(folder), '--workers', '0']) == 2


def test_a_campaign_on_an_existing_dask_scheduler(tmp_path):
    from distributed import LocalCluster

    folder = tmp_path / 'c'
    folder.mkdir()
    write(
        folder,
        """
        duration: 4.0
        controller: false
        stream: {parcels: [{label: P-1, at: 0.0}]}
        expect: [{no_jam: true}]
        """,
        'one.yaml',
    )
    with LocalCluster(
        n_workers=1, threads_per_worker=2, processes=True, dashboard_address=None
    ) as cluster:
        done = subprocess.run(
            [
                sys.executable,
                '-m',
                'sorter_cell',
                'scenario',
                'campaign',
                str(folder),
                '--seeds',
                '2',
                '--scheduler',
                cluster.scheduler_address,
                '--quiet',
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert '2 runs in' in done.stdout and '2 passed, 0 failed' in done.stdout
    bad = subprocess.run(
        [
            sys.executable,
            '-m',
            'sorter_cell',
            'scenario',
            'campaign',
            str(folder),
            '--scheduler',
            'tcp://127.0.0.1:9',
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode == 2 and 'cannot reach a Dask scheduler' in bad.stderr
