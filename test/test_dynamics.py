"""Whole-step physics against analytic solutions and conservation laws (docs/physics.md "Time integration", "Analytic references")."""
import copy
import subprocess
import sys

import numpy as np
import pytest
import scipy.integrate
import scipy.optimize

from abd_joint_sim import Scene, World
from abd_joint_sim.solver import linsolve
from abd_joint_sim.solver.solver import Solver

from physics_helpers import box, chain_dict, hinge_dict, scene_dict, world_from


I_AXIS = 64 * 0.32 / 12 + 64 * 0.36          # 0.4 m cube, COM 0.6 m from the axis
TIGHT = dict(velocity_tol=1e-5, transrate_tol=1e-5)


@pytest.mark.slow
def test_reference_scene_angular_acceleration_is_40_4():
    """libuipc tests 74/80: tau = 1000 N m on I_axis = 24.747 kg m^2."""
    assert I_AXIS == pytest.approx(24.747, abs=1e-3)
    w = world_from(hinge_dict())
    w.set_torque('hinge', 1000.0)
    w.step(5)
    t, h = w.time, w.dt
    alpha = 2 * w.joint_angles()[0] / (t * (t + h))     # BDF1: θ_n = ½α t_n (t_n + h)
    assert alpha == pytest.approx(40.4, rel=0.01)


def test_bdf1_matches_its_discrete_solution_and_is_first_order():
    """θ_n = ½α t_n² + ½α h t_n for implicit Euler; the error vs ½αt² halves with h."""
    tau, T = 100.0, 0.4
    alpha = tau / I_AXIS
    errors = []
    for h in (0.02, 0.01, 0.005):
        w = world_from(hinge_dict(), dt=h, newton=TIGHT)
        w.set_torque('hinge', tau)
        w.step(int(round(T / h)))
        theta = w.joint_angles()[0]
        assert theta == pytest.approx(0.5 * alpha * T * T + 0.5 * alpha * h * T, rel=0.01)
        errors.append(theta - 0.5 * alpha * T * T)
    orders = np.log2(np.abs(np.array(errors[:-1]) / errors[1:]))
    assert np.all(np.abs(orders - 1.0) < 0.1), orders


def test_bdf2_is_second_order_and_applies_the_torque():
    tau, T = 100.0, 0.4
    alpha = tau / I_AXIS
    errors = []
    for h in (0.02, 0.01, 0.005):
        w = world_from(hinge_dict(), dt=h, integrator='bdf2', newton=TIGHT)
        w.set_torque('hinge', tau)
        w.step(int(round(T / h)))
        errors.append(w.joint_angles()[0] - 0.5 * alpha * T * T)
    orders = np.log2(np.abs(np.array(errors[:-1]) / errors[1:]))
    assert np.all(orders > 1.8), orders
    assert abs(errors[-1]) < 1e-3 * 0.5 * alpha * T * T


def _free_pair_reference(theta_end_time, tau=1.0, m=8.0, Ic=0.2 ** 2 * 8 / 6, d=0.1):
    """θ(t) = 2φ with t(φ) = ∫₀^φ sqrt((I_c + m d² sin² s)/(2τ s)) ds (docs/physics.md "Analytic references")."""
    def t_of(phi):
        # substitute s = u²: the integrand's 1/sqrt(s) singularity becomes smooth
        f = lambda u: 2 * np.sqrt((Ic + m * d * d * np.sin(u * u) ** 2) / (2 * tau))
        return scipy.integrate.quad(f, 0.0, np.sqrt(phi), epsabs=1e-13, epsrel=1e-13)[0]
    phi = scipy.optimize.brentq(lambda p: t_of(p) - theta_end_time, 1e-12, 50.0, xtol=1e-14)
    return 2 * phi


def test_free_pair_reference_value():
    assert _free_pair_reference(1.0) == pytest.approx(11.786632172303, abs=1e-9)


