#!/usr/bin/env bash
# The whole test suite: creates/refreshes .venv, compiles the model's numba kernels
# into their on-disk cache (once per clone; the time is printed), then runs pytest
# with the defaults from pytest.ini. Extra arguments are passed on to pytest.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
source scripts/_venv.sh

# The kernels compile for the generic x86-64 CPU, as those a wheel ships
# (sorter_sim/model/portable_kernels.py): the suite runs what users load, and the
# installed-package test builds its wheel from this cache instead of compiling again.
# Generic code runs this model as fast as the host's (the module says by how much).
export NUMBA_CPU_NAME=generic
unset NUMBA_CPU_FEATURES
.venv/bin/sorter warmup --all
# Python keeps the bytecode of what it imports (the project's sources, pytest's rewritten
# tests) for the next process to read. The suite starts some 400 Python processes, and
# two workers that each collect every test file: where PYTHONDONTWRITEBYTECODE turns
# that off, each compiles again all it imports (a worker's collection takes 11 s instead
# of 5.5 s, a node process 0.3 s more). The suite's own processes keep it on.
unset PYTHONDONTWRITEBYTECODE
exec .venv/bin/python -m pytest "$@"
