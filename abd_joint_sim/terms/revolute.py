"""Revolute joint (libuipc UID 18), PHYSICS.md §3.

    E = K/2 (‖J(x̄0_i) q_i − J(x̄0_j) q_j‖² + ‖J(x̄1_i) q_i − J(x̄1_j) q_j‖²),  K = γ (m_i + m_j)

No h² factor: its physical spring constant is γ(m_i+m_j)/h². E is quadratic in q, so its
24x24 Hessian on [q_i, q_j] is constant and PSD; it is precomputed in the Model
(`joint_hessian`) and the gradient is one batched mat-vec.
"""
from __future__ import annotations

import numpy as np

from ..model import point_jacobian
from .base import EnergyTerm, PairScatter

ALL = tuple(range(12))


class RevoluteJoint(EnergyTerm):
    name = 'revolute_joint'
    uid = 18

    def __init__(self, model):
        self.model = model
        self.joints = np.arange(model.joint_count)
        # rest anchors per side k: (J, anchor a, 3)
        self.xbar = [np.stack([model.joint_anchor0[:, k], model.joint_anchor1[:, k]], axis=1) for k in (0, 1)]
        self.scatter = PairScatter(model, self.joints, ALL)

    @classmethod
    def build(cls, model):
        return cls(model) if model.joint_count else None

    def _separations(self, q):
        """x_i − x_j of both anchor pairs, x = A x̄ + p: (J,2,3). Computed as differences of
        positions, not as zᵀHz, whose terms (K|x|²) cancel catastrophically."""
        m = self.model
        out = []
        for k, body in enumerate((m.joint_parent, m.joint_child)):
            A = q[body, 3:12].reshape(-1, 3, 3)
            out.append(np.matmul(self.xbar[k], A.transpose(0, 2, 1)) + q[body, None, :3])
        return out[0] - out[1]

    def energy(self, q, ctx):
        d = self._separations(q)
        return 0.5 * float(np.dot(self.model.joint_K, (d * d).sum(axis=(1, 2))))

    def accumulate(self, q, ctx, grad, diag, pair, project=True):
        d = self.model.joint_K[:, None, None] * self._separations(q)      # K (x_i − x_j)
        n = len(self.joints)
        g = np.empty((n, 24))
        for k, sign in ((0, 1.0), (1, -1.0)):
            # ∂/∂p = Σ_a K d_a,  ∂/∂A = Σ_a K d_a x̄_aᵀ
            g[:, 12 * k:12 * k + 3] = sign * d.sum(axis=1)
            g[:, 12 * k + 3:12 * k + 12] = sign * np.matmul(d.transpose(0, 2, 1), self.xbar[k]).reshape(n, 9)
        self.scatter.gradient(g, grad)
        self.scatter.hessian(self.model.joint_hessian, diag, pair)


def joint_separation(model, q) -> np.ndarray:
    """Largest distance between the two bodies' copies of P0 or P1, per joint. [m] (J,)"""
    if model.joint_count == 0:
        return np.zeros(0)
    out = []
    for anchors in (model.joint_anchor0, model.joint_anchor1):
        xi = np.einsum('jrk,jk->jr', point_jacobian(anchors[:, 0]), q[model.joint_parent])
        xj = np.einsum('jrk,jk->jr', point_jacobian(anchors[:, 1]), q[model.joint_child])
        out.append(np.linalg.norm(xi - xj, axis=1))
    return np.maximum(*out)
