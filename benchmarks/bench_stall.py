"""
Benchmark of the accurate method's step counts over the no-stall matrix: prints figures.

Not a test (the suite's test_exact_stick.py checks a coarser grid against a bound): a
0.7 x 0.2 m, 5 kg parcel enters the disk field stuck to the belt (the seed's Fig. 9a
set-up, μ = 0.6 everywhere, b -> ∞) at every belt speed of ``--speeds`` and every disk
angle from 0° to 90° in 5° steps, with and without the moment, and runs to the scrap line
y = 0.7 m or to ``--t-max`` s (α = 0°: the disks push along the belt). A stall (steps
collapsing near a balanced slip) would show as a run that fails or counts in the
millions; the largest right-hand-side count (every step: the full model's, the
break-away layer's and those taken in ln |slip|) per belt speed and overall is printed,
with the full model's step count.

    .venv/bin/python benchmarks/bench_stall.py [--t-max 30]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sorter_sim.model.core.simulate import Parcel, simulate  # noqa: E402
from sorter_sim.model.build import cell_strips, entry_state  # noqa: E402

SPEEDS = (0.05, 0.1, 0.2, 0.5, 1.0, 1.5, 2.0, 3.0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--t-max", type=float, default=30.0, help="time span of a run [s]")
    args = parser.parse_args()
    if not args.t_max > 0.0:
        parser.error(f"--t-max must be a positive number of seconds, got {args.t_max}")
    parcel = Parcel(0.7, 0.2, 5.0)
    worst = (0, None)
    failures = []
    runs = 0
    t0 = time.perf_counter()
    print("belt v [m/s]  runs  largest rhs (α, moment, full-model steps)")
    per_speed = 2 * len(range(0, 91, 5))
    for v in SPEEDS:
        local = (0, None)
        for alpha in range(0, 91, 5):
            for rotation in (True, False):
                res = simulate(
                    parcel,
                    cell_strips(v, float(alpha), math.inf, 0.6, 0.6, 0.6),
                    entry_state(parcel, v),
                    (0.0, args.t_max),
                    "accurate",
                    y_target=0.7,
                    rotation=rotation,
                    max_points=20_000,
                )
                runs += 1
                if not res.success:
                    failures.append((v, alpha, rotation, res.message))
                key = (res.nfev, (alpha, "on" if rotation else "off", res.n_steps))
                local = max(local, key, key=lambda k: k[0])
                worst = max(worst, (res.nfev, (v, *key[1])), key=lambda k: k[0])
        print(f"{v:12g}  {per_speed:4d}  {local[0]:6d} {local[1]}")
    wall = time.perf_counter() - t0
    print(
        f"{runs} runs in {wall:.1f} s, {len(failures)} failed; largest {worst[0]} rhs at "
        f"v = {worst[1][0]} m/s, α = {worst[1][1]}°, moment {worst[1][2]}, {worst[1][3]} steps"
    )
    for f in failures:
        print("FAILED", f)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
