"""The prismatic family (terms/prismatic*.py: UID 20, 21, 667, 669): energies against the
independent oracle (test/oracle.py), derivatives against finite differences with the checker
of test_terms.py (and broken variants it must catch), the distance and its rate, the force
against the oracle, and the physics against closed forms (docs/physics.md "Analytic
references"): a slider under a constant force, the reduced mass of a free pair, polarity,
momentum, a slider on its drive, a limit, the separation under load."""
import math

import numpy as np
import pytest

import oracle
from abd_joint_sim import Scene, World, compile_scene
from abd_joint_sim.errors import SceneError
from abd_joint_sim.solver import model_data
from abd_joint_sim.terms import angle as angles
from abd_joint_sim.terms import (prismatic, prismatic_damping, prismatic_driving,
                                 prismatic_limit)
from abd_joint_sim.terms import reference_shape
from abd_joint_sim.terms.context import StepContext

from physics_helpers import box, prismatic_distance, prismatic_generalized_force, random_rotation
from test_terms import check_term, dense

TERMS = {'prismatic': prismatic, 'prismatic_driving': prismatic_driving, 'prismatic_limit': prismatic_limit,
         'prismatic_damping': prismatic_damping}


def _scene(**slide):
    """A fixed base c, a hinge c → a, a slide a → b along +x with `slide`'s extras, and a
    locked slide c → b (zero-width limit)."""
    d = dict(dt=0.01, bodies=[box('a', (0, 0, 0)), box('b', (0.5, 0.1, 0.0)), box('c', (1.0, 0, 0), fixed=True)],
             joints=[dict(name='hinge', parent='c', child='a', p0=[0.5, 0, 0], p1=[0.5, 0, 1]),
                     dict(name='slide', type='prismatic', parent='a', child='b', p0=[0.25, 0.05, 0.0],
                          p1=[0.75, 0.05, 0.1], init_distance=0.05,
                          external_force=dict(force=2.0, enabled=True),
                          driving=dict(aim_distance=0.2, enabled=True, strength_ratio=50.0),
                          limit=dict(lower=0.04, upper=0.06, strength=3.0), damping=30.0, **slide),
                     dict(name='lock', type='prismatic', parent='c', child='b', p0=[0.8, 0, 0],
                          p1=[0.8, 1, 0], limit=dict(lower=0.0, upper=0.0))])
    return Scene.from_dict(d)


MODEL = compile_scene(_scene())
DATA = model_data.build(MODEL)


def _state(seed, scale=0.15):
    """A generic state: rotated, sheared and displaced free bodies."""
    rng = np.random.default_rng(seed)
    q = MODEL.body_q0.copy()
    for b in np.flatnonzero(~MODEL.body_fixed):
        A = random_rotation(rng) @ (np.eye(3) + scale * rng.normal(size=(3, 3)))
        q[b, 3:12] = A.ravel()
        q[b, :3] += 0.05 * rng.normal(size=3)
    return q


TARGETS = np.array([0.13])      # UID 21 target d̃ (relative to init_distance)
START = np.array([0.0, 0.02, -0.01])    # joint positions at the step's start (relative)
Q_PREV = _state(99, scale=0.1)          # the bodies one step back (BDF2 damping)


def _ctx(on=True):
    J, D = MODEL.joint_count, len(MODEL.drive_joints) + len(MODEL.prismatic_drive_joints)
    assert D == 1
    ref = prismatic_damping.references(DATA, MODEL.body_q0, Q_PREV, START, 0.01, True,
                                       np.empty(angles.ANGLE_WORK_SHAPE), np.zeros(reference_shape(MODEL)))
    return StepContext(0.01, 1.0, MODEL.body_q0.copy(), START.copy(), TARGETS.copy(), np.full(D, on),
                       np.empty(angles.ANGLE_WORK_SHAPE), ref)


def _oracle(name, q):
    if name == 'prismatic':
        return oracle.prismatic_energy(MODEL, q)
    if name == 'prismatic_driving':
        return oracle.prismatic_driving_energy(MODEL, q, TARGETS, [True])
    if name == 'prismatic_damping':
        return oracle.prismatic_damping_energy(MODEL, q, Q_PREV, START, 0.01, True)
    return oracle.prismatic_limit_energy(MODEL, q)


