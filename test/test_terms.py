"""Every compiled energy term (abd_joint_sim/terms/) against the independent oracle
(test/oracle.py, written from docs/physics.md) and against finite differences: energy =
oracle, gradient = FD of the energy, raw Hessian = FD of the gradient, symmetric, projected
Hessian PSD. The checker itself must fail on deliberately broken terms."""
import numpy as np
import pytest
from numba import njit

import oracle
from abd_joint_sim import Scene, compile_scene
from abd_joint_sim.terms import angle as angles
from abd_joint_sim.solver import model_data, newton
from abd_joint_sim.terms import damping, driving, inertia, limit, ortho, revolute, torque
from abd_joint_sim.terms import reference_shape
from abd_joint_sim.terms.context import StepContext

from physics_helpers import box, generalized_force, random_rotation, theta_and_slope_at, theta_derivatives

TERMS = {'inertia': inertia, 'ortho': ortho, 'revolute': revolute, 'driving': driving, 'limit': limit,
         'damping': damping}


MODEL_SCENE = dict(dt=0.01, bodies=[box('a', (0, 0, 0)), box('b', (0.5, 0.1, 0.0)), box('c', (1.0, 0, 0), fixed=True)],
                   joints=[dict(name='j0', parent='a', child='b', p0=[0.25, 0, -0.2], p1=[0.25, 0.1, 0.3],
                                init_angle=0.3,
                                driving=dict(aim_angle=1.2, enabled=True, strength_ratio=50.0),
                                limit=dict(lower=-0.2, upper=0.4, strength=3.0),
                                external_torque=dict(torque=1.0), damping=40.0),
                           dict(name='j1', parent='c', child='b', p0=[0.8, 0, 0], p1=[0.8, 0, 1],
                                limit=dict(lower=0.1, upper=0.1), external_torque=dict(torque=1.0))])
MODEL = compile_scene(Scene.from_dict(MODEL_SCENE))
DATA = model_data.build(MODEL)


def _state(seed, scale=0.15):
    """A generic state: rotated, sheared and displaced bodies (not near SO(3))."""
    rng = np.random.default_rng(seed)
    q = MODEL.body_q0.copy()
    for b in range(MODEL.body_count):
        if MODEL.body_fixed[b]:
            continue
        A = random_rotation(rng) @ (np.eye(3) + scale * rng.normal(size=(3, 3)))
        q[b, 3:12] = A.ravel()
        q[b, :3] += 0.05 * rng.normal(size=3)
    return q


#: the bodies one step back, for the dampers' BDF2 reference (the contexts are BDF2's, s = 9/4),
#: and Newton's start, where the dampers' angle is linearised
Q_PREV = _state(99, scale=0.1)
Q_START = _state(98, scale=0.1)


def _ctx(q_tilde=None, on=True, angle_start=None):
    J = MODEL.joint_count
    q_tilde = MODEL.body_q0.copy() if q_tilde is None else q_tilde
    start = np.zeros(J) if angle_start is None else np.asarray(angle_start, float)
    return StepContext(0.01, 9.0 / 4.0, q_tilde, start, np.full(len(MODEL.drive_joints), 0.9),
                       np.full(len(MODEL.drive_joints), on), np.empty(angles.ANGLE_WORK_SHAPE),
                       _angle_ref(start, True))


def _angle_ref(start, bdf2=False):
    """StepContext.angle_ref (newton.references): the limits' rows and the dampers'
    (linearised at Q_START)."""
    start = np.asarray(start, float)
    return newton.references(DATA, Q_START, Q_PREV, start, 0.01, bdf2,
                             np.empty(angles.ANGLE_WORK_SHAPE), np.empty(reference_shape(MODEL)))


def _oracle_energy(name, q, ctx):
    if name == 'inertia':
        return oracle.inertia_energy(MODEL, q, ctx.q_tilde, ctx.scale)
    if name == 'ortho':
        return oracle.ortho_energy(MODEL, q, ctx.h)
    if name == 'revolute':
        return oracle.revolute_energy(MODEL, q)
    if name == 'driving':
        return oracle.driving_energy(MODEL, q, ctx.angle_start, ctx.drive_target, ctx.drive_on)
    if name == 'damping':
        return oracle.damping_energy(MODEL, q, Q_START, Q_PREV, ctx.angle_start, ctx.h, True)
    return oracle.limit_energy(MODEL, q, ctx.angle_start)


def dense(term, q, ctx, project, model=None, data=None):
    """(E, ∇E (12B,), ∇²E (12B,12B)) of a compiled term, the blocks assembled densely (on
    MODEL, DATA unless another model and its compiled data are given)."""
    model, data = (MODEL, DATA) if model is None else (model, data)
    B, J = model.body_count, model.joint_count
    grad, diag, pair = np.zeros((B, 12)), np.zeros((B, 12, 12)), np.zeros((J, 12, 12))
    term.accumulate(q, data, ctx, grad, diag, pair, project)
    H = np.zeros((12 * B, 12 * B))
    for b in range(B):
        H[12 * b:12 * b + 12, 12 * b:12 * b + 12] += diag[b]
    for j in range(J):
        i_b, j_b = model.joint_parent[j], model.joint_child[j]
        H[12 * i_b:12 * i_b + 12, 12 * j_b:12 * j_b + 12] += pair[j]
        H[12 * j_b:12 * j_b + 12, 12 * i_b:12 * i_b + 12] += pair[j].T
    return term.energy(q, data, ctx), grad.ravel(), H


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), np.max(np.abs(a)), 1e-300))


def check_term(term, q, ctx, *, eps=1e-6, rtol=2e-5, name='term', model=None, data=None):
    """Raise ValueError if the term's derivatives at q disagree with finite differences of
    its own energy / gradient, its Hessian is asymmetric, or its projection is not PSD (on
    MODEL, DATA unless another model and its compiled data are given)."""
    model, data = (MODEL, DATA) if model is None else (model, data)
    E, g, H = dense(term, q, ctx, False, model, data)
    _, _, Hp = dense(term, q, ctx, True, model, data)
    dofs = np.concatenate([np.arange(12 * b, 12 * b + 12) for b in np.flatnonzero(~model.body_fixed)])
    flat = q.ravel()
    g_fd = np.zeros(len(dofs))
    H_fd = np.zeros((len(dofs), len(dofs)))
    for k, d in enumerate(dofs):
        step = eps * max(1.0, abs(flat[d]))
        qp, qm = flat.copy(), flat.copy()
        qp[d] += step
        qm[d] -= step
        qp, qm = qp.reshape(q.shape), qm.reshape(q.shape)
        g_fd[k] = (term.energy(qp, data, ctx) - term.energy(qm, data, ctx)) / (2 * step)
        H_fd[:, k] = (dense(term, qp, ctx, False, model, data)[1][dofs]
                      - dense(term, qm, ctx, False, model, data)[1][dofs]) / (2 * step)
    if not (np.all(np.isfinite(g)) and np.all(np.isfinite(H))):
        raise ValueError(f'{name}: non-finite gradient or Hessian')
    err = _rel(g[dofs], g_fd)
    if err > rtol:
        raise ValueError(f'{name}: gradient disagrees with finite differences (rel. error {err:.2e})')
    Hs = H[np.ix_(dofs, dofs)]
    err = _rel(Hs, H_fd)
    if err > rtol:
        raise ValueError(f'{name}: Hessian disagrees with finite differences (rel. error {err:.2e})')
    if _rel(Hs, Hs.T) > 1e-12:
        raise ValueError(f'{name}: Hessian is not symmetric')
    w = np.linalg.eigvalsh(Hp[np.ix_(dofs, dofs)])
    if w.min() < -1e-9 * max(1.0, abs(w).max()):
        raise ValueError(f'{name}: projected Hessian is not PSD (min eigenvalue {w.min():.3e})')
    return E


