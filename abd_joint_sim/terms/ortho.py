"""Orthogonality potential, libuipc UID 1 (docs/physics.md "Shape energy (UID 1)"):

    E = h² Σ_free κ v̄ ‖A Aᵀ − I‖²_F,   C = A Aᵀ − I,   ∇_A E = 4 h² κ v̄ C A

Hessian (vec A row-major, index 3i+k): 4h²κv̄ [δ_ij (AᵀA)_lk + A_il A_jk + C_ij δ_kl]. It is
indefinite away from SO(3); its PSD projection comes from the analytic eigensystem of
A = U Σ Vᵀ: eigenvectors vec(u_i v_iᵀ) with λ = 3σ_i² − 1, and (u_i v_jᵀ ± u_j v_iᵀ)/√2 with
λ = σ_i² + σ_j² − 1 ± σ_i σ_j (i < j), times 4h²κv̄; negative λ are clamped to 0.

Every λ is ≥ −‖C‖_F, so Newton uses the exact Hessian (no 3x3 SVD) and projects only where
4h²κv̄ ‖C‖_F exceeds ORTHO_EXACT_SHARE s μ_min(M̄) (m.ortho_exact_bound; docs/decisions.md).
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import flat, kernel
from ..smallmat import svd3_in
from . import inertia

NAME = 'ortho_potential'    #: in Solver.terms
STORED = True               #: stored energy (World.mechanical_energy; its h² cancels there)
CONSTANT_HESSIAN = False
ORTHO_EXACT_SHARE = 0.5     # of s μ_min(M̄) the exact shape Hessian may take (docs/decisions.md)
FIELDS = (
    ('ortho_weight', '(B,) κ v̄ of UID 1 [Pa m³]'),
    ('ortho_exact_bound', '(B,) UID 1\'s Hessian is used unprojected while h² ‖AAᵀ − I‖_F ≤ s × '
                          'this (`exact_bound`)'),
)


def used(model) -> bool:
    return model.body_count > int(model.body_fixed.sum())


def from_scene(scene, model) -> dict:
    """No Model fields of its own: it reads the bodies'."""
    return {}


def exact_bound(Mbar, weight):
    """(B,) ORTHO_EXACT_SHARE μ_min(M̄) / (4 κv̄) per body (inf without a shape term): below s
    times it, h² ‖AAᵀ − I‖_F keeps the exact Hessian within that share of s μ_min(M̄)."""
    mu = inertia.min_eigenvalue(Mbar)
    with np.errstate(divide='ignore'):
        return np.where(weight > 0.0, ORTHO_EXACT_SHARE * mu / (4.0 * weight), np.inf)


def build(model, data) -> dict:
    weight = flat.array(model.body_kappa * model.body_volume, np.float64)
    return dict(ortho_weight=weight,
                ortho_exact_bound=flat.array(exact_bound(data['body_Mbar'], weight), np.float64))


@kernel(inline='always')
def _aat(q, b, r, c):
    """(A Aᵀ)_rc of body b, A = q[b, 3:12] row-major."""
    return (q[b, 3 + 3 * r] * q[b, 3 + 3 * c] + q[b, 4 + 3 * r] * q[b, 4 + 3 * c]
            + q[b, 5 + 3 * r] * q[b, 5 + 3 * c])


@kernel(inline='always')
def _ata(q, b, l, k):
    """(Aᵀ A)_lk of body b."""
    return q[b, 3 + l] * q[b, 3 + k] + q[b, 6 + l] * q[b, 6 + k] + q[b, 9 + l] * q[b, 9 + k]


