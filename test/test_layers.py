"""
The layers of the code, as declared in setup.cfg's import-linter contracts.

The first test checks the project as it is. The others prove the contracts can fail:
a copy of the packages with one deliberate ``import rclpy`` in the model core must
break the core's contract, and the PLC logic's too, which imports the core; the model
importing the runtime breaks the layers; the controller importing the cell runtime
breaks its own contract.
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ('sorter_sim', 'sorter_control', 'sorter_ros', 'sorter_cell')
LINT_IMPORTS = Path(sys.executable).parent / 'lint-imports'


def _lint_imports(tree: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(tree))
    return subprocess.run(
        [str(LINT_IMPORTS), '--config', str(tree / 'setup.cfg'), '--no-cache'],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_every_layer_contract_is_kept():
    out = _lint_imports(ROOT)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
    assert 'Contracts: 7 kept, 0 broken.' in out.stdout, out.stdout[-2000:]


def _copy(tmp_path):
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns('__pycache__'))
    shutil.copy(ROOT / 'setup.cfg', tmp_path / 'setup.cfg')


def test_an_rclpy_import_in_the_core_breaks_its_contract(tmp_path):
    _copy(tmp_path)
    friction = tmp_path / 'sorter_sim' / 'model' / 'core' / 'friction.py'
    friction.write_text('import rclpy  # noqa: F401\n' + friction.read_text())
    out = _lint_imports(tmp_path)
    assert out.returncode == 1, out.stdout[-4000:]
    assert 'Contracts: 5 kept, 2 broken.' in out.stdout, out.stdout[-2000:]
    assert 'The model imports no ROS, no messages, no YAML BROKEN' in out.stdout
    assert (
        "The controller's PLC logic and timing import no ROS and no messages BROKEN" in out.stdout
    )
    assert 'sorter_sim.model.core.friction -> rclpy' in out.stdout, out.stdout[-2000:]


def test_the_model_importing_the_runtime_breaks_the_layers(tmp_path):
    _copy(tmp_path)
    build = tmp_path / 'sorter_sim' / 'model' / 'build.py'
    build.write_text('import sorter_sim.runtime.params  # noqa: F401\n' + build.read_text())
    out = _lint_imports(tmp_path)
    assert out.returncode == 1, out.stdout[-4000:]
    assert 'Contracts: 3 kept, 4 broken.' in out.stdout, out.stdout[-2000:]
    assert 'sorter_sim.model is not allowed to import sorter_sim.runtime' in out.stdout


def test_the_controller_importing_the_cell_runtime_breaks_its_contract(tmp_path):
    _copy(tmp_path)
    node = tmp_path / 'sorter_control' / 'node.py'
    node.write_text('import sorter_sim.runtime.cell  # noqa: F401\n' + node.read_text())
    out = _lint_imports(tmp_path)
    assert out.returncode == 1, out.stdout[-4000:]
    assert 'Contracts: 6 kept, 1 broken.' in out.stdout, out.stdout[-2000:]
    assert 'The controller shares the pure model with the simulator, nothing above it BROKEN' in (
        out.stdout
    )
