"""Every URDF under a directory, loaded, stepped and timed against MuJoCo on the same file:
robots this project's tests and benches do not ship. One row per file: loaded and run (bodies, Newton iterations
per step over 200 one-step calls, ours and MuJoCo µs per step in one call of 1000 steps,
CPU time, the ratio), refused (the SceneError's message), or failed (the SimulationError).

    pip download --no-deps example-robot-data==6.0.0 -d /tmp/erd      # not a dependency
    cd /tmp/erd && python -m zipfile -e example_robot_data-6.0.0-0-py3-none-any.whl x
    python bench/peers.py sweep /tmp/erd/x [--match ur5 --match panda] [--torque-scale 0]

Conditions as `bench/peers.py robots`: dt 1 ms, gravity, a fixed base, the bench's
torques (`robot_bench.torques`, times `--torque-scale`) on every actuated joint, MuJoCo with contacts off, without
the meshes it cannot open and with its own inertia repairs where its compiler refuses the
file (`robot_bench.mujoco_model`; the row says so, and where MuJoCo's integration diverged).
"""
from __future__ import annotations

import argparse
import glob
import math
import os
import sys
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))     # this checkout's package
sys.path.insert(0, str(Path(__file__).resolve().parent))

from robot_bench import DT, mujoco_robot_steps, ours_robot_steps  # noqa: E402


def ours(path, scale=1.0):
    """('ran', bodies, iterations, µs) or ('refused' / 'failed', message)."""
    from abd_joint_sim import Scene, SimulationError, World
    from abd_joint_sim.errors import SceneError
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')                 # the importer's repairs (docs/urdf.md)
        try:
            world = World(Scene.from_urdf(path, dt=DT))
        except SceneError as exc:
            return ('refused', str(exc))
    try:
        its, t = ours_robot_steps(world, 1000, scale)
        return ('ran', world.model.body_count, its, t * 1e6)
    except SimulationError as exc:
        return ('failed', str(exc))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bench/peers.py sweep', description=__doc__.split('\n')[0])
    ap.add_argument('root', help='a directory searched for *.urdf')
    ap.add_argument('--match', action='append', default=[], help='only files whose path has this')
    ap.add_argument('--torque-scale', type=float, default=1.0,
                    help="the bench's torques times this on both sides (0: gravity alone)")
    args = ap.parse_args(argv)
    if not math.isfinite(args.torque_scale):
        ap.error(f'--torque-scale must be a finite number, got {args.torque_scale}')
    files = sorted(glob.glob(os.path.join(args.root, '**', '*.urdf'), recursive=True))
    files = [f for f in files if not args.match or any(s in f for s in args.match)]
    if not files:
        print(f'no .urdf under {args.root}')
        return 1
    print('| file | outcome | bodies | Newton it/step | ours µs/step | MuJoCo µs/step | ours/MuJoCo |')
    print('|---|---|---|---|---|---|---|')
    counts = {'ran': 0, 'refused': 0, 'failed': 0}
    for path in files:
        name = os.path.relpath(path, args.root)
        result = ours(path, args.torque_scale)
        counts[result[0]] += 1
        if result[0] != 'ran':
            msg = result[1][len(path) + 2:] if result[1].startswith(path + ': ') else result[1]
            print(f'| {name} | {result[0]}: {msg} | | | | | |', flush=True)
            continue
        _, bodies, its, t = result
        mj_t, note, why = mujoco_robot_steps(path, 1000, scale=args.torque_scale)
        mj_t = mj_t * 1e6 if mj_t else None
        ratio = f'{t / mj_t:.1f}' if mj_t else '–'
        mj_cell = (f'{mj_t:.1f}' if mj_t else f'– {why}') + (f' ({note})' if note else '')
        print(f'| {name} | ran | {bodies} | {its:.2f} | {t:.1f} | {mj_cell} | {ratio} |', flush=True)
    print(f'\n{len(files)} files: {counts["ran"]} ran, {counts["refused"]} refused, '
          f'{counts["failed"]} failed (load {os.getloadavg()[0]:.2f})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
