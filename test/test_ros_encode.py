"""sim_node's messages as CDR bytes packed from a template: the bytes the
node publishes and records for /joint_states and the body markers must be exactly what
rclpy's serializer makes of the same message (alignment padding aside, which rclpy leaves
unset), decode to the same values in rclpy and in rosbags (an independent CDR
implementation), and the packed path must be able to fail its own check."""
from __future__ import annotations

import math
import os
import struct

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import get_typestore, Stores
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from abd_joint_sim import Scene, World
from abd_joint_sim.record import cdr
from abd_joint_sim.ros import convert
from abd_joint_sim.ros.markers import MarkerBuilder
from physics_helpers import nearest_rotations, quaternion

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STORE = get_typestore(Stores.ROS2_JAZZY)
NAMES = ([], ['hinge'], ['a', 'bb'], ['shoulder', 'elbow', 'wrist_ü'],
         [f'lbr_iiwa_joint_{k}' for k in range(1, 8)])


def _states(n: int, rng) -> list[tuple[int, list, list, list]]:
    special = [0.0, -0.0, 1e-310, -1e308, 1e308, math.pi, 5e-324]
    out = [(0, [0.0] * n, [0.0] * n, [0.0] * n),
           ((2 ** 31 - 1) * 10 ** 9 + 999_999_999, [special[k % 7] for k in range(n)],
            [special[(k + 3) % 7] for k in range(n)], [special[(k + 5) % 7] for k in range(n)])]
    for k in range(40):
        ns = convert.seconds_to_ns(k * 0.0137)
        out.append((ns, *(rng.normal(scale=10.0 ** rng.integers(-8, 8), size=(3, n)).tolist())))
    return out


@pytest.mark.parametrize('frame_id', ['', 'base', 'ab', 'wörld'])
def test_joint_state_encoder_gives_rclpys_bytes(frame_id):
    rng = np.random.default_rng(7)
    for names in NAMES:
        enc = convert.JointStateEncoder(names, frame_id)
        assert enc.checked, (names, frame_id)
        for ns, p, v, e in _states(len(names), rng):
            raw = enc.encode(ns, p, v, e)
            msg = convert.joint_state_msg(ns, names, p, v, e, frame_id)
            assert raw == cdr.without_padding(serialize_message(msg), msg), (names, ns)
            assert deserialize_message(raw, JointState) == msg
            theirs = STORE.deserialize_cdr(raw, 'sensor_msgs/msg/JointState')
            assert list(theirs.name) == names and theirs.header.frame_id == frame_id
            assert (theirs.header.stamp.sec * 10 ** 9 + theirs.header.stamp.nanosec) == ns
            for mine, other in ((p, theirs.position), (v, theirs.velocity),
                                (e, theirs.effort)):
                assert [struct.pack('<d', x) for x in mine] == \
                    [struct.pack('<d', x) for x in other]           # bit for bit, -0.0 too
        with pytest.raises(ValueError, match='differ in length'):
            enc.encode(0, [0.0] * (len(names) + 1), [0.0] * len(names), [0.0] * len(names))


def test_joint_state_encoder_check_can_fail_and_falls_back():
    enc = convert.JointStateEncoder(['a', 'b'], 'base')
    head = enc._template._args[0]                       # the constant bytes before the stamp
    enc._template._args[0] = head[:-1] + b'\x07'        # a wrong constant byte
    state = (0, [1.0, 2.0], [3.0, 4.0], [5.0, 6.0])
    assert enc._pack(*state) != enc._serialize(*state)
    enc.checked = False                                 # what __init__ decides on a mismatch
    msg = convert.joint_state_msg(*state[:1], ['a', 'b'], *state[1:], 'base')
    assert enc.encode(*state) == cdr.without_padding(serialize_message(msg), msg)


def test_template_packs_fields_in_stream_order_and_refuses_overlaps():
    """cdr.Template: fields given in any order land at their offsets; a field whose code
    reaches into the next is refused."""
    msg = convert.joint_state_msg(0, ['a', 'b'], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 'f')
    template = cdr.Template(msg, [(('effort',), '2d'), (('header', 'stamp', 'sec'), 'iI')])
    filled = convert.joint_state_msg(3 * 10 ** 9 + 4, ['a', 'b'], [0.0, 0.0], [0.0, 0.0],
                                     [5.0, -6.0], 'f')
    assert template.pack([5.0, -6.0], (3, 4)) == cdr.serialized(filled)
    assert template.matches([(([5.0, -6.0], (3, 4)), filled)])
    assert not template.matches([(([5.0, -6.0], (3, 5)), filled)])
    with pytest.raises(ValueError, match='overlaps'):
        cdr.Template(msg, [(('position',), '4d'), (('velocity',), '2d')])


