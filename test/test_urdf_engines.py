"""The URDF import checked against PyBullet (an engine nobody here wrote) on robot files
shipped in the pybullet wheel (`pybullet_data`, never copied into this repository).

From rest, gravity plus a torque on every joint, PyBullet's motors off, the joints'
`<dynamics damping>` applied by both engines (the KUKA iiwa has 0.5 N m s/rad on every joint,
pendulum5 1.0), no link damping, inertia from the file; after 40 ms the joint velocities and angle changes must agree within 1 %
(relative, norm over the joints). PyBullet runs at dt = 1e-4 (semi-implicit Euler: its own
angle error is ~h/T = 0.25 %), ours at 5e-4 with BDF2. Figures per robot: docs/urdf.md
"Checked against PyBullet and MuJoCo"; the script at the bottom of docs/urdf.md reproduces them.
"""
import os
import sys

import numpy as np
import pytest

from abd_joint_sim import Scene, World

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'bench', 'lib'))

pybullet = pytest.importorskip('pybullet', reason='pybullet not installed (requirements-test.txt)')
pybullet_data = pytest.importorskip('pybullet_data', reason='pybullet_data not installed')

T_END = 0.04


def torques_for(n):
    return [((-1) ** k) * (2.0 - 0.2 * k) for k in range(n)]


def run_pybullet(path, names, torques, q0, dt=1e-4):
    p = pybullet
    cid = p.connect(p.DIRECT)
    try:
        p.setGravity(0, 0, -9.81, physicsClientId=cid)
        p.setTimeStep(dt, physicsClientId=cid)
        rid = p.loadURDF(path, useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE,
                         physicsClientId=cid)
        index = {}
        for k in range(p.getNumJoints(rid, physicsClientId=cid)):
            index[p.getJointInfo(rid, k, physicsClientId=cid)[1].decode()] = k
            p.changeDynamics(rid, k, linearDamping=0, angularDamping=0, physicsClientId=cid)
        p.changeDynamics(rid, -1, linearDamping=0, angularDamping=0, physicsClientId=cid)
        ids = [index[n] for n in names]
        for n, k in zip(names, ids):
            p.resetJointState(rid, k, q0.get(n, 0.0), 0.0, physicsClientId=cid)
        p.setJointMotorControlArray(rid, ids, p.VELOCITY_CONTROL, forces=[0.0] * len(ids),
                                    physicsClientId=cid)
        for _ in range(int(round(T_END / dt))):
            p.setJointMotorControlArray(rid, ids, p.TORQUE_CONTROL, forces=list(torques),
                                        physicsClientId=cid)
            p.stepSimulation(physicsClientId=cid)
        states = p.getJointStates(rid, ids, physicsClientId=cid)
    finally:
        p.disconnect(cid)
    return np.array([s[0] for s in states]), np.array([s[1] for s in states])


def run_ours(path, q0, dt=5e-4, **options):
    """(world after T_END, joint names, torques): our run of the comparisons, BDF2."""
    import warnings
    from abd_joint_sim.urdf import UrdfWarning
    with warnings.catch_warnings():
        # pendulum5's <dynamics friction> is not simulated and said once (test_urdf.py
        # asserts that warning); here it would only repeat
        warnings.filterwarnings('ignore', '.*<dynamics friction> is not simulated', UrdfWarning)
        scene = Scene.from_urdf(path, dt=dt, integrator='bdf2', initial_positions=q0, **options)
    world = World(scene)
    names = list(scene.joint_names)
    assert np.allclose(world.joint_angles(), [q0.get(n, 0.0) for n in names], atol=1e-12)
    torques = torques_for(len(names))       # N m on a revolute joint, N on a prismatic one
    for n, tau in zip(names, torques):
        world.set_effort(n, tau)
    world.step(int(round(T_END / dt)))
    return world, names, torques


def compare(rel_path, q0, dt=5e-4, **options):
    path = os.path.join(pybullet_data.getDataPath(), rel_path)
    world, names, torques = run_ours(path, q0, dt, **options)
    q_ref, v_ref = run_pybullet(path, names, torques, q0)
    start = np.array([q0.get(n, 0.0) for n in names])
    dv = np.linalg.norm(world.joint_velocities() - v_ref) / np.linalg.norm(v_ref)
    dq = np.linalg.norm(world.joint_angles() - q_ref) / np.linalg.norm(q_ref - start)
    return names, dv, dq


