"""
Compile the model's numba kernels into their on-disk cache, once, and say how long it took.

numba compiles a kernel at its first call and caches the machine code next to the
sources (``__pycache__/*.nbi|*.nbc``), so that every later process loads it in
milliseconds. ``scripts/test.sh`` runs this before the test suite: on a fresh clone
the compilation is paid here, once, instead of inside whichever test first calls a
kernel, and the time printed is the suite's compile share. Run it by hand with
``python -m sorter_sim.runtime.warmup``; on a warm cache it takes about a second.

What it runs touches every kernel entry point the project uses: one parcel through
the seed's cell with each method, with and without the reductions, a speed-dependent
law, the Fig. 4 body with each method, and a cell with a parcel diverted.
"""

from __future__ import annotations

import time


def warm_up() -> float:
    """Run the representative workloads; return the wall time they took [s]."""
    t0 = time.perf_counter()
    from sorter_sim.model.core.cache import check_kernel_cache
    from sorter_sim.runtime.scene import DEFAULTS, run_scene, validate

    check_kernel_cache()
    from sorter_sim.model.core.oscillator import Oscillator, run_oscillator

    base = validate(DEFAULTS)
    for method in ("accurate", "implicit", "threshold"):
        for reductions in (True, False):
            for law in ("const1", "bspline"):
                scene = {k: dict(v) for k, v in base.items()}
                scene["solver"].update(method=method, reductions=reductions, t_max=0.2)
                scene["friction"]["model"] = law
                scene["zones"]["b"] = 1.0
                run_scene(validate(scene))
    for method in ("accurate", "implicit", "threshold"):
        run_oscillator(Oscillator(), 1.0, method)

    from sorter_sim.runtime.params import CellParams

    for integrator in ("accurate", "implicit"):
        warm_cell(CellParams.defaults().with_changes({"integrator": integrator}, runtime=False))
    return time.perf_counter() - t0


def warm_cell(params) -> float:
    """
    Run a throwaway cell of these parameters for 12 s simulated; return the wall time [s].

    The simulation node calls it before its clock starts, so that compiling (or
    loading) the kernels a parcel needs is start-up time, not simulated time a
    real-time cell would have to drop when the first parcel arrives.

    Parameters
    ----------
    params : CellParams
        The cell's parameters.

    Returns
    -------
    float
        The wall time it took [s].

    """
    from sorter_sim.runtime.cell import Cell, ParcelSpec

    t0 = time.perf_counter()
    # the node's own stream, a diverted parcel among it, until parcels have left by
    # every exit: the paths a running cell takes first
    cell = Cell(params.with_changes({"arrival": "gap"}, runtime=False))
    cell.popup(True)
    cell.induct(ParcelSpec(0.4, 0.3, 5.0, 0.0, 0.0, "W"))
    cell.advance(int(round(6.0 / params.control_period)))
    cell.parcels()  # what the node publishes as poses
    cell.popup(False)
    cell.advance(int(round(6.0 / params.control_period)))
    return time.perf_counter() - t0


def main() -> int:
    """Entry point of ``python -m sorter_sim.runtime.warmup``."""
    print(f"numba kernels compiled or loaded from the cache in {warm_up():.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
