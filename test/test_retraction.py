"""The screw retraction Newton steps with (abd_joint_sim/solver/retraction.py).

Checked against geometry, not against itself: an infinitesimal rigid motion about a known
axis must give the exact finite rotation about that axis; any step must agree with q + Δq to
first order (error ratio 4 when Δq halves); a pure deformation must be applied unchanged; the
linear momentum of a free system must be exactly that of the linear step.
"""
import numpy as np
import pytest

from abd_joint_sim import Scene
from abd_joint_sim.model import compile_scene
from abd_joint_sim.solver import model_data, workspace
from abd_joint_sim.solver import retraction
from abd_joint_sim.solver.retraction import SCREW_STRAIN, SMALL_ANGLE, floating_groups

from conftest import SCENES


def _apply(model, q, dq):
    """q ⊕ dq of the compiled retraction for a model."""
    out = np.empty_like(q)
    data = model_data.build(model)
    retraction.retract(np.ascontiguousarray(q), np.ascontiguousarray(dq), 1.0, data,
                       workspace.build(model, data), out)
    return out


def _anchored_body():
    """A model whose body 0 is free and jointed to a fixed body 1: no group shift."""
    box = dict(box=[0.2, 0.2, 0.2], density=1000.0)
    return compile_scene(Scene.from_dict(dict(
        dt=0.01, bodies=[dict(name='free', position=[0, 0, 0], **box),
                         dict(name='base', position=[1, 0, 0], fixed=True, **box)],
        joints=[dict(name='j', parent='base', child='free', p0=[0.5, 0, 0], p1=[0.5, 0, 1])])))


_ANCHORED = None


def retract(q, dq, bodies):
    """q ⊕ dq of one free body (row 0 of q), without a momentum correction."""
    global _ANCHORED
    if _ANCHORED is None:
        _ANCHORED = _anchored_body()
    q2 = np.vstack([q, _ANCHORED.body_q0[1:]])
    dq2 = np.vstack([dq, np.zeros((1, 12))])
    return _apply(_ANCHORED, q2, dq2)[:1]


def screw_coefficients(theta):
    return np.array([retraction.screw_coefficients(float(t)) for t in np.atleast_1d(theta)]).T


