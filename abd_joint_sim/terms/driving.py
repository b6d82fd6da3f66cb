"""Joint driving, libuipc UID 19 (docs/physics.md "Driving (UID 19)"): a spring on the joint
angle toward a target,

    E = K/2 (θ − θ_target)²,   K = γ (m_i + m_j),   E' = K (θ − θ_target),   E'' = K

for each enabled drive; θ is the unwrapped angle relative to init_angle (angle.py) and
θ_target the aim (relative to init_angle), or the angle at the start of the step when the
drive is passive. Like UID 18 it carries no h² (physical potential E/h²). Gradient and
Hessian via angle.accumulate_angle_joint (PSD-projected, or exact where the bodies' inertia
keeps Newton's matrix positive definite).
"""
from __future__ import annotations

import numpy as np

from ..jit import flat, kernel
from . import angle, select
from .revolute import stiffness

NAME = 'driving'            #: in Solver.terms
STORED = True               #: E/h² is stored energy (World.mechanical_energy)
CONSTANT_HESSIAN = False
ANGLE_BUDGET = True          #: shares its bodies' inertia (model_data.joint_angle_budget)
#: a scene joint's keys that put the term on it (jit/warmup.py's scenes)
EXAMPLE = dict(driving=dict(aim_angle=0.5, enabled=True))
FIELDS = (
    ('drive_joints', '(D,) joints with UID 19'),
    ('drive_K', '(D,) UID 19 stiffness γ (m_i + m_j)'),
)


def used(model) -> bool:
    return len(model.drive_joints) > 0


def from_scene(scene, model, prefix='drive_', sliding=False, aim='aim_angle') -> dict:
    """The Model's fields of this term (prismatic_driving's with its `prefix`, on the sliding
    joints, aim `aim_distance`): the joints with a drive, (n,); their K [kg] (γ (m_i + m_j)),
    aim0 (rad, or m sliding), passive0 and enabled0, (n,)."""
    ks = select.joints(scene, model, sliding, lambda j: j.driving is not None)
    spec = [scene.joints[k].driving for k in ks]
    mass, parent, child = model.body_mass, model.joint_parent, model.joint_child
    return {prefix + 'joints': ks,
            prefix + 'K': np.array([stiffness(s.strength_ratio, mass[parent[k]], mass[child[k]])
                                    for s, k in zip(spec, ks)], float),
            prefix + 'aim0': np.array([getattr(s, aim) for s in spec], float),
            prefix + 'passive0': np.array([s.passive for s in spec], bool),
            prefix + 'enabled0': np.array([s.enabled for s in spec], bool)}


def build(model, data) -> dict:
    return dict(drive_joints=flat.array(model.drive_joints, np.int64),
                drive_K=flat.array(model.drive_K, np.float64))


@kernel
def energy(q, m, ctx):
    parent, child, nbar, bbar = m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar
    joints, K, on, target, start = m.drive_joints, m.drive_K, ctx.drive_on, ctx.drive_target, ctx.angle_start
    E = 0.0
    if joints.size == 0:                    # (the loop below would still cost its setup)
        return E
    for k in range(joints.size):
        if on[k]:
            j = joints[k]
            x = angle.unwrap(angle.theta_at(q, parent, child, nbar, bbar, j), start[j])
            e = x - target[k]
            E += 0.5 * K[k] * e * e
    return E


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E and the (projected) Hessian of the enabled drives via angle.accumulate_angle_joint
    (in ctx.angle_work); returns E (`energy`'s bits)."""
    drive_joints, K, on = m.drive_joints, m.drive_K, ctx.drive_on
    target, start = ctx.drive_target, ctx.angle_start
    parent, child, nbar, bbar = m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar
    budget = m.joint_angle_budget
    work = ctx.angle_work
    E = 0.0
    for k in range(drive_joints.size):
        if on[k]:
            j = drive_joints[k]
            x = angle.unwrap(angle.theta_at(q, parent, child, nbar, bbar, j), start[j])
            e = x - target[k]
            E += 0.5 * K[k] * e * e
            angle.accumulate_angle_joint(q, parent, child, nbar, bbar, j, K[k] * e, K[k],
                                          grad, diag, pair, project, work, ctx.scale * budget[j])
    return E
