"""The optional numba backend (abd_joint_sim/fast/) takes the same steps as the numpy reference.

Agreement criterion: after N steps, max |Δq| ≤ 1e-9 × body size, equal joint angles and
velocities to the same relative level, and identical StepReports (Newton and line-search
iterations, status, sub-steps, warnings). The two backends evaluate the same formulas with
different summation orders and a different 3x3 SVD / eigen-solver, so they differ by
round-off (≈1e-15 relative per step). The drive+limit scene once amplified round-off at the
default tolerance and ran tight; with the screw steps and the warm start that starts from the
lower-energy guess it no longer does (`test_resting_limit_does_not_amplify_roundoff`), and it
runs 200 steps at both tolerances.
"""
import copy
import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip('numba')

from abd_joint_sim import Scene, World  # noqa: E402
from abd_joint_sim import fast  # noqa: E402
from abd_joint_sim.fast import kernels, step as fast_step  # noqa: E402
from abd_joint_sim.solver import newton, retraction  # noqa: E402
from abd_joint_sim.terms import forces  # noqa: E402
from abd_joint_sim.terms.forces import ExternalTorque  # noqa: E402
from abd_joint_sim.terms.ortho import projected_hessian  # noqa: E402
from abd_joint_sim.world import StepReport  # noqa: E402

from conftest import SCENES  # noqa: E402
from physics_helpers import box, chain_dict, hinge_dict, random_rotation, scene_dict  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
TIGHT = dict(velocity_tol=1e-6, transrate_tol=1e-6)


def _report_key(r):
    return (r.newton_iterations, r.line_search_iterations, r.status, r.converged, r.substeps,
            tuple(r.warnings))


def _pair(d):
    scene = Scene.from_dict(copy.deepcopy(d))
    a, b = World(scene, backend='numpy'), World(scene, backend='numba')
    assert (a.backend, b.backend) == ('numpy', 'numba')
    return a, b


def _run_both(d, steps, setup=None, schedule=None):
    """Step both backends; compare every report and the final state. Returns the worlds."""
    a, b = _pair(d)
    for w in (a, b):
        if setup:
            setup(w)
    for k in range(steps):
        for w in (a, b):
            if schedule:
                schedule(w, k)
        ra, rb = a.step(), b.step()
        assert _report_key(ra) == _report_key(rb), (k, ra, rb)
        assert ra.max_step_rotation == pytest.approx(rb.max_step_rotation, rel=1e-6, abs=1e-12)
    _assert_same_state(a, b)
    return a, b


def _assert_same_state(a, b, tol=1e-9):
    size = a.model.body_size[:, None]
    sa, sb = a.state, b.state
    assert np.all(np.abs(sa.q - sb.q) <= tol * size), np.abs(sa.q - sb.q).max()
    assert np.all(np.abs(sa.q_prev - sb.q_prev) <= tol * size)
    scale_v = max(1.0, np.abs(sa.v).max())
    assert np.abs(sa.v - sb.v).max() <= 1e-6 * scale_v       # v = Δq/h: 1/h times Δq's error
    assert np.abs(sa.joint_angle - sb.joint_angle).max(initial=0.0) <= tol * 10
    scale_w = max(1.0, np.abs(sa.joint_velocity).max(initial=0.0))
    assert np.abs(sa.joint_velocity - sb.joint_velocity).max(initial=0.0) <= 1e-6 * scale_w
    assert (sa.time, sa.step_count, sa.history_dt) == (sb.time, sb.step_count, sb.history_dt)


def _torques(value):
    def setup(w):
        for j in w.actuated_joint_names:
            w.set_torque(j, value)
    return setup


def _drive_limit_hinge(**kw):
    d = hinge_dict(dt=0.005, **kw)
    d['joints'][0]['driving'] = dict(aim_angle=0.6, enabled=True)
    d['joints'][0]['limit'] = dict(lower=-0.2, upper=0.3, strength=1e4)
    return d


