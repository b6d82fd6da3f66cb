"""The URDF robots against MuJoCo and PyBullet: one real robot description, the KUKA iiwa
shipped in the pybullet wheel (`pybullet_data/kuka_iiwa/model.urdf`, 7 revolute joints),
loaded by `Scene.from_urdf`, MuJoCo (its URDF import) and PyBullet (`loadURDF`): per-step
cost at dt = 1 ms with gravity and a torque on every joint, each engine's default
integrator (ours: bdf1; MuJoCo: Euler; PyBullet: its semi-implicit Euler), from Python.
Then `robots`: more robots of pybullet_data (arms, legged robots with a fixed base), n steps
per call on both sides, ours against MuJoCo where MuJoCo loads the file.

    python bench/peers.py robots [--quick]
"""
from __future__ import annotations

import os
import statistics
import time

import numpy as np

DT = 1e-3


def robot_path():
    """Path of the KUKA URDF, or None without pybullet_data."""
    try:
        import pybullet_data
    except ImportError:
        return None
    path = os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa', 'model.urdf')
    return path if os.path.isfile(path) else None


def torques(n, scale=1.0):
    return [scale * ((-1) ** k) * (2.0 - 0.2 * k) for k in range(n)]


def _time(step, steps, repeats):
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(steps):
            step()
        out.append((time.perf_counter() - t0) / steps)
    return statistics.median(out)


def ours(path):
    """(one-step call, n-step call, Newton iterations of the one-step calls so far)."""
    from abd_joint_sim import Scene, World
    scene = Scene.from_urdf(path, dt=DT)
    world = World(scene)
    for name, tau in zip(scene.joint_names, torques(len(scene.joint_names))):
        world.set_torque(name, tau)
    world.step(3)
    its = []

    def step():
        its.append(world.step().newton_iterations)
    return step, world.step, its


def mujoco(path):
    """(one-step call, n-step call), or None without MuJoCo."""
    arm = _mujoco_arm(path)
    if arm is None:
        return None
    mj, m, d = arm
    d.qfrc_applied[:] = torques(m.nv)
    return (lambda: mj.mj_step(m, d)), (lambda n: mj.mj_step(m, d, n))     # nstep: one call


def _mujoco_arm(path):
    """(mujoco, model, data) of the URDF at dt DT, contacts off; None without MuJoCo."""
    try:
        import mujoco as mj
    except ImportError:
        return None
    m = mj.MjModel.from_xml_path(path)
    m.opt.timestep = DT
    m.opt.disableflags |= mj.mjtDisableBit.mjDSBL_CONTACT
    return mj, m, mj.MjData(m)


def pybullet(path):
    """(one-step call, disconnect), or None without PyBullet."""
    arm = _pybullet_arm(path)
    if arm is None:
        return None
    p, cid, rid, ids = arm
    tau = torques(len(ids))

    def step():     # a torque command holds for one step in PyBullet: set it every step
        p.setJointMotorControlArray(rid, ids, p.TORQUE_CONTROL, forces=tau, physicsClientId=cid)
        p.stepSimulation(physicsClientId=cid)
    return step, (lambda: p.disconnect(cid))


def _pybullet_arm(path):
    """(pybullet, client, robot, joint ids): the URDF on a fixed base, gravity, dt DT, the
    default velocity motors off (so torques act alone); None without PyBullet."""
    try:
        import pybullet as p
    except ImportError:
        return None
    cid = p.connect(p.DIRECT)
    p.setGravity(0, 0, -9.81, physicsClientId=cid)
    p.setTimeStep(DT, physicsClientId=cid)
    rid = p.loadURDF(path, useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE,
                     physicsClientId=cid)
    ids = list(range(p.getNumJoints(rid, physicsClientId=cid)))
    p.setJointMotorControlArray(rid, ids, p.VELOCITY_CONTROL, forces=[0.0] * len(ids),
                                physicsClientId=cid)
    return p, cid, rid, ids


#: the controller loop's PD law, the same in every engine: τ = KP (AIM − θ) − KD θ̇ (gains with
#: which MuJoCo's explicit Euler stays stable on the arm and ours takes 1.00 Newton iteration)
KP, KD, AIM = 10.0, 0.1, 0.3


