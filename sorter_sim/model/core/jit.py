"""
How the core's kernels are compiled.

Every kernel compiles once per argument types. numba types a constant argument as a
literal (``Literal[bool](True)``, ``Literal[int](0)``, a literal inside a tuple) and
compiles a kernel called from compiled code once per literal value it is called with:
``_approach`` once for a falling and once for a growing slip, ``_stuck_phase`` once
for a log counter that is 0 and once for one that is not, the event writer once per
event code. Those copies computed nothing different (LLVM still folds a constant
where it inlines the kernel) and were a fifth of the compiles of a cold cell: 245
against 198 for the shipped scene, 156 s against 143 s. So the decorators below hand
numba the argument types without their literal values: ``kernel`` for a kernel that
may allocate and compiles with its caller's runtime setting, and the two below for
the runtime.

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

Each decorator caches its kernel on disk with ``KernelCache`` (``cache.py``): numba's own
cache, with the kernels a wheel ships compiled for any x86-64 CPU read behind it.
"""

from __future__ import annotations

from numba import njit
from numba.core import types

from sorter_sim.model.core.cache import KernelCache


def _once_per_type(dispatcher):
    """
    Make calls from compiled code resolve ``dispatcher`` by its arguments' types alone.

    numba resolves such a call through the dispatcher's ``get_call_template``, which
    compiles the kernel for the argument types it is given; a literal type there is a
    copy of the kernel of its own. Passed without their literal values, the types of
    every call site that differs only in its constants meet in one compiled version,
    and the call converts the constant (a literal converts to its type safely).
    A call from Python never carries literal types: it is unchanged.
    """
    typed = dispatcher.get_call_template

    def get_call_template(args, kws):
        return typed(
            tuple(types.unliteral(a) for a in args),
            {k: types.unliteral(v) for k, v in kws.items()},
        )

    dispatcher.get_call_template = get_call_template
    return dispatcher


def _cached(dispatcher):
    """
    Cache ``dispatcher`` on disk as ``cache=True`` would, with the shipped kernels behind.

    ``KernelCache`` is numba's own cache of the kernel (the user's folder, the same
    files) that also reads the kernels a wheel ships compiled for any x86-64 CPU.
    """
    dispatcher._cache = KernelCache(dispatcher.py_func)
    return dispatcher


def once_per_type(**options):
    """Return a decorator that compiles with numba's ``options``, once per argument types."""
    cache = options.pop('cache', False)
    compile_with = njit(**options)
    if cache:
        return lambda function: _once_per_type(_cached(compile_with(function)))
    return lambda function: _once_per_type(compile_with(function))


def _kernel_step(function):
    return _cached(njit(inline='always')(function))


kernel = once_per_type(cache=True)
borrowing = once_per_type(cache=True, _nrt=False)
allocating = once_per_type(cache=True, _nrt=True)
kernel_step = _kernel_step

__all__ = ["allocating", "borrowing", "kernel", "kernel_step", "once_per_type"]
