"""
The benchmark of a user's test runs (not a timing test: its figures are its to print).

Only its quickest case here, so that a change to the fixtures cannot break the
benchmark that measures them unseen; the other cases share its code paths with the
fixtures' own tests.
"""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.ros


def test_the_benchmark_prints_the_fixture_set_up_first_and_later():
    done = subprocess.run(
        [
            sys.executable,
            str(ROOT / 'benchmarks' / 'bench_user_tests.py'),
            '--cases',
            'setup',
            '--repeat',
            '1',
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert re.search(r'setup first +\d+\.\d\d s wall', done.stdout), done.stdout
    assert re.search(r'setup later +\d+\.\d\d s wall', done.stdout), done.stdout
    assert done.stdout.startswith('# ') and 'load average after' in done.stdout