@pytest.mark.parametrize('integrator,h,rel', [('bdf1', 0.001, 0.03), ('bdf2', 0.001, 2e-3)])
def test_free_pair_keeps_zero_momentum_and_follows_the_closed_form(integrator, h, rel):
    w = world_from(scene_dict('free_pair'), dt=h, integrator=integrator)
    worst_p = worst_l = 0.0
    for _ in range(5):
        w.step(100)
        P, L = w.momentum()
        worst_p, worst_l = max(worst_p, np.abs(P).max()), max(worst_l, np.abs(L).max())
    # scale: the bodies' own angular momentum is I_c*omega ~ 0.05 * 4 = 0.2
    assert worst_p < 1e-9 and worst_l < 1e-8
    assert w.joint_angles()[0] == pytest.approx(_free_pair_reference(w.time), rel=rel)


def test_free_fall_matches_bdf1_exactly_and_bodies_stay_rigid():
    g = np.array([0.0, -9.8, 0.0])
    w = World(Scene.from_dict(dict(dt=0.01, gravity=g.tolist(), bodies=[box('b', (0, 1, 0))])))
    assert w.terms == ('ortho_potential', 'gravity')
    w.step(20)
    n, h = 20, 0.01
    p, A = w.body_pose('b')
    assert p == pytest.approx([0, 1, 0] + g * h * h * n * (n + 1) / 2, abs=1e-12)
    assert A == pytest.approx(np.eye(3), abs=1e-12)


def test_fixed_bodies_never_move():
    w = world_from(scene_dict('default'))
    w.set_torque('shoulder', 30.0)
    w.set_torque('elbow', -15.0)
    q0 = w.state.q[0].copy()
    w.step(200)
    assert np.array_equal(w.state.q[0], q0) and not w.state.v[0].any()
    assert w.joint_angles()[0] > 0.05


@pytest.mark.parametrize('integrator', ['bdf1', 'bdf2'])
def test_unforced_pendulum_energy_never_grows(integrator):
    # transrate_tol 0.05: at the reference default 0.1 one Newton step from q~ can be
    # accepted with enough residual to gain ~1e-3 J in a swing (docs/decisions.md).
    d = dict(dt=0.005, gravity=[0, 0, -9.81], integrator=integrator,
             newton=dict(velocity_tol=0.05, transrate_tol=0.05),
             bodies=[box('base', (0, 0, 0), fixed=True), box('arm', (0.6, 0, 0), (0.6, 0.1, 0.1))],
             joints=[dict(name='j', parent='base', child='arm', p0=[0.2, -0.1, 0], p1=[0.2, 0.1, 0])])
    w = World(Scene.from_dict(d))
    energies, angles = [w.mechanical_energy()], []
    for _ in range(300):
        w.step()
        energies.append(w.mechanical_energy())
        angles.append(w.joint_angles()[0])
    e = np.array(energies)
    scale = 6.0                                  # m g d: the energy the swing exchanges
    if integrator == 'bdf1':                     # implicit Euler is dissipative step by step
        assert np.all(np.diff(e) <= 1e-9 * scale)
    else:                                        # BDF2 is not monotone, but never gains
        assert e.max() <= e[0] + 1e-9 * scale
    # +y axis: a positive angle turns the +x arm towards -z, i.e. down; it swings through
    assert max(angles) > 1.4


def test_terms_follow_the_scene():
    assert world_from(hinge_dict()).terms == ('ortho_potential', 'revolute_joint', 'external_torque')
    w = world_from(scene_dict('default'))
    assert w.terms == ('ortho_potential', 'revolute_joint', 'limit', 'gravity', 'external_torque')
    d = hinge_dict()
    del d['joints'][0]['external_torque']
    d['joints'][0]['driving'] = dict(aim_angle=0.5, enabled=True)
    w = world_from(d)
    assert w.terms == ('ortho_potential', 'revolute_joint', 'driving')
    assert w.actuated_joint_names == ()


# -- joint damping (terms/damping.py) against the damped hinge's closed form -------------------
# I θ̈ = τ − d θ̇ from rest: θ̇ = (τ/d)(1 − e^(−t/T₀)), θ = (τ/d)(t − T₀(1 − e^(−t/T₀))), T₀ = I/d.
DAMPED_TAU, DAMPED_T0 = 100.0, 0.2
DAMPED_D = I_AXIS / DAMPED_T0


