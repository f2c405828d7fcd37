"""
The warehouse's cost per request as requests pile up: flat, or it would fall behind a busy line.

Requests for parcels still on their way are held; each request rewrites only its own
parcel's rule, and a parcel's request goes when it leaves the line. This prints the
wall time per request (the minimum of three runs of a block of requests) after
0, 1 000, 5 000 and 20 000 requests held, and the same with every request's parcel
leaving after it, which is how a running line holds them:

    python benchmarks/bench_wcs_requests.py
"""

from __future__ import annotations

import platform
import time

from sorter_control.wcs import LineWcs
from sorter_sim.model.description import chute_pairs

BLOCK = 500


def per_request_s(held: int, *, leave: bool, stations: int = 12) -> float:
    """Return the wall time of one request [s] with ``held`` requests already taken."""
    chutes = chute_pairs(stations)
    names = [c for pair in chutes for c in pair]
    w = LineWcs(chutes)
    w.set_plan('v1', [(f'D{j:02d}', c) for j, c in enumerate(names)])
    for i in range(held):
        w.request(f'H{i:07d}', f'D{i % len(names):02d}')
    best = float('inf')
    for run in range(3):
        t0 = time.perf_counter()
        for i in range(BLOCK):
            label = f'B{run}x{i:05d}'
            w.request(label, f'D{i % len(names):02d}')
            if leave:
                w.exited(label, names[i % len(names)], 0, 1.0)
                w.forget(label)
        best = min(best, (time.perf_counter() - t0) / BLOCK)
    return best


def main() -> dict:
    """Print and return the cost per request [µs] by requests held."""
    print(f'python {platform.python_version()} on {platform.machine()}')
    print(f'{"held":>8} {"us/request":>11} {"us/request+exit":>16}')
    out = {}
    for held in (0, 1_000, 5_000, 20_000):
        a = per_request_s(held, leave=False) * 1e6
        b = per_request_s(held, leave=True) * 1e6
        out[held] = (a, b)
        print(f'{held:>8} {a:>11.1f} {b:>16.1f}')
    return out


if __name__ == '__main__':
    main()
