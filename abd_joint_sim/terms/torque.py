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
def any_active(m, torque_value, torque_enabled):
    """Whether some joint's torque is enabled and nonzero (else F = 0)."""
    for k in range(m.torque_joints.size):
        if torque_enabled[k] and torque_value[k] != 0.0:
            return True
    return False


@njit(cache=True, error_model='numpy')
def _work(m):
    """One allocation for a call: (ê per torque joint (T,3), es (2,3), A (3,3), A⁻¹ (3,3), F (9,))."""
    T = m.torque_joints.size
    buf = np.empty(3 * T + 33)
    return (buf[0:3 * T].reshape((T, 3)), buf[3 * T:3 * T + 6].reshape((2, 3)),
            buf[3 * T + 6:3 * T + 15].reshape((3, 3)), buf[3 * T + 15:3 * T + 24].reshape((3, 3)),
            buf[3 * T + 24:3 * T + 33])


@njit(cache=True, error_model='numpy')
def _inverse_if_regular(q, b, A, inv):
    """inv = A_b⁻¹; False (no torque on the body) if |det A| ≤ SINGULAR_RATIO |a1||a2||a3|."""
    for r in range(3):
        for c in range(3):
            A[r, c] = q[b, 3 + 3 * r + c]
    det = abs(det_inv3(A, inv))
    scale = 1.0
    for r in range(3):
        scale *= math.sqrt(A[r, 0] * A[r, 0] + A[r, 1] * A[r, 1] + A[r, 2] * A[r, 2])
    return det > SINGULAR_RATIO * scale


@njit(cache=True, error_model='numpy')
def _body_force(q, m, t, e, torque_value, torque_enabled, A, inv, f):
    """f (9,) = F_b[3:12] of torque body t (b = m.torque_bodies[t]): Σ over its joints k of
    (τ_k/2) [±ê_k]× A_b^{−T}, summed in the order of m.torque_body_entries (A_b⁻¹ computed
    once per body). Returns -1 if no torque acts on it, 0 if the singular guard skips it, 1."""
    b = m.torque_bodies[t]
    entries = m.torque_body_entries
    active = False
    for i in range(m.torque_body_ptr[t], m.torque_body_ptr[t + 1]):
        k = entries[i] // 2
        if torque_enabled[k] and torque_value[k] != 0.0:
            active = True
    if not active:
        return -1
    if not _inverse_if_regular(q, b, A, inv):
        return 0
    for r in range(9):
        f[r] = 0.0
    for i in range(m.torque_body_ptr[t], m.torque_body_ptr[t + 1]):
        k, side = entries[i] // 2, entries[i] % 2
        tau = torque_value[k] if torque_enabled[k] else 0.0
        if tau == 0.0:
            continue
        sign = -1.0 if side == 0 else 1.0            # ê_i = −ê_j
        ex, ey, ez = sign * e[k, 0], sign * e[k, 1], sign * e[k, 2]
        # (τ/2) [ê]× A^{−T}: column c of A^{−T} is row c of A^{−1}
        for c in range(3):
            w0, w1, w2 = inv[c, 0], inv[c, 1], inv[c, 2]
            f[c] += 0.5 * tau * (ey * w2 - ez * w1)
            f[3 + c] += 0.5 * tau * (ez * w0 - ex * w2)
            f[6 + c] += 0.5 * tau * (ex * w1 - ey * w0)
    return 1


@njit(cache=True, error_model='numpy')
def _axes(q, m, torque_value, torque_enabled, e, es):
    torque_joints, parent, child, x_bar = m.torque_joints, m.joint_parent, m.joint_child, m.joint_x_bar
    for k in range(torque_joints.size):
        if torque_enabled[k] and torque_value[k] != 0.0:
            axis_at(q, parent, child, x_bar, torque_joints[k], e[k], es)


@njit(cache=True, error_model='numpy')
def _list_skipped(q, m, torque_value, torque_enabled, skipped, A, inv):
    """The bodies the singular guard skips, once per (side, joint) in that order (parent side
    of every joint first); returns their count. Runs only when some body was skipped."""
    torque_joints, parent, child = m.torque_joints, m.joint_parent, m.joint_child
    n_skipped = 0
    for side in range(2):
        for k in range(torque_joints.size):
            tau = torque_value[k] if torque_enabled[k] else 0.0
            if tau == 0.0:
                continue
            j = torque_joints[k]
            b = parent[j] if side == 0 else child[j]
            if not _inverse_if_regular(q, b, A, inv):
                skipped[n_skipped] = b
                n_skipped += 1
    return n_skipped


@njit(cache=True, error_model='numpy')
def generalized_force(q, m, torque_value, torque_enabled, F, skipped):
    """Adds F_k of every enabled joint to F (B,12). Bodies skipped by the singular guard are
    written to `skipped` (parent side of every joint first, then child side); returns their
    count."""
    if not any_active(m, torque_value, torque_enabled):
        return 0
    e, es, A, inv, f = _work(m)
    _axes(q, m, torque_value, torque_enabled, e, es)
    any_skipped = False
    for t in range(m.torque_bodies.size):
        status = _body_force(q, m, t, e, torque_value, torque_enabled, A, inv, f)
        if status == 0:
            any_skipped = True
        elif status == 1:
            b = m.torque_bodies[t]
            for r in range(9):
                F[b, 3 + r] += f[r]
    if not any_skipped:
        return 0
    return _list_skipped(q, m, torque_value, torque_enabled, skipped, A, inv)


@njit(cache=True, error_model='numpy')
def add_acceleration(q, m, torque_value, torque_enabled, acc, skipped):
    """acc += M⁻¹F of the UID 668 torques; returns the number of skipped bodies. F_b is nonzero
    only in its A rows, on the torque bodies, so with M⁻¹ = blocks per spatial row k
    (m.body_Minv_bar) (M⁻¹F)_r is a 3-term sum, in the order of the dense 12x12 product."""
    if not any_active(m, torque_value, torque_enabled):
        return 0
    e, es, A, inv, f = _work(m)
    _axes(q, m, torque_value, torque_enabled, e, es)
    Minv_bar = m.body_Minv_bar
    any_skipped = False
    for t in range(m.torque_bodies.size):
        status = _body_force(q, m, t, e, torque_value, torque_enabled, A, inv, f)
        if status == 0:
            any_skipped = True
        if status != 1:
            continue
        b = m.torque_bodies[t]
        for k in range(3):
            Mi = Minv_bar[b, k]
            f0, f1, f2 = f[3 * k], f[3 * k + 1], f[3 * k + 2]
            acc[b, k] += Mi[0, 1] * f0 + Mi[0, 2] * f1 + Mi[0, 3] * f2
            for i in range(3):
                acc[b, 3 + 3 * k + i] += Mi[1 + i, 1] * f0 + Mi[1 + i, 2] * f1 + Mi[1 + i, 3] * f2
    if not any_skipped:
        return 0
    return _list_skipped(q, m, torque_value, torque_enabled, skipped, A, inv)
