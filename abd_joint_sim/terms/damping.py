"""Viscous joint damping (docs/physics.md "Joint damping"): a torque −d θ̇ on each damped
joint, d [N m s/rad], integrated implicitly with the integrator's θ̇ = (θ − θ*)/(c h):

    BDF1: θ* = θⁿ,                  c = 1
    BDF2: θ* = (4θⁿ − θⁿ⁻¹)/3,      c = 2/3
    E = K/2 (θ − θ*)²,   K = h d / c

θ (unwrapped, relative to init_angle) is taken linear in q from Newton's start q₀
(`references`, once per step):

    θ(q) ≈ θ₀ + ∇θ₀·(q − q₀),   E = K/2 e²,   e = θ₀ − θ* + ∇θ₀·(q − q₀)
    ∇E = K e ∇θ₀,   ∇²E = K ∇θ₀∇θ₀ᵀ (PSD: nothing to project)

Where the answer's own angle shows the linearisation missed by more than LINEAR_TOL, the
step linearises again at the answer and Newton goes on (`linearisation_holds`,
solver/step.py; docs/decisions.md).
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import SceneError
from ..geometry import skew
from ..jit import flat, kernel
from . import angle, select

#: largest h d / I of a damped joint (I: the lighter body's moment about the axis; for a
#: prismatic joint h c / m): beyond it the damper outweighs the body's inertia by more than
#: double precision resolves in Newton's matrix (measured: steps fail from ~4e19), and the
#: joint is locked for all purposes
DAMPING_RATIO_MAX = 1e15
NAME = 'joint_damping'      #: in Solver.terms
STORED = False              #: dissipative: no stored energy (World.mechanical_energy)
CONSTANT_HESSIAN = False
ANGLE_BUDGET = True          #: shares its bodies' inertia (model_data.joint_angle_budget)
#: a scene joint's keys that put the term on it (jit/warmup.py's scenes)
EXAMPLE = dict(damping=0.1)
FIELDS = (
    ('damping_joints', '(P,) joints with viscous damping'),
    ('damping_coeff', '[N m s/rad] (P,) their damping coefficients d'),
)


def used(model) -> bool:
    return len(model.damping_joints) > 0


def from_scene(scene, model) -> dict:
    """The Model's fields of this term: damping_joints (P,), the revolute joints with viscous
    damping, and damping_coeff [N m s/rad] (P,). SceneError for a damper a step cannot
    resolve: h d above DAMPING_RATIO_MAX times the lighter body's moment about the axis."""
    pj = select.joints(scene, model, False, lambda j: j.damping > 0.0)
    coeff = np.array([scene.joints[k].damping for k in pj], float)
    for j, d in zip(pj, coeff):
        inertia = axis_inertia(model, j)
        if model.dt * d > DAMPING_RATIO_MAX * inertia:
            raise SceneError(
                f'{scene.source}: joint {model.joint_names[j]!r}: damping {d:g} N m s/rad is '
                f'{model.dt * d / inertia:.1e} times the moment of its lighter body about the axis '
                f'({inertia:.2e} kg m^2) per step of {model.dt:g} s (dt d / I), beyond the '
                f'{DAMPING_RATIO_MAX:g} a step can resolve: a joint damped this hard does not '
                'move; lock it, or lower the damping')
    return dict(damping_joints=pj, damping_coeff=coeff)


def axis_inertia(model, j: int) -> float:
    """[kg m²] The lighter of joint j's two bodies' moment of inertia about the joint's axis
    (inf for a fixed body): ½ q̇ᵀ M q̇ = ½ I for a unit turn about the axis, q̇ =
    (−a × x̄0, [a]ₓ) in the body's rest frame (x = t + A x̄, A's rows in q). The same on any
    pose: the axis turns with the body."""
    m = model
    out = math.inf
    for side, b in enumerate((int(m.joint_parent[j]), int(m.joint_child[j]))):
        if m.body_fixed[b]:
            continue
        x0, x1 = m.joint_anchor0[j, side], m.joint_anchor1[j, side]
        a = (x1 - x0) / np.linalg.norm(x1 - x0)
        qdot = np.concatenate([-np.cross(a, x0), skew(a).ravel()])
        out = min(out, float(qdot @ m.body_M[b] @ qdot))
    return out


def build(model, data) -> dict:
    return dict(damping_joints=flat.array(model.damping_joints, np.int64),
                damping_coeff=flat.array(model.damping_coeff, np.float64))

BDF2_RATE = 2.0 / 3.0       # c of BDF2: θ̇ = (3θ − 4θⁿ + θⁿ⁻¹)/(2h) = (θ − θ*)/(c h)
#: a damper's row of `references`: K, θ₀ − θ*, ∇θ₀·q₀, ∇θ₀ over [vec A_parent, vec A_child],
#: θ*; damper k's is row L + k of StepContext.angle_ref, after the L limits' rows
ROW = 3 + 18 + 1
REFERENCE_COLUMNS = ROW     #: the columns of its rows of StepContext.angle_ref
TARGET = ROW - 1
#: how far the linearised angle may miss the answer's own, as a share of the damper's turn in
#: the step (θ − θ*) or of the rotation Newton's tolerance allows (transrate_tol h), whichever
#: is larger: beyond it the angle is linearised again at the answer and Newton continues
LINEAR_TOL = 1e-3
#: at most this many such repeats in a step (the second linearisation is at Newton's answer)
RELINEARISE_MAX = 3


