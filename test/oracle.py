"""A small, independent test oracle: the energies, the joint angle and the UID 668 force
written densely in numpy straight from docs/physics.md, unoptimised and without the
compiled code's helpers. The compiled terms (abd_joint_sim/terms/, terms/angle.py) are checked
against it; it is not a second simulator (no Hessians, no Newton, no step)."""
from __future__ import annotations

import numpy as np


def affine(q, b):
    """(p (3,), A (3,3)) of body b: q = [p, rows of A]."""
    return q[b, :3], q[b, 3:12].reshape(3, 3)


def point(q, b, x_bar):
    p, A = affine(q, b)
    return A @ x_bar + p


def theta(model, q, j):
    """docs/physics.md "Joint angle": cos = (n_i·n_j + b_i·b_j)/2, sin = (b_i·n_j − n_i·b_j)/2."""
    _, Ai = affine(q, model.joint_parent[j])
    _, Aj = affine(q, model.joint_child[j])
    ni, nj = Ai @ model.joint_nbar[j, 0], Aj @ model.joint_nbar[j, 1]
    bi, bj = Ai @ model.joint_bbar[j, 0], Aj @ model.joint_bbar[j, 1]
    return np.arctan2(0.5 * (bi @ nj - ni @ bj), 0.5 * (ni @ nj + bi @ bj))


def unwrap(x, ref):
    return ref + np.remainder(x - ref + np.pi, 2 * np.pi) - np.pi


def inertia_energy(model, q, q_tilde, scale):
    E = 0.0
    for b in np.flatnonzero(~model.body_fixed):
        d = q[b] - q_tilde[b]
        E += 0.5 * scale * d @ model.body_M[b] @ d
    return E


def ortho_energy(model, q, h):
    """UID 1: h² Σ κ v̄ ‖A Aᵀ − I‖²_F over the free bodies."""
    E = 0.0
    for b in np.flatnonzero(~model.body_fixed):
        _, A = affine(q, b)
        E += model.body_kappa[b] * model.body_volume[b] * np.sum((A @ A.T - np.eye(3)) ** 2)
    return h * h * E


def revolute_energy(model, q):
    """UID 18: K/2 Σ_{P0, P1} |x_i − x_j|², K = γ (m_i + m_j)."""
    E = 0.0
    for j in range(model.joint_count):
        i_b, j_b = model.joint_parent[j], model.joint_child[j]
        for anchors in (model.joint_anchor0[j], model.joint_anchor1[j]):
            d = point(q, i_b, anchors[0]) - point(q, j_b, anchors[1])
            E += 0.5 * model.joint_K[j] * d @ d
    return E


def driving_energy(model, q, angle_start, target, on):
    """UID 19: K/2 (θ − θ_target)² per enabled drive."""
    E = 0.0
    for k, j in enumerate(model.drive_joints):
        if on[k]:
            x = unwrap(theta(model, q, j), angle_start[j])
            E += 0.5 * model.drive_K[k] * (x - target[k]) ** 2
    return E


def theta_gradient(model, q, j):
    """∇θ of joint j w.r.t. [vec A_parent, vec A_child] (18,): θ = atan2(s, c) with
    c = (n_i·n_j + b_i·b_j)/2, s = (b_i·n_j − n_i·b_j)/2, n = A n̄, so ∂(A n̄)·w/∂A = w n̄ᵀ and
    ∇θ = (c ∇s − s ∇c)/(c² + s²)."""
    _, Ai = affine(q, model.joint_parent[j])
    _, Aj = affine(q, model.joint_child[j])
    nbi, nbj = model.joint_nbar[j]
    bbi, bbj = model.joint_bbar[j]
    ni, nj, bi, bj = Ai @ nbi, Aj @ nbj, Ai @ bbi, Aj @ bbj
    c, s = 0.5 * (ni @ nj + bi @ bj), 0.5 * (bi @ nj - ni @ bj)
    dc = 0.5 * np.concatenate([(np.outer(nj, nbi) + np.outer(bj, bbi)).ravel(),
                               (np.outer(ni, nbj) + np.outer(bi, bbj)).ravel()])
    ds = 0.5 * np.concatenate([(np.outer(nj, bbi) - np.outer(bj, nbi)).ravel(),
                               (np.outer(bi, nbj) - np.outer(ni, bbj)).ravel()])
    return (c * ds - s * dc) / (c * c + s * s)