@pytest.mark.parametrize('rel_path, q0', [
    ('kuka_iiwa/model.urdf', {}),
    ('kuka_iiwa/model.urdf', {'lbr_iiwa_joint_2': 0.5, 'lbr_iiwa_joint_4': -1.0,
                              'lbr_iiwa_joint_6': 0.8}),
    ('pendulum5.urdf', {}),
])
@pytest.mark.slow
def test_joint_motion_agrees_with_pybullet(rel_path, q0):
    names, dv, dq = compare(rel_path, q0)
    print(f'{rel_path} q0={q0}: velocity {dv:.2e}, angle {dq:.2e} (relative)')
    assert len(names) >= 5
    assert dv < 0.01 and dq < 0.01


def test_cartpole_cart_force_and_pole_torque_agree_with_pybullet():
    """pybullet_data's cartpole: a prismatic cart (2 N along its rail) and a continuous pole
    (−1.8 N m): joint velocities and position changes after 40 ms within 1 %."""
    names, dv, dq = compare('cartpole.urdf', {})
    print(f'cartpole.urdf: velocity {dv:.2e}, position {dq:.2e} (relative)')
    assert names == ['slider_to_cart', 'cart_to_pole']
    assert dv < 0.01 and dq < 0.01


def test_a_flipped_torque_sign_is_caught():
    """The comparison can fail: the same run with every torque negated on our side only."""
    path = os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa/model.urdf')
    scene = Scene.from_urdf(path, dt=5e-4, integrator='bdf2')
    world = World(scene)
    torques = torques_for(len(scene.joint_names))
    for n, tau in zip(scene.joint_names, torques):
        world.set_torque(n, -tau)
    world.step(int(round(T_END / 5e-4)))
    _, v_ref = run_pybullet(path, list(scene.joint_names), torques, {})
    assert np.linalg.norm(world.joint_velocities() - v_ref) / np.linalg.norm(v_ref) > 0.1


def run_mujoco(path, names, torques, q0, dt=1e-4, lock=()):
    """MuJoCo's own URDF import, RK4 at 1e-4, with the file's <dynamics> damping; friction
    loss, armature and contacts switched off (we simulate none of them); the joints in `lock`
    made fixed, and a file whose `package://` meshes MuJoCo cannot open loaded without its
    geometry (bench/lib/robot_bench.py `mujoco_model`: with contacts off it plays no part)."""
    mujoco = pytest.importorskip('mujoco', reason='mujoco not installed (requirements-test.txt)')
    from robot_bench import mujoco_model
    m = mujoco_model(path, lock)[0]
    m.opt.timestep = dt
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    m.dof_frictionloss[:] = 0.0
    m.dof_armature[:] = 0.0
    d = mujoco.MjData(m)
    adr = {m.joint(i).name: (m.jnt_qposadr[i], m.jnt_dofadr[i]) for i in range(m.njnt)}
    for n, tau in zip(names, torques):
        d.qpos[adr[n][0]] = q0.get(n, 0.0)
        d.qfrc_applied[adr[n][1]] = tau
    for _ in range(int(round(T_END / dt))):
        mujoco.mj_step(m, d)
    return (np.array([d.qpos[adr[n][0]] for n in names]),
            np.array([d.qvel[adr[n][1]] for n in names]))


@pytest.mark.parametrize('rel_path, q0, lock', [
    ('kuka_iiwa/model.urdf', {'lbr_iiwa_joint_2': 0.5, 'lbr_iiwa_joint_4': -1.0}, []),
    ('pendulum5.urdf', {}, []),
    # fingers held rigid on both sides; a pose inside joints 4 and 6's limits (0 is outside
    # joint 4's [-3.07, -0.07], where the two engines' limits push differently)
    ('franka_panda/panda.urdf', {'panda_joint4': -1.5, 'panda_joint6': 1.5},
     ['panda_finger_joint1', 'panda_finger_joint2']),
    # a sliding finger (the other mimics it: held rigid), from inside its [0, 0.04] m range
    ('franka_panda/panda.urdf', {'panda_joint4': -1.5, 'panda_joint6': 1.5, 'panda_finger_joint1': 0.02},
     ['panda_finger_joint2']),
    ('cartpole.urdf', {}, []),                  # a prismatic cart (N) and a continuous pole (N m)
])
def test_joint_motion_agrees_with_mujoco(rel_path, q0, lock):
    """The same runs against MuJoCo loading the same file (a second engine; MuJoCo RK4 and
    PyBullet agree with each other to ~1e-6 on the KUKA without damping, 6e-4 with it)."""
    path = os.path.join(pybullet_data.getDataPath(), rel_path)
    world, names, torques = run_ours(path, q0, lock=lock)
    q_ref, v_ref = run_mujoco(path, names, torques, q0, lock=lock)
    start = np.array([q0.get(n, 0.0) for n in names])
    dv = np.linalg.norm(world.joint_velocities() - v_ref) / np.linalg.norm(v_ref)
    dq = np.linalg.norm(world.joint_angles() - q_ref) / np.linalg.norm(q_ref - start)
    print(f'{rel_path} vs MuJoCo: velocity {dv:.2e}, angle {dq:.2e} (relative)')
    assert dv < 0.01 and dq < 0.01


