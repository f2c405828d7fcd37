"""
The cell's runtime-free loop calls no kernel that allocates without its own runtime.

``advance_cell``'s period loop is compiled without numba's runtime (``jit.borrowing``)
and numba compiles whatever that loop calls with the caller's runtime setting unless
the callee names its own. A callee that allocates (``np.empty``, a copy) then fails to
compile, but only when the cell's loop is the first to call it: on a cold cache, the
very first ``sorter demo`` of a new user, never in a suite whose warm-up compiled it
earlier from a single-parcel run. Checked here from the sources, without compiling:
every kernel the loop calls (its inlined steps' callees included) either allocates
nothing anywhere in its call tree or is compiled ``jit.allocating``.
"""

import inspect
import re
import types

from numba.core.registry import CPUDispatcher

from sorter_sim.model.core import cell_kernels

# what allocates in the core's kernels
ALLOCATION = re.compile(
    r'np\.(empty|zeros|ones|full|array|empty_like|zeros_like|ones_like|concatenate|'
    r'sort|argsort|linspace|arange|copy)\b|\.copy\(\)'
)


def _global_names(code):
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names |= _global_names(const)
    return names


def _callees(kernel):
    func = kernel.py_func
    for name in _global_names(func.__code__):
        value = func.__globals__.get(name)
        if isinstance(value, CPUDispatcher) and value is not kernel:
            yield value


def _code_of(kernel):
    # the body without its docstring (a docstring may well say "np.empty")
    source = inspect.getsource(kernel.py_func)
    doc = kernel.py_func.__doc__
    return source.replace(doc, '') if doc else source


def _allocates(kernel, seen):
    if kernel in seen:
        return False
    seen.add(kernel)
    return bool(ALLOCATION.search(_code_of(kernel))) or any(
        _allocates(callee, seen) for callee in _callees(kernel)
    )


LOOPS = [cell_kernels._advance_periods_accurate, cell_kernels._advance_periods_implicit]


def _called_from_the_loop():
    """Return the kernels the runtime-free loops call, looking through their inlined steps."""
    called, seen = {}, set()
    stack = list(LOOPS)
    while stack:
        kernel = stack.pop()
        for callee in _callees(kernel):
            if callee in seen:
                continue
            seen.add(callee)
            if callee.targetoptions.get('inline') == 'always':
                stack.append(callee)
            else:
                called[callee.py_func.__qualname__] = callee
    return called


def test_the_cell_loop_is_compiled_without_the_runtime():
    # the premise: if the loop gets numba's runtime back, this check is moot
    for loop in LOOPS:
        assert loop.targetoptions.get('_nrt') is False


def test_every_allocating_kernel_the_loop_calls_has_its_own_runtime():
    called = _called_from_the_loop()
    # the integrators are among them: the walk does reach the loop's callees
    assert {'run_accurate', 'run_implicit'} <= set(called)
    inherit = sorted(
        name
        for name, kernel in called.items()
        if kernel.targetoptions.get('_nrt') is not True and _allocates(kernel, set())
    )
    assert not inherit, (
        f'{inherit}: called from the cell\'s runtime-free loop and allocating; compile them '
        '@allocating (sorter_sim/model/core/jit.py) or they fail on a cold cache'
    )
