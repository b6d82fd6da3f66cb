"""UID 668 torque and the joint angle, against docs/physics.md "Joint angle" and "External joint torque (UID 668)" (virtual work, signs,
antisymmetry, enable gating, singular guard, multi-turn angle)."""
import numpy as np
import pytest
import scipy.linalg

from abd_joint_sim import Scene, World
from abd_joint_sim.geometry import skew

from physics_helpers import (box, hinge_dict, random_rotation, rotation_about, theta as joint_theta,
                             torque_axis, torque_force, world_from)



def _tilted_world(axis=(0.3, -0.5, 0.8), rpy_child=(0.4, -0.2, 1.1)):
    """A free pair with a skew axis and rotated bodies, so no basis is axis-aligned."""
    axis = np.array(axis) / np.linalg.norm(axis)
    c = np.array([0.1, 0.2, -0.1])
    d = dict(dt=0.005, bodies=[box('p', c - 0.25 * np.array([1, 0, 0]), rpy=[0.3, 0.2, -0.5]),
                               box('c', c + 0.25 * np.array([1, 0, 0]), rpy=list(rpy_child))],
             joints=[dict(name='j', parent='p', child='c', p0=list(c - 0.2 * axis), p1=list(c + 0.2 * axis),
                          external_torque=dict(torque=0.0, enabled=True))])
    return World(Scene.from_dict(d)), axis, c


@pytest.mark.parametrize('phi', [-3.0, -1.2, -0.1, 0.0, 0.4, 1.5, 3.1])
def test_rotating_child_by_phi_about_t_reads_phi(phi):
    w, axis, c = _tilted_world()
    q = w.state.q.copy()
    R = rotation_about(axis, phi)
    A = q[1, 3:12].reshape(3, 3)
    q[1, 3:12] = (R @ A).ravel()                      # rotate the child about +t by phi
    q[1, :3] = c + R @ (q[1, :3] - c)
    theta = joint_theta(w, q)
    assert theta == pytest.approx(phi, abs=1e-12)
    assert w.max_joint_separation() < 1e-12


def test_rotating_parent_by_phi_reads_minus_phi():
    w, axis, c = _tilted_world()
    q = w.state.q.copy()
    q[0, 3:12] = (rotation_about(axis, 0.7) @ q[0, 3:12].reshape(3, 3)).ravel()
    assert joint_theta(w, q) == pytest.approx(-0.7, abs=1e-12)


def test_generalized_force_does_virtual_work_tau_e_dot_domega():
    """F^A : δA = τ ê·δω for δA = [δω]x A, by finite differences of a rigid rotation, for
    rotated and for sheared (affine) A alike."""
    w, axis, _ = _tilted_world()
    rng = np.random.default_rng(4)
    tau = 7.5
    for shear in (0.0, 0.2):
        q = w.state.q.copy()
        for b in (0, 1):
            q[b, 3:12] = (random_rotation(rng) @ (np.eye(3) + shear * rng.normal(size=(3, 3)))).ravel()
        F, skipped = torque_force(w, q, [tau])
        assert skipped == []
        e_j = torque_axis(w, q)
        for b, e in ((0, -e_j), (1, e_j)):
            dw = rng.normal(size=3)
            eps = 1e-6
            A = q[b, 3:12].reshape(3, 3)
            K = skew(dw)                                    # [dw]x
            dA = (scipy.linalg.expm(eps * K) @ A - scipy.linalg.expm(-eps * K) @ A) / (2 * eps)
            work = float(F[b, 3:12] @ dA.ravel())
            assert work == pytest.approx(tau * float(e @ dw), rel=1e-7)
            assert not F[b, :3].any(), 'a pure torque has no translational part'


def test_torques_on_both_bodies_balance_and_follow_p0_to_p1():
    """Third law: turning both bodies together by δω (a rigid motion of the pair) does no
    work, F_i:δA_i + F_j:δA_j = 0, even when the bodies' raw axes differ (drift)."""
    w, axis, _ = _tilted_world()
    rng = np.random.default_rng(1)
    q = w.state.q.copy()
    q[:, 3:12] += 1e-3 * rng.normal(size=(2, 9))        # drift between the bodies' axes
    F, _ = torque_force(w, q, [3.0])
    for _ in range(3):
        K = skew(rng.normal(size=3))
        work = sum(float(F[b, 3:12] @ (K @ q[b, 3:12].reshape(3, 3)).ravel()) for b in (0, 1))
        one = abs(float(F[1, 3:12] @ (K @ q[1, 3:12].reshape(3, 3)).ravel()))
        assert abs(work) <= 1e-12 * max(one, 1.0) and one > 1e-3
    assert float(torque_axis(w, q) @ axis) > 0.999     # child axis along +t = p1 - p0