# -- the terms ------------------------------------------------------------------------------
@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize('name', list(TERMS))
def test_energy_matches_the_oracle(name, seed):
    q = _state(seed)
    E = TERMS[name].energy(q, DATA, _ctx())
    ref = _oracle(name, q)
    assert ref > 0.0, 'the state must activate the term'
    assert E == pytest.approx(ref, rel=1e-12)


@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize('name', list(TERMS))
def test_derivatives_match_finite_differences(name, seed):
    E = check_term(TERMS[name], _state(seed), _ctx(), name=name, model=MODEL, data=DATA)
    assert E > 0.0


@pytest.mark.parametrize('project', [False, True])
@pytest.mark.parametrize('name', list(TERMS))
def test_accumulate_returns_the_bits_of_the_energy(name, project):
    B, J = MODEL.body_count, MODEL.joint_count
    for seed in range(10):
        q = _state(seed)
        E = TERMS[name].energy(q, DATA, _ctx())
        got = TERMS[name].accumulate(q, DATA, _ctx(), np.zeros((B, 12)), np.zeros((B, 12, 12)),
                                     np.zeros((J, 12, 12)), project)
        assert got == E > 0.0


def test_projected_hessians_are_the_gauss_newton_part():
    """Newton's Hessian of UID 20 is K Σ ∇C_kᵀ∇C_k: PSD, and the whole Hessian where the
    joint holds (C = 0, the initial pose moved rigidly)."""
    q = _state(4, scale=0.4)
    for term in TERMS.values():
        _, _, H = dense(term, q, _ctx(), True, MODEL, DATA)
        assert np.linalg.eigvalsh(H).min() > -1e-9 * np.abs(H).max()
    rng = np.random.default_rng(3)
    q = MODEL.body_q0.copy()
    R = random_rotation(rng)
    for b in range(MODEL.body_count):       # every body (fixed too) turned and moved alike
        q[b, :3] = R @ q[b, :3] + 0.3
        q[b, 3:12] = (R @ q[b, 3:12].reshape(3, 3)).ravel()
    _, _, Hraw = dense(prismatic, q, _ctx(), False, MODEL, DATA)
    _, _, Hp = dense(prismatic, q, _ctx(), True, MODEL, DATA)
    assert prismatic.energy(q, DATA, _ctx()) < 1e-25
    np.testing.assert_allclose(Hp, Hraw, atol=1e-9 * np.abs(Hraw).max())


def test_disabled_drive_contributes_nothing():
    E, g, H = dense(prismatic_driving, _state(3), _ctx(on=False), True, MODEL, DATA)
    assert E == 0.0 and not g.any() and not H.any()


class _Broken:
    """A prismatic term with one deliberate mistake: `curvature` drops the K C·∇²C part of the
    raw Hessian (the Gauss-Newton matrix passed off as the whole one), `sign` the limit's
    gradient on the child with the wrong sign."""

    def __init__(self, term, mode):
        self.term, self.mode = term, mode
        self.energy = term.energy

    def accumulate(self, q, data, ctx, grad, diag, pair, project):
        if self.mode == 'curvature':
            return self.term.accumulate(q, data, ctx, grad, diag, pair, True)
        E = self.term.accumulate(q, data, ctx, grad, diag, pair, project)
        b = MODEL.joint_child[MODEL.prismatic_limit_joints[0]]
        grad[b] *= -1.0
        return E


@pytest.mark.parametrize('term,mode,message', [(prismatic, 'curvature', 'Hessian disagrees'),
                                               (prismatic_driving, 'curvature', 'Hessian disagrees'),
                                               (prismatic_limit, 'sign', 'gradient disagrees')])
def test_the_checker_catches_broken_prismatic_terms(term, mode, message):
    with pytest.raises(ValueError, match=message):
        check_term(_Broken(term, mode), _state(0), _ctx(), model=MODEL, data=DATA)


