"""Prismatic joint limit, libuipc UID 669 (docs/physics.md "Prismatic limit (UID 669)"): the
cubic barrier of UID 670 (limit.phi) on the distance x = d(q) of a prismatic joint
(prismatic.py), bounds [m] relative to init_distance. ∇E = E' ∇d; Newton's Hessian is
E''∇d∇dᵀ (PSD: E'' ≥ 0), the raw one adds E' ∇²d. Requirement: a prismatic joint (UID 20).
"""
from __future__ import annotations

from ..jit import kernel
from . import limit, prismatic

NAME = 'prismatic_limit'    #: in Solver.terms
STORED = True               #: E/h² is stored energy (World.mechanical_energy)
CONSTANT_HESSIAN = False
#: a scene joint's keys that put the term on it (jit/warmup.py's scenes)
EXAMPLE = dict(type='prismatic', limit=dict(lower=-0.01, upper=0.01))
FIELDS = (
    ('prismatic_limit_joints', '(Ls,) joints with UID 669'),
    ('prismatic_limit_lower', '[m] (Ls,) lower bound relative to init_distance'),
    ('prismatic_limit_upper', '[m] (Ls,) upper bound relative to init_distance'),
    ('prismatic_limit_strength', '(Ls,) s of UID 669'),
)


def used(model) -> bool:
    return len(model.prismatic_limit_joints) > 0


def from_scene(scene, model) -> dict:
    return limit.from_scene(scene, model, 'prismatic_limit_', True)


def build(model, data) -> dict:
    return limit.build(model, data, 'prismatic_limit_')


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
