#!/usr/bin/env bash
# Regenerate the golden bags of test/test_headless_replay.py (see docs/replay.md).
# Run after a deliberate change of the physics (or of the bag layout), from anywhere:
#     bash test/data/make_golden.sh
# then check the new bags replay (done below), review and commit them with the change.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
# shellcheck disable=SC1091
source scripts/env.sh >/dev/null
set -euo pipefail
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
cd test/data
rm -rf golden_default golden_three_link
python -m abd_joint_sim.tools.run_headless --schedule default_schedule.yaml --scene default \
    --out golden_default
python -m abd_joint_sim.tools.run_headless --schedule three_link_schedule.yaml \
    --scene ./three_link.yaml --out golden_three_link
python -m abd_joint_sim.tools.replay_check golden_default
python -m abd_joint_sim.tools.replay_check golden_three_link
du -sh golden_default golden_three_link
