"""package.xml names every dependency setup.py installs, by its rosdep key."""

from __future__ import annotations

import ast
import re
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# pip requirement -> the rosdep keys that stand for it in package.xml
ROSDEP = {
    'setuptools': ['python3-setuptools'],
    'numpy': ['python3-numpy'],
    'scipy': ['python3-scipy'],
    'numba': ['python3-numba'],
    'pyyaml': ['python3-yaml'],
    'matplotlib': ['python3-matplotlib'],
    'dask': ['python3-dask', 'python3-distributed'],
    'pyarrow': ['python3-pyarrow'],
    'tqdm': ['python3-tqdm'],
    'foxglove-sdk': ['python3-foxglove-sdk-pip'],
    'mcap': ['python3-mcap-pip'],
    'mcap-ros2-support': ['python3-mcap-ros2-support-pip'],
    'websockets': ['python3-websockets'],
    'protobuf': ['python3-protobuf'],
    'pymodbus': ['python3-pymodbus'],
    'asyncua': ['python3-asyncua-pip'],
    'python-snap7': ['python3-snap7-pip'],
    'ros-jazzy-rclpy': ['rclpy'],
    'ros-jazzy-common-interfaces': [
        'std_msgs',
        'std_srvs',
        'geometry_msgs',
        'sensor_msgs',
        'visualization_msgs',
        'diagnostic_msgs',
    ],
    'pytest': ['python3-pytest'],
    'pytest-xdist': ['python3-pytest-xdist'],
    'import-linter': ['python3-import-linter-pip'],
    'ruff': ['python3-ruff-pip'],
    'ament-lint-pep257': ['ament_pep257'],
    'hypothesis': ['python3-hypothesis'],
    'pymodbustcp': ['python3-pymodbustcp-pip'],
    'rosbags': ['python3-rosbags-pip'],
    'cryptography': ['python3-cryptography'],
}


def _setup_requirements() -> tuple[list[str], list[str]]:
    """(install_requires, extras_require['test']) of setup.py, as normalised names."""
    tree = ast.parse((ROOT / 'setup.py').read_text())
    call = next(
        n
        for n in ast.walk(tree)
        if isinstance(n, ast.Call) and getattr(n.func, 'id', '') == 'setup'
    )
    kw = {
        k.arg: ast.literal_eval(k.value)
        for k in call.keywords
        if k.arg in ('install_requires', 'extras_require')
    }

    def name(req: str) -> str:
        return re.split(r'[\[<>=!~; ]', req, maxsplit=1)[0].lower().replace('_', '-')

    return [name(r) for r in kw['install_requires']], [
        name(r) for r in kw['extras_require']['test']
    ]


def test_package_xml_names_every_dependency_of_setup_py():
    runtime, testing = _setup_requirements()
    xml = ET.parse(ROOT / 'package.xml').getroot()
    keys = {
        tag: {e.text.strip() for e in xml.findall(tag)}
        for tag in ('exec_depend', 'test_depend', 'buildtool_depend', 'depend')
    }
    unmapped = sorted(set(runtime + testing) - set(ROSDEP))
    assert not unmapped, f'add the rosdep key of {unmapped} to ROSDEP and package.xml'
    for req in runtime:
        for key in ROSDEP[req]:
            where = keys['exec_depend'] | keys['depend'] | keys['buildtool_depend']
            assert key in where, f'{req}: package.xml lacks <exec_depend>{key}</exec_depend>'
    for req in testing:
        for key in ROSDEP[req]:
            where = keys['test_depend'] | keys['exec_depend'] | keys['depend']
            assert key in where, f'{req}: package.xml lacks <test_depend>{key}</test_depend>'
    # and nothing in package.xml that setup.py does not install (message packages aside)
    known = {k for req in runtime + testing for k in ROSDEP[req]}
    extra = {
        k
        for k in keys['exec_depend'] | keys['test_depend']
        if k.startswith('python3-') and k not in known
    }
    assert not extra, f'package.xml names {sorted(extra)}, which setup.py does not install'
