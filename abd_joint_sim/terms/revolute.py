"""Revolute joint, libuipc UID 18 (docs/physics.md "Revolute joint (UID 18)"): the two
anchors P0, P1 stored in each body's rest frame (x̄0_k, x̄1_k, same order on both bodies)
are pulled together by

    E = K/2 Σ_{a ∈ {P0, P1}} |x_i^a − x_j^a|²,   x_k^a = A_k x̄_k^a + p_k = J(x̄_k^a) q_k,
    K = γ (m_i + m_j)   (γ = strength_ratio)

computed from the separations (no cancellation, docs/decisions.md). ∇E = K Σ_a D_aᵀ d_a
with d_a = x_i^a − x_j^a, D_a = [J(x̄_i^a), −J(x̄_j^a)]; the Hessian K Σ_a D_aᵀD_a is
constant and PSD (model.joint_hessian). It carries no h²: its physical potential is E/h².
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model='numpy')
def separation(q, i_body, j_body, x_bar, j, a, d):
    """d = x_i − x_j of anchor a (0: P0, 1: P1) of joint j between bodies i_body, j_body
    (x_bar = m.joint_x_bar; arrays, not m: this runs per joint and anchor). [m]"""
    for r in range(3):
        xi = q[i_body, r]
        xj = q[j_body, r]
        for c in range(3):
            xi += q[i_body, 3 + 3 * r + c] * x_bar[j, 0, a, c]
            xj += q[j_body, 3 + 3 * r + c] * x_bar[j, 1, a, c]
        d[r] = xi - xj


@njit(cache=True, error_model='numpy')
def joint_separation(q, m, j):
    """max_a |x_i^a − x_j^a| of joint j (NaN wins). [m]"""
    return _separation_norm(q, m.joint_parent[j], m.joint_child[j], m.joint_x_bar, j)


@njit(cache=True, error_model='numpy', inline='always')
def _separation_norm(q, i_body, j_body, x_bar, j):
    """max_a |x_i^a − x_j^a| of joint j (NaN wins); `separation`'s sums without its work
    array (the post-step check runs this on every joint). [m]"""
    out = 0.0
    for a in range(2):
        n2 = 0.0
        for r in range(3):
            xi = q[i_body, r]
            xj = q[j_body, r]
            for c in range(3):
                xi += q[i_body, 3 + 3 * r + c] * x_bar[j, 0, a, c]
                xj += q[j_body, 3 + 3 * r + c] * x_bar[j, 1, a, c]
            d = xi - xj
            n2 += d * d
        n = math.sqrt(n2)
        if n > out or n != n:
            out = n
    return out


@njit(cache=True, error_model='numpy')
def max_separation(q, m):
    """The largest joint separation over all joints (0 without joints; NaN wins). [m]"""
    parent, child, x_bar = m.joint_parent, m.joint_child, m.joint_x_bar
    out = 0.0
    for j in range(parent.size):
        n = _separation_norm(q, parent[j], child[j], x_bar, j)
        if n > out or n != n:
            out = n
    return out


@njit(cache=True, error_model='numpy')
def check_separations(q, m):
    """(largest separation, whether a joint exceeds m.joint_warn_separation, the first joint
    beyond m.joint_fault_separation or -1). [m]"""
    parent, child, x_bar = m.joint_parent, m.joint_child, m.joint_x_bar
    warn, fault = m.joint_warn_separation, m.joint_fault_separation
    largest = 0.0
    overloaded = False
    apart = -1
    for j in range(parent.size):
        n = _separation_norm(q, parent[j], child[j], x_bar, j)
        if n > largest or n != n:
            largest = n
        if n > warn[j]:
            overloaded = True
        if not n <= fault[j] and apart < 0:
            apart = j
    return largest, overloaded, apart


@njit(cache=True, error_model='numpy')
def energy(q, m, ctx):
    parent, child, x_bar, K = m.joint_parent, m.joint_child, m.joint_x_bar, m.joint_K
    if parent.size == 0:
        return 0.0
    d = np.empty(3)
    E = 0.0
    for j in range(parent.size):
        acc = 0.0
        for a in range(2):
            separation(q, parent[j], child[j], x_bar, j, a, d)
            acc += d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        E += K[j] * acc
    return 0.5 * E


@njit(cache=True, error_model='numpy')
def accumulate(q, m, ctx, grad, diag, pair, project):
    accumulate_gradient(q, m, ctx, grad)
    parent, child, H = m.joint_parent, m.joint_child, m.joint_hessian
    for j in range(parent.size):
        i_body, j_body = parent[j], child[j]
        for r in range(12):
            for c in range(12):
                diag[i_body, r, c] += H[j, r, c]
                diag[j_body, r, c] += H[j, 12 + r, 12 + c]
                pair[j, r, c] += H[j, r, 12 + c]


@njit(cache=True, error_model='numpy')
def accumulate_gradient(q, m, ctx, grad):
    """∇E only: Newton's assembly starts from the constant Hessian blocks
    (model_data.constant_hessian), so the step adds just this."""
    parent, child, x_bar, K = m.joint_parent, m.joint_child, m.joint_x_bar, m.joint_K
    if parent.size == 0:
        return
    buf = np.empty(9)
    Kd = buf[0:6].reshape((2, 3))
    d = buf[6:9]
    for j in range(parent.size):
        i_body, j_body = parent[j], child[j]
        for a in range(2):
            separation(q, i_body, j_body, x_bar, j, a, d)
            for r in range(3):
                Kd[a, r] = K[j] * d[r]
        for side in range(2):
            b = i_body if side == 0 else j_body
            sign = 1.0 if side == 0 else -1.0
            for r in range(3):
                grad[b, r] += sign * (Kd[0, r] + Kd[1, r])
                for c in range(3):
                    grad[b, 3 + 3 * r + c] += sign * (Kd[0, r] * x_bar[j, side, 0, c]
                                                      + Kd[1, r] * x_bar[j, side, 1, c])
