"""Revolute joint, libuipc UID 18 (docs/physics.md "Revolute joint (UID 18)"): the two
anchors P0, P1 stored in each body's rest frame (x̄0_k, x̄1_k, same order on both bodies)
are pulled together by

    E = K/2 Σ_{a ∈ {P0, P1}} |x_i^a − x_j^a|²,   x_k^a = A_k x̄_k^a + p_k = J(x̄_k^a) q_k,
    K = γ (m_i + m_j)   (γ = strength_ratio)

computed from the separations (no cancellation, docs/decisions.md). ∇E = K Σ_a D_aᵀ d_a
with d_a = x_i^a − x_j^a, D_a = [J(x̄_i^a), −J(x̄_j^a)]; the Hessian K Σ_a D_aᵀD_a is
constant and PSD (`constant_hessian`, summed into Newton's constant blocks once per model
by `add_constant_hessian`). It carries no h²: its physical potential is E/h².
"""
from __future__ import annotations

import math

import numpy as np

from ..geometry import point_jacobian
from ..jit import flat, kernel
from . import select

NAME = 'revolute_joint'     #: in Solver.terms
STORED = True               #: E/h² is stored energy (World.mechanical_energy)
CONSTANT_HESSIAN = True     #: Newton adds only the gradient (accumulate_gradient)
# Joint anchors further apart than SEPARATION_WARN x the smaller body's size: the step warns
# (an overloaded joint: torque or speed too large for strength_ratio and dt). Further than
# SEPARATION_FAULT x the larger body's size, the joint has come apart: no joint force of
# UID 18 is stiff enough to make that a valid state, so the step fails.
SEPARATION_WARN = 0.01
SEPARATION_FAULT = 1e3
#: a scene joint's keys that put the term on it (jit/warmup.py's scenes)
EXAMPLE = dict()
FIELDS = (
    ('revolute_joints', '(R,) the revolute joints (UID 18; the others are prismatic, UID 20)'),
    ('joint_x_bar', '[m] (J,2,2,3) anchors x̄: [joint, side (i, j), anchor (P0, P1), xyz]'),
    ('joint_K', '[kg] (J,) UID 18 stiffness K = γ (m_i + m_j)'),
    ('joint_hessian', '(J,24,24) constant Hessian of the UID 18 energy (0 on a prismatic joint)'),
    ('joint_warn_separation', '[m] (J,) anchor separation above which a step warns (overloaded joint)'),
    ('joint_fault_separation', '[m] (J,) anchor separation above which a joint has come apart (a fault)'),
)


def used(model) -> bool:
    return len(model.revolute_joints) > 0


def from_scene(scene, model) -> dict:
    """The Model's fields of this term: revolute_joints (R,), the revolute joints."""
    return dict(revolute_joints=select.joints(scene, model, False))


def stiffness(strength_ratio, mass_i, mass_j):
    """K = γ (m_i + m_j) [kg] of a joint between bodies of masses m_i, m_j (UID 18, UID 19)."""
    return strength_ratio * (mass_i + mass_j)


def constant_hessian(K, anchor0, anchor1) -> np.ndarray:
    """(J,24,24) K Σ_a D_aᵀD_a per joint, D_a = [J(x̄_i^a), −J(x̄_j^a)] (anchors (J,2,3))."""
    H = np.zeros((len(K), 24, 24))
    for k in range(len(K)):
        D = [np.hstack([point_jacobian(anchors[0]), -point_jacobian(anchors[1])])   # (3,24)
             for anchors in (anchor0[k], anchor1[k])]
        H[k] = K[k] * sum(Dk.T @ Dk for Dk in D)
    return H


def build(model, data) -> dict:
    m = model
    J = m.joint_count
    size, parent, child = m.body_size, m.joint_parent, m.joint_child
    return dict(
        revolute_joints=flat.array(m.revolute_joints, np.int64),
        joint_x_bar=flat.array(np.stack([m.joint_anchor0, m.joint_anchor1], axis=2).reshape(J, 2, 2, 3),
                               np.float64),
        joint_K=flat.array(m.joint_K, np.float64),
        joint_hessian=flat.array(constant_hessian(np.where(m.joint_slides, 0.0, m.joint_K), m.joint_anchor0,
                                                  m.joint_anchor1), np.float64),
        joint_warn_separation=flat.array(SEPARATION_WARN * np.minimum(size[parent], size[child]), np.float64),
        joint_fault_separation=flat.array(SEPARATION_FAULT * np.maximum(size[parent], size[child]), np.float64))


@kernel
def separation(q, i_body, j_body, x_bar, j, a):
    """x_i − x_j of anchor a (0: P0, 1: P1) of joint j as a tuple (no work array: an array
    costs an allocation and reference counts). [m]"""
    return (_gap(q, i_body, j_body, x_bar, j, a, 0), _gap(q, i_body, j_body, x_bar, j, a, 1),
            _gap(q, i_body, j_body, x_bar, j, a, 2))