def test_field_offsets_and_padding_against_rosbags():
    """The offsets of cdr.field_offsets hold the fields' values; without_padding only zeroes
    bytes that are padding (rosbags decodes the result to the same message, and serialises
    it back to the same bytes: its serializer writes zero padding)."""
    msg = convert.joint_state_msg(1_500_000_003, ['a', 'bbb', 'cc'], [0.1, -0.2, 0.3],
                                  [1.0, 2.0, 3.0], [-4.0, 5.0, 6.5], 'f')
    raw = cdr.without_padding(serialize_message(msg), msg)
    off = cdr.field_offsets(msg)
    assert struct.unpack_from('<iI', raw, off[('header', 'stamp', 'sec')]) == (1, 500_000_003)
    for attr in ('position', 'velocity', 'effort'):
        assert list(struct.unpack_from('<3d', raw, off[(attr,)])) == list(getattr(msg, attr))
    theirs = STORE.serialize_cdr(STORE.deserialize_cdr(raw, 'sensor_msgs/msg/JointState'),
                                 'sensor_msgs/msg/JointState')
    assert bytes(theirs) == raw


def _scenes():
    import pybullet_data
    kuka = os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa', 'model.urdf')
    return [Scene.from_file(os.path.join(REPO, 'abd_joint_sim', 'scenes', 'default.yaml')),
            Scene.from_urdf(os.path.join(REPO, 'abd_joint_sim', 'robots', 'demo_arm.urdf')),
            Scene.from_urdf(kuka)]


@pytest.mark.slow
@pytest.mark.parametrize('axes', [False, True])
def test_marker_bytes_are_rclpys_bytes_of_the_built_markers(axes):
    """build_serialized against serialize_message(build()) of a second builder, over a
    swinging run of each scene (every body pose and arrow moves), and decoded by rosbags."""
    for scene in _scenes():
        world = World(scene)
        for k, joint in enumerate(world.actuated_joint_names):
            world.set_torque(joint, (-1) ** k * 2.0)
        packed, built = MarkerBuilder(scene, 'world', axes), MarkerBuilder(scene, 'map', axes)
        built.frame_id = packed.frame_id = 'world'
        for k in range(25):
            world.step(7)
            ns = convert.seconds_to_ns(world.time)
            raw = packed.build_serialized(ns, world.body_pose)
            msg = built.build(ns, world.body_pose)
            assert raw == cdr.without_padding(serialize_message(msg), msg), (scene.name, k)
            # (against a decoded copy: the colours are float32, msg holds them as given)
            assert deserialize_message(raw, MarkerArray) == \
                deserialize_message(serialize_message(msg), MarkerArray)
        assert packed._packed_ok
        theirs = STORE.deserialize_cdr(raw, 'visualization_msgs/msg/MarkerArray')
        for m, t in zip(msg.markers, theirs.markers):
            assert (t.pose.position.x, t.pose.orientation.w, t.header.stamp.nanosec) == \
                (m.pose.position.x, m.pose.orientation.w, m.header.stamp.nanosec)
        # A pose that is not finite: nothing, as build() gives None.
        assert packed.build_serialized(0, lambda n: (np.full(3, np.nan), np.eye(3))) is None


def test_marker_bytes_fall_back_when_the_check_fails():
    scene = _scenes()[0]
    world = World(scene)
    builder = MarkerBuilder(scene)
    builder.build_serialized(0, world.body_pose)
    builder._packed_ok = False                  # what the first call decides on a mismatch
    world.step(5)
    raw = builder.build_serialized(5, world.body_pose)
    msg = MarkerBuilder(scene).build(5, world.body_pose)
    assert raw == cdr.without_padding(serialize_message(msg), msg)
    # ... and the check itself can fail: a pose packed one field off lands in other bytes.
    path = ('markers', 0, 'pose', 'position')
    right = cdr.Template(msg, [(path + ('x',), '7d')])
    wrong = cdr.Template(msg, [(path + ('y',), '7d')])
    pose = msg.markers[0].pose
    pose.position.x, pose.position.y, pose.position.z = 1.0, 2.0, 3.0
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = 0, 0, 0, 1.0
    values = [(1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0)]
    assert right.matches([(values, msg)]) and not wrong.matches([(values, msg)])


def _quaternion_reference(R):
    """The previous implementation (numpy scalars, np.argmax), kept to prove the plain-float
    one gives the very same bits."""
    R = np.asarray(R, dtype=float)
    t = R[0, 0] + R[1, 1] + R[2, 2]
    k = int(np.argmax([t, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + t)
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, \
            (R[1, 0] - R[0, 1]) / s
    elif k == 1:
        s = 2.0 * math.sqrt(max(1.0 + R[0, 0] - R[1, 1] - R[2, 2], 1e-300))
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, \
            (R[0, 2] + R[2, 0]) / s
    elif k == 2:
        s = 2.0 * math.sqrt(max(1.0 + R[1, 1] - R[0, 0] - R[2, 2], 1e-300))
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, \
            (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(max(1.0 + R[2, 2] - R[0, 0] - R[1, 1], 1e-300))
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, \
            (R[1, 2] + R[2, 1]) / s, 0.25 * s
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    return float(x), float(y), float(z), float(w)


def test_quaternion_bits_unchanged():
    rng = np.random.default_rng(3)
    Rs = list(nearest_rotations(rng.normal(size=(3000, 3, 3))))
    Rs += [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]),
           np.diag([-1.0, -1.0, 1.0])]           # ties and each of the four branches
    branches = set()
    for R in Rs:
        assert quaternion(R) == _quaternion_reference(R)
        t = np.trace(R)
        branches.add(int(np.argmax([t, R[0, 0], R[1, 1], R[2, 2]])))
    assert branches == {0, 1, 2, 3}