def test_distance_matches_the_oracle_and_its_rate_is_the_derivative():
    rng = np.random.default_rng(2)
    parent, child, fr = DATA.joint_parent, DATA.joint_child, DATA.prismatic_frame
    for seed in range(4):
        q = _state(seed, 0.3)
        v = rng.normal(size=q.shape)
        for j in MODEL.prismatic_joints:
            k = DATA.prismatic_slot[j]
            d = prismatic_distance(q, DATA, j)
            assert d == pytest.approx(oracle.prismatic_distance(MODEL, q, j), abs=1e-14)
            d2, rate = prismatic.distance_and_rate(q, v, parent[j], child[j], fr, k, np.empty((16, 3)))
            eps = 1e-6
            fd = (prismatic_distance(q + eps * v, DATA, j) - prismatic_distance(q - eps * v, DATA, j)) / (2 * eps)
            assert d2 == d and rate == pytest.approx(fd, rel=1e-7, abs=1e-9)
    assert list(DATA.prismatic_slot) == [-1, 0, 1]


def test_force_matches_the_oracle_and_is_antisymmetric():
    T = len(MODEL.torque_joints)
    for seed in range(3):
        q = _state(seed)
        values, on = np.array([2.5]), np.ones(1, bool)
        F = np.zeros((MODEL.body_count, 12))
        prismatic_generalized_force(q, DATA, np.r_[np.zeros(T), values], np.r_[np.zeros(T, bool), on], F)
        np.testing.assert_allclose(F, oracle.prismatic_force(MODEL, q, values), rtol=1e-12, atol=1e-14)
        a, b = MODEL.joint_parent[1], MODEL.joint_child[1]
        assert np.array_equal(F[a, :3], -F[b, :3]) and F[b, :3].any()       # exactly antisymmetric
    # disabled or zero: nothing
    F = np.zeros((MODEL.body_count, 12))
    prismatic_generalized_force(_state(0), DATA, np.array([2.5]), np.zeros(1, bool), F)
    assert not F.any()


# -- physics against closed forms --------------------------------------------------------
def _slider(force=None, fixed_parent=True, density=(1000.0, 1000.0), integrator='bdf1', dt=0.01,
            offset=0.0, gravity=(0.0, 0.0, 0.0), **joint):
    """Two 0.4 m cubes on the x axis, a prismatic joint along +x (its axis `offset` off the
    cubes' centres in y), no gravity unless given."""
    j = dict(name='slide', type='prismatic', parent='base', child='cart', p0=[0.3, offset, 0.0],
             p1=[1.3, offset, 0.0], **joint)
    if force is not None:
        j['external_force'] = dict(force=force, enabled=True)
    return World(Scene.from_dict(dict(
        dt=dt, integrator=integrator, gravity=list(gravity),
        bodies=[dict(box('base', (0, 0, 0), fixed=fixed_parent), density=density[0]),
                dict(box('cart', (0.6, 0, 0)), density=density[1])],
        joints=[j])))


def _box_mass(density):
    return density * 0.4 ** 3


@pytest.mark.parametrize('integrator', ['bdf1', 'bdf2'])
def test_constant_force_on_a_fixed_parent_is_f_t2_over_2m(integrator):
    """d(t) = f t²/(2m), m the child's mass: BDF1 adds its first-order ½ a h t."""
    f, h = 32.0, 0.01
    w = _slider(f, integrator=integrator, dt=h)
    a = f / _box_mass(1000.0)                        # 0.5 m/s²
    w.step(50)
    t = w.time
    d, v = w.joint_positions()[0], w.joint_velocities()[0]
    exact = 0.5 * a * t * t
    expect = exact + (0.5 * a * h * t if integrator == 'bdf1' else 0.0)
    assert d == pytest.approx(expect, rel=1e-3)
    assert v == pytest.approx(a * t, rel=1e-3)
    if integrator == 'bdf2':
        assert abs(d - exact) < 0.1 * 0.5 * a * h * t        # second order