def _ring(n_free):
    """A fixed base and n free boxes joined in a closed loop (not a forest)."""
    bodies = [box('base', (0.0, 0.0, -1.0), fixed=True)]
    joints = []
    for k in range(n_free):
        ang = 2 * np.pi * k / n_free
        bodies.append(box(f'b{k}', (np.cos(ang), np.sin(ang), 0.0), (0.2, 0.2, 0.2)))
    for k in range(n_free):
        a, b = 2 * np.pi * k / n_free, 2 * np.pi * (k + 1) / n_free
        mid = 0.5 * (np.array([np.cos(a), np.sin(a), 0]) + np.array([np.cos(b), np.sin(b), 0]))
        joints.append(dict(name=f'j{k}', parent=f'b{k}', child=f'b{(k + 1) % n_free}',
                           p0=list(mid - [0, 0, 0.1]), p1=list(mid + [0, 0, 0.1]),
                           external_torque=dict(torque=0.5 * (-1) ** k, enabled=True)))
    joints.append(dict(name='anchor', parent='base', child='b0', p0=[1.0, 0, -0.6], p1=[1.0, 0, -0.4]))
    return dict(dt=0.002, gravity=[0.0, 0.0, -9.81], bodies=bodies, joints=joints)


def _tree():
    """A fixed base with two branches of 3 links each (a tree, not a chain)."""
    bodies = [box('base', (0.0, 0.0, 0.0), (0.2, 0.2, 0.2), fixed=True)]
    joints = []
    for side, sgn in (('l', -1), ('r', 1)):
        prev = 'base'
        for k in range(1, 4):
            name = f'{side}{k}'
            bodies.append(box(name, (sgn * 0.2 * k, 0.0, 0.0), (0.2, 0.1, 0.1)))
            x = sgn * 0.2 * (k - 0.5)
            joints.append(dict(name=f'j{name}', parent=prev, child=name, p0=[x, 0, -0.1], p1=[x, 0, 0.1],
                               external_torque=dict(torque=0.3 * k * sgn, enabled=True)))
            prev = name
    return dict(dt=0.001, gravity=[0.0, 0.0, -9.81], bodies=bodies, joints=joints)


# -- selection ------------------------------------------------------------------------------
def test_backend_selection(monkeypatch):
    scene = Scene.from_dict(hinge_dict())
    assert World(scene, backend='numpy').backend == 'numpy'
    assert World(scene, backend='numba').backend == 'numba'
    with pytest.raises(ValueError, match='backend'):
        World(scene, backend='cuda')
    monkeypatch.setenv('ABD_BACKEND', 'numpy')
    assert World(scene).backend == 'numpy'
    monkeypatch.setenv('ABD_BACKEND', 'numba')
    assert World(scene).backend == 'numba'
    monkeypatch.delenv('ABD_BACKEND')
    assert World(scene).backend == 'numba'           # auto: numba when it is importable
    assert fast.AVAILABLE


def test_a_large_loop_keeps_numpy_and_a_small_one_runs_dense():
    big = Scene.from_dict(_ring(9))
    assert World(big, backend='auto').backend == 'numpy'
    with pytest.warns(RuntimeWarning, match='loop'):
        assert World(big, backend='numba').backend == 'numpy'
    small = World(Scene.from_dict(_ring(4)), backend='numba')
    assert fast_step.packed_for(small).mi[6] == kernels.KIND_DENSE
    tree = World(Scene.from_dict(_tree()), backend='numba')
    assert fast_step.packed_for(tree).mi[6] == kernels.KIND_TREE


def test_constants_match_the_reference():
    assert kernels.ROUNDOFF == newton.ROUNDOFF
    assert kernels.SINGULAR_RATIO == forces.SINGULAR_RATIO
    assert kernels.SMALL_ANGLE == retraction.SMALL_ANGLE
    assert kernels.SCREW_STRAIN == retraction.SCREW_STRAIN


