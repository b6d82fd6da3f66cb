"""Joint driving, libuipc UID 19 (docs/physics.md "Driving (UID 19)"): a spring on the joint
angle toward a target,

    E = K/2 (θ − θ_target)²,   K = γ (m_i + m_j),   E' = K (θ − θ_target),   E'' = K

for each enabled drive; θ is the unwrapped angle relative to init_angle (angles.py) and
θ_target the aim (relative to init_angle), or the angle at the start of the step when the
drive is passive. Like UID 18 it carries no h² (physical potential E/h²). Gradient and
PSD-projected Hessian via angles.accumulate_angle_hessian.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .. import angles


@njit(cache=True, error_model='numpy')
def energy(q, m, ctx):
    E = 0.0
    for k in range(m.drive_joints.size):
        if ctx.drive_on[k]:
            j = m.drive_joints[k]
            x = angles.unwrap(angles.theta(q, m, j), ctx.angle_start[j])
            e = x - ctx.drive_target[k]
            E += 0.5 * m.drive_K[k] * e * e
    return E


@njit(cache=True, error_model='numpy')
def accumulate(q, m, ctx, grad, diag, pair, project):
    D = m.drive_joints.size
    joints = np.empty(D, dtype=np.int64)
    d1s = np.empty(D)
    d2s = np.empty(D)
    n = 0
    for k in range(D):
        if ctx.drive_on[k]:
            j = m.drive_joints[k]
            x = angles.unwrap(angles.theta(q, m, j), ctx.angle_start[j])
            joints[n] = j
            d1s[n] = m.drive_K[k] * (x - ctx.drive_target[k])
            d2s[n] = m.drive_K[k]
            n += 1
    angles.accumulate_angle_hessian(q, m, joints, d1s, d2s, n, grad, diag, pair, project)