def test_free_pair_slides_with_the_reduced_mass_and_keeps_its_momentum():
    """Free bodies of masses m1, m2: d̈ = f (1/m1 + 1/m2) = f/m_red; linear and angular
    momentum stay zero (the forces are collinear: the axis is off the centres)."""
    f, h = 20.0, 0.01
    m1, m2 = _box_mass(500.0), _box_mass(2000.0)
    w = _slider(f, fixed_parent=False, density=(500.0, 2000.0), integrator='bdf2', offset=0.1)
    w.step(40)
    t = w.time
    a = f * (1 / m1 + 1 / m2)
    assert w.joint_positions()[0] == pytest.approx(0.5 * a * t * t, rel=2e-3)
    assert w.joint_velocities()[0] == pytest.approx(a * t, rel=2e-3)
    linear, angular = w.momentum()
    assert np.abs(linear).max() < 1e-9 * f * t and np.abs(angular).max() < 1e-8 * f * t
    # each body moves as f/m along the axis, opposite ways
    p_base, _ = w.body_pose('base')
    p_cart, _ = w.body_pose('cart')
    assert p_base[0] == pytest.approx(-0.5 * f / m1 * t * t, rel=5e-3)
    assert p_cart[0] - 0.6 == pytest.approx(0.5 * f / m2 * t * t, rel=5e-3)


@pytest.mark.parametrize('f', [10.0, -10.0])
def test_polarity_positive_force_increases_the_distance(f):
    """A positive f pushes the child along +t (p0 → p1) relative to the parent; the axis
    reversed (p1 → p0) reverses the motion the same force makes."""
    w = _slider(f)
    w.step(10)
    d = w.joint_positions()[0]
    assert np.sign(d) == np.sign(f) and w.body_pose('cart')[0][0] - 0.6 == pytest.approx(d, rel=1e-3)
    back = World(Scene.from_dict(dict(dt=0.01, bodies=[box('base', (0, 0, 0), fixed=True), box('cart', (0.6, 0, 0))],
                                      joints=[dict(name='slide', type='prismatic', parent='base', child='cart',
                                                   p0=[1.3, 0, 0], p1=[0.3, 0, 0],
                                                   external_force=dict(force=f, enabled=True))])))
    back.step(10)
    assert back.joint_positions()[0] == pytest.approx(d, rel=1e-3)
    assert back.body_pose('cart')[0][0] - 0.6 == pytest.approx(-d, rel=1e-3)


def test_a_slider_on_its_drive_oscillates_with_the_spring_period():
    """UID 21 on a fixed parent: E ≈ K (d − d̃)² (two equal terms), a spring of k = 2K/h²
    [N/m], K = γ (m_i + m_j): period 2π sqrt(m/k), m the child's mass (BDF2, 300+ steps per
    period)."""
    h, gamma = 0.01, 1e-4
    w = _slider(None, integrator='bdf2', dt=h, driving=dict(aim_distance=0.05, enabled=True, strength_ratio=gamma))
    m = _box_mass(1000.0)
    k = 2 * gamma * (m + m) / h ** 2                        # the fixed base's mass counts in K
    period = 2 * math.pi * math.sqrt(m / k)
    d, times = [], []
    for _ in range(int(2.2 * period / h)):
        w.step()
        d.append(w.joint_positions()[0] - 0.05)
        times.append(w.time)
    d = np.array(d)
    ups = [times[i] - h * d[i] / (d[i] - d[i - 1]) for i in range(1, len(d)) if d[i - 1] < 0 <= d[i]]
    assert len(ups) >= 2
    assert ups[1] - ups[0] == pytest.approx(period, rel=1e-2)
    assert d.min() == pytest.approx(-0.05, rel=0.05)        # from rest at 0: amplitude 0.05 m


def test_limit_stops_the_slide_and_separation_is_reported():
    """A force against the upper bound under gravity across the axis: the slide stops there
    (the cubic barrier lets it in by a little), the joint carries the cart's weight (its
    separation reported: the weight over the joint's stiffness, far below the warning)."""
    w = _slider(40.0, limit=dict(lower=-0.1, upper=0.05, strength=10.0), gravity=(0, 0, -9.81))
    w.step(200)
    d = w.joint_positions()[0]
    assert 0.05 < d < 0.07 and abs(w.joint_velocities()[0]) < 0.05
    sep = w.last_step.max_joint_separation
    assert sep == w.max_joint_separation()
    assert 0.0 < sep < prismatic.SEPARATION_WARN * 0.4
    assert not w.last_step.warnings