@pytest.mark.parametrize('scene', ['free_pair', 'default', 'hinge'])
def test_screw_retraction_matches_numpy(scene):
    """kernels.retract against solver/retraction.py on random states and steps, with angles
    on both sides of the series switch, bodies near and far (linear step) from a rotation,
    a floating group (free_pair) and anchored ones."""
    w = World(Scene.from_yaml(SCENES / f'{scene}.yaml'), backend='numba')
    mi = fast_step.packed_for(w).mi
    mf = fast_step.packed_for(w).mf
    parts = kernels.unpack(mi, mf)
    free_idx, group, share = parts[16], parts[23], parts[-1]     # unpack order
    ref = retraction.ScrewRetraction(w.model)
    rng = np.random.default_rng(7)
    for scale, strain in ((1e-6, 1e-3), (3e-3, 1e-3), (0.05, 1e-3), (0.8, 1e-3), (0.05, 0.05)):
        q = w.model.body_q0 + strain * rng.normal(size=w.model.body_q0.shape)
        dq = scale * rng.normal(size=q.shape)
        dq[w.model.body_fixed] = 0.0
        for alpha in (1.0, 0.25):
            out = np.empty_like(q)
            kernels.retract(q, dq, alpha, free_idx, group, share, int(mi[12]), out, np.empty((2, 3)))
            np.testing.assert_allclose(out, ref(q, alpha * dq), rtol=0, atol=1e-15)


# -- kernels against the numpy terms ----------------------------------------------------------
def test_svd3_and_projected_ortho_hessian_match_numpy():
    rng = np.random.default_rng(3)
    mats = [rng.normal(size=(3, 3)) for _ in range(20)]
    mats += [random_rotation(rng) @ (np.eye(3) + 1e-6 * rng.normal(size=(3, 3))) for _ in range(20)]
    mats += [np.array([[1, 0, 0], [0, 1, 0], [1, 1e-8, 1e-8]]), np.eye(3), np.diag([1.0, 1.0, -1.0]),
             np.zeros((3, 3))]
    U, S, V = np.empty((3, 3)), np.empty(3), np.empty((3, 3))
    for A in mats:
        kernels.svd3(A, U, S, V)
        scale = max(1.0, np.abs(A).max())
        assert np.abs(U * S @ V.T - A).max() <= 1e-14 * scale
        assert np.abs(U.T @ U - np.eye(3)).max() <= 1e-14 and np.abs(V.T @ V - np.eye(3)).max() <= 1e-14
        assert np.abs(S - np.linalg.svd(A)[1]).max() <= 1e-14 * scale
        q = np.zeros((1, 12))
        q[0, 3:] = A.ravel()
        g, d = np.zeros((1, 12)), np.zeros((1, 12, 12))
        kernels.ortho_accumulate(q, np.zeros(1, np.int64), np.ones(1), 0.5, g, d)
        ref = projected_hessian(A[None])[0]
        assert np.abs(d[0, 3:, 3:] - ref).max() <= 1e-13 * max(1.0, np.abs(ref).max())


def test_jacobi_eigh_matches_lapack():
    rng = np.random.default_rng(5)
    for n in (3, 12):
        X = rng.normal(size=(n, n))
        S = X + X.T
        w, V = np.empty(n), np.empty((n, n))
        kernels.jacobi_eigh(S.copy(), w, V)
        assert np.abs(np.sort(w) - np.linalg.eigvalsh(S)).max() <= 1e-13 * np.abs(S).max()
        assert np.abs(V * w @ V.T - S).max() <= 1e-13 * np.abs(S).max()


