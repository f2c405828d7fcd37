"""
What a user's test costs: fixture set-up, a cell test, a line test, a scenario, a campaign.

``python benchmarks/bench_user_tests.py [--repeat 3] [--cases setup,cell,line,scenario,campaign]``

Each case is what a controls engineer's own test does, timed on the wall clock:

- ``setup``: ``SorterCell()`` made and closed, the first time in a process (imports,
  the kernels loaded) and the later times (the minimum of ``--repeat``);
- ``cell``: a 10-parcel single-cell test (fixture set-up, this project's controller
  started, 10 parcels until every one is out), with the single-threaded executor (the
  fixture's default) and with the events executor (``sorter_cell(events=True)``);
- ``line``: a 6-station line test (``SorterLine(6)``, 20 parcels to destinations drawn
  over the 12 chutes, until every one has its disposition);
- ``scenario``: ``sorter scenario run examples/minimal_controller_scenario.yaml`` as a
  process, start to end;
- ``campaign``: ``sorter scenario campaign`` of that scenario with 6 seeds on 2 workers.

The machine (cores, load average before and after) and the versions are printed
with the figures; the simulated seconds each case covered are given beside its wall
time. Not a test: nothing here judges the figures.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / 'examples'
CASES = ('setup', 'cell', 'line', 'scenario', 'campaign')


def case_setup(repeat: int) -> list[str]:
    """Time SorterCell() made and closed: the first in this process, then the best later."""
    from sorter_cell.testing import SorterCell

    times = []
    for _ in range(1 + repeat):
        t0 = time.perf_counter()
        SorterCell().close()
        times.append(time.perf_counter() - t0)
    return [
        f'setup first      {times[0]:7.2f} s wall',
        f'setup later      {min(times[1:]):7.2f} s wall (min of {repeat}; '
        f'max {max(times[1:]):.2f})',
    ]


def case_cell(repeat: int) -> list[str]:
    """Time a 10-parcel single-cell test, set-up included, with each executor."""
    from sorter_cell.testing import SorterCell

    out = []
    for events in (False, True):
        walls, sim = [], 0.0
        for _ in range(repeat):
            t0 = time.perf_counter()
            with SorterCell(events=events) as cell:
                cell.add_controller()
                for i in range(10):
                    cell.induct(f'{"AB"[i % 2]}-{i}', length=0.4, width=0.3)
                done = cell.run_until(lambda: len(cell.outcomes) == 10, 60.0)
                sim = cell.t
            walls.append(time.perf_counter() - t0)
            if not done:
                out.append(f'  (did not finish: {done})')
        name = 'events' if events else 'single-threaded'
        out.append(
            f'cell 10 parcels  {min(walls):7.2f} s wall for {sim:.1f} s simulated '
            f'({name} executor; min of {repeat})'
        )
    return out


def case_line(repeat: int) -> list[str]:
    """Time a 6-station line test with 20 parcels, set-up included."""
    import numpy as np

    from sorter_cell.testing.line import SorterLine

    walls, sim, codes = [], 0.0, {}
    for _ in range(repeat):
        rng = np.random.default_rng(1)
        t0 = time.perf_counter()
        with SorterLine(6) as line:
            dests = sorted(line.wcs.wcs.plan)
            for i in range(20):
                line.induct(f'P{i:03d}', dests[int(rng.integers(len(dests)))])
            done = line.run_until(lambda: len(line.dispositions) == 20, 120.0)
            sim = line.t
            codes = {}
            for d in line.dispositions:
                codes[d.code] = codes.get(d.code, 0) + 1
        walls.append(time.perf_counter() - t0)
        if not done:
            return [f'line did not finish: {done}']
    return [
        f'line 6 x 20      {min(walls):7.2f} s wall for {sim:.1f} s simulated '
        f'(min of {repeat}; dispositions {codes})'
    ]


def _sorter(*args, cwd=None) -> float:
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, '-m', 'sorter_cell', *args], cwd=cwd, capture_output=True, text=True
    )
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f'sorter {" ".join(args)}: {done.stdout[-500:]}{done.stderr[-500:]}')
    return wall


def case_scenario(repeat: int) -> list[str]:
    """Time ``sorter scenario run`` of the example scenario, as a process."""
    path = EXAMPLES / 'minimal_controller_scenario.yaml'
    walls = [_sorter('scenario', 'run', str(path), '--no-record') for _ in range(repeat)]
    return [f'scenario file    {min(walls):7.2f} s wall, process included (min of {repeat})']


def case_campaign(repeat: int) -> list[str]:
    """Time a campaign of 6 runs on 2 workers."""
    folder = Path(tempfile.mkdtemp(prefix='bench-campaign-'))
    try:
        for name in ('minimal_controller.py', 'minimal_controller_scenario.yaml'):
            shutil.copy(EXAMPLES / name, folder / name)
        walls = [
            _sorter(
                'scenario', 'campaign', str(folder), '--seeds', '6', '--workers', '2', '--quiet'
            )
            for _ in range(repeat)
        ]
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return [f'campaign 6 on 2  {min(walls):7.2f} s wall (min of {repeat})']


def main() -> None:
    """Print the figures."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--repeat', type=int, default=3, help='runs per case; the minimum is kept')
    ap.add_argument('--cases', default=','.join(CASES), help=f'of {", ".join(CASES)}')
    args = ap.parse_args()
    cases = [c.strip() for c in args.cases.split(',') if c.strip()]
    unknown = sorted(set(cases) - set(CASES))
    if unknown or args.repeat < 1:
        sys.exit(
            f'--cases takes {", ".join(CASES)}; --repeat >= 1 (got {args.cases!r}, {args.repeat})'
        )
    cpu = platform.processor() or platform.machine()
    print(
        f'# {platform.node()}: {os.cpu_count()} cores, {cpu}, Python '
        f'{platform.python_version()}, load average before {os.getloadavg()[0]:.2f}'
    )
    for case in cases:
        for line in globals()[f'case_{case}'](args.repeat):
            print(line, flush=True)
    print(f'# load average after {os.getloadavg()[0]:.2f}')


if __name__ == '__main__':
    main()
