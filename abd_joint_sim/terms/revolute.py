"""Revolute joint (libuipc UID 18), PHYSICS.md §3.

    E = K/2 (‖J(x̄0_i) q_i − J(x̄0_j) q_j‖² + ‖J(x̄1_i) q_i − J(x̄1_j) q_j‖²),  K = γ (m_i + m_j)

No h² factor: its physical spring constant is γ(m_i+m_j)/h². E is quadratic in q, so its
24x24 Hessian on [q_i, q_j] is constant and PSD; it is precomputed in the Model
(`joint_hessian`) and the gradient is one batched mat-vec.
"""
from __future__ import annotations

import numpy as np

from ..model import point_jacobian
from .base import EnergyTerm, add_pair_gradient, add_pair_hessian

ALL = tuple(range(12))


class RevoluteJoint(EnergyTerm):
    name = 'revolute_joint'
    uid = 18

    def __init__(self, model):
        self.model = model
        self.joints = np.arange(model.joint_count)
        # point Jacobians (J, anchor a, side k, 3, 12)
        self.jac = np.stack([point_jacobian(model.joint_anchor0), point_jacobian(model.joint_anchor1)], axis=1)

    @classmethod
    def build(cls, model):
        return cls(model) if model.joint_count else None

    def _separations(self, q):
        """J(x̄a_i) q_i − J(x̄a_j) q_j for a = 0, 1: (J,2,3). Computed as differences of
        positions, not as zᵀHz, whose terms (K|x|²) cancel catastrophically."""
        m = self.model
        xi = np.einsum('jarc,jc->jar', self.jac[:, :, 0], q[m.joint_parent])
        xj = np.einsum('jarc,jc->jar', self.jac[:, :, 1], q[m.joint_child])
        return xi - xj

    def energy(self, q, ctx):
        d = self._separations(q)
        return 0.5 * float(np.sum(self.model.joint_K * np.einsum('jar,jar->j', d, d)))

    def accumulate(self, q, ctx, grad, diag, pair, project=True):
        d = self.model.joint_K[:, None, None] * self._separations(q)
        g = np.concatenate([np.einsum('jarc,jar->jc', self.jac[:, :, 0], d),
                            -np.einsum('jarc,jar->jc', self.jac[:, :, 1], d)], axis=1)
        add_pair_gradient(self.model, self.joints, g, grad, ALL)
        add_pair_hessian(self.model, self.joints, self.model.joint_hessian, diag, pair, ALL)


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