# -- whole steps ------------------------------------------------------------------------------
CASES = {
    'hinge_bdf1_torque': (lambda: hinge_dict(), 100, _torques(1000.0)),
    'hinge_bdf2_torque': (lambda: hinge_dict(integrator='bdf2'), 100, _torques(1000.0)),
    'hinge_torque_off': (lambda: hinge_dict(gravity=[0.0, -9.81, 0.0]), 50, None),
    'free_pair_bdf1': (lambda: scene_dict('free_pair'), 300, None),
    'free_pair_bdf2': (lambda: dict(scene_dict('free_pair'), integrator='bdf2'), 300, None),
    'default_torques': (lambda: scene_dict('default'), 300, _torques(5.0)),
    'default_idle': (lambda: scene_dict('default'), 100, None),
    'default_bdf2': (lambda: dict(scene_dict('default'), integrator='bdf2'), 200, _torques(-8.0)),
    'drive_limit_tight': (lambda: _drive_limit_hinge(newton=TIGHT), 200, None),
    'drive_limit_default_tol': (lambda: _drive_limit_hinge(), 200, None),
    'drive_limit_bdf2_tight': (lambda: _drive_limit_hinge(newton=TIGHT, integrator='bdf2'), 100, None),
    'chain12': (lambda: chain_dict(12), 100, None),
    'chain12_bdf2_gravity': (lambda: chain_dict(12, gravity=(0.0, 0.0, -9.81)) | {'integrator': 'bdf2'}, 60, None),
    'tree': (lambda: _tree(), 100, None),
    # default tolerance: Newton's 2nd iteration lands on the round-off floor, where the
    # reference's own iteration counts flip under a 1e-15 nudge
    # (test_roundoff_floor_flips_iteration_counts_in_the_reference_too): 3 steps there, 60 at
    # a velocity_tol that one iteration meets (decrement 1.1e-5 ≤ ½Σm(0.5·h)² = 1.6e-5)
    'ring4_dense': (lambda: _ring(4) | {'newton': {'velocity_tol': 0.5}}, 60, None),
    'ring4_dense_default_tol': (lambda: _ring(4), 3, None),
}


@pytest.mark.parametrize('name', sorted(CASES))
def test_backends_agree(name):
    make, steps, setup = CASES[name]
    _run_both(make(), steps, setup)


def test_control_changes_between_steps_agree():
    """Torque enable/disable and values changing during the run; passive drive."""
    d = scene_dict('default')
    d['joints'][0]['driving'] = dict(aim_angle=0.4, enabled=False, strength_ratio=5.0)

    def schedule(w, k):
        if k == 20:
            w.set_torque('shoulder', 12.0)
            w.set_torque('elbow', -6.0)
        if k == 60:
            w.set_torque_enabled('elbow', False)
        if k == 90:
            w.set_drive('shoulder', enabled=True)
        if k == 130:
            w.set_drive('shoulder', passive=True)
            w.set_torque_enabled('elbow', True)
    _run_both(d, 160, schedule=schedule)


def test_near_singular_affine_matrix_is_guarded_alike():
    def setup(w):
        w.set_torque('hinge', 10.0)
        w.state.q[1, 3:12] = np.array([[1, 0, 0], [0, 1, 0], [1, 1e-8, 1e-8]]).ravel()
    a, b = _pair(hinge_dict())
    for w in (a, b):
        setup(w)
    ra, rb = a.step(), b.step()
    assert _report_key(ra) == _report_key(rb)
    assert any('near-singular' in m and "'arm'" in m for m in rb.warnings)
    _assert_same_state(a, b)


def test_substeps_and_failures_agree():
    """A joint turning more than max_step_rotation: sub-stepping, same retry warnings; and a
    Newton that hits max_iterations (reported, result kept)."""
    d = hinge_dict(dt=0.05, newton=dict(max_step_rotation=0.3))
    a, _ = _run_both(d, 6, _torques(1000.0))
    assert a.last_step.substeps > 1 and 'retrying as 2 sub-steps' in a.last_step.warnings[0]
    d = hinge_dict(newton=dict(velocity_tol=1e-9, transrate_tol=1e-9, max_iterations=1,
                               max_substep_depth=1))
    a, b = _run_both(d, 3, _torques(1000.0))
    assert a.last_step.status == 'max_iterations' and not b.last_step.converged


