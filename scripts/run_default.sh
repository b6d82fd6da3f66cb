#!/usr/bin/env bash
# README's first command: set up what the node needs (requirements.txt), build the package
# with colcon into ./install when its files changed since the last build, compile the physics
# kernels the first time, and run sim_node on the packaged default scene, recording to
# ./bags/<timestamp>, as `ros2 run abd_joint_sim sim_node` would. Arguments:
#   --no-record            run without recording (the node's default: the script passes no
#                          `record` parameter)
#   anything else          passed to the node, e.g.
#                          bash scripts/run_default.sh --ros-args -p real_time_factor:=0.5
# A `record` parameter of the caller's (`-p record:=my_bag`) replaces the script's own, so it
# is given once. build/, install/, log/ and bags/ go under $ABD_BUILD_ROOT (default: the
# repository).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
WS="${ABD_BUILD_ROOT:-$ROOT}"

RECORD=1
ARGS=()
for arg in "$@"; do
    case "$arg" in
        --no-record) RECORD=0 ;;
        record:=*) RECORD=0; ARGS+=("$arg") ;;   # the caller's own `-p record:=...`
        *) ARGS+=("$arg") ;;
    esac
done

# shellcheck source=env.sh
source scripts/env.sh "$ROOT/requirements.txt" || { echo "[run_default] environment set-up failed" >&2; exit 1; }
set -euo pipefail

# colcon only when a file the install space is built from changed, was added or removed
# since the last build (install/.abd-built holds one hash of their names and contents at that
# build).
SOURCES=(abd_joint_sim launch config resource setup.py setup.cfg package.xml)
STAMP="$WS/install/.abd-built"
current="$(find "${SOURCES[@]}" -type f ! -path '*/__pycache__/*' ! -name '*.pyc' -print0 \
           | sort -z | xargs -0 sha1sum | sha1sum | cut -c1-40)"
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$current" ] \
        && [ -d "$WS/install/abd_joint_sim" ]; then
    echo "[run_default] install space up to date ($WS/install): no colcon build" >&2
else
    mkdir -p "$WS/log"
    echo "[run_default] colcon build -> $WS/install (log: $WS/log)" >&2
    rm -f "$STAMP"
    if ! colcon --log-base "$WS/log" build --base-paths "$ROOT" --build-base "$WS/build" \
            --install-base "$WS/install" \
            --event-handlers console_cohesion- summary- status- terminal_title- \
            > "$WS/log/colcon_build.out" 2>&1 < /dev/null; then
        cat "$WS/log/colcon_build.out" >&2 || true
        echo "[run_default] colcon build failed" >&2
        exit 1
    fi
    echo "$current" > "$STAMP"
fi

# `source install/local_setup.bash`, as on a full ROS install: puts the install prefix on
# AMENT_PREFIX_PATH and its site-packages on PYTHONPATH. Done by hand if the script is missing.
if [ -f "$WS/install/local_setup.bash" ]; then
    set +u
    # shellcheck disable=SC1091
    source "$WS/install/local_setup.bash"
    set -u
else
    PREFIX="$WS/install/abd_joint_sim"
    SITE="$(python -c 'import sys; print("python%d.%d" % sys.version_info[:2])')"
    export AMENT_PREFIX_PATH="$PREFIX:$AMENT_PREFIX_PATH"
    export PYTHONPATH="$PREFIX/lib/$SITE/site-packages${PYTHONPATH:+:$PYTHONPATH}"
fi

# `ros2 run abd_joint_sim sim_node`: <prefix>/lib/<pkg>/<exe> found through the ament index.
# The node compiles the physics kernels itself the first time on a machine (announced, with
# a progress line every 5 s; abd_joint_sim/jit/warmup.py) and loads them from the cache after.
EXE="$(python -c 'import os; from ament_index_python.packages import get_package_prefix as p
print(os.path.join(p("abd_joint_sim"), "lib", "abd_joint_sim", "sim_node"))')"
if [ "$RECORD" = 1 ]; then
    BAG="$WS/bags/$(date +%Y%m%d-%H%M%S)"
    mkdir -p "$WS/bags"
    echo "[run_default] $EXE (recording to $BAG; Ctrl-C stops the node and closes the bag)" >&2
    exec "$EXE" --ros-args -p "record:=$BAG" "${ARGS[@]}"
fi
echo "[run_default] $EXE (Ctrl-C stops the node)" >&2
exec "$EXE" "${ARGS[@]}"