def ours_controller(path):
    """One step of a Python controller at 1 kHz: read the joint angles and velocities, a PD
    torque on every joint, set them, step (World.set_torques and World.step())."""
    from abd_joint_sim import Scene, World
    world = World(Scene.from_urdf(path, dt=DT))
    act = np.array([world.joint_names.index(j) for j in world.actuated_joint_names])

    def step():
        world.set_torques(KP * (AIM - world.joint_angles()[act]) - KD * world.joint_velocities()[act])
        world.step()
    return step


def mujoco_controller(path):
    """The same loop in MuJoCo (qpos, qvel, qfrc_applied, mj_step), or None without it."""
    arm = _mujoco_arm(path)
    if arm is None:
        return None
    mj, m, d = arm

    def step():
        d.qfrc_applied[:] = KP * (AIM - d.qpos) - KD * d.qvel
        mj.mj_step(m, d)
    return step


def pybullet_controller(path):
    """The same loop in PyBullet (getJointStates, TORQUE_CONTROL, stepSimulation): (step,
    disconnect), or None without it."""
    arm = _pybullet_arm(path)
    if arm is None:
        return None
    p, cid, rid, ids = arm

    def step():
        states = p.getJointStates(rid, ids, physicsClientId=cid)
        q = np.array([s[0] for s in states])
        v = np.array([s[1] for s in states])
        p.setJointMotorControlArray(rid, ids, p.TORQUE_CONTROL, forces=KP * (AIM - q) - KD * v,
                                    physicsClientId=cid)
        p.stepSimulation(physicsClientId=cid)
    return step, (lambda: p.disconnect(cid))


def run(quick=False, peers=True):
    """Print the robot's row; returns its figures (a dict: path; s/step of ours `one` step
    per call and `n` per call, MuJoCo's `mj_one` and `mj_n`, PyBullet's `pb_one`; the PD
    controller's `pd`, `mj_pd`, `pb_pd`; a peer's is None where it did not run), or None
    without the file. The
    engines take turns round after round (a burst of load on this shared machine then falls
    on all of them); each engine's own rounds follow its own simulated time: ours
    5 × 500 one-step calls, then 5 calls of 500 steps."""
    path = robot_path()
    if path is None:
        print('URDF robot: skipped (pybullet_data not installed: requirements-bench.txt)')
        return None
    steps, repeats = (100, 3) if quick else (500, 5)
    step, step_n, its = ours(path)
    mj = mujoco(path) if peers else None
    pb = pybullet(path) if peers else None
    single = {'ours': [], 'mujoco': [], 'pybullet': []}
    many = {'ours': [], 'mujoco': []}
    loop = {'ours': [], 'mujoco': [], 'pybullet': []}
    ctl = ours_controller(path)
    mj_ctl = mujoco_controller(path) if peers else None
    pb_ctl = pybullet_controller(path) if peers else None
    try:
        for _ in range(repeats):
            single['ours'].append(_time(step, steps, 1))
            if mj:
                single['mujoco'].append(_time(mj[0], 5 * steps, 1))
            if pb:
                single['pybullet'].append(_time(pb[0], 5 * steps, 1))
        for _ in range(repeats):
            many['ours'].append(_time(lambda: step_n(steps), 1, 1) / steps)
            if mj:
                many['mujoco'].append(_time(lambda: mj[1](5 * steps), 1, 1) / (5 * steps))
        for _ in range(repeats):
            loop['ours'].append(_time(ctl, steps, 1))
            if mj_ctl:
                loop['mujoco'].append(_time(mj_ctl, 5 * steps, 1))
            if pb_ctl:
                loop['pybullet'].append(_time(pb_ctl[0], 5 * steps, 1))
    finally:
        for peer_ in (pb, pb_ctl):
            if peer_:
                peer_[1]()
    t, t_n = statistics.median(single['ours']), statistics.median(many['ours'])
    mj_t = statistics.median(single['mujoco']) if mj else None
    mj_n = statistics.median(many['mujoco']) if mj else None
    pb_t = statistics.median(single['pybullet']) if pb else None

    def peer(x):
        return ('–', '–') if x is None else (f'{x * 1e6:.1f}', f'{t / x:.1f}')
    print('\nURDF robot (pybullet_data/kuka_iiwa/model.urdf, 7 joints, dt 1 ms, gravity, torque on '
          'every joint, each engine loading the same file):')
    print('| robot | µs/step median | RTF at dt | Newton it/step | MuJoCo µs/step | '
          'ours/MuJoCo | PyBullet µs/step | ours/PyBullet |')
    print('|' + '---|' * 8)
    print(f'| KUKA iiwa | {t * 1e6:.0f} | {DT / t:.1f} | {float(np.mean(its)):.2f} | {peer(mj_t)[0]} | '
          f'{peer(mj_t)[1]} | {peer(pb_t)[0]} | {peer(pb_t)[1]} |')
    if mj_n:
        print(f'n steps per call on both sides: ours World.step(n) {t_n * 1e6:.1f} µs/step, MuJoCo '
              f'mj_step(m, d, n) {mj_n * 1e6:.1f} µs/step: ours/MuJoCo {t_n / mj_n:.1f}')
    c = statistics.median(loop['ours'])
    line = (f'a Python PD controller on every joint (read θ, θ̇; set the torques; one step): ours '
            f'{c * 1e6:.1f} µs/step')
    pd = {}
    for name, key in (('MuJoCo', 'mujoco'), ('PyBullet', 'pybullet')):
        pd[key] = statistics.median(loop[key]) if loop[key] else None
        if pd[key]:
            line += f', {name} {pd[key] * 1e6:.1f}: ours/{name} {c / pd[key]:.1f}'
    print(line)
    return dict(path=path, one=t, n=t_n, mj_one=mj_t, mj_n=mj_n, pb_one=pb_t, pd=c,
                mj_pd=pd['mujoco'], pb_pd=pd['pybullet'])


