"""Prismatic joint limit, libuipc UID 669 (docs/physics.md "Prismatic limit (UID 669)"): the
cubic barrier of UID 670 (limit.phi) on the distance x = d(q) of a prismatic joint
(prismatic.py), relative to init_distance, with l = lower − init_distance,
u = upper − init_distance, w = u − l and strength s:

    x > u:  E = s ((x − u)/w)³          x < l:  E = s ((l − x)/w)³          inside: E = 0
    w = 0:  E = s |x − l|³ (a locked joint)

∇E = E' ∇d; Newton's Hessian is E''∇d∇dᵀ (PSD: E'' ≥ 0), the raw one adds E' ∇²d.
Requirement: a prismatic joint (UID 20); bounds in m.
"""
from __future__ import annotations

import numpy as np

from ..jit import flat, kernel
from . import limit, prismatic, select

NAME = 'prismatic_limit'    #: in Solver.terms
STORED = True               #: E/h² is stored energy (World.mechanical_energy)
CONSTANT_HESSIAN = False
#: the fields of the compiled model (solver/model_data.py) this term owns: (name, meaning)
FIELDS = (
    ('prismatic_limit_joints', '(Ls,) joints with UID 669'),
    ('prismatic_limit_lower', '[m] (Ls,) lower bound relative to init_distance'),
    ('prismatic_limit_upper', '[m] (Ls,) upper bound relative to init_distance'),
    ('prismatic_limit_strength', '(Ls,) s of UID 669'),
)


def used(model) -> bool:
    return len(model.prismatic_limit_joints) > 0


def from_scene(scene, model) -> dict:
    """The Model's fields of this term: prismatic_limit_joints (n,), the joints with UID 669;
    prismatic_limit_lower and _upper [m] (absolute), prismatic_limit_strength, (n,)."""
    ks = select.joints(scene, model, True, lambda j: j.limit is not None)
    spec = [scene.joints[k].limit for k in ks]
    return dict(prismatic_limit_joints=ks, prismatic_limit_lower=np.array([s.lower for s in spec], float),
                prismatic_limit_upper=np.array([s.upper for s in spec], float),
                prismatic_limit_strength=np.array([s.strength for s in spec], float))


def build(model, data) -> dict:
    """FIELDS' values for a Model (data: the compiled model's fields built so far)."""
    lj, init = model.prismatic_limit_joints, model.joint_init_angle
    return dict(prismatic_limit_joints=flat.array(lj, np.int64),
                prismatic_limit_lower=flat.array(model.prismatic_limit_lower - init[lj], np.float64),
                prismatic_limit_upper=flat.array(model.prismatic_limit_upper - init[lj], np.float64),
                prismatic_limit_strength=flat.array(model.prismatic_limit_strength, np.float64))


@kernel
def energy(q, m, ctx):
    joints, lower, upper, strength = (m.prismatic_limit_joints, m.prismatic_limit_lower,
                                      m.prismatic_limit_upper, m.prismatic_limit_strength)
    parent, child, fr, slot = m.joint_parent, m.joint_child, m.prismatic_frame, m.prismatic_slot
    E = 0.0
    for k in range(joints.size):
        j = joints[k]
        x = prismatic.distance_at(q, parent[j], child[j], fr, slot[j])
        if limit.active(x, lower[k], upper[k]):
            E += limit.phi(x, lower[k], upper[k], strength[k])[0]
    return E


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E and ∇²E of the limits outside their range (Gauss-Newton with `project`), straight
    into the joint's blocks, ∇d in rows 0–1 of ctx.angle_work; returns E (the bits of `energy`)."""
    joints, lower, upper, strength = (m.prismatic_limit_joints, m.prismatic_limit_lower,
                                      m.prismatic_limit_upper, m.prismatic_limit_strength)
    parent, child, fr, slot = m.joint_parent, m.joint_child, m.prismatic_frame, m.prismatic_slot
    work = ctx.angle_work
    E = 0.0
    for k in range(joints.size):
        j = joints[k]
        i_body, j_body, s = parent[j], child[j], slot[j]
        x = prismatic.distance_at(q, i_body, j_body, fr, s)
        if not limit.active(x, lower[k], upper[k]):
            continue
        e, d1, d2 = limit.phi(x, lower[k], upper[k], strength[k])
        E += e
        prismatic.slide_gradient(q, i_body, j_body, fr, s, 0.5, 0.5, work, 0)      # ∇d
        prismatic.add_rank_one(work, 0, d1, d2, i_body, j_body, j, grad, diag, pair)
        if not project:                                                             # + E' ∇²d
            prismatic.add_slide_curvature(fr, s, i_body, j_body, j, 0.5 * d1, 0.5 * d1, diag, pair)
    return E
