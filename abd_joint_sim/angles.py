"""Joint angle θ of revolute joints, shared by the torque, driving and limit terms.

PHYSICS.md §4: per body k the stored basis (n̄_k, b̄_k) is carried by A_k (no
normalisation), n_k = A_k n̄_k, b_k = A_k b̄_k, and

    cos θ = (n_i·n_j + b_i·b_j)/2,   sin θ = (b_i·n_j − n_i·b_j)/2,   θ = atan2(sin, cos).

Rotating the child by +φ about +t gives θ = +φ (n_j = cos φ n + sin φ b, b = t × n).
Derivatives are taken with respect to x = [vec A_i, vec A_j] (18,), vec = row-major, so
x maps onto q_i[3:12] and q_j[3:12]. c and s are bilinear in (A_i, A_j): their second
derivatives are zero within a body and ½ I3 ⊗ (outer products) across the pair.
"""
from __future__ import annotations

import numpy as np

TWO_PI = 2.0 * np.pi


def _frames(model, q, joints):
    A = q[:, 3:12].reshape(-1, 3, 3)
    Ai, Aj = A[model.joint_parent[joints]], A[model.joint_child[joints]]
    nbi, nbj = model.joint_nbar[joints, 0], model.joint_nbar[joints, 1]
    bbi, bbj = model.joint_bbar[joints, 0], model.joint_bbar[joints, 1]
    # columns 0, 1 of A @ [n̄ b̄]: both frame vectors in one batched product per body
    fi = np.matmul(Ai, np.stack([nbi, bbi], axis=2))
    fj = np.matmul(Aj, np.stack([nbj, bbj], axis=2))
    ni, bi, nj, bj = fi[:, :, 0], fi[:, :, 1], fj[:, :, 0], fj[:, :, 1]
    return (ni, nj, bi, bj), (nbi, nbj, bbi, bbj)


def _cos_sin(ni, nj, bi, bj):
    c = 0.5 * (np.einsum('jr,jr->j', ni, nj) + np.einsum('jr,jr->j', bi, bj))
    s = 0.5 * (np.einsum('jr,jr->j', bi, nj) - np.einsum('jr,jr->j', ni, bj))
    return c, s


def joint_theta(model, q, joints) -> np.ndarray:
    """Wrapped angle θ ∈ (−π, π] of the given joints, relative to the rest pose. (len(joints),)"""
    (ni, nj, bi, bj), _ = _frames(model, q, joints)
    c, s = _cos_sin(ni, nj, bi, bj)
    return np.arctan2(s, c)


def unwrap(theta, reference):
    """The branch of θ nearest to `reference`: reference + remainder(θ − reference, 2π)."""
    return reference + np.remainder(theta - reference + np.pi, TWO_PI) - np.pi


def _outer(u, v):
    return np.einsum('jr,jc->jrc', u, v).reshape(-1, 9)


def joint_theta_derivatives(model, q, joints, hessian=True):
    """θ (wrapped), dθ/dx (n,18) and, if asked, d²θ/dx² (n,18,18)."""
    (ni, nj, bi, bj), (nbi, nbj, bbi, bbj) = _frames(model, q, joints)
    c, s = _cos_sin(ni, nj, bi, bj)
    theta = np.arctan2(s, c)
    # ∂(A n̄)·w/∂A = w n̄ᵀ
    dc = 0.5 * np.concatenate([_outer(nj, nbi) + _outer(bj, bbi), _outer(ni, nbj) + _outer(bi, bbj)], axis=1)
    ds = 0.5 * np.concatenate([_outer(nj, bbi) - _outer(bj, nbi), _outer(bi, nbj) - _outer(ni, bbj)], axis=1)
    r2 = c * c + s * s
    N = c[:, None] * ds - s[:, None] * dc
    grad = N / r2[:, None]
    if not hessian:
        return theta, grad, None
    n = len(joints)
    eye = np.eye(3)
    # cross-body second derivatives (9x9): ½ I3 ⊗ (...)
    cc = 0.5 * (np.einsum('jc,jd->jcd', nbi, nbj) + np.einsum('jc,jd->jcd', bbi, bbj))
    ss = 0.5 * (np.einsum('jc,jd->jcd', bbi, nbj) - np.einsum('jc,jd->jcd', nbi, bbj))
    ddc = np.zeros((n, 18, 18))
    dds = np.zeros((n, 18, 18))
    ddc[:, :9, 9:] = np.einsum('rs,jcd->jrcsd', eye, cc).reshape(n, 9, 9)
    dds[:, :9, 9:] = np.einsum('rs,jcd->jrcsd', eye, ss).reshape(n, 9, 9)
    ddc[:, 9:, :9] = ddc[:, :9, 9:].transpose(0, 2, 1)
    dds[:, 9:, :9] = dds[:, :9, 9:].transpose(0, 2, 1)
    P = c[:, None] * dc + s[:, None] * ds
    hess = (np.einsum('ja,jb->jab', ds, dc) - np.einsum('ja,jb->jab', dc, ds)
            + c[:, None, None] * dds - s[:, None, None] * ddc) / r2[:, None, None] \
        - 2.0 * np.einsum('ja,jb->jab', N, P) / (r2 * r2)[:, None, None]
    hess = 0.5 * (hess + hess.transpose(0, 2, 1))   # exact analytically; remove roundoff asymmetry
    return theta, grad, hess
