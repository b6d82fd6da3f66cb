"""Joint angle θ of a revolute joint, shared by UID 668 (angle readout), UID 19 and UID 670
(docs/physics.md "Joint angle").

Per body k the stored basis (n̄_k, b̄_k) is carried by A_k (not normalised):
n_k = A_k n̄_k, b_k = A_k b̄_k, and

    cos θ = (n_i·n_j + b_i·b_j)/2,   sin θ = (b_i·n_j − n_i·b_j)/2,   θ = atan2(sin, cos).

Rotating the child by +φ about +t = (P1 − P0)/|P1 − P0| gives θ = +φ (b = t × n).
Derivatives are taken with respect to x = [vec A_i, vec A_j] (18,), vec = row-major, so x
maps onto q_i[3:12] and q_j[3:12]. c and s are bilinear in (A_i, A_j): their second
derivatives are zero within a body and ½ I3 ⊗ (outer products) across the pair.
`unwrap` picks the branch of θ nearest to the previous step's angle (multi-turn angle).
`accumulate_angle_hessian` adds the gradient and PSD-projected Hessian of any E(θ), the
shared part of UID 19 and UID 670.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .smallmat import eigh_ql

TWO_PI = 2.0 * np.pi
# [rad] Far from its minimum, E'∇²θ (the curvature of the angle itself) misleads Newton: θ is
# atan2 of two quantities bilinear in (A_i, A_j), so E'∇²θ has directions of negative
# curvature that shear and shrink A rather than turn it, and a stiff drive asked to turn
# 0.3 rad in one step made Newton crawl into singular A (issue 15). Where |E'/E''| (the
# distance to a drive's target) exceeds this, the Hessian is the Gauss-Newton E''∇θ∇θᵀ:
# PSD, and with the screw retraction it turns the body. Near the minimum E'∇²θ is kept
# (fast local convergence); the gradient, and so Newton's answer, is the same either way.
GAUSS_NEWTON_RANGE = 0.1
WORK_SHAPE = (8, 18)     #: work array of theta_derivatives_at


@njit(cache=True, error_model='numpy')
def unwrap(theta, reference):
    """The branch of θ nearest to `reference`: reference + ((θ − reference + π) mod 2π) − π
    (Python's float % has the sign of 2π, like numpy's remainder)."""
    return reference + (theta - reference + np.pi) % TWO_PI - np.pi


@njit(cache=True, error_model='numpy')
def frames(q, i_body, j_body, nbar, bbar, j, fr):
    """fr[0..3] = n_i, n_j, b_i, b_j of joint j in world axes (nbar, bbar = m.joint_nbar,
    m.joint_bbar: the functions ending in `_at` take the model's arrays, not m, because they
    run once per joint and a structref field lookup in such a loop costs more than the math)."""
    for r in range(3):
        ni = nj = bi = bj = 0.0
        for c in range(3):
            Ai = q[i_body, 3 + 3 * r + c]
            Aj = q[j_body, 3 + 3 * r + c]
            ni += Ai * nbar[j, 0, c]
            bi += Ai * bbar[j, 0, c]
            nj += Aj * nbar[j, 1, c]
            bj += Aj * bbar[j, 1, c]
        fr[0, r] = ni
        fr[1, r] = nj
        fr[2, r] = bi
        fr[3, r] = bj


@njit(cache=True, error_model='numpy')
def cos_sin(fr):
    """(cos θ, sin θ) of the frames (not normalised: |(c, s)| = 1 only for rigid A)."""
    c = 0.5 * ((fr[0, 0] * fr[1, 0] + fr[0, 1] * fr[1, 1] + fr[0, 2] * fr[1, 2])
               + (fr[2, 0] * fr[3, 0] + fr[2, 1] * fr[3, 1] + fr[2, 2] * fr[3, 2]))
    s = 0.5 * ((fr[2, 0] * fr[1, 0] + fr[2, 1] * fr[1, 1] + fr[2, 2] * fr[1, 2])
               - (fr[0, 0] * fr[3, 0] + fr[0, 1] * fr[3, 1] + fr[0, 2] * fr[3, 2]))
    return c, s


@njit(cache=True, error_model='numpy')
def theta(q, m, j):
    """Wrapped θ ∈ (−π, π] of joint j, relative to the rest pose."""
    return theta_at(q, m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar, j)


@njit(cache=True, error_model='numpy')
def theta_at(q, parent, child, nbar, bbar, j):
    """θ of joint j from the frames' dot products, without a work array."""
    i_body, j_body = parent[j], child[j]
    ninj = bibj = binj = nibj = 0.0
    for r in range(3):
        ni = nj = bi = bj = 0.0
        for c in range(3):
            Ai = q[i_body, 3 + 3 * r + c]
            Aj = q[j_body, 3 + 3 * r + c]
            ni += Ai * nbar[j, 0, c]
            bi += Ai * bbar[j, 0, c]
            nj += Aj * nbar[j, 1, c]
            bj += Aj * bbar[j, 1, c]
        ninj += ni * nj
        bibj += bi * bj
        binj += bi * nj
        nibj += ni * bj
    return math.atan2(0.5 * (binj - nibj), 0.5 * (ninj + bibj))


