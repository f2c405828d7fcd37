"""
The node benchmark runs end to end on a tiny cell: every case, every front end at once.

Not a timing test (the figures are the benchmark's to print, not ours to judge): it
checks that each case of ``benchmarks/bench_cell.py`` runs, with the subscriber
process, the live view's client, the recording and the three fieldbus clients, and
prints a ratio for each, so that a change to any front end cannot break the
benchmark that measures it unseen.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.ros


def _bench(script: str, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run ``benchmarks/<script>`` with ``args`` in a process of its own; return it."""
    return subprocess.run(
        [sys.executable, str(ROOT / 'benchmarks' / script), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _bench_json(script: str, *args: str) -> dict:
    """Run a benchmark with ``--json``; return the object it printed last."""
    import json

    out = _bench(script, *args, '--json')
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _compare():
    """Import benchmarks/compare.py."""
    sys.path.insert(0, str(ROOT / 'benchmarks'))
    try:
        import compare
    finally:
        sys.path.remove(str(ROOT / 'benchmarks'))
    return compare


def test_bench_cell_runs_every_case_and_prints_a_ratio_for_each():
    out = subprocess.run(
        [
            sys.executable,
            str(ROOT / 'benchmarks' / 'bench_cell.py'),
            '--sim-s',
            '0.3',
            '--parcels',
            '3',
            '--repeat',
            '1',
            '--cases',
            'node,node+rawsub,node+fieldbus,everything/10ms',
        ],
        capture_output=True,
        text=True,
        timeout=150,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    lines = {ln.split()[0]: ln for ln in out.stdout.splitlines() if ln and ln[0] != '#'}
    every = 'everything/10ms'  # everything at once, with the 10 ms I/O cycle
    assert set(lines) == {'cell', 'node', 'node+rawsub', 'node+fieldbus', every}
    for name in ('node+rawsub', 'node+fieldbus', every):
        assert re.search(r'ratio \d+\.\d\d', lines[name]), lines[name]
    assert re.search(r'client reads [1-9]\d*/s', lines[every])  # the clients read
    assert re.search(r'received [1-9]\d*', lines[every])  # the subscriber received
    assert re.search(r'frames [1-9]\d*', lines[every])  # the live client was sent
    assert 'file ' in lines[every]
    # the raw subscriber ran (what it received in a run this short depends on the load)
    assert re.search(r'received \d+', lines['node+rawsub'])
    # compare.py's watching case reads the same lines: each case it knows, no other
    watching = _compare().watching_figures(out.stdout)
    assert set(watching) == {
        'node alone, real-time factor',
        'node, node thread ms/simulated s',
        'node+fieldbus, ratio to node',
        'node+fieldbus, node thread ms/simulated s',
    }
    assert watching['node+fieldbus, ratio to node'] == pytest.approx(
        float(re.search(r'ratio (\d+\.\d\d)', lines['node+fieldbus']).group(1))
    )
    assert all(v > 0 for v in watching.values())


def test_bench_executor_prints_the_floor_of_both_executors_and_every_marker_comes_back():
    """Its drain figure is only a figure if each marker published came back to its node."""
    got = _bench_json('bench_executor.py', '--calls', '50')
    assert [r['executor'] for r in got['rows']] == ['EventsExecutor', 'SingleThreadedExecutor']
    for r in got['rows']:
        assert all(r[k] > 0 for k in ('spin_once_idle_us', 'marker_round_us'))
    # a message between nodes of one process is queued inside the publisher's call: the
    # events executor serves it in the very next call, which is what the drain counts on
    assert got['rows'][0]['marker_not_in_one_call'] == 0
    bad = _bench('bench_executor.py', '--calls', '5', timeout=60)
    assert bad.returncode == 2 and '--calls must be in [10, 100000], got 5' in bad.stderr


def test_bench_loop_splits_the_demos_slices_into_parts_that_add_up():
    """The parts it times are inside the slice: their shares add up to at most the whole."""
    got = _bench_json('bench_loop.py', '--sim-time', '2')
    parts = {r['part']: r for r in got['rows']}
    assert list(parts) == ['physics', 'publishing', 'drain', 'waits', 'settle', 'scan', 'predict']
    # one slice a 10 ms scan (the demo aligns its slices to the controller's timer)
    assert got['slices'] >= 90 * got['sim_time_s'] and got['sim_time_s'] >= 2.0
    assert all(r['ms_per_slice'] > 0 for r in parts.values() if r['part'] != 'predict')
    # the scans run inside the drain or the waits; the rest do not overlap
    outside = sum(parts[p]['share'] for p in ('physics', 'publishing', 'drain', 'waits', 'settle'))
    assert 0.5 < outside <= 1.0 + 1e-9, outside
    for inside in ('scan', 'predict'):
        assert parts[inside]['share'] <= parts['drain']['share'] + parts['waits']['share']
    # every slice publishes the clock once and sends the drain's marker at least once
    per = got['messages_per_slice']
    assert per['/clock'] == pytest.approx(1.0, abs=0.05), per
    assert per['/sorter_sim/_run_loop_drain'] >= 1.0, per
    bad = _bench('bench_loop.py', '--sim-time', '0', timeout=60)
    assert bad.returncode == 2 and '--sim-time must be in [1, 600] s, got 0' in bad.stderr
    bad = _bench('bench_loop.py', '--stations', '65', timeout=60)
    assert bad.returncode == 2 and '--stations must be in [1, 64], got 65' in bad.stderr


def test_bench_loop_splits_a_lines_slices_too():
    """With --stations the line's physics and publishing are timed, and its programs' scans."""
    got = _bench_json('bench_loop.py', '--sim-time', '1', '--stations', '2')
    parts = {r['part']: r for r in got['rows']}
    assert got['stations'] == 2 and got['sim_time_s'] >= 1.0
    for p in ('physics', 'publishing', 'drain', 'settle', 'scan'):
        assert parts[p]['ms_per_slice'] > 0, p
    # two programs, one scan a slice each (the slices end at their 10 ms scans)
    assert got['slices'] >= 90 * got['sim_time_s']
    assert got['messages_per_slice']['/clock'] == pytest.approx(1.0, abs=0.05)


def test_compare_runs_a_case_on_a_tree_and_refuses_a_bad_one():
    """compare.py's cell_physics case reads its figures off the tree it is given."""
    compare = _compare()
    figures = compare.case('cell_physics', ROOT, 1.0)
    assert set(figures) == {'real-time factor', 'us a period'}
    # one figure from the other: 1 ms a period
    assert figures['real-time factor'] == pytest.approx(1e3 / figures['us a period'], rel=1e-6)
    with pytest.raises(ValueError, match='unknown case'):
        compare.case('warp', ROOT, 1.0)
    with pytest.raises(SystemExit):
        compare.main(['HEAD', '--cases', 'warp'])
    with pytest.raises(SystemExit):  # one revision twice
        compare.main(['HEAD', 'HEAD', '--cases', 'demo'])
