#!/usr/bin/env bash
# README's first command: set everything up, build the package with colcon into ./install,
# and run sim_node on the packaged default scene with recording on, as
# `ros2 run abd_joint_sim sim_node` would. Extra arguments are passed to the node, e.g.
#   bash scripts/run_default.sh --ros-args -p real_time_factor:=0.5 -p record:=''
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck source=env.sh
source scripts/env.sh
set -euo pipefail

mkdir -p "$ROOT/log"
echo "[run_default] colcon build -> $ROOT/install (log: $ROOT/log)" >&2
if ! colcon build --base-paths . --build-base build --install-base install \
        --event-handlers console_cohesion- summary- status- terminal_title- \
        > "$ROOT/log/colcon_build.out" 2>&1 < /dev/null; then
    cat "$ROOT/log/colcon_build.out" >&2 2>/dev/null || true
    mkdir -p "$ROOT/log"
echo "[run_default] colcon build failed" >&2
    exit 1
fi

# What `source install/setup.bash` does for this package, without relying on the generated
# scripts (they need a bash with the colcon prefix tools): put the install prefix on
# AMENT_PREFIX_PATH and its site-packages on PYTHONPATH.
PREFIX="$ROOT/install/abd_joint_sim"
[ -d "$PREFIX" ] || PREFIX="$ROOT/install"          # --merge-install layout
SITE="$(python -c 'import sys; print("python%d.%d" % sys.version_info[:2])')"
export AMENT_PREFIX_PATH="$PREFIX:$AMENT_PREFIX_PATH"
export PYTHONPATH="$PREFIX/lib/$SITE/site-packages${PYTHONPATH:+:$PYTHONPATH}"

# `ros2 run abd_joint_sim sim_node`: <prefix>/lib/<pkg>/<exe> found through the ament index.
EXE="$(python - <<'PY'
import os
from ament_index_python.packages import get_package_prefix
print(os.path.join(get_package_prefix('abd_joint_sim'), 'lib', 'abd_joint_sim', 'sim_node'))
PY
)"
BAG="$ROOT/bags/$(date +%Y%m%d-%H%M%S)"
mkdir -p "$ROOT/bags"
echo "[run_default] $EXE (recording to $BAG; Ctrl-C stops and closes the bag)" >&2
# A packaged node script starts with a '#!' line pointing at the venv's python.
# Later --ros-args sections win, so `-p record:=''` from the caller turns recording off.
exec "$EXE" --ros-args -p "record:=$BAG" "$@"
