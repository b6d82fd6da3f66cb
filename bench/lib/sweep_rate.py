"""Cases per second of `sweep` (docs/sweeps.md "Speed"): serially in this process, on a
local Ray with 1 and 2 workers; the overhead per case; and the same sweeps of a two-link arm
and of the KUKA iiwa URDF in MuJoCo's own batch runner (`mujoco.rollout`, open-loop
torques, as many threads as workers).

    python bench/peers.py sweeps [--cases 16] [--duration 0.5] [--workers 1 2] [--no-mujoco]
                                [--robot arm|kuka|both]

Each rate is measured with warm workers: the Ray workers are started and have loaded the
compiled kernels (one case each) before the clock starts, as in a long sweep; the Ray
start-up is given on its own line. Overhead per case = (sweep wall time × workers − the
cases' own wall times) / cases: dispatch, argument and result transfer, the driver's
bookkeeping (and, with several workers, a worker idling at the end). Wall-clock times on a machine that may be shared: compare the ratios.
"""
from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
import sys
import tempfile
import time

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / 'bench'))
sys.path.insert(0, str(REPO / 'bench' / 'lib'))

from abd_joint_sim.tools import sweep  # noqa: E402

KUKA_JOINT = 'lbr_iiwa_joint_2'


def arm_spec(tmp: Path, cases: int, duration: float) -> Path:
    """The two-link arm (builders.chain_scene(2): vertical hinges, no gravity), the
    shoulder's torque swept, the elbow's 1 N m."""
    import yaml
    from abd_joint_sim.builders import chain_scene
    scene = tmp / 'arm.yaml'
    scene.write_text(yaml.safe_dump(chain_scene(2, dt=1e-3), sort_keys=False))
    spec = tmp / 'arm_sweep.yaml'
    spec.write_text(yaml.safe_dump({
        'scene': str(scene), 'duration': duration,
        'grid': {'joints.j1.external_torque.torque': arm_torques(cases)}}, sort_keys=False))
    return spec


def arm_torques(cases: int) -> list:
    return [float(x) for x in np.linspace(0.2, 2.0, cases)]


def kuka_spec(tmp: Path, path: str, cases: int, duration: float) -> Path:
    """The KUKA iiwa (pybullet_data) under gravity with bench/robot_bench.py's torques,
    its second joint's initial angle swept (a Monte Carlo over initial configurations)."""
    import yaml
    from robot_bench import torques
    spec = tmp / 'kuka_sweep.yaml'
    names = [f'lbr_iiwa_joint_{k}' for k in range(1, 8)]
    spec.write_text(yaml.safe_dump({
        'scene': path, 'urdf_options': {'dt': 1e-3}, 'duration': duration,
        'schedule': {'events': [{'t': 0.0, 'torque': dict(zip(names, torques(7)))}]},
        'grid': {f'robot.initial_positions.{KUKA_JOINT}': kuka_angles(cases)}},
        sort_keys=False))
    return spec


def kuka_angles(cases: int) -> list:
    return [float(x) for x in np.linspace(-0.5, 0.5, cases)]


def jobs_of(spec) -> list:
    return [sweep.Job(k, sweep.case_name(k, len(spec.cases)), values)
            for k, values in enumerate(spec.cases)]


def serial_rate(spec) -> dict:
    worker = sweep.CaseWorker(spec.setup)          # kernels loaded: not timed
    jobs = jobs_of(spec)
    worker.run(jobs[0])                              # as the Ray workers' warm round
    t0 = time.perf_counter()
    rows = [worker.run(job) for job in jobs]
    wall = time.perf_counter() - t0
    return _result('in-process, serial', rows, wall, 1)


def ray_rate(spec, workers: int) -> dict:
    t0 = time.perf_counter()
    engine = sweep.RayEngine(workers, None)
    try:
        jobs = jobs_of(spec)
        engine.run(spec.setup, jobs[:workers], lambda row: None)    # workers up and warm
        startup = time.perf_counter() - t0
        rows: list = []
        t0 = time.perf_counter()
        engine.run(spec.setup, jobs, rows.append)
        wall = time.perf_counter() - t0
    finally:
        engine.close()
    result = _result(f'Ray local, {workers} worker(s)', rows, wall, workers)
    result['startup'] = startup
    return result


def _result(name: str, rows: list, wall: float, workers: int) -> dict:
    """Rates; overhead per case = (wall x workers - the cases' own wall times) / cases:
    the worker time not spent in a case (dispatch, transfer, idling at the end)."""
    bad = [r for r in rows if r['status'] != 'ok']
    assert not bad, bad[0]
    case_wall = sum(r['wall_s'] for r in rows)
    return {'name': name, 'cases': len(rows), 'wall': wall, 'rate': len(rows) / wall,
            'case_wall': case_wall / len(rows),
            'overhead': (wall * workers - case_wall) / len(rows)}


def mujoco_arm_rate(cases: int, duration: float, threads: int) -> dict | None:
    try:
        import mujoco
        from mujoco import rollout
    except ImportError:
        return None
    from engines import make_mujoco
    model = make_mujoco(2, dt=1e-3)[0].data.model     # bench/peers.py's two-link chain
    nstep = int(round(duration / model.opt.timestep))
    control = np.zeros((cases, nstep, model.nu))
    control[:, :, 0] = np.array(arm_torques(cases))[:, None]
    control[:, :, 1] = 1.0
    return _rollout(mujoco, rollout, model, control, None, threads,
                    f'MuJoCo rollout, two-link arm, {threads} thread(s)')


