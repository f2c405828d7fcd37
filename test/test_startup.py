"""
What a process that runs the model pays to start.

numba's array maths asks once, when a process's first kernel loads, whether a BLAS
exists, by importing ``scipy.linalg.cython_blas``; that imports all of
``scipy.linalg`` (0.3 s). ``sorter_sim.model.core.cache`` answers that one question
without the import, and leaves every later one to numba: a kernel that calls
``np.dot`` still finds scipy's BLAS. Each check runs in a fresh interpreter, as a
node or a command starts.
"""

import json
import subprocess
import sys

PROBE = r"""
import json, sys
from sorter_sim.runtime.scene import DEFAULTS, run_scene, validate

_, summary = run_scene(validate(DEFAULTS))  # the first kernels load: numba's target context
loaded = 'scipy.linalg' in sys.modules

import numba
import numpy as np
from numba.np import arraymath, linalg

@numba.njit
def dot(a, b):
    return np.dot(a, b)

print(json.dumps({
    't_scrap': summary['t_scrap'],
    'scipy_linalg_at_first_kernel': loaded,
    'numba_has_blas': arraymath._HAVE_BLAS,
    'probe_is_numbas': linalg.ensure_blas.__module__ == 'numba.np.linalg',
    'dot': dot(np.arange(3.0), np.array([1.0, 2.0, 4.0])),
    'scipy_linalg_after_dot': 'scipy.linalg' in sys.modules,
}))
"""


def test_a_model_process_loads_its_kernels_without_scipy_linalg_and_blas_still_works():
    done = subprocess.run(
        [sys.executable, '-c', PROBE], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-3000:]
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got['t_scrap'] > 0.0  # the model ran
    assert not got['scipy_linalg_at_first_kernel'], 'numba imported scipy.linalg to ask for BLAS'
    # numba's answer is the true one (scipy, a dependency, has a BLAS), and numba asks
    # itself from then on: compiling np.dot imported scipy's BLAS and used it
    assert got['numba_has_blas'] and got['probe_is_numbas']
    assert got['dot'] == 0.0 * 1.0 + 1.0 * 2.0 + 2.0 * 4.0
    assert got['scipy_linalg_after_dot']
