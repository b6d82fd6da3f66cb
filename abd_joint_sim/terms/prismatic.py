"""Prismatic joint, libuipc UID 20 (docs/physics.md "Prismatic joint (UID 20)"): the child
slides along the axis t̂ = (P1 − P0)/|P1 − P0| of its parent, without turning relative to it.

Each body k ∈ {i (parent), j (child)} stores the joint frame in its rest coordinates: the
point c̄_k (P0, translation included) and the directions t̄_k, n̄_k, b̄_k (rotation only).
In the current state c_k = A_k c̄_k + p_k, t_k = A_k t̄_k, n_k = A_k n̄_k, b_k = A_k b̄_k, and

    C0 = (c_j − c_i) × t_i,   C1 = (c_i − c_j) × t_j,   C2 = n_i − n_j,   C3 = b_i − b_j
    E = K/2 Σ_k |C_k|²,       K = γ (m_i + m_j)   (γ = strength_ratio, no h²: E/h² is physical)

C0, C1 leave only the slide along t; C2, C3 forbid relative rotation. With r = c_j − c_i and
the constant Jacobians Dr = ∂r/∂x, L_tk = ∂t_k/∂x (x = [q_i, q_j] (24,), all of c, t, n, b
are linear in x): ∇C0 = −[t_i]× Dr + [r]× L_ti, ∇C1 = [t_j]× Dr − [r]× L_tj, ∇C2 = L_ni − L_nj,
∇C3 = L_bi − L_bj; ∇E = K Σ ∇C_kᵀ C_k. C0, C1 are bilinear in x, so E is quartic and its
Hessian is not constant:

    ∇²E = K Σ ∇C_kᵀ ∇C_k + K (Drᵀ M0 L_ti + L_tiᵀ M0ᵀ Dr) + K (Drᵀ M1 L_tj + L_tjᵀ M1ᵀ Dr),
    M0 = −[C0]×,  M1 = [C1]×       (from w·(a × b) = −aᵀ [w]× b)

Newton takes its Gauss-Newton part K Σ ∇C_kᵀ∇C_k (`project`): PSD by construction, exact
where the joint holds (C = 0); the rest is O(|C|/ℓ) of it (ℓ the bodies' size), a few 1e-4
on a loaded joint. The raw Hessian (project False) is the whole one, for the tests.

The joint coordinate (the distance), shared by UID 667's readout, UID 21 and UID 669:

    d(q) = ½ (c_j − c_i)·(t_i + t_j),   ∇d = ½ ((t_i + t_j)ᵀ Dr + rᵀ (L_ti + L_tj))

the signed slide of the child along +t relative to the parent, 0 at creation; the reported
distance is d + init_distance. ḋ = ∇d·v. Its separation (reported as UID 18's) is
max(|C0|, |C1|) [m]: how far each body's axis point is off the other's axis.
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import flat, kernel

NAME = 'prismatic_joint'    #: in Solver.terms
STORED = True               #: E/h² is stored energy (World.mechanical_energy)
CONSTANT_HESSIAN = False
# the same warning and fault rule as UID 18's (revolute.SEPARATION_WARN, SEPARATION_FAULT)
SEPARATION_WARN = 0.01
SEPARATION_FAULT = 1e3
#: the fields of the compiled model (solver/model_data.py) this term owns: (name, meaning)
FIELDS = (
    ('prismatic_joints', '(S,) the prismatic joints (UID 20)'),
    ('prismatic_slot', '(J,) k of joint j in prismatic_joints, -1 for a revolute joint'),
    ('prismatic_frame', '[m] (S,2,4,3) per joint and side (parent, child): c̄, t̄, n̄, b̄ in the '
                        'body\'s rest frame'),
    ('prismatic_K', '[kg] (S,) UID 20 stiffness K = γ (m_i + m_j)'),
    ('prismatic_warn_separation', '[m] (S,) separation above which a step warns (overloaded joint)'),
    ('prismatic_fault_separation', '[m] (S,) separation above which the joint has come apart'),
)
#: rows of the work array `frames` fills: c_i, c_j, t_i, t_j, n_i, n_j, b_i, b_j
WORK_ROWS = 8


def used(model) -> bool:
    return len(model.prismatic_joints) > 0


def rest_frames(model) -> np.ndarray:
    """(S,2,4,3) c̄, t̄, n̄, b̄ per prismatic joint and side, from the Model's anchors (the
    initial poses are rigid: A⁻¹ = Aᵀ keeps t̄ a unit vector)."""
    S = model.prismatic_joints
    out = np.zeros((len(S), 2, 4, 3))
    for k, j in enumerate(S):
        for side in range(2):
            x0, x1 = model.joint_anchor0[j, side], model.joint_anchor1[j, side]
            out[k, side, 0] = x0
            out[k, side, 1] = (x1 - x0) / np.linalg.norm(x1 - x0)
            out[k, side, 2] = model.joint_nbar[j, side]
            out[k, side, 3] = model.joint_bbar[j, side]
    return out


def build(model, data) -> dict:
    """FIELDS' values for a Model (data: the compiled model's fields built so far)."""
    m = model
    S = m.prismatic_joints
    slot = np.full(m.joint_count, -1, np.int64)
    slot[S] = np.arange(len(S))
    size, parent, child = m.body_size, m.joint_parent[S], m.joint_child[S]
    return dict(
        prismatic_joints=flat.array(S, np.int64),
        prismatic_slot=flat.array(slot, np.int64),
        prismatic_frame=flat.array(rest_frames(m), np.float64),
        prismatic_K=flat.array(m.prismatic_K, np.float64),
        prismatic_warn_separation=flat.array(SEPARATION_WARN * np.minimum(size[parent], size[child]),
                                             np.float64),
        prismatic_fault_separation=flat.array(SEPARATION_FAULT * np.maximum(size[parent], size[child]),
                                              np.float64))


# -- geometry of one joint ----------------------------------------------------------------------
@kernel
def frames(q, i_body, j_body, fr, k, W):
    """W (≥ 8, 3) rows c_i, c_j, t_i, t_j, n_i, n_j, b_i, b_j of prismatic joint k (fr =
    m.prismatic_frame) in world axes."""
    for side in range(2):
        b = i_body if side == 0 else j_body
        for r in range(3):
            c = q[b, r]
            t = n = bb = 0.0
            for col in range(3):
                a = q[b, 3 + 3 * r + col]
                c += a * fr[k, side, 0, col]
                t += a * fr[k, side, 1, col]
                n += a * fr[k, side, 2, col]
                bb += a * fr[k, side, 3, col]
            W[side, r] = c
            W[2 + side, r] = t
            W[4 + side, r] = n
            W[6 + side, r] = bb


@kernel
def distance_at(q, i_body, j_body, fr, k, W):
    """d(q) of prismatic joint k, relative to its creation. [m]"""
    frames(q, i_body, j_body, fr, k, W)
    d = 0.0
    for r in range(3):
        d += (W[1, r] - W[0, r]) * (W[2, r] + W[3, r])
    return 0.5 * d


@kernel
def distance(q, m, j):
    """d(q) of joint j (a prismatic joint), relative to its creation. [m]"""
    k = m.prismatic_slot[j]
    return distance_at(q, m.joint_parent[j], m.joint_child[j], m.prismatic_frame, k, np.empty((WORK_ROWS, 3)))


@kernel
def distance_and_rate(q, v, i_body, j_body, fr, k, W):
    """(d, ḋ = ∇d·v) of prismatic joint k at q, velocities v (B,12); W (16,3) work. [m, m/s]"""
    frames(q, i_body, j_body, fr, k, W)
    frames(v, i_body, j_body, fr, k, W[8:])     # the rates: ċ_k = J(c̄_k) v_k, ṫ_k = Ȧ_k t̄_k
    d = rate = 0.0
    for r in range(3):
        rr = W[1, r] - W[0, r]
        tt = W[2, r] + W[3, r]
        d += rr * tt
        rate += (W[9, r] - W[8, r]) * tt + rr * (W[10, r] + W[11, r])
    return 0.5 * d, 0.5 * rate


@kernel
def linear_maps(fr, k, L):
    """L (8,3,24): the constant Jacobians of c_i, c_j, t_i, t_j, n_i, n_j, b_i, b_j w.r.t.
    x = [q_i, q_j]: a point x̄ gives [I3 | I3 ⊗ x̄ᵀ], a direction [0 | I3 ⊗ x̄ᵀ], on its
    body's 12 columns."""
    for a in range(8):
        for r in range(3):
            for c in range(24):
                L[a, r, c] = 0.0
    for side in range(2):
        o = 12 * side
        for r in range(3):
            L[side, r, o + r] = 1.0
            for col in range(3):
                L[side, r, o + 3 + 3 * r + col] = fr[k, side, 0, col]
                L[2 + side, r, o + 3 + 3 * r + col] = fr[k, side, 1, col]
                L[4 + side, r, o + 3 + 3 * r + col] = fr[k, side, 2, col]
                L[6 + side, r, o + 3 + 3 * r + col] = fr[k, side, 3, col]