def _damped_hinge(h, integrator, d=DAMPED_D, **kw):
    scene = hinge_dict(dt=h, integrator=integrator, newton=TIGHT, **kw)
    scene['joints'][0]['damping'] = d
    w = world_from(scene)
    w.set_torque('hinge', DAMPED_TAU)
    return w


def _damped_closed_form(t, d=DAMPED_D):
    T0 = I_AXIS / d
    v_end = DAMPED_TAU / d
    return v_end * (t - T0 * (1 - np.exp(-t / T0))), v_end * (1 - np.exp(-t / T0))


def test_damped_hinge_follows_bdf1s_discrete_solution_and_converges_first_order():
    """BDF1 of I ω' = τ − d ω is ω_(n+1) = (ω_n + hτ/I)/(1 + hd/I): the damping torque taken at
    the end of the step. The world follows that recursion, and its error against the closed
    form halves with h."""
    T = 0.4
    errors = []
    for h in (0.02, 0.01, 0.005):
        w = _damped_hinge(h, 'bdf1')
        omega, theta = 0.0, 0.0
        for _ in range(int(round(T / h))):
            omega = (omega + h * DAMPED_TAU / I_AXIS) / (1 + h * DAMPED_D / I_AXIS)
            theta += h * omega
        w.step(int(round(T / h)))
        assert w.joint_velocities()[0] == pytest.approx(omega, rel=2e-3)
        assert w.joint_angles()[0] == pytest.approx(theta, rel=2e-3)
        errors.append(w.joint_angles()[0] - _damped_closed_form(T)[0])
    orders = np.log2(np.abs(np.array(errors[:-1]) / errors[1:]))
    assert np.all(np.abs(orders - 1.0) < 0.1), orders


def test_damped_hinge_stays_second_order_with_bdf2():
    """BDF2 takes the damper's rate as (3θ − 4θⁿ + θⁿ⁻¹)/(2h); with BDF1's (θ − θⁿ)/h instead
    the damped hinge's speed would converge at first order. (The speed: the angle's error
    reaches the joint's elastic floor, ~3e-7 rad, by h = 0.005.)"""
    T = 0.4
    errors = []
    for h in (0.02, 0.01, 0.005):
        w = _damped_hinge(h, 'bdf2')
        w.step(int(round(T / h)))
        theta, omega = _damped_closed_form(T)
        errors.append(w.joint_velocities()[0] - omega)
        assert w.joint_angles()[0] == pytest.approx(theta, rel=5e-4)
    orders = np.log2(np.abs(np.array(errors[:-1]) / errors[1:]))
    assert np.all(orders > 1.8), orders


@pytest.mark.parametrize('integrator', ['bdf1', 'bdf2'])
def test_damping_a_thousand_times_past_explicit_stability_settles_without_overshoot(integrator):
    """h d / I = 1000 (explicit damping diverges beyond 2): the implicit damper takes the
    joint to its terminal speed τ/d within a few steps and never beyond it."""
    h = 0.01
    d = 1000 * I_AXIS / h
    w = _damped_hinge(h, integrator, d=d)
    speeds = []
    for _ in range(20):
        report = w.step()
        assert report.converged and not report.warnings
        speeds.append(w.joint_velocities()[0])
    v_end = DAMPED_TAU / d
    assert np.all(np.array(speeds) <= v_end * (1 + 1e-3)) and min(speeds) > 0.0
    assert speeds[-1] == pytest.approx(v_end, rel=1e-3)