def mujoco_kuka_rate(path: str, cases: int, duration: float, threads: int) -> dict | None:
    try:
        import mujoco
        from mujoco import rollout
    except ImportError:
        return None
    from robot_bench import mujoco_model, torques
    model, _ = mujoco_model(path)
    model.opt.timestep = 1e-3
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    nstep = int(round(duration / model.opt.timestep))
    qpos = np.tile(model.qpos0, (cases, 1))
    joint = model.joint(KUKA_JOINT)
    qpos[:, joint.qposadr[0]] = kuka_angles(cases)
    control = np.tile(np.array(torques(model.nv)), (cases, nstep, 1))
    return _rollout(mujoco, rollout, model, control, qpos, threads,
                    f'MuJoCo rollout, KUKA iiwa, {threads} thread(s)',
                    spec=mujoco.mjtState.mjSTATE_QFRC_APPLIED)


def _rollout(mujoco, rollout, model, control, qpos, threads, name, spec=None) -> dict:
    data = mujoco.MjData(model)
    size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state0 = np.zeros(size)
    mujoco.mj_getState(model, data, state0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    states = np.tile(state0, (control.shape[0], 1))
    if qpos is not None:               # FULLPHYSICS = time, qpos, qvel, ...
        states[:, 1:1 + model.nq] = qpos
    datas = [mujoco.MjData(model) for _ in range(threads)]
    kwargs = {'control_spec': spec} if spec is not None else {}
    with rollout.Rollout(nthread=threads) as runner:
        runner.rollout(model, datas, states[:1], control[:1], **kwargs)     # warm
        t0 = time.perf_counter()
        runner.rollout(model, datas, states, control, **kwargs)
        wall = time.perf_counter() - t0
    cases = control.shape[0]
    return {'name': name, 'cases': cases, 'wall': wall, 'rate': cases / wall,
            'case_wall': math.nan, 'overhead': math.nan}


def table(results: list) -> str:
    lines = ['| runner | cases | wall [s] | cases/s | mean case wall [s] | overhead/case [ms] |',
             '|---|---|---|---|---|---|']
    for r in results:
        lines.append(f'| {r["name"]} | {r["cases"]} | {r["wall"]:.2f} | {r["rate"]:.2f} | '
                     + ('–' if math.isnan(r['case_wall']) else f'{r["case_wall"]:.3f}') + ' | '
                     + ('–' if math.isnan(r['overhead']) else f'{1e3 * r["overhead"]:.1f}')
                     + ' |')
    return '\n'.join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bench/peers.py sweeps', description=__doc__.split('\n')[0])
    ap.add_argument('--cases', type=int, default=16)
    ap.add_argument('--duration', type=float, default=0.5, help='simulated s per case')
    ap.add_argument('--workers', type=int, nargs='*', default=[1, 2])
    ap.add_argument('--no-mujoco', action='store_true')
    ap.add_argument('--robot', choices=('arm', 'kuka', 'both'), default='both')
    args = ap.parse_args(argv)
    sweep._ray_environment(None)
    sweep._export_pythonpath()
    import numba
    print(f'peers.py sweeps: {args.cases} cases of {args.duration:g} s simulated, dt 1 ms; '
          f'{os.cpu_count()} CPU(s), numba {numba.__version__}', flush=True)
    tmp = Path(tempfile.mkdtemp(prefix='sweep-bench-'))
    try:
        return _bench(args, tmp)
    finally:
        import shutil
        shutil.rmtree(tmp, ignore_errors=True)


def _bench(args, tmp: Path) -> int:
    robots = [('two-link arm', arm_spec(tmp, args.cases, args.duration), None)] \
        if args.robot != 'kuka' else []
    if args.robot != 'arm':
        from robot_bench import robot_path
        path = robot_path()
        if path:
            robots.append(('KUKA iiwa', kuka_spec(tmp, path, args.cases, args.duration), path))
        else:
            print('peers.py sweeps: pybullet_data not installed: no KUKA iiwa rows')
    for label, spec_path, path in robots:
        spec = sweep.load_spec(spec_path)
        results = [serial_rate(spec)]
        print(f'  {label}: {results[-1]["name"]}: {results[-1]["rate"]:.2f} cases/s', flush=True)
        for workers in args.workers:
            results.append(ray_rate(spec, workers))
            print(f'  {label}: {results[-1]["name"]}: {results[-1]["rate"]:.2f} cases/s '
                  f'(start-up {results[-1]["startup"]:.1f} s)', flush=True)
        if not args.no_mujoco:
            for threads in args.workers:
                r = (mujoco_arm_rate(args.cases, args.duration, threads) if path is None
                     else mujoco_kuka_rate(path, args.cases, args.duration, threads))
                if r is not None:
                    results.append(r)
        print(f'\n### {label}\n\n{table(results)}\n', flush=True)
        ray = {r['name']: r['rate'] for r in results}
        one, two = ray.get('Ray local, 1 worker(s)'), ray.get('Ray local, 2 worker(s)')
        if one and two:
            print(f'2 workers / 1 worker: {two / one:.2f}x\n', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