@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize('name', list(TERMS))
def test_term_energy_matches_the_oracle(name, seed):
    q = _state(seed)
    ctx = _ctx(q_tilde=_state(seed + 10), angle_start=[0.1, -0.2])
    E = TERMS[name].energy(q, DATA, ctx)
    ref = _oracle_energy(name, q, ctx)
    assert ref > 0.0, 'the state must activate the term'
    assert E == pytest.approx(ref, rel=1e-12)


def test_step_context_takes_arrays_of_any_layout():
    """StepContext is one numba type (C-contiguous writable arrays): arrays of another layout,
    a read-only q̃, the references in Fortran order and drive switches as ints, are copied
    into it, and the terms give what they give on the originals; the others are shared."""
    q = _state(3)
    ctx = _ctx(q_tilde=_state(13), angle_start=[0.1, -0.2])
    frozen_q_tilde = ctx.q_tilde.copy()
    frozen_q_tilde.flags.writeable = False
    odd = StepContext(ctx.h, ctx.scale, frozen_q_tilde, ctx.angle_start, ctx.drive_target,
                      ctx.drive_on.astype(int), ctx.angle_work, np.asfortranarray(ctx.angle_ref))
    assert odd.angle_start is ctx.angle_start and odd.q_tilde is not frozen_q_tilde
    for term in TERMS.values():
        assert term.energy(q, DATA, odd) == term.energy(q, DATA, ctx)
    changed = ctx.replace(scale=1.0)
    assert changed.scale == 1.0 and changed.q_tilde is ctx.q_tilde
    assert inertia.energy(q, DATA, changed) != inertia.energy(q, DATA, ctx)


def test_the_step_context_is_the_workspaces_own():
    """The step passes its Workspace's context (terms/context.py), whose arrays are the
    Workspace's: what the step writes into q_tilde, angle_start, drive_target and angle_ref
    is what the terms read."""
    from abd_joint_sim.solver import workspace
    ws = workspace.build(MODEL, DATA).__dict__
    ctx = ws['ctx'].__dict__
    for name in ('q_tilde', 'angle_start', 'drive_target', 'drive_on', 'angle_work', 'angle_ref'):
        assert ctx[name] is ws[name], name


@pytest.mark.parametrize('project', [False, True])
@pytest.mark.parametrize('shear', [0.15, 1e-3])
@pytest.mark.parametrize('name', list(TERMS))
def test_term_accumulate_returns_the_bits_of_its_energy(name, shear, project):
    """Newton takes Π at its start from the assembly there (newton.assemble): every term's
    accumulate (and accumulate_gradient, where the Hessian is constant) returns its energy
    with the bits of `energy`, sheared far from SO(3) (the shape term's projected path) or
    near it (its exact path)."""
    term = TERMS[name]
    B, J = MODEL.body_count, MODEL.joint_count
    # 40 states: a sum reordered rounds alike in most of them (UID 18's sum of squares
    # reversed changes 4 of 80)
    for seed in range(40):
        q = _state(seed, shear)
        ctx = _ctx(q_tilde=_state(seed + 10, shear), angle_start=[0.1, -0.2])
        E = term.energy(q, DATA, ctx)
        assert E > 0.0, 'the state must activate the term'
        got = term.accumulate(q, DATA, ctx, np.zeros((B, 12)), np.zeros((B, 12, 12)),
                              np.zeros((J, 12, 12)), project)
        assert got == E, (got, E)
        if hasattr(term, 'accumulate_gradient'):
            assert term.accumulate_gradient(q, DATA, ctx, np.zeros((B, 12))) == E


@pytest.mark.parametrize('scale', [9.0 / 4.0, 1.7])
def test_newton_assembly_returns_the_bits_of_the_potential(scale):
    """newton.assemble's Π(q) is newton.potential's, bit for bit, with the model's own BDF
    scale (constant s·M) and another (the inertia term's Hessian assembled), and its
    gradient and blocks are what it assembled before it returned Π."""
    from abd_joint_sim.solver import newton
    B, J = MODEL.body_count, MODEL.joint_count
    for seed in range(8):
        q = _state(seed)
        ctx = _ctx(q_tilde=_state(seed + 10), angle_start=[0.1, -0.2]).replace(scale=scale)
        grad, diag, pair = np.zeros((B, 12)), np.zeros((B, 12, 12)), np.zeros((J, 12, 12))
        blocks, E = newton.assemble(q, DATA, ctx, grad, diag, pair)
        terms = [TERMS[n].energy(q, DATA, ctx) for n in TERMS]
        assert min(terms) > 0.0, 'every term must be active'
        assert E == newton.potential(q, DATA, ctx)
        assert blocks is pair and np.abs(grad).max() > 0.0 and np.abs(pair).max() > 0.0

@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize('name', list(TERMS))
def test_term_derivatives_match_finite_differences(name, seed):
    q = _state(seed)
    E = check_term(TERMS[name], q, _ctx(q_tilde=_state(seed + 10)), name=name)
    assert np.isfinite(E) and E > 0.0


def test_joint_angle_matches_the_oracle():
    from abd_joint_sim.terms import angle as angles
    for seed in range(5):
        q = _state(seed, scale=0.3)
        for j in range(MODEL.joint_count):
            assert angles.theta(q, DATA, j) == pytest.approx(oracle.theta(MODEL, q, j), abs=1e-14)


def test_torque_force_matches_the_oracle():
    for seed in range(3):
        q = _state(seed)
        taus = np.array([2.5, -1.5])
        F = np.zeros((MODEL.body_count, 12))
        skipped = np.zeros(4, dtype=np.int64)
        n = generalized_force(q, DATA, taus, np.ones(2, bool), F, skipped)
        assert n == 0
        np.testing.assert_allclose(F, oracle.torque_force(MODEL, q, taus), rtol=1e-12, atol=1e-14)


def test_limit_is_active_on_both_sides_and_zero_inside():
    lo, up, s = -0.2, 0.4, 3.0
    E, d1, _ = limit.phi(lo - 0.3, lo, up, s)
    assert E > 0 and d1 < 0            # below the lower limit it pushes up
    E, d1, _ = limit.phi(up + 0.3, lo, up, s)
    assert E > 0 and d1 > 0            # above the upper limit it pushes down
    E, d1, _ = limit.phi(0.4, 0.1, 0.1, s)
    assert E > 0 and d1 > 0            # zero-width limit: s|x - l|^3
    assert limit.phi(0.1, lo, up, s) == (0.0, 0.0, 0.0)
    assert not limit.active(0.1, lo, up) and limit.active(0.11, 0.1, 0.1)


def test_projected_hessians_are_psd_far_from_rest():
    q = _state(7, scale=0.8)            # strongly sheared: ortho is non-convex here
    ctx = _ctx()
    for name in ('ortho', 'driving', 'limit'):
        _, _, H = dense(TERMS[name], q, ctx, project=True)
        w = np.linalg.eigvalsh(H)
        assert w.min() > -1e-8 * abs(w).max(), name
    _, _, Hraw = dense(ortho, q, ctx, project=False)
    assert np.linalg.eigvalsh(Hraw).min() < 0, 'this state should make the raw ortho Hessian indefinite'


