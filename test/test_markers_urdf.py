"""Markers of real URDF robots (ros/markers.py on Scene.from_urdf), checked against PyBullet.

Robot files come from the pybullet wheel (`pybullet_data`, never copied here). Each robot is
loaded at a non-zero configuration, driven by torques and gravity for some steps; then

* there is one marker per URDF ``<visual>`` (of every link, merged fixed links included), of
  the visual's kind and size (meshes as MESH_RESOURCE with the file's URI and scale);
* each marker's pose equals the pose of its link's frame composed with the visual's
  ``<origin>``, where the link frame comes from PyBullet's forward kinematics
  (``getLinkState``, worldLinkFrame) at the joint angles our world reports, and the visual
  origin is read from the XML by this test (not by abd_joint_sim.urdf).

The tolerance (0.5 mm, 1e-3 in the rotation's Frobenius norm) is far above the affine
bodies' deformation and the joints' compliance (<= 4e-5 here) and far below what a wrong
sign, frame or composition order moves a visual (centimetres).
"""
from __future__ import annotations

import os
from types import SimpleNamespace
import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from abd_joint_sim import Scene, World
from abd_joint_sim.ros.markers import MarkerBuilder

pybullet = pytest.importorskip('pybullet', reason='pybullet not installed (requirements-test.txt)')
pybullet_data = pytest.importorskip('pybullet_data', reason='pybullet_data not installed')

POS_TOL = 5e-4      # m
ROT_TOL = 1e-3      # Frobenius norm of the rotation difference


def _transform(position, quat_xyzw) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    T[:3, 3] = position
    return T


def _origin(el) -> np.ndarray:
    """<origin xyz rpy> of an element as a 4x4 (URDF rpy: extrinsic x, y, z)."""
    T = np.eye(4)
    o = el.find('origin')
    if o is not None:
        T[:3, 3] = [float(v) for v in o.get('xyz', '0 0 0').split()]
        T[:3, :3] = Rotation.from_euler('xyz', [float(v) for v in
                                                o.get('rpy', '0 0 0').split()]).as_matrix()
    return T


def expected_visuals(path: str) -> list[dict]:
    """Every <visual> of the file: link, geometry tag, size/scale, filename, origin."""
    out = []
    for link in ET.parse(path).getroot().findall('link'):
        for vis in link.findall('visual'):
            geom = vis.find('geometry')
            if geom is None or len(geom) == 0:
                continue
            g = geom[0]
            if g.tag == 'box':
                scale = [float(v) for v in g.get('size').split()]
            elif g.tag == 'sphere':
                scale = [2 * float(g.get('radius'))] * 3
            elif g.tag == 'cylinder':
                r = float(g.get('radius'))
                scale = [2 * r, 2 * r, float(g.get('length'))]
            else:
                scale = [float(v) for v in g.get('scale', '1 1 1').split()]
            out.append({'link': link.get('name'), 'kind': g.tag, 'scale': scale,
                        'uri': g.get('filename', ''), 'origin': _origin(vis)})
    return out


def pybullet_link_frames(path: str, angles: dict) -> dict:
    """World pose (4x4) of every link frame at joint positions `angles` (PyBullet FK)."""
    p = pybullet
    cid = p.connect(p.DIRECT)
    try:
        rid = p.loadURDF(path, useFixedBase=True, physicsClientId=cid)
        link_index = {}
        for k in range(p.getNumJoints(rid, physicsClientId=cid)):
            info = p.getJointInfo(rid, k, physicsClientId=cid)
            link_index[info[12].decode()] = k
            if info[1].decode() in angles:
                p.resetJointState(rid, k, angles[info[1].decode()], physicsClientId=cid)
        # The base pose PyBullet reports is its inertial frame: back to the link frame.
        pos, orn = p.getBasePositionAndOrientation(rid, physicsClientId=cid)
        dyn = p.getDynamicsInfo(rid, -1, physicsClientId=cid)
        frames = {None: _transform(pos, orn) @ np.linalg.inv(_transform(dyn[3], dyn[4]))}
        for name, k in link_index.items():
            state = p.getLinkState(rid, k, computeForwardKinematics=True, physicsClientId=cid)
            frames[name] = _transform(state[4], state[5])
    finally:
        p.disconnect(cid)
    return frames


