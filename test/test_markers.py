"""Body markers (ros/markers.py): the pose extraction against scipy, the shapes, and the
markers a headless run records (read back by rosbags) against World.body_pose of a world
stepped the same way. The live node's markers are checked in test_markers_node below."""
from __future__ import annotations

import dataclasses
import signal

import numpy as np
import pytest
from scipy.linalg import polar
from scipy.spatial.transform import Rotation

from conftest import NodeProcess, Probe, next_domain_id
from abd_joint_sim import Scene
from abd_joint_sim.ros.markers import equal_inertia_box, MarkerBuilder
from physics_helpers import nearest_rotation, quaternion
from abd_joint_sim.ros.params import config_from_values, resolve_scene
from abd_joint_sim.scene import VisualSpec
from abd_joint_sim.tools.schedule import parse_schedule

SCHEDULE = {'duration': 1.5, 'events': [
    {'t': 0.0, 'torque': {'shoulder': 2.0, 'elbow': 1.0}},
    {'t': 0.7, 'torque': {'shoulder': -3.0, 'elbow': -0.5}}]}


def _rot(marker) -> np.ndarray:
    o = marker.pose.orientation
    return Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()


def _pos(marker) -> np.ndarray:
    p = marker.pose.position
    return np.array([p.x, p.y, p.z])


# ------------------------------------------------------------------------- pure maths ----
def test_nearest_rotation_is_scipys_polar_factor():
    rng = np.random.default_rng(1)
    for _ in range(50):
        R = Rotation.random(random_state=rng).as_matrix()
        A = R @ (np.eye(3) + 0.05 * rng.standard_normal((3, 3)))   # stretched and sheared
        U, _ = polar(A)                                             # A = U P, U orthogonal
        got = nearest_rotation(A)
        np.testing.assert_allclose(got, U, atol=1e-12)
        assert abs(np.linalg.det(got) - 1.0) < 1e-12
    # A reflection: the polar factor has det -1; ours is the nearest proper rotation.
    A = np.diag([1.0, 2.0, -0.5])
    R = nearest_rotation(A)
    assert abs(np.linalg.det(R) - 1.0) < 1e-12
    # polar factor diag(1, 1, -1); the sign flips on the smallest singular value (z)
    np.testing.assert_allclose(R, np.eye(3), atol=1e-12)


def test_compiled_frame_poses_match_the_numpy_reference():
    """smallmat.frame_poses (what the markers use, compiled) against scipy: positions A t + p,
    orientations the polar factor of A (the nearest proper rotation for the reflection)
    times R_v, and False (not a traceback) for a non-finite body."""
    from abd_joint_sim.smallmat import frame_poses
    rng = np.random.default_rng(7)
    B, F = 6, 9
    A = np.array([Rotation.random(random_state=rng).as_matrix()
                  @ (np.eye(3) + 0.05 * rng.standard_normal((3, 3))) for _ in range(B)])
    A[2] = np.diag([1.0, 2.0, -0.5])                              # det < 0: a reflection
    P = rng.standard_normal((B, 3))
    body = rng.integers(0, B, F).astype(np.intp)
    t = rng.standard_normal((F, 3))
    Rv = np.array([Rotation.random(random_state=rng).as_matrix() for _ in range(F)])
    ends_body = rng.integers(0, B, 4).astype(np.intp)
    ends = rng.standard_normal((4, 3))
    poses, points = np.empty((F, 7)), np.empty((4, 3))
    assert frame_poses(P, A, body, t, Rv, ends_body, ends, poses, points)
    for i, b in enumerate(body):
        U = np.eye(3) if b == 2 else polar(A[b])[0]     # diag(1, 2, -0.5): nearest is I
        R = Rotation.from_quat(poses[i, 3:]).as_matrix()
        np.testing.assert_allclose(poses[i, :3], A[b] @ t[i] + P[b], rtol=0, atol=1e-14)
        np.testing.assert_allclose(R, U @ Rv[i], rtol=0, atol=1e-12)
        assert poses[i, 6] >= 0.0
    for i, b in enumerate(ends_body):
        np.testing.assert_allclose(points[i], A[b] @ ends[i] + P[b], rtol=0, atol=1e-14)
    A[4, 1, 2] = np.nan
    assert not frame_poses(P, A, body, t, Rv, ends_body, ends, poses, points)