def test_newton_decrement_criterion_agrees():
    """dt = 0.1, τ = 100 N·m on the hinge (0.04-0.3 rad per step): the step-size test alone
    stopped after a few iterations far from the minimiser; the decrement criterion
    −½∇Πᵀ Δq ≤ s·½Σm(velocity_tol·h)² keeps Newton going, and the screw steps
    (solver/retraction.py) get there in 5-7 iterations (linear steps took ~31 and amplified
    round-off ~1000x per step). Same iterations, line searches and state over ten steps."""
    for integrator in ('bdf1', 'bdf2'):
        a, b = _run_both(hinge_dict(dt=0.1, integrator=integrator), 10, _torques(100.0))
        assert a.last_step.newton_iterations >= 4 and a.last_step.converged


def test_predicted_rotation_splits_alike():
    """dt = 1e-2, τ = 1e5: ∇θ·(q̃ − qⁿ) predicts 5.9 rad for the first step, which is refused
    before solving (state untouched) and sub-stepped on both backends."""
    d = hinge_dict(dt=1e-2)
    a, b = _run_both(d, 1, _torques(1e5))
    for w in (a, b):
        r = w.last_step
        assert r.substeps > 1
        assert 'a joint is predicted to turn' in r.warnings[0] and 'retrying as 2 sub-steps' in r.warnings[0]
    a, b = _run_both(d, 5, _torques(1e5))
    assert a.last_step.substeps > 1
    # the refusal itself: no Newton iteration, state unchanged, same string; without the
    # flag (deepest sub-step level) the step is solved
    out = []
    for w in _pair(d):
        w.set_torque('hinge', 1e5)
        start = w.state
        q0 = start.q.copy()
        report = StepReport()
        failure = w._single(w.model.dt, report, True)
        assert failure == 'a joint is predicted to turn 5.86 rad in one step (limit 1.57)'
        assert w.state is start and np.array_equal(w.state.q, q0)
        assert (report.newton_iterations, report.line_search_iterations, report.warnings) == (0, 0, [])
        report = StepReport()
        out.append((w._single(w.model.dt, report, False), report.newton_iterations))
        assert w.state is not start and report.newton_iterations > 0
    assert out[0] == out[1] and 'predicted' not in str(out[0][0])


def _degenerate_pair(side_bodies):
    """The free pair with A = diag(1, 1, 0) (zero third row and column) on the given bodies:
    their raw axis A(x̄1 − x̄0) with x̄1 − x̄0 ∥ z is exactly 0."""
    def setup(w):
        w.set_torque('hinge', 2.0)
        for body in side_bodies:
            w.state.q[body, 3:12] = np.diag([1.0, 1.0, 0.0]).ravel()
    return setup


@pytest.mark.parametrize('bodies', [(1,), (0,), (0, 1)], ids=['child', 'parent', 'both'])
def test_degenerate_torque_axis_agrees(bodies):
    """ExternalTorque.axes: an unusable raw axis (norm ≤ 1e-12·|x̄1 − x̄0|) is replaced by the
    other body's, so the healthy body keeps its torque (no NaN); with neither the torque is 0.
    The degenerate body is also singular, so it is skipped (warning) on both backends."""
    d = scene_dict('free_pair')
    a, b = _pair(d)
    setup = _degenerate_pair(bodies)
    for w in (a, b):
        setup(w)
    # the accelerations themselves: compiled against terms/forces.py
    m = a.model
    q = a.state.q.copy()
    ref = np.zeros((2, 12))
    msgs = []
    ExternalTorque.build(m).acceleration(q, a.control, ref, msgs)
    xbar = np.stack([m.joint_anchor0, m.joint_anchor1], axis=2)
    skipped = np.empty(2, dtype=np.int64)
    acc, ns = kernels.accelerations(q, m.body_fixed.astype(np.int64), m.body_Minv, np.zeros(3), False,
                                    m.joint_parent, m.joint_child, xbar, m.torque_joints,
                                    a.control.torque_value, a.control.torque_enabled, skipped)
    assert np.all(np.isfinite(acc)) and np.all(np.isfinite(ref))
    assert np.abs(acc - ref).max() <= 1e-12 * np.abs(ref).max(initial=1.0)
    assert sorted(skipped[:ns].tolist()) == sorted(bodies) and len(msgs) == ns
    healthy = [k for k in (0, 1) if k not in bodies]
    for k in healthy:                       # full torque about ∓z from the healthy body's own axis
        assert np.abs(acc[k, 3:12]).max() > 0.0
    if not healthy:
        assert not acc.any()
    # whole steps
    for _ in range(3):
        ra, rb = a.step(), b.step()
        assert _report_key(ra) == _report_key(rb)
        assert np.all(np.isfinite(a.state.q)) and np.all(np.isfinite(b.state.q))
    _assert_same_state(a, b)
    if healthy:
        k = healthy[0]
        # the healthy body turned the way its torque pushes it: the parent about −z (negative
        # joint angle contribution), the child about +z
        w_z = a.state.v[k, 4] - a.state.v[k, 6]   # Ȧ[0,1] − Ȧ[1,0] ≈ −2 ω_z
        assert (w_z < 0) == (k == 1)


