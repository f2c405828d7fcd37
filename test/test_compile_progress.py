"""What a first run says while numba compiles (which kernel, how far, how long), or nothing."""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
from numba import njit

from sorter_sim.model import compile_progress as cp


_SOURCE = """
@njit
def leaf_a(x):
    return x * 2.0


@njit
def leaf_b(x):
    return x + 1.0


@njit
def top(x):
    s = 0.0
    for i in range(x.shape[0]):
        s += leaf_a(x[i]) + leaf_b(x[i])
    return s
"""


def _kernels():
    """Three fresh kernels of a module's shape (not cached: they compile in the test)."""
    namespace = {'njit': njit}
    exec(compile(_SOURCE, '<kernels>', 'exec'), namespace)
    return namespace['top'], namespace['leaf_a'], namespace['leaf_b']


def test_reachable_follows_the_functions_a_kernel_names():
    top, _, _ = _kernels()
    names = cp.reachable(top)
    assert len(names) == 3, names
    assert any(n.endswith('leaf_a') for n in names) and any(n.endswith('leaf_b') for n in names)


def test_the_real_cell_kernel_reaches_dozens_of_functions():
    from sorter_sim.model.core.cell_kernels import advance_cell_accurate

    # the estimate the progress line gives for a cell's first compile
    assert 30 <= len(cp.reachable(advance_cell_accurate)) <= 400


@pytest.fixture
def progress(monkeypatch):
    out = io.StringIO()
    monkeypatch.setattr(cp, 'FIRST_S', 0.0)
    monkeypatch.setattr(cp, 'EVERY_LOG_S', 0.05)
    monkeypatch.setattr(cp, '_installed', False)
    monkeypatch.setattr(cp, '_quiet', False)
    from numba.core import event

    before = dict(event._registered)
    cp.install(out)
    yield out
    # take this test's listener off again
    event._registered.clear()
    event._registered.update(before)


def test_a_compile_is_announced_with_its_kernel_its_count_and_its_time(progress):
    top, _, _ = _kernels()
    original = cp._Progress.finish

    def slow_finish(self):
        time.sleep(0.2)  # let the ticker speak at least once
        original(self)

    cp._Progress.finish = slow_finish
    try:
        assert top(np.arange(3.0)) == pytest.approx(2 * 3.0 + 3.0 + 3.0)
    finally:
        cp._Progress.finish = original
    text = progress.getvalue()
    assert "compiling the model's kernels" in text and 'top' in text, text
    assert 'of ~3 functions' in text, text
    assert 'compiled top (3 functions) in' in text, text
    # loaded, not compiled: a second call says nothing more
    progress.truncate(0)
    progress.seek(0)
    top(np.arange(3.0))
    assert progress.getvalue() == ''


def test_quiet_says_nothing(progress):
    top, _, _ = _kernels()
    cp.set_quiet(True)
    try:
        top(np.arange(2.0))
        time.sleep(0.2)
    finally:
        cp.set_quiet(False)
    assert progress.getvalue() == ''
