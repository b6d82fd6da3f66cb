"""Energy terms on the joint angle: driving (libuipc UID 19) and limit (UID 670).

Both use the unwrapped angle continued from the step start, PHYSICS.md §6:
    x(q) = rel_start + remainder(θ(q) − rel_start, 2π)
so dx/dq = dθ/dq. They act on the affine parts q[3:12] of the two bodies (18 DOF) and their
Hessians E''∇θ∇θᵀ + E'∇²θ are PSD-projected (∇²θ is indefinite).
"""
from __future__ import annotations

import numpy as np

from ..angles import joint_theta, joint_theta_derivatives, unwrap
from .base import EnergyTerm, PairScatter, project_psd

AFFINE = tuple(range(3, 12))


class _AngleTerm(EnergyTerm):
    def __init__(self, model, joints):
        self.model = model
        self.joints = joints
        self._scatter = {}

    def _scatter_for(self, active):
        """Scatter for the active subset (cached: the active set rarely changes)."""
        key = active.tobytes()
        if key not in self._scatter:
            self._scatter[key] = PairScatter(self.model, self.joints[active], AFFINE)
        return self._scatter[key]

    def _active(self, ctx):
        return np.ones(len(self.joints), bool)

    def _active_at(self, q, ctx):
        """Joints whose energy may be non-zero at q (default: those active in ctx)."""
        return self._active(ctx)

    def _phi(self, x, ctx, active):
        """(E, E', E'') per active joint as functions of the unwrapped relative angle x."""
        raise NotImplementedError

    def _x(self, theta, ctx, active):
        return unwrap(theta, ctx.joint_rel_start[self.joints[active]])

    def energy(self, q, ctx):
        active = self._active_at(q, ctx)
        if not active.any():
            return 0.0
        theta = joint_theta(self.model, q, self.joints[active])
        E, _, _ = self._phi(self._x(theta, ctx, active), ctx, active)
        return float(E.sum())

    def accumulate(self, q, ctx, grad, diag, pair, project=True):
        active = self._active_at(q, ctx)
        if not active.any():
            return
        joints = self.joints[active]
        theta, dth, ddth = joint_theta_derivatives(self.model, q, joints)
        _, d1, d2 = self._phi(self._x(theta, ctx, active), ctx, active)
        scatter = self._scatter_for(active)
        scatter.gradient(d1[:, None] * dth, grad)
        H = d2[:, None, None] * np.einsum('ja,jb->jab', dth, dth) + d1[:, None, None] * ddth
        if project:
            H = project_psd(H)
        scatter.hessian(H, diag, pair)


class Driving(_AngleTerm):
    """UID 19: E = K/2 (x − target)²,  K = γ_d (m_i + m_j); target = aim − init_angle, or the
    step-start angle when passive (locks the joint). Only enabled drives contribute."""

    name = 'driving'
    uid = 19

    @classmethod
    def build(cls, model):
        return cls(model, model.drive_joints) if len(model.drive_joints) else None

    def _active(self, ctx):
        return ctx.drive_active

    def _phi(self, x, ctx, active):
        K = self.model.drive_K[active]
        d = x - ctx.drive_target[active]
        return 0.5 * K * d * d, K * d, K


class Limit(_AngleTerm):
    """UID 670, with l = lower − init, u = upper − init, w = u − l, s = strength:
    E = s((x−u)/w)³ above u, s((l−x)/w)³ below l, 0 inside; s|x−l|³ when w = 0."""

    name = 'limit'
    uid = 670

    @classmethod
    def build(cls, model):
        return cls(model, model.limit_joints) if len(model.limit_joints) else None

    def _bounds(self, active):
        m = self.model
        init = m.joint_init_angle[self.joints[active]]
        return m.limit_lower[active] - init, m.limit_upper[active] - init, m.limit_strength[active]

    def _active_at(self, q, ctx):
        # Inside its range a limit has exactly zero energy, gradient and Hessian: only the
        # joints outside (or on a zero-width limit) need derivatives.
        everything = np.ones(len(self.joints), bool)
        x = self._x(joint_theta(self.model, q, self.joints), ctx, everything)
        lo, up, _ = self._bounds(everything)
        return (x > up) | (x < lo) | ((lo == up) & (x != lo))

    def _phi(self, x, ctx, active):
        lo, up, s = self._bounds(active)
        w = up - lo
        zero = w == 0.0
        ws = np.where(zero, 1.0, w)
        above, below = (x > up) & ~zero, (x < lo) & ~zero
        a = (x - up) / ws
        b = (lo - x) / ws
        E = np.where(above, s * a ** 3, np.where(below, s * b ** 3, 0.0))
        d1 = np.where(above, 3 * s * a * a / ws, np.where(below, -3 * s * b * b / ws, 0.0))
        d2 = np.where(above, 6 * s * a / ws ** 2, np.where(below, 6 * s * b / ws ** 2, 0.0))
        e = x - lo
        E = np.where(zero, s * np.abs(e) ** 3, E)
        d1 = np.where(zero, 3 * s * np.abs(e) * e, d1)
        d2 = np.where(zero, 6 * s * np.abs(e), d2)
        return E, d1, d2