def test_a_step_never_writes_into_the_previous_state():
    """World.step keeps the old State by reference to undo a step: neither backend may write
    into its arrays (plain, bdf2, sub-stepped and predicted-split steps)."""
    for d, tau in ((hinge_dict(integrator='bdf2'), 1000.0), (hinge_dict(dt=1e-2), 1e5),
                   (_drive_limit_hinge(), 0.0), (scene_dict('default'), 5.0)):
        for w in _pair(d):
            for j in w.actuated_joint_names:
                w.set_torque(j, tau)
            for _ in range(3):
                old = w.state
                saved = {k: getattr(old, k).copy() for k in
                         ('q', 'v', 'q_prev', 'v_prev', 'joint_angle', 'joint_velocity')}
                w.step()
                assert w.state is not old
                for k, x in saved.items():
                    assert np.array_equal(getattr(old, k), x), (w.backend, k)


def test_reset_and_dt_change_restart_bdf2_alike():
    d = hinge_dict(integrator='bdf2')
    a, b = _pair(d)
    for w in (a, b):
        w.set_torque('hinge', 500.0)
        w.step(10)
        w.reset()
        w.set_torque('hinge', -300.0)
        w.step(10)
    _assert_same_state(a, b)
    assert a.last_step.newton_iterations == b.last_step.newton_iterations


def test_resting_limit_does_not_amplify_roundoff():
    """The drive+limit hinge at the default tolerance, numpy against itself with a 1e-15
    nudge. The first linear-step core turned it into ~1e-8 within 200 steps, and a warm start
    from the last correction alone kept the resting body jittering at the tolerance level
    (4.8e-8 at step 200, 1e-4 later); starting from the lower-energy guess it stays at
    round-off (measured 1.5e-14 over 400 steps)."""
    scene = Scene.from_dict(_drive_limit_hinge())
    a, b = World(scene, backend='numpy'), World(scene, backend='numpy')
    b.state.q[1, 0] += 1e-15
    worst = 0.0
    for _ in range(400):
        a.step()
        b.step()
        worst = max(worst, float(np.abs(a.state.q - b.state.q).max()))
    assert worst < 1e-12


@pytest.mark.parametrize('backend', ['numpy', 'numba'])
def test_no_line_search_wandering_at_the_roundoff_floor(backend):
    """ring4's 2nd Newton iteration has a decrement ~1e-19 against a rounding slack
    ROUNDOFF·|Π| ~1e-19. Once the tolerances hold only the full step is tried, so a step
    never wanders there (it used to take up to 10 Newton iterations and 215 halvings), with
    or without a 1e-15 nudge; which of 2/0 or 2/1 a step takes may still be rounding."""
    scene = Scene.from_dict(_ring(4))
    a, b = World(scene, backend=backend), World(scene, backend=backend)
    b.state.q[1, 0] += 1e-15
    for _ in range(60):
        for r in (a.step(), b.step()):
            assert r.converged and r.newton_iterations <= 2 and r.line_search_iterations <= 1, r
    # the nudge grows (converged iterates differ within the Newton tolerance, 5e-4 m per
    # step here) but stays far below it
    assert np.abs(a.state.q - b.state.q).max() < 1e-6


