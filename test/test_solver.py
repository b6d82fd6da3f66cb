"""The Solver's behaviour (abd_joint_sim/solver/): the linear-solve choice, small dense
kernels against LAPACK, the refusal of a step predicted to turn too far, the degenerate
torque-axis guard, states never written in place, batching bit-identical to single steps,
round-off staying round-off, the joint-came-apart fault, the compile-once cache and the
import layering."""
from __future__ import annotations

import ast
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from abd_joint_sim import Scene, SimulationError, World
from abd_joint_sim.smallmat import eigh_ql_in, jacobi_eigh, svd3_in
from abd_joint_sim.solver import linsolve

from physics_helpers import box, chain_dict, forward_block, hinge_dict, random_rotation, scene_dict

REPO = Path(__file__).resolve().parents[1]


def _report_key(r):
    return (r.newton_iterations, r.line_search_iterations, r.status, r.converged, r.substeps,
            tuple(r.warnings))


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


def _world(d):
    return World(Scene.from_dict(d))


# -- linear solve and small kernels -----------------------------------------------------------
@pytest.mark.slow
def test_a_large_loop_is_refused_with_a_message_and_a_small_one_runs_dense():
    with pytest.raises(ValueError, match='closed loop.*at most 64'):
        _world(_ring(70))
    small = _world(_ring(4))
    assert small.solver.data.solve_kind == linsolve.DENSE
    small.step(5)
    assert small.last_step.converged
    tree = _world(_tree())
    assert tree.solver.data.solve_kind == linsolve.TREE


def _check_elimination(nf, sp, sc):
    """linsolve's order over the forest with edges (sp, sc): children first along graph
    edges, one root per component; returns (order, parent, depth of the deepest body)."""
    order, parent = linsolve._forest(nf, np.asarray(sp, dtype=np.int64), np.asarray(sc, dtype=np.int64))
    assert sorted(order.tolist()) == list(range(nf))
    position = {int(s): t for t, s in enumerate(order)}
    edges = {frozenset((int(a), int(b))) for a, b in zip(sp, sc)}
    for s_, p in enumerate(parent.tolist()):
        if p >= 0:
            assert position[p] > position[s_] and frozenset((s_, p)) in edges
    components = nf - len(edges)                 # a forest: one root per component
    assert int((parent < 0).sum()) == components
    depth = 0
    for s_ in range(nf):
        d, x = 0, s_
        while parent[x] >= 0:
            x, d = int(parent[x]), d + 1
        depth = max(depth, d)
    return order, parent, depth


def test_the_tree_solve_order_roots_each_tree_at_its_centre():
    """A chain is eliminated from both ends towards its middle; random forests keep the
    order's rules: children first along edges, one root per tree."""
    for n in (1, 2, 3, 4, 7, 10, 31):
        _, _, depth = _check_elimination(n, range(n - 1), range(1, n))
        assert depth == n // 2                  # rooted at the middle
    rng = np.random.default_rng(5)
    for trial in range(200):
        n = int(rng.integers(1, 40))
        sp, sc = [], []
        for c in range(1, n):                   # a random forest: attach to an earlier slot, or not
            if rng.random() < 0.85:
                sp.append(int(rng.integers(0, c)))
                sc.append(c)
        perm = rng.permutation(n)               # slots in any order
        _check_elimination(n, perm[sp].tolist(), perm[sc].tolist())


def _textbook_cholesky(W):
    """The row-by-row lower Cholesky factor in plain Python floats (IEEE doubles, each
    operation rounded as compiled code rounds it): (L with W's upper half, 1/diag(L)), or
    None at a pivot that is not positive."""
    W = [[float(x) for x in row] for row in W]
    inv_d = [0.0] * 12
    for i in range(12):
        for j in range(i + 1):
            s = W[i][j]
            for k in range(j):
                s -= W[i][k] * W[j][k]
            if j < i:
                W[i][j] = s * inv_d[j]
            elif not s > 0.0:
                return None
            else:
                W[i][i] = math.sqrt(s)
                inv_d[i] = 1.0 / W[i][i]
    return np.array(W), np.array(inv_d)