def damping_energy(model, q, q0, q_prev, angle_start, h, bdf2, linear=True):
    """Joint damping: the potential whose θ-derivative is h² d θ̇ (the torque −d θ̇ times h²,
    as s M (q − q̃) carries it), θ̇ the integrator's rate at the end of the step: BDF1
    (θ − θⁿ)/h, BDF2 (3θ − 4θⁿ + θⁿ⁻¹)/(2h), θⁿ⁻¹ the angle at q_prev. θ̇ is linear in θ with
    slope r = 1/h or 3/(2h), so E = h² d θ̇² / (2r). With `linear`, θ is θ(q0) + ∇θ(q0)·(q − q0)
    (the compiled term's linearisation at Newton's start), else θ(q) itself."""
    E = 0.0
    for k, j in enumerate(model.damping_joints):
        d = model.damping_coeff[k]
        now = angle_start[j]
        if linear:
            i, c = model.joint_parent[j], model.joint_child[j]
            dA = np.concatenate([q[i, 3:12] - q0[i, 3:12], q[c, 3:12] - q0[c, 3:12]])
            x = unwrap(theta(model, q0, j), now) + theta_gradient(model, q0, j) @ dA
        else:
            x = unwrap(theta(model, q, j), now)
        if bdf2:
            before = unwrap(theta(model, q_prev, j), now)
            rate, r = (3 * x - 4 * now + before) / (2 * h), 3 / (2 * h)
        else:
            rate, r = (x - now) / h, 1 / h
        E += h * h * d * rate ** 2 / (2 * r)
    return E


def limit_energy(model, q, angle_start):
    """UID 670: s((x − u)/w)³ above u, s((l − x)/w)³ below l, s|x − l|³ for w = 0."""
    E = 0.0
    for k, j in enumerate(model.limit_joints):
        x = unwrap(theta(model, q, j), angle_start[j])
        lo = model.limit_lower[k] - model.joint_init_angle[j]
        up = model.limit_upper[k] - model.joint_init_angle[j]
        s, w = model.limit_strength[k], up - lo
        if w == 0:
            E += s * abs(x - lo) ** 3
        elif x > up:
            E += s * ((x - up) / w) ** 3
        elif x < lo:
            E += s * ((lo - x) / w) ** 3
    return E


def torque_force(model, q, taus):
    """UID 668: F_k = [0; vec((τ/2)[ê_k]× A_k^{−T})], ê_j = ½(ẽ_i + ẽ_j), ê_i = −ê_j."""
    F = np.zeros((model.body_count, 12))
    for k, j in enumerate(model.torque_joints):
        i_b, j_b = model.joint_parent[j], model.joint_child[j]
        raw = []
        for side, b in ((0, i_b), (1, j_b)):
            _, A = affine(q, b)
            e = A @ (model.joint_anchor1[j, side] - model.joint_anchor0[j, side])
            raw.append(e / np.linalg.norm(e))
        e_j = 0.5 * (raw[0] + raw[1])
        for b, e in ((i_b, -e_j), (j_b, e_j)):
            _, A = affine(q, b)
            E = np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])
            F[b, 3:12] += (0.5 * taus[k] * E @ np.linalg.inv(A).T).ravel()
    return F


# -- the prismatic family (UID 20, 21, 667, 669), from docs/physics.md -------------------------
def prismatic_frame(model, q, j):
    """(c_i, c_j, t_i, t_j, n_i, n_j, b_i, b_j) of prismatic joint j: each body's copy of the
    joint point P0 (translation included) and of the axis t = (P1 − P0)/|P1 − P0| and the
    normals n, b (rotation only), from the joint's rest anchors and angle basis."""
    out = {}
    for side, b in ((0, model.joint_parent[j]), (1, model.joint_child[j])):
        _, A = affine(q, b)
        x0, x1 = model.joint_anchor0[j, side], model.joint_anchor1[j, side]
        out['c', side] = point(q, b, x0)
        out['t', side] = A @ ((x1 - x0) / np.linalg.norm(x1 - x0))
        out['n', side] = A @ model.joint_nbar[j, side]
        out['b', side] = A @ model.joint_bbar[j, side]
    return out


