"""
How the core's kernels are compiled.

numba counts the references to every array a compiled function receives: an atomic
add at its entry and a subtract at its exit, about 10 ns a call on a server core, and
not removed where the function branches or may fail. In the innermost kernels
(clipping the footprint to a strip, a strip's wrench, μ at a quadrature point, a
Dormand-Prince stage) that counting was a fifth of a whole Fig. 9a diversion. A
kernel that allocates nothing and returns no array needs none of it: its caller holds
the references for the duration of the call. ``borrowing`` compiles such a kernel
without numba's runtime (its ``_nrt`` option, which numba's own test suite compiles
runtime-free kernels with); one that allocated would fail to compile, never run
wrongly.

``kernel_step`` compiles a named step of a longer kernel (``advance_cell``'s per-period and
per-parcel steps): numba inlines it into its caller before type inference, so the
kernel compiles to one function as if the steps were written out in it. Called as a
function, a step that takes the cell's bundles (``CellSetup``, ``Parcels``, the
scratch) receives some thirty arrays: passing them, and counting their references,
cost more per parcel-period than the parcel's own closed-form motion (the cell ran
10-30x slower with its steps as calls).

``allocating`` compiles a kernel that allocates (its scratch, its trajectory) and that a
``borrowing`` kernel calls: the cell's loop calls the integrators. numba compiles a
callee with its caller's runtime setting unless the callee names its own, so without
it the integrators compiled runtime-free whenever the cell's loop was the first to
call them (a cold cache) and failed to compile (``np.empty`` has no runtime-free
form); it worked only where a single-parcel run had compiled them first.
"""

from __future__ import annotations

from numba import njit

borrowing = njit(cache=True, _nrt=False)
kernel_step = njit(cache=True, inline='always')
allocating = njit(cache=True, _nrt=True)

__all__ = ["allocating", "borrowing", "kernel_step"]