def test_the_block_factor_gives_the_bits_of_the_textbook_loop():
    """factor_block runs in three passes that the compiler unrolls (its docstring): the same
    sum for every entry as the one row-by-row loop, so the same bits, signed zeros included
    (a body's own block has exact zeros where its translation rows do not couple); and
    False at a pivot that is not positive, in either pass."""
    rng = np.random.default_rng(3)
    cases = []
    for trial in range(30):
        a = rng.standard_normal((12, 12)) * 10.0 ** rng.integers(-3, 4)
        cases.append(a @ a.T + 1e-3 * np.eye(12))
    leaf = cases[0].copy()                      # the translation rows of a body's own block
    for r in range(3):
        for c in range(12):
            if c != r and (c < 3 or (c - 3) // 3 != r):
                leaf[r, c] = leaf[c, r] = -0.0 if (r + c) % 2 else 0.0
    leaf[:3, :3] += 50.0 * np.eye(3)
    cases.append(leaf)
    for W in cases:
        expected = _textbook_cholesky(W)
        blocks, inv_d = W[None].copy(), np.zeros((1, 12))
        assert linsolve.factor_block(blocks, 0, inv_d, 0)
        L, d = expected
        assert np.array_equal(np.signbit(np.tril(blocks[0])), np.signbit(np.tril(L)))
        assert np.array_equal(np.tril(blocks[0]), np.tril(L)) and np.array_equal(inv_d[0], d)
    for pivot in (1, 7):                        # not PD in the first pass, and in the last
        bad = cases[1].copy()
        bad[pivot, pivot] = -1.0
        assert _textbook_cholesky(bad) is None
        assert not linsolve.factor_block(bad[None].copy(), 0, np.zeros((1, 12)), 0)
    nan = cases[2].copy()
    nan[11, 11] = np.nan
    assert not linsolve.factor_block(nan[None].copy(), 0, np.zeros((1, 12)), 0)


def test_svd3_matches_lapack():
    rng = np.random.default_rng(2)
    cases = [random_rotation(rng), np.diag([1.0, 1.0, 1e-9]), np.diag([2.0, 0.0, 0.0]),
             -random_rotation(rng)] + [rng.normal(size=(3, 3)) for _ in range(20)]
    for A in cases:
        U, S, V = np.empty((3, 3)), np.empty(3), np.empty((3, 3))
        svd3_in(A, U, S, V, np.empty((2, 3, 3)))
        assert np.abs(S - np.linalg.svd(A, compute_uv=False)).max() <= 1e-13 * max(1.0, np.abs(A).max())
        assert np.abs(U * S @ V.T - A).max() <= 1e-13 * max(1.0, np.abs(A).max())
        assert np.abs(U.T @ U - np.eye(3)).max() < 1e-13 and np.abs(V.T @ V - np.eye(3)).max() < 1e-13


def test_jacobi_eigh_matches_lapack():
    rng = np.random.default_rng(5)
    for n in (3, 12):
        X = rng.normal(size=(n, n))
        S = X + X.T
        w, V = np.empty(n), np.empty((n, n))
        jacobi_eigh(S.copy(), w, V, 50)
        assert np.abs(np.sort(w) - np.linalg.eigvalsh(S)).max() <= 1e-13 * np.abs(S).max()
        assert np.abs(V * w @ V.T - S).max() <= 1e-13 * np.abs(S).max()


def test_ql_eigh_matches_lapack_on_general_degenerate_and_rank_deficient_matrices():
    """smallmat.eigh_ql_in (the angle terms' 12x12 projection) against LAPACK."""
    rng = np.random.default_rng(7)
    for n in (3, 12):
        for kind in range(3):
            X = rng.normal(size=(n, n))
            S = X + X.T
            if kind == 1:                       # rank 3, like an angle term's Hessian
                G = rng.normal(size=(n, 3))
                S = 10 * G @ G.T - np.outer(G[:, 0], G[:, 0])
            elif kind == 2:                     # two clusters of equal eigenvalues
                S = np.diag(np.r_[np.ones(n // 2), -np.ones(n - n // 2)]) + 1e-9 * S
            w, V = np.empty(n), np.empty((n, n))
            assert eigh_ql_in(S.copy(), w, V, np.empty(n))  # converged, no Jacobi fallback
            scale = np.abs(S).max()
            assert np.abs(np.sort(w) - np.linalg.eigvalsh(S)).max() <= 1e-13 * scale
            assert np.abs(V * w @ V.T - S).max() <= 1e-13 * scale
            assert np.abs(V.T @ V - np.eye(n)).max() <= 1e-13


# -- single steps -------------------------------------------------------------------------------
def test_predicted_rotation_is_refused_before_solving_and_sub_stepped():
    """dt = 1e-2, τ = 1e5: ∇θ·(q̃ − qⁿ) predicts 5.9 rad for the first step, which is refused
    before solving (state untouched, no Newton iteration) and sub-stepped."""
    from abd_joint_sim.solver.solver import _Tally
    w = _world(hinge_dict(dt=1e-2))
    w.set_torque('hinge', 1e5)
    start = w.state
    q0 = start.q.copy()
    tally = _Tally()
    new, failure = w.solver._decode(start, w.model.dt, *w.solver._compute(start, w.control, w.model.dt, True), tally)
    assert new is None and failure == 'a joint is predicted to turn 5.86 rad in one step (limit 1.57)'
    assert np.array_equal(start.q, q0)
    assert (tally.newton_iterations, tally.line_search_iterations, tally.warnings) == (0, 0, [])
    new, failure = w.solver._decode(start, w.model.dt, *w.solver._compute(start, w.control, w.model.dt, False),
                                    _Tally())
    assert new is not None and 'predicted' not in str(failure)      # without the flag: solved
    r = w.step()
    assert r.substeps > 1
    assert 'a joint is predicted to turn' in r.warnings[0] and 'retrying as 2 sub-steps' in r.warnings[0]


@pytest.mark.parametrize('bodies', [(1,), (0,), (0, 1)], ids=['child', 'parent', 'both'])
def test_degenerate_torque_axis_keeps_the_healthy_body_torqued(bodies):
    """A body whose A maps x̄1 − x̄0 to 0 has no usable raw axis: the other body's is used for
    both, so the healthy body keeps its torque (no NaN); with neither the torque is 0. The
    degenerate body is also singular, so it is skipped, with a warning naming it."""
    from physics_helpers import torque_force
    w = _world(scene_dict('free_pair'))
    w.set_torque('hinge', 2.0)
    for b in bodies:
        w.state.q[b, 3:12] = np.diag([1.0, 1.0, 0.0]).ravel()
    F, skipped = torque_force(w, w.state.q, [2.0])
    assert np.all(np.isfinite(F)) and sorted(skipped) == sorted(bodies)
    healthy = [k for k in (0, 1) if k not in bodies]
    for k in healthy:
        assert np.abs(F[k, 3:12]).max() > 0.0
    if not healthy:
        assert not F.any()
    r = w.step()            # the first step is taken from the singular state (ortho then restores A)
    assert sum('near-singular' in m for m in r.warnings) == len(bodies)
    for _ in range(3):
        w.step()
        assert np.all(np.isfinite(w.state.q))
    if healthy:
        k = healthy[0]
        w_z = w.state.v[k, 4] - w.state.v[k, 6]   # Ȧ[0,1] − Ȧ[1,0] ≈ −2 ω_z
        assert (w_z < 0) == (k == 1)


def test_a_step_never_writes_into_the_previous_state():
    """World keeps the old State by reference to undo a step: nothing may write into it
    (plain, bdf2, sub-stepped and predicted-split steps, single and batched)."""
    for d, tau in ((hinge_dict(integrator='bdf2'), 1000.0), (hinge_dict(dt=1e-2), 1e5),
                   (_drive_limit_hinge(), 0.0), (scene_dict('default'), 5.0)):
        w = _world(d)
        for j in w.actuated_joint_names:
            w.set_torque(j, tau)
        for n in (1, 1, 3, 1, 4):
            old = w.state
            saved = {k: getattr(old, k).copy() for k in
                     ('q', 'v', 'q_prev', 'v_prev', 'joint_angle', 'joint_velocity', 'warm_start',
                      'warm_start_prev', 'warm_start_prev2')}
            w.step(n)
            assert w.state is not old
            for k, x in saved.items():
                assert np.array_equal(getattr(old, k), x), k


def test_reset_restarts_exactly():
    d = hinge_dict(integrator='bdf2')
    a, b = _world(d), _world(d)
    a.set_torque('hinge', 500.0)
    a.step(10)
    a.reset()
    for w in (a, b):
        w.set_torque('hinge', -300.0)
        w.step(10)
    assert np.array_equal(a.state.q, b.state.q) and a.last_step == b.last_step


def test_resting_limit_does_not_amplify_roundoff():
    """The drive+limit hinge at the default tolerance against itself with a 1e-15 nudge: a
    warm start from the last correction alone kept the resting body jittering at the
    tolerance level; starting from the lower-energy guess it stays at round-off."""
    scene = Scene.from_dict(_drive_limit_hinge())
    a, b = World(scene), World(scene)
    b.state.q[1, 0] += 1e-15
    worst = 0.0
    for _ in range(400):
        a.step()
        b.step()
        worst = max(worst, float(np.abs(a.state.q - b.state.q).max()))
    assert worst < 1e-12


def test_no_line_search_wandering_at_the_roundoff_floor():
    """ring4's 2nd Newton iteration has a decrement ~1e-19 against a rounding slack
    ROUNDOFF·|Π| ~1e-19. Once the tolerances hold only the full step is tried, so a step
    never wanders there (else it takes up to 10 Newton iterations and 215 halvings)."""
    scene = Scene.from_dict(_ring(4))
    a, b = World(scene), World(scene)
    b.state.q[1, 0] += 1e-15
    for _ in range(60):
        for r in (a.step(), b.step()):
            assert r.converged and r.newton_iterations <= 2 and r.line_search_iterations <= 1, r
    assert np.abs(a.state.q - b.state.q).max() < 1e-6


# -- batching -----------------------------------------------------------------------------------
BATCH_CASES = {
    'default_torques': (scene_dict('default'), 300, _torques(3.0)),
    'default_bdf2': (dict(scene_dict('default'), integrator='bdf2'), 300, _torques(-4.0)),
    'default_idle': (scene_dict('default'), 100, None),
    'hinge_substeps': (hinge_dict(dt=0.01), 20, _torques(1e5)),
    'hinge_fast_warns': (hinge_dict(dt=0.01), 30, _torques(3000.0)),
}


def _state_fields(w):
    s = w.state
    return [s.time, s.q, s.v, s.q_prev, s.v_prev, s.warm_start, s.warm_start_prev,
            s.warm_start_prev2, s.extrapolation_order(w.dt), s.joint_angle, s.joint_velocity,
            s.step_count, s.history_dt]


@pytest.mark.parametrize('case', sorted(BATCH_CASES))
def test_n_clean_steps_are_bit_identical_to_single_steps(case):
    """World.step(n, trajectory) (sim_node's clean batches) leaves the same state, bit for bit, as the same
    number of World.step calls, reports each step's joint angles, and stops before a step
    World.step would sub-step or warn on, which the caller then takes with World.step."""
    from abd_joint_sim.world import Trajectory
    d, n, setup = BATCH_CASES[case]
    one, batched = _world(d), _world(d)
    for w in (one, batched):
        if setup:
            setup(w)
    angles_one, angles_batched, fallbacks, steps = [], [], 0, 0
    for _ in range(n):
        one.step()
        angles_one.append(one.state.joint_angle.copy())
    while steps < n:
        rows = Trajectory()
        batched.step(min(7, n - steps), rows)
        count, times, angles = rows.count, rows.times, rows.positions
        assert len(times) == count == len(angles)
        angles_batched += [a.copy() for a in angles]
        steps += count
        if count == 0:
            batched.step()
            angles_batched.append(batched.state.joint_angle.copy())
            fallbacks += 1
            steps += 1
    for x, y in zip(_state_fields(one), _state_fields(batched)):
        assert np.array_equal(x, y)
    assert np.array_equal(np.array(angles_one), np.array(angles_batched))
    assert _report_key(one.last_step) == _report_key(batched.last_step)
    if case == 'hinge_substeps':
        assert fallbacks == n                   # every step sub-steps: none is clean
    elif case == 'hinge_fast_warns':
        assert 0 < fallbacks < n                # clean until it turns > 0.1 rad per step
        assert 'damps rotation' in one.last_step.warnings[-1]
    else:
        assert fallbacks == 0


@pytest.mark.parametrize('case', sorted(BATCH_CASES))
def test_step_n_is_bit_identical_to_n_single_steps(case):
    """World.step(n) runs the clean steps in one compiled call; the result (state and the
    last report, warnings included) is that of n calls of World.step()."""
    d, n, setup = BATCH_CASES[case]
    one, many = _world(d), _world(d)
    for w in (one, many):
        if setup:
            setup(w)
    for _ in range(n):
        last = one.step()
    assert many.step(n) == last
    for x, y in zip(_state_fields(one), _state_fields(many)):
        assert np.array_equal(x, y)


@pytest.mark.parametrize('case', sorted(BATCH_CASES) + ['drive_limit'])
def test_one_step_calls_keep_the_state_in_the_solver_with_the_same_bits(case):
    """World.step() keeps the state in the solver's ring buffers (solver/resident.py) and
    builds a State only when it is read. Against Solver.step on States (the functional path)
    the reports and states are the same bits, whether the state is read between steps or
    not, replaced (`world.state = ...`), changed in place after being read (as tests and
    studies perturb one), given without its warm-start history, mixed with step(n), or taken
    through the recovery path (warnings, sub-steps); a State once read never changes
    afterwards."""
    from abd_joint_sim.state import State
    if case == 'drive_limit':
        d, n, setup = _drive_limit_hinge(), 120, None
    else:
        d, n, setup = BATCH_CASES[case]
    w, ref = _world(d), _world(d)
    for x in (w, ref):
        if setup:
            setup(x)
    s, solver = ref.state, ref.solver
    held = None
    for k in range(n):
        if k == n // 3:                     # replaced by another State (a copy of the reference's)
            w.state = s.copy()
        if k == 2 * n // 3:                 # a State without its warm-start history (a user's)
            s = State(s.time, s.q.copy(), s.v.copy(), s.q_prev.copy(), s.v_prev.copy(),
                      s.joint_angle.copy(), s.joint_velocity.copy(), s.step_count, s.history_dt,
                      s.warm_start.copy())
            w.state = s
        if k == n // 2:                     # read, then perturbed in place
            w.state.q[-1, 0] += 1e-9
            s = s.copy()
            s.q[-1, 0] += 1e-9
        if k % 7 == 3:                      # step(n) between one-step calls
            for _ in range(3):
                s, report = solver.step(s, ref.control)
            assert w.step(3) == report
            continue
        if k % 5 == 0:                      # a State read and kept
            held = (w.state, w.state.q.copy(), w.state.warm_start_prev.copy())
        s, report = solver.step(s, ref.control)
        assert w.step() == report, k
        assert w.time == s.time and np.array_equal(w.joint_angles(), s.joint_angle)
    ref.state = s
    for x, y in zip(_state_fields(w), _state_fields(ref)):
        assert np.array_equal(x, y)
    assert w.solver._resident_entry is not None         # the call skipped numba's dispatcher
    assert np.array_equal(held[0].q, held[1]) and np.array_equal(held[0].warm_start_prev, held[2])
    if case in ('hinge_substeps', 'hinge_fast_warns'):
        assert report.warnings                  # the recovery path was taken


def test_a_one_step_call_whose_line_search_halved_reports_the_halvings():
    """The compiled one-step call returns a clean step's Newton iterations, or −1 when its line
    search halved the step, and the report then comes from the outcome row. A real robot
    (the Minitaur of pybullet_data, light legs under 5x the benchmark's torques) halves on
    its first step: the reports, and states, match Solver.step's on States."""
    import pybullet_data
    path = os.path.join(pybullet_data.getDataPath(), 'quadruped', 'minitaur_derpy.urdf')
    w, ref = World(Scene.from_urdf(path, dt=1e-3)), World(Scene.from_urdf(path, dt=1e-3))
    for x in (w, ref):
        for k, name in enumerate(x.actuated_joint_names):
            x.set_torque(name, 5.0 * (-1) ** k * (2.0 - 0.2 * k))
    s, halved = ref.state, 0
    for _ in range(4):
        s, report = ref.solver.step(s, ref.control)
        assert w.step() == report
        halved += report.line_search_iterations > 0 and not report.warnings
    assert halved                                       # the path was taken
    ref.state = s
    for x, y in zip(_state_fields(w), _state_fields(ref)):
        assert np.array_equal(x, y)


def test_a_state_set_in_another_layout_is_stepped_as_numpy_copies_it_and_a_wrong_shape_is_refused():
    """World.step() copies a State that was set into the solver's ring in one compiled call
    (resident.load_ring). A State whose arrays are Fortran-ordered or strided views steps
    exactly as the same State in plain arrays; one whose q has a body too many raises
    numpy's ValueError naming the shapes, and copies nothing."""
    from abd_joint_sim.state import State
    d, _, setup = BATCH_CASES['default_torques']
    w, ref = _world(d), _world(d)
    for x in (w, ref):
        setup(x)
        x.step(5)
    s = ref.state

    def strided(a):                         # every other column of a wider array
        wide = np.zeros(a.shape[:-1] + (2 * a.shape[-1],))
        wide[..., ::2] = a
        return wide[..., ::2]
    odd = State(s.time, np.asfortranarray(s.q), strided(s.v), strided(s.q_prev),
                np.asfortranarray(s.v_prev), strided(s.joint_angle), s.joint_velocity.copy(),
                s.step_count, s.history_dt, strided(s.warm_start), np.asfortranarray(s.warm_start_prev),
                strided(s.warm_start_prev2))
    assert not odd.q.flags.c_contiguous and not odd.v.flags.c_contiguous
    w.state = odd
    ref.state = s.copy()
    for _ in range(3):
        assert w.step() == ref.step()
    for x, y in zip(_state_fields(w), _state_fields(ref)):
        assert np.array_equal(x, y)
    before = w.state.copy()
    bad = before.copy()
    bad.q = np.vstack([bad.q, bad.q[-1:]])
    w.state = bad
    with pytest.raises(ValueError, match='broadcast'):
        w.step()
    w.state = before
    w.step()
    ref.step()
    assert np.array_equal(w.state.q, ref.state.q)


def test_body_pose_reads_the_solver_buffers_without_building_a_state():
    """World.body_pose after one-step calls copies the body's row of the solver's ring: no
    State is built (which, with its copy back before the next step, cost more than half a
    7-joint arm's step), the values are the state's, and changing the returned arrays
    changes nothing in the World."""
    d, _, setup = BATCH_CASES['default_torques']
    w = _world(d)
    setup(w)
    name = w.body_names[-1]
    for _ in range(4):
        w.step()
    p, A = w.body_pose(name)
    assert w._resident._state is None
    p[:] = 7.0
    A[:] = 7.0
    q = w.state.q[w.body_names.index(name)]
    p2, A2 = w.body_pose(name)
    assert np.array_equal(p2, q[:3]) and np.array_equal(A2, q[3:12].reshape(3, 3))
    assert not (p2 == 7.0).any()


def test_a_failed_one_step_call_keeps_the_last_good_state():
    """SimulationError from World.step() leaves the state of the last good step: one held
    only in the solver's buffers (never read as a State), and one read and changed in place
    (a joint flown apart)."""
    d = chain_dict(3, torque=0.5)
    w, twin = _world(d), _world(d)
    for x in (w, twin):
        x.step(5)
        x.step()
    w.control.torque_value[:] = 1e300       # (set_torque refuses it: written past the check)
    with pytest.raises(SimulationError, match='non-finite'):
        w.step()
    for x, y in zip(_state_fields(w), _state_fields(twin)):
        assert np.array_equal(x, y)
    w.control.torque_value[:] = twin.control.torque_value
    assert w.step() == twin.step()          # and steps on from it as if nothing happened
    w.state.q[2, :3] += 1e16                # the forearm flies off
    before = _state_fields(w)
    with pytest.raises(SimulationError, match='came apart'):
        w.step()
    for x, y in zip(_state_fields(w), before):
        assert np.array_equal(x, y)


@pytest.mark.parametrize('case', ['chain', 'drive_limit', 'every_term', 'swinging_hinge'])
def test_the_compiled_step_allocates_nothing_per_step(case):
    """The arrays a step works in live in the Solver's Workspace (docs/decisions.md):
    an allocation inside the step costs a malloc. Counted by numba's NRT
    statistics: a batch of 200 steps allocates what one of 20 does (the call's own
    arguments), on a chain under torque, with the screw retraction and the torque axes at
    work, and with gravity; on a hinge whose drive holds it in its limit (the angle
    terms' work array); on the warm-up's scene with every term (the prismatic joints'
    rates); and on a hinge swinging under gravity (the shape term's projected Hessian)."""
    from numba.core.runtime import _nrt_python as nrt      # (numba is pinned)
    from abd_joint_sim.jit.warmup import _scene, _terms_scene
    if case == 'chain':
        w = _world(chain_dict(4, torque=0.8, gravity=(0.0, 0.0, -9.81)))
        w.step(5)
    elif case == 'drive_limit':
        w = _world(_drive_limit_hinge())
        w.step(60)
        assert w.state.joint_angle[0] > 0.3 + 0.05          # past the upper limit: it is active
    else:
        hinge = dict(name='j', parent='base', child='b0', p0=[0.1, 0, -0.05], p1=[0.1, 0, 0.05])
        w = World(_terms_scene() if case == 'every_term' else
                  _scene(['b0'], [hinge], gravity=[0.0, -9.81, 0.0]))
        for j in w.actuated_joint_names:
            w.set_effort(j, 0.5)
        w.step(5)
    was_on = nrt.memsys_stats_enabled()
    nrt.memsys_enable_stats()
    try:
        counts = []
        for n in (20, 200):
            before = nrt.memsys_get_stats_alloc()
            w.step(n)
            counts.append(nrt.memsys_get_stats_alloc() - before)
    finally:
        if not was_on:
            nrt.memsys_disable_stats()
    assert w.last_step.newton_iterations >= 1
    if case == 'chain':
        assert abs(w.joint_velocities()).max() > 0.1
    assert counts[0] > 0 and counts[1] == counts[0], counts


@pytest.mark.slow
def test_the_bound_entry_point_never_reads_an_array_of_another_layout():
    """Solver calls the compiled step's entry point directly (no per-call typing) only with
    arrays the step made or Control arrays it checked; a State or Control whose arrays have
    another layout (Fortran order, strided views) goes through numba's dispatcher. Both give
    the same steps, bit for bit; fed to the entry point, such arrays would be misread."""
    from abd_joint_sim.state import State
    d = chain_dict(3, torque=0.7)
    plain, odd = _world(d), _world(d)
    for w in (plain, odd):
        w.set_torque('j3', 2.0)
    def strided(a):
        out = np.zeros((2,) + a.shape, dtype=a.dtype, order='F')[1]
        out[...] = a
        return out
    for k in range(12):
        plain.step()
        s = odd.state
        if k % 3 == 0:              # a State of odd arrays, as a user might build one
            odd.state = State(s.time, np.asfortranarray(s.q), strided(s.v), strided(s.q_prev),
                              np.asfortranarray(s.v_prev), strided(s.joint_angle),
                              s.joint_velocity, s.step_count, s.history_dt, strided(s.warm_start),
                              strided(s.warm_start_prev), strided(s.warm_start_prev2))
            assert not odd.state.q.flags.c_contiguous and not odd.state.v.flags.c_contiguous
        if k == 5:                  # Control arrays replaced by strided views
            c = odd.control
            c.torque_value = strided(c.torque_value)
            c.torque_enabled = strided(c.torque_enabled)
            assert not c.torque_value.flags.c_contiguous
        odd.step()
    assert plain.solver._resident_entry is not None and odd.solver._resident_entry is not None
    # World.step() calls the entry point with the plain Control, the dispatcher with the odd one
    assert plain._resident.io_key[-1] is True and odd._resident.io_key[-1] is False
    for x, y in zip(_state_fields(plain), _state_fields(odd)):
        assert np.array_equal(x, y)
    # and the odd arrays really are read where they are: a torque written into the strided
    # Control array takes effect exactly as in the plain one
    plain.set_torque('j1', -3.0)
    odd.set_torque('j1', -3.0)
    for _ in range(5):
        plain.step()
        odd.step()
    for x, y in zip(_state_fields(plain), _state_fields(odd)):
        assert np.array_equal(x, y)


def test_solver_step_calls_the_entry_point_only_with_arrays_it_made():
    """Solver.step calls step.steps' entry point directly (no per-call typing) when the
    State's arrays are those its last call made and the Control's are checked; a State or
    Control of another layout goes through numba's dispatcher. The same bits either way."""
    from abd_joint_sim.state import State

    def strided(a):
        out = np.zeros((2,) + a.shape, dtype=a.dtype, order='F')[1]
        out[...] = a
        return out
    d = chain_dict(3, torque=0.7)
    plain, odd = _world(d), _world(d)
    c = odd.control
    c.torque_value = strided(c.torque_value)
    sp, so = plain.state, odd.state
    for k in range(9):
        if k % 3 == 1:              # a State of odd arrays, as a user might build one
            odd_copies = {}         # (an unknown past warm start is the newer one itself)
            history = [odd_copies.setdefault(id(a), strided(a))
                       for a in (so.warm_start, so.warm_start_prev, so.warm_start_prev2)]
            so = State(so.time, np.asfortranarray(so.q), strided(so.v), strided(so.q_prev),
                       np.asfortranarray(so.v_prev), strided(so.joint_angle), so.joint_velocity,
                       so.step_count, so.history_dt, *history)
        sp, rp = plain.solver.step(sp, plain.control)
        so, ro = odd.solver.step(so, c)
        assert rp == ro
    assert plain.solver._entry is not None              # the plain calls skipped the dispatcher
    assert odd.solver._control == (None,) * 5           # the strided Control never reached it
    plain.state, odd.state = sp, so
    for x, y in zip(_state_fields(plain), _state_fields(odd)):
        assert np.array_equal(x, y)


# -- faults ---------------------------------------------------------------------------------------
@pytest.mark.parametrize('distance', [1e16, 1e10])
def test_a_joint_that_came_apart_is_a_fault_and_the_state_is_kept(distance):
    """Anchors > 1e3 x the bodies' size apart: no valid state, SimulationError naming the
    joint, the World keeps the last good state (not only a warning)."""
    w = _world(scene_dict('default'))
    w.step(2)
    w.state.q[2, :3] += distance                       # the forearm flies off
    good = w.state
    with pytest.raises(SimulationError, match=r"joint '(elbow|shoulder)' came apart: anchors .* m apart"):
        w.step(3)
    assert w.state is good and w.time == pytest.approx(2 * w.dt)


def test_a_failed_step_names_a_torque_its_body_cannot_carry_at_this_dt():
    """A step that fails even with sub-steps says which torque alone would turn its lighter
    body more than the accuracy threshold in one step from rest, ½ (τ/I) dt² with I the
    body's moment about the joint's axis from its affine mass matrix: checked against the
    parallel-axis value of a URDF link (I_xx + m d²), and silent for a torque that is not."""
    from test_urdf import inertial, joint, link, robot
    text = robot(link('base', inertial(1.0)),
                 link('finger', inertial(0.001, xyz='0 0.01 0.02', ixx=1e-9, iyy=2e-9, izz=2e-9)),
                 joint('j', 'revolute', 'base', 'finger', axis='1 0 0',
                       extra='<limit lower="-3" upper="3" effort="50"/>'))
    w = World(Scene.from_urdf(text, gravity=[0, 0, 0]))
    i_axis = 1e-9 + 0.001 * (0.01 ** 2 + 0.02 ** 2)
    assert w.solver.axis_inertia(0) == pytest.approx(i_axis, rel=1e-12)
    w.set_torque('j', 1.0)
    hint = w.solver._torque_hint(w.control)
    turn = 0.5 * 1.0 / i_axis * w.dt ** 2
    assert f"joint 'j' (1 N m on a body of {i_axis:.3g} kg m^2" in hint and f'{turn:.3g} rad' in hint
    w.set_torque('j', 1e-4)
    assert w.solver._torque_hint(w.control) == ''
    w.set_torque('j', 1.0)
    w.set_torque_enabled('j', False)
    assert w.solver._torque_hint(w.control) == ''


def test_a_moderately_overloaded_joint_only_warns():
    d = hinge_dict()
    d['joints'][0]['strength_ratio'] = 1e-4            # a weak joint keeps its separation
    w = _world(d)
    w.state.q[1, :3] += 0.05 * w.model.body_size[1]   # 5 % of the body: overloaded, not apart
    r = w.step()
    assert any("joint 'hinge' anchors" in m and 'overloaded' in m for m in r.warnings)
    assert r.max_joint_separation > 0.0


# -- compile once, and layering ---------------------------------------------------------------
@pytest.mark.slow
def test_warm_up_command_reports_and_the_cache_is_shared(tmp_path):
    """`python -m abd_joint_sim.jit.warmup` succeeds; the cache lives outside the source tree, in
    one directory keyed on the kernel sources, so an install (another copy of the same
    files) finds it (cache.py)."""
    from abd_joint_sim.jit import cache
    proc = subprocess.run([sys.executable, '-m', 'abd_joint_sim.jit.warmup'], cwd=REPO, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert 'physics kernels' in proc.stdout
    assert cache.marker().exists()
    assert REPO not in cache.directory().parents
    copy = tmp_path / 'abd_joint_sim'
    import shutil
    shutil.copytree(REPO / 'abd_joint_sim', copy, ignore=shutil.ignore_patterns('__pycache__'))
    code = ('import abd_joint_sim, abd_joint_sim.jit.cache as c, sys; '
            'assert abd_joint_sim.__file__.startswith(sys.argv[1]), abd_joint_sim.__file__; '
            'print(c.marker())')
    out = subprocess.run([sys.executable, '-c', code, str(copy)], cwd=tmp_path, capture_output=True,
                         text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(tmp_path)))
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == str(cache.marker())     # same sources, same cache entry


@pytest.mark.slow
def test_kernel_cache_is_per_source_version_and_pruned(tmp_path):
    """Another version of the kernel sources (here: a copy with one kernel file edited) gets its
    own cache directory, so versions used alternately neither recompile over each other nor
    read each other's index (numba unpickles an index's signatures before checking its stamp:
    a type the running version lacks was an ImportError); `prune` keeps the KEEP newest."""
    import shutil
    from abd_joint_sim.jit import cache
    copy = tmp_path / 'pkg' / 'abd_joint_sim'
    shutil.copytree(REPO / 'abd_joint_sim', copy, ignore=shutil.ignore_patterns('__pycache__'))
    with open(copy / 'terms' / 'gravity.py', 'a') as f:
        f.write('\n# an edit\n')
    code = ('import abd_joint_sim.jit.cache as c; print(c.directory())')
    env = dict(os.environ, PYTHONPATH=str(tmp_path / 'pkg'), ABD_KERNEL_CACHE=str(tmp_path / 'cache'))
    out = subprocess.run([sys.executable, '-c', code], cwd=tmp_path, capture_output=True, text=True,
                         timeout=120, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    edited = Path(out.stdout.strip())
    env['PYTHONPATH'] = str(REPO)
    out = subprocess.run([sys.executable, '-c', code], cwd=tmp_path, capture_output=True, text=True,
                         timeout=120, env=env)
    ours = Path(out.stdout.strip())
    assert edited.parent == ours.parent and edited != ours
    # prune: compiled versions beyond KEEP go, oldest first; an unfinished recent one stays
    root = ours.parent
    root.mkdir(parents=True, exist_ok=True)
    for k in range(cache.KEEP + 2):
        d = root / f'{k:020d}'
        d.mkdir()
        (d / f'compiled-{k}').write_text('')
        os.utime(d, (1000 + k, 1000 + k))
    (root / 'unfinished').mkdir()
    edited.mkdir(exist_ok=True)                 # (importing the package may have made it)
    code = ('import abd_joint_sim.jit.cache as c; c.mark_compiled()')
    out = subprocess.run([sys.executable, '-c', code], cwd=tmp_path, capture_output=True, text=True,
                         timeout=120, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    left = sorted(d.name for d in root.iterdir())
    assert left == sorted([ours.name, edited.name, 'unfinished'] + [f'{k:020d}' for k in range(3, cache.KEEP + 2)])


@pytest.mark.slow
def test_an_unreadable_kernel_cache_index_is_compiled_over(tmp_path):
    """A cache index that cannot be unpickled (here: one naming a module that does not exist,
    as another version's index did; or truncated) costs a compile, not a traceback."""
    env = dict(os.environ, PYTHONPATH=str(REPO), ABD_KERNEL_CACHE=str(tmp_path / 'cache'))
    code = ('import numpy as np; from abd_joint_sim import smallmat; U, S, V = np.zeros((3, 3)), '
            'np.zeros(3), np.zeros((3, 3)); smallmat.svd3_in(np.diag([2.0, 3.0, 1.0]), U, S, V, '
            'np.zeros((2, 3, 3))); print(S.tolist())')
    first = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=300, env=env)
    assert first.returncode == 0, first.stderr[-2000:]
    indexes = list((tmp_path / 'cache').rglob('smallmat.svd3_in-*.nbi'))
    assert indexes
    import pickle
    # a pickle of a global from a module that does not exist (hand-written opcodes: protocol 0
    # GLOBAL 'abd_joint_sim.no_such_module Missing', then STOP)
    missing = b'cabd_joint_sim.no_such_module\nMissing\n.'
    for index in indexes:
        with open(index, 'rb') as f:
            version = pickle.load(f)
        with open(index, 'wb') as f:
            pickle.dump(version, f)
            f.write(missing)
    again = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=300, env=env)
    assert again.returncode == 0, again.stderr[-2000:]
    assert again.stdout == first.stdout and 'Traceback' not in again.stderr


def _imports(path: Path, module: str, package: str = 'abd_joint_sim'):
    """Modules of `package` imported by the file of `module` (relative imports resolved)."""
    is_init = path.name == '__init__.py'
    base = module.split('.') if is_init else module.split('.')[:-1]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                parts = base[:len(base) - node.level + 1]
                name = '.'.join(parts + ([node.module] if node.module else []))
            else:
                name = node.module or ''
            if name.startswith(package):
                out.add(name)
                out.update(f'{name}.{a.name}' for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith(package))
    return out


def _module(path: Path) -> str:
    mod = '.'.join(path.relative_to(REPO).with_suffix('').parts)
    return mod[:-len('.__init__')] if mod.endswith('.__init__') else mod


def _layer_violations(files):
    """(file, bad imports) for modules below World that import World, the node, the tools or
    the warm-up, for terms/ and smallmat importing the solver, and for jit/ importing the rest."""
    bad = []
    for path, module in files:
        imported = _imports(path, module)
        up = {m for m in imported if m.startswith(('abd_joint_sim.world', 'abd_joint_sim.ros',
                                                   'abd_joint_sim.tools', 'abd_joint_sim.jit.warmup'))}
        if module.startswith('abd_joint_sim.terms') or module == 'abd_joint_sim.smallmat':
            up |= {m for m in imported if m.startswith('abd_joint_sim.solver')}
        if module.startswith('abd_joint_sim.jit'):          # the compiler machinery: the ground floor
            up |= {m for m in imported if m.startswith('abd_joint_sim.') and not m.startswith('abd_joint_sim.jit')}
        if up:
            bad.append((path.name, up))
    return bad


def test_physics_layers_import_downward_only():
    """terms/ knows nothing of the solver, jit/ (but the warm-up) nothing of the physics, the
    solver nothing of World, and no module below World imports it (or the node): no cycle,
    nothing reaches up."""
    pkg = REPO / 'abd_joint_sim'
    below_world = [*sorted((pkg / 'terms').glob('*.py')), *sorted((pkg / 'solver').glob('*.py')),
                   *sorted(f for f in (pkg / 'jit').glob('*.py') if f.name != 'warmup.py'),
                   pkg / 'smallmat.py', pkg / 'model.py', pkg / 'state.py']
    assert _layer_violations([(f, _module(f)) for f in below_world]) == []


def test_import_layer_check_can_fail(tmp_path):
    probe = tmp_path / 'probe.py'
    probe.write_text('from ..world import World\nfrom ..solver.step import steps\n')
    bad = _layer_violations([(probe, 'abd_joint_sim.terms.probe')])
    assert bad and bad[0][1] == {'abd_joint_sim.world', 'abd_joint_sim.world.World', 'abd_joint_sim.solver.step',
                                 'abd_joint_sim.solver.step.steps'}


def test_a_first_compile_is_announced_before_it_starts(monkeypatch, tmp_path, capsys):
    """Without the compiled-marker, ensure_compiled prints its line to stderr BEFORE the
    kernels run (a first run never waits in silence); with it, nothing is printed."""
    from abd_joint_sim.jit import cache, warmup
    seen = []

    def fake_run():
        seen.append(capsys.readouterr().err)      # what was printed before compiling
    monkeypatch.setattr(warmup, '_run_kernels', fake_run)
    monkeypatch.setattr(warmup, '_done', False)
    monkeypatch.setenv('ABD_COMPILE_JOBS', '1')         # (no second compiling process)
    monkeypatch.setattr(cache, 'marker', lambda: tmp_path / 'compiled-marker')
    monkeypatch.setattr(cache, 'mark_compiled', lambda: (tmp_path / 'compiled-marker').write_text(''))
    out = warmup.ensure_compiled()
    assert out['compiled'] and 'compiling the physics kernels (first run on this machine' in seen[0]
    monkeypatch.setattr(warmup, '_done', False)
    out = warmup.ensure_compiled()
    assert not out['compiled'] and seen[1] == '' and capsys.readouterr().err == ''


def _demo_arm_driven():
    s = Scene.from_urdf(str(REPO / 'abd_joint_sim' / 'robots' / 'demo_arm.urdf'), gravity=[0, 0, 0],
                        driving={'enabled': True})
    return World(s)


def test_two_large_drive_aims_at_once_converge_to_the_aims():
    """A drive is K/2 (θ − target)², K = γ(m_i+m_j), no h²: a stiff pull that brings the
    joint to its aim within a step. Two aims of 0.3 rad set at once, with the curvature
    Hessian, send Newton into singular A (SimulationError); with Gauss-Newton they converge, the bodies stay rigid and the
    joints sit at their aims (the inertia against K makes the gap ~1e-4 rad). The bodies are
    strained by a few % (the pull is stiff against κ at this dt; the full curvature Hessian gives
    the same strains, to 5 digits, for one such aim alone, which it can solve) but far from
    the singular A the failure went to."""
    w = _demo_arm_driven()
    w.set_drive('elbow', aim=0.3)
    w.set_drive('shoulder_pan', aim=-0.2)
    r = w.step()
    assert r.converged and r.substeps == 1
    names = list(w.joint_names)
    angles = w.joint_angles()
    assert angles[names.index('elbow')] == pytest.approx(0.3, abs=3e-3)
    assert angles[names.index('shoulder_pan')] == pytest.approx(-0.2, abs=3e-3)
    for b in w.body_names:
        _, A = w.body_pose(b)
        assert np.abs(A @ A.T - np.eye(3)).max() < 0.1 and np.linalg.det(A) > 0.8, b
    for _ in range(20):                 # and it stays there
        w.step()
    assert w.joint_angles()[names.index('elbow')] == pytest.approx(0.3, abs=3e-3)


def test_a_drive_aim_beyond_one_step_fails_with_what_to_do():
    """An aim more than max_step_rotation away cannot be reached in one step, and sub-steps
    ask for the same turn: the error names the drive and says to move the aim gradually;
    the state is kept."""
    w = _demo_arm_driven()
    w.set_drive('elbow', aim=3.0)
    with pytest.raises(SimulationError, match=r"'elbow'.*aim 3 rad.*smaller increments"):
        w.step()
    assert w.time == 0.0
    w.set_drive('elbow', aim=1.0)       # a reachable aim then works from the kept state
    assert w.step().converged


def test_a_fresh_solver_steps_exactly_like_a_used_one():
    """The Solver's Workspace carries nothing from one step to the next: a new Solver
    stepping from a state reached by another gives bit-identical results."""
    from abd_joint_sim.solver.solver import Solver
    for d in (_tree(), _ring(4), _drive_limit_hinge()):
        w = World(Scene.from_dict(d))
        _torques(0.3)(w)
        w.step(7)
        fresh = Solver(w.model)
        a, _ = w.solver.step(w.state, w.control)
        b, _ = fresh.step(w.state, w.control)
        np.testing.assert_array_equal(a.q, b.q)
        np.testing.assert_array_equal(a.joint_angle, b.joint_angle)
        np.testing.assert_array_equal(a.joint_velocity, b.joint_velocity)


_CACHE_UNWRITABLE = r'''
import resource, sys
import numpy as np
from abd_joint_sim import smallmat      # installs the package's kernel cache
A = np.array([[2.0, 0, 0], [0, 3.0, 0], [0, 0, 4.0]])
L = A.copy()
resource.setrlimit(resource.RLIMIT_FSIZE, (512, 512))     # the cache cannot be written
smallmat.cholesky(L, 3)                                    # compiles, then fails to store it
print('ok', L[0, 0], L[2, 2])
'''


@pytest.mark.slow
def test_a_kernel_cache_that_cannot_be_written_does_not_stop_the_run(tmp_path):
    """A full disk (here RLIMIT_FSIZE) under the kernel cache: one line on stderr saying the
    kernels will be compiled again, and the run goes on with correct results."""
    import os
    import signal
    import subprocess
    import sys
    env = dict(os.environ, ABD_KERNEL_CACHE=str(tmp_path / 'cache'))
    res = subprocess.run([sys.executable, '-c', _CACHE_UNWRITABLE], capture_output=True,
                         text=True, timeout=300, env=env, stdin=subprocess.DEVNULL,
                         preexec_fn=lambda: signal.signal(signal.SIGXFSZ, signal.SIG_IGN))
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.split() == ['ok', repr(2.0 ** 0.5), '2.0'], res.stdout
    lines = [ln for ln in res.stderr.splitlines() if 'could not store the compiled' in ln]
    assert len(lines) == 1 and 'compiled again next time' in lines[0], res.stderr[-3000:]


def test_the_constant_joint_blocks_are_never_written():
    """In a model without drives and limits Newton's solve reads the UID 18 joint blocks
    straight from the model (newton.assemble returns m.constant_pair, not a copy): stepping
    must leave them as built, and give the same states as a model whose joint blocks are
    copied every iteration (the same chain with a limit it never reaches)."""
    d = chain_dict(4, torque=0.5)
    plain = _world(d)
    limited = dict(d, joints=[dict(j, limit=dict(lower=-50.0, upper=50.0)) for j in d['joints']])
    other = _world(limited)
    before = plain.solver.data.constant_pair.copy()
    assert np.abs(before).max() > 0.0
    plain.step(40)
    other.step(40)
    assert np.array_equal(plain.solver.data.constant_pair, before)
    assert np.array_equal(plain.state.q, other.state.q)
    assert np.abs(plain.joint_angles()).max() > 1e-3


def _singular_arm(w):
    """The hinge's arm with a rank ~2 affine matrix and a torque: the first step skips its
    torque (warning), and the shape term restores A within it (clean steps follow)."""
    w.set_torque('hinge', 10.0)
    w.state.q[1, 3:12] = np.array([[1, 0, 0], [0, 1, 0], [1, 1e-8, 1e-8]]).ravel()


def _overloaded(w):
    w.state.q[1, :3] += 0.05 * w.model.body_size[1]   # 5 % of the body: overloaded, not apart


WARNING_CASES = {
    # every step from the 13th on turns more than 0.1 rad: bdf1's accuracy warning
    'fast_spin': (hinge_dict(dt=0.01), 30, _torques(3000.0), 'damps rotation', -1),
    'skipped_torque': (hinge_dict(), 5, _singular_arm, 'near-singular', 0),
    'overloaded': (dict(hinge_dict(), joints=[dict(hinge_dict()['joints'][0], strength_ratio=1e-4)]),
                   4, _overloaded, 'overloaded', 1),
}


@pytest.mark.parametrize('case', sorted(WARNING_CASES))
def test_step_n_keeps_steps_that_only_warn_in_its_compiled_batch(case):
    """A step that needs no sub-step but warns (a joint turned more than the accuracy
    threshold, an overloaded joint, a skipped torque) stays in World.step(n)'s compiled batch
    and in World.step()'s compiled call (step.kept): the same states, bit for bit, and the
    same reports, warnings worded, as the functional Solver.step on States; no step goes
    through the Solver's recovery. A batch ends after a step that skipped a torque (its
    `skipped` row is the step's own)."""
    d, n, setup, words, warn_at = WARNING_CASES[case]
    worlds = [_world(d) for _ in range(3)]
    for w in worlds:
        setup(w)
    ref, many, one = worlds
    s = ref.state
    reports = []
    for _ in range(n):
        s, r = ref.solver.step(s, ref.control)
        reports.append(r)
    assert words in ' '.join(reports[warn_at].warnings)
    assert all(r.substeps == 1 for r in reports)          # (1: the step itself, not split)
    recovered = []
    for w in (many, one):
        real = w.solver._recover

        def counted(*args, real=real):
            recovered.append(args)
            return real(*args)
        w.solver._recover = counted
    assert many.step(n) == reports[-1]
    assert [one.step() for _ in range(n)] == reports
    assert not recovered
    ref.state = s
    for w in (many, one):
        for x, y in zip(_state_fields(ref), _state_fields(w)):
            assert np.array_equal(x, y)


@pytest.mark.slow
def test_a_long_step_n_runs_in_bounded_batches_with_the_same_states():
    """World.step(n) runs at most `batch_limit` steps per compiled call (the batch writes every
    step's state: unbounded, World.step(100_000) would allocate gigabytes); split or not, the
    states are those of n single steps, bit for bit."""
    d = chain_dict(3, torque=0.4)
    one, split, whole = _world(d), _world(d), _world(d)
    assert 2 <= split.solver.batch_limit
    assert whole.solver.batch_limit >= 25
    split.solver.batch_limit = 4
    sizes, run = [], split.solver._run

    def counted(s, c, h, n, *args):
        sizes.append(n)
        return run(s, c, h, n, *args)
    split.solver._run = counted
    for _ in range(25):
        one.step()
    split.step(25)
    assert len(sizes) >= 6 and max(sizes) <= 4      # (a last single step goes through step())
    whole.step(25)
    for w in (split, whole):
        for x, y in zip(_state_fields(one), _state_fields(w)):
            assert np.array_equal(x, y)
    big = _world(chain_dict(1000, torque=0.0))
    assert 2 <= big.solver.batch_limit < 10        # ~1 MB of states per batch


def _subnormal_count(*arrays):
    tiny = np.finfo(float).tiny
    return sum(int(np.count_nonzero((a != 0.0) & (np.abs(a) < tiny))) for a in arrays)


@pytest.mark.slow
def test_a_long_chain_under_torque_holds_no_subnormal_numbers():
    """A disturbance decays ~10^0.7 per link along a chain, so after a few steps the far links'
    zero entries would hold subnormals (< 2.2e-308), each operation on which is ~100× slower on
    x86 (docs/decisions.md). The step flushes them to zero while it runs, and only while it
    runs: numpy after a step still keeps a subnormal."""
    from abd_joint_sim.builders import chain_scene
    from abd_joint_sim.jit import subnormals
    from physics_helpers import mxcsr
    if not subnormals.X86:
        pytest.skip('FTZ/DAZ are set on x86-64 only')      # pragma: no cover
    w = World(Scene.from_dict(chain_scene(600)))
    before = mxcsr()
    w.step(4)
    s = w.state
    assert _subnormal_count(s.q, s.v, s.q_prev, s.v_prev, s.warm_start) == 0
    # the disturbance reached far enough down the chain to have made subnormals
    moved = np.abs(s.q - w.model.body_q0).max(axis=1)
    assert np.any((moved > 0.0) & (moved < 1e-290)) and np.any(moved > 1e-4)
    assert mxcsr() & subnormals.FTZ_DAZ == before & subnormals.FTZ_DAZ
    assert np.array([1e-310])[0] * 1.0 == 1e-310


def test_flat_copies_and_fills_match_numpy_assignment():
    """jit/flat.py's loops write what `dst[...] = src` and `dst[...] = value` write, on the
    shapes the step uses (a copy into another array's memory, not a view of it)."""
    from abd_joint_sim.jit import flat
    rng = np.random.default_rng(3)
    for shape in ((7,), (5, 12), (4, 12, 12), (2, 3, 5, 12)):
        src = rng.standard_normal(shape)
        dst = np.full(shape, np.nan)
        flat.copy(dst, src)
        assert np.array_equal(dst, src) and not np.shares_memory(dst, src)
        src[(0,) * len(shape)] += 1.0
        assert not np.array_equal(dst, src)
        flat.fill(dst, -2.5)
        assert np.all(dst == -2.5)
    view = np.zeros((2, 4, 12, 12))
    flat.copy(view[1], np.ones((4, 12, 12)))        # a C-contiguous slab of a larger array
    assert view[1].all() and not view[0].any()


@pytest.mark.slow
def test_vectorised_block_kernels_give_the_bits_of_plain_loops():
    """forward_block12 and schur_update12 are written for LLVM's SLP vectoriser and always
    compiled with it (jit.kernel, slp.vectorized; numba keeps it off by default after
    miscompilations). Against the same Python functions compiled without it, and against
    the loop forms they replace (forward_block; the lower-half loop of the Schur update),
    bit for bit; forward_vector12 against forward_block with one column too."""
    from numba import njit
    plain_forward = njit(linsolve.forward_block12.py_func)
    plain_schur = njit(linsolve.schur_update12.py_func)
    rng = np.random.default_rng(11)
    for trial in range(30):
        a = rng.standard_normal((12, 12))
        W = a @ a.T + 0.5 * np.eye(12)
        d = np.empty(12)
        assert linsolve.factor_block(W[None], 0, d[None], 0)     # (in place: views of W, d)
        X0 = rng.standard_normal((12, 12)) * 10.0 ** rng.integers(-3, 4)
        X0[rng.random((12, 12)) < 0.1] = -0.0       # (a −0.0 of U becomes +0.0, as a copy)
        outs = []
        for forward in (linsolve.forward_block12, plain_forward):
            X = np.full((12, 12), np.nan)
            forward(W[None], 0, d[None], X[None], 0, X0[None], 0, False)       # U = X0
            outs.append(X)
            X = np.full((12, 12), np.nan)
            forward(W[None], 0, d[None], X[None], 0, X0.T.copy()[None], 0, True)   # U = (X0ᵀ)ᵀ
            outs.append(X)
            X = X0.copy()
            forward(W[None], 0, d[None], X[None], 0, X[None], 0, False)      # in place
            outs.append(X)
        X = 0.0 + X0
        forward_block(W, d, X, 12)
        for out in outs:
            assert np.array_equal(out, X) and not np.signbit(out[out == 0.0]).any()
        y0 = X0[:, 0].copy()
        y1, y2 = y0.copy(), y0.copy()
        linsolve.forward_vector12(W[None], 0, d[None], y1[None], 0)
        forward_block(W, d, y2.reshape((12, 1)), 1)
        assert np.array_equal(y1, y2)
        D0, y, b0 = rng.standard_normal((12, 12)), rng.standard_normal(12), rng.standard_normal(12)
        results = []
        for schur in (linsolve.schur_update12, plain_schur):
            D, b = D0.copy(), b0.copy()
            ys = np.stack([y, b])             # the child's y, then the parent's b
            schur(X[None], ys, 0, D[None], 0, 1)
            results.append((D, ys[1]))
        D, b = D0.copy(), b0.copy()
        for k in range(12):                  # the loop form, lower half
            for r in range(12):
                for c in range(r + 1):
                    D[r, c] -= X[k, r] * X[k, c]
                b[r] -= X[k, r] * y[k]
        for got, want in ((results[0], results[1]), (results[0], (D, b))):
            assert np.array_equal(np.tril(got[0]), np.tril(want[0]))
            assert np.array_equal(got[1], want[1])
        assert np.array_equal(results[0][0], results[1][0])


_SLP_PROBE = r'''
import hashlib, os, sys
import numpy as np
import pybullet_data
from abd_joint_sim import Scene, World
from abd_joint_sim.builders import chain_scene
from abd_joint_sim.jit.warmup import _loop_scene, _terms_scene
scenes = {
    'chain': Scene.from_dict(chain_scene(6, torque=0.8)),
    'every term, bdf2': _terms_scene(),
    'loop (dense solve)': _loop_scene(),
    'kuka': Scene.from_urdf(os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa', 'model.urdf')),
}
for name, scene in scenes.items():
    w = World(scene)
    for k, j in enumerate(w.actuated_joint_names):
        w.set_effort(j, (-1.0) ** k * 2.0)
    w.step(150)
    h = hashlib.sha256()
    for a in (w.state.q, w.state.v, w.state.warm_start, w.joint_angles(), w.joint_velocities()):
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    print(name, w.last_step.newton_iterations, h.hexdigest())
'''


@pytest.mark.slow
def test_a_build_without_the_vectoriser_steps_bit_identically(tmp_path):
    """The kernels are compiled with LLVM's SLP vectoriser (jit/slp.py), which numba
    keeps off because it once miscompiled. A build with ABD_SLP=0 (every kernel scalar,
    compiled afresh into its own cache) steps four scenes (tree and dense solves, BDF1 and
    BDF2, every term of both joint families, gravity, the KUKA arm into its limits) to the same bits."""
    def run(extra):
        env = dict(os.environ, **extra)
        out = subprocess.run([sys.executable, '-c', _SLP_PROBE], env=env, capture_output=True,
                             text=True, timeout=600, cwd=str(REPO))
        assert out.returncode == 0, out.stderr[-3000:]
        return [line for line in out.stdout.splitlines() if line.strip()]
    vectorised = run({})
    scalar = run({'ABD_SLP': '0', 'ABD_KERNEL_CACHE': str(tmp_path / 'cache')})
    assert len(vectorised) == 4
    assert any((tmp_path / 'cache').rglob('*.nbi'))          # it did compile its own build
    assert vectorised == scalar


def test_every_kernel_is_compiled_by_the_one_decorator():
    """No kernel of the package is compiled by a bare `njit`: each goes through `jit.kernel`,
    which gives it the on-disk cache, numpy's error model and the SLP vectoriser."""
    import re
    from numba.core.registry import CPUDispatcher
    from abd_joint_sim.jit import slp
    from abd_joint_sim.solver import newton, step
    from abd_joint_sim.terms import TERMS
    pkg = REPO / 'abd_joint_sim'
    bare = [str(f.relative_to(pkg)) for f in pkg.rglob('*.py')
            if f.parent.name != 'jit' and re.search(r'\bnjit\b', f.read_text())]
    assert bare == []
    kernels = [getattr(mod, name) for mod in (newton, step, *TERMS) for name in dir(mod)
               if isinstance(getattr(mod, name), CPUDispatcher)]
    assert len(kernels) > 40
    for k in kernels:
        assert k.targetoptions['error_model'] == 'numpy' and k._cache.__class__.__name__ != 'NullCache'
        assert k.compile.__qualname__ == slp.vectorized.__qualname__ + '.<locals>.compile', k