def prismatic_distance(model, q, j):
    """d = ½ (c_j − c_i)·(t_i + t_j), relative to the joint's creation. [m]"""
    f = prismatic_frame(model, q, j)
    return 0.5 * (f['c', 1] - f['c', 0]) @ (f['t', 0] + f['t', 1])


def prismatic_energy(model, q):
    """UID 20: K/2 (|(c_j − c_i) × t_i|² + |(c_i − c_j) × t_j|² + |n_i − n_j|² + |b_i − b_j|²)."""
    E = 0.0
    for j in model.prismatic_joints:
        f = prismatic_frame(model, q, j)
        r = f['c', 1] - f['c', 0]
        C = [np.cross(r, f['t', 0]), np.cross(-r, f['t', 1]), f['n', 0] - f['n', 1], f['b', 0] - f['b', 1]]
        E += 0.5 * model.joint_K[j] * sum(c @ c for c in C)
    return E


def prismatic_driving_energy(model, q, targets, on):
    """UID 21: K/2 (t_i·(c_j − c_i) − d̃)² + K/2 (t_j·(c_j − c_i) − d̃)² per enabled drive."""
    E = 0.0
    for k, j in enumerate(model.prismatic_drive_joints):
        if on[k]:
            f = prismatic_frame(model, q, j)
            r = f['c', 1] - f['c', 0]
            E += 0.5 * model.prismatic_drive_K[k] * ((f['t', 0] @ r - targets[k]) ** 2
                                                     + (f['t', 1] @ r - targets[k]) ** 2)
    return E


def prismatic_limit_energy(model, q):
    """UID 669: UID 670's cubic on the distance, bounds relative to init_distance."""
    E = 0.0
    for k, j in enumerate(model.prismatic_limit_joints):
        x = prismatic_distance(model, q, j)
        lo = model.prismatic_limit_lower[k] - model.joint_init_angle[j]
        up = model.prismatic_limit_upper[k] - model.joint_init_angle[j]
        s, w = model.prismatic_limit_strength[k], up - lo
        if w == 0:
            E += s * abs(x - lo) ** 3
        elif x > up:
            E += s * ((x - up) / w) ** 3
        elif x < lo:
            E += s * ((lo - x) / w) ** 3
    return E


def prismatic_force(model, q, forces):
    """UID 667: F_k = J(c̄_k)ᵀ (f t̂_k), t̂_j = ½(t̃_i + t̃_j), t̂_i = −t̂_j, t̃_k the normalised
    axis of body k from its own anchors."""
    F = np.zeros((model.body_count, 12))
    for k, j in enumerate(model.prismatic_force_joints):
        raw = []
        for side, b in ((0, model.joint_parent[j]), (1, model.joint_child[j])):
            _, A = affine(q, b)
            e = A @ (model.joint_anchor1[j, side] - model.joint_anchor0[j, side])
            raw.append(e / np.linalg.norm(e))
        t_j = 0.5 * (raw[0] + raw[1])
        for side, b, t in ((0, model.joint_parent[j], -t_j), (1, model.joint_child[j], t_j)):
            w = forces[k] * t
            F[b, :3] += w
            F[b, 3:12] += np.outer(w, model.joint_anchor0[j, side]).ravel()
    return F


def prismatic_damping_energy(model, q, q_prev, start, h, bdf2):
    """Prismatic joint damping: the potential whose d-derivative is h² c ḋ, ḋ the integrator's
    rate at the end of the step (BDF1 (d − dⁿ)/h, BDF2 (3d − 4dⁿ + dⁿ⁻¹)/(2h), dⁿ⁻¹ at
    q_prev): ḋ is linear in d with slope r, so E = h² c ḋ² / (2r)."""
    E = 0.0
    for k, j in enumerate(model.prismatic_damping_joints):
        c, now, x = model.prismatic_damping_coeff[k], start[j], prismatic_distance(model, q, j)
        if bdf2:
            rate, r = (3 * x - 4 * now + prismatic_distance(model, q_prev, j)) / (2 * h), 3 / (2 * h)
        else:
            rate, r = (x - now) / h, 1 / h
        E += h * h * c * rate ** 2 / (2 * r)
    return E