def run_robot(rel_path: str, q0: dict, lock=(), steps: int = 150):
    """(path, scene, world, MarkerArray) after `steps` of alternating torques and gravity."""
    path = os.path.join(pybullet_data.getDataPath(), rel_path)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')        # repaired inertias etc.: test_urdf_engines
        scene = Scene.from_urdf(path, dt=1e-3, initial_positions=q0, lock=list(lock))
    world = World(scene)
    for k, name in enumerate(scene.joint_names):
        world.set_torque(name, (-1) ** k * 1.0)
    world.step(steps)
    msg = MarkerBuilder(scene).build(123, world.body_pose)
    return path, scene, world, msg


def _marker_pose(m) -> np.ndarray:
    o, q = m.pose.orientation, m.pose.position
    return _transform([q.x, q.y, q.z], [o.x, o.y, o.z, o.w])


def match_markers(path: str, scene, world, msg) -> tuple[list, list, float, float]:
    """Pair every expected visual with one marker (minimum total pose error); returns the
    pairs (visual, marker), and the worst position and rotation errors."""
    angles = dict(zip(scene.joint_names, world.joint_angles()))
    frames = pybullet_link_frames(path, angles)
    visuals = expected_visuals(path)
    for v in visuals:
        v['world'] = frames.get(v['link'], frames[None]) @ v['origin']
    markers = list(msg.markers)
    assert len(markers) == len(visuals), 'one marker per <visual>'
    cost = np.zeros((len(visuals), len(markers)))
    for a, v in enumerate(visuals):
        for b, m in enumerate(markers):
            T = _marker_pose(m)
            cost[a, b] = np.linalg.norm(T[:3, 3] - v['world'][:3, 3]) + \
                np.linalg.norm(T[:3, :3] - v['world'][:3, :3])
    rows, cols = linear_sum_assignment(cost)
    pairs = [(visuals[a], markers[b]) for a, b in zip(rows, cols)]
    dpos = max(np.linalg.norm(_marker_pose(m)[:3, 3] - v['world'][:3, 3]) for v, m in pairs)
    drot = max(np.linalg.norm(_marker_pose(m)[:3, :3] - v['world'][:3, :3]) for v, m in pairs)
    return pairs, dpos, drot


def check_kinds(pairs) -> None:
    from visualization_msgs.msg import Marker
    kinds = {'box': Marker.CUBE, 'sphere': Marker.SPHERE, 'cylinder': Marker.CYLINDER,
             'mesh': Marker.MESH_RESOURCE}
    for v, m in pairs:
        assert m.type == kinds[v['kind']], (v['link'], v['kind'], m.type)
        np.testing.assert_allclose([m.scale.x, m.scale.y, m.scale.z], v['scale'], rtol=1e-12,
                                   err_msg=v['link'])
        assert m.mesh_resource == v['uri'], v['link']
        assert m.ns.startswith('bodies/') and m.header.frame_id == 'world'