def test_ortho_analytic_projection_matches_eigendecomposition():
    rng = np.random.default_rng(11)
    q = _state(11, scale=0.6)
    q[0, 3:12] = (random_rotation(rng) @ np.diag([1.0, 1.0, 0.2])).ravel()    # compressed
    ctx = _ctx()
    _, _, Hraw = dense(ortho, q, ctx, project=False)
    _, _, Hp = dense(ortho, q, ctx, project=True)
    negative = 0
    for b in np.flatnonzero(~MODEL.body_fixed):
        block = Hraw[12 * b + 3:12 * b + 12, 12 * b + 3:12 * b + 12]
        w, V = np.linalg.eigh(block)
        ref = (V * np.maximum(w, 0.0)) @ V.T
        negative += w.min() < -1e-3 * abs(w).max()
        assert np.abs(Hp[12 * b + 3:12 * b + 12, 12 * b + 3:12 * b + 12] - ref).max() < 1e-10 * np.abs(block).max()
    assert negative, 'the projection must matter here'


def _near_rotation_state(rng, strain):
    """Every free body at a random rotation times diag(σ), σ² = 1 − strain/√3 (a uniform
    compression with ‖AAᵀ − I‖_F = strain): where the shape term's raw Hessian is indefinite."""
    q = MODEL.body_q0.copy()
    sigma = np.sqrt(1.0 - strain / np.sqrt(3.0))
    for b in np.flatnonzero(~MODEL.body_fixed):
        q[b, 3:12] = (random_rotation(rng) @ np.diag([sigma] * 3)).ravel()
    return q


def test_ortho_hessian_is_exact_where_the_inertia_keeps_newtons_matrix_definite():
    """Near SO(3) Newton takes the shape term's exact Hessian (no projection): its negative
    part, ≥ −4h²κv̄‖AAᵀ − I‖_F, is at most ORTHO_EXACT_SHARE of the inertia term's s μ_min(M̄),
    so the body's block of Newton's matrix stays that far from singular. Beyond the bound
    it is projected as before."""
    ctx = _ctx()
    h, s = ctx.h, ctx.scale
    free = np.flatnonzero(~MODEL.body_fixed)
    mu = np.linalg.eigvalsh(DATA.body_Mbar)[:, 0]
    # the largest ‖C‖_F with the exact Hessian, per body; the test state uses the smallest
    limit_c = s * DATA.ortho_exact_bound[free] / (h * h)
    assert np.all(limit_c < 0.1), 'the bound must be reached by small strains here'
    rng = np.random.default_rng(5)
    for share, expect_exact in ((0.999, True), (1.5, False)):
        q = _near_rotation_state(rng, share * limit_c.min() if expect_exact else share * limit_c.max())
        _, _, Hraw = dense(ortho, q, ctx, project=False)
        _, _, Hnewton = dense(ortho, q, ctx, project=True)
        for b in free:
            rows = slice(12 * b + 3, 12 * b + 12)
            raw, used = Hraw[rows, rows], Hnewton[rows, rows]
            assert np.linalg.eigvalsh(raw).min() < 0.0, 'a compressed body: the raw Hessian is indefinite'
            if expect_exact:
                assert np.array_equal(used, raw)
                block = s * DATA.body_M[b] + Hnewton[12 * b:12 * b + 12, 12 * b:12 * b + 12]
                smallest = np.linalg.eigvalsh(block).min()
                # at least half the body's smallest inertia is left (ORTHO_EXACT_SHARE ≤ 0.5)
                assert smallest >= 0.5 * s * mu[b] * (1.0 - 1e-9), (
                    f'body {b}: Newton block smallest eigenvalue {smallest:.3e} vs s μ_min {s * mu[b]:.3e}')
            else:
                w, V = np.linalg.eigh(raw)
                np.testing.assert_allclose(used, (V * np.maximum(w, 0.0)) @ V.T, rtol=0,
                                           atol=1e-10 * np.abs(raw).max())


def test_disabled_drive_contributes_nothing():
    q = _state(3)
    E, g, H = dense(driving, q, _ctx(on=False), project=True)
    assert E == 0.0 and not g.any() and not H.any()


# -- the checker must be able to fail -------------------------------------------------------
class _Broken:
    """The ortho term with one deliberate mistake."""

    energy = staticmethod(ortho.energy)

    def __init__(self, mode):
        self.mode = mode

    def accumulate(self, q, data, ctx, grad, diag, pair, project):
        ortho.accumulate(q, data, ctx, grad, diag, pair, project)
        b = 0
        if self.mode == 'grad':
            grad[b, 4] *= 1.01
        elif self.mode == 'hess':
            diag[b, 4, 4] *= 1.01
            diag[b, 5, 5] *= 0.99
        elif self.mode == 'asym':
            diag[b, 4, 5] += 1e-3 * abs(diag[b, 4, 4])
        elif self.mode == 'neg' and project:
            diag[b, 3:12, 3:12] -= 2 * np.abs(diag[b, 3:12, 3:12]).max() * np.eye(9)


@pytest.mark.parametrize('mode,message', [('grad', 'gradient disagrees'), ('hess', 'Hessian disagrees'),
                                          ('asym', 'Hessian'), ('neg', 'not PSD')])
def test_checker_catches_broken_terms(mode, message):
    with pytest.raises(ValueError, match=message):
        check_term(_Broken(mode), _state(0), _ctx())


def test_oracle_comparison_can_fail(monkeypatch):
    """An angle of the wrong sign (child and parent swapped) is seen by the comparison."""
    q = _state(1)
    ctx = _ctx(angle_start=[0.1, -0.2])
    good = driving.energy(q, DATA, ctx)
    assert good == pytest.approx(_oracle_energy('driving', q, ctx), rel=1e-12)
    right = oracle.theta
    monkeypatch.setattr(oracle, 'theta', lambda model, q, j: -right(model, q, j))
    assert good != pytest.approx(_oracle_energy('driving', q, ctx), rel=1e-6)


def test_joint_angle_slope_is_the_directional_derivative():
    """angles.theta_and_slope_at (the joint velocity θ̇ = ∇θ·v and the predicted rotation)
    against a central difference of θ along the direction, on sheared states."""
    from abd_joint_sim.terms import angle as angles
    rng = np.random.default_rng(5)
    zero = np.zeros((MODEL.body_count, 12))
    for seed in range(4):
        q = _state(seed, scale=0.3)
        d = rng.normal(size=q.shape)
        for j in range(MODEL.joint_count):
            args = (DATA.joint_parent, DATA.joint_child, DATA.joint_nbar, DATA.joint_bbar, j)
            th, slope = theta_and_slope_at(q, d, zero, *args)
            eps = 1e-6
            fd = (angles.theta(q + eps * d, DATA, j) - angles.theta(q - eps * d, DATA, j)) / (2 * eps)
            assert th == pytest.approx(angles.theta(q, DATA, j), abs=1e-15)
            assert slope == pytest.approx(fd, rel=1e-7, abs=1e-9)
            # the direction as a difference of two arrays gives the same
            assert theta_and_slope_at(q, q + d, q, *args)[1] == pytest.approx(slope, rel=1e-9)


