"""
A core kernel compiles once per argument types, whatever constants its callers pass.

numba types a constant argument of a call from compiled code as a literal and, left
alone, compiles the callee once per literal value (``jit._once_per_type``): a fifth of
the compiles of a cold cell were such copies. Checked on two small kernels written
here, and on every kernel the core defines: each resolves its calls by types alone,
except the inlined steps, which are typed in their caller and never compiled alone.
"""

import importlib
import pkgutil

from numba.core import types
from numba.core.registry import CPUDispatcher

import sorter_sim.model.core as core
from sorter_sim.model.core.jit import once_per_type

# the core's decorators without their cache, so that these compile in every run
_uncached = once_per_type()
_uncached_borrowing = once_per_type(_nrt=False)


@_uncached_borrowing
def _scaled(x, flag, times):
    return times * x if flag else x


@_uncached
def _calls_with_constants(x):
    return _scaled(x, True, 2) + _scaled(x, False, 3) + _scaled(x, True, 4)


def test_a_kernel_called_with_different_constants_compiles_once():
    assert _calls_with_constants(1.5) == 3.0 + 1.5 + 6.0
    assert len(_scaled.signatures) == 1, _scaled.signatures
    (signature,) = _scaled.signatures
    assert not any(isinstance(t, types.Literal) for t in signature), signature


def _core_kernels():
    for info in pkgutil.iter_modules(core.__path__):
        module = importlib.import_module(f'{core.__name__}.{info.name}')
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == module.__name__:
                yield f'{info.name}.{name}', value


def test_every_core_kernel_resolves_its_calls_by_types_alone():
    kernels = dict(_core_kernels())
    assert len(kernels) > 100, sorted(kernels)
    literal_copies = sorted(
        name
        for name, dispatcher in kernels.items()
        if dispatcher.targetoptions.get('inline', 'never') == 'never'
        and 'get_call_template' not in vars(dispatcher)
    )
    assert not literal_copies, f'compiled once per constant: {literal_copies}'
