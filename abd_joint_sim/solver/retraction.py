"""Screw retraction: apply a Newton step Δq to affine bodies along rigid motions.

Newton's step is linear in q = [p, A]; a body turning by δ rad under q + Δq is also
stretched by ~δ²/2. At everyday stiffness that stretch costs nothing, but at κ ≳ 1e11 the
ortho potential blocks the linear step, the line search cuts it, and Newton crawls along the
curved valley of rotations taking tiny steps that look converged (docs/studies.md §3,
fixed item 6; the Maratos effect of a stiff penalty on a curved constraint). So each
body's step is split into
    Δp = t,   ΔA = W A + D,   W = skew(ΔA A⁻¹)   (the spin of the velocity gradient)
and applied as the screw motion that (t, W) describe, plus the remaining deformation D:
    A' = exp(W) (A + D),   p' = c + exp(W)(p − c) + t∥
where c is the screw axis (the points whose first-order motion is along ω). A body turning
about a hinge is thus turned exactly about the hinge line and neither its shape nor the
joint is stretched. To first order q' = q + Δq, so Newton's fixed point and local
convergence are unchanged; the line search still only accepts decreases of Π.
The screw is meant for (nearly) rigid bodies: where A is far from a rotation
(max |A Aᵀ − I| > SCREW_STRAIN, e.g. a thin body's prediction sheared by a couple on its tiny
cross-section inertia) the step stays linear for that body. Measured on the 0.4 x 4e-4 m
rod of study/stability.py: screws from such states led Newton, from a prediction sheared
beyond recognition, to another local minimiser of Π (0.63 rad instead of 2e-4); at 1e-2
they are only used once the ortho term has pulled A back near SO(3).
A linear Newton step keeps the linear momentum of a free system exactly balanced (the sum
of ∂Π/∂p is linear in q); the screw's O(Δq²) turn would not, so within every group of
bodies joined to no fixed body the mass-weighted mean of that turn's translation is
removed (a rigid shift of the group: no joint or body is strained by it).
"""
from __future__ import annotations

import numpy as np

SCREW_STRAIN = 1e-2   # max |A Aᵀ − I| up to which a body's step is applied as a screw
# [rad] below: Taylor series of the screw coefficients to θ⁶ (truncation < 1e-21 relative);
# above, the closed forms lose ~eps/θ² to cancellation (< 3e-12 relative)
SMALL_ANGLE = 1e-2


def screw_coefficients(theta):
    """(sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ), accurate at θ → 0."""
    t2 = theta * theta
    small = theta < SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    s = np.where(small, 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0)), np.sin(safe) / safe)
    c = np.where(small, 0.5 - t2 / 24.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0)),
                 (1.0 - np.cos(safe)) / (safe * safe))
    b = np.where(small, t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0)), (safe - np.sin(safe)) / safe)
    return s, c, b


def floating_groups(model):
    """Per body, the index of its group of jointed bodies if no body of the group is fixed,
    else -1 (a fixed body takes up any momentum)."""
    B = model.body_count
    root = list(range(B))

    def find(i):
        while root[i] != i:
            root[i] = root[root[i]]
            i = root[i]
        return i

    for a, b in zip(model.joint_parent, model.joint_child):
        root[find(int(a))] = find(int(b))
    roots = np.array([find(i) for i in range(B)])
    anchored = set(roots[model.body_fixed].tolist())
    labels = {r: k for k, r in enumerate(sorted(set(roots.tolist()) - anchored))}
    return np.array([labels.get(r, -1) for r in roots.tolist()], dtype=np.int64)


class ScrewRetraction:
    """q ⊕ Δq for one model: the free bodies, their floating groups and masses."""

    def __init__(self, model):
        self.bodies = np.flatnonzero(~model.body_fixed)
        group = floating_groups(model)[self.bodies]
        self.floating = group >= 0
        self.group = group[self.floating]
        self.groups = int(self.group.max()) + 1 if len(self.group) else 0
        mass = model.body_mass[self.bodies][self.floating]
        self.share = mass / np.bincount(self.group, mass, self.groups)[self.group]

    def __call__(self, q, dq):
        return retract(q, dq, self.bodies, self)


def retract(q, dq, bodies, momentum=None):
    """q with the step dq applied to `bodies` as screw motions (module docstring); with
    `momentum` (a ScrewRetraction), each floating group's mean turn translation removed."""
    out = q + dq
    if len(bodies) == 0:
        return out
    A = q[bodies, 3:12].reshape(-1, 3, 3)
    rigid = np.abs(np.matmul(A, A.transpose(0, 2, 1)) - np.eye(3)).max(axis=(1, 2)) <= SCREW_STRAIN
    dA = dq[bodies, 3:12].reshape(-1, 3, 3) * rigid[:, None, None]
    t = dq[bodies, :3] * rigid[:, None]
    S = np.matmul(dA, np.linalg.inv(np.where(rigid[:, None, None], A, np.eye(3))))
    w = 0.5 * np.stack([S[:, 2, 1] - S[:, 1, 2], S[:, 0, 2] - S[:, 2, 0], S[:, 1, 0] - S[:, 0, 1]], axis=1)
    W = np.zeros_like(S)
    W[:, 2, 1], W[:, 1, 2] = w[:, 0], -w[:, 0]
    W[:, 0, 2], W[:, 2, 0] = w[:, 1], -w[:, 1]
    W[:, 1, 0], W[:, 0, 1] = w[:, 2], -w[:, 2]
    theta2 = np.sum(w * w, axis=1)
    theta = np.sqrt(theta2)
    s, c, b = screw_coefficients(theta)
    # exp(W)(A + D) − (A + ΔA) = −b W A + s W D + c W²(A + D) (Rodrigues, s − 1 = −b): added
    # to q + Δq as a correction of order θ², so that a tiny step rounds exactly like q + Δq
    WA = np.matmul(W, A)
    D = dA - WA
    corr = (-b[:, None, None] * WA + s[:, None, None] * np.matmul(W, D)
            + c[:, None, None] * np.matmul(W, np.matmul(W, A + D)))
    out[bodies, 3:12] += corr.reshape(-1, 9)
    # p' − p = t + (exp(W) − I − W)(p − c) = t + c(θ)·ω×t − b(θ)·t⊥, with W(p − c) = t⊥
    wt = np.sum(w * t, axis=1)
    t_perp = t - w * np.where(theta2 > 0, wt / np.where(theta2 > 0, theta2, 1.0), 0.0)[:, None]
    turn = c[:, None] * np.cross(w, t) - b[:, None] * t_perp
    if momentum is not None and momentum.groups:
        f = momentum.floating
        mean = np.zeros((momentum.groups, 3))
        np.add.at(mean, momentum.group, momentum.share[:, None] * turn[f])
        turn[f] -= mean[momentum.group]
    out[bodies, :3] += turn
    return out
