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
    monkeypatch.setattr(ros_env, 'SOURCE_CONFIG_DIR', tmp_path)
    assert ros_env.find_config_dir() == tmp_path


def _fake_ament_prefix(prefix: Path) -> Path:
    marker = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
    marker.mkdir(parents=True)
    (marker / 'sorter_cell').touch()
    config = prefix / 'share' / 'sorter_cell' / 'config'
    config.mkdir(parents=True)
    return config


def test_falls_back_to_installed_share(monkeypatch, tmp_path):
    pytest.importorskip('ament_index_python')
    config = _fake_ament_prefix(tmp_path / 'install')
    monkeypatch.setattr(ros_env, 'SOURCE_CONFIG_DIR', tmp_path / 'missing')
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / 'install'))
    assert ros_env.find_config_dir() == config


@pytest.mark.parametrize('ament_prefix', [None, 'empty'])
def test_clear_error_when_nowhere(monkeypatch, tmp_path, ament_prefix):
    monkeypatch.setattr(ros_env, 'SOURCE_CONFIG_DIR', tmp_path / 'missing')
    if ament_prefix is None:
        monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    else:
        (tmp_path / ament_prefix).mkdir()
        monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / ament_prefix))
    with pytest.raises(FileNotFoundError, match='config directory not found'):
        ros_env.find_config_dir()