def test_far_drive_uses_the_gauss_newton_hessian_and_keeps_the_gradient():
    """Beyond GAUSS_NEWTON_RANGE from its target a drive's projected Hessian is E''∇θ∇θᵀ
    (rank one in the angle), its gradient unchanged; near the target it is the full one."""
    from abd_joint_sim.terms import angle as angles
    q = _state(2, scale=0.05)
    j = int(MODEL.drive_joints[0])
    start = np.zeros(MODEL.joint_count)
    theta = angles.unwrap(angles.theta(q, DATA, j), 0.0)
    for offset, gauss_newton in ((0.5, True), (0.02, False)):
        ctx = StepContext(0.01, 1.0, q.copy(), start, np.array([theta - offset]), np.array([True]),
                             np.empty(angles.ANGLE_WORK_SHAPE), _angle_ref(start))
        _, g, Hp = dense(driving, q, ctx, project=True)
        _, g_raw, _ = dense(driving, q, ctx, project=False)
        np.testing.assert_array_equal(g, g_raw)
        grad = np.zeros(18)
        theta_derivatives(q, DATA, j, grad, np.zeros((18, 18)), False)
        K = float(MODEL.drive_K[0])
        i_b, j_b = MODEL.joint_parent[j], MODEL.joint_child[j]
        idx = np.r_[12 * i_b + 3:12 * i_b + 12, 12 * j_b + 3:12 * j_b + 12]
        gn = K * np.outer(grad, grad)
        if gauss_newton:
            np.testing.assert_allclose(Hp[np.ix_(idx, idx)], gn, atol=1e-9 * K)
        else:
            assert np.abs(Hp[np.ix_(idx, idx)] - gn).max() > 1e-3 * K


# -- the angle terms' projection -------------------------------------------------------------
def _reference_angle_projection(q, joints, d1s, d2s):
    """The former projection, kept here as the reference: per joint H = E''∇θ∇θᵀ + E'∇²θ
    (E' → 0 beyond GAUSS_NEWTON_RANGE) on the 18 coordinates vec A_i, vec A_j, reduced to
    QᵀHQ (12x12, Q = diag(I3 ⊗ [n̄_i b̄_i], I3 ⊗ [n̄_j b̄_j])), eigen-decomposed by LAPACK;
    kept as is when every eigenvalue of the batch is ≥ 0, else negative ones clamped to 0.
    Returns the dense (12B, 12B) matrix."""
    from abd_joint_sim.terms import angle as angles
    B = MODEL.body_count
    blocks, all_psd = [], True
    for j, d1, d2 in zip(joints, d1s, d2s):
        g, hh = np.zeros(18), np.zeros((18, 18))
        theta_derivatives(q, DATA, j, g, hh, True)
        gauss_newton = abs(d1) > angles.GAUSS_NEWTON_RANGE * d2
        H = d2 * np.outer(g, g) + (0.0 if gauss_newton else d1) * hh
        Q = np.zeros((18, 12))
        for side in range(2):
            F = np.stack([DATA.joint_nbar[j, side], DATA.joint_bbar[j, side]], axis=1)
            Q[9 * side:9 * side + 9, 6 * side:6 * side + 6] = np.kron(np.eye(3), F)
        w, V = np.linalg.eigh(Q.T @ H @ Q)
        skip = gauss_newton and d2 >= 0
        all_psd &= skip or w.min() >= 0
        blocks.append((j, H, None if skip else (Q @ V, w)))
    out = np.zeros((12 * B, 12 * B))
    for j, H, eig in blocks:
        if eig is not None and not all_psd:
            QV, w = eig
            H = (QV * np.maximum(w, 0.0)) @ QV.T
        idx = np.r_[12 * MODEL.joint_parent[j] + 3:12 * MODEL.joint_parent[j] + 12,
                    12 * MODEL.joint_child[j] + 3:12 * MODEL.joint_child[j] + 12]
        out[np.ix_(idx, idx)] += H
    return out


def _projected_angle_hessian(q, joints, d1s, d2s):
    from abd_joint_sim.terms import angle as angles
    B, J = MODEL.body_count, MODEL.joint_count
    grad, diag, pair = np.zeros((B, 12)), np.zeros((B, 12, 12)), np.zeros((J, 12, 12))
    work = np.empty(angles.ANGLE_WORK_SHAPE)
    for j, d1, d2 in zip(joints, d1s, d2s):
        angles.accumulate_angle_joint(q, DATA.joint_parent, DATA.joint_child, DATA.joint_nbar,
                                      DATA.joint_bbar, int(j), float(d1), float(d2), grad, diag, pair,
                                      True, work, 0.0)
    H = np.zeros((12 * B, 12 * B))
    for b in range(B):
        H[12 * b:12 * b + 12, 12 * b:12 * b + 12] += diag[b]
    for j in range(J):
        i_b, j_b = MODEL.joint_parent[j], MODEL.joint_child[j]
        H[12 * i_b:12 * i_b + 12, 12 * j_b:12 * j_b + 12] += pair[j]
        H[12 * j_b:12 * j_b + 12, 12 * i_b:12 * i_b + 12] += pair[j].T
    return H


def _rigid_state(seed):
    rng = np.random.default_rng(seed)
    q = MODEL.body_q0.copy()
    for b in np.flatnonzero(~MODEL.body_fixed):
        q[b, 3:12] = random_rotation(rng).ravel()
    return q


ANGLE_CASES = [(-3.0, 40.0), (2.5, 40.0), (-0.5, 40.0), (0.7, 40.0), (1e-3, 1.0), (-1e-3, 0.0),
               (4.0, 0.0), (0.0, 5.0), (0.0, -2.0), (-0.05, 2.0), (0.05, 2.0)]


@pytest.mark.parametrize('shape', ['rigid', 'near', 'sheared', 'far'])
def test_angle_projection_equals_the_12x12_eigen_projection(shape):
    """The closed-form projection (angles.angle_hessian_projected) against the former 12x12
    eigen-decomposition, E' of both signs, near (E'∇²θ kept) and far (Gauss-Newton) from the
    minimum, one joint and both at once, on rigid and sheared pairs up to far from SO(3)."""
    worst, clamped = 0.0, 0
    for seed in range(6):
        q = {'rigid': _rigid_state(seed), 'near': _state(seed, 1e-7), 'sheared': _state(seed, 0.15),
             'far': _state(seed, 0.8)}[shape]
        for d1, d2 in ANGLE_CASES:
            for joints, d1s, d2s in (([0], [d1], [d2]), ([1], [-d1], [d2]),
                                     ([0, 1], [d1, 0.3 * d1], [d2, 2 * d2])):
                ref = _reference_angle_projection(q, joints, d1s, d2s)
                new = _projected_angle_hessian(q, joints, d1s, d2s)
                raw = _raw_angle_hessian(q, joints, d1s, d2s)
                scale = np.abs(raw).max()           # rounding is relative to the raw Hessian
                worst = max(worst, np.abs(new - ref).max() / scale)
                clamped += not np.allclose(ref, raw, atol=1e-6 * scale)
    assert clamped, 'the projection must matter in these cases'
    assert worst < 1e-12, worst


