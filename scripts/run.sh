#!/usr/bin/env bash
# The main job: creates/refreshes .venv, then runs the sorter cell demo.
# Extra arguments are passed on to `sorter demo`.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
source scripts/_venv.sh

exec .venv/bin/sorter demo "$@"
