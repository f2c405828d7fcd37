"""
Commits side by side: the benchmarks that guard the loop, the physics and a user's test.

``python benchmarks/compare.py BASE [OTHER ...] [HEAD] [--cases demo,user10,...] [--repeat 3]
[--sim-time 60]``: with one revision, it is compared with HEAD; with more, the last is
compared with each of the others in one run (``compare.py 69d5ceb 3a305ee HEAD``: the
issue's base, the commit before, this one).

Each revision is checked out once into ``.bench/<sha>`` (a detached git worktree, its
numba kernels compiled there on first use and kept), and every case runs as a process
of its own with that tree first on ``PYTHONPATH``, the two revisions alternating run by
run, so that both meet the same machine: on a shared machine the load moves by a third
from minute to minute, and a figure of one commit taken an hour after the other's says
more about the hour than the commit. The medians are printed side by side with their
ratio; nothing is judged (a timed assertion flakes on a shared machine, a printed ratio
is read by the one who lands the change).

Cases (``--cases``, default all but ``core`` and ``line48``):

- ``demo``: ``sorter demo --sim-time S --json``, the cell and its controller over ROS in
  fast mode: real-time factor;
- ``line24``, ``line48``: ``sorter demo --stations N --sim-time S --json --no-drain``:
  real-time factor of the stream (the same figure as with the line run empty after it);
- ``user10``: a user's test with the ``sorter_cell`` fixture, its defaults and this
  project's controller, 10 parcels until every one is out: set-up (warm) and run, wall;
- ``line_physics``: ``benchmarks/bench_line.py`` at 1 and 24 stations, the physics alone;
- ``cell_physics``: ``benchmarks/bench_cell.py``'s ``cell`` case, the default cell's
  physics alone (``Cell.advance``, 200 parcels on the belt, none touching): real-time
  factor and us a period;
- ``core``: ``sorter bench core``: the accurate method's time for Fig. 9a at 1e-6 m;
- ``watching``: ``benchmarks/bench_cell.py``'s node alone, with the live view, with a
  recording and with the fieldbus clients at the default I/O cycle (``--sim-s`` 10, one
  run each a round): the node's real-time factor, each front end's ratio to it (cost =
  1 - ratio) and the node thread's CPU per simulated second.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH_DIR = ROOT / '.bench'
CASES = (
    'demo',
    'line24',
    'line48',
    'user10',
    'line_physics',
    'cell_physics',
    'core',
    'watching',
)
WATCHING = ('node', 'node+live', 'node+rec', 'node+fieldbus')
DEFAULT_CASES = ('demo', 'line24', 'user10', 'line_physics')

USER10 = r"""
import json, time
from sorter_cell.testing import SorterCell
SorterCell().close()  # the first in a process loads the kernels: the warm set-up is timed
t0 = time.perf_counter()
with SorterCell() as cell:
    t1 = time.perf_counter()
    cell.add_controller()
    t2 = time.perf_counter()
    for i in range(10):
        cell.induct(f'{"AB"[i % 2]}-{i}', length=0.4, width=0.3)
    done = cell.run_until(lambda: len(cell.outcomes) == 10, 60.0)
    t3 = time.perf_counter()
    exits = sorted((o.label, o.exit) for o in cell.outcomes)
print(json.dumps({'setup_s': t1 - t0 + (t2 - t1), 'run_s': t3 - t2, 'sim_s': cell.t,
                  'done': bool(done), 'exits': exits}))
