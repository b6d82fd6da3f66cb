"""External joint torque, libuipc UID 668 (docs/physics.md "External joint torque (UID 668)"):
a generalized force without energy, entering the prediction q̃ only. For each enabled joint
with torque τ:

    ẽ_k = normalize(A_k (x̄1_k − x̄0_k))        each body from its OWN anchors and A
    ê_j = ½(ẽ_i + ẽ_j),   ê_i = −ê_j            same-order anchors: exact third law
    F_k = [0₃ ; vec((τ/2) [ê_k]× A_k^{−T})]      vec = row-major into q[3:12]

Virtual work: for δA = [δω]× A, F^A : δA = τ ê·δω. Positive τ turns the child about +t, so
it increases the joint angle. Guards: a raw axis of norm ≤ AXIS_EPS |x̄1 − x̄0| (or not
finite) is unusable and the other body's axis is used for both (neither: no torque); a
near-singular A_k (|det A| / (|a1||a2||a3|) < SINGULAR_RATIO) gets no torque, and the step
reports the body.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..smallmat import det_inv3

SINGULAR_RATIO = 1e-6
AXIS_EPS = 1e-12


@njit(cache=True, error_model='numpy')
def axis(q, m, j, e):
    """e = ê_j (3,) of joint j, the child's torque axis (0 when neither raw axis is usable)."""
    axis_at(q, m.joint_parent, m.joint_child, m.joint_x_bar, j, e, np.empty((2, 3)))


@njit(cache=True, error_model='numpy')
def axis_at(q, parent, child, x_bar, j, e, es):
    """axis() on the model's arrays, es (2,3) a work array (it runs once per joint)."""
    usable = 0
    for side in range(2):
        b = parent[j] if side == 0 else child[j]
        v0 = v1 = v2 = 0.0
        d2 = 0.0
        for c in range(3):
            dc = x_bar[j, side, 1, c] - x_bar[j, side, 0, c]
            d2 += dc * dc
            v0 += q[b, 3 + c] * dc
            v1 += q[b, 6 + c] * dc
            v2 += q[b, 9 + c] * dc
        nrm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        if math.isfinite(nrm) and nrm > AXIS_EPS * math.sqrt(d2):
            es[side, 0], es[side, 1], es[side, 2] = v0 / nrm, v1 / nrm, v2 / nrm
            usable += 1
        else:
            es[side, 0] = es[side, 1] = es[side, 2] = 0.0
    half = 0.5 if usable == 2 else 1.0          # one of them is 0 if not both
    for r in range(3):
        e[r] = half * (es[0, r] + es[1, r])


@njit(cache=True, error_model='numpy')
def generalized_force(q, m, torque_value, torque_enabled, F, skipped):
    """Adds F_k of every enabled joint to F (B,12). Bodies skipped by the singular guard are
    written to `skipped` (parent side of every joint first, then child side); returns their
    count."""
    torque_joints, parent, child = m.torque_joints, m.joint_parent, m.joint_child
    T = torque_joints.size
    n_skipped = 0
    e = np.empty((T, 3))
    es = np.empty((2, 3))
    for k in range(T):
        if torque_enabled[k] and torque_value[k] != 0.0:
            axis_at(q, parent, child, m.joint_x_bar, torque_joints[k], e[k], es)
    A = np.empty((3, 3))
    inv = np.empty((3, 3))
    for side in range(2):
        sign = -1.0 if side == 0 else 1.0            # ê_i = −ê_j
        for k in range(T):
            tau = torque_value[k] if torque_enabled[k] else 0.0
            if tau == 0.0:
                continue
            j = torque_joints[k]
            b = parent[j] if side == 0 else child[j]
            for r in range(3):
                for c in range(3):
                    A[r, c] = q[b, 3 + 3 * r + c]
            det = abs(det_inv3(A, inv))
            scale = 1.0
            for r in range(3):
                scale *= math.sqrt(A[r, 0] * A[r, 0] + A[r, 1] * A[r, 1] + A[r, 2] * A[r, 2])
            if not det > SINGULAR_RATIO * scale:
                skipped[n_skipped] = b
                n_skipped += 1
                continue
            ex, ey, ez = sign * e[k, 0], sign * e[k, 1], sign * e[k, 2]
            # (τ/2) [ê]× A^{−T}: column c of A^{−T} is row c of A^{−1}
            for c in range(3):
                w0, w1, w2 = inv[c, 0], inv[c, 1], inv[c, 2]
                F[b, 3 + c] += 0.5 * tau * (ey * w2 - ez * w1)
                F[b, 6 + c] += 0.5 * tau * (ez * w0 - ex * w2)
                F[b, 9 + c] += 0.5 * tau * (ex * w1 - ey * w0)
    return n_skipped


@njit(cache=True, error_model='numpy')
def add_acceleration(q, m, torque_value, torque_enabled, acc, skipped):
    """acc += M⁻¹F of the UID 668 torques; returns the number of skipped bodies."""
    any_on = False
    for k in range(m.torque_joints.size):
        if torque_enabled[k] and torque_value[k] != 0.0:
            any_on = True
    if not any_on:
        return 0
    B = q.shape[0]
    F = np.zeros((B, 12))
    n_skipped = generalized_force(q, m, torque_value, torque_enabled, F, skipped)
    Minv = m.body_Minv
    for b in range(B):
        for r in range(12):
            s = 0.0
            for c in range(12):
                s += Minv[b, r, c] * F[b, c]
            acc[b, r] += s
    return n_skipped
