"""
What ``sorter scenario run`` writes: only where it is told, never over a file it did not write.

A recording a scenario file names lies in the scenario's folder (a path leaving it is
refused; one given on the command line may go anywhere); no folder is created; a file
already there is replaced only if it is a recording (or a JUnit report) this command
wrote; a write that fails is one line and exit 2; the result names the recording.
"""

from __future__ import annotations

import json
import textwrap

from sorter_cell.cli import main

SCENARIO = """
duration: 1.0
controller: false
stream:
  parcels: [{label: A-1, at: 0.0}]
expect:
  - {no_jam: true}
"""


def write(folder, text, name='sc.yaml'):
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / name
    p.write_text(textwrap.dedent(text))
    return p


def test_a_scenario_may_not_record_outside_its_folder_nor_over_another_file(tmp_path, capsys):
    victim = tmp_path / 'x' / 'victim.mcap'
    victim.parent.mkdir()
    victim.write_text('not a recording: precious')
    sc = write(tmp_path / 'sc', SCENARIO + 'cell: {record_path: ../x/victim.mcap}\n')
    assert main(['scenario', 'run', str(sc)]) == 2
    err = capsys.readouterr().err
    assert 'writes only inside its own folder' in err and len(err.strip().splitlines()) == 1
    # inside its folder, but a file that is not a recording: kept
    (tmp_path / 'sc' / 'notes.mcap').write_text('my notes')
    sc2 = write(tmp_path / 'sc', SCENARIO + 'cell: {record_path: notes.mcap}\n', 'sc2.yaml')
    assert main(['scenario', 'run', str(sc2)]) == 2
    assert 'is not a recording this command wrote: not overwritten' in capsys.readouterr().err
    # on the command line too
    assert main(['scenario', 'run', str(sc), '--record', str(victim)]) == 2
    assert 'not overwritten' in capsys.readouterr().err
    assert victim.read_text() == 'not a recording: precious'
    assert (tmp_path / 'sc' / 'notes.mcap').read_text() == 'my notes'


def test_the_result_names_the_recording_the_scenario_made_in_its_folder(tmp_path, capsys):
    sc = write(tmp_path / 'sc', SCENARIO + 'cell: {record_path: run.mcap}\n')
    assert main(['scenario', 'run', str(sc), '--json']) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    rec = tmp_path / 'sc' / 'run.mcap'
    assert result['record'] == str(rec) and rec.read_bytes().startswith(b'\x89MCAP0')
    # a recording of an earlier run is replaced
    assert main(['scenario', 'run', str(sc), '--json']) == 0


def test_no_folder_is_made_and_a_failed_write_is_one_line_exit_2(tmp_path, capsys):
    sc = write(tmp_path, SCENARIO)
    for flag in ('--junit', '--record'):
        target = tmp_path / 'made' / 'by' / ('out.xml' if flag == '--junit' else 'r.mcap')
        assert main(['scenario', 'run', str(sc), flag, str(target)]) == 2
        assert 'does not exist (it is not created)' in capsys.readouterr().err
        assert not (tmp_path / 'made').exists()
    assert main(['scenario', 'run', str(sc), '--junit', '/dev/full']) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and '--junit' in err and 'Traceback' not in err


def test_the_line_demo_refuses_zero_segments(capsys):
    assert main(['demo', '--stations', '3', '--segments', '0']) == 2
    assert '--segments must be an integer in [1, --stations]' in capsys.readouterr().err


def test_a_bad_expectation_value_exits_2_naming_its_key(tmp_path, capsys):
    sc = write(tmp_path, 'duration: 1.0\nexpect: [{at: 1, faults: [[1]]}]\n')
    assert main(['scenario', 'run', str(sc)]) == 2
    err = capsys.readouterr().err
    assert 'expect[0].faults must be a list of estop, jam, watchdog' in err
    assert 'Traceback' not in err and len(err.strip().splitlines()) == 1
