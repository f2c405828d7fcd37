"""
``sorter warmup [--all]``: compile the model's kernels into numba's cache before a run needs them.

numba compiles a kernel at its first call and caches it on disk; a machine (or a CI
job) that starts from nothing pays the compile in whichever command runs first. This
verb pays it up front, with progress on standard error:

- ``sorter warmup``: what ``sorter demo``, ``sim_node`` and ``controller_node`` need with
  the shipped parameters (``config/cell.yaml``, ``config/controller.yaml``): the cell's
  kernels for its method and friction law, and the controller's timing predictor;
- ``sorter warmup --all``: every kernel of the model, every method and friction law and
  the studies' (what ``scripts/test.sh`` runs before the suite).

A CI job keeps the result between runs by caching the folder it names
(``NUMBA_CACHE_DIR``; docs/testing.md). An installed wheel ships the kernels compiled
for any x86-64 CPU: there this verb loads them in seconds, and it says whether they fit
(the same numba and Python as the wheel was built with) or why not.
"""

from __future__ import annotations

import json
import time


def add_arguments(parser) -> None:
    """Add the verb's options."""
    parser.add_argument(
        "--all",
        action="store_true",
        help="every kernel: all methods, friction laws and the studies' (the test suite's)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress while compiling")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")


def warm_shipped() -> None:
    """Run what the demo and the two nodes run first, with the shipped parameters."""
    from sorter_cell.demo import stream_plan
    from sorter_ros.env import find_config_dir
    from sorter_ros.params_file import read_params_file
    from sorter_sim.runtime.params import CellParams
    from sorter_sim.runtime.warmup import warm_cell

    config = find_config_dir()
    values = read_params_file(config / "cell.yaml", "sorter_sim")
    warm_cell(CellParams.from_values(values))
    # the controller's timing predictor and the demo's stream plan
    stream_plan((0.3, 0.7), config)


def run(args) -> int:
    """Compile (or load) the kernels; print where they are cached and how long it took."""
    from sorter_sim.model.core.cache import SHIPPED_DIR, kernel_cache_dir, shipped_kernels_fit

    t0 = time.perf_counter()
    if args.all:
        from sorter_sim.runtime.warmup import warm_up

        warm_up()
    else:
        warm_shipped()
    wall = time.perf_counter() - t0
    what = "every kernel" if args.all else "the kernels the demo and the nodes need"
    unfit = shipped_kernels_fit(SHIPPED_DIR)
    if args.json:
        print(
            json.dumps(
                {
                    "all": args.all,
                    "seconds": round(wall, 2),
                    "cache": str(kernel_cache_dir()),
                    "shipped": str(SHIPPED_DIR) if unfit is None else None,
                }
            )
        )
    else:
        shipped = f"shipped kernels in {SHIPPED_DIR}" if unfit is None else unfit
        print(
            f"sorter warmup: {what}, compiled or loaded in {wall:.1f} s; "
            f"cached in {kernel_cache_dir()}; {shipped}"
        )
    return 0