@kernel
def slide_gradient(W, L, side, g):
    """g (24,) = ∇u_k of u_k = t_k·r (k = side: 0 parent, 1 child): t_kᵀ Dr + rᵀ L_tk, from
    frames W and linear_maps L."""
    for c in range(24):
        x = 0.0
        for r in range(3):
            x += W[2 + side, r] * (L[1, r, c] - L[0, r, c]) + (W[1, r] - W[0, r]) * L[2 + side, r, c]
        g[c] = x


@kernel
def add_slide_curvature(L, side, w, H):
    """H (24,24) += w ∇²u_k = w (Drᵀ L_tk + L_tkᵀ Dr) (u_k = t_k·r is bilinear)."""
    for a in range(24):
        for b in range(24):
            x = 0.0
            for r in range(3):
                x += (L[1, r, a] - L[0, r, a]) * L[2 + side, r, b] + L[2 + side, r, a] * (L[1, r, b] - L[0, r, b])
            H[a, b] += w * x


@kernel
def distance_gradient(W, L, g, work):
    """g (24,) = ∇d = ½ (∇u_i + ∇u_j) (work: (24,))."""
    slide_gradient(W, L, 0, g)
    slide_gradient(W, L, 1, work)
    for c in range(24):
        g[c] = 0.5 * (g[c] + work[c])