def test_quaternion_matches_scipy():
    rng = np.random.default_rng(2)
    mats = [Rotation.random(random_state=rng).as_matrix() for _ in range(200)]
    mats += [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0]),
             np.eye(3)]
    for R in mats:
        q = np.array(quaternion(R))
        ref = Rotation.from_matrix(R).as_quat()
        assert min(np.abs(q - ref).max(), np.abs(q + ref).max()) < 1e-12
        assert q[3] >= 0.0


def test_equal_inertia_box_has_the_inertia():
    rng = np.random.default_rng(3)
    m, sides = 2.5, np.array([0.3, 0.1, 0.05])
    I_box = m / 12.0 * np.diag([sides[1] ** 2 + sides[2] ** 2, sides[0] ** 2 + sides[2] ** 2,
                                sides[0] ** 2 + sides[1] ** 2])
    R = Rotation.random(random_state=rng).as_matrix()
    I = R @ I_box @ R.T
    got_sides, axes = equal_inertia_box(m, I.ravel())
    I_got = axes @ (m / 12.0 * np.diag([got_sides[1] ** 2 + got_sides[2] ** 2,
                                        got_sides[0] ** 2 + got_sides[2] ** 2,
                                        got_sides[0] ** 2 + got_sides[1] ** 2])) @ axes.T
    np.testing.assert_allclose(I_got, I, atol=1e-12)
    np.testing.assert_allclose(sorted(got_sides), sorted(sides), rtol=1e-10)
    assert abs(np.linalg.det(axes) - 1.0) < 1e-12