def test_a_damped_hinge_spinning_down_loses_the_energy_its_damper_dissipates():
    """No torque, the arm spinning at 2 rad/s at the start, a damper of time constant
    T₀ = I/d = 0.2 s (BDF2, dt 1 ms): the speed follows ω₀ e^(−t/T₀), and the mechanical
    energy lost (World.mechanical_energy, which holds no damper) is the work of the damping
    torque, ∫ d θ̇² dt (trapezoid over the reported speeds); measured 1.2e-5 and 4e-5."""
    h, w0 = 1e-3, 2.0
    scene = hinge_dict(dt=h, integrator='bdf2', newton=TIGHT)
    scene['joints'][0]['damping'] = DAMPED_D
    scene['bodies'][1].update(angular_velocity=[0.0, 0.0, w0], velocity=[0.0, 0.6 * w0, 0.0])
    w = world_from(scene)
    e0 = w.mechanical_energy()
    assert e0 == pytest.approx(0.5 * I_AXIS * w0 ** 2, rel=1e-9)
    dissipated, before = 0.0, w0
    for _ in range(300):
        w.step()
        now = w.joint_velocities()[0]
        dissipated += 0.5 * h * DAMPED_D * (before ** 2 + now ** 2)
        before = now
    assert now == pytest.approx(w0 * np.exp(-w.time / DAMPED_T0), rel=1e-4)
    assert e0 - w.mechanical_energy() == pytest.approx(dissipated, rel=2e-4)
    assert dissipated > 0.7 * e0                        # most of it went


@pytest.mark.parametrize('ratio', [1, 100])
def test_a_damper_linearised_far_from_the_answer_is_linearised_again(ratio):
    """A torque step from rest the damper undoes within the step: Newton starts from the
    explicit prediction, where the torque alone has turned the joint ~0.7 rad, and the answer
    barely turns. The damper's angle, linearised at that start, misses the answer's by far
    more than damping.LINEAR_TOL; the step linearises it again at the answer and goes on
    (solver/step.py). The speed then follows BDF1's recursion (to the rigid closed form's
    reach); linearised once only it was off by 30 % to 7000x (measured)."""
    h = 0.01
    d = ratio * I_AXIS / h
    scene = hinge_dict(dt=h, integrator='bdf1', newton=TIGHT)
    scene['joints'][0]['damping'] = d
    w = world_from(scene)
    tau = 0.05 * I_AXIS / h ** 2
    w.set_torque('hinge', tau)
    omega = 0.0
    for _ in range(3):
        report = w.step()
        assert report.converged and not report.warnings     # one step, no sub-steps
        omega = (omega + h * tau / I_AXIS) / (1 + h * d / I_AXIS)
        assert w.joint_velocities()[0] == pytest.approx(omega, rel=5e-3)


def test_driving_reaches_its_aim_and_passive_locks():
    d = hinge_dict()
    d['joints'][0]['driving'] = dict(aim_angle=0.5, enabled=True, strength_ratio=100.0)
    w = world_from(d)
    w.step(300)
    assert w.joint_angles()[0] == pytest.approx(0.5, abs=0.02)
    w.set_drive('hinge', passive=True)
    w.set_torque('hinge', 200.0)
    a = w.joint_angles()[0]
    w.step(20)
    assert abs(w.joint_angles()[0] - a) < 0.02


def test_limit_stops_the_joint():
    d = hinge_dict()
    d['joints'][0]['limit'] = dict(lower=-0.3, upper=0.3, strength=1.0)
    w = world_from(d)
    w.set_torque('hinge', 500.0)
    w.step(200)
    free = world_from(hinge_dict())
    free.set_torque('hinge', 500.0)
    free.step(200)
    assert free.joint_angles()[0] > 5.0
    assert 0.3 < w.joint_angles()[0] < 0.6


def test_independent_mechanisms_evolve_as_if_alone():
    a = hinge_dict()
    b = hinge_dict()
    for body in b['bodies']:
        body['name'] += '_b'
        body['position'][1] += 5.0
    j = b['joints'][0]
    j.update(name='hinge_b', parent='base_b', child='arm_b', p0=[0, 5, -0.5], p1=[0, 5, 0.5])
    both = dict(a, bodies=a['bodies'] + b['bodies'], joints=a['joints'] + b['joints'])
    w2, w1 = world_from(both), world_from(a)
    w2.set_torque('hinge', 300.0)
    w2.set_torque('hinge_b', -100.0)
    w1.set_torque('hinge', 300.0)
    w2.step(30)
    w1.step(30)
    assert w2.joint_angles()[0] == pytest.approx(w1.joint_angles()[0], rel=1e-6)
    assert w2.joint_angles()[1] < 0