@kernel(inline='always')
def _gap(q, i_body, j_body, x_bar, j, a, r):
    """Row r of separation."""
    xi = q[i_body, r]
    xj = q[j_body, r]
    for c in range(3):
        xi += q[i_body, 3 + 3 * r + c] * x_bar[j, 0, a, c]
        xj += q[j_body, 3 + 3 * r + c] * x_bar[j, 1, a, c]
    return xi - xj


@kernel
def joint_separation(q, m, j):
    """max_a |x_i^a − x_j^a| of joint j (NaN wins). [m]"""
    return _separation_norm(q, m.joint_parent[j], m.joint_child[j], m.joint_x_bar, j)


@kernel(inline='always')
def _separation_norm(q, i_body, j_body, x_bar, j):
    """max_a |x_i^a − x_j^a| of joint j (NaN wins). [m]"""
    out = 0.0
    for a in range(2):
        d0, d1, d2 = separation(q, i_body, j_body, x_bar, j, a)
        n = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if n > out or n != n:
            out = n
    return out


@kernel
def max_separation(q, m):
    """The largest separation over the revolute joints (0 without; NaN wins). [m]"""
    parent, child, x_bar = m.joint_parent, m.joint_child, m.joint_x_bar
    out = 0.0
    for j in m.revolute_joints:
        n = _separation_norm(q, parent[j], child[j], x_bar, j)
        if n > out or n != n:
            out = n
    return out


@kernel
def check_separations(q, m):
    """(largest separation [m], whether one exceeds its warning, the first joint beyond its
    fault separation or -1) over the revolute joints."""
    parent, child, x_bar = m.joint_parent, m.joint_child, m.joint_x_bar
    warn, fault = m.joint_warn_separation, m.joint_fault_separation
    largest = 0.0
    overloaded = False
    apart = -1
    for j in m.revolute_joints:
        n = _separation_norm(q, parent[j], child[j], x_bar, j)
        if n > largest or n != n:
            largest = n
        if n > warn[j]:
            overloaded = True
        if not n <= fault[j] and apart < 0:
            apart = j
    return largest, overloaded, apart


@kernel
def energy(q, m, ctx):
    parent, child, x_bar, K = m.joint_parent, m.joint_child, m.joint_x_bar, m.joint_K
    joints = m.revolute_joints
    if joints.size == 0:
        return 0.0
    E = 0.0
    for j in joints:
        acc = 0.0
        for a in range(2):
            d0, d1, d2 = separation(q, parent[j], child[j], x_bar, j, a)
            acc += d0 * d0 + d1 * d1 + d2 * d2
        E += K[j] * acc
    return 0.5 * E


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    E = accumulate_gradient(q, m, ctx, grad)
    add_constant_hessian(m.joint_parent, m.joint_child, m.joint_hessian, diag, pair)
    return E


@kernel
def add_constant_hessian(parent, child, H, diag, pair):
    """The joints' constant Hessians H (J,24,24) added into diag and pair (0 if prismatic)."""
    for j in range(parent.size):
        i_body, j_body = parent[j], child[j]
        for r in range(12):
            for c in range(12):
                diag[i_body, r, c] += H[j, r, c]
                diag[j_body, r, c] += H[j, 12 + r, 12 + c]
                pair[j, r, c] += H[j, r, 12 + c]


@kernel
def accumulate_gradient(q, m, ctx, grad):
    """∇E only (the Hessian is in model_data.constant_blocks); returns E (`energy`'s bits)."""
    parent, child, x_bar, K = m.joint_parent, m.joint_child, m.joint_x_bar, m.joint_K
    joints = m.revolute_joints
    if joints.size == 0:
        return 0.0
    E = 0.0
    for j in joints:
        i_body, j_body = parent[j], child[j]
        d0, d1, d2 = separation(q, i_body, j_body, x_bar, j, 0)
        acc = d0 * d0 + d1 * d1 + d2 * d2
        Kd0 = (K[j] * d0, K[j] * d1, K[j] * d2)             # K d at anchor P0
        d0, d1, d2 = separation(q, i_body, j_body, x_bar, j, 1)
        acc += d0 * d0 + d1 * d1 + d2 * d2
        Kd1 = (K[j] * d0, K[j] * d1, K[j] * d2)             # and at P1
        E += K[j] * acc
        for side in range(2):
            b = i_body if side == 0 else j_body
            sign = 1.0 if side == 0 else -1.0
            for r in range(3):
                grad[b, r] += sign * (Kd0[r] + Kd1[r])
                for c in range(3):
                    grad[b, 3 + 3 * r + c] += sign * (Kd0[r] * x_bar[j, side, 0, c]
                                                      + Kd1[r] * x_bar[j, side, 1, c])
    return 0.5 * E
