"""Every energy term's gradient and Hessian against finite differences, and the checker
itself against deliberately broken terms (it must be able to fail)."""
import numpy as np
import pytest

from abd_joint_sim import Scene, compile_scene
from abd_joint_sim.terms.angle_terms import Driving, Limit
from abd_joint_sim.terms.base import StepContext
from abd_joint_sim.terms.check import check_term
from abd_joint_sim.terms.ortho import OrthoPotential
from abd_joint_sim.terms.revolute import RevoluteJoint

from physics_helpers import box, random_rotation


def _model():
    d = dict(dt=0.01, bodies=[box('a', (0, 0, 0)), box('b', (0.5, 0.1, 0.0)), box('c', (1.0, 0, 0), fixed=True)],
             joints=[dict(name='j0', parent='a', child='b', p0=[0.25, 0, -0.2], p1=[0.25, 0.1, 0.3],
                          init_angle=0.3,
                          driving=dict(aim_angle=1.2, enabled=True, strength_ratio=50.0),
                          limit=dict(lower=-0.2, upper=0.4, strength=3.0)),
                     dict(name='j1', parent='c', child='b', p0=[0.8, 0, 0], p1=[0.8, 0, 1],
                          limit=dict(lower=0.1, upper=0.1))])
    return compile_scene(Scene.from_dict(d))


def _state(model, seed, scale=0.15):
    """A generic state: rotated, sheared and displaced bodies (not near SO(3))."""
    rng = np.random.default_rng(seed)
    q = model.body_q0.copy()
    for b in range(model.body_count):
        if model.body_fixed[b]:
            continue
        A = random_rotation(rng) @ (np.eye(3) + scale * rng.normal(size=(3, 3)))
        q[b, 3:12] = A.ravel()
        q[b, :3] += 0.05 * rng.normal(size=3)
    return q


def _ctx(model, rel=None, active=True):
    rel = np.zeros(model.joint_count) if rel is None else rel
    return StepContext(h=0.01, joint_rel_start=rel,
                       drive_target=np.full(len(model.drive_joints), 0.9),
                       drive_active=np.full(len(model.drive_joints), active))


@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize('term_cls', [OrthoPotential, RevoluteJoint, Driving, Limit])
def test_term_derivatives_match_finite_differences(term_cls, seed):
    model = _model()
    term = term_cls.build(model)
    assert term is not None
    q = _state(model, seed)
    E = check_term(term, model, q, _ctx(model), eps=1e-6, rtol=2e-5)
    assert np.isfinite(E)


def test_limit_is_active_on_both_sides_and_zero_inside():
    model = _model()
    term = Limit.build(model)
    ctx = _ctx(model)
    q = model.body_q0.copy()
    assert term.energy(q, ctx) == 0.0 or model.limit_lower[1] == model.limit_upper[1]
    init = model.joint_init_angle[model.limit_joints]
    lo, up = model.limit_lower - init, model.limit_upper - init     # relative bounds
    on = np.ones(2, bool)
    E, d1, _ = term._phi(lo - 0.3, ctx, on)
    assert E[0] > 0 and d1[0] < 0          # below the lower limit it pushes up
    E, d1, _ = term._phi(up + 0.3, ctx, on)
    assert E[0] > 0 and d1[0] > 0          # above the upper limit it pushes down
    assert E[1] > 0 and d1[1] > 0          # zero-width limit: s|x - l|^3
    inside = 0.5 * (model.limit_lower[0] + model.limit_upper[0]) - init[0]
    E, d1, d2 = term._phi(np.full(2, inside), ctx, np.ones(2, bool))
    assert E[0] == 0.0 and d1[0] == 0.0 and d2[0] == 0.0


def test_projected_hessians_are_psd_far_from_rest():
    model = _model()
    q = _state(model, 7, scale=0.8)            # strongly sheared: ortho is non-convex here
    ctx = _ctx(model)
    for cls in (OrthoPotential, Driving, Limit):
        term = cls.build(model)
        _, _, Hraw = term.dense(model, q, ctx, project=False)
        _, _, H = term.dense(model, q, ctx, project=True)
        w = np.linalg.eigvalsh(H)
        assert w.min() > -1e-8 * abs(w).max(), cls.name
    _, _, Hraw = OrthoPotential.build(model).dense(model, q, ctx, project=False)
    assert np.linalg.eigvalsh(Hraw).min() < 0, 'this state should make the raw ortho Hessian indefinite'


def test_disabled_drive_contributes_nothing():
    model = _model()
    term = Driving.build(model)
    q = _state(model, 3)
    E, g, H = term.dense(model, q, _ctx(model, active=False))
    assert E == 0.0 and not g.any() and not H.any()


# -- the checker must be able to fail -------------------------------------------------------
class _Broken(OrthoPotential):
    mode = ''

    def accumulate(self, q, ctx, grad, diag, pair, project=True):
        super().accumulate(q, ctx, grad, diag, pair, project)
        b = self.bodies[0]
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
    model = _model()
    term = _Broken(model, np.flatnonzero(~model.body_fixed))
    term.mode = mode
    with pytest.raises(ValueError, match=message):
        check_term(term, model, _state(model, 0), _ctx(model))


def test_ortho_analytic_projection_matches_eigendecomposition():
    from abd_joint_sim.terms.base import project_psd
    from abd_joint_sim.terms.ortho import projected_hessian
    rng = np.random.default_rng(11)
    A = np.eye(3) + rng.normal(scale=0.6, size=(50, 3, 3))
    A[0] = random_rotation(rng)                         # at rest: twist modes exactly zero
    A[1] = np.diag([1.0, 1.0, 0.2])                     # compressed: negative modes
    C = A @ A.transpose(0, 2, 1) - np.eye(3)
    eye = np.eye(3)
    raw = (np.einsum('ij,blk->bikjl', eye, A.transpose(0, 2, 1) @ A)
           + np.einsum('bil,bjk->bikjl', A, A) + np.einsum('bij,kl->bikjl', C, eye)).reshape(-1, 9, 9)
    assert np.abs(projected_hessian(A) - project_psd(raw)).max() < 1e-10 * np.abs(raw).max()
    assert (np.linalg.eigvalsh(raw) < -1e-3).any(axis=1).sum() > 10     # the projection mattered