def _skew(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _rotation(w):
    th = np.linalg.norm(w)
    K = _skew(w / th)
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def _random_rotation(rng):
    return _rotation(rng.normal(size=3))


@pytest.mark.slow
@pytest.mark.parametrize('angle', [1e-9, 1e-5, 1e-3, 0.3, 1.5, 3.0])
def test_rigid_step_about_an_axis_is_the_exact_rotation(angle):
    rng = np.random.default_rng(int(angle * 1e9) % 1000)
    A = _random_rotation(rng)
    p, c = rng.normal(size=3), rng.normal(size=3)       # c: a point on the rotation axis
    axis = rng.normal(size=3)
    w = angle * axis / np.linalg.norm(axis)
    W = _skew(w)
    slide = 0.2 * axis                                  # a screw: plus a slide along the axis
    q = np.concatenate([p, A.ravel()])[None]
    dq = np.concatenate([W @ (p - c) + slide, (W @ A).ravel()])[None]
    out = retract(q, dq, np.array([0]))
    R = _rotation(w)
    np.testing.assert_allclose(out[0, :3], c + R @ (p - c) + slide, atol=1e-14)
    np.testing.assert_allclose(out[0, 3:].reshape(3, 3), R @ A, atol=1e-14)
    # the body is not stretched, and a point on the axis only slides
    A2 = out[0, 3:].reshape(3, 3)
    np.testing.assert_allclose(A2 @ A2.T, np.eye(3), atol=1e-14)
    xbar = np.linalg.solve(A, c - p)                   # body point that sits on the axis
    np.testing.assert_allclose(out[0, :3] + A2 @ xbar, c + slide, atol=1e-13)


def test_first_order_agreement_with_the_linear_step():
    rng = np.random.default_rng(3)
    q = np.concatenate([rng.normal(size=3), (_random_rotation(rng) + 1e-3 * rng.normal(size=(3, 3))).ravel()])[None]
    dq = rng.normal(size=(1, 12))
    errs = [np.abs(retract(q, e * dq, np.array([0])) - (q + e * dq)).max() for e in (1e-2, 5e-3, 2.5e-3)]
    assert errs[0] > 1e-7                                  # the correction is really there
    assert errs[0] / errs[1] == pytest.approx(4.0, rel=0.05)
    assert errs[1] / errs[2] == pytest.approx(4.0, rel=0.05)


def test_pure_deformation_and_translation_are_linear():
    rng = np.random.default_rng(4)
    A = _random_rotation(rng)
    q = np.concatenate([rng.normal(size=3), A.ravel()])[None]
    S = rng.normal(size=(3, 3))
    S = 0.5 * (S + S.T)
    # ΔA = S A with S symmetric has no spin: skew(ΔA Aᵀ) = skew(S) = 0
    dq = np.concatenate([rng.normal(size=3), (S @ A).ravel()])[None]
    np.testing.assert_allclose(retract(q, dq, np.array([0])), q + dq, atol=1e-15)


def test_a_body_far_from_a_rotation_takes_the_linear_step():
    # a sheared A (a thin body's prediction under a couple): skew(ΔA A⁻¹) is no spin there
    rng = np.random.default_rng(6)
    A = _random_rotation(rng) @ (np.eye(3) + 3 * SCREW_STRAIN * np.triu(np.ones((3, 3)), 1))
    q = np.concatenate([rng.normal(size=3), A.ravel()])[None]
    dq = 0.3 * rng.normal(size=(1, 12))
    np.testing.assert_array_equal(retract(q, dq, np.array([0])), q + dq)
    q[0, 3:] = _random_rotation(rng).ravel()
    assert np.abs(retract(q, dq, np.array([0])) - (q + dq)).max() > 1e-3


def test_screw_coefficients_are_smooth_at_the_series_switch():
    edge = SMALL_ANGLE * np.array([1 - 1e-12, 1 + 1e-12])
    for f in screw_coefficients(edge):
        assert f[0] == pytest.approx(f[1], rel=1e-11)
    # the series against exact values at 1e-3 rad (closed forms in extended precision)
    t = np.longdouble('1e-3')
    s, c, b = screw_coefficients(np.array([1e-3]))
    assert s[0] == pytest.approx(float(np.sin(t) / t), rel=1e-15)
    assert c[0] == pytest.approx(float((1 - np.cos(t)) / t**2), rel=1e-12)
    assert b[0] == pytest.approx(float((t - np.sin(t)) / t), rel=1e-12)
    s, c, b = screw_coefficients(np.array([0.0, 2.0]))
    assert (s[0], c[0], b[0]) == (1.0, 0.5, 0.0)
    assert s[1] == pytest.approx(np.sin(2) / 2) and c[1] == pytest.approx((1 - np.cos(2)) / 4)
    assert b[1] == pytest.approx((2 - np.sin(2)) / 2)


def test_free_system_keeps_the_linear_steps_momentum():
    model = compile_scene(Scene.from_yaml(SCENES / 'free_pair.yaml'))
    groups = floating_groups(model)
    assert groups.tolist() == [0, 0]
    rng = np.random.default_rng(5)
    q = model.body_q0.copy()
    dq = 0.3 * rng.normal(size=q.shape)
    out = _apply(model, q, dq)
    m = model.body_mass[:, None]
    np.testing.assert_allclose(np.sum(m * out[:, :3], axis=0), np.sum(m * (q + dq)[:, :3], axis=0), atol=1e-13)
    assert np.abs(out - (q + dq)).max() > 1e-3              # and it did turn the bodies


def test_anchored_group_is_not_shifted():
    # the hinge's arm hangs on a fixed base: its step turns it about the hinge, no shift
    model = compile_scene(Scene.from_yaml(SCENES / 'hinge.yaml'))
    assert floating_groups(model).tolist() == [-1, -1]
    assert model_data.build(model).group_count == 0
    q = model.body_q0.copy()
    w = np.array([0.0, 0.0, 0.4])                          # about the hinge line (z through 0)
    dq = np.zeros_like(q)
    dq[1, :3] = _skew(w) @ q[1, :3]
    dq[1, 3:] = (_skew(w) @ q[1, 3:].reshape(3, 3)).ravel()
    out = _apply(model, q, dq)
    np.testing.assert_allclose(out[1, :3], _rotation(w) @ q[1, :3], atol=1e-14)
    np.testing.assert_array_equal(out[0], q[0])
