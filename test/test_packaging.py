"""
package.xml names every dependency setup.py installs, by the key rosdep resolves.

The keys are checked against a pinned copy of rosdistro's database (test/data/rosdep/:
the entries of rosdep/python.yaml and jazzy/distribution.yaml that package.xml names,
from the commit their headers give), and every module the package imports against
package.xml and setup.py, so that ``rosdep install`` and ``pip install`` each bring
everything the code imports.
"""

from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from importlib import metadata
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PINNED = ROOT / 'test' / 'data' / 'rosdep'
PACKAGES = ('sorter_sim', 'sorter_control', 'sorter_ros', 'sorter_cell')
# rosdistro has no key for these (checked below against the pinned database): package.xml
# names each in a comment, docs/setup.md installs each with pip
NO_KEY = {
    'dask',
    'distributed',
    'pyarrow',
    'foxglove-sdk',
    'mcap',
    'lz4',
    'zstandard',
    'asyncua',
    'import-linter',
}
# a ROS bundle wheel of setup.py -> the rosdistro repositories whose packages it brings
BUNDLES = {
    'ros-jazzy-common-interfaces': ('common_interfaces',),
    'ros-jazzy-rclpy': ('rclpy', 'rcl_interfaces'),
}

# pip requirement -> the rosdep keys that stand for it in package.xml
ROSDEP = {
    'setuptools': ['python3-setuptools'],
    'numpy': ['python3-numpy'],
    'scipy': ['python3-scipy'],
    'numba': ['python3-numba'],
    'pyyaml': ['python3-yaml'],
    'matplotlib': ['python3-matplotlib'],
    'dask': [],
    'distributed': [],
    'pyarrow': [],
    'tqdm': ['python3-tqdm'],
    'foxglove-sdk': [],
    'mcap': [],
    'mcap-ros2-support': ['mcap-ros2-support'],
    'lz4': [],
    'zstandard': [],
    'websockets': ['python3-websockets'],
    'protobuf': ['python3-protobuf'],
    'pymodbus': ['python3-pymodbus'],
    'asyncua': [],
    'python-snap7': ['python3-python-snap7-pip'],
    'ros-jazzy-rclpy': ['rclpy', 'rosgraph_msgs', 'rcl_interfaces', 'builtin_interfaces'],
    'ros-rosidl-adapter': ['rosidl_adapter'],
    'ros-ament-index-python': ['ament_index_python'],
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
    'import-linter': [],
    'build': [],
    'ruff': ['python3-ruff-pip'],
    'ament-lint-pep257': ['ament_pep257'],
    'hypothesis': ['python3-hypothesis'],
    'pymodbustcp': ['pymodbustcp-pip'],
    'rosbags': ['python3-rosbags-pip'],
    'cryptography': ['python3-cryptography'],
}


def _name(req: str) -> str:
    """Return a requirement's distribution name, normalised (PEP 503)."""
    return re.sub(r'[-_.]+', '-', re.split(r'[\[<>=!~; ]', req, maxsplit=1)[0]).lower()


def _package_xml() -> tuple[dict, str]:
    """Return package.xml's keys by tag, and its text (comments included)."""
    text = (ROOT / 'package.xml').read_text()
    xml = ET.fromstring(text)
    keys = {
        tag: {e.text.strip() for e in xml.findall(tag)}
        for tag in ('exec_depend', 'test_depend', 'buildtool_depend', 'depend')
    }
    return keys, text


def _pinned() -> tuple[dict, dict]:
    """Return the pinned rosdep/python.yaml entries and {ROS package: its repository}."""
    python = yaml.safe_load((PINNED / 'python.yaml').read_text())
    dist = yaml.safe_load((PINNED / 'jazzy-distribution.yaml').read_text())
    ros = {
        pkg: repo
        for repo, entry in dist['repositories'].items()
        for pkg in entry['release']['packages']
    }
    return python, ros


def _setup_lists() -> dict:
    """install_requires and extras_require of setup.py, as written."""
    tree = ast.parse((ROOT / 'setup.py').read_text())
    call = next(
        n
        for n in ast.walk(tree)
        if isinstance(n, ast.Call) and getattr(n.func, 'id', '') == 'setup'
    )
    return {
        k.arg: ast.literal_eval(k.value)
        for k in call.keywords
        if k.arg in ('install_requires', 'extras_require')
    }


def _setup_requirements() -> tuple[list[str], list[str]]:
    """(install_requires, extras_require['test']) of setup.py, as normalised names."""
    kw = _setup_lists()
    return [_name(r) for r in kw['install_requires']], [
        _name(r) for r in kw['extras_require']['test']
    ]