def _raw_angle_hessian(q, joints, d1s, d2s):
    from abd_joint_sim.terms import angle as angles
    B = MODEL.body_count
    out = np.zeros((12 * B, 12 * B))
    for j, d1, d2 in zip(joints, d1s, d2s):
        g, hh = np.zeros(18), np.zeros((18, 18))
        theta_derivatives(q, DATA, j, g, hh, True)
        idx = np.r_[12 * MODEL.joint_parent[j] + 3:12 * MODEL.joint_parent[j] + 12,
                    12 * MODEL.joint_child[j] + 3:12 * MODEL.joint_child[j] + 12]
        out[np.ix_(idx, idx)] += d2 * np.outer(g, g) + d1 * hh
    return out


def test_angle_hessian_has_the_structure_the_projection_uses():
    """QᵀHQ = I3 ⊗ E'M_θ + rank 2, M_θ with eigenvalues ±1/(2r): so ±E'/(2r) are eigenvalues
    at least 4 times each (what angles.angle_hessian_projected relies on), and H with E' ≠ 0
    is never PSD (why joint-by-joint projection equals the former batch rule)."""
    from abd_joint_sim.terms import angle as angles
    for seed in range(4):
        q = _state(seed, 0.4)
        for j in range(MODEL.joint_count):
            g, hh = np.zeros(18), np.zeros((18, 18))
            theta_derivatives(q, DATA, j, g, hh, True)
            Q = np.zeros((18, 12))
            for side in range(2):
                F = np.stack([DATA.joint_nbar[j, side], DATA.joint_bbar[j, side]], axis=1)
                Q[9 * side:9 * side + 9, 6 * side:6 * side + 6] = np.kron(np.eye(3), F)
            fr = np.zeros((4, 3))
            angles.frames(q, MODEL.joint_parent[j], MODEL.joint_child[j], DATA.joint_nbar,
                          DATA.joint_bbar, j, fr)
            r = np.hypot(*angles.cos_sin(fr))
            for d1 in (-2.0, 3.0):
                w = np.linalg.eigvalsh(Q.T @ (5.0 * np.outer(g, g) + d1 * hh) @ Q)
                for sign in (1, -1):
                    assert np.sum(np.isclose(w, sign * d1 / (2 * r), rtol=1e-9)) >= 4
                assert w.min() < 0


def _textbook_exact_angle_hessian(work, c, s, r, o, nbi, bbi, nbj, bbj, e1, e2, i_body, j_body, j, diag,
                                  pair):
    """angles._add_exact_angle_hessian as the loops it was before it was written for the
    vectoriser, in plain Python floats: each body's block as its upper triangle, mirrored."""
    f = [[float(x) for x in row] for row in work]
    dc, ds, G = f[4], f[5], f[8]
    Dr = [(c * dc[a] + s * ds[a]) / r for a in range(18)]
    k1 = e1 / r
    kx = e1 / (2.0 * r)
    for a in range(9):
        ga, ra, gj, rj = G[a], Dr[a], G[9 + a], Dr[9 + a]
        for b in range(a, 9):
            xi = e2 * (ga * G[b]) - k1 * (ga * Dr[b] + ra * G[b])
            xj = e2 * (gj * G[9 + b]) - k1 * (gj * Dr[9 + b] + rj * G[9 + b])
            diag[i_body, 3 + a, 3 + b] += xi
            diag[j_body, 3 + a, 3 + b] += xj
            if b != a:
                diag[i_body, 3 + b, 3 + a] += xi
                diag[j_body, 3 + b, 3 + a] += xj
        ca = a % 3
        for b in range(9):
            x = e2 * (ga * G[9 + b]) - k1 * (ga * Dr[9 + b] + ra * G[9 + b])
            if a // 3 == b // 3:
                cb = b % 3
                x += kx * (float(nbi[ca]) * (o[0] * float(nbj[cb]) + o[1] * float(bbj[cb]))
                           + float(bbi[ca]) * (o[2] * float(nbj[cb]) + o[3] * float(bbj[cb])))
            pair[j, 3 + a, 3 + b] += x


def test_the_exact_angle_hessian_gives_the_bits_of_the_textbook_loops():
    """The exact angle Hessian, written with whole rows for the vectoriser, adds the same bits
    as its triangle-and-mirror loops, onto blocks that already hold values (random frames,
    slopes and coefficients of both signs, 7 decades)."""
    rng = np.random.default_rng(3)
    for trial in range(40):
        work = rng.normal(size=angles.ANGLE_WORK_SHAPE) * 10.0 ** rng.uniform(-3, 3)
        c, s = rng.normal(size=2)
        r = float(np.hypot(c, s))
        o = rng.normal(size=4)
        nbi, bbi, nbj, bbj = rng.normal(size=(4, 3))
        e1, e2 = rng.normal(size=2) * 10.0 ** rng.uniform(-2, 2, size=2)
        i_body, j_body, j = (0, 2, 1) if trial % 2 else (2, 1, 0)
        diag, pair = rng.normal(size=(3, 12, 12)), rng.normal(size=(2, 12, 12))
        want_d, want_p = diag.copy(), pair.copy()
        before = diag.copy()
        angles._add_exact_angle_hessian(work, c, s, r, *o, nbi, bbi, nbj, bbj, e1, e2, i_body, j_body, j,
                                        diag, pair)
        _textbook_exact_angle_hessian(work, c, s, r, o, nbi, bbi, nbj, bbj, e1, e2, i_body, j_body, j,
                                      want_d, want_p)
        assert not np.array_equal(diag, before)
        np.testing.assert_array_equal(diag, want_d)
        np.testing.assert_array_equal(pair, want_p)


@pytest.mark.slow
def test_angle_hessian_is_exact_where_the_inertia_keeps_newtons_matrix_definite():
    """angles.accumulate_angle_joint takes E''∇θ∇θᵀ + E'∇²θ unprojected where its most
    negative eigenvalue is provably ≥ −exact_bound (Weyl's bound from its structure; the terms pass
    s × model_data's joint_angle_budget), else the PSD projection. On rigid, near-rigid and
    sheared pairs, E' of both signs: with an unlimited bound it must be the raw Hessian (the
    closed form against theta_derivatives' ∇²θ); with a bound just below what the raw
    Hessian's most negative eigenvalue needs, the projection (the rule may not take it
    then); with a bound twice that, exact in most cases (the bound is not vacuous)."""
    from abd_joint_sim.terms import angle as angles
    checked = taken = 0
    work = np.empty(angles.ANGLE_WORK_SHAPE)
    for seed in range(4):
        for q in (_rigid_state(seed), _state(seed, 1e-7), _state(seed, 0.15)):
            for d1, d2 in ANGLE_CASES:
                if abs(d1) > angles.GAUSS_NEWTON_RANGE * d2 or (d1 == 0.0 and d2 >= 0.0):
                    continue                 # Gauss-Newton or PSD as it is: no projection
                for j in range(MODEL.joint_count):
                    raw = _raw_angle_hessian(q, [j], [d1], [d2])
                    proj = _reference_angle_projection(q, [j], [d1], [d2])
                    lam = np.linalg.eigvalsh(raw).min()
                    scale = np.abs(raw).max()
                    got = {}
                    for name, bound in (('inf', np.inf), ('zero', 0.0), ('below', 0.999 * -lam),
                                        ('twice', 2.0 * -lam)):
                        B, J = MODEL.body_count, MODEL.joint_count
                        g, d, p = np.zeros((B, 12)), np.zeros((B, 12, 12)), np.zeros((J, 12, 12))
                        angles.accumulate_angle_joint(q, MODEL.joint_parent, MODEL.joint_child,
                                                      DATA.joint_nbar, DATA.joint_bbar, j, d1, d2,
                                                      g, d, p, True, work, bound)
                        H = np.zeros((12 * B, 12 * B))
                        for b in range(B):
                            H[12 * b:12 * b + 12, 12 * b:12 * b + 12] += d[b]
                        i_b, j_b = MODEL.joint_parent[j], MODEL.joint_child[j]
                        H[12 * i_b:12 * i_b + 12, 12 * j_b:12 * j_b + 12] += p[j]
                        H[12 * j_b:12 * j_b + 12, 12 * i_b:12 * i_b + 12] += p[j].T
                        got[name] = H
                    assert lam < 0.0                    # E'∇²θ with E' ≠ 0 is never PSD
                    assert np.abs(got['inf'] - raw).max() <= 1e-11 * scale
                    assert np.abs(got['zero'] - proj).max() <= 1e-12 * scale
                    assert np.abs(got['below'] - proj).max() <= 1e-12 * scale
                    checked += 1
                    taken += np.abs(got['twice'] - raw).max() <= 1e-11 * scale
    assert checked >= 40 and taken >= 0.5 * checked, (checked, taken)


