"""The angle terms (driving UID 19, limit UID 670) on the KUKA iiwa, this tree against
another checkout, in one run: µs per `World.step()` and per call of the term's assembly
(`limit.accumulate` / `driving.accumulate` timed from compiled code), each implementation
in its own subprocess, alternating rounds, CPU time (as bench/side_by_side.py).

    git archive <commit> | tar -x -C /tmp/old        # the code to compare with
    python bench/angle_terms.py --old /tmp/old [--rounds 3]

Scenes (dt 1 ms, gravity, pybullet_data's kuka_iiwa/model.urdf via Scene.from_urdf):
- `kuka_limits`: bench/robot_bench.py's torque on every joint; after 1 s of it two joint
  limits are active (joints 2 and 7 beyond their range), then timed.
- `kuka_drives`: the same plus a drive on every joint holding it at its initial angle
  (strength_ratio 100): seven drives, each a few mrad from its aim (E'∇²θ kept, so each
  is PSD-projected in every Newton iteration).
Answers: the joint angles after the 3000 steps, this tree against the other checkout, and
beside it the other checkout against itself started from a state moved by one rounding step
(the arm under these torques is chaotic: any rounding difference grows ~10× per 300 steps).
Set ABD_KERNEL_CACHE per checkout to a directory of your own (e.g.
`ABD_KERNEL_CACHE=~/.cache/abd-kc`, the child adds `-old` / `-new`) so the two trees do not
recompile each other's kernels; a cache directory others can write is refused (cache.py).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]

CHILD = r'''
import dataclasses, gc, json, sys, time
sys.path.insert(0, sys.argv[1]); sys.path.insert(0, sys.argv[1] + '/bench')
import numpy as np
from numba import njit
from abd_joint_sim import Scene, World
from abd_joint_sim.scene import DrivingSpec
from abd_joint_sim.terms import driving, limit
import robot_bench
name, steps, perturb = sys.argv[2], int(sys.argv[3]), sys.argv[4] == '1'
scene = Scene.from_urdf(robot_bench.robot_path(), dt=1e-3)
if name == 'kuka_drives':
    joints = tuple(dataclasses.replace(j, driving=DrivingSpec(enabled=True, aim_angle=j.init_angle))
                   for j in scene.joints)
    scene = dataclasses.replace(scene, joints=joints)
term = driving if name == 'kuka_drives' else limit

@njit
def assemble(term_id, q, data, ctx, g, d, p, n):
    for _ in range(n):
        if term_id == 0:
            limit.accumulate(q, data, ctx, g, d, p, True)
        else:
            driving.accumulate(q, data, ctx, g, d, p, True)

def make():
    w = World(scene)
    for j, tau in zip(scene.joint_names, robot_bench.torques(len(scene.joint_names))):
        w.set_torque(j, tau)
    if perturb:     # every free A entry moved by one rounding step: how far rounding alone goes
        free = ~w.model.body_fixed
        sign = np.random.default_rng(0).choice([-1.0, 1.0], size=w.state.q[free, 3:12].shape)
        w.state.q[free, 3:12] *= 1.0 + 2.2e-16 * sign
    w.step(1000)
    return w
w = make()
ctx = w.solver.context(w.state, w.control, w.dt)
q, data = w.state.q, w.solver.data
active = int(term.active_joints(q, data, ctx)[3])
B, J = q.shape[0], len(scene.joint_names)
g, d, p = np.zeros((B, 12)), np.zeros((B, 12, 12)), np.zeros((J, 12, 12))
tid = 1 if term is driving else 0
assemble(tid, q, data, ctx, g, d, p, 10)
gc.disable()
t0 = time.process_time()
assemble(tid, q, data, ctx, g, d, p, 20000)
call = (time.process_time() - t0) / 20000
its = []
t0 = time.process_time()
for _ in range(steps):
    its.append(w.step().newton_iterations)
single = (time.process_time() - t0) / steps
angles = [float(a) for a in w.joint_angles()]
w = make()
t0 = time.process_time()
w.step(steps)
batched = (time.process_time() - t0) / steps
print(json.dumps(dict(call=call, single=single, batched=batched, its=float(np.mean(its)),
                      active=active, angles=angles)))
'''

SCENES = {'kuka_limits': 2000, 'kuka_drives': 2000}


def run(root, name, steps, which, perturb=False):
    env = dict(os.environ)
    if env.get('ABD_KERNEL_CACHE'):
        env['ABD_KERNEL_CACHE'] = f'{env["ABD_KERNEL_CACHE"]}-{which}'
    out = subprocess.run([sys.executable, '-c', CHILD, str(root), name, str(steps), '1' if perturb else '0'],
                         capture_output=True, text=True, timeout=1800, env=env)
    if out.returncode:
        raise RuntimeError(out.stderr[-2000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--old', type=Path, required=True, help='checkout of the code to compare with')
    ap.add_argument('--rounds', type=int, default=3)
    ap.add_argument('--scenes', nargs='*', default=list(SCENES))
    args = ap.parse_args(argv)
    print('| scene | active terms | term assembly µs/call old → new | µs/step old → new (new/old) | '
          'µs/step in step(n) old → new | Newton it/step old, new | max |Δ angle| new − old [rad] | '
          'the same, old − old from a start moved by one rounding step |')
    print('|---|---|---|---|---|---|---|---|')
    for name in args.scenes:
        res = {'old': [], 'new': []}
        for _ in range(args.rounds):
            res['old'].append(run(args.old, name, SCENES[name], 'old'))
            res['new'].append(run(HERE, name, SCENES[name], 'new'))
        med = {k: {f: statistics.median(r[f] for r in v) * 1e6 for f in ('call', 'single', 'batched')}
               for k, v in res.items()}
        def diff(x, y):
            return max(abs(a - b) for a, b in zip(x['angles'], y['angles']))
        noise = diff(res['old'][0], run(args.old, name, SCENES[name], 'old', perturb=True))
        o, n = med['old'], med['new']
        print(f'| {name} | {res["new"][0]["active"]} | {o["call"]:.2f} → {n["call"]:.2f} | '
              f'{o["single"]:.1f} → {n["single"]:.1f} ({n["single"] / o["single"]:.2f}) | '
              f'{o["batched"]:.1f} → {n["batched"]:.1f} | '
              f'{res["old"][0]["its"]:.2f}, {res["new"][0]["its"]:.2f} | '
              f'{diff(res["old"][0], res["new"][0]):.1e} | {noise:.1e} |', flush=True)


if __name__ == '__main__':
    main()