@njit(cache=True, error_model='numpy')
def theta_derivatives(q, m, j, grad, hess, want_hess):
    """See theta_derivatives_at."""
    return theta_derivatives_at(q, m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar, j,
                                grad, hess, want_hess, np.empty(WORK_SHAPE))


@njit(cache=True, error_model='numpy')
def theta_derivatives_at(q, parent, child, nbar, bbar, j, grad, hess, want_hess, work):
    """Wrapped θ of joint j; fills grad = ∇θ (18,) and, if want_hess, hess = ∇²θ (18,18),
    w.r.t. [vec A_i, vec A_j]. With N = c ∇s − s ∇c, P = c ∇c + s ∇s, r² = c² + s²:
    ∇θ = N / r², ∇²θ = (∇s ∇cᵀ − ∇c ∇sᵀ + c ∇²s − s ∇²c)/r² − 2 N Pᵀ / r⁴ (symmetrised)."""
    # work rows: 0-3 the frames, 4 ∇c, 5 ∇s, 6 N, 7 P (a per-joint loop allocates it once)
    fr = work[0:4, 0:3]
    frames(q, parent[j], child[j], nbar, bbar, j, fr)
    c, s = cos_sin(fr)
    th = math.atan2(s, c)
    dc = work[4]
    ds = work[5]
    nbi, nbj = nbar[j, 0], nbar[j, 1]
    bbi, bbj = bbar[j, 0], bbar[j, 1]
    for r in range(3):                     # ∂(A n̄)·w/∂A = w n̄ᵀ
        for k in range(3):
            dc[3 * r + k] = 0.5 * (fr[1, r] * nbi[k] + fr[3, r] * bbi[k])
            dc[9 + 3 * r + k] = 0.5 * (fr[0, r] * nbj[k] + fr[2, r] * bbj[k])
            ds[3 * r + k] = 0.5 * (fr[1, r] * bbi[k] - fr[3, r] * nbi[k])
            ds[9 + 3 * r + k] = 0.5 * (fr[2, r] * nbj[k] - fr[0, r] * bbj[k])
    r2 = c * c + s * s
    N = work[6]
    for a in range(18):
        N[a] = c * ds[a] - s * dc[a]
        grad[a] = N[a] / r2
    if not want_hess:
        return th
    P = work[7]
    for a in range(18):
        P[a] = c * dc[a] + s * ds[a]
    rr = r2 * r2
    for a in range(18):
        for b in range(18):
            hess[a, b] = (ds[a] * dc[b] - dc[a] * ds[b]) / r2 - 2.0 * N[a] * P[b] / rr
    for k in range(3):                     # cross-body ∇²c, ∇²s = ½ I3 ⊗ (...)
        for d in range(3):
            cc = 0.5 * (nbi[k] * nbj[d] + bbi[k] * bbj[d])
            ss = 0.5 * (bbi[k] * nbj[d] - nbi[k] * bbj[d])
            extra = (c * ss - s * cc) / r2
            for r in range(3):
                hess[3 * r + k, 9 + 3 * r + d] += extra
                hess[9 + 3 * r + d, 3 * r + k] += extra
    for a in range(18):                    # exact analytically; remove round-off asymmetry
        for b in range(a + 1, 18):
            h = 0.5 * (hess[a, b] + hess[b, a])
            hess[a, b] = h
            hess[b, a] = h
    return th


