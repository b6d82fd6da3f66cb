"""URDF import (abd_joint_sim/urdf.py, Scene.from_urdf, the robot: block): mapping rules
checked against hand-computed values, real-world quirks, and errors."""
import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from abd_joint_sim import Scene, World
from abd_joint_sim.errors import SceneError
from abd_joint_sim.geometry import axis_rotation, matrix_rpy, rpy_matrix
from abd_joint_sim.scene import load_yaml
from abd_joint_sim.urdf import UrdfWarning

HERE = os.path.dirname(os.path.abspath(__file__))
DEMO = os.path.join(os.path.dirname(HERE), 'abd_joint_sim', 'robots', 'demo_arm.urdf')


def inertial(mass, xyz='0 0 0', rpy='0 0 0', ixx=0.01, iyy=0.01, izz=0.01, ixy=0.0):
    return (f'<inertial><origin xyz="{xyz}" rpy="{rpy}"/><mass value="{mass}"/>'
            f'<inertia ixx="{ixx}" ixy="{ixy}" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial>')


def robot(*parts, name='r'):
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n' + '\n'.join(parts) + '\n</robot>\n'


def link(name, body=''):
    return f'<link name="{name}">{body}</link>'


def joint(name, jtype, parent, child, xyz='0 0 0', rpy='0 0 0', axis='0 0 1', extra=''):
    return (f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="{axis}"/>{extra}</joint>')


SPEED_LIMITS = '<limit velocity> is not enforced'


def _from_urdf_warned(text, speed_limits=False, **options):
    """(Scene.from_urdf(text, **options), the UrdfWarning messages it gave; the one about
    ignored speed limits, which nearly every robot gives, only with speed_limits=True)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        scene = Scene.from_urdf(text, **options)
    return scene, [str(w.message) for w in caught if issubclass(w.category, UrdfWarning)
                   and (speed_limits or SPEED_LIMITS not in str(w.message))]


ARM = robot(
    '<material name="blue"><color rgba="0 0 1 1"/></material>',
    link('base', inertial(5.0)),
    link('upper', inertial(2.0, xyz='0.25 0 0', ixx=0.01, iyy=0.05, izz=0.05)
         + '<visual><origin xyz="0.25 0 0" rpy="0 1.5707963267948966 0"/><geometry>'
           '<cylinder radius="0.05" length="0.5"/></geometry><material name="blue"/></visual>'),
    link('tool', inertial(0.5, xyz='0 0 0.05', ixx=0.002, iyy=0.002, izz=0.001)
         + '<visual><geometry><mesh filename="package://my_robot/meshes/tool.stl" '
           'scale="0.001 0.001 0.001"/></geometry></visual>'),
    joint('shoulder', 'revolute', 'base', 'upper', xyz='0 0 0.3', axis='0 1 0',
          extra='<limit lower="-1.5" upper="1.5" effort="40" velocity="2"/>'),
    joint('tool_mount', 'fixed', 'upper', 'tool', xyz='0.5 0 0', rpy='0 0 1.5707963267948966'),
    # ROS 1 / Gazebo / ros2_control extras the simulation ignores
    '<transmission name="t1"><type>transmission_interface/SimpleTransmission</type>'
    '<joint name="shoulder"><hardwareInterface>EffortJointInterface</hardwareInterface></joint>'
    '<actuator name="m1"><mechanicalReduction>1</mechanicalReduction></actuator></transmission>',
    '<gazebo reference="upper"><material>Gazebo/Blue</material></gazebo>',
    '<ros2_control name="sys" type="system"><hardware><plugin>x/Y</plugin></hardware>'
    '<joint name="shoulder"><command_interface name="effort"/></joint></ros2_control>')


def test_mapping_fixed_merge_limits_effort_visuals():
    scene = Scene.from_urdf(ARM, dt=1e-3, gravity=[0, 0, 0])
    assert scene.body_names == ('base', 'upper')          # tool merged into upper
    assert scene.joint_names == ('shoulder',)
    assert scene.gravity == (0.0, 0.0, 0.0) and scene.dt == 1e-3
    base, upper = scene.bodies
    assert base.fixed and not upper.fixed
    # Lumped: mass sum, COM the mass-weighted mean, inertia by the parallel-axis theorem.
    s = upper.shape
    assert s.mass == pytest.approx(2.5)
    c_tool = np.array([0.5, 0, 0.05])
    c = (2.0 * np.array([0.25, 0, 0]) + 0.5 * c_tool) / 2.5
    assert np.allclose(s.com, c)
    Rz = rpy_matrix([0, 0, math.pi / 2])
    I_tool = Rz @ np.diag([0.002, 0.002, 0.001]) @ Rz.T
    expect = np.zeros((3, 3))
    for m, ck, Ik in ((2.0, np.array([0.25, 0, 0]), np.diag([0.01, 0.05, 0.05])),
                      (0.5, c_tool, I_tool)):
        d = ck - c
        expect += Ik + m * (d @ d * np.eye(3) - np.outer(d, d))
    assert np.allclose(np.array(s.inertia).reshape(3, 3), expect, atol=1e-12)
    j = scene.joints[0]
    assert j.p0 == pytest.approx((0, 0, 0.3)) and j.p1 == pytest.approx((0, 1, 0.3))
    assert j.limit.lower == -1.5 and j.limit.upper == 1.5
    assert j.external_torque.effort_limit == 40.0 and j.external_torque.enabled
    # Visuals: the cylinder keeps its link-frame pose and named material; the merged tool's
    # mesh moves into upper's frame with the fixed joint's pose.
    cyl, mesh = upper.visuals
    assert cyl.kind == 'cylinder' and cyl.size == (0.05, 0.5) and cyl.rgba == (0, 0, 1, 1)
    assert cyl.origin_xyz == pytest.approx((0.25, 0, 0))
    assert mesh.kind == 'mesh' and mesh.mesh_uri == 'package://my_robot/meshes/tool.stl'
    assert mesh.size == (0.001, 0.001, 0.001) and mesh.rgba is None
    assert mesh.origin_xyz == pytest.approx((0.5, 0, 0))
    assert np.allclose(rpy_matrix(mesh.origin_rpy), Rz)


def test_limits_switch_and_overrides():
    scene = Scene.from_urdf(ARM, limits=False, strength_ratio=50.0, kappa=1e9,
                            joints={'shoulder': {'driving': {'strength_ratio': 20.0},
                                                 'external_torque': {'effort_limit': 5.0}}})
    j = scene.joints[0]
    assert j.limit is None and j.strength_ratio == 50.0
    assert j.driving.strength_ratio == 20.0 and j.driving.aim_angle == 0.0
    assert j.external_torque.effort_limit == 5.0
    assert all(b.kappa == 1e9 for b in scene.bodies)
    scene = Scene.from_urdf(ARM, actuated=[], joints={'shoulder': {'limit': {'lower': -0.5,
                                                                              'upper': 0.5}}})
    assert scene.joints[0].external_torque is None and scene.joints[0].limit.upper == 0.5


@pytest.mark.slow
def test_sign_and_inertia_against_the_analytic_rotation():
    """+τ about the URDF axis turns the link by +τ t²/(2 I_axis) (no gravity): the reported
    angle and velocity follow the URDF joint position's sign."""
    scene = Scene.from_urdf(ARM, dt=1e-4, gravity=[0, 0, 0], limits=False)
    I_axis = (np.array(scene.bodies[1].shape.inertia).reshape(3, 3)[1, 1]
              + 2.5 * (scene.bodies[1].shape.com[0] ** 2 + scene.bodies[1].shape.com[2] ** 2))
    world = World(scene)
    p, A = world.body_pose('upper')
    com0 = A @ np.array(scene.bodies[1].shape.com) + p
    world.set_torque('shoulder', 0.5)
    world.step(100)
    t = world.time
    assert world.joint_velocities()[0] == pytest.approx(0.5 * t / I_axis, rel=2e-3)
    assert world.joint_angles()[0] == pytest.approx(0.5 * t * t / (2 * I_axis), rel=2e-2)
    # and the child really turned right-handedly about +y, which moves +x toward -z.
    p, A = world.body_pose('upper')
    com = A @ np.array(scene.bodies[1].shape.com) + p
    assert com[2] - com0[2] == pytest.approx(-world.joint_angles()[0] * com0[0], rel=1e-2)


def test_initial_positions_place_bodies_by_forward_kinematics():
    q = 0.7
    scene = Scene.from_urdf(ARM, initial_positions={'shoulder': q}, gravity=[0, 0, 0])
    world = World(scene)
    assert world.joint_angles()[0] == pytest.approx(q, abs=1e-12)
    p, A = world.body_pose('upper')
    assert np.allclose(p, [0, 0, 0.3])
    assert np.allclose(A, axis_rotation([0, 1, 0], q), atol=1e-12)
    world.step(10)          # at rest and no torque: stays there
    assert world.joint_angles()[0] == pytest.approx(q, abs=1e-9)


def test_matrix_rpy_round_trip_including_gimbal_lock():
    rng = np.random.default_rng(1)
    for rpy in list(rng.uniform(-3, 3, (20, 3))) + [(0.3, math.pi / 2, 0.2), (0.1, -math.pi / 2, 1)]:
        R = rpy_matrix(rpy)
        assert np.allclose(rpy_matrix(matrix_rpy(R)), R, atol=1e-12)


@pytest.mark.parametrize('jtype', ['planar', 'floating', 'spherical'])
def test_unsupported_joint_is_one_clear_error_and_lock_holds_it(jtype):
    text = robot(link('a', inertial(1)), link('b', inertial(1)), link('c', inertial(1)),
                 joint('j1', 'revolute', 'a', 'b', extra='<limit lower="-1" upper="1" effort="1" velocity="1"/>'),
                 joint('slide', jtype, 'b', 'c', xyz='0 0 0.2', axis='1 0 0',
                       extra='<limit lower="0" upper="0.1" effort="1" velocity="1"/>'))
    with pytest.raises(SceneError) as err:
        Scene.from_urdf(text)
    msg = str(err.value)
    assert "'slide'" in msg and jtype in msg and 'lock: [slide]' in msg and '\n' not in msg
    scene = Scene.from_urdf(text, lock=['slide'])
    assert scene.body_names == ('a', 'b') and scene.bodies[1].shape.mass == 2.0


def test_several_unsupported_joints_in_one_error_and_a_trailing_nul():
    """Every joint that cannot be simulated is named in ONE error (types beyond URDF's, such
    as PyBullet's 'spherical', included), so a user fixes them in one go; a file ending in a
    NUL byte (pybullet_data's humanoid.urdf) reads as tinyxml reads it."""
    text = robot(link('a', inertial(1)), link('b', inertial(1)), link('c', inertial(1)),
                 link('d', inertial(1)),
                 joint('ball', 'spherical', 'a', 'b'),
                 joint('hinge', 'revolute', 'b', 'c', extra='<limit lower="-1" upper="1" effort="1" velocity="1"/>'),
                 joint('slide', 'planar', 'c', 'd', axis='1 0 0',
                       extra='<limit lower="0" upper="0.1" effort="1" velocity="1"/>')) + '\x00'
    with pytest.raises(SceneError) as err:
        Scene.from_urdf(text)
    msg = str(err.value)
    assert ("2 joints cannot be simulated" in msg and "'ball' (spherical)" in msg
            and "'slide' (planar)" in msg and 'lock: [ball, slide]' in msg), msg
    scene = Scene.from_urdf(text, lock=['ball', 'slide'])
    assert scene.joint_names == ('hinge',) and scene.body_names == ('a', 'c')


def test_prismatic_joint_loads_with_its_limit_effort_and_initial_position():
    """URDF prismatic -> UID 20 along <axis> from the joint origin, <limit lower upper> [m]
    -> UID 669, effort -> the UID 667 force limit [N], initial_positions [m] ->
    init_distance (the child placed along the axis), <dynamics damping> -> its damping [N s/m]."""
    import warnings
    from abd_joint_sim.urdf import UrdfWarning
    text = robot(link('a', inertial(1)), link('b', inertial(1)),
                 joint('slide', 'prismatic', 'a', 'b', xyz='0 0 0.2', axis='0 2 0',
                       extra='<limit lower="-0.1" upper="0.3" effort="40" velocity="1"/>'
                             '<dynamics damping="3"/>'))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        scene = Scene.from_urdf(text, initial_positions={'slide': 0.05})
    said = [str(w.message) for w in caught if issubclass(w.category, UrdfWarning)]
    assert len(said) == 1 and '<limit velocity> is not enforced' in said[0], said   # only that
    (j,) = scene.joints
    assert j.type == 'prismatic' and j.init_distance == 0.05 and j.damping == 3.0
    assert np.allclose(j.p0, [0, 0, 0.2]) and np.allclose(np.subtract(j.p1, j.p0), [0, 1, 0])
    assert (j.limit.lower, j.limit.upper) == (-0.1, 0.3) and j.external_force.effort_limit == 40.0
    assert np.allclose(scene.bodies[1].position, [0, 0.05, 0.2])
    w = World(scene)
    w.set_effort('slide', 5.0)
    w.step(10)
    assert w.joint_positions()[0] > 0.05


def test_mimic_joint_refused_naming_it():
    text = robot(link('a', inertial(1)), link('b', inertial(1)), link('c', inertial(1)),
                 joint('j1', 'continuous', 'a', 'b'),
                 joint('j2', 'continuous', 'b', 'c', extra='<mimic joint="j1" multiplier="1"/>'))
    with pytest.raises(SceneError, match=r"joint 'j2'.*mimics joint 'j1'.*lock: \[j2\]"):
        Scene.from_urdf(text)
    scene = Scene.from_urdf(text, lock=['j2'])
    assert scene.joint_names == ('j1',) and scene.joints[0].limit is None   # continuous


@pytest.mark.parametrize('opts, match', [
    ({'lokc': ['a']}, r"unknown option\(s\) 'lokc'"),
    ({'lock': ['nope']}, r"robot.lock: unknown joint 'nope'"),
    ({'initial_positions': {'elbow': 1.0}}, r"initial_positions: unknown joint 'elbow'"),
    ({'initial_positions': {'shoulder': float('nan')}}, r'initial_positions.shoulder'),
    ({'actuated': ['tool_mount']}, r"actuated: joint 'tool_mount' is fixed"),
    ({'joints': {'shoulder': {'stiffness': 1}}}, r"joints.shoulder: unknown key\(s\) 'stiffness'"),
    ({'fixed_base': 'yes'}, r'fixed_base: must be true or false'),
    # absurd values: one line, not a traceback (OverflowError, TypeError)
    ({'strength_ratio': 10 ** 400}, r'strength_ratio: must be a finite number > 0, got 1000'),
    ({'initial_positions': {'shoulder': 10 ** 400}}, r'initial_positions.shoulder: must be a finite number'),
    ({'joints': {'shoulder': {'damping': 10 ** 400}}}, r'joints.shoulder.damping: must be a finite number >= 0'),
    ({'gravity': 9.81}, r'gravity: must be a list of 3 numbers'),
    ({'gravity': None}, r'gravity: must be a list of 3 numbers'),
])
def test_bad_options_name_what_is_wrong(opts, match):
    with pytest.raises(SceneError, match=match):
        Scene.from_urdf(ARM, **opts)


def test_the_first_wrong_actuated_joint_as_listed_is_named():
    """Two joints that cannot be actuated: the error names the first one listed, whatever
    Python's string hashing (PYTHONHASHSEED) of that run."""
    code = ('import sys; from abd_joint_sim import Scene\n'
            'try:\n'
            '    Scene.from_urdf(sys.argv[1], lock=["shoulder"], actuated=sys.argv[2:])\n'
            'except Exception as e:\n'
            '    print(e)\n')
    for order in (['tool_mount', 'shoulder'], ['shoulder', 'tool_mount']):
        for seed in ('0', '1', '2', '3'):
            env = dict(os.environ, PYTHONHASHSEED=seed)
            out = subprocess.run([sys.executable, '-c', code, str(ARM), *order], env=env,
                                 capture_output=True, text=True, timeout=120,
                                 cwd=str(Path(__file__).resolve().parents[1]))
            assert f'robot.actuated: joint {order[0]!r} is' in out.stdout, (seed, out)


def test_non_physical_inertias_repaired_with_one_warning_each():
    text = robot(link('a', inertial(1)),
                 link('b', inertial(1.0, ixx=0.001, iyy=0.05, izz=0.1)),     # triangle broken
                 link('c', inertial(2.0, ixx=0.0, iyy=0.0, izz=0.0)),        # point mass
                 joint('j1', 'continuous', 'a', 'b', axis='1 0 0'),
                 joint('j2', 'continuous', 'b', 'c', xyz='0 0 0.3', axis='1 0 0'))
    scene, msgs = _from_urdf_warned(text)
    assert len(msgs) == 2 and len(scene.warnings) == 2
    assert "link 'b'" in msgs[0] and 'triangle' in msgs[0] and 'balanceinertia' in msgs[0]
    assert np.allclose(np.array(scene.bodies[1].shape.inertia).reshape(3, 3),
                       np.eye(3) * (0.001 + 0.05 + 0.1) / 3)
    r = (3 * 2.0 / 1000 / (4 * math.pi)) ** (1 / 3)
    assert "link 'c'" in msgs[1] and 'sphere' in msgs[1]
    assert np.allclose(np.array(scene.bodies[2].shape.inertia).reshape(3, 3), 0.4 * 2 * r * r * np.eye(3))
    World(scene).step(5)


def test_a_flat_body_gets_a_little_thickness_with_a_warning():
    """Moments on the triangle inequality's edge (I_z = I_x + I_y: a body with no thickness,
    as the Allegro hand's links in example-robot-data have) are valid for a rigid-body engine
    but leave an affine body a mode without inertia: its smallest second moment is raised to
    FLAT_RATIO of its largest, in the same principal axes, with a warning; the rigid inertia
    changes by that much, and the hinge then turns under torque as a rigid plate would."""
    from abd_joint_sim.urdf import FLAT_RATIO
    R = rpy_matrix([0.3, -0.2, 0.5])
    # S = (8e-5, 2e-5, 5e-12): flat (exactly on the edge, I_z = I_x + I_y, is refused as a
    # broken triangle inequality; generated descriptions land just inside it)
    I = R @ np.diag([2e-5, 8e-5, 1e-4 - 1e-11]) @ R.T
    I = I.tolist()
    body = (f'<inertial><origin xyz="0 0 0.03"/><mass value="0.065"/><inertia ixx="{I[0][0]!r}" '
            f'ixy="{I[0][1]!r}" ixz="{I[0][2]!r}" iyy="{I[1][1]!r}" iyz="{I[1][2]!r}" izz="{I[2][2]!r}"/>'
            '</inertial>')
    text = robot(link('base', inertial(1.0)), link('plate', body),
                 joint('j', 'revolute', 'base', 'plate', axis='1 0 0',
                       extra='<limit lower="-3" upper="3" effort="5"/>'))
    scene, msgs = _from_urdf_warned(text, gravity=[0, 0, 0])
    assert len(msgs) == 1 and "link 'plate'" in msgs[0] and 'flat body' in msgs[0]
    got = np.linalg.eigvalsh(np.array(scene.bodies[1].shape.inertia).reshape(3, 3))
    lift = FLAT_RATIO * (8e-5 - 5e-12) - 5e-12              # S_z raised to FLAT_RATIO S_x
    assert np.allclose(got, [2e-5 + lift, 8e-5 + lift, 1e-4 - 1e-11], rtol=0, atol=1e-17)
    world = World(scene)
    world.set_torque('j', 0.02)
    reports = [world.step() for _ in range(100)]
    # the plate turns as a rigid one about the x axis through the joint (t = 0.1 s): I_xx of
    # the repaired inertia about the COM, 3 cm off the axis
    i_axis = np.array(scene.bodies[1].shape.inertia).reshape(3, 3)[0, 0] + 0.065 * 0.03 ** 2
    assert world.joint_angles()[0] == pytest.approx(0.5 * 0.02 / i_axis * 0.1 ** 2, rel=0.02)
    assert max(r.newton_iterations for r in reports) <= 20 and all(r.substeps == 1 for r in reports)


def test_a_point_mass_written_with_round_off_is_a_sphere_with_a_warning():
    """Moments of ~1e-20 kg m^2 on a 0.746 kg link (iCub's r_ankle_1 in example-robot-data:
    positive, so not caught as zero) give an affine body no inertia: the iCub failed within
    its first steps under 0.02 N m. Below POINT_MASS_RATIO of a water-density sphere's moments
    they are replaced by that sphere, as zero moments are."""
    tiny = ('<inertial><mass value="0.746"/><inertia ixx="2.71051e-20" ixy="-1.69407e-21" '
            'ixz="1.35525e-20" iyy="5.42101e-20" iyz="3.38813e-21" izz="1.35525e-20"/></inertial>')
    text = robot(link('base', inertial(1.0)), link('foot', tiny),
                 joint('ankle', 'revolute', 'base', 'foot', axis='0 1 0', xyz='0 0 -0.1',
                       extra='<limit lower="-1" upper="1" effort="20"/>'))
    scene, msgs = _from_urdf_warned(text, gravity=[0, 0, 0])
    assert len(msgs) == 1 and "link 'foot'" in msgs[0] and 'negligible for its mass' in msgs[0]
    r = (3 * 0.746 / 1000 / (4 * math.pi)) ** (1 / 3)
    assert np.allclose(np.array(scene.bodies[1].shape.inertia).reshape(3, 3), 0.4 * 0.746 * r * r * np.eye(3))
    world = World(scene)
    world.set_torque('ankle', 0.02)
    world.step(50)
    i_axis = 0.4 * 0.746 * r * r                               # (the COM is on the axis)
    assert world.joint_angles()[0] == pytest.approx(0.5 * 0.02 / i_axis * 0.05 ** 2, rel=0.02)
    # a real small link (a 10 g, 1 cm aluminium cube) is left alone
    cube = 0.01 * 0.01 ** 2 / 6
    small = robot(link('base', inertial(1.0)), link('foot', inertial(0.01, ixx=cube, iyy=cube, izz=cube)),
                  joint('ankle', 'revolute', 'base', 'foot', axis='0 1 0'))
    with warnings.catch_warnings():
        warnings.simplefilter('error', UrdfWarning)
        assert np.allclose(np.array(Scene.from_urdf(small).bodies[1].shape.inertia).reshape(3, 3),
                           cube * np.eye(3))


def test_massless_links():
    # A massless frame on a fixed joint merges trivially; a massless moving leaf is held rigid
    # with a warning; a massless moving link carrying a moving joint is refused.
    text = robot(link('world'), link('a', inertial(1)), link('b', inertial(1)), link('flange'),
                 link('spin'),
                 joint('weld', 'fixed', 'world', 'a'),
                 joint('j1', 'continuous', 'a', 'b', axis='1 0 0'),
                 joint('j_flange', 'fixed', 'b', 'flange', xyz='0 0 0.2'),
                 joint('j_spin', 'continuous', 'flange', 'spin'))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        scene = Scene.from_urdf(text)
    assert scene.body_names == ('world', 'b') and scene.joint_names == ('j1',)
    assert any("link 'spin' has no mass" in str(w.message) and "'j_spin'" in str(w.message)
               for w in caught)
    text2 = robot(link('a', inertial(1)), link('ghost'), link('c', inertial(1)),
                  joint('j1', 'continuous', 'a', 'ghost'), joint('j2', 'continuous', 'ghost', 'c'))
    with pytest.raises(SceneError, match=r"link 'ghost' \(joint 'j1'\) has no mass.*lock: \[j1\]"):
        Scene.from_urdf(text2)


@pytest.mark.parametrize('text, match', [
    ('<robot name="x"><link name="a"></robot>', r'<robot_description>: line 1, column \d+: not well-formed'),
    ('<?xml version="1.0"?><!DOCTYPE r [<!ENTITY a "aaaa">]><robot name="x"><link name="a"/></robot>',
     r'DOCTYPE/ENTITY declarations are not accepted'),
    ('<robot name="x" xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:property name="a" value="1"/>'
     '<link name="a"/></robot>', 'is a xacro element'),
    ('<robot name="x"><link name="a"/><link name="b"/></robot>', 'one tree'),
    ('<sdf/>', r'root element is <sdf>'),
])
def test_bad_xml_is_one_line(text, match):
    with pytest.raises(SceneError, match=match) as err:
        Scene.from_urdf(text)
    assert '\n' not in str(err.value)


def test_malformed_file_names_file_and_line(tmp_path):
    path = tmp_path / 'bad.urdf'
    path.write_text('<robot name="x">\n<link name="a">\n</robot>\n')
    with pytest.raises(SceneError, match=r'bad.urdf: line 3, column \d+: not well-formed'):
        Scene.from_urdf(str(path))


def test_white_space_before_the_xml_declaration_is_read_as_ros_reads_it(tmp_path):
    """Blank lines before `<?xml ...?>` (pybullet_data's biped2d_pybullet.urdf and
    diff_ring.urdf) are refused by expat but read by tinyxml (ROS, PyBullet): read them too,
    and keep the line numbers of a later error true."""
    good = '\n\n  ' + ARM          # ARM starts with its declaration
    assert Scene.from_urdf(good).joint_names == Scene.from_urdf(ARM).joint_names
    path = tmp_path / 'late.urdf'
    path.write_text('\n\n<?xml version="1.0"?>\n<robot name="x">\n<link name="a">\n</robot>\n')
    with pytest.raises(SceneError, match=r'late.urdf: line 6, column \d+: not well-formed'):
        Scene.from_urdf(str(path))


def test_robot_block_in_scene_yaml(tmp_path):
    (tmp_path / 'arm.urdf').write_text(ARM)
    (tmp_path / 'scene.yaml').write_text(
        'dt: 0.002\nintegrator: bdf2\nnewton: {max_iterations: 20}\n'
        'robot:\n  urdf: arm.urdf\n  initial_positions: {shoulder: 0.3}\n  limits: false\n')
    scene = Scene.from_yaml(tmp_path / 'scene.yaml')
    assert scene.dt == 0.002 and scene.integrator == 'bdf2' and scene.newton.max_iterations == 20
    assert scene.gravity == (0, 0, -9.81) and scene.joint_names == ('shoulder',)
    assert scene.joints[0].init_angle == 0.3 and scene.joints[0].limit is None
    assert scene.robot_description == ARM
    # The stored source text is the lowered scene: it rebuilds the same scene without the URDF.
    again = Scene.from_dict(load_yaml(scene.source_text))
    assert again.bodies == scene.bodies and again.joints == scene.joints
    (tmp_path / 'bad.yaml').write_text('robot: {urdf: arm.urdf, lokc: [x]}\n')
    with pytest.raises(SceneError, match=r"bad.yaml: robot: unknown key\(s\) 'lokc'"):
        Scene.from_yaml(tmp_path / 'bad.yaml')
    (tmp_path / 'missing.yaml').write_text('robot: {urdf: nothere.urdf}\n')
    with pytest.raises(SceneError, match=r'missing.yaml: robot: .*nothere.urdf: cannot read URDF'):
        Scene.from_yaml(tmp_path / 'missing.yaml')


def test_packaged_demo_arm_loads_and_runs():
    scene = Scene.from_urdf(DEMO)
    assert scene.joint_names == ('shoulder_pan', 'shoulder_lift', 'elbow')
    assert all(j.limit is not None for j in scene.joints)
    world = World(scene)
    world.step(20)
    assert np.all(np.isfinite(world.joint_angles()))
    assert Scene.from_file(DEMO).joint_names == scene.joint_names


@pytest.mark.parametrize('opts, match', [
    ({'initial_positions': {'shoulder': 2.0}}, r"initial_positions.shoulder: 2 rad is outside the joint's limit \[-1.5, 1.5\]"),
    ({'joints': {'shoulder': {'driving': {'aim': 1.0}}}}, r"joints.shoulder.driving: unknown key\(s\) 'aim'"),
    ({'joints': {'shoulder': {'limit': 3}}}, r'joints.shoulder.limit: must be a mapping'),
    ({'kappa': -1.0}, r'robot.kappa: must be a finite number > 0'),
    ({'joints': {'shoulder': {'strength_ratio': 0}}}, r'joints.shoulder.strength_ratio: must be'),
    ({'joints': {'shoulder': {'damping': -0.5}}}, r'joints.shoulder.damping: must be a finite number >= 0'),
    ({'joints': {'shoulder': {'damping': 'high'}}}, r'joints.shoulder.damping: must be a finite number >= 0'),
    ({'damping': 0.5}, r'robot.damping: must be true .* or false'),
])
def test_bad_overrides_name_the_joint_and_field(opts, match):
    with pytest.raises(SceneError, match=match):
        Scene.from_urdf(ARM, **opts)
    # an initial position outside the URDF limit is fine once the limit is off
    Scene.from_urdf(ARM, initial_positions={'shoulder': 2.0}, limits=False)


def test_zero_outside_the_limit_starts_at_the_nearest_bound_with_a_warning():
    text = ARM.replace('lower="-1.5" upper="1.5"', 'lower="0.5" upper="1.5"')
    scene, msgs = _from_urdf_warned(text, gravity=[0, 0, 0])
    assert len(msgs) == 1 and "joint 'shoulder': position 0 is outside its limit [0.5, 1.5]" in msgs[0]
    world = World(scene)
    assert world.joint_angles()[0] == pytest.approx(0.5, abs=1e-12)
    world.step(20)
    assert world.joint_angles()[0] == pytest.approx(0.5, abs=1e-6)     # at rest, not thrown
    # no limit, no clamp; an explicit position outside the limit stays an error
    assert Scene.from_urdf(text, limits=False).joints[0].init_angle == 0.0
    with pytest.raises(SceneError, match='outside'):
        Scene.from_urdf(text, initial_positions={'shoulder': 0.0})


@pytest.mark.parametrize('bounds', ['lower="-1e+16" upper="1e+16"', 'lower="-1e16" upper="0.5"'])
def test_a_limit_beyond_the_supported_angles_is_no_limit_with_a_warning(bounds):
    """lower="-1e+16" upper="1e+16" (a drone's rotors in example-robot-data) is a description's
    way of saying "unlimited": the joint is taken as continuous, with one warning naming it,
    and the scene loads (the scene's own |angle| <= 1e4 rad would refuse the number)."""
    text = ARM.replace('lower="-1.5" upper="1.5"', bounds)
    scene, msgs = _from_urdf_warned(text)
    assert len(msgs) == 1 and "joint 'shoulder': limit [-1e+16," in msgs[0] and 'no limit' in msgs[0]
    assert scene.joints[0].limit is None and scene.joints[0].external_torque.effort_limit == 40.0
    world = World(scene)
    world.set_torque('shoulder', 40.0)
    world.step(50)
    assert np.isfinite(world.joint_angles()).all() and abs(world.joint_angles()[0]) > 0.0
    # an override still sets a limit of its own
    with pytest.warns(UrdfWarning, match='no limit'):
        scene = Scene.from_urdf(text, joints={'shoulder': {'limit': {'lower': -1.0, 'upper': 1.0}}})
    assert scene.joints[0].limit.lower == -1.0


def test_xacro_substitutions_refused_but_not_in_comments():
    ok = ARM.replace('<link name="base">', '<!-- ${not_expanded} is fine here -->\n<link name="base">')
    assert Scene.from_urdf(ok).joint_names == ('shoulder',)
    bad = ARM.replace('xyz="0 0 0.3"', 'xyz="$(optenv ARM_Z 0 0 0.3)"')
    with pytest.raises(SceneError, match=r"<origin> xyz='\$\(optenv ARM_Z 0 0 0.3\)' is an unexpanded xacro/launch substitution"):
        Scene.from_urdf(bad)
    # a macro file as xacro leaves it when nothing calls the macro (ur3.urdf of
    # example-robot-data): no link, and the message says why
    macro = ('<?xml version="1.0"?>\n<robot xmlns:xacro="http://wiki.ros.org/xacro">\n'
             '<!-- Author: someone -->\n</robot>\n')
    with pytest.raises(SceneError, match=r'no <link> in the robot \(the file declares the xacro namespace'):
        Scene.from_urdf(macro)
    with pytest.raises(SceneError, match=r'no <link> in the robot$'):
        Scene.from_urdf('<robot name="empty"/>')


def test_ignored_speed_limits_are_said_once_per_robot():
    """<limit velocity> is not enforced: one warning per robot naming the moving joints that
    have one (none for a robot without, or for a fixed joint's)."""
    _, msgs = _from_urdf_warned(Path(DEMO).read_text(), speed_limits=True)
    speed = [m for m in msgs if SPEED_LIMITS in m]
    assert speed == ['<robot_description>: <limit velocity> is not enforced (joint speeds are not '
                     'limited): ignored on 3 joint(s): shoulder_pan, shoulder_lift, elbow (of '
                     '<limit>, lower, upper and effort are)'], msgs
    _, msgs = _from_urdf_warned(ARM.replace(' velocity="2"', ''), speed_limits=True)
    assert not [m for m in msgs if SPEED_LIMITS in m], msgs
    with pytest.raises(SceneError, match=r'velocity'):
        Scene.from_urdf(ARM.replace('velocity="2"', 'velocity="fast"'))


def _damped_arm(dynamics):
    return robot(link('base', inertial(5.0)), link('upper', inertial(2.0, xyz='0.25 0 0')),
                 link('fore', inertial(1.0, xyz='0.2 0 0')),
                 joint('shoulder', 'revolute', 'base', 'upper', axis='0 1 0',
                       extra='<limit lower="-1.5" upper="1.5" effort="40" velocity="2"/>' + dynamics),
                 joint('elbow', 'continuous', 'upper', 'fore', xyz='0.5 0 0', axis='0 1 0',
                       extra='<dynamics damping="0.25"/>'))


def test_joint_damping_is_read_switched_off_and_overridden_and_friction_is_said_once():
    """<dynamics damping> becomes the joint's damping (terms/damping.py); `damping: false`
    drops it, `joints: {j: {damping: d}}` sets it; <dynamics friction> is not simulated and
    said in one warning naming the joints; a negative damping is refused naming the joint."""
    text = _damped_arm('<dynamics damping="0.7" friction="0.3"/>')
    scene, msgs = _from_urdf_warned(text)
    assert {j.name: j.damping for j in scene.joints} == {'shoulder': 0.7, 'elbow': 0.25}
    assert len(msgs) == 1 and 'friction' in msgs[0] and 'ignored on 1 joint(s): shoulder' in msgs[0]
    assert World(scene).terms == ('ortho_potential', 'revolute_joint', 'limit', 'joint_damping',
                                  'gravity', 'external_torque')
    off, _ = _from_urdf_warned(text, damping=False)
    assert [j.damping for j in off.joints] == [0.0, 0.0] and 'joint_damping' not in World(off).terms
    over, _ = _from_urdf_warned(text, joints={'elbow': {'damping': 2.0}, 'shoulder': {'damping': False}})
    assert {j.name: j.damping for j in over.joints} == {'shoulder': 0.0, 'elbow': 2.0}
    assert Scene.from_dict(scene.to_dict()).joints == scene.joints     # kept by a bag's scene
    with pytest.raises(SceneError, match=r"joint 'shoulder' <dynamics>: damping=\"-0.7\" is negative"):
        Scene.from_urdf(_damped_arm('<dynamics damping="-0.7"/>'))
    with pytest.raises(SceneError, match=r"joint 'shoulder' <dynamics>: damping=\"1e\+12\" is beyond the supported 1e\+09"):
        Scene.from_urdf(_damped_arm('<dynamics damping="1e12"/>'))
    with pytest.raises(SceneError, match=r"joint 'shoulder' <dynamics>: damping='nan' must be 1 finite"):
        Scene.from_urdf(_damped_arm('<dynamics damping="nan"/>'))