@pytest.mark.parametrize('integrator', ['bdf1', 'bdf2'])
def test_damped_slider_approaches_the_terminal_velocity(integrator):
    """Joint damping c [N s/m] under a constant force f, fixed parent: ḋ = (f/c)(1 − e^(−ct/m)),
    d = (f/c)(t − (m/c)(1 − e^(−ct/m))) (BDF2: within 0.5 %; BDF1 first order)."""
    f, c, h = 20.0, 40.0, 5e-3
    w = _slider(f, integrator=integrator, dt=h, damping=c)
    m = _box_mass(1000.0)
    w.step(400)                                       # 2 s, 1.25 time constants
    t = w.time
    v = f / c * (1 - math.exp(-c * t / m))
    d = f / c * (t - m / c * (1 - math.exp(-c * t / m)))
    rtol = 5e-3 if integrator == 'bdf2' else 2e-2
    assert w.joint_velocities()[0] == pytest.approx(v, rel=rtol)
    assert w.joint_positions()[0] == pytest.approx(d, rel=rtol)
    assert 'prismatic_damping' in w.terms


def test_init_distance_offsets_what_is_reported_and_the_bounds():
    w = _slider(None, init_distance=0.3, limit=dict(lower=0.2, upper=0.4),
                driving=dict(aim_distance=0.35, enabled=True))
    assert w.joint_positions()[0] == 0.3
    w.step(100)
    assert w.joint_positions()[0] == pytest.approx(0.35, abs=2e-3)
    w.set_drive('slide', aim=0.5)                     # beyond the upper limit: held near it
    w.step(200)
    assert 0.4 < w.joint_positions()[0] < 0.5


# -- terms a scene uses, scene format, API ----------------------------------------------
def test_terms_are_assembled_only_where_a_scene_has_them():
    w = _slider(1.0, driving=dict(aim_distance=0.0), limit=dict(lower=-1, upper=1))
    assert w.terms == ('ortho_potential', 'prismatic_joint', 'prismatic_driving', 'prismatic_limit',
                       'external_force')
    assert World(_scene()).terms == ('ortho_potential', 'revolute_joint', 'prismatic_joint', 'prismatic_driving',
                                     'prismatic_limit', 'prismatic_damping', 'external_force')
    from physics_helpers import hinge_dict
    assert not any('prismatic' in t or t == 'external_force' for t in World(Scene.from_dict(hinge_dict())).terms)


def test_effort_and_drive_api_in_the_joints_units():
    w = World(_scene())
    assert w.joint_types == ('revolute', 'prismatic', 'prismatic')
    assert w.actuated_joint_names == ('slide',)
    assert w.set_effort('slide', 3.5) == 3.5
    assert list(w.applied_efforts()) == [0.0, 3.5, 0.0] and not w.applied_torques().any()
    w.set_effort_enabled('slide', False)
    assert not w.effort_enabled('slide') and not w.applied_efforts().any()
    with pytest.raises(ValueError, match=r"joint 'slide' is prismatic: its effort is a force \(UID 667, N\)"):
        w.set_torque('slide', 1.0)
    with pytest.raises(ValueError, match=r"joint 'slide': effort \(N\) nan is not finite"):
        w.set_effort('slide', float('nan'))
    with pytest.raises(ValueError, match=r"aim distance 20000.0 m is outside"):
        w.set_drive('slide', aim=2e4)
    w.set_drive('slide', aim=0.1)
    assert w.control.drive_aim.tolist() == [0.1]
    assert np.array_equal(w.joint_positions(), w.joint_angles())
    assert w.joint_positions().tolist() == [0.0, 0.05, 0.0]


