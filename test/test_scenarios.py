"""
Scenario files and campaigns: ``sorter scenario run`` and ``sorter scenario campaign``.

The shipped examples run and pass; a scenario whose expectation fails exits 1 with
the failure in its JUnit file and its recording kept; a bad file is refused in
one line naming the key, before anything runs.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from sorter_cell.cli import main
from sorter_cell.testing.scenario import Check, ScenarioError, load_scenario, report, run_scenario

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((REPO / 'config' / 'scenarios').glob('*.yaml'))
USER_EXAMPLES = REPO / 'examples'


def test_the_examples_the_issue_asks_for_are_there():
    names = {load_scenario(p).name for p in EXAMPLES}
    assert {
        'default stream',
        'stuck divert eye',
        'lost controller',
        'e-stop mid divert',
        'dense stream',
        'touching stream without gap rules',
        'stopper queue',
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
    # the failure explains itself: where the cell was when the run ended
    for fact in (
        'the cell: t = ',
        's wall since it started',
        'parcels: 1 inducted, 0 on the cell, 0 waiting at the induction, 1 out: A-1 straight at',
        'faults: none; PackML: Execute',
        f'recording: {rec}',
    ):
        assert fact in out, out
    suite = ET.parse(junit).getroot().find('testsuite')
    assert suite.get('tests') == '2' and suite.get('failures') == '1'
    (failure,) = suite.iter('failure')
    assert 'got exit straight' in failure.get('message') and str(rec) in failure.text
    assert 'parcels: 1 inducted' in failure.text and 'PackML: Execute' in failure.text
    # the evidence: an MCAP file with the cell's outcome in it
    from mcap.reader import make_reader

    with rec.open('rb') as f:
        topics = {ch.topic for _, ch, _ in make_reader(f).iter_messages()}
    assert '/sort/outcomes' in topics and '/sensors/edges' in topics


def test_without_record_the_evidence_is_kept_for_a_failure_only(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv('TMPDIR', str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, 'tempdir', None)  # TMPDIR is read again
    stream = 'stream: {parcels: [{label: A-1, at: 0.0}]}\n'
    good = write(
        tmp_path, f'duration: 1.0\ncontroller: false\n{stream}expect: [{{no_jam: true}}]\n'
    )
    assert main(['scenario', 'run', str(good)]) == 0
    assert 'recording' not in capsys.readouterr().out
    assert not list(tmp_path.glob('sorter-scenario-*'))
    bad = write(
        tmp_path,
        f'duration: 1.0\ncontroller: false\n{stream}expect: [{{parcel: A-1, exit: left}}]\n',
        'bad.yaml',
    )
    assert main(['scenario', 'run', str(bad)]) == 1
    out = capsys.readouterr().out
    (kept,) = tmp_path.glob('sorter-scenario-*/bad.mcap')
    assert f'recording: {kept}' in out and kept.stat().st_size > 0
    assert main(['scenario', 'run', str(bad), '--no-record']) == 1
    assert 'recording' not in capsys.readouterr().out


def test_the_users_node_runs_in_lock_step_and_two_runs_agree():
    sc = load_scenario(USER_EXAMPLES / 'minimal_controller_scenario.yaml')
    assert sc.controller.kind == 'node'
    first, second = run_scenario(sc), run_scenario(sc)
    assert first.passed, first.state
    exits = [[(o.label, o.exit, o.t) for o in r.outcomes] for r in (first, second)]
    assert len(exits[0]) == 4 and exits[0] == exits[1]


def test_a_scenarios_recording_holds_the_controllers_topics_too(tmp_path):
    from ros_harness import recorded_topic_counts

    (tmp_path / 'minimal_controller.py').write_text(
        (USER_EXAMPLES / 'minimal_controller.py').read_text()
    )
    sc = write(
        tmp_path,
        """
        duration: 4.0
        cell: {alpha_deg: 90.0}
        controller: {node: "minimal_controller:MinimalController"}
        stream: {parcels: [{label: L-1, at: 0.0}]}
        expect: [{parcel: L-1, exit: left}]
        """,
    )
    record = tmp_path / 'run.mcap'
    res = run_scenario(load_scenario(sc), record=str(record))
    assert res.passed, res.state
    counts = recorded_topic_counts(record)
    # the user's node's heartbeat (every 50 ms) beside what the cell writes, once
    assert counts['/controller/heartbeat'] > 40, counts
    assert counts['/sort/outcomes'] == 1, counts


def test_the_users_controller_as_a_process_follows_the_cells_clock(tmp_path):
    # from outside the project, as a third party runs it
    for name in ('minimal_controller.py', 'run_minimal_controller.py'):
        (tmp_path / name).write_text((USER_EXAMPLES / name).read_text())
    sc = tmp_path / 'process.yaml'
    sc.write_text((USER_EXAMPLES / 'minimal_controller_process.yaml').read_text())
    done = subprocess.run(
        [sys.executable, '-m', 'sorter_cell', 'scenario', 'run', str(sc), '--no-record'],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert '[ok] parcel L-1: exit left' in done.stdout


def test_a_controller_process_that_ends_early_fails_the_run_with_its_exit_code(tmp_path):
    sc = write(
        tmp_path,
        """
        duration: 2.0
        controller: {command: ["{python}", "-c", "import sys; sys.exit(3)"], start_timeout: 20}
        expect: [{no_jam: true}]
        """,
    )
    result = run_scenario(load_scenario(sc))
    assert not result.passed
    assert 'ended with exit code 3 before it subscribed' in result.error


BAD = [
    ('duration: 5\nexpect: [{no_jam: true}]\nspeed: 3\n', 'unknown key(s) speed'),
    ('expect: [{no_jam: true}]\n', 'duration is missing'),
    ('duration: -1\nexpect: [{no_jam: true}]\n', 'duration must be in'),
    ('duration: 5\n', 'expect must be a non-empty list'),
    ('duration: 5\nexpect: [{no_jam: false}]\n', 'no_jam must be true'),
    ('duration: 5\nexpect: [{parcel: A}]\n', 'needs exit or result'),
    ('duration: 5\nexpect: [{parcel: A, exit: up}]\n', 'exit must be one of'),
    ('duration: 5\nexpect: [{parcel: A, exit: left, cause: rail}]\n', 'needs exit: jammed'),
    ('duration: 5\nexpect: [{parcel: A, exit: jammed, cause: 7}]\n', 'cause must be what'),
    ('duration: 5\nexpect: [{parcel: A, exit: jammed, cause: stopper}]\n', 'or parcel <id>'),
    ('duration: 5\nexpect: [{parcel: A, exit: jammed, cause: parcel A}]\n', 'or parcel <id>'),
    (
        'duration: 5\ncell: {rails: [-0.6, -0.35, -0.6]}\nexpect: [{no_jam: true}]\n',
        "'rails' takes 4 numbers a rail",
    ),
    (
        'duration: 5\ncell: {contact: jam, rails: [-0.6, -0.35, -0.6, 0.35]}\n'
        'expect: [{no_jam: true}]\n',
        "'rails' needs contact: rigid",
    ),
    (
        'duration: 5\ncell: {rails: [-0.6, -0.35, 9.0, 0.35]}\nexpect: [{no_jam: true}]\n',
        'off the cell',
    ),
    (
        'duration: 5\ncontroller: false\nexpect: [{parcel: A, result: sorted}]\n',
        'needs a controller',
    ),
    ('duration: 5\nexpect: [{at: 1, controller_state: dizzy}]\n', 'controller_state must be'),
    ('duration: 5\nexpect: [{at: 1, faults: [fire]}]\n', 'faults must be a list of'),
    ('duration: 5\ncell: {belt_speed: 99}\nexpect: [{no_jam: true}]\n', 'belt_speed'),
    ('duration: 5\ncell: {time_mode: fast}\nexpect: [{no_jam: true}]\n', 'cell.time_mode'),
    ('duration: 5\ncontroller: {bogus: 1}\nexpect: [{no_jam: true}]\n', 'unknown parameter'),
    ('duration: 5\ncontroller: true\nexpect: [{no_jam: true}]\n', 'controller must be false'),
    ('duration: 5\ncontroller: {node: nocolon}\nexpect: [{no_jam: true}]\n', 'module:callable'),
    (
        'duration: 5\ncontroller: {node: "no_such_module_44:X"}\nexpect: [{no_jam: true}]\n',
        "cannot import 'no_such_module_44'",
    ),
    (
        'duration: 5\ncontroller: {node: "math:nothing"}\nexpect: [{no_jam: true}]\n',
        "'math' has no 'nothing'",
    ),
    (
        'duration: 5\ncontroller: {node: "math:pi"}\nexpect: [{no_jam: true}]\n',
        'is not callable',
    ),
    (
        'duration: 5\ncontroller: {node: "math:floor", speed: 1}\nexpect: [{no_jam: true}]\n',
        'unknown key(s) speed with node',
    ),
    (
        'duration: 5\ncontroller: {node: "rclpy.node:Node", parameters: {a: {b: 1}}}\n'
        'expect: [{no_jam: true}]\n',
        'controller.parameters.a',
    ),
    ('duration: 5\ncontroller: {command: ls}\nexpect: [{no_jam: true}]\n', 'command must be'),
    (
        'duration: 5\ncontroller: {command: [ls], start_timeout: 0}\nexpect: [{no_jam: true}]\n',
        'start_timeout must be in',
    ),
    (
        'duration: 5\ncontroller: {command: [ls]}\nexpect: [{at: 1, controller_state: jam}]\n',
        "needs this project's controller",
    ),
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
    (
        'duration: 5\ncontroller: {command: [ls, "a\\0b"]}\nexpect: [{no_jam: true}]\n',
        'controller.command[1]',
    ),
    (
        'duration: 5\ncontroller: {node: "os:getcwd"}\nexpect: [{no_jam: true}]\n',
        "'os:getcwd' is not a node factory: it takes no context=, parameter_overrides=",
    ),
    (
        'duration: 5\nline: {programs: {1: "os:getcwd"}}\nexpect: [{no_jam: true}]\n',
        "line.programs.1 'os:getcwd' is not a node factory",
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


# (where in the document, the bad value): a key a cell's and a line's scenario share
SHARED_BAD = [
    (path, value)
    for path in (
        ('duration',),
        ('seed',),
        ('name',),
        ('stream', 'parcels', 0, 'at'),
        ('stream', 'parcels', 0, 'length'),
        ('stream', 'parcels', 0, 'mass'),
        ('stream', 'parcels', 0, 'label'),
        ('expect', 0, 'throughput_at_least'),
        ('expect', 0, 'no_jam'),
    )
    for value in (float('nan'), float('inf'), -1, '1', True, None, [1])
]


@pytest.mark.parametrize(
    'path, value', SHARED_BAD, ids=[f'{".".join(map(str, p))}={v!r}' for p, v in SHARED_BAD]
)
def test_a_key_a_cell_and_a_line_share_is_checked_the_same_way_in_both(path, value):
    from sorter_cell.testing.scenario import check_scenario

    def doc(form: dict) -> dict:
        d = {
            'duration': 5.0,
            'stream': {'parcels': [{'label': 'A-1', 'at': 0.0}]},
            'expect': [{'throughput_at_least': 10}],
            **form,
        }
        if path[0] == 'expect':
            d['expect'] = [{}]  # the one kind the entry names
        where = d
        for step in path[:-1]:
            where = where[step]
        where[path[-1]] = value
        return d

    said = []
    for form in ({'controller': False}, {'line': {'stations': 2}}):
        try:
            check_scenario(doc(form))
        except ScenarioError as exc:
            said.append(str(exc))
        else:
            said.append('taken')
    cell, line = said
    assert cell == line.replace(' (on a line)', ''), (cell, line)


def test_a_factory_that_raises_is_refused_in_one_line(tmp_path, capsys):
    (tmp_path / 'raising.py').write_text(
        'def make(context, parameter_overrides):\n    raise RuntimeError("no plc here")\n'
    )
    sc = write(
        tmp_path,
        """
        duration: 1.0
        controller: {node: "raising:make"}
        expect: [{no_jam: true}]
        """,
    )
    assert main(['scenario', 'run', str(sc), '--no-record']) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and str(sc) in err, err
    assert "'raising:make' raised RuntimeError making its node: no plc here" in err, err
    assert 'Traceback' not in err and captured.out == ''


def test_a_callback_that_blocks_is_reported_with_its_duration(tmp_path):
    (tmp_path / 'sleepy.py').write_text(
        textwrap.dedent(
            """
            import time

            from rclpy.node import Node


            class Sleepy(Node):
                def __init__(self, **kwargs):
                    super().__init__('sleepy', **kwargs)
                    self.slept = False
                    self.create_timer(0.1, self.tick)

                def tick(self):
                    if not self.slept:
                        self.slept = True
                        time.sleep(1.5)
            """
        )
    )
    sc = write(
        tmp_path,
        """
        duration: 1.0
        controller: {node: "sleepy:Sleepy"}
        expect: [{no_jam: true}]
        """,
    )
    result = run_scenario(load_scenario(sc))
    assert result.passed, result.error
    (note,) = result.notes
    assert "'sleepy' timer of 0.1 s blocked for" in note and 'at t = 0.1' in note, note
    took = float(note.split('blocked for ')[1].split(' s')[0])
    assert took >= 1.5  # slept 1.5 s at least; more on a loaded machine
    assert note in report(result)


def _alive(pid: int) -> bool:
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[-1].split()[0]
    except OSError:
        return False
    return state != 'Z'


def test_a_command_is_ended_with_every_process_it_started(tmp_path):
    # the command and its child both ignore SIGTERM; neither ever subscribes to /clock
    pidfile = tmp_path / 'grandchild.pid'
    child = (
        'import os, signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); '
        f'open({str(pidfile)!r}, "w").write(str(os.getpid())); time.sleep(600)'
    )
    command = (
        'import signal, subprocess, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); '
        f'subprocess.Popen([sys.executable, "-c", {child!r}]); time.sleep(600)'
    )
    sc = write(
        tmp_path,
        f"""
        duration: 1.0
        controller: {{command: ["{{python}}", "-c", {json.dumps(command)}], start_timeout: 8}}
        expect: [{{no_jam: true}}]
        """,
    )
    result = run_scenario(load_scenario(sc))
    assert 'did not subscribe to /clock within 8 s' in result.error, result.error
    pid = int(pidfile.read_text())
    assert not _alive(pid), 'the grandchild outlived the run'


def test_a_junit_file_stays_xml_whatever_the_text_holds():
    from sorter_cell.testing.scenario import ScenarioResult, junit_xml

    r = ScenarioResult('name \x1b[31mred\x07', error='stderr: \x00\x1b[0m bell \x07 end')
    r.checks = [Check('check \x1b', False, 'detail \x0b\x0c')]
    root = ET.fromstring(junit_xml([r]).split('\n', 1)[1])  # parses: valid XML 1.0
    suite = root.find('testsuite')
    assert suite.get('name') == 'name \\x1b[31mred\\x07'
    assert '\\x00\\x1b[0m bell \\x07 end' in suite.find('testcase/failure').get('message')


def test_a_campaign_refusing_a_file_imports_no_module_of_another(tmp_path, capsys):
    folder = tmp_path / 'c'
    folder.mkdir()
    marker = tmp_path / 'imported'
    (folder / 'noisy.py').write_text(
        f'open({str(marker)!r}, "w").write("top level run")\n'
        'def make(context, parameter_overrides):\n    return None\n'
    )
    write(
        folder,
        'duration: 5\ncontroller: {node: "noisy:make"}\nexpect: [{no_jam: true}]\n',
        'a.yaml',
    )
    write(folder, 'duration: 5\n', 'b.yaml')
    write(
        folder,
        'duration: 5\ncontroller: {node: "absent_44:make"}\nexpect: [{no_jam: true}]\n',
        'c.yaml',
    )
    assert main(['scenario', 'campaign', str(folder)]) == 2
    err = capsys.readouterr().err
    assert 'b.yaml' in err and 'expect must be' in err, err
    assert not marker.exists()
    (folder / 'b.yaml').unlink()
    assert main(['scenario', 'campaign', str(folder)]) == 2
    err = capsys.readouterr().err
    assert 'c.yaml' in err and "cannot import 'absent_44'" in err, err
    assert not marker.exists()


def _user_project(root: Path, module: str) -> Path:
    """Make a user's project: their controller module at its top, scenarios in scenarios/."""
    (root / f'{module}.py').write_text((USER_EXAMPLES / 'minimal_controller.py').read_text())
    folder = root / 'scenarios'
    folder.mkdir()
    write(
        folder,
        f"""
        duration: 4.0
        cell: {{alpha_deg: 90.0}}
        controller: {{node: "{module}:MinimalController"}}
        stream: {{parcels: [{{label: L-1, at: 0.0}}]}}
        expect: [{{parcel: L-1, exit: left}}]
        """,
        'node.yaml',
    )
    return folder