#: robots of pybullet_data that Scene.from_urdf loads (revolute and continuous joints; the
#: others held rigid by ROBOT_OPTIONS)
ROBOTS = ('kuka_iiwa/model.urdf', 'xarm/xarm6_robot.urdf', 'pendulum5.urdf', 'a1/a1.urdf',
          'laikago/laikago.urdf', 'quadruped/minitaur.urdf', 'mini_cheetah/mini_cheetah.urdf',
          'franka_panda/panda.urdf')
#: Scene.from_urdf options per robot: the Panda's two prismatic finger joints held rigid
#: (MuJoCo, which would keep them, refuses its package:// meshes anyway)
ROBOT_OPTIONS = {'franka_panda/panda.urdf': {'lock': ['panda_finger_joint1',
                                                      'panda_finger_joint2']}}


def mujoco_model(path, lock=(), repair=False):
    """MuJoCo's model of the URDF at `path`, its joints in `lock` fixed as ours holds them.
    Where MuJoCo cannot open the meshes (`package://` paths it does not resolve), the same
    file without its <visual> and <collision> elements: with contacts off the geometry plays
    no part in the dynamics, which the <inertial> elements give. With `repair`, an inertia
    MuJoCo's compiler rejects (a principal moment above the sum of the other two, a
    massless moving body) is repaired by its own options (`balanceinertia`, `boundmass`,
    `boundinertia`, given in the URDF's <mujoco> extension) instead of refused: the model
    then has the file's structure but not quite its inertias, good for timing only. Returns
    (model, what was changed: '' or a note)."""
    import xml.etree.ElementTree as ET
    import mujoco as mj
    text = open(path).read()
    root = ET.fromstring(text)
    for joint in root.iter('joint'):
        if joint.get('name') in lock:
            joint.set('type', 'fixed')
    notes = []
    if repair:
        ext = ET.SubElement(root, 'mujoco')
        ET.SubElement(ext, 'compiler', balanceinertia='true', boundmass='1e-6', boundinertia='1e-9')
        notes.append('inertias repaired by MuJoCo')
    if lock or repair:
        text = ET.tostring(root, encoding='unicode')
    try:
        model = mj.MjModel.from_xml_string(text) if lock or repair else mj.MjModel.from_xml_path(path)
        return model, ', '.join(notes)
    except ValueError as exc:
        if 'package:' not in str(exc) and 'opening file' not in str(exc):
            raise
    for link in root.iter('link'):
        for geometry in link.findall('visual') + link.findall('collision'):
            link.remove(geometry)
    return mj.MjModel.from_xml_string(ET.tostring(root, encoding='unicode')), ', '.join(
        notes + ['without its meshes'])


def ours_robot_steps(world, steps, scale=1.0):
    """(Newton iterations per step over 200 one-step calls, s per step in one call of `steps`)
    of a loaded robot World under `scale` × `torques` on every actuated joint, after 3 steps;
    CPU time."""
    names = world.actuated_joint_names
    for joint, tau in zip(names, torques(len(names), scale)):
        world.set_torque(joint, tau)
    world.step(3)
    its = sum(world.step().newton_iterations for _ in range(200)) / 200
    t0 = time.process_time()
    world.step(steps)
    return its, (time.process_time() - t0) / steps