@kernel
def references(m, q0, q_prev, angle_start, h, bdf2, work, out):
    """Rows L + k of out (angle_ref, L limits): per damped joint k, K = h d / c, θ₀ − θ*,
    ∇θ₀·q₀, ∇θ₀ and θ* for Newton's start q0, from angle_start (θⁿ) and, with bdf2, q_prev
    (θⁿ⁻¹). `work`: angle.ANGLE_WORK_SHAPE. Returns out."""
    joints, d = m.damping_joints, m.damping_coeff
    L = m.limit_joints.size
    parent, child, nbar, bbar = m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar
    G = work[8]
    for k in range(joints.size):
        j = joints[k]
        now = angle_start[j]
        if bdf2:
            before = angle.unwrap(angle.theta_at(q_prev, parent, child, nbar, bbar, j), now)
            target, rate = (4.0 * now - before) / 3.0, BDF2_RATE
        else:
            target, rate = now, 1.0
        theta0 = angle.theta_derivatives_at(q0, parent, child, nbar, bbar, j, G, work[0:8], False,
                                             work[0:8])
        i_body, j_body = parent[j], child[j]
        dot = 0.0
        for a in range(9):
            dot += G[a] * q0[i_body, 3 + a] + G[9 + a] * q0[j_body, 3 + a]
        row = L + k
        for a in range(18):
            out[row, 3 + a] = G[a]
        out[row, 0] = h * d[k] / rate
        out[row, 1] = angle.unwrap(theta0, now) - target
        out[row, 2] = dot
        out[row, TARGET] = target
    return out


@kernel
def linearisation_holds(m, q, angle, ref, floor):
    """Whether at Newton's answer q every damper's linearised angle is within LINEAR_TOL of
    its exact one, `angle` (J,, relative to init_angle); `floor` [rad]: the smallest turn the
    share is taken of."""
    joints, parent, child, init = m.damping_joints, m.joint_parent, m.joint_child, m.joint_init_angle
    L = m.limit_joints.size
    for k in range(joints.size):
        j = joints[k]
        exact = angle[j] - init[j] - ref[L + k, TARGET]
        miss = _excess(q, ref, L + k, parent[j], child[j]) - exact
        if not abs(miss) <= LINEAR_TOL * max(abs(exact), floor):
            return False
    return True


@kernel(inline='always')
def _excess(q, ref, k, i_body, j_body):
    """e = θ₀ − θ* + ∇θ₀·(q − q₀) of the damper whose row of ref is k."""
    dot = 0.0
    for a in range(9):
        dot += ref[k, 3 + a] * q[i_body, 3 + a] + ref[k, 12 + a] * q[j_body, 3 + a]
    return ref[k, 1] + (dot - ref[k, 2])


@kernel
def energy(q, m, ctx):
    joints, parent, child, ref = m.damping_joints, m.joint_parent, m.joint_child, ctx.angle_ref
    L = m.limit_joints.size
    E = 0.0
    for k in range(joints.size):
        j = joints[k]
        e = _excess(q, ref, L + k, parent[j], child[j])
        E += 0.5 * ref[L + k, 0] * e * e
    return E


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E and ∇²E (exact, PSD: `project` changes nothing); returns E (the bits of `energy`)."""
    joints, parent, child, ref = m.damping_joints, m.joint_parent, m.joint_child, ctx.angle_ref
    L = m.limit_joints.size
    E = 0.0
    for kk in range(joints.size):
        j = joints[kk]
        k = L + kk                          # the damper's row
        i_body, j_body = parent[j], child[j]
        K = ref[k, 0]
        e = _excess(q, ref, k, i_body, j_body)
        E += 0.5 * K * e * e
        f = K * e
        # ∇θ₀ of each body in locals and each row written out: vector operations (SLP)
        a0, a1, a2, a3, a4 = ref[k, 3], ref[k, 4], ref[k, 5], ref[k, 6], ref[k, 7]
        a5, a6, a7, a8 = ref[k, 8], ref[k, 9], ref[k, 10], ref[k, 11]
        b0, b1, b2, b3, b4 = ref[k, 12], ref[k, 13], ref[k, 14], ref[k, 15], ref[k, 16]
        b5, b6, b7, b8 = ref[k, 17], ref[k, 18], ref[k, 19], ref[k, 20]
        for a in range(9):
            gi = ref[k, 3 + a]
            gj = ref[k, 12 + a]
            grad[i_body, 3 + a] += f * gi
            grad[j_body, 3 + a] += f * gj
            gi *= K
            gj *= K
            r = 3 + a
            diag[i_body, r, 3] += gi * a0
            diag[i_body, r, 4] += gi * a1
            diag[i_body, r, 5] += gi * a2
            diag[i_body, r, 6] += gi * a3
            diag[i_body, r, 7] += gi * a4
            diag[i_body, r, 8] += gi * a5
            diag[i_body, r, 9] += gi * a6
            diag[i_body, r, 10] += gi * a7
            diag[i_body, r, 11] += gi * a8
            diag[j_body, r, 3] += gj * b0
            diag[j_body, r, 4] += gj * b1
            diag[j_body, r, 5] += gj * b2
            diag[j_body, r, 6] += gj * b3
            diag[j_body, r, 7] += gj * b4
            diag[j_body, r, 8] += gj * b5
            diag[j_body, r, 9] += gj * b6
            diag[j_body, r, 10] += gj * b7
            diag[j_body, r, 11] += gj * b8
            pair[j, r, 3] += gi * b0
            pair[j, r, 4] += gi * b1
            pair[j, r, 5] += gi * b2
            pair[j, r, 6] += gi * b3
            pair[j, r, 7] += gi * b4
            pair[j, r, 8] += gi * b5
            pair[j, r, 9] += gi * b6
            pair[j, r, 10] += gi * b7
            pair[j, r, 11] += gi * b8
    return E
