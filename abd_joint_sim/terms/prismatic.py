"""Prismatic joint, libuipc UID 20 (docs/physics.md "Prismatic joint (UID 20)"): the child
slides along the axis t̂ = (P1 − P0)/|P1 − P0| of its parent, without turning relative to it.

With the joint frame c̄_k, t̄_k, n̄_k, b̄_k stored on each body k ∈ {i (parent), j (child)} and
c_k = A_k c̄_k + p_k, t_k = A_k t̄_k, n_k = A_k n̄_k, b_k = A_k b̄_k:

    C0 = (c_j − c_i) × t_i,   C1 = (c_i − c_j) × t_j,   C2 = n_i − n_j,   C3 = b_i − b_j
    E = K/2 Σ_k |C_k|²,       K = γ (m_i + m_j)   (γ = strength_ratio, no h²: E/h² is physical)

E is quartic: Newton takes the Gauss-Newton part K Σ ∇C_kᵀ∇C_k (`project`: PSD, exact where
the joint holds); the raw Hessian (project False) is the whole one, for the tests.
The distance d(q) = ½ (c_j − c_i)·(t_i + t_j) (UID 667's readout, UID 21, UID 669) is the
child's signed slide along +t, 0 at creation; ḋ = ∇d·v. The separation is max(|C0|, |C1|) [m].
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import flat, kernel
from . import select

NAME = 'prismatic_joint'    #: in Solver.terms
STORED = True               #: E/h² is stored energy (World.mechanical_energy)
CONSTANT_HESSIAN = False
SEPARATION_WARN = 0.01      # the same rule as UID 18's (revolute.py)
SEPARATION_FAULT = 1e3
#: a scene joint's keys that put the term on it (jit/warmup.py's scenes)
EXAMPLE = dict(type='prismatic')
FIELDS = (
    ('prismatic_joints', '(S,) the prismatic joints (UID 20)'),
    ('prismatic_slot', '(J,) k of joint j in prismatic_joints, -1 for a revolute joint'),
    ('prismatic_frame', '[m] (S,2,4,3) per joint and side: c̄, t̄, n̄, b̄ in the rest frame'),
    ('prismatic_K', '[kg] (S,) UID 20 stiffness K = γ (m_i + m_j)'),
    ('prismatic_outer', '(S,12,4,4) `outer_products` of the rest vectors ȳ'),
    ('prismatic_warn_separation', '[m] (S,) separation above which a step warns (overloaded joint)'),
    ('prismatic_fault_separation', '[m] (S,) separation above which the joint has come apart'),
)


def used(model) -> bool:
    return len(model.prismatic_joints) > 0


def from_scene(scene, model) -> dict:
    """The Model's fields of this term: prismatic_joints (S,), the prismatic joints, and
    prismatic_K [kg] (S,), their UID 20 stiffness (the joint's K, model.joint_K)."""
    sj = select.joints(scene, model, True)
    return dict(prismatic_joints=sj, prismatic_K=np.array([model.joint_K[k] for k in sj], float))


def rest_frames(model) -> np.ndarray:
    """(S,2,4,3) c̄, t̄, n̄, b̄ per prismatic joint and side, from the Model's anchors."""
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


#: the rows of `outer_products`: c̃ t̃ ñ b̃ are the homogeneous rest vectors of the joint frame
#: ([1, c̄], [0, t̄], [0, n̄], [0, b̄]) on the parent (i) and the child (j)
OUTER_ROWS = ('c̃_i c̃_iᵀ', 'c̃_i t̃_iᵀ', 't̃_i t̃_iᵀ', 'ñ_i ñ_iᵀ + b̃_i b̃_iᵀ',
              'c̃_j c̃_jᵀ', 'c̃_j t̃_jᵀ', 't̃_j t̃_jᵀ', 'ñ_j ñ_jᵀ + b̃_j b̃_jᵀ',
              'c̃_i c̃_jᵀ', 't̃_i c̃_jᵀ', 'c̃_i t̃_jᵀ', 'ñ_i ñ_jᵀ + b̃_i b̃_jᵀ')


def outer_products(frames) -> np.ndarray:
    """(S,12,4,4) the outer products OUTER_ROWS of each joint's rest vectors (`rest_frames`):
    the constant factors of UID 20's Hessian blocks (`accumulate`)."""
    S = len(frames)
    y = np.zeros((S, 2, 4, 4))
    y[:, :, :, 1:] = frames
    y[:, :, 0, 0] = 1.0
    c, t, n, b = (y[:, :, a] for a in range(4))
    o = np.einsum
    out = np.empty((S, 12, 4, 4))
    for side in range(2):
        out[:, 4 * side] = o('sk,sl->skl', c[:, side], c[:, side])
        out[:, 4 * side + 1] = o('sk,sl->skl', c[:, side], t[:, side])
        out[:, 4 * side + 2] = o('sk,sl->skl', t[:, side], t[:, side])
        out[:, 4 * side + 3] = o('sk,sl->skl', n[:, side], n[:, side]) + o('sk,sl->skl', b[:, side], b[:, side])
    out[:, 8] = o('sk,sl->skl', c[:, 0], c[:, 1])
    out[:, 9] = o('sk,sl->skl', t[:, 0], c[:, 1])
    out[:, 10] = o('sk,sl->skl', c[:, 0], t[:, 1])
    out[:, 11] = o('sk,sl->skl', n[:, 0], n[:, 1]) + o('sk,sl->skl', b[:, 0], b[:, 1])
    return out


def build(model, data) -> dict:
    m = model
    S = m.prismatic_joints
    slot = np.full(m.joint_count, -1, np.int64)
    slot[S] = np.arange(len(S))
    size, parent, child = m.body_size, m.joint_parent[S], m.joint_child[S]
    frames = rest_frames(m)
    return dict(
        prismatic_joints=flat.array(S, np.int64),
        prismatic_slot=flat.array(slot, np.int64),
        prismatic_frame=flat.array(frames, np.float64),
        prismatic_outer=flat.array(outer_products(frames), np.float64),
        prismatic_K=flat.array(m.prismatic_K, np.float64),
        prismatic_warn_separation=flat.array(SEPARATION_WARN * np.minimum(size[parent], size[child]),
                                             np.float64),
        prismatic_fault_separation=flat.array(SEPARATION_FAULT * np.maximum(size[parent], size[child]),
                                              np.float64))


# -- geometry of one joint ----------------------------------------------------------------------
# A frame vector a (0: c, 1: t, 2: n, 3: b) is J(ȳ) q, ȳ = [1, c̄] or [0, x̄]: its Jacobian
# I3 ⊗ ȳᵀ, and M (I3 ⊗ ȳᵀ) has M[m, r] ȳ[κ] at row m, column `col(r, κ)`.


@kernel(inline='always')
def col(r, kappa):
    """Column of q (12,) holding entry (r, κ) of I3 ⊗ ȳᵀ: p_r for κ = 0, A[r, κ − 1] else."""
    return r if kappa == 0 else 3 + 3 * r + kappa - 1


@kernel(inline='always')
def rest(fr, k, side, a, kappa):
    """Entry κ of the homogeneous rest vector ȳ of frame vector a on `side` of joint k."""
    if kappa == 0:
        return 1.0 if a == 0 else 0.0
    return fr[k, side, a, kappa - 1]


@kernel(inline='always')
def row(q, b, fr, k, side, a, r):
    """Row r of frame vector a (0: c, 1: t, 2: n, 3: b) of joint k's `side` on body b, in world
    axes: c_r = p_r + A[r]·c̄, t_r = A[r]·t̄. [m for c]"""
    x = q[b, r] if a == 0 else 0.0
    for c in range(3):
        x += q[b, 3 + 3 * r + c] * fr[k, side, a, c]
    return x


@kernel(inline='always')
def axis_and_offset(q, i_body, j_body, fr, k):
    """(r, t_i, t_j) of joint k, each a 3-tuple: r = c_j − c_i, t_k = A_k t̄_k."""
    r = (row(q, j_body, fr, k, 1, 0, 0) - row(q, i_body, fr, k, 0, 0, 0),
         row(q, j_body, fr, k, 1, 0, 1) - row(q, i_body, fr, k, 0, 0, 1),
         row(q, j_body, fr, k, 1, 0, 2) - row(q, i_body, fr, k, 0, 0, 2))
    ti = (row(q, i_body, fr, k, 0, 1, 0), row(q, i_body, fr, k, 0, 1, 1), row(q, i_body, fr, k, 0, 1, 2))
    tj = (row(q, j_body, fr, k, 1, 1, 0), row(q, j_body, fr, k, 1, 1, 1), row(q, j_body, fr, k, 1, 1, 2))
    return r, ti, tj


@kernel
def frames(q, i_body, j_body, fr, k, W):
    """W (≥ 8, 3) rows c_i, c_j, t_i, t_j, n_i, n_j, b_i, b_j of prismatic joint k in world axes."""
    for side in range(2):
        b = i_body if side == 0 else j_body
        for r in range(3):
            W[side, r] = row(q, b, fr, k, side, 0, r)
            W[2 + side, r] = row(q, b, fr, k, side, 1, r)
            W[4 + side, r] = row(q, b, fr, k, side, 2, r)
            W[6 + side, r] = row(q, b, fr, k, side, 3, r)


@kernel
def distance_at(q, i_body, j_body, fr, k):
    """d(q) of prismatic joint k, relative to its creation. [m]"""
    r, ti, tj = axis_and_offset(q, i_body, j_body, fr, k)
    d = 0.0
    for c in range(3):
        d += r[c] * (ti[c] + tj[c])
    return 0.5 * d


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


# -- derivatives of the slides u_k = t_k·r and of d = ½ (u_i + u_j), in blocks ---------------------
@kernel
def slide_gradient(q, i_body, j_body, fr, k, w_i, w_j, g, row0):
    """Rows row0, row0 + 1 of g (≥ row0 + 2, ≥ 12) = w_i ∇u_i + w_j ∇u_j over q_i, q_j
    (u_k = t_k·r: ∂u_k/∂r = t_k, ∂u_k/∂t_k = r, with r = c_j − c_i); returns (u_i, u_j).
    ∇d: w_i = w_j = ½."""
    r, ti, tj = axis_and_offset(q, i_body, j_body, fr, k)
    ui = uj = 0.0
    for c in range(3):
        ui += ti[c] * r[c]
        uj += tj[c] * r[c]
    for s in range(3):
        tw = w_i * ti[s] + w_j * tj[s]          # ∂/∂r
        rw_i, rw_j = w_i * r[s], w_j * r[s]     # ∂/∂t_i, ∂/∂t_j
        for kappa in range(4):
            g[row0, col(s, kappa)] = -tw * rest(fr, k, 0, 0, kappa) + rw_i * rest(fr, k, 0, 1, kappa)
            g[row0 + 1, col(s, kappa)] = tw * rest(fr, k, 1, 0, kappa) + rw_j * rest(fr, k, 1, 1, kappa)
    return ui, uj


@kernel
def add_slide_curvature(fr, k, i_body, j_body, j, w_i, w_j, diag, pair):
    """The blocks += w_i ∇²u_i + w_j ∇²u_j: u_k is bilinear, its second-order part dr·dt_k,
    so ∇²u_k has the entries ±δ_rs ȳ[κ] z̄[λ] between the points' and t_k's columns."""
    for kap in range(4):
        ci, ti = rest(fr, k, 0, 0, kap), rest(fr, k, 0, 1, kap)
        cj, tj = rest(fr, k, 1, 0, kap), rest(fr, k, 1, 1, kap)
        for lam in range(4):
            ci_l, ti_l = rest(fr, k, 0, 0, lam), rest(fr, k, 0, 1, lam)
            cj_l, tj_l = rest(fr, k, 1, 0, lam), rest(fr, k, 1, 1, lam)
            hii = -w_i * (ti * ci_l + ci * ti_l)
            hjj = w_j * (cj * tj_l + tj * cj_l)
            hij = w_i * ti * cj_l - w_j * ci * tj_l
            for r in range(3):
                a, b = col(r, kap), col(r, lam)
                diag[i_body, a, b] += hii
                diag[j_body, a, b] += hjj
                pair[j, a, b] += hij


@kernel
def add_rank_one(g, row0, c, w, i_body, j_body, j, grad, diag, pair):
    """grad += c g and the blocks += w g gᵀ, g over q_i, q_j in rows row0, row0 + 1 of g."""
    i_row, j_row = row0, row0 + 1
    for a in range(12):
        grad[i_body, a] += c * g[i_row, a]
        grad[j_body, a] += c * g[j_row, a]
        wi, wj = w * g[i_row, a], w * g[j_row, a]
        for b in range(12):
            diag[i_body, a, b] += wi * g[i_row, b]
            diag[j_body, a, b] += wj * g[j_row, b]
            pair[j, a, b] += wi * g[j_row, b]


# -- the energy -----------------------------------------------------------------------------------
@kernel(inline='always')
def constraints(q, i_body, j_body, fr, k, r, ti, tj):
    """(C0, C1, C2, C3) of joint k as 3-tuples, from axis_and_offset's (r, t_i, t_j)."""
    C0 = (r[1] * ti[2] - r[2] * ti[1], r[2] * ti[0] - r[0] * ti[2], r[0] * ti[1] - r[1] * ti[0])
    C1 = (-(r[1] * tj[2] - r[2] * tj[1]), -(r[2] * tj[0] - r[0] * tj[2]), -(r[0] * tj[1] - r[1] * tj[0]))
    C2 = (row(q, i_body, fr, k, 0, 2, 0) - row(q, j_body, fr, k, 1, 2, 0),
          row(q, i_body, fr, k, 0, 2, 1) - row(q, j_body, fr, k, 1, 2, 1),
          row(q, i_body, fr, k, 0, 2, 2) - row(q, j_body, fr, k, 1, 2, 2))
    C3 = (row(q, i_body, fr, k, 0, 3, 0) - row(q, j_body, fr, k, 1, 3, 0),
          row(q, i_body, fr, k, 0, 3, 1) - row(q, j_body, fr, k, 1, 3, 1),
          row(q, i_body, fr, k, 0, 3, 2) - row(q, j_body, fr, k, 1, 3, 2))
    return C0, C1, C2, C3


@kernel(inline='always')
def sum_of_squares(C0, C1, C2, C3):
    """Σ |C_k|², in the order C0, C1, C2, C3."""
    acc = 0.0
    for C in (C0, C1, C2, C3):
        acc += C[0] * C[0]
        acc += C[1] * C[1]
        acc += C[2] * C[2]
    return acc


@kernel
def separation_at(q, i_body, j_body, fr, k):
    """max(|C0|, |C1|) of prismatic joint k: each body's axis point off the other's axis. [m]"""
    r, ti, tj = axis_and_offset(q, i_body, j_body, fr, k)
    C0, C1, _, _ = constraints(q, i_body, j_body, fr, k, r, ti, tj)
    a = math.sqrt(C0[0] * C0[0] + C0[1] * C0[1] + C0[2] * C0[2])
    b = math.sqrt(C1[0] * C1[0] + C1[1] * C1[1] + C1[2] * C1[2])
    return a if (a > b or a != a) else b


@kernel
def joint_separation(q, m, j):
    """The separation of joint j (a prismatic joint). [m]"""
    return separation_at(q, m.joint_parent[j], m.joint_child[j], m.prismatic_frame, m.prismatic_slot[j])


@kernel
def check_separations(q, m):
    """revolute.check_separations over the prismatic joints. [m]"""
    joints, parent, child, fr = m.prismatic_joints, m.joint_parent, m.joint_child, m.prismatic_frame
    warn, fault = m.prismatic_warn_separation, m.prismatic_fault_separation
    largest = 0.0
    overloaded = False
    apart = -1
    for k in range(joints.size):
        j = joints[k]
        n = separation_at(q, parent[j], child[j], fr, k)
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
    E = 0.0
    for k in range(joints.size):
        j = joints[k]
        r, ti, tj = axis_and_offset(q, parent[j], child[j], fr, k)
        C0, C1, C2, C3 = constraints(q, parent[j], child[j], fr, k, r, ti, tj)
        E += K[k] * sum_of_squares(C0, C1, C2, C3)
    return 0.5 * E


@kernel(inline='always')
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E and ∇²E (Gauss-Newton with `project`, else the whole Hessian), straight into the
    joint's three 12×12 blocks; returns E (the bits of `energy`).

    With X = [t_i]×, Y = [t_j]×, R = [r]× and ȳ the rest vectors (c̃, t̃, ñ, b̃ of each side),
    ∇C0 = [X ⊗ c̃_iᵀ + R ⊗ t̃_iᵀ | −X ⊗ c̃_jᵀ], ∇C1 = [−Y ⊗ c̃_iᵀ | Y ⊗ c̃_jᵀ − R ⊗ t̃_jᵀ],
    ∇C2 = [I ⊗ ñ_iᵀ | −I ⊗ ñ_jᵀ], ∇C3 likewise with b̃, so K Σ ∇C_kᵀ∇C_k is, with
    P = XᵀX + YᵀY, U = XᵀR, V = YᵀR, S = RᵀR:

        ii:  P ⊗ c̃_ic̃_iᵀ + U ⊗ c̃_it̃_iᵀ + Uᵀ ⊗ t̃_ic̃_iᵀ + S ⊗ t̃_it̃_iᵀ + I ⊗ (ñ_iñ_iᵀ + b̃_ib̃_iᵀ)
        jj:  P ⊗ c̃_jc̃_jᵀ − V ⊗ c̃_jt̃_jᵀ − Vᵀ ⊗ t̃_jc̃_jᵀ + S ⊗ t̃_jt̃_jᵀ + I ⊗ (ñ_jñ_jᵀ + b̃_jb̃_jᵀ)
        ij: −P ⊗ c̃_ic̃_jᵀ − Uᵀ ⊗ t̃_ic̃_jᵀ + V ⊗ c̃_it̃_jᵀ − I ⊗ (ñ_iñ_jᵀ + b̃_ib̃_jᵀ)

    ((N ⊗ ȳz̄ᵀ) has N[r, s] ȳ[κ] z̄[λ] at (col(r, κ), col(s, λ)); the 4×4 ȳz̄ᵀ are constant:
    m.prismatic_outer, OUTER_ROWS.) The rest of the whole Hessian,
    K C·∇²C, is bilinear in the same pairs (w·(dr × dt) = dtᵀ [w]× dr): it is U → U + [C0]×,
    V → V − [C1]× in the same formulas."""
    joints, parent, child, fr, K = m.prismatic_joints, m.joint_parent, m.joint_child, m.prismatic_frame, m.prismatic_K
    outer = m.prismatic_outer
    E = 0.0
    for k in range(joints.size):
        j = joints[k]
        i_body, j_body = parent[j], child[j]
        r, ti, tj = axis_and_offset(q, i_body, j_body, fr, k)
        C0, C1, C2, C3 = constraints(q, i_body, j_body, fr, k, r, ti, tj)
        Kk = K[k]
        E += Kk * sum_of_squares(C0, C1, C2, C3)
        # the gradient: K Σ ∇C_kᵀ C_k, per side the coefficients of c̃, t̃, ñ, b̃
        a0, b0 = cross(C0, ti), cross(C1, tj)
        ec = (a0[0] - b0[0], a0[1] - b0[1], a0[2] - b0[2])      # C0 × t_i − C1 × t_j
        et_i, et_j = cross(C0, r), cross(C1, r)
        for s in range(3):
            for kappa in range(4):
                grad[i_body, col(s, kappa)] += Kk * (ec[s] * rest(fr, k, 0, 0, kappa)
                                                     + et_i[s] * rest(fr, k, 0, 1, kappa)
                                                     + C2[s] * rest(fr, k, 0, 2, kappa)
                                                     + C3[s] * rest(fr, k, 0, 3, kappa))
                grad[j_body, col(s, kappa)] += Kk * (-ec[s] * rest(fr, k, 1, 0, kappa)
                                                     - et_j[s] * rest(fr, k, 1, 1, kappa)
                                                     - C2[s] * rest(fr, k, 1, 2, kappa)
                                                     - C3[s] * rest(fr, k, 1, 3, kappa))
        ri = r[0] * ti[0] + r[1] * ti[1] + r[2] * ti[2]
        rj = r[0] * tj[0] + r[1] * tj[1] + r[2] * tj[2]
        tt = ti[0] * ti[0] + ti[1] * ti[1] + ti[2] * ti[2] + tj[0] * tj[0] + tj[1] * tj[1] + tj[2] * tj[2]
        rr = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
        for a in range(3):
            for b in range(3):
                delta = 1.0 if a == b else 0.0
                P = Kk * (tt * delta - ti[a] * ti[b] - tj[a] * tj[b])    # XᵀX = |t|² I − t tᵀ
                U = Kk * (ri * delta - r[a] * ti[b])                     # XᵀR = (t·r) I − r tᵀ
                Ut = Kk * (ri * delta - r[b] * ti[a])
                V = Kk * (rj * delta - r[a] * tj[b])
                Vt = Kk * (rj * delta - r[b] * tj[a])
                S = Kk * (rr * delta - r[a] * r[b])
                if not project:                 # + [C0]×[a, b], − [C1]×[a, b]
                    e0 = _skew(C0, a, b)
                    e1 = _skew(C1, a, b)
                    U += Kk * e0
                    Ut -= Kk * e0
                    V -= Kk * e1
                    Vt += Kk * e1
                D = Kk * delta
                for kap in range(4):
                    x = col(a, kap)
                    for lam in range(4):
                        y = col(b, lam)
                        diag[i_body, x, y] += (P * outer[k, 0, kap, lam] + U * outer[k, 1, kap, lam]
                                               + Ut * outer[k, 1, lam, kap] + S * outer[k, 2, kap, lam]
                                               + D * outer[k, 3, kap, lam])
                        diag[j_body, x, y] += (P * outer[k, 4, kap, lam] - V * outer[k, 5, kap, lam]
                                               - Vt * outer[k, 5, lam, kap] + S * outer[k, 6, kap, lam]
                                               + D * outer[k, 7, kap, lam])
                        pair[j, x, y] += (-P * outer[k, 8, kap, lam] - Ut * outer[k, 9, kap, lam]
                                          + V * outer[k, 10, kap, lam] - D * outer[k, 11, kap, lam])
    return 0.5 * E


@kernel(inline='always')
def _skew(w, a, b):
    """[w]×[a, b]."""
    if a == b:
        return 0.0
    if a == 0:
        return -w[2] if b == 1 else w[1]
    if a == 1:
        return w[2] if b == 0 else -w[0]
    return -w[1] if b == 0 else w[0]
