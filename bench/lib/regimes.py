"""Where a step stops taking one Newton iteration: chains of 10 links of several sizes under
several torques (dt 1 ms, bdf1, no gravity), ours one step per call against MuJoCo's Euler on
the same chain (`peers.make_mujoco`), CPU time. Light links under large torques turn more
than ~0.1 rad per step (our bdf1 accuracy warning); there Newton takes several iterations
per step, and MuJoCo's Euler at the same dt is where it reports the simulation unstable.
For docs/speed.md.

    python bench/peers.py regimes [--steps 1000] [--links 10]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import engines as peers                                          # noqa: E402
from abd_joint_sim import Scene, World                          # noqa: E402
from abd_joint_sim.builders import chain_scene                  # noqa: E402

SIZES = (0.05, 0.1, 0.2, 1.0)        # [m] link length (boxes link × link/2 × link/2)
TORQUES = (0.01, 0.1, 1.0)           # [N m] on every joint


def ours(links, link, tau, steps):
    """(max rotation per step [rad], mean Newton it/step, µs/step, warnings)."""
    world = World(Scene.from_dict(chain_scene(links, link=link, torque=tau)))
    its, rotation, warned = [], 0.0, 0
    t0 = time.process_time()
    for _ in range(steps):
        report = world.step()
        its.append(report.newton_iterations)
        rotation = max(rotation, report.max_step_rotation)
        warned += bool(report.warnings)
    return rotation, float(np.mean(its)), (time.process_time() - t0) / steps * 1e6, warned


def mujoco(links, link, tau, steps):
    """(µs/step, whether MuJoCo reported the simulation unstable), or None without it."""
    made = peers.make_mujoco(links, tau=tau, link=link)
    if made is None:
        return None
    step, _ = made
    here = os.getcwd()
    with tempfile.TemporaryDirectory() as scratch:
        os.chdir(scratch)           # MuJoCo appends its warnings to ./MUJOCO_LOG.TXT
        try:
            t0 = time.process_time()
            for _ in range(steps):
                step()
            elapsed = time.process_time() - t0
        finally:
            os.chdir(here)
    import mujoco as mj
    # mj_step resets the state where the accelerations turned non-finite or huge, and counts it
    unstable = step.data.warning[mj.mjtWarning.mjWARN_BADQACC].number > 0
    return elapsed / steps * 1e6, unstable


def main(argv=None):
    ap = argparse.ArgumentParser(prog='bench/peers.py regimes', description=__doc__.split('\n\n')[0])
    ap.add_argument('--steps', type=int, default=1000)
    ap.add_argument('--links', type=int, default=10)
    args = ap.parse_args(argv)
    warnings.simplefilter('ignore')
    print(f'chain of {args.links} links, dt 1 ms, {args.steps} steps from rest, one step per call, '
          f'load {os.getloadavg()[0]:.2f}')
    print('| link [m] | torque [N m] | max rotation per step [rad] | Newton it/step | steps with a '
          'warning | ours µs/step | MuJoCo µs/step | ours/MuJoCo | MuJoCo Euler |')
    print('|---|---|---|---|---|---|---|---|---|')
    for link in SIZES:
        for tau in TORQUES:
            rotation, its, us, warned = ours(args.links, link, tau, args.steps)
            peer = mujoco(args.links, link, tau, args.steps)
            if peer is None:
                mj = ratio = verdict = '–'
            else:
                mj, ratio = f'{peer[0]:.1f}', f'{us / peer[0]:.1f}'
                verdict = '**unstable**' if peer[1] else 'ran'
            print(f'| {link} | {tau} | {rotation:.3f} | {its:.2f} | {warned} | {us:.1f} | {mj} | {ratio} '
                  f'| {verdict} |', flush=True)


if __name__ == '__main__':
    main()