def test_chain_and_tree_move_and_hold_together():
    # Equal torques on every joint cancel on interior links: only the last link is driven
    # (+tau) and the base reacts, so the last joint opens positive.
    w = world_from(chain_dict(12, torque=0.05))
    w.step(50)
    assert w.joint_angles()[-1] > 1e-3 and w.max_joint_separation() < 1e-4 and w.last_step.converged
    tree = chain_dict(3, torque=0.0)
    tree['bodies'].append(box('side', (0.2, 0.3, 0.0), (0.2, 0.1, 0.1)))
    tree['joints'].append(dict(name='branch', parent='link1', child='side', p0=[0.2, 0.15, -0.1],
                               p1=[0.2, 0.15, 0.1], external_torque=dict(torque=-0.05, enabled=True)))
    w = world_from(tree)
    w.step(50)
    assert w.joint_angles()[-1] < -1e-3 and w.max_joint_separation() < 1e-4


def _star(n_arms, arm_len):
    """A free hub with n_arms chains: RCM cannot give it a narrow band."""
    d = chain_dict(1, torque=0.1)
    d['bodies'][1]['fixed'] = False
    for a in range(n_arms):
        prev = 'link1'
        ang = 2 * np.pi * a / n_arms
        for k in range(1, arm_len + 1):
            name = f'arm{a}_{k}'
            c = np.array([0.2 + 0.25 * k * np.cos(ang), 0.25 * k * np.sin(ang), 0.0])
            d['bodies'].append(box(name, c, (0.1, 0.1, 0.1)))
            x = c - 0.125 * np.array([np.cos(ang), np.sin(ang), 0.0])
            d['joints'].append(dict(name=f'j{a}_{k}', parent=prev, child=name, p0=list(x + [0, 0, -0.1]),
                                    p1=list(x + [0, 0, 0.1]), external_torque=dict(torque=0.05, enabled=True)))
            prev = name
    return d


def _doubled_joints(n):
    """A chain whose second and last joints (both between free links) are each doubled (a
    second hinge on the same axis, anchors moved along it): edges of two joints, eliminated
    towards the chain's middle from the joints' parent at one end and from their child at the
    other (linsolve's several-joint path: U summed, as is and transposed)."""
    d = chain_dict(n, torque=0.1)
    for src in (d['joints'][1], d['joints'][-1]):
        p0, p1 = np.array(src['p0']), np.array(src['p1'])
        extra = dict(src, name=src['name'] + '_twin', p0=list(p0 + 0.3 * (p1 - p0)),
                     p1=list(p1 + 0.3 * (p1 - p0)))
        extra.pop('external_torque', None)
        d['joints'].append(extra)
    return d


@pytest.mark.parametrize('scene', [chain_dict(10, torque=0.1), _star(8, 2), _doubled_joints(5)])
def test_tree_solve_agrees_with_dense(scene):
    fast = world_from(scene)
    assert fast.solver.data.solve_kind == linsolve.TREE
    fast.step(20)
    dense = world_from(scene)
    dense.solver = Solver(dense.model, force_dense=True)
    assert dense.solver.data.solve_kind == linsolve.DENSE
    dense.step(20)
    assert np.abs(dense.state.q - fast.state.q).max() < 1e-10
    assert np.abs(fast.state.q - fast.model.body_q0).max() > 1e-6      # it did move
    twins = sum(j['name'].endswith('_twin') for j in scene['joints'])
    assert (np.diff(fast.solver.data.tree_edge_ptr) == 2).sum() == twins   # edges of two joints


@pytest.mark.parametrize('case', ['kappa_1e12', 'strength_1e6', 'mass_ratio_1e6', 'mass_ratio_inv_1e6'])
def test_stiff_and_extreme_cases_stay_stable(case):
    d = hinge_dict(dt=0.01)
    d['bodies'][1]['fixed'] = False
    d['bodies'][0]['fixed'] = case == 'strength_1e6'
    if case == 'kappa_1e12':
        for b in d['bodies']:
            b['kappa'] = 1e12
    if case == 'strength_1e6':
        d['joints'][0]['strength_ratio'] = 1e6
    if case.startswith('mass_ratio'):
        k = 0 if case == 'mass_ratio_1e6' else 1
        d['bodies'][k]['density'] = 1000.0 * 1e6
    w = world_from(d)
    w.set_torque('hinge', 1000.0)
    for _ in range(20):
        report = w.step(5)
        assert np.all(np.isfinite(w.state.q))
        assert report.converged or report.warnings
    assert w.max_joint_separation() < 1e-3 * 0.4
    assert w.joint_angles()[0] > 0