def mujoco_robot_steps(path, steps, lock=(), scale=1.0):
    """(s per step or None, note, why not) of MuJoCo on the URDF at `path` under `scale` ×
    `torques`, contacts off, in one mj_step(m, d, steps) after 3 steps; CPU time. `note` says what
    mujoco_model changed and whether MuJoCo's integration diverged (it then resets its state);
    `why` is MuJoCo's refusal, '' if it ran or is not installed."""
    try:
        import mujoco as mj
    except ImportError:
        return None, '', ''
    try:
        try:
            m, note = mujoco_model(path, lock)
        except ValueError as exc:           # an inertia MuJoCo's compiler rejects
            if 'inertia' not in str(exc) and 'mass' not in str(exc):
                raise
            m, note = mujoco_model(path, lock, repair=True)
        m.opt.timestep = DT
        m.opt.disableflags |= mj.mjtDisableBit.mjDSBL_CONTACT
        d = mj.MjData(m)
        d.qfrc_applied[:] = torques(m.nv, scale)
        mj.mj_step(m, d, 3)
        t0 = time.process_time()
        mj.mj_step(m, d, steps)
        t = (time.process_time() - t0) / steps
        resets = d.warning[mj.mjtWarning.mjWARN_BADQACC].number
        if resets:          # its explicit integration diverged: it reset the state
            note = ', '.join(filter(None, [note, f'unstable: MuJoCo reset its state '
                                                 f'{resets}× in {steps + 3} steps']))
        return t, note, ''
    except Exception as exc:                     # noqa: BLE001 (a peer's refusal)
        return None, '', str(exc).splitlines()[0][:60]


def robots(quick=False, peers=True):
    """One row per robot of ROBOTS: bodies, Newton iterations per step (mean of 200 single
    steps), ours World.step(n) and MuJoCo mj_step(m, d, n) µs/step and their ratio (MuJoCo
    '–' where its URDF import refuses the file: package:// mesh paths, inertias it rejects).
    Torques as `torques`; CPU time of this process. Returns the rows as dicts (name, bodies,
    its, ours and mujoco s/step, mj_cell: MuJoCo's cell as printed)."""
    import warnings
    try:
        import pybullet_data
    except ImportError:
        print('robots: skipped (pybullet_data not installed: requirements-bench.txt)')
        return []
    from abd_joint_sim import Scene, World
    steps = 300 if quick else 2000
    print(f'\nRobots of pybullet_data (dt 1 ms, gravity, torque on every joint, fixed base, '
          f'{steps} steps in one call on both sides, CPU time):')
    print('| robot | bodies | Newton it/step | ours µs/step | MuJoCo µs/step | ours/MuJoCo |')
    print('|' + '---|' * 6)
    rows = []
    for name in ROBOTS:
        path = os.path.join(pybullet_data.getDataPath(), name)
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')             # the importer's repairs (docs/urdf.md)
            world = World(Scene.from_urdf(path, dt=DT, **ROBOT_OPTIONS.get(name, {})))
        its, ours_t = ours_robot_steps(world, steps)
        mj_t, why, note = None, '', ''
        if peers:
            mj_t, note, why = mujoco_robot_steps(path, steps, ROBOT_OPTIONS.get(name, {}).get('lock', ()))
        ratio = f'{ours_t / mj_t:.1f}' if mj_t else '–'
        mj_cell = f'{mj_t * 1e6:.1f}' if mj_t else f'– ({why})' if why else '–'
        if mj_t and note:
            mj_cell += f' ({note})'
        print(f'| {name} | {world.model.body_count} | {its:.2f} | {ours_t * 1e6:.1f} | '
              f'{mj_cell} | {ratio} |', flush=True)
        rows.append(dict(name=name, bodies=world.model.body_count, its=its, ours=ours_t, mujoco=mj_t,
                         mj_cell=mj_cell))
    return rows


def main(argv=None) -> int:
    import argparse
    import sys
    from pathlib import Path
    ap = argparse.ArgumentParser(prog='bench/peers.py robots', description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer steps and robots')
    args = ap.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))     # this checkout's package
    run(args.quick)
    robots(args.quick)
    return 0
