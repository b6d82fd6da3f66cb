"""Prismatic joint driving, libuipc UID 21 (docs/physics.md "Prismatic driving (UID 21)"): a
spring pulling a prismatic joint (UID 20) toward a target distance d̃,

    E = K/2 (u_i − d̃)² + K/2 (u_j − d̃)²,   u_k = t_k·(c_j − c_i),   K = γ (m_i + m_j)

for each enabled drive (u_k the slide along body k's own axis; d̃ the aim minus
init_distance, or the start's distance when passive). No h². Newton's Hessian is
K Σ_k ∇u_k∇u_kᵀ (PSD), the raw one adds K Σ_k (u_k − d̃) ∇²u_k. The targets are rows D.. of
StepContext.drive_target and drive_on and of Control's drive arrays, after UID 19's.
Requirement: a prismatic joint (the scene refuses `aim_angle` on one).
"""
from __future__ import annotations

import numpy as np

from ..jit import flat, kernel
from . import driving, prismatic

NAME = 'prismatic_driving'  #: in Solver.terms
STORED = True               #: E/h² is stored energy (World.mechanical_energy)
CONSTANT_HESSIAN = False
#: a scene joint's keys that put the term on it (jit/warmup.py's scenes)
EXAMPLE = dict(type='prismatic', driving=dict(aim_distance=0.01, enabled=True))
FIELDS = (
    ('prismatic_drive_joints', '(Ds,) joints with UID 21'),
    ('prismatic_drive_K', '[kg] (Ds,) UID 21 stiffness γ (m_i + m_j)'),
)


def used(model) -> bool:
    return len(model.prismatic_drive_joints) > 0


def from_scene(scene, model) -> dict:
    return driving.from_scene(scene, model, 'prismatic_drive_', True, 'aim_distance')


def build(model, data) -> dict:
    return dict(prismatic_drive_joints=flat.array(model.prismatic_drive_joints, np.int64),
                prismatic_drive_K=flat.array(model.prismatic_drive_K, np.float64))


@kernel
def targets(m, angle_start, drive_aim, drive_passive, target):
    """target[D + k] = d̃ of UID 21 drive k (after the D revolute drives): its aim minus
    init_distance, or angle_start when passive."""
    D = m.drive_joints.size
    joints, init = m.prismatic_drive_joints, m.joint_init_angle
    for k in range(joints.size):
        j = joints[k]
        target[D + k] = angle_start[j] if drive_passive[D + k] else drive_aim[D + k] - init[j]


@kernel
def energy(q, m, ctx):
    joints, K = m.prismatic_drive_joints, m.prismatic_drive_K
    parent, child, fr, slot = m.joint_parent, m.joint_child, m.prismatic_frame, m.prismatic_slot
    D = m.drive_joints.size
    on, target = ctx.drive_on, ctx.drive_target
    E = 0.0
    for k in range(joints.size):
        if on[D + k]:
            j = joints[k]
            r, ti, tj = prismatic.axis_and_offset(q, parent[j], child[j], fr, slot[j])
            ui = uj = 0.0
            for c in range(3):
                ui += ti[c] * r[c]
                uj += tj[c] * r[c]
            ei, ej = ui - target[D + k], uj - target[D + k]
            E += 0.5 * K[k] * (ei * ei + ej * ej)
    return E


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E and ∇²E (Gauss-Newton with `project`), straight into the joint's blocks, ∇u_i and
    ∇u_j in rows 0–3 of ctx.angle_work; returns E (the bits of `energy`)."""
    joints, K = m.prismatic_drive_joints, m.prismatic_drive_K
    parent, child, fr, slot = m.joint_parent, m.joint_child, m.prismatic_frame, m.prismatic_slot
    D = m.drive_joints.size
    on, target = ctx.drive_on, ctx.drive_target
    work = ctx.angle_work
    E = 0.0
    for k in range(joints.size):
        if not on[D + k]:
            continue
        j = joints[k]
        i_body, j_body, s = parent[j], child[j], slot[j]
        ui, uj = prismatic.slide_gradient(q, i_body, j_body, fr, s, 1.0, 0.0, work, 0)    # ∇u_i
        prismatic.slide_gradient(q, i_body, j_body, fr, s, 0.0, 1.0, work, 2)             # ∇u_j
        ei, ej = ui - target[D + k], uj - target[D + k]
        Kk = K[k]
        E += 0.5 * Kk * (ei * ei + ej * ej)
        prismatic.add_rank_one(work, 0, Kk * ei, Kk, i_body, j_body, j, grad, diag, pair)
        prismatic.add_rank_one(work, 2, Kk * ej, Kk, i_body, j_body, j, grad, diag, pair)
        if not project:                                     # + K Σ_k (u_k − d̃) ∇²u_k
            prismatic.add_slide_curvature(fr, s, i_body, j_body, j, Kk * ei, Kk * ej, diag, pair)
    return E
