"""Rigid-body geometry shared by the scene, the URDF reader and the model: rotations in the
URDF's roll-pitch-yaw convention, the cross-product matrix and an affine body's point Jacobian.
"""
from __future__ import annotations

import math

import numpy as np


def rpy_matrix(rpy) -> np.ndarray:
    """URDF convention: R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def skew(w) -> np.ndarray:
    """[w]x with [w]x v = w x v; batched over leading axes."""
    w = np.asarray(w, dtype=float)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -w[..., 2], w[..., 1]
    out[..., 1, 0], out[..., 1, 2] = w[..., 2], -w[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -w[..., 1], w[..., 0]
    return out


def point_jacobian(xbar) -> np.ndarray:
    """J(x̄) = [I3 | I3 ⊗ x̄ᵀ], shape (..., 3, 12)."""
    xbar = np.asarray(xbar, dtype=float)
    J = np.zeros(xbar.shape[:-1] + (3, 12))
    for r in range(3):
        J[..., r, r] = 1.0
        J[..., r, 3 + 3 * r:6 + 3 * r] = xbar
    return J


def matrix_rpy(R) -> tuple:
    """(roll, pitch, yaw) with ``rpy_matrix(rpy) == R`` (pitch in [-pi/2, pi/2])."""
    R = np.asarray(R, dtype=float)
    c = math.hypot(R[0, 0], R[1, 0])
    if not c > 1e-9:                        # gimbal lock: only roll -/+ yaw is defined
        return (0.0, math.atan2(-R[2, 0], c), math.atan2(-R[0, 1], R[1, 1]))
    return (math.atan2(R[2, 1], R[2, 2]), math.atan2(-R[2, 0], c), math.atan2(R[1, 0], R[0, 0]))


def axis_rotation(axis, angle) -> np.ndarray:
    """Right-hand rotation by `angle` about the unit `axis` (Rodrigues)."""
    K = skew(axis)
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