def test_effort_limit_clamps_the_force():
    w = _slider(None)
    w2 = World(Scene.from_dict(dict(dt=0.01, bodies=[box('base', (0, 0, 0), fixed=True), box('cart', (0.6, 0, 0))],
                                    joints=[dict(name='slide', type='prismatic', parent='base', child='cart',
                                                 p0=[0.3, 0, 0], p1=[1.3, 0, 0],
                                                 external_force=dict(force=1.0, enabled=True, effort_limit=5.0))])))
    assert w2.set_effort('slide', 50.0) == 5.0 and w2.set_efforts([-9.0]).tolist() == [-5.0]
    assert w.actuated_joint_names == ()


BASE = dict(dt=0.01, bodies=[box('base', (0, 0, 0), fixed=True), box('cart', (0.6, 0, 0))])


@pytest.mark.parametrize('joint,where,message', [
    (dict(external_torque=dict(torque=1.0)), 'joints[0].external_torque',
     "joint 'slide' is prismatic: the external torque (UID 668) requires a revolute joint"),
    (dict(init_angle=0.1), 'joints[0].init_angle', 'takes init_distance (m)'),
    (dict(external_force=dict(force=10.0, effort_limit=5.0)), 'joints[0].external_force.force',
     '|10.0| N exceeds effort_limit 5.0 N'),
    (dict(external_force=dict(force='strong')), 'joints[0].external_force.force', 'must be a number'),
    (dict(driving=dict(aim_angle=0.1)), 'joints[0].driving.aim_angle', 'its drive takes aim_distance (m)'),
    (dict(limit=dict(lower=0.2, upper=0.1)), 'joints[0].limit', 'lower 0.2 > upper 0.1 (m)'),
    (dict(init_distance=0.5, limit=dict(lower=0.0, upper=0.1)), 'joints[0].init_distance',
     "0.5 m is outside the joint's limit [0, 0.1] m"),
    (dict(damping=1e300), 'joints[0].damping', '|value| <= 1e+09 N s/m'),
    (dict(init_distance=1e300), 'joints[0].init_distance', '|value| <= 10000 m'),
])
def test_scene_errors_name_the_joint_field_and_unit(joint, where, message):
    j = dict(name='slide', type='prismatic', parent='base', child='cart', p0=[0.3, 0, 0], p1=[1.3, 0, 0], **joint)
    with pytest.raises(SceneError) as err:
        Scene.from_dict(dict(BASE, joints=[j]))
    assert f'<dict>: {where}: ' in str(err.value) and message in str(err.value), str(err.value)
    assert '\n' not in str(err.value)


def test_a_revolute_joint_refuses_the_prismatic_fields():
    j = dict(name='hinge', parent='base', child='cart', p0=[0.3, 0, 0], p1=[0.3, 0, 1],
             external_force=dict(force=1.0))
    with pytest.raises(SceneError, match=r'joints\[0\].external_force: .*requires a prismatic joint \(UID 20\)'):
        Scene.from_dict(dict(BASE, joints=[j]))
    j = dict(name='hinge', parent='base', child='cart', p0=[0.3, 0, 0], p1=[0.3, 0, 1], init_distance=0.1)
    with pytest.raises(SceneError, match=r'joints\[0\].init_distance: .*takes init_angle \(rad\)'):
        Scene.from_dict(dict(BASE, joints=[j]))


def test_a_damper_too_hard_to_resolve_is_refused():
    """dt c beyond 1e15 times the lighter body's mass: one error naming joint, value and unit."""
    from abd_joint_sim.model import compile_scene as compile_
    j = dict(name='slide', type='prismatic', parent='base', child='cart', p0=[0.3, 0, 0], p1=[1.3, 0, 0],
             damping=1e9)
    light = dict(dt=1.0, bodies=[box('base', (0, 0, 0), fixed=True), dict(box('cart', (0.6, 0, 0)), density=1e-6)],
                 joints=[j])
    with pytest.raises(SceneError, match=r"joint 'slide': damping 1e\+09 N s/m is .* times the mass of its "
                                         r"lighter body .* lock it, or lower the damping"):
        compile_(Scene.from_dict(light))
    compile_(Scene.from_dict(dict(light, dt=1e-3, bodies=BASE['bodies'])))      # a real one is fine
