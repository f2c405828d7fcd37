"""
The package as a user's project gets it: a wheel installed into a fresh virtualenv.

``installed_package.installed_venv`` builds the wheel and the sdist and installs the
wheel with pip into a new virtualenv outside the repository. Every command below runs
from a temporary folder outside the repository, with the virtualenv's ``bin/`` on the
PATH and nothing of the checkout in the environment (no ``PYTHONPATH``, no
``AMENT_PREFIX_PATH``): the documented commands, a shipped scenario by its name, the
paper's Fig. 9, and the pytest plugin on ``examples/``.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import tarfile
import threading
import time
import zipfile
from pathlib import Path

import pytest
from installed_package import CORE, REPO, installed_venv, user_env

pytestmark = [pytest.mark.ros, pytest.mark.xdist_group('installed_package')]


@pytest.fixture(scope='module')
def venv(tmp_path_factory) -> Path:
    """Return the wheel, installed into a fresh virtualenv (once for this file's tests)."""
    return installed_venv(tmp_path_factory.mktemp('installed'))


@pytest.fixture
def outside(tmp_path) -> Path:
    """Return a working folder outside the repository."""
    assert REPO not in tmp_path.parents
    return tmp_path


# what a command prints on standard error while it compiles a kernel
# (sorter_sim/model/compile_progress.py)
COMPILING = "compiling the model's kernels"


def assert_nothing_compiled(venv: Path, output: str) -> None:
    """
    Fail if a command compiled a kernel of the model instead of loading the shipped one.

    numba writes what it compiles into the installed core's ``__pycache__`` (the shipped
    kernels are read in place, never copied there): a kernel compiled by any command of
    this module, however briefly, leaves its index there. The progress line is printed
    only after 2 s of compiling, and not under ``--json``.
    """
    site = next((venv / 'lib').glob('python3*/site-packages'))
    compiled = sorted(p.name for p in (site / CORE / '__pycache__').glob('*.nbi'))
    assert not compiled, f'compiled instead of loading the shipped kernels: {compiled[:8]}'
    assert COMPILING not in output, f'the shipped kernels were not used:\n{output}'


def _domain() -> int:
    return int(os.environ['ROS_DOMAIN_ID'])  # this worker's (conftest.py)


def run(venv: Path, cwd: Path, *argv: str, timeout: float = 50.0):
    """Run an installed command as its user would; return the finished process."""
    done = subprocess.run(
        [str(venv / 'bin' / argv[0]), *argv[1:]],
        cwd=cwd,
        env=user_env(venv, _domain()),
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert 'Traceback' not in done.stderr, done.stderr
    assert_nothing_compiled(venv, done.stderr)
    return done


def start_and_stop(venv: Path, cwd: Path, ready: str, *argv: str, within: float = 40.0):
    """Start a node, wait until it says ``ready``, stop it with SIGINT; return its output."""
    proc = subprocess.Popen(
        [str(venv / 'bin' / argv[0]), *argv[1:]],
        cwd=cwd,
        env=user_env(venv, _domain()),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
    reader.start()
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < within and proc.poll() is None:
            if any(ready in line for line in list(lines)):
                break
            time.sleep(0.1)
        assert proc.poll() is None, f'{argv[0]} ended ({proc.returncode}):\n{"".join(lines)}'
        assert any(ready in line for line in list(lines)), (
            f'{argv[0]} never said {ready!r}; it printed:\n{"".join(lines)}'
        )
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)
        reader.join(timeout=5)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    text = ''.join(lines)
    assert proc.returncode == 0, f'{argv[0]} exited {proc.returncode}:\n{text}'
    assert 'Traceback' not in text, text
    assert_nothing_compiled(venv, text)
    return text


def test_the_wheel_carries_the_config_and_no_tests(venv):
    (wheel,) = (venv.parent / 'dist').glob('*.whl')
    names = set(zipfile.ZipFile(wheel).namelist())
    for shipped in (
        'sorter_cell/config/cell.yaml',
        'sorter_cell/config/controller.yaml',
        'sorter_cell/config/scenes/fig9a.yaml',
        'sorter_cell/config/scenarios/stuck_divert_eye.yaml',
        'sorter_cell/config/sweeps/example.yaml',
    ):
        assert shipped in names, shipped
    assert not any(n.startswith(('test/', 'examples/', 'benchmarks/')) for n in names)
    print(f'wheel {wheel.name}: {wheel.stat().st_size / 1e3:.0f} kB')


def test_the_wheel_ships_the_kernels_of_its_own_sources_for_any_x86_64_cpu(venv):
    from sorter_sim.model.core.cache import python_tag, sources_digest

    (wheel,) = (venv.parent / 'dist').glob('*.whl')
    shipped = 'sorter_sim/model/core/shipped_kernels/'
    with zipfile.ZipFile(wheel) as zf:
        manifest = json.loads(zf.read(shipped + 'manifest.json'))
        kernels = [n for n in zf.namelist() if n.startswith(shipped) and n.endswith('.nbi')]
    import numba

    assert manifest['sources'] == sources_digest(REPO / 'sorter_sim' / 'model' / 'core')
    assert (manifest['numba'], manifest['python']) == (numba.__version__, python_tag())
    assert manifest['signatures'] >= len(kernels) > 50, (manifest, len(kernels))
    (sdist,) = (venv.parent / 'dist').glob('*.tar.gz')
    assert not [n for n in tarfile.open(sdist).getnames() if 'shipped_kernels/' in n]


def test_the_installed_package_finds_its_config_without_any_variable(venv, outside):
    done = run(
        venv,
        outside,
        'python',
        '-c',
        'from sorter_ros.env import find_config_dir; print(find_config_dir())',
    )
    assert done.returncode == 0, done.stderr
    found = Path(done.stdout.strip())
    assert venv in found.parents and (found / 'scenarios' / 'default_stream.yaml').is_file()


def test_sorter_demo_runs_from_any_folder(venv, outside):
    done = run(venv, outside, 'sorter', 'demo', '--sim-time', '8', '--json')
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary['inducted'] > 0 and summary['mis_sorted'] == 0, summary


def test_sorter_demo_runs_a_line_from_any_folder(venv, outside):
    # a short stream, not drained: what is checked is the six-station line running from an
    # installed package (its physics and dispositions have tests of their own)
    done = run(
        venv,
        outside,
        *('sorter', 'demo', '--stations', '6', '--sim-time', '3', '--no-drain', '--json'),
        timeout=55.0,
    )
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary['inducted'] >= 1 and summary['stations'] == 6, summary
    assert summary['mis_sorted'] == 0 and summary['jams'] == 0, summary


@pytest.mark.parametrize(
    ('argv', 'ready'),
    [
        (['sim_node'], 'sorter cell ready'),
        (['controller_node'], "waiting for the cell's parameters"),
        (['line_node', '--ros-args', '-p', 'stations:=6', '-p', 'time_mode:=fast'], 'line ready'),
        (['wcs_node'], 'sorter wcs ready: 1 station(s), 2 chutes'),
    ],
    ids=['sim_node', 'controller_node', 'line_node', 'wcs_node'],
)
def test_each_node_starts_and_stops_from_any_folder(venv, outside, argv, ready):
    start_and_stop(venv, outside, ready, *argv)


def test_a_shipped_scenario_runs_by_its_name(venv, outside):
    by_name = run(venv, outside, 'sorter', 'scenario', 'run', 'stuck_divert_eye', '--json')
    assert by_name.returncode == 0, by_name.stderr
    assert json.loads(by_name.stdout)['passed'], by_name.stdout


def test_a_scenario_file_runs_by_its_path_and_an_unknown_name_is_refused(venv, outside):
    config = Path(
        run(
            venv,
            outside,
            'python',
            '-c',
            'from sorter_ros.env import find_config_dir; print(find_config_dir())',
        ).stdout.strip()
    )
    mine = outside / 'mine.yaml'
    shutil.copy(config / 'scenarios' / 'stuck_divert_eye.yaml', mine)
    by_path = run(venv, outside, 'sorter', 'scenario', 'run', str(mine), '--json')
    assert json.loads(by_path.stdout)['passed'], by_path.stdout
    unknown = run(venv, outside, 'sorter', 'scenario', 'run', 'no_such_scenario')
    assert unknown.returncode == 2 and 'stuck_divert_eye' in unknown.stderr, unknown.stderr


def test_the_paper_figure_9_from_any_folder(venv, outside):
    done = run(venv, outside, 'sorter', 'paper', '9', '--quick', '--out', 'figs')
    assert done.returncode == 0, done.stderr
    assert any((outside / 'figs').iterdir())


EXAMPLE_TESTS = sorted(p.name for p in (REPO / 'examples').glob('test_*.py'))


def _example_test_ids() -> list[str]:
    """Return each example test as 'file::name': one pytest run each, as a user runs one."""
    import ast

    ids = []
    for name in EXAMPLE_TESTS:
        tree = ast.parse((REPO / 'examples' / name).read_text(encoding='utf-8'))
        ids += [
            f'{name}::{node.name}'
            for node in tree.body
            if isinstance(node, ast.FunctionDef) and node.name.startswith('test_')
        ]
    return ids


EXAMPLE_SCENARIOS = sorted(p.name for p in (REPO / 'examples').glob('*.yaml'))


@pytest.fixture
def examples(outside) -> Path:
    """examples/ copied to a folder outside the repository, as a user's project holds them."""
    for f in (REPO / 'examples').iterdir():
        if f.is_file():
            shutil.copy(f, outside / f.name)
    return outside


@pytest.mark.parametrize('test_id', _example_test_ids())
def test_the_pytest_plugin_runs_the_examples_outside_the_repository(venv, examples, test_id):
    """The fixtures (a cell, a line with the user's station program) from the installed plugin."""
    done = run(
        venv,
        examples,
        'python',
        '-m',
        'pytest',
        '-q',
        '-p',
        'no:cacheprovider',
        test_id,
        timeout=55.0,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert '1 passed' in done.stdout and 'failed' not in done.stdout, done.stdout


@pytest.mark.parametrize('scenario', EXAMPLE_SCENARIOS)
def test_the_example_scenarios_run_the_users_controller_outside_the_repository(
    venv, examples, scenario
):
    """A scenario file that starts the user's own node (in process, as a process, on a line)."""
    done = run(venv, examples, 'sorter', 'scenario', 'run', scenario, '--json', timeout=55.0)
    assert done.returncode == 0, done.stdout + done.stderr
    assert json.loads(done.stdout)['passed'], done.stdout


def test_the_examples_are_all_exercised():
    assert {'test_minimal_controller.py', 'test_station_program.py'} <= set(EXAMPLE_TESTS)
    assert 'line_scenario.yaml' in EXAMPLE_SCENARIOS