# ------------------------------------------------------------------------ the shapes ----
def test_scene_shapes_visuals_and_fallback():
    from visualization_msgs.msg import Marker
    scene = Scene.from_dict({
        'dt': 0.01, 'gravity': [0, 0, 0],
        'bodies': [
            {'name': 'ball', 'sphere': 0.1, 'density': 1000.0, 'position': [0, 0, 0],
             'fixed': True},
            {'name': 'can', 'cylinder': {'radius': 0.05, 'length': 0.3}, 'density': 1000.0,
             'position': [1, 0, 0], 'rpy': [0.3, 0.0, 0.0]},
            {'name': 'blob', 'inertial': {'mass': 2.0, 'com': [0.1, 0.0, 0.0],
                                          'inertia': [[0.02, 0, 0], [0, 0.05, 0],
                                                      [0, 0, 0.06]]},
             'position': [2, 0, 0]},
        ],
        'joints': [{'name': 'j', 'parent': 'ball', 'child': 'can', 'p0': [0.5, 0, 0],
                    'p1': [0.5, 0, 1]}]})
    poses = {b.name: (np.array(b.position, float), Rotation.from_euler(
        'xyz', b.rpy).as_matrix()) for b in scene.bodies}
    msg = MarkerBuilder(scene, 'map', joint_axes=True).build(5, lambda n: poses[n])
    by = {(m.ns, m.id): m for m in msg.markers}
    assert list(by) == [('bodies/ball', 0), ('bodies/can', 0), ('bodies/blob', 0),
                        ('joint_axes', 0)]
    assert all(m.header.frame_id == 'map' and m.header.stamp.nanosec == 5 for m in msg.markers)
    ball, can, blob, axis = msg.markers
    assert ball.type == Marker.SPHERE and (ball.scale.x, ball.scale.z) == (0.2, 0.2)
    assert can.type == Marker.CYLINDER and (can.scale.x, can.scale.y, can.scale.z) == \
        (0.1, 0.1, 0.3)
    np.testing.assert_allclose(_rot(can), Rotation.from_euler('xyz', [0.3, 0, 0]).as_matrix(),
                               atol=1e-12)
    # inertial: the box of equal inertia, at the COM: sides sqrt(6 (Ij + Ik - Ii) / m)
    assert blob.type == Marker.CUBE
    np.testing.assert_allclose(_pos(blob), [2.1, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(sorted([blob.scale.x, blob.scale.y, blob.scale.z]),
                               sorted(np.sqrt(6 * np.array([0.09, 0.03, 0.01]) / 2.0)),
                               rtol=1e-10)
    assert axis.type == Marker.ARROW
    np.testing.assert_allclose([[p.x, p.y, p.z] for p in axis.points], [[0.5, 0, 0],
                                                                         [0.5, 0, 1]])

    # Visuals (URDF): one marker per visual, meshes with their URI and scale, posed by the
    # body pose composed with the visual's origin.
    visuals = (VisualSpec('mesh', size=(0.001, 0.001, 0.001),
                          mesh_uri='package://robot/meshes/link.stl',
                          origin_xyz=(0.0, 0.2, 0.0), origin_rpy=(0.0, 0.0, 0.5)),
               VisualSpec('box', size=(0.1, 0.2, 0.3), rgba=(1.0, 0.0, 0.0, 0.5)))
    bodies = (dataclasses.replace(scene.bodies[0], visuals=visuals),) + scene.bodies[1:]
    scene2 = dataclasses.replace(scene, bodies=bodies)
    Rb = Rotation.from_euler('z', 0.7).as_matrix()
    pb = np.array([0.3, -0.2, 0.1])
    msg = MarkerBuilder(scene2).build(0, lambda n: (pb, Rb) if n == 'ball' else poses[n])
    mesh, box = msg.markers[0], msg.markers[1]
    assert (mesh.ns, mesh.id, box.ns, box.id) == ('bodies/ball', 0, 'bodies/ball', 1)
    assert mesh.type == Marker.MESH_RESOURCE
    assert mesh.mesh_resource == 'package://robot/meshes/link.stl'
    assert (mesh.scale.x, mesh.scale.y, mesh.scale.z) == (0.001, 0.001, 0.001)
    np.testing.assert_allclose(_pos(mesh), pb + Rb @ [0.0, 0.2, 0.0], atol=1e-12)
    np.testing.assert_allclose(_rot(mesh), Rotation.from_euler('z', 1.2).as_matrix(),
                               atol=1e-12)
    assert box.type == Marker.CUBE and (box.color.r, box.color.a) == (1.0, 0.5)
    assert mesh.header.frame_id == 'world'


# ---------------------------------------------------------------- a recorded run ----
def _poses_by_time(config_values: dict) -> dict:
    """body name -> pose at every step of the schedule, in a World stepped on its own."""
    from abd_joint_sim.tools.sim import HeadlessSim
    scene = Scene.from_yaml(resolve_scene('default'))
    sim = HeadlessSim(scene, config_from_values(config_values))
    out: dict[int, dict] = {}

    class Collect:
        def on_state(self, s, segment, force):
            out[s.time_ns] = {b: s.world.body_pose(b) for b in s.world.body_names}

        def on_applied(self, s, applied):
            pass

    sim.run(parse_schedule(SCHEDULE), Collect())
    return out


@pytest.mark.slow
def test_recorded_markers_follow_the_bodies(tmp_path):
    """run_headless's bag, read by rosbags: one marker per body at 30 Hz of simulated time,
    each posed as World.body_pose (nearest rotation, p) of an independently stepped world."""
    from rosbags.highlevel import AnyReader
    from abd_joint_sim.tools.sim import BagRecorder, HeadlessSim
    scene_path = resolve_scene('default')
    scene = Scene.from_yaml(scene_path)
    values = {'scene': 'default', 'marker_joint_axes': True}
    sim = HeadlessSim(scene, config_from_values(values))
    rec = BagRecorder(str(tmp_path / 'run'), sim, scene_path, scene.source_text)
    try:
        sim.run(parse_schedule(SCHEDULE), rec)
    finally:
        rec.close()
    truth = _poses_by_time(values)
    dt_ns = 1_000_000
    with AnyReader([tmp_path / 'run']) as reader:
        conns = [c for c in reader.connections if c.topic == '/markers']
        assert conns and conns[0].msgtype == 'visualization_msgs/msg/MarkerArray'
        seen = []
        for conn, t, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            seen.append(t)
            bodies = [m for m in msg.markers if m.ns.startswith('bodies/')]
            assert [m.ns for m in bodies] == [f'bodies/{b}' for b in scene.body_names]
            axes = [m for m in msg.markers if m.ns == 'joint_axes']
            assert [m.id for m in axes] == [0, 1]
            # The arrow (drawn from the parent) lies on the axis as the child carries it too:
            # the joint keeps both bodies' copies of P0 and P1 together.
            for m, joint in zip(axes, scene.joints):
                child = next(b for b in scene.bodies if b.name == joint.child)
                R0 = Rotation.from_euler('xyz', child.rpy).as_matrix()
                p, A = truth[t][joint.child]
                for point, P in zip(m.points, (joint.p0, joint.p1)):
                    via_child = A @ (R0.T @ (np.array(P) - child.position)) + p
                    np.testing.assert_allclose([point.x, point.y, point.z], via_child,
                                               atol=1e-5)
            for m in bodies:
                stamp = m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
                assert stamp == t and m.header.frame_id == 'world' and m.id == 0
                p, A = truth[t][m.ns.split('/', 1)[1]]
                np.testing.assert_allclose([m.pose.position.x, m.pose.position.y,
                                            m.pose.position.z], p, atol=1e-12)
                o = m.pose.orientation
                R = Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()
                np.testing.assert_allclose(R, polar(A)[0], atol=1e-9)
    # 30 Hz on the grid k/30 s: the first step at or after each grid point.
    expected = []
    for k in range(46):
        grid = -(-k * 10 ** 9 // 30)
        expected.append(-(-grid // dt_ns) * dt_ns)
    assert seen == expected[:len(seen)] and len(seen) == 46, seen[:5]
    # The bodies moved: the forearm turned by more than 0.5 rad over the run.
    A0, A1 = truth[0]['forearm'][1], truth[seen[-1]]['forearm'][1]
    assert np.arccos(np.clip((np.trace(polar(A0)[0].T @ polar(A1)[0]) - 1) / 2, -1, 1)) > 0.5


def test_marker_rate_zero_records_no_markers(tmp_path):
    from abd_joint_sim.record import read_messages
    from abd_joint_sim.tools.sim import BagRecorder, HeadlessSim
    scene_path = resolve_scene('hinge')
    scene = Scene.from_yaml(scene_path)
    sim = HeadlessSim(scene, config_from_values({'scene': 'hinge', 'marker_rate': 0.0}))
    rec = BagRecorder(str(tmp_path / 'off'), sim, scene_path, scene.source_text)
    sim.run(parse_schedule({'duration': 0.2, 'events': []}), rec)
    rec.close()
    assert not [t for t, *_ in read_messages(tmp_path / 'off') if t == '/markers']
    assert '/markers' not in (tmp_path / 'off' / 'metadata.yaml').read_text()


# --------------------------------------------------------------- the live node ----
@pytest.mark.slow
def test_markers_node(tmp_path):
    """sim_node (paused, hinge scene, torque 1000 N m) advanced by ~/step: every step
    publishes a MarkerArray (a forced publish) with one marker per body, posed as
    World.body_pose of a world stepped the same way, and records the same markers."""
    from std_msgs.msg import Float64
    from std_srvs.srv import Trigger
    from visualization_msgs.msg import MarkerArray
    from abd_joint_sim import World
    domain = next_domain_id()
    bag = tmp_path / 'live'
    node = NodeProcess.sim_node(tmp_path, domain, {
        'scene': 'hinge', 'start_paused': True, 'record': str(bag),
        'marker_frame_id': 'odom'})
    probe = Probe(domain)
    got: list = []
    steps = 8
    try:
        n = probe.node
        n.create_subscription(MarkerArray, '/markers', got.append, 10)
        torque = n.create_publisher(Float64, '/joint_torque/hinge', 10)
        probe.wait_matched_subscriber(torque, log=node)
        step = n.create_client(Trigger, '/abd_joint_sim/step')
        probe.wait_for(lambda: step.service_is_ready(), 30.0, 'the ~/step service', node)
        torque.publish(Float64(data=1000.0))
        probe.spin_for(1.0)     # delivered before the first step (it is paused)
        for _ in range(steps):
            assert probe.call(step, Trigger.Request(), log=node).success
        probe.wait_for(lambda: len([m for m in got if m.markers[0].header.stamp.nanosec
                                    or m.markers[0].header.stamp.sec]) >= steps, 20.0,
                       f'{steps} marker arrays', node)
        assert node.stop(signal.SIGINT) == 0, node.output()[-3000:]
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)
    world = World(Scene.from_yaml(resolve_scene('hinge')))
    world.set_torque('hinge', 1000.0)
    truth = {}
    for _ in range(steps):
        world.step()
        truth[round(world.time * 1e9)] = {b: world.body_pose(b) for b in world.body_names}
    live = {}
    for msg in got:
        stamp = msg.markers[0].header.stamp
        live[stamp.sec * 10 ** 9 + stamp.nanosec] = msg
    for t, poses in truth.items():
        msg = live[t]
        assert [(m.ns, m.id, m.header.frame_id) for m in msg.markers] == \
            [('bodies/base', 0, 'odom'), ('bodies/arm', 0, 'odom')]
        for m in msg.markers:
            p, A = poses[m.ns.split('/')[1]]
            np.testing.assert_allclose(_pos(m), p, atol=1e-9)
            np.testing.assert_allclose(_rot(m), polar(A)[0], atol=1e-7)
    # The arm turned (1000 N m on I = 24.7 kg m^2), so the check above is not trivial.
    assert np.linalg.norm(truth[max(truth)]['arm'][0] - [0.6, 0.0, 0.0]) > 1e-3
    # The bag, read by rosbags, holds the same markers at the same (log) times.
    from rosbags.highlevel import AnyReader

    def fields(m):
        return (m.ns, m.id, m.type, m.action, m.header.frame_id, m.header.stamp.sec,
                m.header.stamp.nanosec, m.pose.position.x, m.pose.position.y,
                m.pose.position.z, m.pose.orientation.x, m.pose.orientation.y,
                m.pose.orientation.z, m.pose.orientation.w, m.scale.x, m.scale.y, m.scale.z,
                round(m.color.r, 6), round(m.color.g, 6), round(m.color.b, 6),
                round(m.color.a, 6), m.mesh_resource)
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == '/markers']
        recorded = {t: reader.deserialize(raw, c.msgtype)
                    for c, t, raw in reader.messages(connections=conns)}
    for t in truth:
        assert [fields(a) for a in recorded[t].markers] == [fields(b) for b in live[t].markers]
    assert set(live) <= set(recorded)


@pytest.mark.slow
def test_markers_node_running_on_the_grid(tmp_path):
    """sim_node running as fast as possible (batched steps) records markers exactly at the
    first step at or after each k / marker_rate, posed as a World stepped on its own (the
    scene's initial torque drives the hinge, so no command timing is involved)."""
    from visualization_msgs.msg import MarkerArray
    from abd_joint_sim import World
    from abd_joint_sim.record import read_messages
    text = open(resolve_scene('hinge')).read().replace('torque: 0.0', 'torque: 100.0')
    assert 'torque: 100.0' in text
    scene_file = tmp_path / 'spin.yaml'
    scene_file.write_text(text)
    domain = next_domain_id()
    bag = tmp_path / 'spin'
    rate, dt = 25.0, 0.002
    node = NodeProcess.sim_node(tmp_path, domain, {
        'scene': str(scene_file), 'real_time_factor': 0.0, 'time_step': dt,
        'record': str(bag), 'marker_rate': rate})
    probe = Probe(domain)
    got: list = []
    try:
        probe.node.create_subscription(MarkerArray, '/markers', got.append, 100)
        probe.wait_for(lambda: any(m.markers[0].header.stamp.sec >= 2 for m in got), 60.0,
                       'markers of t >= 2 s', node)
        assert node.stop(signal.SIGINT) == 0, node.output()[-3000:]
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)
    recorded = [(t, m) for topic, _, t, m in read_messages(bag) if topic == '/markers']
    assert len(recorded) >= 2 * rate     # the probe saw t >= 2 s (SIGINT may beat the last)
    step_ns = round(dt * 1e9)
    expected = [-(-(-(-k * 10 ** 9 // round(rate))) // step_ns) * step_ns
                for k in range(len(recorded))]
    times = [t for t, _ in recorded]
    bad = next((k for k, (a, b) in enumerate(zip(times, expected)) if a != b), None)
    assert bad is None, (f'marker {bad} of {len(times)} recorded at {times[bad]} ns, expected '
                         f'{expected[bad]} ns; around it: {times[max(bad - 2, 0):bad + 3]}')
    world = World(Scene.from_yaml(scene_file), dt=dt)
    for t, msg in recorded:
        while round(world.time * 1e9) < t:
            world.step()
        assert round(world.time * 1e9) == t
        for m in msg.markers:
            p, A = world.body_pose(m.ns.split('/')[1])
            np.testing.assert_allclose(_pos(m), p, atol=1e-9)
            np.testing.assert_allclose(_rot(m), polar(A)[0], atol=1e-7)
    # the hinge did turn (the largest excursion: the spinning body passes its start again
    # every turn, so the last marker may be near it)
    assert max(np.linalg.norm(_pos(msg.markers[1]) - [0.6, 0, 0]) for _, msg in recorded) > 0.1


def test_marker_parameters_are_checked():
    from abd_joint_sim.ros.params import coerce
    with pytest.raises(ValueError, match="'marker_frame_id': empty"):
        config_from_values({'marker_frame_id': ' '})
    with pytest.raises(ValueError, match="'marker_rate'"):
        coerce('marker_rate', -1.0)
    with pytest.raises(ValueError, match="'marker_joint_axes'"):
        coerce('marker_joint_axes', 'yes')
    cfg = config_from_values({'marker_rate': 10})
    assert cfg.marker_rate == 10.0 and cfg.marker_frame_id == 'world'
    assert not cfg.marker_joint_axes


def test_run_headless_schedule_sets_marker_parameters(tmp_path):
    """A schedule's parameters reach the recorder: 10 Hz, frame 'odom', joint axes."""
    import yaml
    from abd_joint_sim.record import read_messages
    from abd_joint_sim.tools.run_headless import main
    schedule = tmp_path / 's.yaml'
    schedule.write_text(yaml.safe_dump({'duration': 0.5, 'parameters': {
        'marker_rate': 10.0, 'marker_frame_id': 'odom', 'marker_joint_axes': True},
        'events': [{'t': 0.0, 'torque': {'hinge': 100.0}}]}))
    assert main(['--schedule', str(schedule), '--scene', 'hinge', '--out',
                 str(tmp_path / 'b'), '-q']) == 0
    arrays = [(t, m) for topic, _, t, m in read_messages(tmp_path / 'b') if topic == '/markers']
    assert [t for t, _ in arrays] == [k * 100_000_000 for k in range(6)]
    assert all(mk.header.frame_id == 'odom' for _, m in arrays for mk in m.markers)
    assert [mk.ns for mk in arrays[0][1].markers] == ['bodies/base', 'bodies/arm', 'joint_axes']


def test_non_finite_pose_gives_no_markers():
    scene = Scene.from_yaml(resolve_scene('hinge'))
    builder = MarkerBuilder(scene)
    good = {b.name: (np.array(b.position, float), np.eye(3)) for b in scene.bodies}
    assert builder.build(0, lambda n: good[n]) is not None
    bad = dict(good, arm=(np.array([np.nan, 0.0, 0.0]), np.eye(3)))
    assert builder.build(1, lambda n: bad[n]) is None
    inf = dict(good, arm=(np.zeros(3), np.full((3, 3), np.inf)))
    assert builder.build(2, lambda n: inf[n]) is None
