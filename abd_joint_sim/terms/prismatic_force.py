"""External force along a prismatic joint's axis, libuipc UID 667 (docs/physics.md
"Prismatic external force (UID 667)"): a generalized force without energy, entering the
prediction q̃ only, as UID 668's torque. For each enabled joint with force f [N], from qⁿ
(BDF2: 2qⁿ − qⁿ⁻¹, as the torque):

    t̃_k = A_k t̄_k / |A_k t̄_k|          each body from its OWN axis (t̄_k: its anchors P0 → P1)
    t̂_j = ½ (t̃_i + t̃_j),   t̂_i = −t̂_j    same-order anchors: an exact antisymmetric pair
    F_k = J(c̄_k)ᵀ (f t̂_k)                  the force f t̂_k acting at the joint's point P0 on body k

J(c̄_k)ᵀ w = [w ; w ⊗ c̄_k]. The pair keeps its linear and angular momentum (docs/decisions.md).
A positive f increases the joint's distance. The force and its flag are rows T.. of
Control.torque_value and torque_enabled, after UID 668's (World.set_effort).
Requirement: a prismatic joint (UID 20; the scene refuses external_force on a revolute one).
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import flat, kernel
from . import select

NAME = 'external_force'     #: in Solver.terms
#: a scene joint's keys that put the term on it (jit/warmup.py's scenes)
EXAMPLE = dict(type='prismatic', external_force=dict(force=1.0, enabled=True))
FIELDS = (
    ('prismatic_force_joints', '(F,) joints with UID 667'),
)
AXIS_EPS = 1e-12


def used(model) -> bool:
    return len(model.prismatic_force_joints) > 0


def from_scene(scene, model) -> dict:
    """The Model's fields of this term: prismatic_force_joints (F,), the prismatic joints with
    UID 667; prismatic_force_value0 [N], _enabled0 and _effort_limit [N] (inf: none), (F,)."""
    sf = select.joints(scene, model, True, lambda j: j.external_force is not None)
    spec = [scene.joints[k].external_force for k in sf]
    return dict(prismatic_force_joints=sf,
                prismatic_force_value0=np.array([s.force for s in spec], float),
                prismatic_force_enabled0=np.array([s.enabled for s in spec], bool),
                prismatic_force_effort_limit=np.array([s.effort_limit for s in spec], float))


def build(model, data) -> dict:
    return dict(prismatic_force_joints=flat.array(model.prismatic_force_joints, np.int64))


@kernel
def any_active(m, effort_value, effort_enabled):
    """Whether some UID 667 force is enabled and nonzero (rows T.. of the effort arrays)."""
    T = m.torque_joints.size
    for k in range(m.prismatic_force_joints.size):
        if effort_enabled[T + k] and effort_value[T + k] != 0.0:
            return True
    return False


@kernel
def axis(q, m, j):
    """t̂_j of joint j (a prismatic joint) as a 3-tuple: the child's force direction (0 when
    neither body's axis is usable: not finite or of norm ≤ AXIS_EPS)."""
    parent, child, fr, k = m.joint_parent, m.joint_child, m.prismatic_frame, m.prismatic_slot[j]
    usable = 0
    e0 = e1 = e2 = 0.0
    for side in range(2):
        b = parent[j] if side == 0 else child[j]
        x0 = q[b, 3] * fr[k, side, 1, 0] + q[b, 4] * fr[k, side, 1, 1] + q[b, 5] * fr[k, side, 1, 2]
        x1 = q[b, 6] * fr[k, side, 1, 0] + q[b, 7] * fr[k, side, 1, 1] + q[b, 8] * fr[k, side, 1, 2]
        x2 = q[b, 9] * fr[k, side, 1, 0] + q[b, 10] * fr[k, side, 1, 1] + q[b, 11] * fr[k, side, 1, 2]
        n = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        if math.isfinite(n) and n > AXIS_EPS:
            usable += 1
            e0 += x0 / n
            e1 += x1 / n
            e2 += x2 / n
    half = 0.5 if usable == 2 else 1.0
    return half * e0, half * e1, half * e2


@kernel(inline='always')
def _body_force(f, e, fr, k, side, c):
    """Entry c of F_k = J(c̄_k)ᵀ (f t̂_k) on `side` (t̂_i = −t̂_j: f negated on the parent)."""
    sf = -f if side == 0 else f
    if c < 3:
        return sf * e[c]
    r = (c - 3) // 3
    return sf * e[r] * fr[k, side, 0, (c - 3) % 3]


@kernel
def add_acceleration(q, m, effort_value, effort_enabled, acc):
    """acc += M⁻¹F of the UID 667 forces on the free bodies (a fixed body's acceleration is
    never read), joint by joint (M⁻¹ is linear: the sum over joints is M⁻¹ ΣF)."""
    T = m.torque_joints.size
    joints, parent, child, fr, slot = (m.prismatic_force_joints, m.joint_parent, m.joint_child,
                                       m.prismatic_frame, m.prismatic_slot)
    Minv, fixed = m.body_Minv, m.body_fixed
    for k in range(joints.size):
        f = effort_value[T + k] if effort_enabled[T + k] else 0.0
        if f == 0.0:
            continue
        j = joints[k]
        e = axis(q, m, j)
        for side in range(2):
            b = parent[j] if side == 0 else child[j]
            if fixed[b]:
                continue
            for r in range(12):
                x = 0.0
                for c in range(12):
                    x += Minv[b, r, c] * _body_force(f, e, fr, slot[j], side, c)
                acc[b, r] += x