@pytest.mark.parametrize('integrator', ['bdf1', 'bdf2'])
@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_positive_torque_increases_the_angle(integrator, sign):
    w = world_from(hinge_dict(), integrator=integrator)
    w.set_torque('hinge', sign * 1000.0)
    w.step(5)
    assert np.sign(w.joint_angles()[0]) == sign and np.sign(w.joint_velocities()[0]) == sign
    assert w.applied_torques()[0] == sign * 1000.0


def test_free_pair_turns_child_positive_parent_negative():
    w, axis, c = _tilted_world()
    w.set_torque('j', 2.0)
    w.step(10)
    _, Ap = w.body_pose('p')
    _, Ac = w.body_pose('c')
    q0 = w.model.body_q0
    rot_p = Ap @ q0[0, 3:12].reshape(3, 3).T
    rot_c = Ac @ q0[1, 3:12].reshape(3, 3).T
    ang = lambda R: np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2
    assert ang(rot_c) @ axis > 0 > ang(rot_p) @ axis
    assert w.joint_angles()[0] > 0


def test_disabled_torque_does_nothing_and_reenabling_applies_current_value():
    w = world_from(hinge_dict())
    q0 = w.state.q.copy()
    w.set_torque('hinge', 500.0)
    w.set_torque_enabled('hinge', False)
    assert w.applied_torques()[0] == 0.0
    w.step(5)
    assert np.abs(w.state.q - q0).max() < 1e-12 and w.joint_angles()[0] == 0.0
    w.set_torque_enabled('hinge', True)
    w.step(5)
    ref = world_from(hinge_dict())
    ref.set_torque('hinge', 500.0)
    ref.step(5)
    assert w.joint_angles()[0] == pytest.approx(ref.joint_angles()[0], rel=1e-9)


def test_disabling_mid_run_stops_the_acceleration():
    w = world_from(hinge_dict(), dt=0.001)
    w.set_torque('hinge', 1000.0)
    w.step(50)
    w.set_torque_enabled('hinge', False)
    w.step(1)
    v1 = w.joint_velocities()[0]
    w.step(50)
    v2 = w.joint_velocities()[0]
    assert v1 > 1.0
    # Free spinning: without the torque it would have gained 50*h*alpha = 2 rad/s. What is
    # left is BDF1 damping and the elastic rebound of joint and body (well under 1 %).
    assert abs(v2 - v1) < 0.01 * v1


def test_singular_affine_matrix_gets_no_torque_and_is_reported():
    w = world_from(hinge_dict())
    w.set_torque('hinge', 10.0)
    q = w.state.q
    q[1, 3:12] = np.array([[1, 0, 0], [0, 1, 0], [1, 1e-8, 1e-8]]).ravel()   # rank ~2
    F, skipped = torque_force(w, q, [10.0])
    assert skipped == [1] and not F[1].any()
    report = w.step()
    assert any('near-singular' in m and "'arm'" in m for m in report.warnings)


def test_angle_is_multi_turn_and_continuous():
    w = world_from(hinge_dict(), dt=0.002)
    w.set_torque('hinge', 2000.0)
    angles = []
    while w.joint_angles()[0] < 3 * 2 * np.pi + 1.0:
        w.step()
        angles.append(w.joint_angles()[0])
        assert len(angles) < 5000
    steps = np.diff(angles)
    assert angles[-1] > 6 * np.pi and np.all(steps > 0) and steps.max() < 0.5
    # the wrapped angle of the final state agrees modulo 2 pi
    wrapped = joint_theta(w, w.state.q)
    assert np.remainder(angles[-1] - wrapped + np.pi, 2 * np.pi) - np.pi == pytest.approx(0.0, abs=1e-9)


def test_init_angle_offsets_the_reported_angle():
    d = hinge_dict()
    d['joints'][0]['init_angle'] = 0.5
    w = world_from(d)
    assert w.joint_angles()[0] == 0.5
    w.set_torque('hinge', 1000.0)
    w.step(5)
    ref = world_from(hinge_dict())
    ref.set_torque('hinge', 1000.0)
    ref.step(5)
    assert w.joint_angles()[0] == pytest.approx(0.5 + ref.joint_angles()[0], abs=1e-12)


