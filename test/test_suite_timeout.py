"""
The suite's own guards: an overrunning test fails alone, and a group runs in one worker.

A deliberately over-running test (a loop inside numba-compiled code, where a timeout
signal could not be handled) is run by pytest in a subprocess with this project's
pytest.ini and a short timeout. It must be reported as one failed test that names the
timeout, the tests before and after it must pass, and pytest must end normally
(exit code 1, no INTERNALERROR).

Tests that share state across a file (a module fixture, a file one test writes and the
next reads) carry an ``xdist_group`` mark: the suite's ``--dist loadgroup`` must keep
each group in one worker, or they race and fail only when the machine is loaded.
"""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

OVERRUNNING = textwrap.dedent('''
    from numba import njit


    def test_before():
        pass


    @njit
    def _spin(n):
        acc = 0.0
        for i in range(n):
            acc += (i % 7) * 1e-9
        return acc


    def test_overruns_inside_compiled_code():
        # about 10^12 iterations: hours, far past the timeout below
        assert _spin(10 ** 12) > 0.0


    def test_after():
        pass
''')


def _pytest_with_the_suites_options(tmp_path, test_file: str, *options: str):
    """Run pytest on ``tmp_path/test_file`` with this project's pytest.ini and ``options``."""
    return subprocess.run(
        [
            sys.executable,
            '-m',
            'pytest',
            '-c',
            str(ROOT / 'pytest.ini'),
            '--rootdir',
            str(tmp_path),
            '-p',
            'no:cacheprovider',
            *options,
            str(tmp_path / test_file),
        ],
        cwd=tmp_path,
        env=dict(os.environ, PYTHONPATH=str(ROOT / 'test')),
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_an_overrunning_test_fails_alone_and_the_suite_goes_on(tmp_path):
    (tmp_path / 'test_overrun.py').write_text(OVERRUNNING)
    out = _pytest_with_the_suites_options(
        tmp_path, 'test_overrun.py', '-o', 'test_timeout=4', '-rA'
    )
    text = out.stdout + out.stderr
    assert out.returncode == 1, text[-3000:]
    assert 'INTERNALERROR' not in text, text[-3000:]
    assert '1 failed, 2 passed' in text, text[-3000:]
    assert 'FAILED test_overrun.py::test_overruns_inside_compiled_code' in text, text[-3000:]
    assert 'PASSED test_overrun.py::test_after' in text, text[-3000:]
    assert 'ran past the per-test time limit of 4 s' in text, text[-3000:]


GROUPED = textwrap.dedent('''
    import pytest


    @pytest.mark.xdist_group('shared')
    @pytest.mark.parametrize('i', range(6))
    def test_grouped(i):
        pass


    @pytest.mark.parametrize('i', range(6))
    def test_free(i):
        pass
''')


def test_an_xdist_group_runs_in_one_worker(tmp_path):
    """The suite's own options (pytest.ini: -n 2 --dist loadgroup) keep a group together."""
    (tmp_path / 'test_grouped.py').write_text(GROUPED)
    out = _pytest_with_the_suites_options(tmp_path, 'test_grouped.py', '-v')
    text = out.stdout + out.stderr
    assert out.returncode == 0, text[-3000:]
    workers = {
        line.split()[0]
        for line in out.stdout.splitlines()
        if 'PASSED' in line and '::test_grouped[' in line
    }
    assert len(workers) == 1, f'the group ran in {sorted(workers)}:\n{text[-3000:]}'
