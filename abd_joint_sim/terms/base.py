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


def add_pair_hessian(model, joints, H, diag, pair, cols):
    """Scatter per-joint Hessians over body pairs. `cols` are the 12-DOF columns covered:
    H is (n, 2*len(cols), 2*len(cols)) on [q_i[cols], q_j[cols]]."""
    m = len(cols)
    c = np.asarray(cols)
    pi, cj = model.joint_parent[joints], model.joint_child[joints]
    ix = np.ix_(c, c)
    blk = np.zeros((len(joints), 12, 12))
    blk[(slice(None),) + ix] = H[:, :m, :m]
    np.add.at(diag, pi, blk)
    blk[(slice(None),) + ix] = H[:, m:, m:]
    np.add.at(diag, cj, blk)
    blk[(slice(None),) + ix] = H[:, :m, m:]
    np.add.at(pair, joints, blk)


def add_pair_gradient(model, joints, g, grad, cols):
    m = len(cols)
    np.add.at(grad, (model.joint_parent[joints][:, None], np.asarray(cols)[None, :]), g[:, :m])
    np.add.at(grad, (model.joint_child[joints][:, None], np.asarray(cols)[None, :]), g[:, m:])


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
