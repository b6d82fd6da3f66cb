"""Error against run time for a real robot description: the KUKA iiwa URDF shipped
in the pybullet wheel (`pybullet_data/kuka_iiwa/model.urdf`, 7 revolute joints, never copied
here), loaded with `Scene.from_urdf`, against a rigid-body reference: MuJoCo loading the same
file (RK4 at dt = 1e-5; its <dynamics> damping, friction loss, armature and contacts off;
the file's joint damping off on our side too, `damping=False`).

Motion: from rest, gravity, and at t = 0 a torque step (−1)^k (2 − 0.2 k) N m on joint k,
for T = 0.2 s (joint 7 turns ~3 rad), joint limits off in both (hitting one is a
non-smooth event, not what is measured). Error = max over the samples (every 10 ms) of max_k |θ_k − θ_k^ref| [rad]:
how far the affine links lag the rigid robot. Swept: dt x {bdf1, bdf2} at κ = 1e8 (the
default), and κ at the finest dt (the elastic floor: an affine body deforms by ~1/κ under
the joint loads). MuJoCo Euler / RK4 at the same dt are timed and scored the same way.
Wall time = seconds per simulated second (stepping only, from Python, in this process).

    python study/urdf_robot.py [--quick] [--out docs/results/urdf_robot]

Writes <out>.md and <out>.csv. Needs pybullet (for the file) and mujoco
(requirements-bench.txt / requirements-test.txt).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abd_joint_sim import Scene, World      # noqa: E402

T_END = 0.2
SAMPLE = 0.01
REL = 'kuka_iiwa/model.urdf'


def robot_path() -> str:
    import pybullet_data
    return os.path.join(pybullet_data.getDataPath(), REL)


def torques(n):
    return [((-1) ** k) * (2.0 - 0.2 * k) for k in range(n)]


def samples(dt):
    every = max(1, int(round(SAMPLE / dt)))
    return every, int(round(T_END / dt))


def run_mujoco(path, dt, integrator='RK4'):
    import mujoco
    m = mujoco.MjModel.from_xml_path(path)
    m.opt.timestep = dt
    m.opt.integrator = getattr(mujoco.mjtIntegrator, f'mjINT_{integrator.upper()}')
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    m.dof_damping[:] = 0.0
    m.dof_frictionloss[:] = 0.0
    m.dof_armature[:] = 0.0
    m.jnt_limited[:] = 0            # the distal joints would reach their limits: a
    m.jnt_range[:] = 0.0            # non-smooth event that is not what is measured here
    d = mujoco.MjData(m)
    names = [m.joint(i).name for i in range(m.njnt)]
    d.qfrc_applied[:] = torques(len(names))
    every, n = samples(dt)
    out = []
    t0 = time.perf_counter()
    for k in range(1, n + 1):
        mujoco.mj_step(m, d)
        if k % every == 0:
            out.append(d.qpos.copy())
    wall = time.perf_counter() - t0
    return names, np.array(out), wall / T_END


def run_ours(path, dt, integrator, kappa):
    scene = Scene.from_urdf(path, dt=dt, integrator=integrator, kappa=kappa, limits=False,
                            damping=False)
    world = World(scene)
    for name, tau in zip(scene.joint_names, torques(len(scene.joint_names))):
        world.set_torque(name, tau)
    every, n = samples(dt)
    out = []
    iters = 0
    t0 = time.perf_counter()
    for k in range(1, n + 1):
        report = world.step()
        iters += report.newton_iterations
        if k % every == 0:
            out.append(world.joint_angles().copy())
    wall = time.perf_counter() - t0
    return list(scene.joint_names), np.array(out), wall / T_END, iters / n, 'compiled'


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer points (a test runs this)')
    ap.add_argument('--out', default='docs/results/urdf_robot')
    args = ap.parse_args(argv)
    path = robot_path()
    names, ref, _ = run_mujoco(path, 1e-5)
    dts = [2e-3, 1e-3, 5e-4] if args.quick else [5e-3, 2e-3, 1e-3, 5e-4, 2.5e-4, 1.25e-4]
    kappas = [1e6, 1e8] if args.quick else [1e5, 1e6, 1e7, 1e8, 1e10]
    rows = []

    def err(q):
        assert len(q) == len(ref), 'dt must divide the 10 ms sampling period'
        return float(np.abs(q - ref).max())

    for integ in ('bdf1', 'bdf2'):
        for dt in dts:
            jn, q, wall, it, backend = run_ours(path, dt, integ, 1e8)
            assert jn == names, (jn, names)
            rows.append(dict(engine=f'ours {integ}', dt=dt, kappa=1e8, error=err(q), wall=wall,
                             newton=it, backend=backend))
            print(rows[-1], flush=True)
    for kappa in kappas:
        if kappa == 1e8:
            continue
        dt = dts[-1]
        jn, q, wall, it, backend = run_ours(path, dt, 'bdf2', kappa)
        rows.append(dict(engine='ours bdf2', dt=dt, kappa=kappa, error=err(q), wall=wall,
                         newton=it, backend=backend))
        print(rows[-1], flush=True)
    for integ in ('Euler', 'RK4'):
        for dt in dts:
            _, q, wall = run_mujoco(path, dt, integ)
            rows.append(dict(engine=f'MuJoCo {integ}', dt=dt, kappa=float('nan'), error=err(q),
                             wall=wall, newton=float('nan'), backend='-'))
            print(rows[-1], flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cols = ['engine', 'dt', 'kappa', 'error', 'wall', 'newton', 'backend']
    with open(out.with_suffix('.csv'), 'w') as f:
        f.write(','.join(cols) + '\n')
        for r in rows:
            f.write(','.join(str(r[c]) for c in cols) + '\n')
    lines = [f'# KUKA iiwa (pybullet_data/{REL}) against a rigid reference',
             '',
             f'Reference: MuJoCo RK4 at dt 1e-5 on the same file. Torque step on every joint '
             f'from rest with gravity, T = {T_END} s; error = max over 10 ms samples of the '
             'largest joint-angle deviation [rad]; wall = s per simulated second. '
             f'Command: `python study/urdf_robot.py{" --quick" if args.quick else ""}`.',
             '',
             '| engine | dt [s] | κ [Pa] | max angle error [rad] | wall [s/s] | Newton it/step | backend |',
             '| --- | --- | --- | --- | --- | --- | --- |']
    for r in rows:
        lines.append(f'| {r["engine"]} | {r["dt"]:g} | {r["kappa"]:.0e} | {r["error"]:.2e} | '
                     f'{r["wall"]:.3g} | {r["newton"]:.2f} | {r["backend"]} |'.replace('| nan |', '| – |'))
    out.with_suffix('.md').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))
    return rows


if __name__ == '__main__':
    main()
