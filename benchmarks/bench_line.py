"""
The line's physics alone: real-time factor against the number of stations.

``python benchmarks/bench_line.py [--stations 1 6 12 24 48] [--sim-time S]``

Each run is a ``sorter_sim.runtime.line.Line`` of N stations one span apart, fed
at station 1 with the default stream (gaps 1.45-1.85 m, the controller's least
gap for a mixed stream), every parcel given a destination drawn uniformly from
the 2N chutes and the straight end. An ideal in-process PLC diverts it: each
station knows, first in first out, which parcel its divert eye sees next, raises
its disks at ±90° for one bound to it and lowers them when the parcel is in the
chute. No ROS, no publishing: the figures are what the physics costs (the share
the simulation node's publishing and the controller add comes with the node).

Each line first runs untimed until a parcel inducted at the start could have reached
its straight end (the line is full); the figures are over the ``--sim-time`` after.
Printed per N: simulated seconds, wall seconds, real-time factor, the cost per
station per simulated second, parcels inducted and where they went (sorted to
their chute, mis-sorted, jammed, still on the line), and the line's throughput
against N times one station's.
"""

from __future__ import annotations

import argparse
import math
import time
from collections import deque

import numpy as np

from sorter_sim.runtime.cell import SensorEdge
from sorter_sim.runtime.line import Line, LineExit, StationEvent, default_layout
from sorter_sim.runtime.params import CellParams

CHUNK = 20  # periods per advance: the node's pose stride at 50 Hz


def run(n: int, sim_time: float, seed: int = 1, fill: bool = True) -> dict:
    """
    Run N stations for ``sim_time`` simulated seconds once the line is full; return figures.

    The line first runs until a parcel inducted at the start could reach its straight
    end (untimed), so that every station carries its share of the stream while timed.
    """
    p = CellParams.defaults().with_changes(
        {'arrival': 'gap', 'arrival_gap': [1.45, 1.85], 'seed': seed}, runtime=False
    )
    line = Line(p, default_layout(n, p))
    rng = np.random.default_rng(seed)
    choices = [(s, side) for s in range(n) for side in ('left', 'right')] + [None]
    dest: dict[int, tuple | None] = {}
    queues = [deque() for _ in range(n)]  # parcel ids each divert eye sees next
    busy: list[int | None] = [None] * n  # the parcel a station's raised disks are for
    seen = 0
    counts = {'sorted': 0, 'mis_sorted': 0, 'jammed': 0, 'straight_end': 0}
    fill_s = (line.positions[-1] - line.positions[0] + p.exit_x - p.induct_x) / p.belt_speed
    fill_steps = math.ceil(fill_s / line.dt / CHUNK) if fill else 0
    steps = fill_steps + math.ceil(sim_time / line.dt / CHUNK)
    wall0 = time.perf_counter()
    t_timed = 0.0
    timed = None
    for step in range(steps):
        if step == fill_steps:
            wall0 = time.perf_counter()
            t_timed = line.t
            timed = dict(counts)
        events = line.advance(CHUNK)
        first = line.stations[0]
        while seen < first.n_inducted:  # parcels placed this chunk, in order
            seen += 1
            dest[seen] = choices[rng.integers(len(choices))]
            queues[0].append(seen)
        for ev in events:
            if isinstance(ev, StationEvent):
                s, e = ev.station, ev.event
                if isinstance(e, SensorEdge) and e.sensor == 'pe_divert' and e.blocked:
                    if not queues[s]:
                        continue
                    pid = queues[s].popleft()
                    d = dest.get(pid)
                    if d is not None and d[0] == s and busy[s] is None:
                        cell = line.stations[s]
                        cell.set_alpha(math.radians(90.0 if d[1] == 'left' else -90.0))
                        cell.popup(True)
                        busy[s] = pid
                    elif s + 1 < n:
                        queues[s + 1].append(pid)
                elif getattr(e, 'exit', None) in ('left', 'right') and busy[s] is not None:
                    line.stations[s].popup(False)
                    busy[s] = None
            elif isinstance(ev, LineExit):
                d = dest.get(ev.parcel_id)
                if ev.exit == 'jammed':
                    counts['jammed'] += 1
                elif ev.exit == 'straight_end':
                    counts['straight_end' if d is None else 'mis_sorted'] += 1
                else:
                    want = None if d is None else line.layout.chutes[d[0]][d[1] == 'right']
                    counts['sorted' if ev.exit == want else 'mis_sorted'] += 1
    wall = time.perf_counter() - wall0
    t = line.t - t_timed
    base = timed or dict.fromkeys(counts, 0)
    out = sum(counts.values()) - sum(base.values())
    return {
        'stations': n,
        'sim_s': t,
        'wall_s': wall,
        'rtf': t / wall,
        'us_per_station_per_sim_s': 1e6 * wall / (n * t),
        'inducted': line.stations[0].n_inducted,
        **counts,
        'on_line': line.n_parcels,
        'throughput_pcs_h': 3600.0 * out / t,
        'fill_s': fill_s if fill else 0.0,
    }


def main() -> None:
    """Print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--stations', type=int, nargs='+', default=[1, 6, 12, 24, 48])
    ap.add_argument('--sim-time', type=float, default=60.0, help='timed, after the fill')
    args = ap.parse_args()
    run(1, 1.0, fill=False)  # kernels loaded, caches warm
    print(
        f"{'N':>3} {'sim s':>6} {'wall s':>7} {'RTF':>7} {'µs/station/s':>13} {'in':>5} "
        f"{'sorted':>7} {'mis':>4} {'jam':>4} {'end':>4} {'on':>4} {'pcs/h':>6}"
    )
    one = None
    for n in args.stations:
        r = run(n, args.sim_time)
        one = one or (r['throughput_pcs_h'] if n == 1 else None)
        print(
            f"{n:>3} {r['sim_s']:>6.1f} {r['wall_s']:>7.2f} {r['rtf']:>7.1f} "
            f"{r['us_per_station_per_sim_s']:>13.0f} {r['inducted']:>5} {r['sorted']:>7} "
            f"{r['mis_sorted']:>4} {r['jammed']:>4} {r['straight_end']:>4} {r['on_line']:>4} "
            f"{r['throughput_pcs_h']:>6.0f}"
        )


if __name__ == '__main__':
    main()