def _installed_sorter(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    # the console script, whose sys.path holds neither the project nor a file's folder
    # (python -m would put the directory it starts in first)
    sorter = Path(sys.executable).parent / 'sorter'
    return subprocess.run(
        [str(sorter), *args], cwd=cwd, capture_output=True, text=True, timeout=120
    )


def test_a_scenario_in_a_subfolder_imports_the_users_module_from_where_the_command_runs(
    tmp_path,
):
    _user_project(tmp_path, 'vowel_sorter')
    done = _installed_sorter(tmp_path, 'scenario', 'run', 'scenarios/node.yaml', '--no-record')
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]


def test_a_campaign_of_a_subfolder_imports_the_users_module_from_where_the_command_runs(
    tmp_path,
):
    # checked, then each run started, from there
    _user_project(tmp_path, 'vowel_sorter')
    done = _installed_sorter(
        tmp_path, 'scenario', 'campaign', 'scenarios', '--seeds', '1', '--workers', '1', '--quiet'
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert '1 passed, 0 failed' in done.stdout


def test_a_users_module_found_nowhere_is_refused_naming_where_it_was_looked_for(
    tmp_path, monkeypatch, capsys
):
    folder = _user_project(tmp_path, 'vowel_sorter_elsewhere')
    (tmp_path / 'vowel_sorter_elsewhere.py').unlink()
    project = tmp_path / 'project'
    project.mkdir()
    monkeypatch.chdir(project)
    assert main(['scenario', 'run', '../scenarios/node.yaml']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert (
        f"cannot import 'vowel_sorter_elsewhere' (looked in ../scenarios, {project} "
        "(the current directory), then sys.path): ModuleNotFoundError"
    ) in err, err
    # nothing of the search is left on the path
    assert str(project) not in sys.path and '../scenarios' not in sys.path
    assert folder.is_dir()


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


def test_the_campaign_table_stays_aligned_with_long_names():
    from sorter_cell.scenario_cli import campaign_table

    run = {'passed': True, 'sim_s': 5.0, 'wall_s': 2.0, 'process_s': 3.0}
    names = ['short', 'a scenario whose name runs well past thirty-two characters']
    rows = [{**run, 'name': n} for n in names] + [{**run, 'name': 'short', 'passed': False}]
    lines = campaign_table(rows).splitlines()
    assert len(lines) == 3
    # every column ends where the header's does, on every line
    for column in ('runs', 'passed', 'failed', 'sim s', 'run s', 'process s'):
        end = lines[0].index(column) + len(column)
        assert all(line[end - 1] != ' ' and line[end : end + 1] in ('', ' ') for line in lines)
    assert lines[1].split()[-6:] == ['2', '1', '1', '5.0', '2.0', '3.0']


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


def _listening_here() -> set:
    """Return the TCP addresses this process listens on, as 'host:port' (from /proc)."""
    import os

    mine = set()
    for fd in os.listdir('/proc/self/fd'):
        try:
            link = os.readlink(f'/proc/self/fd/{fd}')
        except OSError:
            continue
        if link.startswith('socket:['):
            mine.add(link[8:-1])
    out = set()
    for table, width in (('/proc/net/tcp', 8), ('/proc/net/tcp6', 32)):
        for row in Path(table).read_text().splitlines()[1:]:
            cols = row.split()
            if cols[3] != '0A' or cols[9] not in mine:  # 0A: LISTEN
                continue
            host, port = cols[1].split(':')
            out.add(('127.0.0.1' if host == '0100007F' else host) + f':{int(port, 16)}')
    return out


def test_two_campaigns_on_one_host_listen_on_loopback_only_and_on_ports_of_their_own():
    import warnings

    from sorter_cell.scenario_cli import local_cluster

    before = _listening_here()
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter('always')
        with local_cluster(1) as one, local_cluster(1) as two:
            opened = _listening_here() - before
            assert one.dashboard_link != two.dashboard_link
    # the scheduler's and the worker's HTTP servers of each, and nothing else
    assert len(opened) == 4 and all(a.startswith('127.0.0.1:') for a in opened), opened
    assert not [w for w in said if 'already in use' in str(w.message)], [
        str(w.message) for w in said
    ]


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
        n_workers=1,
        threads_per_worker=2,
        processes=True,
        dashboard_address='127.0.0.1:0',
        worker_dashboard_address='127.0.0.1:0',
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
    # refused at once, not after dask's 10 s of connecting again (sorter_sim.studies.scheduler)
    assert 'connection refused: nothing listens on 127.0.0.1 port 9' in bad.stderr, bad.stderr
    beyond = subprocess.run(
        [sys.executable, '-m', 'sorter_cell', 'scenario', 'campaign', str(folder)]
        + ['--scheduler', 'tcp://127.0.0.1:99999'],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert beyond.returncode == 2, beyond.stderr
    assert 'port 99999 is not a TCP port: it must be in 1-65535' in beyond.stderr, beyond.stderr


def campaign(folder, *args, env=None) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, '-m', 'sorter_cell', 'scenario', 'campaign', str(folder), '--quiet']
        + list(args),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def runs(junit) -> list[dict]:
    out = []
    for suite in ET.parse(junit).getroot().findall('testsuite'):
        props = {p.get('name'): p.get('value') for p in suite.iter('property')}
        out.append({'name': suite.get('name'), **props})
    return out


def test_two_campaigns_at_once_never_share_a_domain(tmp_path):
    import os

    folder = tmp_path / 'c'
    folder.mkdir()
    write(
        folder,
        """
        duration: 1.0
        controller: false
        expect: [{no_jam: true}]
        """,
        'one.yaml',
    )
    # the lock files in a folder of this test's own: no other run of the suite meets them
    env = dict(os.environ, SORTER_DOMAIN_LOCKS=str(tmp_path / 'locks'))
    env['SORTER_CAMPAIGN_DOMAINS'] = '150'  # one domain for two campaigns: one run waits
    junits = [tmp_path / 'a.xml', tmp_path / 'b.xml']
    procs = [campaign(folder, '--workers', '1', '--junit', str(j), env=env) for j in junits]
    for proc in procs:
        out, err = proc.communicate(timeout=150)
        assert proc.returncode == 0, out[-2000:] + err[-2000:]
    (a,), (b,) = (runs(j) for j in junits)
    assert a['ros_domain'] == b['ros_domain'] == '150'
    first, second = sorted((a, b), key=lambda r: float(r['wall_start']))
    assert float(second['wall_start']) >= float(first['wall_end'])  # one at a time


def test_the_domain_range_is_an_option_and_a_variable_checked_before_anything_runs(
    tmp_path, capsys, monkeypatch
):
    from sorter_cell.testing.domains import DomainClaim, campaign_domains

    folder = tmp_path / 'c'
    folder.mkdir()
    write(folder, 'duration: 1\nexpect: [{no_jam: true}]\n', 'a.yaml')
    for bad in ('140-', '171-140', '140-300', 'x'):
        assert main(['scenario', 'campaign', str(folder), '--domains', bad]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and '--domains must be a ROS domain range A-B' in err
    monkeypatch.setenv('SORTER_CAMPAIGN_DOMAINS', '7-3')
    assert main(['scenario', 'campaign', str(folder)]) == 2
    assert 'SORTER_CAMPAIGN_DOMAINS must be' in capsys.readouterr().err
    assert campaign_domains('140-171') == range(140, 172)
    monkeypatch.setenv('SORTER_CAMPAIGN_DOMAINS', '160-161')
    assert campaign_domains(None) == range(160, 162)
    monkeypatch.setenv('SORTER_DOMAIN_LOCKS', str(tmp_path / 'locks'))
    with DomainClaim(range(160, 162)) as a, DomainClaim(range(160, 162)) as b:
        assert {a, b} == {160, 161}
        with pytest.raises(TimeoutError, match='held by other runs'):
            DomainClaim(range(160, 162), timeout_s=0.2).acquire()
    with DomainClaim(range(160, 162)) as again:
        assert again == 160  # let go at the end of the block


def test_a_campaign_of_the_users_node_repeats_its_exits(tmp_path):
    folder = tmp_path / 'c'
    folder.mkdir()
    # the module is found from the scenario file's folder
    (folder / 'minimal_controller.py').write_text(
        (USER_EXAMPLES / 'minimal_controller.py').read_text()
    )
    write(
        folder,
        """
        duration: 4.0
        cell: {alpha_deg: 90.0}
        controller: {node: "minimal_controller:MinimalController"}
        stream: {parcels: [{label: L-1, at: 0.0}, {label: S-1, at: 0.5}]}
        expect: [{parcel: L-1, exit: left}]
        """,
        'node.yaml',
    )
    junit = tmp_path / 'c.xml'
    proc = campaign(folder, '--workers', '2', '--seeds', '2', '--junit', str(junit))
    out, err = proc.communicate(timeout=150)
    assert proc.returncode == 0, out[-2000:] + err[-2000:]
    exits = [r['exits'] for r in runs(junit)]
    assert len(exits) == 2 and exits[0] == exits[1] and 'L-1 left' in exits[0]