def test_the_angle_budget_shares_a_quarter_of_each_body_inertia():
    """model_data.joint_angle_budget: per joint, the smaller over its free bodies of
    ANGLE_EXACT_SHARE μ_min(M̄_b) / (angle terms on b's joints); the drives, limits and
    dampers on a body's joints then take at most that share of its inertia together."""
    mu = np.linalg.eigvalsh(DATA.body_Mbar)[:, 0]
    # j0 (a-b: a drive, a limit, a damper), j1 (fixed c - b: a limit): a has 3 terms, b has 4
    share = model_data.ANGLE_EXACT_SHARE
    expect = [min(share * mu[0] / 3, share * mu[1] / 4), share * mu[1] / 4]
    assert np.allclose(DATA.joint_angle_budget, expect, rtol=1e-14, atol=0)
    for b in range(2):                                  # the quarter, summed over b's terms
        terms = [DATA.joint_angle_budget[0]] * 3 + ([DATA.joint_angle_budget[1]] if b == 1 else [])
        assert sum(terms) <= share * mu[b] * (1 + 1e-12)


def _active_angle_terms(name, q, ctx):
    """(joints, E', E'', n) of the enabled drives or the active limits at q."""
    out = []
    if name == 'driving':
        for k, j in enumerate(MODEL.drive_joints):
            if ctx.drive_on[k]:
                x = angles.unwrap(angles.theta(q, DATA, j), ctx.angle_start[j])
                K = DATA.drive_K[k]
                out.append((j, K * (x - ctx.drive_target[k]), K))
    else:
        for k, j in enumerate(MODEL.limit_joints):
            x = angles.unwrap(angles.theta(q, DATA, j), ctx.angle_start[j])
            lower, upper = DATA.limit_lower[k], DATA.limit_upper[k]
            if limit.active(x, lower, upper):
                out.append((j, *limit.phi(x, lower, upper, DATA.limit_strength[k])[1:]))
    if not out:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0), 0
    joints, d1s, d2s = zip(*out)
    return np.array(joints), np.array(d1s), np.array(d2s), len(out)


@pytest.mark.parametrize('name', ['driving', 'limit'])
def test_terms_project_like_the_12x12_eigen_projection(name):
    """Through the terms' own `accumulate` (the fused loops): drives near their target on
    either side (E'∇²θ kept) and limits active above and below, against the reference."""
    from abd_joint_sim.terms import angle as angles
    term, signs = TERMS[name], set()
    exact = projected = 0
    j = int(MODEL.drive_joints[0])
    for seed in range(4):
        q = _state(seed, 0.1)
        theta = angles.unwrap(angles.theta(q, DATA, j), 0.0)
        for offset in (0.03, -0.05, 0.4):
            # drives: target beside the angle; limits: the step-start branch and init shift x
            start = np.array([offset, -offset]) if name == 'limit' else np.zeros(MODEL.joint_count)
            ctx = StepContext(0.01, 1.0, q.copy(), start, np.array([theta - offset]), np.array([True]),
                             np.empty(angles.ANGLE_WORK_SHAPE), _angle_ref(start))
            joints, d1s, d2s, n = _active_angle_terms(name, q, ctx)
            if n == 0:
                continue
            signs |= set(np.sign(d1s[:n]))
            ref = _reference_angle_projection(q, joints[:n], d1s[:n], d2s[:n])
            _, _, H = dense(term, q, ctx, project=True)
            _, _, raw = dense(term, q, ctx, project=False)
            tol = 1e-12 * np.abs(raw).max()
            if np.abs(H - ref).max() > tol:
                # the exact Hessian, taken only where the inertia keeps Newton's matrix PD
                assert np.abs(H - raw).max() <= tol
                budget = ctx.scale * DATA.joint_angle_budget[joints[:n]].sum()
                assert np.linalg.eigvalsh(raw).min() >= -budget * (1 + 1e-9)
                exact += 1
            else:
                projected += 1
    assert signs >= {-1.0, 1.0}, signs
    assert projected, (exact, projected)

# -- M = M̄ ⊗ I3: the structured inertia and M⁻¹F against the dense 12x12 sums ------------------
# The dense loops below are the plain definitions (Σ_c M[r, c] d[c] over all 12 columns, in
# column order); the terms' 4-term sums drop only exact zeros of M, so they must agree bit for bit.

@njit
def _dense_inertia(q, q_tilde, M, free, s, grad, diag):
    E = 0.0
    for b in free:
        for r in range(12):
            Md = 0.0
            for c in range(12):
                Md += M[b, r, c] * (q[b, c] - q_tilde[b, c])
                diag[b, r, c] += s * M[b, r, c]
            E += Md * (q[b, r] - q_tilde[b, r])
            grad[b, r] += s * Md
    return 0.5 * s * E


@njit
def _dense_apply(Minv, F, acc):
    for b in range(F.shape[0]):
        for r in range(12):
            x = 0.0
            for c in range(12):
                x += Minv[b, r, c] * F[b, c]
            acc[b, r] += x


def _textbook_ortho_hessian(q, b, w, diag):
    """The shape term's exact Hessian added to diag[b] entry by entry, in plain Python floats:
    w [A_il A_jk + δ_ij (AᵀA)_lk + δ_kl C_ij] at row 3i + k, column 3j + l of the A-block
    (the loop nest ortho.accumulate ran before it was written out for the vectoriser)."""
    A = [[float(q[b, 3 + 3 * r + c]) for c in range(3)] for r in range(3)]
    AAt = [[A[r][0] * A[c][0] + A[r][1] * A[c][1] + A[r][2] * A[c][2] for c in range(3)] for r in range(3)]
    AtA = [[A[0][l] * A[0][k] + A[1][l] * A[1][k] + A[2][l] * A[2][k] for k in range(3)] for l in range(3)]
    for i in range(3):
        for k in range(3):
            for j in range(3):
                for l in range(3):
                    x = A[i][l] * A[j][k]
                    if i == j:
                        x += AtA[l][k]
                    if k == l:
                        x += AAt[i][j] - 1.0 if i == j else AAt[i][j]
                    diag[b, 3 + 3 * i + k, 3 + 3 * j + l] += w * x