@pytest.mark.slow
def test_core_does_not_import_rclpy():
    code = ('import sys, abd_joint_sim, abd_joint_sim.world; '
            'w = abd_joint_sim.World(abd_joint_sim.Scene.from_yaml(sys.argv[1])); w.step(); '
            'assert "rclpy" not in sys.modules, "core imported rclpy"')
    from physics_helpers import SCENES
    subprocess.run([sys.executable, '-c', code, str(SCENES / 'default.yaml')], check=True)


@pytest.mark.parametrize('integrator', ['bdf1', 'bdf2'])
def test_warm_start_saves_an_iteration_and_keeps_the_solution(integrator):
    """State.warm_start (Newton starts from q̃ plus the last step's correction, or from q̃
    where Π is lower) must not change the physics beyond Newton's tolerance, only the work:
    the default arm under torque takes ~1 iteration per step with it and ~2 from q̃ alone
    (the couple spins the thin links about their own centres; the hinges correct that by
    about the same amount every step). Measured after 400 steps: both within 1e-5 rad of a
    velocity_tol = 1e-7 solve (bdf1: warm 3e-8, cold 6e-7; bdf2: 9e-6 both)."""
    d = scene_dict('default')
    d['integrator'] = integrator
    tight = copy.deepcopy(d)
    tight['newton'] = dict(velocity_tol=1e-7, transrate_tol=1e-7, max_iterations=200)
    worlds = {'warm': world_from(d), 'cold': world_from(d), 'tight': world_from(tight)}
    its = dict.fromkeys(worlds, 0)
    for w in worlds.values():
        w.set_torque('shoulder', 4.0)
        w.set_torque('elbow', -1.5)
    for _ in range(400):
        worlds['cold'].state.warm_start[:] = 0.0        # every step from q̃, as before
        worlds['cold'].state.warm_start_prev[:] = 0.0
        worlds['cold'].state.warm_start_prev2[:] = 0.0
        for name, w in worlds.items():
            its[name] += w.step().newton_iterations
    assert its['warm'] <= 1.1 * 400 and its['cold'] >= 1.9 * 400, its
    ref = worlds['tight'].joint_angles()
    assert np.abs(ref).max() > 0.5                                  # the arm did move
    for name in ('warm', 'cold'):
        assert np.allclose(worlds[name].joint_angles(), ref, atol=2e-5, rtol=0), name
    worlds['warm'].reset()
    assert not worlds['warm'].state.warm_start.any()


#: (robot, integrator, most quadratic/plain iterations, most quadratic/linear iterations)
_EXTRAPOLATION_CASES = [
    ('xarm/xarm6_robot.urdf', 'bdf1', 0.7, 1.02),
    ('xarm/xarm6_robot.urdf', 'bdf2', 0.75, 1.02),
    ('mini_cheetah/mini_cheetah.urdf', 'bdf1', 0.7, 0.75),
    ('mini_cheetah/mini_cheetah.urdf', 'bdf2', 0.95, 0.95),
]