@pytest.mark.parametrize('rel_path, q0, lock', [
    # meshes, 7 revolute joints, from a bent pose
    ('kuka_iiwa/model.urdf', {'lbr_iiwa_joint_2': 0.5, 'lbr_iiwa_joint_4': -1.0,
                              'lbr_iiwa_joint_6': 0.8, 'lbr_iiwa_joint_7': 0.6}, ()),
    # boxes, cylinders with rotated origins, a sphere, meshes; fixed joints merged
    ('r2d2.urdf', {'head_swivel': 0.9, 'right_front_wheel_joint': 1.2,
                   'left_gripper_joint': 0.3}, ('gripper_extension',)),
    # cylinders and boxes on links merged by fixed joints
    ('TwoJointRobot_w_fixedJoints.urdf', {'joint_1': 0.7, 'joint_2': -0.9}, ()),
])
@pytest.mark.slow
def test_markers_of_real_robots_follow_pybullet_forward_kinematics(rel_path, q0, lock):
    path, scene, world, msg = run_robot(rel_path, q0, lock)
    moved = np.abs(world.joint_angles() - [q0.get(n, 0.0) for n in scene.joint_names])
    assert moved.max() > 1e-3, 'the robot must have moved from its initial pose'
    pairs, dpos, drot = match_markers(path, scene, world, msg)
    check_kinds(pairs)
    print(f'{rel_path}: {len(pairs)} markers, worst position {dpos:.1e} m, '
          f'rotation {drot:.1e}')             # docs/urdf.md quotes these (pytest -s)
    assert dpos < POS_TOL and drot < ROT_TOL, (dpos, drot)
    # stable ids: index of the visual within its body, per body namespace
    ids: dict = {}
    for m in msg.markers:
        ids.setdefault(m.ns, []).append(m.id)
    assert all(v == list(range(len(v))) for v in ids.values())
    assert all(m.header.stamp.nanosec == 123 for m in msg.markers)


def test_a_wrong_configuration_is_caught():
    """The check can fail: markers of the same robot at other joint angles do not match
    PyBullet's FK at the reported angles."""
    q0 = {'lbr_iiwa_joint_2': 0.5, 'lbr_iiwa_joint_4': -1.0}
    path, scene, world, _ = run_robot('kuka_iiwa/model.urdf', q0, steps=50)
    other = {n: q + (0.05 if n == 'lbr_iiwa_joint_2' else 0.0)
             for n, q in zip(scene.joint_names, world.joint_angles())}
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        scene2 = Scene.from_urdf(path, initial_positions=other)
    wrong = MarkerBuilder(scene2).build(0, World(scene2).body_pose)
    _, dpos, _ = match_markers(path, scene, world, wrong)
    assert dpos > 10 * POS_TOL


def test_mesh_scale_and_uri_of_a_scaled_mesh():
    """cube_small.urdf: one link, a mesh with scale 0.05 (no joints)."""
    from visualization_msgs.msg import Marker
    path, scene, world, msg = run_robot('cube_small.urdf', {}, steps=1)
    (m,) = msg.markers
    assert m.type == Marker.MESH_RESOURCE and m.mesh_resource == 'cube.obj'
    assert (m.scale.x, m.scale.y, m.scale.z) == (0.05, 0.05, 0.05)
    pairs, dpos, drot = match_markers(path, scene, world, msg)
    check_kinds(pairs)
    assert dpos < 1e-12 and drot < 1e-12


# ------------------------------------------------------------ pictures of a robot bag ----
R2D2_BODIES = {'left_gripper': ('left_gripper', 'left_tip'),       # fixed joints merged
               'right_gripper': ('right_gripper', 'right_tip')}


def _pybullet_body_coms(path: str, angles: dict) -> dict:
    """World COM of each r2d2 gripper body (its links lumped by mass), PyBullet FK."""
    p = pybullet
    cid = p.connect(p.DIRECT)
    try:
        rid = p.loadURDF(path, useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE,
                         physicsClientId=cid)
        index = {}
        for k in range(p.getNumJoints(rid, physicsClientId=cid)):
            info = p.getJointInfo(rid, k, physicsClientId=cid)
            index[info[12].decode()] = k
            if info[1].decode() in angles:
                p.resetJointState(rid, k, angles[info[1].decode()], physicsClientId=cid)
        out = {}
        for body, links in R2D2_BODIES.items():
            m = np.array([p.getDynamicsInfo(rid, index[n], physicsClientId=cid)[0]
                          for n in links])
            c = np.array([p.getLinkState(rid, index[n], computeForwardKinematics=True,
                                         physicsClientId=cid)[0] for n in links])
            out[body] = (m[:, None] * c).sum(axis=0) / m.sum()
    finally:
        p.disconnect(cid)
    return out


