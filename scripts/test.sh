#!/usr/bin/env bash
# README's second command (and CI's, via .ci/run): set everything up and run the whole test
# suite. Extra arguments go to pytest, e.g. `bash scripts/test.sh -k ros_node -x`, or
# `bash scripts/test.sh -m "not slow"` for the quick subset (pytest.ini, docs/quick-start.md).
# Each DDS test bounds its own waits with subprocess/receive timeouts (no pytest-timeout);
# the whole run is additionally capped by ABD_TEST_TIMEOUT seconds (default 2700).
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT" || exit 1
# shellcheck source=env.sh
source scripts/env.sh "$ROOT/requirements-test.txt" || { echo "[test] environment set-up failed" >&2; exit 1; }
export PYTHONDONTWRITEBYTECODE=1
# Compile the physics kernels once per machine (announced before it starts, a progress line
# every 5 s; a few seconds from the cache after), so no test pays for it. The cache is shared
# with the install space.
python -m abd_joint_sim.jit.warmup >&2 || { echo "[test] the physics kernels failed to compile" >&2; exit 1; }
# The live page's browser test (test/test_live_browser.py) needs Debian's chromium: installed
# here when missing and running as root (CI); otherwise that test fails saying how to install
# it. Its three.js comes from abd_joint_sim/live/web/package-lock.json (npm ci, in the test).
if ! command -v "${ABD_CHROMIUM:-/usr/bin/chromium}" >/dev/null 2>&1 && [ "$(id -u)" = 0 ] \
        && command -v apt-get >/dev/null 2>&1; then
    echo "[test] installing chromium (apt-get) for the live page's browser test" >&2
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; } >&2 \
        || echo "[test] apt-get install chromium failed: the browser test will say so" >&2
fi
timeout --signal=INT --kill-after=30 "${ABD_TEST_TIMEOUT:-2700}" \
    python -m pytest -q -p no:cacheprovider test "$@" < /dev/null
status=$?
case $status in
    0) ;;
    5) echo "[test] pytest collected no tests: counted as a failure" >&2; status=1 ;;
    124|130) echo "[test] test suite exceeded ${ABD_TEST_TIMEOUT:-2700} s" >&2 ;;
esac
exit $status