# pybullet_data's xArm and Mini Cheetah are repaired on import (inertias, friction), with
# warnings test_urdf_engines.py asserts; here they would only repeat
@pytest.mark.filterwarnings('ignore::abd_joint_sim.urdf.UrdfWarning')
@pytest.mark.parametrize('robot, integrator, vs_plain, vs_linear', _EXTRAPOLATION_CASES)
def test_extrapolated_warm_start_saves_iterations_on_robots(robot, integrator, vs_plain, vs_linear):
    """Newton starts from the warm start extrapolated over the last three steps
    (3 warm_start − 3 warm_start_prev + warm_start_prev2; State.extrapolation_order), or
    from the plain warm start or q̃ where Π is lower. Three worlds on the same robot of
    pybullet_data under gravity and torques: the quadratic start (the default), the linear
    one (warm_start_prev2 marked unknown before every step) and the plain warm start
    (warm_start_prev too). Measured over steps 100-700, Newton iterations per step
    (quadratic / linear / plain): xArm 6 bdf1 1.10 / 1.13 / 2.00, bdf2 1.37 / 1.42 / 2.10;
    Mini Cheetah bdf1 1.16 / 1.96 / 2.08, bdf2 1.88 / 2.20 / 2.31 (its links are light and
    stiff: the linear start's first correction still exceeds the tolerances). Every start
    must keep the solution: every 20th step, each world's step against a tolerance-1e-7
    solve from the same state (measured at most 1.7e-6 m, mean at most 1.0e-7 m, against
    the displacement tolerance velocity_tol·h = 5e-5 m). Comparing the end states instead
    would compare chaotic trajectories (the arm flails in and out of its limits)."""
    import os
    pybullet_data = pytest.importorskip('pybullet_data')
    path = os.path.join(pybullet_data.getDataPath(), robot)
    tight = dict(velocity_tol=1e-7, transrate_tol=1e-7, max_iterations=200)
    # without the xArm's joint damping (1 N m s/rad), as measured: with it the arm moves so
    # smoothly that even the plain start takes one iteration
    worlds = {name: World(Scene.from_urdf(path, integrator=integrator, damping=False))
              for name in ('quadratic', 'linear', 'plain')}
    ref = World(Scene.from_urdf(path, integrator=integrator, newton=tight, damping=False))
    for w in (*worlds.values(), ref):
        for k, j in enumerate(w.actuated_joint_names):
            w.set_torque(j, (-1) ** k * (2.0 - 0.2 * k))
    tol = worlds['quadratic'].model.newton.velocity_tol * worlds['quadratic'].dt
    its = dict.fromkeys(worlds, 0)
    deviation = {name: [] for name in worlds}
    for k in range(1, 701):
        linear, plain = worlds['linear'].state, worlds['plain'].state
        linear.warm_start_prev2 = linear.warm_start_prev         # two known: linear
        plain.warm_start_prev = plain.warm_start_prev2 = plain.warm_start   # none known
        assert (linear.extrapolation_order(linear.history_dt), plain.extrapolation_order(plain.history_dt)) \
            == ((1, 0) if k > 2 else (0, 0))
        for name, w in worlds.items():
            start = w.state
            n = w.step().newton_iterations
            if k > 100:                                     # past the start's transient
                its[name] += n
                if k % 20 == 0:
                    solved, _ = ref.solver.step(start, w.control)
                    deviation[name].append(float(np.abs(w.state.q - solved.q).max()))
    assert np.abs(worlds['quadratic'].joint_angles()).max() > 0.3          # the robot did move
    assert worlds['quadratic'].state.extrapolation_order(worlds['quadratic'].dt) == 2
    assert its['plain'] >= 1.8 * 600, its
    assert its['quadratic'] <= vs_plain * its['plain'] and its['quadratic'] <= vs_linear * its['linear'], its
    for name, d in deviation.items():
        assert max(d) <= 0.1 * tol and np.mean(d) <= 0.01 * tol, (name, max(d), np.mean(d))


def test_warm_start_does_not_keep_a_resting_limit_jittering():
    """A drive pushing a hinge into its limit comes to rest. Starting Newton from the last
    correction alone carried each step's stopping error into the next and kept the body
    jittering at the tolerance level (max |v| 2.6e-2 m/s after 1000 steps on numpy); the
    start with the lower Π (q̃ here) keeps it at rest like the plain prediction (2.6e-5)."""
    d = hinge_dict(dt=0.005)
    d['joints'][0]['driving'] = dict(aim_angle=0.6, enabled=True)
    d['joints'][0]['limit'] = dict(lower=-0.2, upper=0.3, strength=1e4)
    w = world_from(d)
    w.step(1000)
    worst = 0.0
    for _ in range(500):
        w.step()
        worst = max(worst, float(np.abs(w.state.v).max()))
    assert worst < 2e-4, worst
