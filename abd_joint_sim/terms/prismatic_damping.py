"""Viscous damping of a prismatic joint (docs/physics.md "Prismatic joint damping"): a force
−c ḋ along the slide, c [N s/m], implicit as terms/damping.py with ḋ = (d − d*)/(c_I h):

    BDF1: d* = dⁿ,                 c_I = 1
    BDF2: d* = (4dⁿ − dⁿ⁻¹)/3,     c_I = 2/3
    E = K/2 (d(q) − d*)²,   K = h c / c_I

d(q) (prismatic.py) is used as it is: Newton's Hessian is K ∇d∇dᵀ (PSD), the raw one adds
K (d − d*) ∇²d. `references` writes K and d* of damper k into row L + P + k of
StepContext.angle_ref. Requirement: a prismatic joint (UID 20).
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import SceneError
from ..jit import flat, kernel
from . import prismatic, select
from .damping import DAMPING_RATIO_MAX

NAME = 'prismatic_damping'  #: in Solver.terms
STORED = False              #: dissipative: no stored energy (World.mechanical_energy)
CONSTANT_HESSIAN = False
#: a scene joint's keys that put the term on it (jit/warmup.py's scenes)
EXAMPLE = dict(type='prismatic', damping=0.5)
FIELDS = (
    ('prismatic_damping_joints', '(Ps,) prismatic joints with viscous damping'),
    ('prismatic_damping_coeff', '[N s/m] (Ps,) their damping coefficients c'),
)
BDF2_RATE = 2.0 / 3.0       # c_I of BDF2: ḋ = (3d − 4dⁿ + dⁿ⁻¹)/(2h) = (d − d*)/(c_I h)
REFERENCE_COLUMNS = 2       #: the columns of its rows of StepContext.angle_ref: K, d*


def used(model) -> bool:
    return len(model.prismatic_damping_joints) > 0


def from_scene(scene, model) -> dict:
    """The Model's fields of this term: prismatic_damping_joints (Ps,), the prismatic joints
    with viscous damping, and prismatic_damping_coeff [N s/m] (Ps,). SceneError for a damper a
    step cannot resolve: h c above damping.DAMPING_RATIO_MAX times the lighter body's mass."""
    sp = select.joints(scene, model, True, lambda j: j.damping > 0.0)
    coeff = np.array([scene.joints[k].damping for k in sp], float)
    for j, c in zip(sp, coeff):
        free = [float(model.body_mass[b]) for b in (model.joint_parent[j], model.joint_child[j])
                if not model.body_fixed[b]]
        mass = min(free) if free else math.inf
        if model.dt * c > DAMPING_RATIO_MAX * mass:
            raise SceneError(
                f'{scene.source}: joint {model.joint_names[j]!r}: damping {c:g} N s/m is '
                f'{model.dt * c / mass:.1e} times the mass of its lighter body ({mass:.2e} kg) per '
                f'step of {model.dt:g} s (dt c / m), beyond the {DAMPING_RATIO_MAX:g} a step can '
                'resolve: a joint damped this hard does not move; lock it, or lower the damping')
    return dict(prismatic_damping_joints=sp, prismatic_damping_coeff=coeff)


def build(model, data) -> dict:
    return dict(prismatic_damping_joints=flat.array(model.prismatic_damping_joints, np.int64),
                prismatic_damping_coeff=flat.array(model.prismatic_damping_coeff, np.float64))


@kernel
def first_row(m):
    """The row of damper 0 in StepContext.angle_ref: after the limits' and revolute dampers'."""
    return m.limit_joints.size + m.damping_joints.size


@kernel
def references(m, q0, q_prev, angle_start, h, bdf2, work, out):
    """Rows first_row + k of out (angle_ref): K = h c / c_I and d* of damper k, from
    angle_start (dⁿ) and, with bdf2, q_prev (dⁿ⁻¹). Returns out."""
    joints, c = m.prismatic_damping_joints, m.prismatic_damping_coeff
    parent, child, fr, slot = m.joint_parent, m.joint_child, m.prismatic_frame, m.prismatic_slot
    row = first_row(m)
    for k in range(joints.size):
        j = joints[k]
        now = angle_start[j]
        if bdf2:
            before = prismatic.distance_at(q_prev, parent[j], child[j], fr, slot[j])
            target, rate = (4.0 * now - before) / 3.0, BDF2_RATE
        else:
            target, rate = now, 1.0
        out[row + k, 0] = h * c[k] / rate
        out[row + k, 1] = target
    return out


@kernel
def energy(q, m, ctx):
    joints, parent, child, fr, slot = (m.prismatic_damping_joints, m.joint_parent, m.joint_child,
                                       m.prismatic_frame, m.prismatic_slot)
    ref = ctx.angle_ref
    row = first_row(m)
    E = 0.0
    for k in range(joints.size):
        j = joints[k]
        e = prismatic.distance_at(q, parent[j], child[j], fr, slot[j]) - ref[row + k, 1]
        E += 0.5 * ref[row + k, 0] * e * e
    return E


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E and ∇²E (Gauss-Newton with `project`), straight into the joint's blocks, ∇d in rows
    0–1 of ctx.angle_work; returns E (the bits of `energy`)."""
    joints, parent, child, fr, slot = (m.prismatic_damping_joints, m.joint_parent, m.joint_child,
                                       m.prismatic_frame, m.prismatic_slot)
    ref = ctx.angle_ref
    row = first_row(m)
    work = ctx.angle_work
    E = 0.0
    for k in range(joints.size):
        j = joints[k]
        i_body, j_body, s = parent[j], child[j], slot[j]
        K = ref[row + k, 0]
        e = prismatic.distance_at(q, i_body, j_body, fr, s) - ref[row + k, 1]
        E += 0.5 * K * e * e
        prismatic.slide_gradient(q, i_body, j_body, fr, s, 0.5, 0.5, work, 0)      # ∇d
        prismatic.add_rank_one(work, 0, K * e, K, i_body, j_body, j, grad, diag, pair)
        if not project:                                                             # + K e ∇²d
            prismatic.add_slide_curvature(fr, s, i_body, j_body, j, 0.5 * K * e, 0.5 * K * e, diag, pair)
    return E