@kernel
def add_distance_curvature(L, w, H):
    """H (24,24) += w ∇²d = (w/2) (∇²u_i + ∇²u_j)."""
    add_slide_curvature(L, 0, 0.5 * w, H)
    add_slide_curvature(L, 1, 0.5 * w, H)


@kernel
def add_blocks(H, g, i_body, j_body, j, grad, diag, pair):
    """A joint's ∇ g (24,) and ∇² H (24,24) over [q_i, q_j] into grad and the blocks."""
    for a in range(12):
        grad[i_body, a] += g[a]
        grad[j_body, a] += g[12 + a]
        for b in range(12):
            diag[i_body, a, b] += H[a, b]
            diag[j_body, a, b] += H[12 + a, 12 + b]
            pair[j, a, b] += H[a, 12 + b]


# -- the energy -----------------------------------------------------------------------------------
@kernel
def residual(W, C):
    """C (12,) = [C0, C1, C2, C3] from frames W; returns Σ C² (in that order)."""
    r0, r1, r2 = W[1, 0] - W[0, 0], W[1, 1] - W[0, 1], W[1, 2] - W[0, 2]
    for side in range(2):
        t0, t1, t2 = W[2 + side, 0], W[2 + side, 1], W[2 + side, 2]
        s = 1.0 if side == 0 else -1.0          # C1 = −r × t_j
        C[3 * side] = s * (r1 * t2 - r2 * t1)
        C[3 * side + 1] = s * (r2 * t0 - r0 * t2)
        C[3 * side + 2] = s * (r0 * t1 - r1 * t0)
    for r in range(3):
        C[6 + r] = W[4, r] - W[5, r]
        C[9 + r] = W[6, r] - W[7, r]
    acc = 0.0
    for a in range(12):
        acc += C[a] * C[a]
    return acc


@kernel
def separation_at(q, i_body, j_body, fr, k, W, C):
    """max(|C0|, |C1|) of prismatic joint k: each body's axis point off the other's axis. [m]"""
    frames(q, i_body, j_body, fr, k, W)
    residual(W, C)
    a = math.sqrt(C[0] * C[0] + C[1] * C[1] + C[2] * C[2])
    b = math.sqrt(C[3] * C[3] + C[4] * C[4] + C[5] * C[5])
    return a if (a > b or a != a) else b


@kernel
def joint_separation(q, m, j):
    """The separation of joint j (a prismatic joint). [m]"""
    return separation_at(q, m.joint_parent[j], m.joint_child[j], m.prismatic_frame, m.prismatic_slot[j],
                         np.empty((WORK_ROWS, 3)), np.empty(12))


@kernel
def check_separations(q, m):
    """(largest separation, whether one exceeds its warning, the first joint beyond its fault
    separation or -1) over the prismatic joints, as revolute.check_separations. [m]"""
    joints, parent, child, fr = m.prismatic_joints, m.joint_parent, m.joint_child, m.prismatic_frame
    warn, fault = m.prismatic_warn_separation, m.prismatic_fault_separation
    W = np.empty((WORK_ROWS, 3))
    C = np.empty(12)
    largest = 0.0
    overloaded = False
    apart = -1
    for k in range(joints.size):
        j = joints[k]
        n = separation_at(q, parent[j], child[j], fr, k, W, C)
        if n > largest or n != n:
            largest = n
        if n > warn[k]:
            overloaded = True
        if not n <= fault[k] and apart < 0:
            apart = j
    return largest, overloaded, apart