def test_warm_up_loads_every_kernel():
    out = fast.warm_up()
    assert out['seconds'] >= 0.0


def test_compiled_joint_separation_matches_world():
    for d in (scene_dict('default'), chain_dict(12), _ring(4)):
        w = World(Scene.from_dict(d), backend='numba')
        for j in w.actuated_joint_names:
            w.set_torque(j, 3.0)
        w.step(20)
        assert fast_step.max_joint_separation(w) == pytest.approx(w.max_joint_separation(),
                                                                  rel=1e-6, abs=1e-14)


def test_without_numba_auto_falls_back_to_numpy_with_one_warning():
    code = '''
import sys, warnings
sys.modules['numba'] = None                 # numba not importable
from abd_joint_sim import Scene, World
from physics_helpers import hinge_dict
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter('always')
    worlds = [World(Scene.from_dict(hinge_dict())) for _ in range(2)]
    worlds[0].step(3)
assert [w.backend for w in worlds] == ['numpy', 'numpy']
assert len([c for c in caught if 'numba' in str(c.message)]) == 1, caught
try:
    World(Scene.from_dict(hinge_dict()), backend='numba')
except RuntimeError as exc:
    assert 'not importable' in str(exc)
else:
    raise AssertionError('explicit numba must fail without numba')
'''
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), str(REPO / 'test')]))
    env.pop('ABD_BACKEND', None)
    proc = subprocess.run([sys.executable, '-c', code], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]


@pytest.mark.parametrize('case', ['default_torques', 'default_bdf2', 'default_idle', 'hinge_substeps'])
def test_step_clean_is_bit_identical_to_single_steps(case):
    """World.step_clean (sim_node's batches: several steps per compiled call) must leave the
    same state, bit for bit, as the same number of World.step calls, report each step's
    joint angles, and stop before a step World.step would sub-step or warn on (the large
    torque on the hinge: every step), which the caller then takes with World.step."""
    d, n, setup = {
        'default_torques': (scene_dict('default'), 300, _torques(3.0)),
        'default_bdf2': (dict(scene_dict('default'), integrator='bdf2'), 300, _torques(-4.0)),
        'default_idle': (scene_dict('default'), 100, None),
        'hinge_substeps': (hinge_dict(dt=0.01), 20, _torques(1e5)),
    }[case]
    one, batched = World(Scene.from_dict(d), backend='numba'), World(Scene.from_dict(d), backend='numba')
    for w in (one, batched):
        if setup:
            setup(w)
    angles_one, angles_batched, fallbacks, steps = [], [], 0, 0
    for _ in range(n):
        one.step()
        angles_one.append(one.state.joint_angle.copy())
    while steps < n:
        count, times, angles, _ = batched.step_clean(min(7, n - steps))
        assert len(times) == count == len(angles)
        angles_batched += [a.copy() for a in angles]
        steps += count
        if count == 0:
            batched.step()
            angles_batched.append(batched.state.joint_angle.copy())
            fallbacks += 1
            steps += 1
    for f in ('time', 'q', 'v', 'q_prev', 'v_prev', 'warm_start', 'joint_angle', 'joint_velocity',
              'step_count', 'history_dt'):
        assert np.array_equal(getattr(one.state, f), getattr(batched.state, f)), f
    assert np.array_equal(np.array(angles_one), np.array(angles_batched))
    assert _report_key(one.last_step) == _report_key(batched.last_step)
    if case == 'hinge_substeps':
        assert fallbacks == n                   # every step sub-steps: none is clean
    else:
        assert fallbacks == 0


def test_step_clean_takes_no_step_on_numpy():
    w = World(Scene.from_dict(scene_dict('default')), backend='numpy')
    count, times, angles, velocities = w.step_clean(5)
    assert count == 0 and times == [] and angles.shape == (0, 2) and w.state.step_count == 0