@pytest.mark.slow
def test_plot_bag_draws_meshes_as_their_bodies_equal_inertia_box(tmp_path, capsys):
    """A robot with mesh visuals (r2d2's grippers, rotated visual origins) recorded by
    run_headless: plot_bag stands in each mesh body's box of equal inertia, centred at the
    body's COM (checked against PyBullet's link COMs at the recorded angles), and says so."""
    pytest.importorskip('matplotlib', reason='matplotlib not installed (requirements-test.txt)')
    from abd_joint_sim.tools import plot_bag, run_headless
    from visualization_msgs.msg import Marker
    path = os.path.join(pybullet_data.getDataPath(), 'r2d2.urdf')
    q0 = {'left_gripper_joint': 0.4, 'right_gripper_joint': 0.2, 'head_swivel': 0.5}
    (tmp_path / 'r2d2.yaml').write_text(
        f'dt: 0.001\nrobot:\n  urdf: {path}\n  lock: [gripper_extension]\n'
        f'  initial_positions: {q0}\n')
    (tmp_path / 'sched.yaml').write_text(
        'duration: 0.3\nevents:\n  - t: 0.0\n    torque: {left_gripper_joint: 0.5, '
        'right_gripper_joint: -0.5}\n')
    bag = tmp_path / 'bag'
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        assert run_headless.main(['--scene', str(tmp_path / 'r2d2.yaml'), '--schedule',
                                  str(tmp_path / 'sched.yaml'), '--out', str(bag),
                                  '-q']) == 0
    run = plot_bag.read_run(bag)
    assert set(R2D2_BODIES) <= set(run.mesh_boxes)
    t, last = run.markers[-1]
    k = int(np.argmin(np.abs(np.array(run.t) - t)))      # the joint state at that time
    angles = dict(zip(run.joint_names, run.position[k]))
    assert abs(angles['left_gripper_joint'] - 0.4) > 1e-3, 'the gripper must have moved'
    coms = _pybullet_body_coms(path, angles)
    for m in last.markers:
        if m.type != Marker.MESH_RESOURCE:
            continue
        body = m.ns.split('/', 1)[1]
        centre = plot_bag._mesh_box_points(run, m).mean(axis=0)
        np.testing.assert_allclose(centre, coms[body], atol=5e-4, err_msg=f'{body} {m.id}')
    out = tmp_path / 'png'
    assert plot_bag.main([str(bag), '--out', str(out), '-q']) == 0
    assert (out / 'poses.png').stat().st_size > 20_000


def test_massless_world_root_is_marked_not_drawn_as_a_made_up_box():
    """pendulum5.urdf's root link `world` has neither mass nor visual: the importer gives
    it a made-up inertia (it is fixed), whose equal-inertia box would be drawn as a 25 cm
    cube; a small sphere marks the frame instead. The five links keep their spheres."""
    from visualization_msgs.msg import Marker
    from abd_joint_sim.urdf import FRAME_MARK_RADIUS
    path, scene, world, msg = run_robot('pendulum5.urdf', {'joint0': 0.3}, steps=20)
    by_ns = {m.ns: m for m in msg.markers}
    root = by_ns['bodies/world']
    assert root.type == Marker.SPHERE
    assert root.scale.x == root.scale.z == 2 * FRAME_MARK_RADIUS
    spheres = [m for m in msg.markers if m.ns != 'bodies/world']
    assert len(spheres) == 5 and all(m.type == Marker.SPHERE for m in spheres)
    # the link spheres are the file's and sit where PyBullet's FK puts them
    visuals = expected_visuals(path)
    angles = dict(zip(scene.joint_names, world.joint_angles()))
    frames = pybullet_link_frames(path, angles)
    for v in visuals:
        T = frames[v['link']] @ v['origin']
        d = min(np.linalg.norm(_marker_pose(m)[:3, 3] - T[:3, 3]) for m in spheres)
        assert d < POS_TOL, (v['link'], d)