@pytest.mark.parametrize('shear', [0.15, 1e-3])
def test_the_shape_hessian_gives_the_bits_of_the_textbook_nest(shear):
    """ortho.accumulate's exact Hessian, written as runs of 9 columns for the vectoriser, adds
    the same bits as the entry-by-entry nest, onto blocks that already hold values."""
    B, J = MODEL.body_count, MODEL.joint_count
    rng = np.random.default_rng(7)
    for seed in range(10):
        q = _state(seed, shear)
        ctx = _ctx(q_tilde=_state(seed + 10, shear))
        start = rng.normal(size=(B, 12, 12))
        got = start.copy()
        ortho.accumulate(q, DATA, ctx, np.zeros((B, 12)), got, np.zeros((J, 12, 12)), False)
        want = start.copy()
        for b in DATA.free_bodies:
            _textbook_ortho_hessian(q, b, 4.0 * ctx.h * ctx.h * DATA.ortho_weight[b], want)
        assert not np.array_equal(got, start)
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize('seed', [0, 1, 2, 3])
def test_inertia_on_the_4x4_blocks_is_bit_identical_to_the_dense_mass_matrix(seed):
    q, q_tilde = _state(seed, 0.3), _state(seed + 20, 0.1)
    ctx = _ctx(q_tilde=q_tilde)
    B, J = MODEL.body_count, MODEL.joint_count
    g, d = np.zeros((B, 12)), np.zeros((B, 12, 12))
    E_dense = _dense_inertia(q, q_tilde, MODEL.body_M, DATA.free_bodies, ctx.scale, g, d)
    g1, d1 = np.zeros((B, 12)), np.zeros((B, 12, 12))
    inertia.accumulate(q, DATA, ctx, g1, d1, np.zeros((J, 12, 12)), True)
    g2 = np.zeros((B, 12))
    inertia.accumulate_gradient(q, DATA, ctx, g2)
    assert E_dense > 0.0 and inertia.energy(q, DATA, ctx) == E_dense
    np.testing.assert_array_equal(g1, g)
    np.testing.assert_array_equal(g2, g)
    np.testing.assert_array_equal(d1, d)


def test_torque_acceleration_is_bit_identical_to_dense_inverse_mass():
    """add_acceleration (A⁻¹ once per body, M⁻¹F on the 4x4 blocks) = M⁻¹ (dense) applied to
    generalized_force (checked against the oracle above) on the free bodies; body b is the
    child of both joints, so its force is a sum of two joints' in their order. The fixed body
    c, a torque body too, gets nothing: its acceleration is never read."""
    B = MODEL.body_count
    for seed in range(3):
        q = _state(seed)
        taus, on = np.array([2.5, -1.5]), np.ones(2, bool)
        F = np.zeros((B, 12))
        assert generalized_force(q, DATA, taus, on, F, np.zeros(4, np.int64)) == 0
        expected = np.full((B, 12), 0.25)
        _dense_apply(MODEL.body_Minv, F, expected)
        acc = np.full((B, 12), 0.25)
        assert torque.add_acceleration(q, DATA, taus, on, acc, np.zeros(4, np.int64), np.empty((4, 3))) == 0
        free = ~MODEL.body_fixed
        assert np.abs(acc[free] - 0.25).max() > 1e-3
        np.testing.assert_array_equal(acc[free], expected[free])
        assert np.all(acc[MODEL.body_fixed] == 0.25) and np.abs(expected[MODEL.body_fixed] - 0.25).max() > 1e-3


def test_torque_singular_guard_lists_each_skipped_side_in_order():
    """A singular A_b gets no torque from any of its joints and is listed once per (side, joint),
    parent sides first: b is the child of both joints, a the parent of j0."""
    names = list(MODEL.body_names)
    a, b = names.index('a'), names.index('b')
    taus, on = np.array([2.5, -1.5]), np.ones(2, bool)
    for singular, listed in (([b], [b, b]), ([a], [a]), ([a, b], [a, b, b])):
        q = _state(4)
        for k in singular:
            q[k, 9:12] = q[k, 3:6] + 1e-9 * q[k, 6:9]          # a3 ≈ a1: det A ≈ 0
        F, skipped = np.zeros((MODEL.body_count, 12)), np.zeros(4, np.int64)
        n = generalized_force(q, DATA, taus, on, F, skipped)
        assert skipped[:n].tolist() == listed
        assert np.all(F[singular] == 0.0)
        acc, skipped2 = np.zeros((MODEL.body_count, 12)), np.zeros(4, np.int64)
        assert torque.add_acceleration(q, DATA, taus, on, acc, skipped2, np.empty((4, 3))) == n
        assert skipped2[:n].tolist() == listed and np.all(acc[singular] == 0.0)
        others = [k for k in range(MODEL.body_count) if k not in singular and not MODEL.body_fixed[k]]
        assert all(np.abs(acc[k]).max() > 0.0 for k in others)


def test_mass_blocks_reject_a_mass_matrix_without_the_kron_structure():
    M, Minv = MODEL.body_M.copy(), MODEL.body_Minv.copy()
    Mbar, Minv_bar = model_data.mass_blocks(M, Minv)
    np.testing.assert_array_equal(Mbar[:, 1:, 1:], M[:, 3:6, 3:6])
    M[0, 4, 7] = 1e-3                                   # couples rows 0 and 1 of A
    with pytest.raises(ValueError, match='M̄ ⊗ I3'):
        model_data.mass_blocks(M, Minv)


def test_limit_inside_answers_only_where_the_angle_is_inside_and_saves_most_angles():
    """limit.inside (no atan2) says "inside" only where the exact angle (unwrap of atan2 about
    the step's start) is at least INSIDE_SAFETY within both bounds; never for a locked joint
    or a start outside the range; and it does answer for most poses near an inside start (the
    point of it). Starts near a bound, near ±π from the pose and beyond a turn included."""
    rng = np.random.default_rng(7)
    k = 0                                           # j0: [-0.5, 0.1] from its init angle; j1 locked
    lo, up = DATA.limit_lower[k], DATA.limit_upper[k]
    j = int(MODEL.limit_joints[k])
    poses = [_state(seed, 0.02 * (seed % 3)) for seed in range(400)]
    within = [q for q in poses if lo + 0.05 < angles.unwrap(angles.theta(q, DATA, j), 0.0) < up - 0.05]
    assert len(within) >= 10
    answered = near = eligible = 0
    for trial in range(3000):
        kind = trial % 4
        q = within[trial % len(within)] if kind == 0 else poses[trial % len(poses)]
        x_here = angles.unwrap(angles.theta(q, DATA, j), 0.0)
        if kind == 0:       # a pose inside, the start within a step of it
            x0 = x_here + rng.normal(scale=0.02)
        elif kind == 1:     # a start a hair inside a bound
            x0 = (lo if rng.random() < 0.5 else up) + rng.choice([-1, 1]) * 10.0 ** rng.uniform(-12, -3)
        elif kind == 2:     # anywhere, turns away included
            x0 = rng.uniform(-10.0, 10.0)
        else:               # the pose half a turn from the start
            x0 = x_here + np.pi * rng.choice([-1, 1]) + rng.normal(scale=1e-3)
        start = np.array([x0, 0.0])
        ref = _angle_ref(start)
        x = angles.unwrap(angles.theta(q, DATA, j), x0)
        said = limit.inside(*angles.cos_sin_at(q, DATA.joint_parent, DATA.joint_child, DATA.joint_nbar,
                                               DATA.joint_bbar, j), ref, k)
        if said:
            answered += 1
            assert lo + limit.INSIDE_SAFETY * 0.5 < x < up - limit.INSIDE_SAFETY * 0.5, (trial, x0, x)
        if lo + 0.05 < x0 < up - 0.05 and abs(x - x0) < 0.02:     # certainly answerable
            eligible += 1
            near += said
        c1, s1 = angles.cos_sin_at(q, DATA.joint_parent, DATA.joint_child, DATA.joint_nbar,
                                   DATA.joint_bbar, int(MODEL.limit_joints[1]))
        assert not limit.inside(c1, s1, ref, 1)     # the locked joint: always the exact path
    assert answered > 500 and near == eligible > 300


