"""
Lint as ROS packages do it, with zero findings.

pycodestyle and pyflakes (flake8's checks, through ruff, configured in pyproject.toml
at ament's line length of 99) and pep257 docstrings (ament_pep257 with its default
ignores) over every Python file of the project.
"""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PATHS = [
    'sorter_sim',
    'sorter_control',
    'sorter_ros',
    'sorter_cell',
    'test',
    'benchmarks',
    'examples',
    'setup.py',
]


def test_flake8_checks_through_ruff():
    out = subprocess.run(
        [str(BIN / 'ruff'), 'check', '--no-cache', *PATHS],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]


def test_pep257():
    out = subprocess.run(
        [str(BIN / 'ament_pep257'), *PATHS], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
    assert 'No problems found' in out.stdout
