"""
Benchmark of the contact step (``contact: rigid``): what touching parcels cost, and what not.

Not a test: it prints figures. The cell's physics alone (``Cell.advance``, no ROS):

  stream jam / rigid   bench_cell.py's ``cell`` case (the default cell, ``--parcels``
                       parcels on the belt at a 2.3 m pitch, all diverted at α = 90°),
                       under ``contact: jam`` and ``contact: rigid``, alternated
                       ``--repeat`` times: no pair in reach, so rigid costs the broad
                       phase's pass over the parcels; the ratio is printed;
  dense riding         20 parcels (0.7 x 0.2 m) touching end to end, stuck to the
                       running belt (the stream at gap 0): 19 contacts every period,
                       no force;
  dense at a stopper   the same 20 pressed by the belt against a stopper: every
                       parcel slides on the belt (integrated each period) and the
                       chain's 40 contact points are solved every period.

Real-time factor = simulated time / wall time; the best of ``--repeat`` runs.

    .venv/bin/python benchmarks/bench_contact.py [--sim-s 5] [--parcels 200] [--repeat 3]
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_cell import bench_cell  # noqa: E402

from sorter_sim.runtime.cell import Cell  # noqa: E402
from sorter_sim.runtime.cell_contacts import place_parcel  # noqa: E402
from sorter_sim.runtime.params import CellParams  # noqa: E402

DENSE = 20
A, B, M = 0.7, 0.2, 5.0


def dense_cell(stopper: bool) -> Cell:
    """20 parcels touching end to end on the running belt, upstream of the disks."""
    values = {'arrival': 'none', 'contact': 'rigid', 'jam_time': 60.0}
    cell = Cell(CellParams.defaults().with_changes(values, runtime=False))
    front = -20.0
    if stopper:
        hw = 0.5 * cell.params.belt_width
        cell.add_rail(front + 0.01, -hw, front + 0.01, hw)
    v = cell.params.belt_speed
    for i in range(DENSE):
        vel = (0.0, 0.0, 0.0) if stopper else (v, 0.0, 0.0)
        place_parcel(cell, i, (front - 0.5 * A - i * A, 0.0, 0.0), (A, B, M), vel)
        if not stopper:
            cell.mode[i] = 0  # stuck to the belt (MODE_BELT)
    return cell


def bench_dense(sim_s: float, stopper: bool) -> dict:
    cell = dense_cell(stopper)
    cell.advance(100)  # settle (and compile), not timed
    n = round(sim_s / cell.dt)
    t0 = time.perf_counter()
    for _ in range(n // 10):
        cell.advance(10)
    wall = time.perf_counter() - t0
    return {
        'rtf': sim_s / wall,
        'us_per_period': 1e6 * wall / n,
        'contacts': int(cell.contacts.counts[0]),
        'jams': cell.outcome_counts['jammed'],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--sim-s', type=float, default=5.0, help='simulated seconds measured')
    ap.add_argument('--parcels', type=int, default=200, help='parcels of the stream case')
    ap.add_argument('--repeat', type=int, default=3)
    args = ap.parse_args()
    machine = platform.processor() or platform.machine()
    print(f'# {platform.node()} {machine}, python {platform.python_version()}')
    best: dict[str, dict] = {}
    for _ in range(args.repeat):
        for contact in ('jam', 'rigid'):
            r = bench_cell(args.sim_s, args.parcels, contact=contact)
            key = f'stream {contact}'
            if key not in best or r['rtf'] > best[key]['rtf']:
                best[key] = r
        for stopper in (False, True):
            r = bench_dense(args.sim_s, stopper)
            key = 'dense at a stopper' if stopper else 'dense riding'
            if key not in best or r['rtf'] > best[key]['rtf']:
                best[key] = r
    print(f'{"case":<22} {"RTF":>9} {"us/period":>10}  notes')
    for key, r in best.items():
        notes = f'jams {r["jams"]}'
        if 'contacts' in r:
            notes += f', contact points {r["contacts"]}'
        else:
            notes += f', parcels {r["parcels_mean"]:.0f}'
        print(f'{key:<22} {r["rtf"]:9.1f} {r["us_per_period"]:10.2f}  {notes}')
    ratio = best['stream rigid']['us_per_period'] / best['stream jam']['us_per_period']
    print(f'no pair in reach: rigid / jam cost per period = {ratio:.3f} (target <= 1.05)')
    print(
        f'dense stream, 20 touching: {best["dense riding"]["rtf"]:.1f}x and '
        f'{best["dense at a stopper"]["rtf"]:.1f}x real time (target >= 20x)'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