@njit(cache=True, error_model='numpy')
def theta_and_slope_at(q, d_plus, d_minus, parent, child, nbar, bbar, j):
    """(wrapped θ, ∇θ(q)·d) of joint j along the direction d = d_plus − d_minus in q[3:12]
    (pass a zero array as d_minus for d = d_plus): θ = atan2(s, c) of cos_sin_slope_at."""
    c, s, slope = cos_sin_slope_at(q, d_plus, d_minus, parent, child, nbar, bbar, j)
    return math.atan2(s, c), slope


@njit(cache=True, error_model='numpy', inline='always')
def cos_sin_slope_at(q, d_plus, d_minus, parent, child, nbar, bbar, j):
    """(c, s, ∇θ(q)·d) of joint j along d = d_plus − d_minus, without θ itself (no atan2: the
    predicted rotation needs the slope only). Computed without forming ∇θ:
    dθ = (c ds − s dc)/(c² + s²), with dc, ds the derivatives of c, s along d, e.g.
    dc = ½(Δn_i·n_j + n_i·Δn_j + Δb_i·b_j + b_i·Δb_j), Δn_k = ΔA_k n̄_k."""
    i_body, j_body = parent[j], child[j]
    ninj = bibj = binj = nibj = 0.0
    dc = ds = 0.0
    for r in range(3):
        ni = nj = bi = bj = 0.0
        dni = dnj = dbi = dbj = 0.0
        for c in range(3):
            Ai = q[i_body, 3 + 3 * r + c]
            Aj = q[j_body, 3 + 3 * r + c]
            dAi = d_plus[i_body, 3 + 3 * r + c] - d_minus[i_body, 3 + 3 * r + c]
            dAj = d_plus[j_body, 3 + 3 * r + c] - d_minus[j_body, 3 + 3 * r + c]
            ni += Ai * nbar[j, 0, c]
            bi += Ai * bbar[j, 0, c]
            nj += Aj * nbar[j, 1, c]
            bj += Aj * bbar[j, 1, c]
            dni += dAi * nbar[j, 0, c]
            dbi += dAi * bbar[j, 0, c]
            dnj += dAj * nbar[j, 1, c]
            dbj += dAj * bbar[j, 1, c]
        ninj += ni * nj
        bibj += bi * bj
        binj += bi * nj
        nibj += ni * bj
        dc += dni * nj + ni * dnj + dbi * bj + bi * dbj
        ds += dbi * nj + bi * dnj - dni * bj - ni * dbj
    cs = 0.5 * (ninj + bibj)
    sn = 0.5 * (binj - nibj)
    return cs, sn, 0.5 * (cs * ds - sn * dc) / (cs * cs + sn * sn)