@kernel
def energy(q, m, ctx):
    weight = m.ortho_weight
    E = 0.0
    for b in m.free_bodies:
        acc = 0.0
        for r in range(3):
            for c in range(3):
                x = _aat(q, b, r, c)
                if r == c:
                    x -= 1.0
                acc += x * x
        E += weight[b] * acc
    return ctx.h * ctx.h * E


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E into grad; into diag the exact Hessian, or with `project` the PSD projection where
    the inertia does not outweigh its negative part (ORTHO_EXACT_SHARE). The exact path
    allocates nothing (docs/speed.md). Returns E, the bits of `energy`."""
    hh = ctx.h * ctx.h
    weight = m.ortho_weight
    exact_bound = m.ortho_exact_bound
    E = 0.0
    for b in m.free_bodies:
        # C = AAᵀ − I (symmetric: (AAᵀ)_rc and (AAᵀ)_cr are the same products)
        C = (_aat(q, b, 0, 0) - 1.0, _aat(q, b, 0, 1), _aat(q, b, 0, 2),
             _aat(q, b, 1, 0), _aat(q, b, 1, 1) - 1.0, _aat(q, b, 1, 2),
             _aat(q, b, 2, 0), _aat(q, b, 2, 1), _aat(q, b, 2, 2) - 1.0)
        w = 4.0 * hh * weight[b]
        for r in range(3):
            for c in range(3):
                grad[b, 3 + 3 * r + c] += w * (C[3 * r] * q[b, 3 + c] + C[3 * r + 1] * q[b, 6 + c]
                                               + C[3 * r + 2] * q[b, 9 + c])
        c2 = 0.0
        for r in range(9):
            c2 += C[r] * C[r]
        E += weight[b] * c2
        if project and not hh * math.sqrt(c2) <= ctx.scale * exact_bound[b]:
            _add_projected_hessian(q, b, w, diag, ctx.angle_work)
            continue
        AtA = (_ata(q, b, 0, 0), _ata(q, b, 0, 1), _ata(q, b, 0, 2),
               _ata(q, b, 1, 0), _ata(q, b, 1, 1), _ata(q, b, 1, 2),
               _ata(q, b, 2, 0), _ata(q, b, 2, 1), _ata(q, b, 2, 2))
        # Row (i, k), columns (j, l) = 3j + l: A_il A_jk, + (AᵀA)_lk where j = i, + C_ij where
        # l = k, in locals, one run of 9 columns for SLP (jit/slp.py): half the loop nest's time
        for i in range(3):
            a0, a1, a2 = q[b, 3 + 3 * i], q[b, 4 + 3 * i], q[b, 5 + 3 * i]        # A_il
            c0, c1, c2 = C[3 * i], C[3 * i + 1], C[3 * i + 2]                      # C_ij
            for k in range(3):
                r = 3 + 3 * i + k
                b0, b1, b2 = q[b, 3 + k], q[b, 6 + k], q[b, 9 + k]               # A_jk
                x00, x01, x02 = a0 * b0, a1 * b0, a2 * b0
                x10, x11, x12 = a0 * b1, a1 * b1, a2 * b1
                x20, x21, x22 = a0 * b2, a1 * b2, a2 * b2
                g0, g1, g2 = AtA[k], AtA[3 + k], AtA[6 + k]                        # (AᵀA)_lk
                if i == 0:
                    x00, x01, x02 = x00 + g0, x01 + g1, x02 + g2
                elif i == 1:
                    x10, x11, x12 = x10 + g0, x11 + g1, x12 + g2
                else:
                    x20, x21, x22 = x20 + g0, x21 + g1, x22 + g2
                if k == 0:
                    x00, x10, x20 = x00 + c0, x10 + c1, x20 + c2
                elif k == 1:
                    x01, x11, x21 = x01 + c0, x11 + c1, x21 + c2
                else:
                    x02, x12, x22 = x02 + c0, x12 + c1, x22 + c2
                diag[b, r, 3] += w * x00
                diag[b, r, 4] += w * x01
                diag[b, r, 5] += w * x02
                diag[b, r, 6] += w * x10
                diag[b, r, 7] += w * x11
                diag[b, r, 8] += w * x12
                diag[b, r, 9] += w * x20
                diag[b, r, 10] += w * x21
                diag[b, r, 11] += w * x22
    return hh * E


@kernel
def _add_projected_hessian(q, b, w, diag, work):
    """The PSD projection of body b's Hessian (w = 4h²κv̄; module docstring) added to diag[b],
    from the SVD of A; work: scratch of ≥ 138 floats, C-contiguous (the step's angle_work)."""
    buf = work.reshape(work.size)[:9 + 9 + 81 + 9 + 9 + 3 + 18]     # cut into named views
    A = buf[0:9].reshape((3, 3))
    U = buf[9:18].reshape((3, 3))
    vecs = buf[18:99].reshape((9, 9))
    lam = buf[99:108]
    V = buf[108:117].reshape((3, 3))
    S = buf[117:120]
    svd_work = buf[120:138].reshape((2, 3, 3))
    r2 = math.sqrt(0.5)
    for r in range(3):
        for c in range(3):
            A[r, c] = q[b, 3 + 3 * r + c]
    svd3_in(A, U, S, V, svd_work)
    # P_ij = vec(u_i v_jᵀ): P_ij[3r + c] = U[r, i] V[c, j]
    n = 0
    for i in range(3):
        for r in range(3):
            for c in range(3):
                vecs[n, 3 * r + c] = U[r, i] * V[c, i]
        lam[n] = 3 * S[i] ** 2 - 1
        n += 1
    for pi in range(3):
        i = 0 if pi < 2 else 1
        j = 1 if pi == 0 else 2
        sq = S[i] ** 2 + S[j] ** 2 - 1
        for r in range(3):
            for c in range(3):
                pij = U[r, i] * V[c, j]
                pji = U[r, j] * V[c, i]
                vecs[n, 3 * r + c] = r2 * (pij + pji)
                vecs[n + 1, 3 * r + c] = r2 * (pij - pji)
        lam[n] = sq + S[i] * S[j]
        lam[n + 1] = sq - S[i] * S[j]
        n += 2
    # Σ_k max(λ_k, 0) v_k v_kᵀ, skipping the clamped eigenvalues; v_k held in locals and
    # each row of the A-block written out, so the SLP vectoriser (jit/slp.py)
    # makes it vector operations: the same bits
    for k in range(9):
        if not lam[k] > 0.0:
            continue
        wl = w * lam[k]
        v0, v1, v2, v3, v4 = vecs[k, 0], vecs[k, 1], vecs[k, 2], vecs[k, 3], vecs[k, 4]
        v5, v6, v7, v8 = vecs[k, 5], vecs[k, 6], vecs[k, 7], vecs[k, 8]
        for a in range(9):
            x = wl * vecs[k, a]
            r = 3 + a
            diag[b, r, 3] += x * v0
            diag[b, r, 4] += x * v1
            diag[b, r, 5] += x * v2
            diag[b, r, 6] += x * v3
            diag[b, r, 7] += x * v4
            diag[b, r, 8] += x * v5
            diag[b, r, 9] += x * v6
            diag[b, r, 10] += x * v7
            diag[b, r, 11] += x * v8
