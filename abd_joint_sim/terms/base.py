"""The term contract, after libuipc's constitutions: one self-contained piece of physics.

An *energy term* adds to the incremental potential Π(q) its energy, gradient and
(PSD-projected) Hessian. Hessians are accumulated as 12x12 blocks: ``diag`` (B,12,12) per
body and ``pair`` (J,12,12) per joint for the (parent row, child column) block, which is
the block-sparsity pattern the linear solver factorises. A *force* (gravity, the UID 668
torque) has no energy and enters only the prediction q̃ (PHYSICS.md §2).
Terms are built from a Model by ``build(model)``, which returns None when the scene does not
use them, so a scene only instantiates what it needs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class StepContext:
    """What energy terms need besides q: fixed for the duration of one step."""

    h: float                        #: [s] step size
    joint_rel_start: np.ndarray     #: [rad] (J,) unwrapped angle minus init_angle at step start
    drive_target: np.ndarray        #: [rad] (D,) target relative angle (aim − init, or start angle if passive)
    drive_active: np.ndarray        #: (D,) bool


def project_psd(H: np.ndarray) -> np.ndarray:
    """Clamp negative eigenvalues of a batch of symmetric matrices to zero."""
    w, V = np.linalg.eigh(H)
    if np.all(w >= 0.0):
        return H
    return np.einsum('...ik,...k,...jk->...ij', V, np.maximum(w, 0.0), V)


class PairScatter:
    """Adds per-joint quantities on [q_i[cols], q_j[cols]] into per-body arrays.

    Built once per term: the parent/child incidence of its joints as sparse matrices, so
    one sparse-dense product replaces a scatter loop (np.add.at is ~10x slower here).
    """

    def __init__(self, model, joints, cols):
        import scipy.sparse
        self.joints = np.asarray(joints)
        self.cols = np.asarray(cols)
        self.m = len(cols)
        self.full = self.m == 12
        n, B = len(self.joints), model.body_count
        ones = np.ones(n)
        idx = np.arange(n)
        self.parent = scipy.sparse.csr_matrix((ones, (model.joint_parent[self.joints], idx)), shape=(B, n))
        self.child = scipy.sparse.csr_matrix((ones, (model.joint_child[self.joints], idx)), shape=(B, n))
        self.sl = slice(int(self.cols[0]), int(self.cols[-1]) + 1)
        assert np.array_equal(self.cols, np.arange(self.cols[0], self.cols[-1] + 1)), 'cols must be a range'

    def gradient(self, g, grad):
        """g (n, 2m) -> grad (B,12)."""
        m = self.m
        grad[:, self.sl] += self.parent @ g[:, :m] + self.child @ g[:, m:]

    def hessian(self, H, diag, pair):
        """H (n, 2m, 2m) -> diag (B,12,12) and pair (J,12,12) blocks."""
        m, n, sl = self.m, len(self.joints), self.sl
        Hpp = np.ascontiguousarray(H[:, :m, :m]).reshape(n, m * m)
        Hcc = np.ascontiguousarray(H[:, m:, m:]).reshape(n, m * m)
        add = (self.parent @ Hpp + self.child @ Hcc).reshape(-1, m, m)
        if self.full:
            diag += add
            pair[self.joints] += H[:, :m, m:]
        else:
            diag[:, sl, sl] += add
            pair[self.joints, sl, sl] += H[:, :m, m:]


class EnergyTerm:
    """Base class: subclasses set `name`, `uid` and implement `energy` and `accumulate`."""

    name = ''
    uid = 0

    def energy(self, q: np.ndarray, ctx: StepContext) -> float:
        raise NotImplementedError

    def accumulate(self, q, ctx, grad, diag, pair, project=True) -> None:
        """Add ∇E to grad (B,12) and the Hessian blocks to diag (B,12,12), pair (J,12,12)."""
        raise NotImplementedError

    def dense(self, model, q, ctx, project=True):
        """(E, ∇E (12B,), ∇²E (12B,12B)): for derivative checks and small dense solves."""
        B, J = model.body_count, model.joint_count
        grad, diag, pair = np.zeros((B, 12)), np.zeros((B, 12, 12)), np.zeros((J, 12, 12))
        self.accumulate(q, ctx, grad, diag, pair, project=project)
        H = np.zeros((12 * B, 12 * B))
        for b in range(B):
            H[12 * b:12 * b + 12, 12 * b:12 * b + 12] += diag[b]
        for j in range(J):
            p, c = model.joint_parent[j], model.joint_child[j]
            H[12 * p:12 * p + 12, 12 * c:12 * c + 12] += pair[j]
            H[12 * c:12 * c + 12, 12 * p:12 * p + 12] += pair[j].T
        return self.energy(q, ctx), grad.ravel(), H