@njit(cache=True, error_model='numpy')
def accumulate_angle_hessian(q, m, joints, d1s, d2s, n, grad, diag, pair, project):
    """For the n joints `joints[:n]` of one term with E'(θ), E''(θ) in d1s, d2s: adds
    ∇E = E'∇θ to grad and H = E''∇θ∇θᵀ + E'∇²θ to the blocks on q[3:12]. With `project`,
    a joint with |E'| > GAUSS_NEWTON_RANGE·E'' gets H = E''∇θ∇θᵀ (PSD) instead, and H is
    PSD-projected as a batch (kept as is when every eigenvalue of the batch is ≥ 0,
    else negative eigenvalues clamped to 0). θ depends on A_k only through A_k n̄_k and
    A_k b̄_k, so H's range lies in the 12-dim span of Q = diag(I3 ⊗ [n̄_i b̄_i], I3 ⊗ [n̄_j b̄_j])
    (orthonormal columns): the eigenproblem is solved on QᵀHQ (12x12)."""
    if n == 0:
        return
    parent, child, nbar, bbar = m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar
    G = np.empty((n, 18))
    H = np.empty((n, 18, 18))
    hh = np.empty((18, 18))
    Q = np.zeros((n, 18, 12))
    Hs = np.empty((n, 12, 12))
    W = np.empty((n, 12))
    V = np.empty((n, 12, 12))
    tmp = np.empty((18, 12))
    work = np.empty(WORK_SHAPE)
    all_psd = True
    is_psd = np.zeros(n, dtype=np.bool_)    # H[k] PSD by construction (kept as is)
    for k in range(n):
        j = joints[k]
        theta_derivatives_at(q, parent, child, nbar, bbar, j, G[k], hh, True, work)
        gauss_newton = project and abs(d1s[k]) > GAUSS_NEWTON_RANGE * d2s[k]
        curvature = 0.0 if gauss_newton else d1s[k]
        for a in range(18):
            for b in range(18):
                H[k, a, b] = d2s[k] * (G[k, a] * G[k, b]) + curvature * hh[a, b]
        if not project:
            continue
        if gauss_newton and d2s[k] >= 0.0:      # E''∇θ∇θᵀ is PSD: nothing to project
            is_psd[k] = True
            continue
        for side in range(2):
            for r in range(3):
                for c in range(3):
                    Q[k, 9 * side + 3 * r + c, 6 * side + 2 * r] = nbar[j, side, c]
                    Q[k, 9 * side + 3 * r + c, 6 * side + 2 * r + 1] = bbar[j, side, c]
        for a in range(18):
            for l in range(12):
                acc = 0.0
                for b in range(18):
                    acc += H[k, a, b] * Q[k, b, l]
                tmp[a, l] = acc
        for l in range(12):
            for l2 in range(l, 12):
                acc = 0.0
                for a in range(18):
                    acc += Q[k, a, l] * tmp[a, l2]
                Hs[k, l, l2] = acc
                Hs[k, l2, l] = acc
        eigh_ql(Hs[k], W[k], V[k])
        for l in range(12):
            if not W[k, l] >= 0.0:
                all_psd = False
    if project and not all_psd:
        for k in range(n):
            if is_psd[k]:
                continue
            for l in range(12):             # V <- Q V, H = Σ max(w, 0) v vᵀ
                for a in range(18):
                    acc = 0.0
                    for l2 in range(12):
                        acc += Q[k, a, l2] * V[k, l2, l]
                    tmp[a, l] = acc
            for a in range(18):
                for b in range(a, 18):
                    acc = 0.0
                    for l in range(12):
                        acc += tmp[a, l] * max(W[k, l], 0.0) * tmp[b, l]
                    H[k, a, b] = acc
                    H[k, b, a] = acc
    for k in range(n):
        j = joints[k]
        i_body, j_body = parent[j], child[j]
        for a in range(9):
            grad[i_body, 3 + a] += d1s[k] * G[k, a]
            grad[j_body, 3 + a] += d1s[k] * G[k, 9 + a]
            for b in range(9):
                diag[i_body, 3 + a, 3 + b] += H[k, a, b]
                diag[j_body, 3 + a, 3 + b] += H[k, 9 + a, 9 + b]
                pair[j, 3 + a, 3 + b] += H[k, a, 9 + b]


@njit(cache=True, error_model='numpy')
def accumulate_angle_gradient(q, m, joints, d1s, n, grad):
    """∇E = E'∇θ of accumulate_angle_hessian alone (Newton with a reused factorisation)."""
    if n == 0:
        return
    parent, child, nbar, bbar = m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar
    G = np.empty(18)
    work = np.empty(WORK_SHAPE)
    for k in range(n):
        j = joints[k]
        theta_derivatives_at(q, parent, child, nbar, bbar, j, G, G.reshape((3, 6)), False, work)
        i_body, j_body = parent[j], child[j]
        for a in range(9):
            grad[i_body, 3 + a] += d1s[k] * G[a]
            grad[j_body, 3 + a] += d1s[k] * G[9 + a]
