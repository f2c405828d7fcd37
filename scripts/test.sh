#!/usr/bin/env bash
# The whole test suite: creates/refreshes .venv, then runs pytest with the
# defaults from pytest.ini. Extra arguments are passed on to pytest.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
source scripts/_venv.sh

exec .venv/bin/python -m pytest "$@"
