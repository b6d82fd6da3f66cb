# Sourced by the scripts: creates/updates .venv with the pinned wheels, and sets the
# environment every ROS process here needs. Idempotent and quiet when nothing changed; says
# what it installs before it does, with pip's own progress and a line whenever venv or pip
# has been silent for 8 s (scripts/heartbeat.py), so a line comes at least every 10 s.
# Usage: source scripts/env.sh [requirements*.txt]   (default: requirements-test.txt)
#   requirements.txt: what the node needs (scripts/run_default.sh);
#   requirements-test.txt: that and what the tests need (scripts/test.sh).
# Returns non-zero (and leaves the venv marked out of date) if the installation fails.
# The caller's shell options are left alone (no set -e: it would end an interactive shell).
ABD_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ABD_VENV="${ABD_VENV:-$ABD_ROOT/.venv}"
# A sourced file sees the caller's positional parameters when given none of its own, so
# `source scripts/env.sh` inside `test.sh -k foo` would see "-k": take $1 only when it names
# a requirements file, else the default (ABD_REQUIREMENTS overrides both).
_abd_req="$ABD_ROOT/requirements-test.txt"
case "$(basename -- "${1:-}")" in
  requirements*.txt) [ -f "$1" ] && _abd_req="$1" ;;
esac
_abd_req="${ABD_REQUIREMENTS:-$_abd_req}"
_abd_ok=1
if [ ! -f "$_abd_req" ]; then
  echo "[env] requirements file not found: $_abd_req" >&2
  _abd_ok=0
elif [ ! -x "$ABD_VENV/bin/python" ]; then
  echo "[env] creating the virtual environment $ABD_VENV (about 10 s)" >&2
  python3 "$ABD_ROOT/scripts/heartbeat.py" "[env] python3 -m venv" 8 -- python3 -m venv "$ABD_VENV" >&2 \
    || { echo "[env] python3 -m venv failed" >&2; _abd_ok=0; }
fi
if [ "$_abd_ok" = 1 ]; then
  # Reinstall only when the requirements changed (hash stamp in the venv, written only
  # after pip succeeded).
  _abd_hash="$(cat "$ABD_ROOT"/requirements*.txt | sha1sum | cut -c1-12)"
  _abd_stamp="$ABD_VENV/.req-$_abd_hash-$(basename "$_abd_req")"
  # requirements-test.txt includes requirements.txt: a test venv serves the node as it is
  if [ "$(basename "$_abd_req")" = requirements.txt ] \
       && [ -f "$ABD_VENV/.req-$_abd_hash-requirements-test.txt" ]; then
    _abd_stamp="$ABD_VENV/.req-$_abd_hash-requirements-test.txt"
  fi
  unset _abd_hash
  if [ ! -f "$_abd_stamp" ]; then
    case "$(basename "$_abd_req")" in
      requirements.txt) _abd_what="rclpy and the ROS 2 Jazzy messages, numpy, numba, mcap, colcon; about 1 min" ;;
      *) _abd_what="the node's wheels and the tests' (scipy, matplotlib, MuJoCo, PyBullet, ...); about 2 min" ;;
    esac
    echo "[env] installing the pinned wheels of $(basename "$_abd_req") into $ABD_VENV" \
         "($_abd_what the first time on 2 cores; pip's progress follows):" >&2
    if python3 "$ABD_ROOT/scripts/heartbeat.py" "[env] pip install" 8 -- \
         "$ABD_VENV/bin/python" -m pip install --disable-pip-version-check -r "$_abd_req" >&2
    then
      touch "$_abd_stamp"
      echo "[env] installed" >&2
    else
      echo "[env] pip install -r $_abd_req failed (see above); the venv stays marked out" \
           "of date, so the next source of scripts/env.sh tries again" >&2
      _abd_ok=0
    fi
    unset _abd_what
  fi
fi
# No DDS traffic may leave loopback (shared/spec/ROS.md).
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
case ":$PATH:" in *":$ABD_VENV/bin:"*) ;; *) export PATH="$ABD_VENV/bin:$PATH" ;; esac
case ":${AMENT_PREFIX_PATH:-}:" in
  *":$ABD_VENV:"*) ;;
  *) export AMENT_PREFIX_PATH="$ABD_VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}" ;;
esac
[ "$_abd_ok" = 1 ]
