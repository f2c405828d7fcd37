"""
Benchmark of the run loop's slices: where a simulated second of ``sorter demo`` goes.

Not a test: it prints a table. It runs ``sorter demo --sim-time S --json`` (the cell,
the project's controller and the observer on one run loop, in fast mode; with
``--stations N`` a line of N stations and their programs, not run empty at the end)
in this process with each part of a slice timed by a wrapper (perf_counter around
the call):

  slice        ``RunLoop._slice``: everything one slice costs;
  physics      ``Cell.advance``: the kernels and the cell's Python around them;
  publishing   ``SimNode.advance`` (a line: ``LineNode.advance``) less the physics:
               the messages of the periods run;
  drain        ``RunLoop._drain``: the executor serving what the slice queued (the
               markers, ``/clock``, the messages taken and the callbacks they run);
  waits        ``RunLoop.serve_one``: waiting for a callback another thread queues (the
               controller's scan timer, which rclpy's timers thread makes ready);
  scan         ``ControllerNode._scan``: the controller's scans (they run inside the
               drain or the waits: their time is part of those);
  predict      ``ControllerNode._warm_step``: the controllers' predictions ahead, one
               length a step of a wall-clock timer (part of the drain, as the scans);
  settle       ``RunLoop._unsettled`` and ``_periods_to_next_timer``: the loop's checks;

each in ms per simulated second, per slice and as a share of the slice; and the
messages a slice publishes, by topic (``Publisher.publish``: the run loop's markers
among them), each of which the executor serves to every subscriber in this process.
The wrappers add about a microsecond a call. The load average is printed with it: on a
shared machine the waits above all grow with the load.

    .venv/bin/python benchmarks/bench_loop.py [--sim-time 20] [--stations 1] [--json]
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import json
import os
import re
import sys
import time

PARTS = {
    # part: (module, class, method)
    'slice': ('sorter_ros.run_loop', 'RunLoop', '_slice'),
    'physics': ('sorter_sim.runtime.cell', 'Cell', 'advance'),
    'node advance': ('sorter_sim.frontends.node', 'SimNode', 'advance'),
    'line advance': ('sorter_sim.frontends.line_node', 'LineNode', 'advance'),
    'drain': ('sorter_ros.run_loop', 'RunLoop', '_drain'),
    'waits': ('sorter_ros.run_loop', 'RunLoop', 'serve_one'),
    'scan': ('sorter_control.node', 'ControllerNode', '_scan'),
    'predict': ('sorter_control.node', 'ControllerNode', '_warm_step'),
    'settle': ('sorter_ros.run_loop', 'RunLoop', '_unsettled'),
    'next timer': ('sorter_ros.run_loop', 'RunLoop', '_periods_to_next_timer'),
}


def _time_parts(spent: collections.Counter, calls: collections.Counter) -> list:
    """
    Wrap each part's method so that its wall time and calls add up in the counters.

    Only inside a slice: the start-up's and the end's spins (the clock standing still)
    are not a simulated second's cost.
    """
    import importlib

    inside = [0]
    for part, (module, cls, name) in PARTS.items():
        owner = getattr(importlib.import_module(module), cls)
        inner = getattr(owner, name)

        def timed(*a, _inner=inner, _part=part, **k):
            if _part != 'slice' and not inside[0]:
                return _inner(*a, **k)
            inside[0] += _part == 'slice'
            t0 = time.perf_counter()
            try:
                return _inner(*a, **k)
            finally:
                spent[_part] += time.perf_counter() - t0
                calls[_part] += 1
                inside[0] -= _part == 'slice'

        setattr(owner, name, timed)
    return inside  # [slices running now]


def _count_messages(topics: collections.Counter, inside: list) -> None:
    """Count what is published inside a slice (``inside[0]`` > 0), by topic."""
    from rclpy.publisher import Publisher

    inner = Publisher.publish

    def counted(self, msg, _inner=inner):
        if inside[0]:
            topics[self.topic_name] += 1
        return _inner(self, msg)

    Publisher.publish = counted


def measure(sim_time: float, stations: int = 1) -> dict:
    """Run the demo (a line of ``stations``) for ``sim_time`` simulated s; return the parts."""
    from sorter_cell.cli import main as sorter

    spent: collections.Counter = collections.Counter()
    calls: collections.Counter = collections.Counter()
    topics: collections.Counter = collections.Counter()
    _count_messages(topics, _time_parts(spent, calls))
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        line = ['--stations', str(stations), '--no-drain'] if stations > 1 else []
        code = sorter(
            ['demo', '--sim-time', str(sim_time), '--json', '--quiet', '--out', _scratch_png()]
            + line
        )
    if code not in (0, None):
        raise SystemExit(f'bench_loop: sorter demo ended with {code}')
    summary = json.loads(out.getvalue())
    slices = calls['slice']
    sim_s = summary['sim_time_s']
    advanced = spent.pop('node advance', 0.0) + spent.pop('line advance', 0.0)
    spent['publishing'] = advanced - spent['physics']
    spent['settle'] += spent.pop('next timer')
    rows = []
    for part in ('physics', 'publishing', 'drain', 'waits', 'settle', 'scan', 'predict'):
        rows.append(
            {
                'part': part,
                'ms_per_sim_s': 1e3 * spent[part] / sim_s,
                'ms_per_slice': 1e3 * spent[part] / slices,
                'share': spent[part] / spent['slice'],
            }
        )
    return {
        'stations': stations,
        'sim_time_s': sim_s,
        'slices': slices,
        'messages_per_slice': {t: n / slices for t, n in topics.most_common()},
        'slice_ms': 1e3 * spent['slice'] / slices,
        'slice_ms_per_sim_s': 1e3 * spent['slice'] / sim_s,
        'real_time_factor': summary['real_time_factor'],
        'rows': rows,
    }


def _scratch_png() -> str:
    import tempfile

    return os.path.join(tempfile.mkdtemp(prefix='bench_loop_'), 'paths.png')


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--sim-time', type=float, default=20.0, help='simulated s, 1-600')
    ap.add_argument('--stations', type=int, default=1, help='1 (the cell) to 64 (a line)')
    ap.add_argument('--json', action='store_true', help='one JSON object')
    args = ap.parse_args(argv)
    if not 1.0 <= args.sim_time <= 600.0:
        ap.error(f'--sim-time must be in [1, 600] s, got {args.sim_time:g}')
    if not 1 <= args.stations <= 64:
        ap.error(f'--stations must be in [1, 64], got {args.stations}')
    fig = measure(args.sim_time, args.stations)
    fig['load_average'] = os.getloadavg()[0]
    if args.json:
        print(json.dumps(fig))
        return 0
    line = f' --stations {args.stations}' if args.stations > 1 else ''
    print(
        f'sorter demo --sim-time {args.sim_time:g}{line}: {fig["slices"]} slices of '
        f'{fig["slice_ms"]:.2f} ms wall, real-time factor {fig["real_time_factor"]:.2f}, '
        f'load average {fig["load_average"]:.2f}'
    )
    print('| part | ms per simulated s | ms per slice | share of a slice |')
    print('|---|---|---|---|')
    for r in fig['rows']:
        part = {'scan': 'of which the scans', 'predict': 'of which the predictions'}.get(
            r['part'], r['part']
        )
        print(
            f'| {part} | {r["ms_per_sim_s"]:.0f} | {r["ms_per_slice"]:.3f} | '
            f'{100 * r["share"]:.0f} % |'
        )
    whole = f'{fig["slice_ms_per_sim_s"]:.0f} | {fig["slice_ms"]:.3f}'
    print(f'| the slice, whole | {whole} | 100 % |')
    per = collections.Counter()
    for topic, n in fig['messages_per_slice'].items():
        per[re.sub(r'^/S[0-9]+/', '/S*/', topic)] += n  # a line's stations' topics, together
    print(
        f'messages a slice: {sum(per.values()):.2f} ('
        + ', '.join(f'{t} {n:.2f}' for t, n in per.most_common() if n >= 0.01)
        + ')'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
