"""Forces without energy: they enter only the prediction q̃ (PHYSICS.md §2, step 2).

Each returns the q-space acceleration M⁻¹F (B,12) evaluated once per step at qⁿ.

External joint torque (libuipc UID 668), PHYSICS.md §5, for each enabled joint with torque τ:
    ẽ_k = normalize(A_k (x̄1_k − x̄0_k))          each body from its OWN anchors and A
    ê_j = ½(ẽ_i + ẽ_j),   ê_i = −ê_j              same-order anchors (§9): exact 3rd law
    F_k = [0₃ ; vec((τ/2) [ê_k]× A_k^{−T})]        vec = row-major into q[3:12]
Virtual work: for δA = [δω]× A, F^A : δA = τ ê·δω (checked by test). Positive τ turns the
child about +t, so it increases the joint angle. A near-singular A_k
(|det A| / (|a1||a2||a3|) < 1e-6) gets no torque, and the step reports it.
"""
from __future__ import annotations

import numpy as np

from ..model import skew

SINGULAR_RATIO = 1e-6


class Gravity:
    """Uniform gravity: in q-space exactly [g, 0, ..., 0] (M⁻¹ of the generalized force)."""

    name = 'gravity'

    def __init__(self, model):
        self.model = model
        self.acc = np.zeros(12)
        self.acc[:3] = model.gravity

    @classmethod
    def build(cls, model):
        return cls(model) if model.has_gravity else None

    def acceleration(self, q, control, out, warnings):
        out[~self.model.body_fixed] += self.acc


class ExternalTorque:
    """UID 668, built only when some joint carries `external_torque`."""

    name = 'external_torque'
    uid = 668

    def __init__(self, model):
        self.model = model
        self.joints = model.torque_joints

    @classmethod
    def build(cls, model):
        return cls(model) if len(model.torque_joints) else None

    def axes(self, q):
        """Symmetrised world axes (ê_i, ê_j), each (T,3).

        A degenerate A can map the anchor difference to (almost) nothing; that body's raw
        axis is then unusable and the other body's is taken for both (so the healthy body
        still gets its torque); with neither usable the axis is 0 and so is the torque."""
        m = self.model
        A = q[:, 3:12].reshape(-1, 3, 3)
        e, ok = [], []
        for side, body in enumerate((m.joint_parent[self.joints], m.joint_child[self.joints])):
            d = m.joint_anchor1[self.joints, side] - m.joint_anchor0[self.joints, side]
            v = np.matmul(A[body], d[:, :, None])[:, :, 0]
            n = np.linalg.norm(v, axis=1, keepdims=True)
            good = np.isfinite(n) & (n > 1e-12 * np.linalg.norm(d, axis=1, keepdims=True))
            e.append(np.divide(v, n, out=np.zeros_like(v), where=good))
            ok.append(good)
        both = ok[0] & ok[1]
        e_j = np.where(both, 0.5 * (e[0] + e[1]), e[0] + e[1])   # one of them is 0 if not both
        return -e_j, e_j
    def generalized_force(self, q, tau):
        """F (B,12) for torques `tau` (T,) (0 = none) and the bodies skipped as singular."""
        m = self.model
        F = np.zeros((m.body_count, 12))
        active = tau != 0.0
        if not active.any():
            return F, []
        A = q[:, 3:12].reshape(-1, 3, 3)
        e_i, e_j = self.axes(q)
        skipped = []
        for e, body in ((e_i, m.joint_parent[self.joints]), (e_j, m.joint_child[self.joints])):
            Ab = A[body[active]]
            det = np.abs(np.linalg.det(Ab))
            scale = np.prod(np.linalg.norm(Ab, axis=2), axis=1)
            ok = det > SINGULAR_RATIO * scale
            FA = np.zeros_like(Ab)
            if ok.any():
                AinvT = np.linalg.inv(Ab[ok]).transpose(0, 2, 1)
                FA[ok] = 0.5 * tau[active][ok, None, None] * (skew(e[active][ok]) @ AinvT)
            np.add.at(F, (body[active], slice(3, 12)), FA.reshape(-1, 9))
            skipped += [int(b) for b in body[active][~ok]]
        return F, skipped

    def acceleration(self, q, control, out, warnings):
        tau = np.where(control.torque_enabled, control.torque_value, 0.0)
        F, skipped = self.generalized_force(q, tau)
        for b in skipped:
            warnings.append(f'body {self.model.body_names[b]!r}: affine matrix near-singular '
                            f'(|det A|/(|a1||a2||a3|) < {SINGULAR_RATIO}); joint torque not applied')
        out += np.matmul(self.model.body_Minv, F[:, :, None])[:, :, 0]