def test_joint_velocity_is_the_derivative_of_the_angle():
    h = 0.001
    w = world_from(hinge_dict(), dt=h, newton=dict(velocity_tol=1e-4, transrate_tol=1e-4))
    w.set_torque('hinge', 1000.0)
    w.step(100)
    a0 = w.joint_angles()[0]
    w.step(1)
    # BDF1: v_n = (q_n - q_{n-1})/h, so dθ/dt = ∇θ·v_n is the backward difference + O(h θ'')
    backward = (w.joint_angles()[0] - a0) / h
    assert w.joint_velocities()[0] == pytest.approx(backward, abs=h * 40.4)


@pytest.mark.parametrize('spinning', ['arm', 'base'])
def test_a_body_given_a_velocity_reports_its_joint_rate_from_the_start(spinning):
    """A scene body set turning about the hinge at 2 rad/s: the joint velocity reads +2 (the
    arm) or −2 (the parent) at t = 0 and again after reset, as ∇θ·v of the initial bodies
    (it read 0 until the first step); bodies at rest read exactly 0."""
    d = hinge_dict()
    k, x = (1, 0.6) if spinning == 'arm' else (0, -0.6)
    d['bodies'][0]['fixed'] = False
    d['bodies'][k].update(angular_velocity=[0.0, 0.0, 2.0], velocity=[0.0, 2.0 * x, 0.0])
    w = world_from(d)
    expect = 2.0 if spinning == 'arm' else -2.0
    assert w.joint_velocities()[0] == pytest.approx(expect, rel=1e-12)
    w.step(3)
    w.reset()
    assert w.joint_velocities()[0] == pytest.approx(expect, rel=1e-12)
    assert world_from(hinge_dict()).joint_velocities()[0] == 0.0


def test_control_rejects_unknown_unactuated_and_non_finite():
    d = hinge_dict()
    d['bodies'].append(box('extra', (2.0, 0, 0)))
    d['joints'].append(dict(name='passive', parent='arm', child='extra', p0=[1.5, 0, 0], p1=[1.5, 0, 1]))
    w = world_from(d)
    with pytest.raises(KeyError, match='unknown joint'):
        w.set_torque('nope', 1.0)
    with pytest.raises(ValueError, match='not actuated'):
        w.set_torque('passive', 1.0)
    with pytest.raises(ValueError, match='not finite'):
        w.set_torque('hinge', float('nan'))
    assert w.actuated_joint_names == ('hinge',)


def test_effort_limit_clamps():
    d = hinge_dict()
    d['joints'][0]['external_torque']['effort_limit'] = 50.0
    w = world_from(d)
    assert w.set_torque('hinge', 80.0) == 50.0 and w.set_torque('hinge', -80.0) == -50.0


def _chain_with_limits():
    from abd_joint_sim.builders import chain_scene
    d = chain_scene(4, torque=0.0)
    d['joints'][1]['external_torque']['effort_limit'] = 0.5
    d['joints'][3]['external_torque']['effort_limit'] = 2.0
    del d['joints'][2]['external_torque']          # not actuated: set_torques skips it
    return d


def test_set_torques_does_what_set_torque_per_joint_does():
    """One array in actuated_joint_names order, clamped like set_torque; the same bits after
    steps as the same torques set joint by joint."""
    d = _chain_with_limits()
    a, b = world_from(d), world_from(d)
    assert a.actuated_joint_names == ('j1', 'j2', 'j4')
    for values in ([0.3, -0.9, 3.5], [-1.0, 0.2, -2.5], [0.0, -0.0, 1e-3]):
        expected = np.array([a.set_torque(j, v) for j, v in zip(a.actuated_joint_names, values)])
        got = b.set_torques(values)
        assert np.array_equal(got, expected) and np.array_equal(np.signbit(got), np.signbit(expected))
        assert np.array_equal(b.applied_torques(), a.applied_torques())
        a.step(5)
        b.step(5)
        assert np.array_equal(a.state.q, b.state.q)
    assert list(got) == [0.0, -0.0, 1e-3]
    clamped = b.set_torques(np.array([9.0, 9.0, 9.0]))
    assert list(clamped) == [9.0, 0.5, 2.0]
    clamped[:] = 0.0                                # a copy: the world's torques stay
    assert b.applied_torques()[[0, 1, 3]].tolist() == [9.0, 0.5, 2.0]
    # any array layout: a strided view, a read-only array, integers
    b.set_torques(np.arange(6.0)[::2])
    ro = np.array([0.1, 0.2, 0.3])
    ro.flags.writeable = False
    assert b.set_torques(ro).tolist() == [0.1, 0.2, 0.3]
    assert b.set_torques((1, 0, -1)).tolist() == [1.0, 0.0, -1.0]


