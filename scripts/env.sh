# Sourced by the scripts: creates/updates .venv with the pinned wheels, and sets the
# environment every ROS process here needs. Idempotent and quiet when nothing changed.
# Usage: source scripts/env.sh [requirements file]
set -e
ABD_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ABD_VENV="${ABD_VENV:-$ABD_ROOT/.venv}"
_req="${1:-$ABD_ROOT/requirements-test.txt}"
if [ ! -x "$ABD_VENV/bin/python" ]; then
  python3 -m venv "$ABD_VENV"
fi
# Reinstall only when the requirements changed (hash stamp in the venv).
_stamp="$ABD_VENV/.req-$(cat "$ABD_ROOT"/requirements*.txt | sha1sum | cut -c1-12)-$(basename "$_req")"
if [ ! -f "$_stamp" ]; then
  "$ABD_VENV/bin/python" -m pip install --disable-pip-version-check -q -r "$_req"
  touch "$_stamp"
fi
# No DDS traffic may leave loopback (shared/spec/ROS.md).
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
export PATH="$ABD_VENV/bin:$PATH"
export AMENT_PREFIX_PATH="$ABD_VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
set +e