def test_leaving_out_the_files_joint_damping_is_caught():
    """pendulum5's joints carry <dynamics damping="1.0">, which both engines apply and the
    comparisons above match to ~3e-5: the same run with the damping dropped on our side only
    (`damping=False`) leaves MuJoCo by far more than their 1 %."""
    path = os.path.join(pybullet_data.getDataPath(), 'pendulum5.urdf')
    world, names, torques = run_ours(path, {}, damping=False)
    _, v_ref = run_mujoco(path, names, torques, {})
    assert np.linalg.norm(world.joint_velocities() - v_ref) / np.linalg.norm(v_ref) > 0.1


def test_robot_study_reduced(tmp_path):
    """study/urdf_robot.py --quick: against MuJoCo RK4 at 1e-5, BDF2's lag behind the rigid
    KUKA shrinks about 4x per halving of dt (second order), and a softer κ lags more."""
    pytest.importorskip('mujoco', reason='mujoco not installed (requirements-test.txt)')
    import sys
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                    'study'))
    import urdf_robot
    rows = urdf_robot.main(['--quick', '--out', str(tmp_path / 'r')])
    bdf2 = {r['dt']: r['error'] for r in rows if r['engine'] == 'ours bdf2' and r['kappa'] == 1e8}
    ratios = [bdf2[2e-3] / bdf2[1e-3], bdf2[1e-3] / bdf2[5e-4]]
    assert all(3.0 < q < 5.5 for q in ratios), (bdf2, ratios)
    soft = [r['error'] for r in rows if r['engine'] == 'ours bdf2' and r['kappa'] == 1e6]
    assert soft and soft[0] > 1.5 * bdf2[5e-4]
    assert (tmp_path / 'r.md').read_text().count('| ours') == len(
        [r for r in rows if r['engine'].startswith('ours')])