"""


def _tree(rev: str) -> Path:
    """Return a worktree of ``rev`` under .bench/, made (and its kernels compiled) once."""
    sha = subprocess.run(
        ['git', 'rev-parse', '--verify', f'{rev}^{{commit}}'],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    if sha.returncode != 0:
        raise SystemExit(f'compare: {rev!r} is not a commit of this repository')
    sha = sha.stdout.strip()
    if sha == _head_sha() and not _dirty():
        return ROOT
    tree = BENCH_DIR / sha[:12]
    if not (tree / 'setup.py').exists():
        BENCH_DIR.mkdir(exist_ok=True)
        subprocess.run(
            ['git', 'worktree', 'add', '--detach', '-f', str(tree), sha], cwd=ROOT, check=True
        )
    stamp = tree / '.bench_warm'
    if not stamp.exists():
        print(f'compare: compiling the kernels of {sha[:12]} (once)', file=sys.stderr)
        # from the tree itself: ``-m`` puts the working folder first on the path; a
        # revision older than ``sorter warmup`` (69d5ceb, the base) has its module
        warm = ['-m', 'sorter_cell', 'warmup', '--all']
        if (
            not (tree / 'sorter_cell' / 'warmup_cli.py').exists()
            and (tree / 'sorter_sim' / 'runtime' / 'warmup.py').exists()
        ):
            warm = ['-m', 'sorter_sim.runtime.warmup']
        subprocess.run([sys.executable, *warm], cwd=tree, env=_env(tree), check=True)
        stamp.write_text('')
    return tree


def _head_sha() -> str:
    return subprocess.run(
        ['git', 'rev-parse', 'HEAD'], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()


def _dirty() -> bool:
    out = subprocess.run(
        ['git', 'status', '--porcelain', '--untracked-files=no'],
        cwd=ROOT,
        capture_output=True,
        text=True,
    ).stdout
    return bool(out.strip())


def _env(tree: Path) -> dict:
    env = dict(os.environ)
    env['PYTHONPATH'] = str(tree)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env['ROS_DOMAIN_ID'] = str(150 + os.getpid() % 50)
    env['NUMBA_CPU_NAME'] = 'generic'
    env.pop('NUMBA_CPU_FEATURES', None)
    return env


def _run(tree: Path, args: list[str], timeout: float = 1800.0) -> str:
    with tempfile.TemporaryDirectory() as tmp:
        done = subprocess.run(
            [sys.executable, *args],
            cwd=tmp,
            env=_env(tree),
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    if done.returncode not in (0, 1):
        raise RuntimeError(f'{" ".join(args)}: exit {done.returncode}: {done.stderr[-400:]}')
    return done.stdout


def _json_line(out: str) -> dict:
    return json.loads(next(line for line in reversed(out.splitlines()) if line.startswith('{')))


def watching_figures(out: str) -> dict:
    """
    Read the watching figures off ``bench_cell.py``'s output; return name -> value.

    Parameters
    ----------
    out : str
        What it printed: a line a case, ``node+rec  real-time factor ... ratio ...``.

    Returns
    -------
    dict
        The node's real-time factor, each front end's ratio to it, and the node
        thread's CPU per simulated second of each, for the cases of WATCHING it ran.

    """
    figures = {}
    line = (
        r'^(node\S*)\s+real-time factor\s+([\d.]+).*?ratio ([\d.]+).*?node thread CPU\s+([\d.]+)'
    )
    for m in re.finditer(line, out, re.M):
        if m.group(1) not in WATCHING:
            continue
        if m.group(1) == 'node':
            figures['node alone, real-time factor'] = float(m.group(2))
        else:
            figures[f'{m.group(1)}, ratio to node'] = float(m.group(3))
        figures[f'{m.group(1)}, node thread ms/simulated s'] = float(m.group(4))
    return figures


def case(name: str, tree: Path, sim_time: float) -> dict:
    """
    Run one case on one tree; return its figures, name -> value.

    Parameters
    ----------
    name : str
        One of CASES.
    tree : Path
        The revision's tree.
    sim_time : float
        Simulated seconds of the demo and line cases.

    Returns
    -------
    dict
        The figures.

    """
    demo = ['-m', 'sorter_cell', 'demo', '--sim-time', str(sim_time), '--json', '--quiet']
    if name == 'demo':
        s = _json_line(_run(tree, demo + ['--out', 'paths.png']))
        return {'real-time factor': s['real_time_factor'], 'inducted': s['inducted']}
    if name in ('line24', 'line48'):
        # the factor is the stream's (both the base and now); the line run empty
        # after it would only add wall time (321 s of 48 stations after 10 s of stream)
        s = _json_line(_run(tree, demo + ['--stations', name[4:], '--no-drain']))
        return {'real-time factor': s['real_time_factor']}
    if name == 'user10':
        s = _json_line(_run(tree, ['-c', USER10]))
        return {'set-up s (warm)': s['setup_s'], 'run s': s['run_s'], 'simulated s': s['sim_s']}
    if name == 'line_physics':
        out = _run(tree, [str(tree / 'benchmarks' / 'bench_line.py'), '--stations', '1', '24'])
        figures = {}
        for n in ('1', '24'):
            m = re.search(rf'^\s*{n}\s*\|?\s+[\d.]+\s*\|?\s+[\d.]+\s*\|?\s+([\d.]+)', out, re.M)
            if m:
                figures[f'real-time factor, N = {n}'] = float(m.group(1))
        return figures
    if name == 'cell_physics':
        code = (
            f'import json, sys; sys.path.insert(0, {str(tree / "benchmarks")!r}); '
            'from bench_cell import bench_cell; r = bench_cell(5.0, 200); '
            "print(json.dumps({'rtf': r['rtf'], 'us': r['us_per_period']}))"
        )
        s = _json_line(_run(tree, ['-c', code]))
        return {'real-time factor': s['rtf'], 'us a period': s['us']}
    if name == 'core':
        out = _run(tree, ['-m', 'sorter_cell', 'bench', 'core'], timeout=3600)
        # its first target's line: the cheapest accurate setting within 1e-6 m, its time
        m = re.search(r'^target 1: .* in ([\d.]+) ms ->', out, re.M)
        return {'Fig. 9a within 1e-6 m, ms': float(m.group(1))} if m else {}
    if name == 'watching':
        cases = ['--cases', ','.join(WATCHING)]
        bench = [str(tree / 'benchmarks' / 'bench_cell.py'), '--sim-s', '10', '--repeat', '1']
        return watching_figures(_run(tree, bench + cases))
    raise ValueError(f'unknown case {name!r}; the cases: {", ".join(CASES)}')


def main(argv=None) -> int:
    """Run the comparison; print the machine, then the table."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument(
        'revs',
        nargs='+',
        metavar='REV',
        help='the commits (a hash, a branch, HEAD~1); the last is compared with each of the '
        'others; one alone is compared with HEAD',
    )
    ap.add_argument('--cases', default=','.join(DEFAULT_CASES), help=f'of {", ".join(CASES)}')
    ap.add_argument('--repeat', type=int, default=3, help='runs of each case per commit')
    ap.add_argument('--sim-time', type=float, default=60.0, help='simulated s of demo, line')
    args = ap.parse_args(argv)
    revs = args.revs if len(args.revs) > 1 else [*args.revs, 'HEAD']
    cases = [c.strip() for c in args.cases.split(',') if c.strip()]
    bad = [c for c in cases if c not in CASES]
    if (
        bad
        or not 1 <= args.repeat <= 20
        or not 1.0 <= args.sim_time <= 600.0
        or not 2 <= len(revs) <= 4
        or len(set(revs)) < len(revs)
    ):
        ap.error(
            f'--cases from {", ".join(CASES)} (got {", ".join(bad)}), --repeat 1-20, '
            '--sim-time 1-600, 2-4 different revisions'
        )
    trees = {rev: _tree(rev) for rev in revs}
    print(
        f'{platform.node()}: {os.cpu_count()} cores, Python {platform.python_version()}, '
        f'load average {os.getloadavg()[0]:.2f} at the start; {args.repeat} runs a case '
        'a commit, alternating'
    )
    head, others = revs[-1], revs[:-1]
    rows = []
    for name in cases:
        runs: dict[str, list[dict]] = {rev: [] for rev in trees}
        for _ in range(args.repeat):
            for rev, tree in trees.items():
                t0 = time.perf_counter()
                runs[rev].append(case(name, tree, args.sim_time))
                print(f'  {name} {rev}: {time.perf_counter() - t0:.1f} s', file=sys.stderr)
        figures = [f for rev in revs for r in runs[rev] for f in r]
        if not figures:  # an output it could not read is said, not left out of the table
            rows.append((name, 'no figure read from its output', [math.nan] * len(revs)))
        for figure in dict.fromkeys(figures):
            medians = []
            for rev in revs:
                got = [r[figure] for r in runs[rev] if figure in r]
                medians.append(statistics.median(got) if got else math.nan)
            rows.append((name, figure, medians))
    print(f'load average {os.getloadavg()[0]:.2f} at the end')
    print(
        '| case | figure | '
        + ' | '.join(f'{rev} (median)' for rev in revs)
        + ' | '
        + ' | '.join(f'ratio {head} / {rev}' for rev in others)
        + ' |'
    )
    print('|---|---|' + '---|' * (2 * len(revs) - 1))
    for name, figure, medians in rows:
        ratios = [medians[-1] / m if m else math.nan for m in medians[:-1]]
        print(
            f'| {name} | {figure} | '
            + ' | '.join(f'{m:.3g}' for m in medians)
            + ' | '
            + ' | '.join(f'{r:.2f}' for r in ratios)
            + ' |'
        )
    return 0


if __name__ == '__main__':
    sys.exit(main())