def test_joint_axis_arrows_of_a_urdf_robot_fit_the_robot():
    """A URDF joint's p1 is p0 + the unit axis (1 m); its arrow starts at the joint origin,
    along the URDF axis in the world, 0.2 x the robot's extent long: demo_arm's joint
    and link origins span 0.4 m in x and 0.3 m in z (diagonal 0.5 m), so 0.1 m, carried by
    the parent body."""
    from abd_joint_sim.ros.markers import robot_axis_length
    from abd_joint_sim.ros.params import resolve_scene
    scene = Scene.from_file(resolve_scene('demo_arm'))
    world = World(scene)
    world.set_torque('shoulder_lift', 12.0)
    world.step(200)
    msg = MarkerBuilder(scene, joint_axes=True).build(0, world.body_pose)
    arrows = {m.id: m for m in msg.markers if m.ns == 'joint_axes'}
    length = robot_axis_length(scene)
    assert length == pytest.approx(0.2 * 0.5, rel=1e-12)
    assert len(arrows) == 3
    # elbow (from the URDF): origin (0.4, 0, 0) and axis (0, -1, 0) in the upper arm's link
    # frame, which is its body frame (rpy 0 at the zero pose)
    upper = next(bd for bd in scene.bodies if bd.name == 'upper_arm')
    assert np.allclose(upper.rpy, 0.0)
    p, A = world.body_pose('upper_arm')
    U, _, Vt = np.linalg.svd(A)
    R = U @ Vt                                              # polar factor of A
    assert np.linalg.norm(R - np.eye(3)) > 0.5, 'the arm must have lifted'
    a, b = ([q.x, q.y, q.z] for q in arrows[scene.joint_names.index('elbow')].points)
    np.testing.assert_allclose(a, p + A @ [0.4, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(np.subtract(b, a), length * (R @ [0.0, -1.0, 0.0]),
                               atol=1e-3 * length)
    # the YAML scenes keep their p0 -> p1 arrows
    assert robot_axis_length(Scene.from_file(resolve_scene('default'))) is None


@pytest.mark.parametrize('rel_path, lock', [
    ('r2d2.urdf', ('gripper_extension',)),      # colours named once in a link, reused after
    ('kuka_iiwa/model.urdf', ()),               # robot-level named materials
    ('pendulum5.urdf', ()),                     # 'Red' referenced but never defined
])
def test_marker_colours_are_pybullets(rel_path, lock):
    """Each visual's colour is the one PyBullet (its own URDF reader) gives it; where the
    file defines none (PyBullet's default white) the marker has our palette colour."""
    path, scene, world, msg = run_robot(rel_path, {}, lock, steps=1)
    p = pybullet
    cid = p.connect(p.DIRECT)
    try:
        rid = p.loadURDF(path, useFixedBase=True, physicsClientId=cid)
        names = {-1: p.getBodyInfo(rid, physicsClientId=cid)[0].decode()}   # the root link
        for k in range(p.getNumJoints(rid, physicsClientId=cid)):
            names[k] = p.getJointInfo(rid, k, physicsClientId=cid)[12].decode()
        theirs: dict = {}
        for v in p.getVisualShapeData(rid, physicsClientId=cid):
            theirs.setdefault(names[v[1]], []).append(tuple(v[7]))
    finally:
        p.disconnect(cid)
    defined = {}          # link -> [(origin, marker)], in the file's order
    # (pendulum5's massless root gets a frame sphere that is no <visual>: not compared)
    drawn = SimpleNamespace(markers=[m for m in msg.markers if m.ns != 'bodies/world'])
    pairs, _, _ = match_markers(path, scene, world, drawn)
    for v, m in pairs:
        defined.setdefault(v['link'], []).append((v['origin'][:3, 3].tolist(), m))
    checked = 0
    for link, entries in defined.items():
        pb = theirs[link]
        assert len(pb) == len(entries), link
        for (_, m), rgba in zip(entries, pb):
            ours = (m.color.r, m.color.g, m.color.b, m.color.a)
            if rgba == (1.0, 1.0, 1.0, 1.0) and ours != rgba:
                continue               # undefined in the file: our palette, their white
            np.testing.assert_allclose(ours, rgba, atol=1e-6, err_msg=link)
            checked += 1
    assert checked >= {'r2d2.urdf': 12, 'kuka_iiwa/model.urdf': 8, 'pendulum5.urdf': 1}[rel_path]
