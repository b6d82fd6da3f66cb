"""OrthoPotential (libuipc UID 1): the affine body's shape energy, PHYSICS.md §1-2.

    E = h² κ v̄ ‖A Aᵀ − I‖²_F                        (h² because it is a potential)
    ∂E/∂A = 4 h² κ v̄ C A,  C = A Aᵀ − I
    ∂²E/∂A_ik ∂A_jl = 4 h² κ v̄ [δ_ij (AᵀA)_lk + A_il A_jk + C_ij δ_kl]

The energy is non-convex (it has saddles where A is not near SO(3)), so its 9x9 Hessian is
projected to PSD by eigenvalue clamping before use. Built over free bodies only: fixed bodies
never move, so their shape energy is a constant.
"""
from __future__ import annotations

import numpy as np

from .base import EnergyTerm, project_psd


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
        return ctx.h ** 2 * float(np.sum(self.weight * np.einsum('bij,bij->b', C, C)))

    def accumulate(self, q, ctx, grad, diag, pair, project=True):
        A = self._A(q)
        C = A @ A.transpose(0, 2, 1) - np.eye(3)
        w = 4.0 * ctx.h ** 2 * self.weight
        grad[self.bodies, 3:12] += (w[:, None, None] * (C @ A)).reshape(-1, 9)
        AtA = A.transpose(0, 2, 1) @ A
        eye = np.eye(3)
        H = (np.einsum('ij,blk->bikjl', eye, AtA)
             + np.einsum('bil,bjk->bikjl', A, A)
             + np.einsum('bij,kl->bikjl', C, eye)).reshape(-1, 9, 9)
        H = w[:, None, None] * H
        if project:
            H = project_psd(H)
        diag[self.bodies, 3:12, 3:12] += H
