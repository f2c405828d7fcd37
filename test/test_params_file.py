"""Parameters files read without ROS: config/controller.yaml as the demo plans with it."""

from pathlib import Path

import pytest

from sorter_cell.demo import _controller_values
from sorter_ros.params_file import read_params_file
from sorter_ros.strict_yaml import MAX_BYTES

CONFIG = Path(__file__).resolve().parents[1] / 'config'


def _config_with(tmp_path, old: str, new: str) -> Path:
    text = (CONFIG / 'controller.yaml').read_text()
    assert old in text
    (tmp_path / 'controller.yaml').write_text(text.replace(old, new, 1))
    return tmp_path


def test_the_shipped_controller_file_is_complete_and_valid():
    given = read_params_file(CONFIG / 'controller.yaml', 'sorter_controller')
    values = _controller_values(CONFIG)
    assert set(given) - {'use_sim_time'} <= set(values)
    assert values['scan_period'] == given['scan_period'] == 0.01
    assert given['photo_eyes.names'] == ['pe_scan', 'pe_divert', 'pe_exit']


@pytest.mark.parametrize(
    'old, new, words',
    [
        ('scan_period: 0.01', 'scan_period: -0.01', ["'scan_period'", '[0.001, 0.1]', '-0.01']),
        ('scan_period: 0.01', 'scan_period: .nan', ["'scan_period'", 'finite']),
        ('jam_margin: 0.5', 'jam_margin: fast', ["'jam_margin'", "'fast'"]),
        ('clearance: 0.02', 'clearence: 0.02', ["unknown controller parameter", "'clearence'"]),
        (
            'clearance: 0.02',
            'clearance: 0.02\n    clearance: 0.03',
            ['appears twice', "'clearance'"],
        ),
        ('/**/sorter_controller:', '/**/other_node:', ["no section for node 'sorter_controller'"]),
    ],
)
def test_a_bad_controller_file_is_refused_naming_the_key(tmp_path, old, new, words):
    config_dir = _config_with(tmp_path, old, new)
    with pytest.raises(ValueError) as err:
        _controller_values(config_dir)
    text = str(err.value)
    assert 'controller.yaml' in text
    for w in words:
        assert w in text, text


def test_files_that_are_not_parameters_files_are_refused(tmp_path):
    cases = {
        'list.yaml': '- a\n- b\n',
        'broken.yaml': 'a: [1, 2\n',
        'flat.yaml': '/**/n:\n  x: 1\n',
        'big.yaml': '#' * (MAX_BYTES + 1),
    }
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ValueError, match=name):
            read_params_file(tmp_path / name, 'n')
    with pytest.raises(ValueError, match='cannot read'):
        read_params_file(tmp_path / 'missing.yaml', 'n')


def _refused_by_run_node(args, capsys) -> str:
    """Run a node's start-up on ``args``; it must exit 2 before rcl or the node is made."""
    import rclpy

    from sorter_ros.env import run_node

    def never():
        raise AssertionError('the node was made')

    with pytest.raises(SystemExit) as exc:
        run_node(never, 'wcs_node', args=['wcs_node', '--ros-args', *args])
    assert exc.value.code == 2 and not rclpy.ok()
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith('wcs_node: ') and len(err) < 500, err
    return err


def test_a_params_file_rcl_would_read_without_bounds_is_refused_first(tmp_path, capsys):
    def params(name: str, body: str) -> str:
        path = tmp_path / name
        path.write_text('/**:\n  ros__parameters:\n' + body)
        return str(path)

    huge = params('huge.yaml', f'    frame_id: {"x" * 50_000_000}\n')
    long_value = params('long.yaml', f'    frame_id: {"x" * 900_000}\n')
    twice = params('twice.yaml', '    frame_id: a\n    frame_id: b\n')
    many = params('many.yaml', ''.join(f'    unknown_{k}: {k}\n' for k in range(3000)))
    deep = params('deep.yaml', '    frame_id: ' + '[' * 100_000 + '\n')
    cases = {
        huge: 'is 50000039 bytes, more than the 1048576 a params file may have',
        long_value: "'frame_id' is 900000 characters, more than the 4096 a value may have",
        twice: "key 'frame_id' appears twice",
        many: 'sets more than the 2000 parameters a params file may set',
        deep: 'nested more than 32 levels deep',
    }
    err = _refused_by_run_node(['-p', 'frame_id:=' + 'x' * 100_000], capsys)
    assert 'the rule is 100010 characters, more than the 4096 a value may have' in err
    for path, why in cases.items():
        # a good file first: each bad one is named whichever place it has
        shipped = str(CONFIG / 'controller.yaml')
        err = _refused_by_run_node(['--params-file', shipped, '--params-file', path], capsys)
        assert why in err and path in err, err


def test_the_wcs_executable_refuses_a_50_mb_params_file_in_one_line(tmp_path):
    import subprocess
    import sys

    path = tmp_path / 'huge.yaml'
    path.write_text('/**:\n  ros__parameters:\n    frame_id: ' + 'x' * 50_000_000 + '\n')
    out = subprocess.run(
        [str(Path(sys.executable).parent / 'wcs_node'), '--ros-args', '--params-file', str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2, out.stderr[-500:]
    assert len(out.stderr.strip().splitlines()) == 1 and '50000039 bytes' in out.stderr
