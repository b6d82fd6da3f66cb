"""Joint limit, libuipc UID 670 (docs/physics.md "Limit (UID 670)"): a cubic barrier outside
[l, u] on the unwrapped joint angle x (relative to init_angle), with w = u − l and strength s:

    x > u:  E = s ((x − u)/w)³          x < l:  E = s ((l − x)/w)³          inside: E = 0
    w = 0:  E = s |x − l|³ (a locked joint)

E' and E'' follow; gradient and Hessian via angles.accumulate_angle_joint (PSD-projected, or
exact where the bodies' inertia keeps Newton's matrix positive definite).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .. import angles


@njit(cache=True, error_model='numpy')
def phi(x, lower, upper, s):
    """(E, E', E'') of the limit at angle x."""
    w = upper - lower
    if w == 0.0:
        e = x - lower
        return s * abs(e) ** 3, 3 * s * abs(e) * e, 6 * s * abs(e)
    if x > upper:
        a = (x - upper) / w
        return s * a ** 3, 3 * s * a * a / w, 6 * s * a / w ** 2
    if x < lower:
        b = (lower - x) / w
        return s * b ** 3, -3 * s * b * b / w, 6 * s * b / w ** 2
    return 0.0, 0.0, 0.0


@njit(cache=True, error_model='numpy')
def active(x, lower, upper):
    """Outside the range, or off a zero-width limit."""
    return x > upper or x < lower or (lower == upper and x != lower)


@njit(cache=True, error_model='numpy')
def angle(q, m, ctx, k):
    """The unwrapped angle x of limit k's joint at q (relative to init_angle). [rad]"""
    j = m.limit_joints[k]
    return angles.unwrap(angles.theta_at(q, m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar, j),
                         ctx.angle_start[j])


@njit(cache=True, error_model='numpy')
def energy(q, m, ctx):
    lower, upper, strength = m.limit_lower, m.limit_upper, m.limit_strength
    E = 0.0
    for k in range(lower.size):
        x = angle(q, m, ctx, k)
        if active(x, lower[k], upper[k]):
            E += phi(x, lower[k], upper[k], strength[k])[0]
    return E


@njit(cache=True, error_model='numpy')
def active_joints(q, m, ctx):
    """(joints, E', E'', n): the n limits outside their range at q, with their slopes."""
    limit_joints, lower, upper, strength = m.limit_joints, m.limit_lower, m.limit_upper, m.limit_strength
    L = limit_joints.size
    joints = np.empty(L, dtype=np.int64)
    d1s = np.empty(L)
    d2s = np.empty(L)
    n = 0
    for k in range(L):
        x = angle(q, m, ctx, k)
        if active(x, lower[k], upper[k]):
            _, d1, d2 = phi(x, lower[k], upper[k], strength[k])
            joints[n] = limit_joints[k]
            d1s[n] = d1
            d2s[n] = d2
            n += 1
    return joints, d1s, d2s, n


@njit(cache=True, error_model='numpy')
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E and the (projected) Hessian of the active limits (active_joints and
    angles.accumulate_angle_hessian fused, joint by joint), working in ctx.angle_work."""
    limit_joints, lower, upper, strength = m.limit_joints, m.limit_lower, m.limit_upper, m.limit_strength
    parent, child, nbar, bbar = m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar
    budget = m.joint_angle_budget
    work = ctx.angle_work
    for k in range(limit_joints.size):
        x = angle(q, m, ctx, k)
        if active(x, lower[k], upper[k]):
            _, d1, d2 = phi(x, lower[k], upper[k], strength[k])
            j = limit_joints[k]
            angles.accumulate_angle_joint(q, parent, child, nbar, bbar, j, d1, d2, grad, diag, pair,
                                          project, work, ctx.scale * budget[j])
