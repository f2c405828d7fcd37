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
