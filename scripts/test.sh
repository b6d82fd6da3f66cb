#!/usr/bin/env bash
# README's second command (and CI's, via .ci/run): set everything up and run the whole test
# suite. Extra arguments go to pytest, e.g. `bash scripts/test.sh -k ros_node -x`, or
# `bash scripts/test.sh -m "not slow"` for the quick subset (pytest.ini, docs/quick-start.md).
# Each DDS test bounds its own waits with subprocess/receive timeouts (no pytest-timeout);
# the whole run is additionally capped by ABD_TEST_TIMEOUT seconds (default 1200).
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT" || exit 1
# shellcheck source=env.sh
source scripts/env.sh "$ROOT/requirements-test.txt" || { echo "[test] environment set-up failed" >&2; exit 1; }
export PYTHONDONTWRITEBYTECODE=1
# Compile the physics kernels once per machine (about 1 min on 2 idle cores, announced before
# it starts, a progress line every 5 s; a few seconds from the cache after), so no test pays
# for it. The cache is shared with the install space.
python -m abd_joint_sim.warmup >&2 || { echo "[test] the physics kernels failed to compile" >&2; exit 1; }
timeout --signal=INT --kill-after=30 "${ABD_TEST_TIMEOUT:-1200}" \
    python -m pytest -q -p no:cacheprovider test "$@" < /dev/null
status=$?
case $status in
    0) ;;
    5) echo "[test] pytest collected no tests: counted as a failure" >&2; status=1 ;;
    124|130) echo "[test] test suite exceeded ${ABD_TEST_TIMEOUT:-1200} s" >&2 ;;
esac
exit $status
