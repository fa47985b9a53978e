#!/usr/bin/env bash
# One entry point: every command first runs scripts/setup.sh (idempotent, fast when nothing changed).
#   ./run.sh sim   [args]   the main job: the paper's experiments on the simulated hand + report
#   ./run.sh test  [args]   the test suite (pytest)
#   ./run.sh exec CMD ...   any installed executable or command inside the environment
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
VENV=${TACFORCE_VENV:-$ROOT/.venv}
cmd=${1:-help}; shift || true

case "$cmd" in
    sim|test|exec|setup) "$ROOT/scripts/setup.sh" ;;
    *) sed -n '2,5p' "$0"; exit 2 ;;
esac

export PATH="$VENV/lib/tacforce_ros:$VENV/bin:$PATH" AMENT_PREFIX_PATH="$VENV"
# Keep DDS traffic on this host (Kilted+; older distros read ROS_LOCALHOST_ONLY).
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
export MPLBACKEND=Agg

case "$cmd" in
    setup) ;;
    sim) exec "$VENV/lib/tacforce_ros/reproduce" "$@" ;;
    test) cd "$ROOT" && exec "$VENV/bin/python" -m pytest "$@" ;;
    exec) exec "$@" ;;
esac
