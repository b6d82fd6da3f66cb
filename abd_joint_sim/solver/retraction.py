"""Screw retraction: apply a Newton step Δq to affine bodies along rigid motions
(docs/physics.md "Newton", the reasons in docs/decisions.md). Each body's step is split into

    Δp = t,   ΔA = W A + D,   W = skew(ΔA A⁻¹)   (the spin of the velocity gradient)

and applied as the screw motion of (t, W) plus the remaining deformation D:
A' = exp(W) (A + D), p' = c + exp(W)(p − c) + t∥ (c the screw axis); to first order
q' = q + Δq. Where max |A Aᵀ − I| > SCREW_STRAIN the body's step stays linear (the 0.4 x
4e-4 m rod of study/stability.py: screws from sheared states led Newton to another minimiser,
0.63 rad instead of 2e-4). Within every group of bodies joined to no fixed body the
mass-weighted mean of the screw's extra translation is removed (momentum stays balanced).
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import kernel
from ..smallmat import adjugate3, product3
from .linsolve import find_root

SCREW_STRAIN = 1e-2   # max |A Aᵀ − I| up to which a body's step is applied as a screw
# [rad] below: Taylor series of the screw coefficients to θ⁶ (truncation < 1e-21 relative);
# above, the closed forms lose ~eps/θ² to cancellation (< 3e-12 relative)
SMALL_ANGLE = 1e-2


def floating_groups(model):
    """Per body, the index of its group of jointed bodies if no body of the group is fixed,
    else -1 (a fixed body takes up any momentum)."""
    B = model.body_count
    root = list(range(B))
    for a, b in zip(model.joint_parent, model.joint_child):
        root[find_root(root, int(a))] = find_root(root, int(b))
    roots = np.array([find_root(root, i) for i in range(B)])
    anchored = set(roots[model.body_fixed].tolist())
    labels = {r: k for k, r in enumerate(sorted(set(roots.tolist()) - anchored))}
    return np.array([labels.get(r, -1) for r in roots.tolist()], dtype=np.int64)


def floating_groups_and_shares(model):
    """(group (B,), share (B,), group count): the floating group of each free body (-1 for
    fixed bodies and those jointed to one) and its mass share m_b / Σ m of the group."""
    group = floating_groups(model)
    groups, on, mass = int(group.max(initial=-1)) + 1, group >= 0, model.body_mass
    share = np.zeros(model.body_count)
    share[on] = mass[on] / np.bincount(group[on], mass[on], groups)[group[on]]
    return group, share, groups


@kernel
def screw_coefficients(th):
    """(sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ), accurate at θ → 0 (series below SMALL_ANGLE)."""
    th2 = th * th
    if th < SMALL_ANGLE:
        cb = th2 / 6.0 * (1.0 - th2 / 20.0 * (1.0 - th2 / 42.0))
        cs = 1.0 - cb
        cc = 0.5 - th2 / 24.0 * (1.0 - th2 / 30.0 * (1.0 - th2 / 56.0))
        return cs, cc, cb
    return math.sin(th) / th, (1.0 - math.cos(th)) / th2, (th - math.sin(th)) / th


@kernel
def retract(q, dq, alpha, m, ws, out):
    """out = q ⊕ α·dq: each free body moved along the screw motion of its step, the floating
    groups' mean turn translation removed (ws.group_mean). 3x3 matrices are 9-tuples of
    locals (smallmat.product3, adjugate3), kept in registers: the plain loops' bits."""
    free_idx, group, share, ngroups = m.free_bodies, m.body_group, m.group_share, m.group_count
    mean = ws.group_mean
    nf = len(free_idx)
    for g in range(ngroups):
        mean[g, 0] = mean[g, 1] = mean[g, 2] = 0.0
    for b in range(q.shape[0]):
        for r in range(12):
            out[b, r] = q[b, r] + alpha * dq[b, r]
    for k in range(nf):
        b = free_idx[k]
        strain = 0.0
        for i in range(3):
            for j in range(3):
                acc = -1.0 if i == j else 0.0
                for c in range(3):
                    acc += q[b, 3 + 3 * i + c] * q[b, 3 + 3 * j + c]
                strain = max(strain, abs(acc))
        if not strain <= SCREW_STRAIN:          # far from a rotation: the linear step
            continue
        # spin W = skew(ΔA A⁻¹) as the axial vector w; A⁻¹ = adj(A)/det A
        A = (q[b, 3], q[b, 4], q[b, 5], q[b, 6], q[b, 7], q[b, 8], q[b, 9], q[b, 10], q[b, 11])
        dA = (dq[b, 3], dq[b, 4], dq[b, 5], dq[b, 6], dq[b, 7], dq[b, 8], dq[b, 9], dq[b, 10], dq[b, 11])
        adj, det = adjugate3(A)
        P = product3(dA, adj)
        s01, s02, s10 = alpha * P[1] / det, alpha * P[2] / det, alpha * P[3] / det
        s12, s20, s21 = alpha * P[5] / det, alpha * P[6] / det, alpha * P[7] / det
        w0 = 0.5 * (s21 - s12)
        w1 = 0.5 * (s02 - s20)
        w2 = 0.5 * (s10 - s01)
        W = (0.0, -w2, w1, w2, 0.0, -w0, -w1, w0, 0.0)
        th2 = w0 * w0 + w1 * w1 + w2 * w2
        th = math.sqrt(th2)
        cs, cc, cb = screw_coefficients(th)
        # exp(W)(A + D) − (A + ΔA) = −b W A + s W D + c W²(A + D), D = ΔA − W A: added to
        # q + αΔq (retraction.py: a tiny step rounds like the linear one)
        WA = product3(W, A)
        D = (alpha * dA[0] - WA[0], alpha * dA[1] - WA[1], alpha * dA[2] - WA[2],
             alpha * dA[3] - WA[3], alpha * dA[4] - WA[4], alpha * dA[5] - WA[5],
             alpha * dA[6] - WA[6], alpha * dA[7] - WA[7], alpha * dA[8] - WA[8])
        WD = product3(W, D)
        Y = (WA[0] + WD[0], WA[1] + WD[1], WA[2] + WD[2], WA[3] + WD[3], WA[4] + WD[4],
             WA[5] + WD[5], WA[6] + WD[6], WA[7] + WD[7], WA[8] + WD[8])
        WY = product3(W, Y)
        for e in range(9):
            out[b, 3 + e] += -cb * WA[e] + cs * WD[e] + cc * WY[e]
        t0, t1, t2 = alpha * dq[b, 0], alpha * dq[b, 1], alpha * dq[b, 2]
        wt = w0 * t0 + w1 * t1 + w2 * t2
        f = wt / th2 if th2 > 0.0 else 0.0
        u0 = cc * (w1 * t2 - w2 * t1) - cb * (t0 - w0 * f)
        u1 = cc * (w2 * t0 - w0 * t2) - cb * (t1 - w1 * f)
        u2 = cc * (w0 * t1 - w1 * t0) - cb * (t2 - w2 * f)
        out[b, 0] += u0
        out[b, 1] += u1
        out[b, 2] += u2
        g = group[b]
        if g >= 0:
            mean[g, 0] += share[b] * u0
            mean[g, 1] += share[b] * u1
            mean[g, 2] += share[b] * u2
    if ngroups > 0:
        for k in range(nf):
            b = free_idx[k]
            g = group[b]
            if g >= 0:
                for r in range(3):
                    out[b, r] -= mean[g, r]
