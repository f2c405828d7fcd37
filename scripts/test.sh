#!/usr/bin/env bash
# The whole test suite: creates/refreshes .venv, compiles the model's numba kernels
# into their on-disk cache (once per clone; the time is printed), then runs pytest
# with the defaults from pytest.ini. Extra arguments are passed on to pytest.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
source scripts/_venv.sh

.venv/bin/sorter warmup --all
exec .venv/bin/python -m pytest "$@"
