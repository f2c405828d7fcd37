"""sorter_ros.env: discovery defaults and config lookup."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from sorter_ros import env as ros_env

REPO = Path(__file__).resolve().parents[1]


def test_discovery_defaults_to_localhost(monkeypatch):
    monkeypatch.delenv('ROS_AUTOMATIC_DISCOVERY_RANGE', raising=False)
    ros_env.apply_ros_env_defaults()
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'


def test_an_empty_discovery_range_means_localhost(monkeypatch):
    for empty in ('', '  '):
        monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', empty)
        ros_env.apply_ros_env_defaults()
        assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'


def test_user_discovery_range_wins(monkeypatch):
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SUBNET')
    ros_env.apply_ros_env_defaults()
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'


def test_module_does_not_import_rclpy():
    code = 'import sys, sorter_ros.env; assert "rclpy" not in sys.modules'
    subprocess.run([sys.executable, '-c', code], cwd=REPO, check=True)


def test_source_config_dir_is_repo_config():
    assert ros_env.SOURCE_CONFIG_DIR == REPO / 'config'


def test_prefers_source_tree(monkeypatch, tmp_path):
    (tmp_path / 'cell.yaml').write_text('')
    monkeypatch.setattr(ros_env, 'SOURCE_CONFIG_DIR', tmp_path)
    assert ros_env.find_config_dir() == tmp_path


def test_an_installed_wheel_finds_its_packaged_config(monkeypatch, tmp_path):
    packaged = tmp_path / 'site' / 'sorter_cell' / 'config'
    packaged.mkdir(parents=True)
    (packaged / 'cell.yaml').write_text('')
    monkeypatch.setattr(ros_env, 'SOURCE_CONFIG_DIR', tmp_path / 'missing')
    monkeypatch.setattr(ros_env, '_packaged_config_dir', lambda: packaged)
    monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    assert ros_env.find_config_dir() == packaged


def test_a_folder_without_the_parameter_files_is_passed_over(monkeypatch, tmp_path):
    # e.g. another distribution's top-level ``config`` folder in site-packages
    (tmp_path / 'other').mkdir()
    packaged = tmp_path / 'packaged'
    packaged.mkdir()
    (packaged / 'cell.yaml').write_text('')
    monkeypatch.setattr(ros_env, 'SOURCE_CONFIG_DIR', tmp_path / 'other')
    monkeypatch.setattr(ros_env, '_packaged_config_dir', lambda: packaged)
    assert ros_env.find_config_dir() == packaged


def test_a_shipped_file_is_found_by_its_name_and_nothing_else_is():
    assert ros_env.shipped_file('scenarios', 'stuck_divert_eye').name == 'stuck_divert_eye.yaml'
    assert ros_env.shipped_file('scenes', 'fig9a.yaml').is_file()
    for bad in ('', '../cell', 'scenes/fig9a', '.hidden', 'no_such_one'):
        assert ros_env.shipped_file('scenes', bad) is None, bad
    with pytest.raises(ValueError, match='scenes, scenarios, sweeps'):
        ros_env.shipped_file('configs', 'cell')
    assert 'default_stream' in ros_env.shipped_names('scenarios')


def _fake_ament_prefix(prefix: Path) -> Path:
    marker = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
    marker.mkdir(parents=True)
    (marker / 'sorter_cell').touch()
    config = prefix / 'share' / 'sorter_cell' / 'config'
    config.mkdir(parents=True)
    (config / 'cell.yaml').write_text('')
    return config


def test_falls_back_to_installed_share(monkeypatch, tmp_path):
    pytest.importorskip('ament_index_python')
    config = _fake_ament_prefix(tmp_path / 'install')
    monkeypatch.setattr(ros_env, 'SOURCE_CONFIG_DIR', tmp_path / 'missing')
    monkeypatch.setattr(ros_env, '_packaged_config_dir', lambda: None)
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / 'install'))
    assert ros_env.find_config_dir() == config


@pytest.mark.parametrize('ament_prefix', [None, 'empty'])
def test_clear_error_when_nowhere(monkeypatch, tmp_path, ament_prefix):
    monkeypatch.setattr(ros_env, 'SOURCE_CONFIG_DIR', tmp_path / 'missing')
    monkeypatch.setattr(ros_env, '_packaged_config_dir', lambda: None)
    if ament_prefix is None:
        monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    else:
        (tmp_path / ament_prefix).mkdir()
        monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / ament_prefix))
    with pytest.raises(FileNotFoundError, match='config directory not found'):
        ros_env.find_config_dir()
