#!/usr/bin/env bash
# README's first command: set everything up, build the package with colcon into ./install,
# and run sim_node on the packaged default scene with recording on (./bags/<timestamp>), as
# `ros2 run abd_joint_sim sim_node` would. Extra arguments are passed to the node, e.g.
#   bash scripts/run_default.sh --ros-args -p real_time_factor:=0.5 -p "record:=''"
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck source=env.sh
source scripts/env.sh "$ROOT/requirements-test.txt"
set -euo pipefail

mkdir -p "$ROOT/log"
echo "[run_default] colcon build -> $ROOT/install (log: $ROOT/log)" >&2
if ! colcon build --base-paths . --build-base build --install-base install \
        --event-handlers console_cohesion- summary- status- terminal_title- \
        > "$ROOT/log/colcon_build.out" 2>&1 < /dev/null; then
    cat "$ROOT/log/colcon_build.out" >&2 || true
    echo "[run_default] colcon build failed" >&2
    exit 1
fi

# `source install/local_setup.bash`, as on a full ROS install: puts the install prefix on
# AMENT_PREFIX_PATH and its site-packages on PYTHONPATH. Done by hand if the script is missing.
if [ -f "$ROOT/install/local_setup.bash" ]; then
    set +u
    # shellcheck disable=SC1091
    source "$ROOT/install/local_setup.bash"
    set -u
else
    PREFIX="$ROOT/install/abd_joint_sim"
    SITE="$(python -c 'import sys; print("python%d.%d" % sys.version_info[:2])')"
    export AMENT_PREFIX_PATH="$PREFIX:$AMENT_PREFIX_PATH"
    export PYTHONPATH="$PREFIX/lib/$SITE/site-packages${PYTHONPATH:+:$PYTHONPATH}"
fi

# Compile the installed copy's physics kernels (~1 min the first time on a machine, announced
# before it starts; ~1 s after: the cache is keyed on the sources, so the source tree's
# compile serves the install too). Run from / : `python -m` puts the current directory first
# on sys.path, and from the repository root that would load the source tree's copy.
(cd / && python -m abd_joint_sim.jit.warmup) >&2 || { echo "[run_default] the physics kernels failed to compile" >&2; exit 1; }

# `ros2 run abd_joint_sim sim_node`: <prefix>/lib/<pkg>/<exe> found through the ament index.
EXE="$(python -c 'import os; from ament_index_python.packages import get_package_prefix as p
print(os.path.join(p("abd_joint_sim"), "lib", "abd_joint_sim", "sim_node"))')"
BAG="$ROOT/bags/$(date +%Y%m%d-%H%M%S)"
mkdir -p "$ROOT/bags"
echo "[run_default] $EXE (recording to $BAG unless overridden; Ctrl-C stops the node and closes the bag)" >&2
# Later --ros-args sections win, so `--ros-args -p "record:=''"` from the caller turns it off
# (the inner quotes make a YAML empty string; a bare `record:=` does not parse).
exec "$EXE" --ros-args -p "record:=$BAG" "$@"
