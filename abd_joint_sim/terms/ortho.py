"""OrthoPotential (libuipc UID 1): the affine body's shape energy, PHYSICS.md §1-2.

    E = h² κ v̄ ‖A Aᵀ − I‖²_F                        (h² because it is a potential)
    ∂E/∂A = 4 h² κ v̄ C A,  C = A Aᵀ − I
    ∂²E/∂A_ik ∂A_jl = 4 h² κ v̄ [δ_ij (AᵀA)_lk + A_il A_jk + C_ij δ_kl]

The energy is non-convex (it has saddles where A is not near SO(3)), so its 9x9 Hessian is
projected to PSD by eigenvalue clamping before use. E depends on A only through its singular
values, E = h²κv̄ Σ_k (σ_k² − 1)², so its eigensystem is analytic (Smith et al. 2019, "Analytic
eigensystems for isotropic distortion energies"): with A = U Σ Vᵀ and P_ij = u_i v_jᵀ,
    scaling P_kk:              λ = 4w (3σ_k² − 1)
    flip   (P_ij + P_ji)/√2:   λ = 4w (σ_i² + σ_iσ_j + σ_j² − 1)
    twist  (P_ij − P_ji)/√2:   λ = 4w (σ_i² − σ_iσ_j + σ_j² − 1)
(w = h²κv̄). Clamping these needs a batched 3x3 SVD instead of a 9x9 eigendecomposition;
test_terms.py checks the result against the raw Hessian and its eigenvalues. Built over free bodies only: fixed bodies
never move, so their shape energy is a constant.
"""
from __future__ import annotations

import numpy as np

from .base import EnergyTerm


class OrthoPotential(EnergyTerm):
    name = 'ortho_potential'
    uid = 1

    def __init__(self, model, bodies):
        self.bodies = bodies
        self.weight = model.body_kappa[bodies] * model.body_volume[bodies]   # κ v̄

    @classmethod
    def build(cls, model):
        free = np.flatnonzero(~model.body_fixed)
        return cls(model, free) if len(free) else None

    def _A(self, q):
        return q[self.bodies, 3:12].reshape(-1, 3, 3)

    def energy(self, q, ctx):
        A = self._A(q)
        C = A @ A.transpose(0, 2, 1) - np.eye(3)
        return ctx.h ** 2 * float(np.dot(self.weight, (C * C).sum(axis=(1, 2))))

    def accumulate(self, q, ctx, grad, diag, pair, project=True):
        A = self._A(q)
        C = A @ A.transpose(0, 2, 1) - np.eye(3)
        w = 4.0 * ctx.h ** 2 * self.weight
        grad[self.bodies, 3:12] += (w[:, None, None] * (C @ A)).reshape(-1, 9)
        if project:
            H = projected_hessian(A)
        else:
            AtA = A.transpose(0, 2, 1) @ A
            eye = np.eye(3)
            H = (np.einsum('ij,blk->bikjl', eye, AtA)
                 + np.einsum('bil,bjk->bikjl', A, A)
                 + np.einsum('bij,kl->bikjl', C, eye)).reshape(-1, 9, 9)
        diag[self.bodies, 3:12, 3:12] += w[:, None, None] * H


_PAIRS = ((0, 1), (0, 2), (1, 2))


def projected_hessian(A):
    """PSD projection of ∂²‖AAᵀ − I‖²/∂A² / 4 for a batch of A (b,3,3) -> (b,9,9)."""
    U, S, Vh = np.linalg.svd(A)
    # P[b,i,j] = vec(u_i v_jᵀ), by broadcasting (einsum is slow for such small batches)
    P = (U.transpose(0, 2, 1)[:, :, None, :, None] * Vh[:, None, :, None, :]).reshape(-1, 3, 3, 9)
    vecs = [P[:, k, k] for k in range(3)]
    lam = [3 * S[:, k] ** 2 - 1 for k in range(3)]
    r2 = np.sqrt(0.5)
    for i, j in _PAIRS:
        sq = S[:, i] ** 2 + S[:, j] ** 2 - 1
        vecs += [r2 * (P[:, i, j] + P[:, j, i]), r2 * (P[:, i, j] - P[:, j, i])]
        lam += [sq + S[:, i] * S[:, j], sq - S[:, i] * S[:, j]]
    V = np.stack(vecs, axis=1)                                       # (b,9 modes,9)
    L = np.maximum(np.stack(lam, axis=1), 0.0)
    return np.matmul(V.transpose(0, 2, 1) * L[:, None, :], V)