def test_the_pytest_extra_pins_pytest_as_the_suites_own_extra_does():
    extras = _setup_lists()['extras_require']
    # a user's `pip install sorter_cell[pytest]` resolves the pytest the suite runs with
    pins = {r for r in extras['test'] if r.startswith('pytest')}
    assert pins == {'pytest>=8,<9.2', 'pytest-xdist>=3.5'}
    assert set(extras['pytest']) == pins


def test_package_xml_names_every_dependency_of_setup_py():
    runtime, testing = _setup_requirements()
    keys, _ = _package_xml()
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
        if k not in known and k not in _pinned()[1]
    }
    assert not extra, f'package.xml names {sorted(extra)}, which setup.py does not install'


def test_every_key_of_package_xml_is_one_rosdep_resolves_on_jazzys_platform():
    python, ros = _pinned()
    keys, text = _package_xml()
    for key in sorted(set().union(*keys.values())):
        if key in ros:
            continue  # a released ROS package: rosdep installs ros-jazzy-<name>
        assert key in python, (
            f'package.xml: {key!r} is no rosdep key (neither in rosdep/python.yaml nor a '
            'jazzy package); name its key, or its pip line in a comment and docs/setup.md'
        )
        rule = python[key].get('ubuntu', python[key].get('*'))
        assert rule, f'{key!r} has no rule for ubuntu (Jazzy is built on noble)'
        if isinstance(rule, dict) and 'noble' in rule:
            assert rule['noble'], f'{key!r} has no rule for ubuntu noble'
    # what has no key has none in the pinned database either (else package.xml would use it)
    setup_md = (ROOT / 'docs' / 'setup.md').read_text()
    for req in sorted(NO_KEY):
        base = req.removeprefix('python-')
        guesses = {f'python3-{base}', f'python3-{base}-pip', f'{base}-pip', base}
        assert not guesses & set(python), f'{req} has a rosdep key now: {guesses & set(python)}'
        assert req in text, f'package.xml says nowhere that {req} has no rosdep key'
        assert re.search(rf"pip install .*['\[]{re.escape(req)}[\]\[>=]", setup_md), (
            f'docs/setup.md has no pip line for {req}'
        )


def _imports() -> set[str]:
    """Return the top-level modules the package imports that are neither its own nor stdlib."""
    found = set()
    for package in PACKAGES:
        for path in (ROOT / package).rglob('*.py'):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    found.update(a.name.split('.')[0] for a in node.names)
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    found.add(node.module.split('.')[0])
    return {m for m in found if m not in sys.stdlib_module_names and m not in PACKAGES}


def _closure(dist: str) -> set[str]:
    """Return the installed distributions ``dist`` requires, directly or not (names normalised)."""
    seen, todo = set(), [dist]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        try:
            requires = metadata.requires(name) or []
        except metadata.PackageNotFoundError:
            continue
        todo += [_name(r) for r in requires if 'extra ==' not in r]
    return seen


def test_every_module_the_package_imports_is_declared_in_package_xml_and_setup_py():
    runtime, testing = _setup_requirements()
    declared = set(runtime) | set(testing)
    keys, text = _package_xml()
    all_keys = set().union(*keys.values())
    _, ros = _pinned()
    owners = metadata.packages_distributions()
    bundles = {bundle: set(_closure(bundle)) for bundle in BUNDLES}
    imports = _imports()
    assert {'rosidl_adapter', 'rclpy', 'asyncua', 'numpy'} <= imports  # the walk sees them
    for module in sorted(imports):
        if module in ros:
            # a ROS package: its own name is its key, its wheel is ros-<name>
            assert module in all_keys, f'{module} is imported: package.xml lacks it'
            wheel = 'ros-' + module.replace('_', '-')
            bundle = [b for b, repos in BUNDLES.items() if ros[module] in repos]
            assert wheel in declared or (bundle and wheel in bundles[bundle[0]]), (
                f'{module} is imported: setup.py lacks {wheel} (nor does a bundle bring it)'
            )
            continue
        dists = {_name(d) for d in owners.get(module, [])}
        assert dists, f'{module} is imported but installed by no distribution'
        req = dists & declared
        assert req, f'{module} is imported: setup.py lacks {sorted(dists)}'
        (req,) = req
        if req in NO_KEY:
            assert req in text, f'{module}: package.xml says nowhere that {req} has no key'
        else:
            missing = set(ROSDEP[req]) - all_keys
            assert not missing, f'{module} is imported: package.xml lacks {sorted(missing)}'
