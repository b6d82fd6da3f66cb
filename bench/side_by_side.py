"""Old against new physics core, in one run: µs per World.step on the default scene and
chains of 1/10/100/1000 links, each implementation in its own subprocess (both are the
package `abd_joint_sim`), alternating rounds so the machine's load hits both alike.

    git worktree add /tmp/old <commit>      # the code to compare with (its kernels compiled)
    python bench/side_by_side.py --old /tmp/old [--rounds 5]

Times are CPU time of the process (`time.process_time`): on a machine shared with other jobs
wall time mostly measures the load, CPU time the code. Per scene and implementation: median
over rounds (and the minimum, the round least disturbed by other jobs) of the mean µs per
`World.step()` call
(one step per call, as the node's single steps), and for this tree also `World.step(n)` (n
steps in one call: the clean ones batched in compiled code). Torque on every joint (the
scene's, else 1 N m), 3 warm-up steps first. `kuka` is the KUKA iiwa URDF of pybullet_data
(gravity, joint limits; the torques swing it into its limits). Each checkout compiles into its
own kernel cache directory (abd_joint_sim/jit/cache.py keys it on the kernel sources; checkouts
from before that share one and recompile over each other: give them ABD_KERNEL_CACHE).
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]

CHILD = r'''
import gc, json, sys, time
sys.path.insert(0, sys.argv[1])
from abd_joint_sim import Scene, World
from abd_joint_sim.builders import chain_scene
name, steps = sys.argv[2], int(sys.argv[3])
import inspect
# before issue 13 World took a backend argument (and the compiled one had to be asked for)
kw = {'backend': 'numba'} if 'backend' in inspect.signature(World).parameters else {}
if name == 'default':
    d = Scene.from_yaml(sys.argv[1] + '/abd_joint_sim/scenes/default.yaml')
elif name == 'kuka':
    import pybullet_data
    d = Scene.from_urdf(pybullet_data.getDataPath() + '/kuka_iiwa/model.urdf')
else:
    d = Scene.from_dict(chain_scene(int(name[5:])))
def make():
    w = World(d, **kw)
    for k, j in enumerate(w.actuated_joint_names):
        w.set_torque(j, w.model.torque_value0[k] or 1.0)
    w.step(3)
    return w
w = make()
gc.disable()
t0 = time.process_time()
for _ in range(steps):
    w.step()
single = (time.process_time() - t0) / steps
its = w.last_step.newton_iterations
w = make()
t0 = time.process_time()
w.step(steps)
batched = (time.process_time() - t0) / steps
print(json.dumps(dict(single=single, batched=batched, its=its, angle=float(w.joint_angles()[-1]))))
'''

SCENES = {'default': 2000, 'chain1': 2000, 'chain10': 1000, 'chain100': 200, 'chain1000': 20,
          'kuka': 1000}


def run(root, name, steps, which):
    out = subprocess.run([sys.executable, '-c', CHILD, str(root), name, str(steps), which],
                         capture_output=True, text=True, timeout=900)
    if out.returncode:
        raise RuntimeError(out.stderr[-2000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--old', type=Path, required=True, help='checkout of the code to compare with')
    ap.add_argument('--rounds', type=int, default=5)
    ap.add_argument('--scenes', nargs='*', default=list(SCENES))
    args = ap.parse_args(argv)
    print('| scene | old µs/step median (min) | new µs/step median (min) | new/old median (min) | '
          'new µs/step in step(n) | Newton it (old, new) | same final angle |')
    print('|---|---|---|---|---|---|---|')
    for name in args.scenes:
        res = {'old': [], 'new': []}
        for _ in range(args.rounds):
            res['old'].append(run(args.old, name, SCENES[name], 'old'))
            res['new'].append(run(HERE, name, SCENES[name], 'new'))
        med = {k: statistics.median(r['single'] for r in v) * 1e6 for k, v in res.items()}
        low = {k: min(r['single'] for r in v) * 1e6 for k, v in res.items()}
        batched = statistics.median(r['batched'] for r in res['new']) * 1e6
        same = res['old'][0]['angle'] == res['new'][0]['angle']
        print(f'| {name} | {med["old"]:.1f} ({low["old"]:.1f}) | {med["new"]:.1f} ({low["new"]:.1f}) | '
              f'{med["new"] / med["old"]:.2f} ({low["new"] / low["old"]:.2f}) | {batched:.1f} | '
              f'{res["old"][0]["its"]}, {res["new"][0]["its"]} | {same} |', flush=True)


if __name__ == '__main__':
    main()
