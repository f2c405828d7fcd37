"""
The model core and the controller logic stay free of ROS.

sorter_sim/model/core/ and sorter_control/logic/ must be usable (and testable)
without rclpy or any message package; the ROS nodes wrap them.
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ROS_FREE_FILES = sorted((REPO / 'sorter_sim' / 'model' / 'core').rglob('*.py')) + sorted(
    (REPO / 'sorter_control' / 'logic').rglob('*.py')
)
FORBIDDEN_PREFIXES = ('rclpy', 'rcl_interfaces', 'builtin_interfaces')
FORBIDDEN_SUFFIXES = ('_msgs', '_srvs')


def imported_modules(source: str, filename: str = '<string>') -> list[str]:
    """Names of all modules imported anywhere in ``source`` (absolute imports)."""
    names = []
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.append(node.module)
    return names


def is_ros_module(name: str) -> bool:
    top = name.split('.')[0]
    return name.startswith(FORBIDDEN_PREFIXES) or any(
        part.endswith(FORBIDDEN_SUFFIXES) for part in (top, name)
    )


def ros_imports(source: str, filename: str = '<string>') -> list[str]:
    return [name for name in imported_modules(source, filename) if is_ros_module(name)]


@pytest.mark.parametrize(
    'source',
    [
        'import rclpy',
        'import rclpy.node',
        'from rclpy.node import Node',
        'import numpy, std_msgs.msg',
        'from std_srvs.srv import SetBool',
        'from rcl_interfaces.msg import ParameterDescriptor',
        'from builtin_interfaces.msg import Time',
        'import sorter_msgs',
        'def f():\n    from geometry_msgs.msg import Twist\n',
        'try:\n    import rclpy\nexcept ImportError:\n    pass\n',
    ],
)
def test_checker_flags_ros_imports(source):
    assert ros_imports(source)


@pytest.mark.parametrize(
    'source',
    [
        'import numpy as np',
        'from scipy.integrate import solve_ivp',
        'from . import friction',
        'from .msgs_like import x',
        'import sorter_sim.model.core.geometry',
        'import os',
    ],
)
def test_checker_passes_ros_free_imports(source):
    assert ros_imports(source) == []


@pytest.mark.parametrize(
    'path',
    [p for p in ROS_FREE_FILES if p.exists()] or [None],
    ids=lambda p: 'no-files-yet' if p is None else str(p.relative_to(REPO)),
)
def test_ros_free_files_import_no_ros(path):
    if path is None:
        pytest.skip('no ROS-free source files exist yet')
    found = ros_imports(path.read_text(), str(path))
    assert not found, f'{path.relative_to(REPO)} imports ROS modules: {found}'


def test_importing_all_of_core_loads_no_rclpy():
    code = '\n'.join(
        [
            'import pkgutil, sys',
            'import sorter_sim.model.core as core',
            'names = [m.name for m in pkgutil.walk_packages(core.__path__, core.__name__ + ".")]',
            'for name in names:',
            '    __import__(name)',
            'ros = sorted(m for m in sys.modules if m.split(".")[0] == "rclpy"',
            '             or m.split(".")[0].endswith(("_msgs", "_srvs")))',
            'assert not ros, f"importing sorter_sim.model.core loaded ROS modules: {ros}"',
            'print(len(names))',
        ]
    )
    result = subprocess.run(
        [sys.executable, '-c', code],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