@pytest.mark.parametrize('bdf2', [False, True])
def test_damping_is_the_implicit_torque_with_the_angle_linearised_at_newtons_start(bdf2):
    """terms/damping.py: at Newton's start q0 the gradient is h² times the damping torque
    d θ̇ along ∇θ (θ̇ the integrator's rate: BDF1 (θ − θⁿ)/h, BDF2 (3θ − 4θⁿ + θⁿ⁻¹)/(2h));
    away from q0 the energy leaves the unlinearised one by O(|q − q0|²), the curvature of θ
    the linearisation drops."""
    start = np.array([0.1, -0.2])
    ctx = _ctx(angle_start=start).replace(angle_ref=_angle_ref(start, bdf2))
    h = ctx.h
    B, J = MODEL.body_count, MODEL.joint_count
    grad = np.zeros((B, 12))
    damping.accumulate(Q_START, DATA, ctx, grad, np.zeros((B, 12, 12)), np.zeros((J, 12, 12)), True)
    j = int(MODEL.damping_joints[0])
    d = float(MODEL.damping_coeff[0])
    now = start[j]
    x = oracle.unwrap(oracle.theta(MODEL, Q_START, j), now)
    before = oracle.unwrap(oracle.theta(MODEL, Q_PREV, j), now)
    rate = (3 * x - 4 * now + before) / (2 * h) if bdf2 else (x - now) / h
    G = oracle.theta_gradient(MODEL, Q_START, j)
    expect = h * h * d * rate * G
    got = np.concatenate([grad[MODEL.joint_parent[j], 3:], grad[MODEL.joint_child[j], 3:]])
    assert abs(rate) > 1.0                              # a real torque, not a zero compared
    np.testing.assert_allclose(got, expect, rtol=1e-10, atol=1e-12 * np.abs(expect).max())
    direction = _state(7, scale=0.2) - MODEL.body_q0
    gaps = []
    for eps in (1e-2, 1e-3):
        q = Q_START + eps * direction
        lin = damping.energy(q, DATA, ctx)
        exact = oracle.damping_energy(MODEL, q, Q_START, Q_PREV, start, h, bdf2, linear=False)
        gaps.append(abs(lin - exact))
    assert gaps[0] > 0.0 and 0.005 < gaps[1] / gaps[0] < 0.02, gaps   # second order: ×0.01


# -- the list of terms, once ------------------------------------------------------------------
def _sums_disagree(data, model, ctx, q, q_prev):
    """How newton's `potential`, `assemble` and `references` disagree, on one model and state,
    with the list of terms: Π must be the terms' energies added in ENERGY_TERMS' order (those
    on joints the model has), assemble's Π potential's, and references' rows those each term
    of REFERENCE_TERMS writes, in the list's order. Returns (disagreements, terms summed)."""
    from abd_joint_sim.solver import newton
    from abd_joint_sim.terms import ENERGY_TERMS, REFERENCE_TERMS, joints
    used = [t for t in ENERGY_TERMS if joints(t) is None or getattr(data, joints(t)).size]
    E = 0.0
    for term in used:
        E += term.energy(q, data, ctx)
    bad = []
    if newton.potential(q, data, ctx) != E:
        bad.append(('potential', newton.potential(q, data, ctx), E))
    B, J = model.body_count, model.joint_count
    _, assembled = newton.assemble(q, data, ctx, np.zeros((B, 12)), np.zeros((B, 12, 12)),
                                   np.zeros((J, 12, 12)))
    if assembled != E:
        bad.append(('assemble', assembled, E))
    args = (data, q, q_prev, ctx.angle_start, 0.01, True, np.empty(angles.ANGLE_WORK_SHAPE))
    expected = np.zeros(reference_shape(model))
    for term in REFERENCE_TERMS:
        if getattr(data, joints(term)).size:
            term.references(*args, expected)
    if not np.array_equal(newton.references(*args, np.zeros(reference_shape(model))), expected):
        bad.append(('references',))
    return bad, used


def test_newtons_sums_follow_the_list_of_terms():
    """newton's potential, assemble and references, written out from the lists of terms, sum
    exactly the list's terms in its order, on the revolute family's model here and the sliding
    family's (test_prismatic), every energy term active in one of them."""
    import test_prismatic as slide
    from abd_joint_sim.terms import ENERGY_TERMS
    summed = set()
    for model, data, state, ctx, q_prev in (
            (MODEL, DATA, _state, lambda: _ctx(angle_start=[0.1, -0.2]), Q_PREV),
            (slide.MODEL, slide.DATA, slide._state, slide._ctx, slide.Q_PREV)):
        for seed in range(4):
            q, c = state(seed), ctx()
            bad, used = _sums_disagree(data, model, c, q, q_prev)
            assert bad == []
            summed |= {t for t in used if t.energy(q, data, c) > 0.0}
    assert summed == set(ENERGY_TERMS)


def test_each_term_builds_its_model_fields_from_the_scene():
    """A Model's fields are its declared bodies and joints plus what each term's `from_scene`
    returns: model.py declares no term's field and no two terms build the same one."""
    import dataclasses
    from abd_joint_sim.model import Model
    from abd_joint_sim.terms import TERMS
    base, seen = {f.name for f in dataclasses.fields(Model)}, set()
    scene = Scene.from_dict(MODEL_SCENE)
    for term in TERMS:
        own = set(term.from_scene(scene, MODEL))
        assert not own & base and not own & seen, term.__name__
        seen |= own
    assert set(MODEL.__dict__) == base | seen
    assert {'torque_joints', 'drive_K', 'limit_lower', 'damping_coeff'} <= seen


def test_the_compiled_model_is_its_terms_fields():
    """ModelData's fields are the base fields and every term's FIELDS, each built by its term
    (build returns exactly its FIELDS), and Solver.terms names the terms the scene uses."""
    from abd_joint_sim.solver.solver import Solver
    from abd_joint_sim.terms import TERMS
    assert [n for n, _ in model_data.FIELDS] == [n for n, _ in model_data.BASE_FIELDS] + [
        n for t in TERMS for n, _ in t.FIELDS]
    values = {name: DATA.__dict__[name] for name, _ in model_data.BASE_FIELDS}
    for term in TERMS:
        built = term.build(MODEL, values)
        assert sorted(built) == sorted(n for n, _ in term.FIELDS), term.__name__
        values.update(built)
    assert Solver(MODEL).terms == ('ortho_potential', 'revolute_joint', 'driving', 'limit',
                                   'joint_damping', 'external_torque')     # no prismatic term