@kernel
def energy(q, m, ctx):
    joints, parent, child, fr, K = m.prismatic_joints, m.joint_parent, m.joint_child, m.prismatic_frame, m.prismatic_K
    if joints.size == 0:
        return 0.0
    W = np.empty((WORK_ROWS, 3))
    C = np.empty(12)
    E = 0.0
    for k in range(joints.size):
        j = joints[k]
        frames(q, parent[j], child[j], fr, k, W)
        E += K[k] * residual(W, C)
    return 0.5 * E


@kernel
def constraint_jacobian(W, L, C, G):
    """G (12,24) = [∇C0; ∇C1; ∇C2; ∇C3] (C from `residual`, for r = c_j − c_i)."""
    r0, r1, r2 = W[1, 0] - W[0, 0], W[1, 1] - W[0, 1], W[1, 2] - W[0, 2]
    for c in range(24):
        d0 = L[1, 0, c] - L[0, 0, c]            # column c of Dr
        d1 = L[1, 1, c] - L[0, 1, c]
        d2 = L[1, 2, c] - L[0, 2, c]
        for side in range(2):
            t0, t1, t2 = W[2 + side, 0], W[2 + side, 1], W[2 + side, 2]
            e0, e1, e2 = L[2 + side, 0, c], L[2 + side, 1, c], L[2 + side, 2, c]   # column c of L_t
            s = 1.0 if side == 0 else -1.0
            # ∂(r × t) = dr × t + r × dt
            G[3 * side, c] = s * ((d1 * t2 - d2 * t1) + (r1 * e2 - r2 * e1))
            G[3 * side + 1, c] = s * ((d2 * t0 - d0 * t2) + (r2 * e0 - r0 * e2))
            G[3 * side + 2, c] = s * ((d0 * t1 - d1 * t0) + (r0 * e1 - r1 * e0))
        for r in range(3):
            G[6 + r, c] = L[4, r, c] - L[5, r, c]
            G[9 + r, c] = L[6, r, c] - L[7, r, c]


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E and ∇²E (Gauss-Newton with `project`, else the whole Hessian); returns E (the bits
    of `energy`)."""
    joints, parent, child, fr, K = m.prismatic_joints, m.joint_parent, m.joint_child, m.prismatic_frame, m.prismatic_K
    if joints.size == 0:
        return 0.0
    W = np.empty((WORK_ROWS, 3))
    C = np.empty(12)
    L = np.empty((8, 3, 24))
    G = np.empty((12, 24))
    H = np.empty((24, 24))
    g = np.empty(24)
    E = 0.0
    for k in range(joints.size):
        j = joints[k]
        i_body, j_body = parent[j], child[j]
        frames(q, i_body, j_body, fr, k, W)
        E += K[k] * residual(W, C)
        linear_maps(fr, k, L)
        constraint_jacobian(W, L, C, G)
        Kk = K[k]
        for a in range(24):
            x = 0.0
            for r in range(12):
                x += G[r, a] * C[r]
            g[a] = Kk * x
            for b in range(a, 24):
                y = 0.0
                for r in range(12):
                    y += G[r, a] * G[r, b]
                H[a, b] = Kk * y
                H[b, a] = Kk * y
        if not project:
            # + K ∇²(w·C) at fixed w = C: w·(dr × dt) = (w × dr)·dt, for C0 = r × t_i and,
            # with the sign, C1 = −r × t_j; each (a, b) pair added to both H[a, b] and H[b, a]
            for side in range(2):
                s = 1.0 if side == 0 else -1.0
                w0, w1, w2 = C[3 * side], C[3 * side + 1], C[3 * side + 2]
                for a in range(24):
                    d0 = L[1, 0, a] - L[0, 0, a]
                    d1 = L[1, 1, a] - L[0, 1, a]
                    d2 = L[1, 2, a] - L[0, 2, a]
                    m0 = s * Kk * (w1 * d2 - w2 * d1)       # s K (w × dr_a)
                    m1 = s * Kk * (w2 * d0 - w0 * d2)
                    m2 = s * Kk * (w0 * d1 - w1 * d0)
                    for b in range(24):
                        x = m0 * L[2 + side, 0, b] + m1 * L[2 + side, 1, b] + m2 * L[2 + side, 2, b]
                        H[a, b] += x
                        H[b, a] += x
        add_blocks(H, g, i_body, j_body, j, grad, diag, pair)
    return 0.5 * E
