"""Ours side by side with MuJoCo and PyBullet: the same chains, robots and URDF files in one
process, the engines taking turns, dt 1 ms (requirements-bench.txt; a peer that is not
installed is said so and its columns show –).

    python bench/peers.py chains --twice        # the tables of docs/speed.md "Against MuJoCo and PyBullet"
    python bench/peers.py sweep DIR             # every URDF under DIR against MuJoCo
    python bench/peers.py sliding               # a sliding joint's cost per body against revolute arms"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent / 'lib'))
import dispatch  # noqa: E402

COMMANDS = {
    'chains': ('chains', 'default scene, hinge, chains of 1-1000 links, a tree; then the KUKA iiwa '
                         'and more robots of pybullet_data (µs per step, ratios)'),
    'robots': ('robot_bench', 'the KUKA iiwa in all three engines and more robots of pybullet_data'),
    'sliding': ('slide_bench', 'the Panda with a sliding finger, with it as a hinge, locked, and the KUKA iiwa: '
                               'cost per body, ours and MuJoCo side by side'),
    'sweep': ('urdf_sweep', 'every URDF under a directory, loaded, stepped and timed against MuJoCo'),
    'chain-urdfs': ('chain_urdfs', 'write 48 URDF chains nobody tuned the simulator for, for `sweep`'),
    'regimes': ('regimes', 'Newton iterations per step where light links turn fast, against MuJoCo'),
    'sweeps': ('sweep_rate', "sweep cases per second in-process and on 1-2 Ray workers, against "
                             "mujoco.rollout on the same cases (docs/sweeps.md)"),
}

if __name__ == '__main__':
    sys.exit(dispatch.run('bench/peers.py', __doc__, COMMANDS))
