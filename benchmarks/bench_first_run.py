"""
The first run as a new user meets it: cold (numba's cache empty) and warm, timed.

Each case runs as its own process, as a user would type it, with ``NUMBA_CACHE_DIR``
pointing at a folder of this benchmark's: an empty one for the cold run (everything the
command needs is compiled), the same one again for the warm run (everything is loaded).

Cases: the first ``sorter demo`` (10 simulated seconds), the first test using the pytest
plugin's fixture (``examples/test_minimal_controller.py``, one test), ``sorter warmup``,
and the start of ``sim_node`` (until it says it is ready). Prints a table with the
machine's load, so that a figure is read with what else ran.

``--venv DIR`` runs the commands of another virtualenv instead of this checkout's: the
package installed there from its wheel, which ships the kernels compiled (an empty
cache then compiles nothing on x86-64), e.g. after ``python -m build`` and
``python -m venv /tmp/v && /tmp/v/bin/pip install dist/*.whl pytest``.

    .venv/bin/python benchmarks/bench_first_run.py [--cases demo,fixture,warmup,sim_node]
        [--venv DIR]
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _env(cache: Path, domain: int) -> dict:
    # a user's numba: no setting of the suite's (scripts/test.sh compiles for any CPU)
    env = {k: v for k, v in os.environ.items() if not k.startswith('NUMBA_')}
    env.update(
        NUMBA_CACHE_DIR=str(cache),
        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
        ROS_DOMAIN_ID=str(domain),
    )
    return env


def _timed(argv: list[str], cache: Path, cwd: Path, domain: int) -> float:
    t0 = time.perf_counter()
    done = subprocess.run(argv, cwd=cwd, env=_env(cache, domain), capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode:
        raise SystemExit(f'{" ".join(argv)} failed ({done.returncode}):\n{done.stderr[-2000:]}')
    return wall


def _node_ready(cache: Path, cwd: Path, domain: int, bin_dir: Path) -> float:
    """Seconds from starting sim_node until it logs that it is ready."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [
            str(bin_dir / 'sim_node'),
            '--ros-args',
            '--params-file',
            str(REPO / 'config/cell.yaml'),
        ],
        cwd=cwd,
        env=_env(cache, domain),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        for line in proc.stdout:
            if 'sorter cell ready' in line:
                return time.perf_counter() - t0
        raise SystemExit('sim_node ended before it was ready')
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)


def main() -> int:
    """Run the cases cold then warm and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--cases', default='demo,fixture,warmup,sim_node')
    parser.add_argument('--venv', type=Path, help="another virtualenv's commands (a wheel's)")
    args = parser.parse_args()
    bin_dir = args.venv.resolve() / 'bin' if args.venv else BIN
    cases = args.cases.split(',')
    work = Path(tempfile.mkdtemp(prefix='first_run_'))
    shutil.copy(REPO / 'examples' / 'minimal_controller.py', work)
    shutil.copy(REPO / 'examples' / 'test_minimal_controller.py', work)
    commands = {
        'demo': [str(bin_dir / 'sorter'), 'demo', '--sim-time', '10', '--quiet'],
        'fixture': [
            str(bin_dir / 'python') if args.venv else sys.executable,
            '-m',
            'pytest',
            '-q',
            '-p',
            'no:cacheprovider',
            '-x',
            'test_minimal_controller.py',
            '-k',
            'test_l_parcels',
        ],
        'warmup': [str(bin_dir / 'sorter'), 'warmup', '--quiet'],
    }
    print(
        f'machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; '
        f'python {platform.python_version()}; load at start {os.getloadavg()[0]:.2f}; '
        f'commands of {bin_dir}'
    )
    print(f'{"case":<10} {"cold [s]":>9} {"warm [s]":>9}')
    for k, case in enumerate(cases):
        cache = work / f'cache_{case}'
        domain = 180 + k
        if case == 'sim_node':
            cold = _node_ready(cache, work, domain, bin_dir)
            warm = _node_ready(cache, work, domain, bin_dir)
        else:
            cold = _timed(commands[case], cache, work, domain)
            warm = _timed(commands[case], cache, work, domain)
        print(f'{case:<10} {cold:9.1f} {warm:9.1f}   (load {os.getloadavg()[0]:.2f})', flush=True)
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