@pytest.mark.parametrize('values, message', [
    ([0.1, 0.2], r"3 values expected \(one per actuated joint: j1, j2, j4\), got shape \(2,\)"),
    ([[0.1, 0.2, 0.3]], r'got shape \(1, 3\)'),
    (0.5, r'got shape \(\)'),
    ([0.1, float('nan'), 0.3], r"joint 'j2': torque nan is not finite; rejected \(no torque changed\)"),
    ([0.1, 0.2, -float('inf')], r"joint 'j4': torque -inf is not finite"),
    (['a', 0.2, 0.3], r'values must be 3 numbers'),
    ({'j1': 1.0}, r'values must be 3 numbers'),
])
def test_set_torques_refuses_bad_input_with_one_message_and_changes_nothing(values, message):
    w = world_from(_chain_with_limits())
    w.set_torques([0.25, -0.25, 0.5])
    before = w.applied_torques()
    with pytest.raises(ValueError, match=message):
        w.set_torques(values)
    assert np.array_equal(w.applied_torques(), before)


def _driven_hinge():
    d = hinge_dict()
    d['joints'][0]['driving'] = dict(strength_ratio=100.0, aim_angle=0.0, passive=False, enabled=False)
    return world_from(d)


@pytest.mark.parametrize('call, message', [
    (lambda w: w.set_torque('hinge', 10 ** 400), r"joint 'hinge': torque 1000.* is not a number; rejected"),
    (lambda w: w.set_torque('hinge', 'x'), r"joint 'hinge': torque 'x' is not a number"),
    (lambda w: w.set_torque('hinge', None), r"joint 'hinge': torque None is not a number"),
    (lambda w: w.set_torque_enabled('hinge', 'no'), r"joint 'hinge': enabled must be True or False, got 'no'"),
    (lambda w: w.set_torque_enabled('hinge', 2), r"enabled must be True or False, got 2"),
    (lambda w: w.set_torque_enabled('hinge', None), r"enabled must be True or False, got None"),
    (lambda w: w.set_drive('hinge', aim='up'), r"joint 'hinge': aim angle 'up' is not a number"),
    (lambda w: w.set_drive('hinge', aim=1e300), r"joint 'hinge': aim angle 1e\+300 rad is outside the supported range \|aim\| <= 10000 rad"),
    (lambda w: w.set_drive('hinge', aim=0.3, enabled='yes'), r"enabled must be True or False, got 'yes'"),
    (lambda w: w.set_drive('hinge', aim=0.3, passive=0.5), r"passive must be True or False, got 0.5"),
    (lambda w: w.step(1.5), r'step: n must be a whole number of steps ≥ 0, got 1.5'),
    (lambda w: w.step(-1), r'got -1'),
    (lambda w: w.step('5'), r"got '5'"),
    (lambda w: w.step(float('nan')), r'got nan'),
    (lambda w: w.step(None), r'got None'),
])
def test_world_commands_refuse_what_is_not_a_number_or_flag_and_change_nothing(call, message):
    """One ValueError naming the joint and the value, nothing changed: no OverflowError
    traceback for an absurd integer, no bool('no') == True, no 1.5 steps truncated to one."""
    w = _driven_hinge()
    w.set_torque('hinge', 0.25)
    w.step(2)
    before = (w.applied_torques().copy(), w.control.torque_enabled.copy(), w.control.drive_aim.copy(),
              w.control.drive_enabled.copy(), w.control.drive_passive.copy(), w.time)
    with pytest.raises(ValueError, match=message):
        call(w)
    after = (w.applied_torques(), w.control.torque_enabled, w.control.drive_aim, w.control.drive_enabled,
             w.control.drive_passive, w.time)
    for a, b in zip(before, after):
        assert np.array_equal(a, b)


def test_world_commands_take_numpy_scalars_and_whole_floats():
    w = _driven_hinge()
    w.set_torque_enabled('hinge', np.bool_(False))
    assert not w.torque_enabled('hinge')
    w.set_torque_enabled('hinge', 1)
    assert w.torque_enabled('hinge')
    w.set_drive('hinge', aim=np.float32(0.5), enabled=np.bool_(True), passive=0)
    assert w.control.drive_aim[0] == 0.5 and w.control.drive_enabled[0] and not w.control.drive_passive[0]
    w.step(2.0)
    w.step(np.int64(3))
    w.step(True)
    assert w.state.step_count == 6 and w.time == pytest.approx(6 * w.dt)
    assert w.step(0) is w.last_step and w.state.step_count == 6
