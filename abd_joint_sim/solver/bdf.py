"""BDF1 / BDF2 time integration (docs/physics.md "Time integration"): the prediction q̃ that
defines the incremental potential, and the velocity update after Newton.

BDF1 (implicit Euler):  q̃ = qⁿ + h vⁿ + h² a,          v = (q − qⁿ)/h,             s = 1
BDF2:                   q̃ = (4qⁿ − qⁿ⁻¹)/3 + (2h/9)(4vⁿ − vⁿ⁻¹) + β h² a,
                        v = (3q − 4qⁿ + qⁿ⁻¹)/(2h),   β = 4/9,   s = 1/β
with a = g_q + M⁻¹F the explicit forces' acceleration (BDF1 at qⁿ, BDF2 at the
extrapolation 2qⁿ − qⁿ⁻¹: the torque turns with A, docs/decisions.md). Fixed bodies keep
q̃ = qⁿ and v = 0. BDF2 needs one step of history at the same h; without it (first step,
after a reset, a dt change or sub-stepping) the step is BDF1 (docs/decisions.md).
"""
from __future__ import annotations

import math

from ..jit import kernel


BETA_BDF2 = 4.0 / 9.0


@kernel
def force_point(q, q_prev, bdf2, out):
    """out = where the explicit forces are evaluated: qⁿ (BDF1) or 2qⁿ − qⁿ⁻¹ (BDF2)."""
    for b in range(q.shape[0]):
        for r in range(12):
            out[b, r] = 2 * q[b, r] - q_prev[b, r] if bdf2 else q[b, r]


@kernel
def predict(m, q, v, q_prev, v_prev, acc, h, bdf2, q_tilde):
    """Fills q_tilde (B,12); returns s, the inertia term's scale (1 or 1/β)."""
    fixed = m.body_fixed
    c1 = 2.0 / 9.0 * h
    c2 = BETA_BDF2 * h * h
    hh = h * h
    for b in range(q.shape[0]):
        if fixed[b]:
            for r in range(12):
                q_tilde[b, r] = q[b, r]
        elif bdf2:
            for r in range(12):
                q_tilde[b, r] = ((4 * q[b, r] - q_prev[b, r]) / 3 + c1 * (4 * v[b, r] - v_prev[b, r])
                                 + c2 * acc[b, r])
        else:
            for r in range(12):
                q_tilde[b, r] = q[b, r] + h * v[b, r] + hh * acc[b, r]
    return 1.0 / BETA_BDF2 if bdf2 else 1.0


@kernel
def velocity(m, q_new, q, q_prev, h, bdf2, v_new):
    """Fills v_new (B,12) from the solved q_new (0 on fixed bodies); returns whether every
    entry is finite."""
    fixed = m.body_fixed
    finite = True
    for b in range(q.shape[0]):
        if fixed[b]:
            for r in range(12):
                v_new[b, r] = 0.0
        elif bdf2:
            for r in range(12):
                x = (3 * q_new[b, r] - 4 * q[b, r] + q_prev[b, r]) / (2 * h)
                v_new[b, r] = x
                finite = finite and math.isfinite(x)
        else:
            for r in range(12):
                x = (q_new[b, r] - q[b, r]) / h
                v_new[b, r] = x
                finite = finite and math.isfinite(x)
    return finite