@pytest.mark.parametrize('rel_path, lock, joints, warned', [
    ('xarm/xarm6_robot.urdf', [], 6, ['link2', 'link3']),         # inertias breaking the triangle inequality
    ('franka_panda/panda.urdf', ['panda_finger_joint1', 'panda_finger_joint2'], 7, []),  # mass="0" link, prismatic fingers
    ('laikago/laikago.urdf', [], 12, None),                        # quadruped, mesh visuals
    ('TwoJointRobot_w_fixedJoints.urdf', [], 2, ['link_1', 'link_2']),
    ('a1/a1.urdf', [], 12, None),                                 # knees: 0 outside the limits
    ('quadruped/spirit40.urdf', [], 12, []),                      # `${...}` in comments only
])
def test_real_files_load_with_warnings_not_errors(rel_path, lock, joints, warned):
    import warnings
    from abd_joint_sim.urdf import UrdfWarning
    path = os.path.join(pybullet_data.getDataPath(), rel_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        scene = Scene.from_urdf(path, lock=lock)
    msgs = [str(w.message) for w in caught if issubclass(w.category, UrdfWarning)]
    assert len(scene.joint_names) == joints and len(msgs) == len(scene.warnings)
    friction = [m for m in msgs if '<dynamics friction> is not simulated' in m]
    speed = [m for m in msgs if '<limit velocity> is not enforced' in m]
    assert len(speed) <= 1                          # said once per robot, if at all
    msgs = [m for m in msgs if m not in friction and m not in speed]
    if warned is not None:
        assert [m.split("link '")[1].split("'")[0] for m in msgs] == warned
    if rel_path.startswith('xarm/'):                # friction="1.0" on its six joints: one line
        assert len(friction) == 1 and 'ignored on 6 joint(s): joint1, joint2' in friction[0]
    else:
        assert friction == []
    if rel_path.startswith('a1/'):
        assert len(msgs) == 4 and all('position 0 is outside its limit' in m for m in msgs)
    World(scene).step(3)


# What a refusal of a pybullet_data file may say (docs/urdf.md "Every URDF of pybullet_data"):
# a joint type this simulator lacks, a mimic joint (the Panda's second finger), a number ROS's urdfdom refuses too, an unexpanded
# substitution, a robot without links. Anything else would be a new refusal to look at.
REFUSALS = (r'cannot be simulated \(only revolute, continuous and prismatic', r"is (spherical|planar|floating): only "
            r'revolute, continuous and prismatic joints are simulated; `lock: \[',
            r'mimics joint .*: mimic joints are not simulated; `lock: \[', r"is not \d number\(s\)$",
            r'must be 3 finite number\(s\)$', r'unexpanded xacro/launch substitution', r'no <link> in the robot$')


@pytest.mark.slow
def test_every_urdf_of_pybullet_data_loads_or_is_one_clear_refusal():
    """All ~1100 URDFs of the wheel: each loads or raises one SceneError line naming the file
    and a known reason (never another exception), and the robots with joints that load are
    at least the 31 of pybullet 3.2.7; a few of them take steps."""
    import glob
    import re
    import warnings
    from abd_joint_sim.errors import SceneError
    root = pybullet_data.getDataPath()
    loaded, refused = [], []
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        for path in sorted(glob.glob(os.path.join(root, '**', '*.urdf'), recursive=True)):
            try:
                scene = Scene.from_urdf(path)
            except SceneError as err:
                msg = str(err)
                assert msg.startswith(path + ': ') and '\n' not in msg, msg
                assert any(re.search(r, msg) for r in REFUSALS), msg
                refused.append(os.path.relpath(path, root))
                continue
            if scene.joints:
                loaded.append((os.path.relpath(path, root), scene))
    assert len(loaded) >= 31, [p for p, _ in loaded]
    assert 'differential/diff_ring.urdf' in dict(loaded)      # white space before <?xml
    assert len(refused) <= 14, refused
    for rel in ('pendulum5.urdf', 'differential/diff_ring.urdf', 'quadruped/minitaur.urdf'):
        world = World(dict(loaded)[rel])
        world.step(20)
        assert np.all(np.isfinite(world.joint_angles()))


def test_panda_loads_with_its_sliding_finger():
    """The Panda's prismatic finger loads and moves under a force; its second finger mimics
    the first (mimic joints are not simulated: one clear error, `lock` holds it); locking both
    merges them into the hand."""
    import warnings
    from abd_joint_sim.errors import SceneError
    path = os.path.join(pybullet_data.getDataPath(), 'franka_panda/panda.urdf')
    fingers = ['panda_finger_joint1', 'panda_finger_joint2']
    with pytest.raises(SceneError, match=r"joint 'panda_finger_joint2' \(prismatic\) mimics joint "
                       r"'panda_finger_joint1'.*`lock: \[panda_finger_joint2\]`"):
        Scene.from_urdf(path)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        scene = Scene.from_urdf(path, lock=fingers[1:])
    assert len(scene.joint_names) == 8 and scene.joints[-1].name == fingers[0]
    assert scene.joints[-1].type == 'prismatic'
    world = World(scene)
    start = world.joint_positions()[-1]
    world.set_effort(fingers[0], 5.0)
    world.step(20)
    assert world.joint_positions()[-1] > start and np.all(np.isfinite(world.joint_positions()))
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        assert len(Scene.from_urdf(path, lock=fingers).joint_names) == 7


@pytest.mark.parametrize('rel_path', ['a1/a1.urdf', 'aliengo/aliengo.urdf',
                                      'quadruped/spirit40.urdf', 'racecar/racecar.urdf'])
def test_more_robots_from_mid_range_poses_agree_with_pybullet(rel_path, monkeypatch):
    """Quadrupeds (fixed trunk) and a car from every limited joint's mid-range (the engines'
    joint limits are different models: at a bound they differ by design), 0.5 N m torques.
    a1 and aliengo have knees whose position 0 is outside their limits (loaded with a
    warning; here the pose is set explicitly)."""
    import warnings
    from abd_joint_sim.urdf import UrdfWarning
    path = os.path.join(pybullet_data.getDataPath(), rel_path)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', UrdfWarning)
        scene = Scene.from_urdf(path)
    q0 = {j.name: 0.5 * (j.limit.lower + j.limit.upper) for j in scene.joints if j.limit}
    monkeypatch.setattr(sys.modules[__name__], 'torques_for',
                        lambda n: [((-1) ** k) * 0.5 for k in range(n)])
    names, dv, dq = compare(rel_path, q0)
    print(f'{rel_path} (mid-range pose): velocity {dv:.2e}, angle {dq:.2e} (relative)')
    assert dv < 0.01 and dq < 0.01
