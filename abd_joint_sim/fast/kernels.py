"""numba kernels: one whole (sub-)step of `World._single`, term by term as in the numpy core.

Every function mirrors a numpy reference (named in its docstring) with scalar loops instead
of batched array calls; the arithmetic is the same, only summation order and LAPACK call
shapes differ (round-off level). All kernels are ``njit(cache=True)``: compiled once per
machine into ``__pycache__`` beside this file (or numba's user cache when that is read-only).

The model is passed packed (`step.pack_model`): one int64 and one float64 vector whose layout
`unpack` reads back into views, because each array argument of a numba call costs ~0.15 µs
to unbox and a step has a budget of a few µs.

Status codes (solver/newton.py `Status`): 0 converged, 1 max_iterations,
2 line_search_failed, 3 nonfinite.

Header slots beyond the model sizes: mi[12] = number of floating groups
(solver/retraction.py), mi[11] = may_split (World._single's flag: `step.py`
keeps one int vector per value, so the kernel's signature and `fast.warm_up` stay as they
are), mf[5] = Σ m_b over free bodies (Newton's energy_tol), mf[6] = newton.max_step_rotation.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

CONVERGED, MAX_ITERATIONS, LINE_SEARCH_FAILED, NONFINITE = 0, 1, 2, 3
ROUNDOFF = 1e-12            # solver/newton.py ROUNDOFF (checked equal by the tests)
SINGULAR_RATIO = 1e-6       # terms/forces.py SINGULAR_RATIO (checked equal by the tests)
TWO_PI = 2.0 * np.pi
HEADER_INTS = 16
HEADER_FLOATS = 8
KIND_DENSE, KIND_TREE = 0, 1
MI_MAY_SPLIT = 11           # mi slot of the may_split flag
POST_OK, POST_NEWTON_NONFINITE, POST_STEP_NONFINITE, POST_PREDICTED_SPLIT = 0, 1, 2, 3
SMALL_ANGLE = 1e-2          # solver/retraction.py SMALL_ANGLE (checked equal by the tests)
SCREW_STRAIN = 1e-2         # solver/retraction.py SCREW_STRAIN (checked equal by the tests)
AXIS_EPS = 1e-12            # terms/forces.py ExternalTorque.axes: raw axis unusable below this


# --------------------------------------------------------------------------- layout
@njit(cache=True, error_model='numpy')
def unpack(mi, mf):
    """Views of the packed model (layout written by `step.pack_model`)."""
    B, J, T, D, L, nf, kind, max_it = mi[0], mi[1], mi[2], mi[3], mi[4], mi[5], mi[6], mi[7]
    ls_max, has_grav, E = mi[8], mi[9], mi[10]
    o = HEADER_INTS
    fixed = mi[o:o + B]; o += B
    jp = mi[o:o + J]; o += J
    jc = mi[o:o + J]; o += J
    tj = mi[o:o + T]; o += T
    dj = mi[o:o + D]; o += D
    lj = mi[o:o + L]; o += L
    free_idx = mi[o:o + nf]; o += nf
    slot = mi[o:o + B]; o += B
    order = mi[o:o + nf]; o += nf
    eparent = mi[o:o + nf]; o += nf
    edge_ptr = mi[o:o + nf + 1]; o += nf + 1
    edge_joint = mi[o:o + E]; o += E
    pair_joints = mi[o:o + J]; o += J          # 1 where both bodies are free
    group = mi[o:o + B]; o += B                # retraction.floating_groups (-1: anchored)
    f = HEADER_FLOATS
    M = mf[f:f + 144 * B].reshape((B, 12, 12)); f += 144 * B
    Minv = mf[f:f + 144 * B].reshape((B, 12, 12)); f += 144 * B
    weight = mf[f:f + B]; f += B
    corners = mf[f:f + 24 * B].reshape((B, 8, 3)); f += 24 * B
    xbar = mf[f:f + 12 * J].reshape((J, 2, 2, 3)); f += 12 * J      # [joint, side, anchor, xyz]
    K = mf[f:f + J]; f += J
    Hj = mf[f:f + 576 * J].reshape((J, 24, 24)); f += 576 * J
    nbar = mf[f:f + 6 * J].reshape((J, 2, 3)); f += 6 * J
    bbar = mf[f:f + 6 * J].reshape((J, 2, 3)); f += 6 * J
    init = mf[f:f + J]; f += J
    dK = mf[f:f + D]; f += D
    lo = mf[f:f + L]; f += L
    up = mf[f:f + L]; f += L
    lstr = mf[f:f + L]; f += L
    share = mf[f:f + B]; f += B                # m_b / Σ m of its floating group
    return (B, J, T, D, L, nf, kind, max_it, ls_max, has_grav, fixed, jp, jc, tj, dj, lj,
            free_idx, slot, order, eparent, edge_ptr, edge_joint, pair_joints, group,
            M, Minv, weight, corners, xbar, K, Hj, nbar, bbar, init, dK, lo, up, lstr, share)


# --------------------------------------------------------------------------- joint angle
@njit(cache=True, error_model='numpy')
def unwrap(theta, ref):
    """angles.unwrap: ref + remainder(θ − ref + π, 2π) − π (numpy's remainder: sign of 2π)."""
    return ref + (theta - ref + np.pi) % TWO_PI - np.pi     # float % is numpy's remainder


@njit(cache=True, error_model='numpy')
def _frames(q, pb, cb, nbar, bbar, j, fr):
    """fr[0..3] = n_i, n_j, b_i, b_j (angles._frames)."""
    for r in range(3):
        ni = nj = bi = bj = 0.0
        for c in range(3):
            Ai = q[pb, 3 + 3 * r + c]
            Aj = q[cb, 3 + 3 * r + c]
            ni += Ai * nbar[j, 0, c]
            bi += Ai * bbar[j, 0, c]
            nj += Aj * nbar[j, 1, c]
            bj += Aj * bbar[j, 1, c]
        fr[0, r] = ni
        fr[1, r] = nj
        fr[2, r] = bi
        fr[3, r] = bj


@njit(cache=True, error_model='numpy')
def _cos_sin(fr):
    c = 0.5 * ((fr[0, 0] * fr[1, 0] + fr[0, 1] * fr[1, 1] + fr[0, 2] * fr[1, 2])
               + (fr[2, 0] * fr[3, 0] + fr[2, 1] * fr[3, 1] + fr[2, 2] * fr[3, 2]))
    s = 0.5 * ((fr[2, 0] * fr[1, 0] + fr[2, 1] * fr[1, 1] + fr[2, 2] * fr[1, 2])
               - (fr[0, 0] * fr[3, 0] + fr[0, 1] * fr[3, 1] + fr[0, 2] * fr[3, 2]))
    return c, s


@njit(cache=True, error_model='numpy')
def joint_theta(q, jp, jc, nbar, bbar, j):
    """angles.joint_theta for one joint: wrapped θ."""
    fr = np.empty((4, 3))
    _frames(q, jp[j], jc[j], nbar, bbar, j, fr)
    c, s = _cos_sin(fr)
    return math.atan2(s, c)


@njit(cache=True, error_model='numpy')
def joint_theta_derivatives(q, jp, jc, nbar, bbar, j, grad, hess, want_hess):
    """angles.joint_theta_derivatives for one joint: returns θ; fills grad (18,) and, if
    want_hess, hess (18,18), w.r.t. [vec A_i, vec A_j] (row-major)."""
    fr = np.empty((4, 3))
    _frames(q, jp[j], jc[j], nbar, bbar, j, fr)
    c, s = _cos_sin(fr)
    theta = math.atan2(s, c)
    dc = np.empty(18)
    ds = np.empty(18)
    nbi, nbj, bbi, bbj = nbar[j, 0], nbar[j, 1], bbar[j, 0], bbar[j, 1]
    for r in range(3):
        for k in range(3):
            dc[3 * r + k] = 0.5 * (fr[1, r] * nbi[k] + fr[3, r] * bbi[k])
            dc[9 + 3 * r + k] = 0.5 * (fr[0, r] * nbj[k] + fr[2, r] * bbj[k])
            ds[3 * r + k] = 0.5 * (fr[1, r] * bbi[k] - fr[3, r] * nbi[k])
            ds[9 + 3 * r + k] = 0.5 * (fr[2, r] * nbj[k] - fr[0, r] * bbj[k])
    r2 = c * c + s * s
    N = np.empty(18)
    for a in range(18):
        N[a] = c * ds[a] - s * dc[a]
        grad[a] = N[a] / r2
    if not want_hess:
        return theta
    P = np.empty(18)
    for a in range(18):
        P[a] = c * dc[a] + s * ds[a]
    rr = r2 * r2
    for a in range(18):
        for b in range(18):
            hess[a, b] = (ds[a] * dc[b] - dc[a] * ds[b]) / r2 - 2.0 * N[a] * P[b] / rr
    # cross-body second derivatives ½ I3 ⊗ (...) of c and s
    for k in range(3):
        for d in range(3):
            cc = 0.5 * (nbi[k] * nbj[d] + bbi[k] * bbj[d])
            ss = 0.5 * (bbi[k] * nbj[d] - nbi[k] * bbj[d])
            extra = (c * ss - s * cc) / r2
            for r in range(3):
                hess[3 * r + k, 9 + 3 * r + d] += extra
                hess[9 + 3 * r + d, 3 * r + k] += extra
    for a in range(18):
        for b in range(a + 1, 18):
            m = 0.5 * (hess[a, b] + hess[b, a])
            hess[a, b] = m
            hess[b, a] = m
    return theta


# --------------------------------------------------------------------------- ortho (UID 1)
@njit(cache=True, error_model='numpy')
def svd3(A, U, S, V):
    """A = U diag(S) Vᵀ for a 3x3 A (S ≥ 0 descending, U, V orthonormal): cyclic Jacobi on
    AᵀA for V, then U from a Gram-Schmidt QR of A V (u3 = u1 × u2), so tiny singular values
    keep full absolute accuracy. ~50x cheaper than a LAPACK call for a 3x3."""
    Bm = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            Bm[r, c] = A[0, r] * A[0, c] + A[1, r] * A[1, c] + A[2, r] * A[2, c]
            V[r, c] = 1.0 if r == c else 0.0
    for sweep in range(12):
        off = Bm[0, 1] * Bm[0, 1] + Bm[0, 2] * Bm[0, 2] + Bm[1, 2] * Bm[1, 2]
        dia = Bm[0, 0] * Bm[0, 0] + Bm[1, 1] * Bm[1, 1] + Bm[2, 2] * Bm[2, 2]
        if off <= 1e-32 * dia:
            break
        for pq in range(3):
            p = 0 if pq < 2 else 1
            qq = 1 if pq == 0 else 2
            apq = Bm[p, qq]
            if apq == 0.0:
                continue
            tau = (Bm[qq, qq] - Bm[p, p]) / (2.0 * apq)
            t = 1.0 / (abs(tau) + math.sqrt(1.0 + tau * tau))
            if tau < 0.0:
                t = -t
            c = 1.0 / math.sqrt(1.0 + t * t)
            sn = t * c
            for k in range(3):                       # B <- Jᵀ B J, V <- V J
                bkp, bkq = Bm[k, p], Bm[k, qq]
                Bm[k, p] = c * bkp - sn * bkq
                Bm[k, qq] = sn * bkp + c * bkq
            for k in range(3):
                bpk, bqk = Bm[p, k], Bm[qq, k]
                Bm[p, k] = c * bpk - sn * bqk
                Bm[qq, k] = sn * bpk + c * bqk
            for k in range(3):
                vkp, vkq = V[k, p], V[k, qq]
                V[k, p] = c * vkp - sn * vkq
                V[k, qq] = sn * vkp + c * vkq
            Bm[p, qq] = 0.0
            Bm[qq, p] = 0.0
    # order by decreasing eigenvalue (insertion sort of 3, columns of V follow)
    for i in range(1, 3):
        k = i
        while k > 0 and Bm[k, k] > Bm[k - 1, k - 1]:
            tmp = Bm[k, k]
            Bm[k, k] = Bm[k - 1, k - 1]
            Bm[k - 1, k - 1] = tmp
            for r in range(3):
                tmp = V[r, k]
                V[r, k] = V[r, k - 1]
                V[r, k - 1] = tmp
            k -= 1
    b = np.empty((3, 3))                              # columns A v_k
    for k in range(3):
        for r in range(3):
            b[r, k] = A[r, 0] * V[0, k] + A[r, 1] * V[1, k] + A[r, 2] * V[2, k]
    s0 = math.sqrt(b[0, 0] * b[0, 0] + b[1, 0] * b[1, 0] + b[2, 0] * b[2, 0])
    if s0 > 0.0:
        for r in range(3):
            U[r, 0] = b[r, 0] / s0
    else:
        U[0, 0], U[1, 0], U[2, 0] = 1.0, 0.0, 0.0
    d = U[0, 0] * b[0, 1] + U[1, 0] * b[1, 1] + U[2, 0] * b[2, 1]
    for r in range(3):
        b[r, 1] -= d * U[r, 0]
    s1 = math.sqrt(b[0, 1] * b[0, 1] + b[1, 1] * b[1, 1] + b[2, 1] * b[2, 1])
    if s1 > 1e-300:
        for r in range(3):
            U[r, 1] = b[r, 1] / s1
    else:                                             # any unit vector ⟂ u1
        k = 0
        if abs(U[1, 0]) < abs(U[k, 0]):
            k = 1
        if abs(U[2, 0]) < abs(U[k, 0]):
            k = 2
        e0, e1, e2 = (1.0 if k == 0 else 0.0), (1.0 if k == 1 else 0.0), (1.0 if k == 2 else 0.0)
        w0 = U[1, 0] * e2 - U[2, 0] * e1
        w1 = U[2, 0] * e0 - U[0, 0] * e2
        w2 = U[0, 0] * e1 - U[1, 0] * e0
        wn = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        U[0, 1], U[1, 1], U[2, 1] = w0 / wn, w1 / wn, w2 / wn
    U[0, 2] = U[1, 0] * U[2, 1] - U[2, 0] * U[1, 1]
    U[1, 2] = U[2, 0] * U[0, 1] - U[0, 0] * U[2, 1]
    U[2, 2] = U[0, 0] * U[1, 1] - U[1, 0] * U[0, 1]
    s2 = U[0, 2] * b[0, 2] + U[1, 2] * b[1, 2] + U[2, 2] * b[2, 2]
    if s2 < 0.0:
        s2 = -s2
        for r in range(3):
            U[r, 2] = -U[r, 2]
    S[0], S[1], S[2] = s0, s1, s2


@njit(cache=True, error_model='numpy')
def ortho_energy(q, free_idx, weight, h):
    """OrthoPotential.energy: h² Σ κv̄ ‖AAᵀ − I‖²_F over free bodies."""
    E = 0.0
    for k in range(free_idx.size):
        b = free_idx[k]
        acc = 0.0
        for r in range(3):
            for c in range(3):
                v = (q[b, 3 + 3 * r] * q[b, 3 + 3 * c] + q[b, 4 + 3 * r] * q[b, 4 + 3 * c]
                     + q[b, 5 + 3 * r] * q[b, 5 + 3 * c])
                if r == c:
                    v -= 1.0
                acc += v * v
        E += weight[b] * acc
    return h * h * E


@njit(cache=True, error_model='numpy')
def ortho_accumulate(q, free_idx, weight, h, grad, diag):
    """OrthoPotential.accumulate with `projected_hessian`: gradient 4h²κv̄ C A and the PSD
    projection of the Hessian from the analytic eigensystem of A = U Σ Vᵀ."""
    A = np.empty((3, 3))
    C = np.empty((3, 3))
    vecs = np.empty((9, 9))
    lam = np.empty(9)
    U = np.empty((3, 3))
    S = np.empty(3)
    V = np.empty((3, 3))
    r2 = math.sqrt(0.5)
    for k in range(free_idx.size):
        b = free_idx[k]
        for r in range(3):
            for c in range(3):
                A[r, c] = q[b, 3 + 3 * r + c]
        for r in range(3):
            for c in range(3):
                C[r, c] = A[r, 0] * A[c, 0] + A[r, 1] * A[c, 1] + A[r, 2] * A[c, 2]
            C[r, r] -= 1.0
        w = 4.0 * h * h * weight[b]
        for r in range(3):
            for c in range(3):
                grad[b, 3 + 3 * r + c] += w * (C[r, 0] * A[0, c] + C[r, 1] * A[1, c] + C[r, 2] * A[2, c])
        svd3(A, U, S, V)
        # P_ij = vec(u_i v_jᵀ): P_ij[3r + c] = U[r, i] V[c, j]
        m = 0
        for i in range(3):
            for r in range(3):
                for c in range(3):
                    vecs[m, 3 * r + c] = U[r, i] * V[c, i]
            lam[m] = 3 * S[i] ** 2 - 1
            m += 1
        for pi in range(3):
            i = 0 if pi < 2 else 1
            j = 1 if pi == 0 else 2
            sq = S[i] ** 2 + S[j] ** 2 - 1
            for r in range(3):
                for c in range(3):
                    pij = U[r, i] * V[c, j]
                    pji = U[r, j] * V[c, i]
                    vecs[m, 3 * r + c] = r2 * (pij + pji)
                    vecs[m + 1, 3 * r + c] = r2 * (pij - pji)
            lam[m] = sq + S[i] * S[j]
            lam[m + 1] = sq - S[i] * S[j]
            m += 2
        for a in range(9):
            for bb in range(9):
                acc = 0.0
                for mm in range(9):
                    acc += vecs[mm, a] * max(lam[mm], 0.0) * vecs[mm, bb]
                diag[b, 3 + a, 3 + bb] += w * acc


# --------------------------------------------------------------------------- revolute (UID 18)
@njit(cache=True, error_model='numpy')
def _separation(q, pb, cb, xbar, j, a, d):
    """x_i − x_j of anchor a (RevoluteJoint._separations)."""
    for r in range(3):
        xi = q[pb, r]
        xj = q[cb, r]
        for c in range(3):
            xi += q[pb, 3 + 3 * r + c] * xbar[j, 0, a, c]
            xj += q[cb, 3 + 3 * r + c] * xbar[j, 1, a, c]
        d[r] = xi - xj


@njit(cache=True, error_model='numpy')
def revolute_energy(q, jp, jc, xbar, K):
    """RevoluteJoint.energy: K/2 Σ |x_i − x_j|² from anchor separations (no cancellation)."""
    d = np.empty(3)
    E = 0.0
    for j in range(jp.size):
        acc = 0.0
        for a in range(2):
            _separation(q, jp[j], jc[j], xbar, j, a, d)
            acc += d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        E += K[j] * acc
    return 0.5 * E


@njit(cache=True, error_model='numpy')
def revolute_accumulate(q, jp, jc, xbar, K, Hj, grad, diag, pair):
    """RevoluteJoint.accumulate: gradient from the separations, the constant Hessian."""
    d = np.empty((2, 3))
    dd = np.empty(3)
    for j in range(jp.size):
        for a in range(2):
            _separation(q, jp[j], jc[j], xbar, j, a, dd)
            for r in range(3):
                d[a, r] = K[j] * dd[r]
        for side in range(2):
            b = jp[j] if side == 0 else jc[j]
            sign = 1.0 if side == 0 else -1.0
            for r in range(3):
                grad[b, r] += sign * (d[0, r] + d[1, r])
                for c in range(3):
                    grad[b, 3 + 3 * r + c] += sign * (d[0, r] * xbar[j, side, 0, c]
                                                      + d[1, r] * xbar[j, side, 1, c])
        pb, cb = jp[j], jc[j]
        for r in range(12):
            for c in range(12):
                diag[pb, r, c] += Hj[j, r, c]
                diag[cb, r, c] += Hj[j, 12 + r, 12 + c]
                pair[j, r, c] += Hj[j, r, 12 + c]


# --------------------------------------------------------------------------- driving / limit
@njit(cache=True, error_model='numpy')
def _limit_phi(x, lo, up, s):
    """Limit._phi for one joint: (E, E', E'')."""
    w = up - lo
    zero = w == 0.0
    ws = 1.0 if zero else w
    if zero:
        e = x - lo
        return s * abs(e) ** 3, 3 * s * abs(e) * e, 6 * s * abs(e)
    if x > up:
        a = (x - up) / ws
        return s * a ** 3, 3 * s * a * a / ws, 6 * s * a / ws ** 2
    if x < lo:
        b = (lo - x) / ws
        return s * b ** 3, -3 * s * b * b / ws, 6 * s * b / ws ** 2
    return 0.0, 0.0, 0.0


@njit(cache=True, error_model='numpy')
def _limit_active(x, lo, up):
    """Limit._active_at: outside the range, or off a zero-width limit."""
    return x > up or x < lo or (lo == up and x != lo)


@njit(cache=True, error_model='numpy')
def angle_energy(q, jp, jc, nbar, bbar, dj, dK, d_on, d_target, lj, lo, up, lstr, rel_start):
    """Driving.energy + Limit.energy (each 0 when no joint is active)."""
    E_drive = 0.0
    for k in range(dj.size):
        if d_on[k]:
            j = dj[k]
            x = unwrap(joint_theta(q, jp, jc, nbar, bbar, j), rel_start[j])
            dd = x - d_target[k]
            E_drive += 0.5 * dK[k] * dd * dd
    E_limit = 0.0
    for k in range(lj.size):
        j = lj[k]
        x = unwrap(joint_theta(q, jp, jc, nbar, bbar, j), rel_start[j])
        if _limit_active(x, lo[k], up[k]):
            E_limit += _limit_phi(x, lo[k], up[k], lstr[k])[0]
    return E_drive + E_limit


@njit(cache=True, error_model='numpy')
def jacobi_eigh(S, w, V):
    """Eigen-decomposition S = V diag(w) Vᵀ of a small symmetric matrix by cyclic Jacobi
    (S is destroyed). Accurate to round-off like LAPACK's syevd, and cheap to compile."""
    n = S.shape[0]
    for r in range(n):
        for c in range(n):
            V[r, c] = 1.0 if r == c else 0.0
    for sweep in range(50):
        off = 0.0
        dia = 0.0
        for p in range(n):
            dia += S[p, p] * S[p, p]
            for q in range(p + 1, n):
                off += S[p, q] * S[p, q]
        if off <= 1e-32 * dia:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = S[p, q]
                if apq == 0.0:
                    continue
                tau = (S[q, q] - S[p, p]) / (2.0 * apq)
                t = 1.0 / (abs(tau) + math.sqrt(1.0 + tau * tau))
                if tau < 0.0:
                    t = -t
                c = 1.0 / math.sqrt(1.0 + t * t)
                sn = t * c
                for k in range(n):
                    skp, skq = S[k, p], S[k, q]
                    S[k, p] = c * skp - sn * skq
                    S[k, q] = sn * skp + c * skq
                for k in range(n):
                    spk, sqk = S[p, k], S[q, k]
                    S[p, k] = c * spk - sn * sqk
                    S[q, k] = sn * spk + c * sqk
                S[p, q] = 0.0
                S[q, p] = 0.0
                for k in range(n):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - sn * vkq
                    V[k, q] = sn * vkp + c * vkq
    for p in range(n):
        w[p] = S[p, p]


@njit(cache=True, error_model='numpy')
def _angle_term_accumulate(q, jp, jc, nbar, bbar, joints, d1s, d2s, n, grad, diag, pair):
    """_AngleTerm.accumulate for the n active joints `joints[:n]` with E', E'' in d1s, d2s:
    H = E''∇θ∇θᵀ + E'∇²θ, PSD-projected as a batch like base.project_psd (kept as is when
    every eigenvalue of the batch is ≥ 0, else clamped), scattered on q[3:12].
    θ depends on A_k only through n_k = A_k n̄_k, b_k = A_k b̄_k, so H's range lies in the
    12-dim span of Q = diag(I3 ⊗ [n̄_i b̄_i], I3 ⊗ [n̄_j b̄_j]) (orthonormal columns): the
    eigenproblem is solved on QᵀHQ (12x12); the other 6 eigenvalues are exactly 0."""
    if n == 0:
        return
    G = np.empty((n, 18))
    H = np.empty((n, 18, 18))
    hh = np.empty((18, 18))
    Q = np.zeros((n, 18, 12))
    Hs = np.empty((n, 12, 12))
    W = np.empty((n, 12))
    V = np.empty((n, 12, 12))
    tmp = np.empty((18, 12))
    all_psd = True
    for k in range(n):
        j = joints[k]
        joint_theta_derivatives(q, jp, jc, nbar, bbar, j, G[k], hh, True)
        for a in range(18):
            for b in range(18):
                H[k, a, b] = d2s[k] * (G[k, a] * G[k, b]) + d1s[k] * hh[a, b]
        for side in range(2):
            for r in range(3):
                for c in range(3):
                    Q[k, 9 * side + 3 * r + c, 6 * side + 2 * r] = nbar[j, side, c]
                    Q[k, 9 * side + 3 * r + c, 6 * side + 2 * r + 1] = bbar[j, side, c]
        for a in range(18):
            for m in range(12):
                acc = 0.0
                for b in range(18):
                    acc += H[k, a, b] * Q[k, b, m]
                tmp[a, m] = acc
        for m in range(12):
            for l in range(m, 12):
                acc = 0.0
                for a in range(18):
                    acc += Q[k, a, m] * tmp[a, l]
                Hs[k, m, l] = acc
                Hs[k, l, m] = acc
        jacobi_eigh(Hs[k], W[k], V[k])
        for m in range(12):
            if not W[k, m] >= 0.0:
                all_psd = False
    if not all_psd:
        for k in range(n):
            for m in range(12):                 # V <- Q V, H = Σ max(w,0) v vᵀ
                for a in range(18):
                    acc = 0.0
                    for l in range(12):
                        acc += Q[k, a, l] * V[k, l, m]
                    tmp[a, m] = acc
            for a in range(18):
                for b in range(a, 18):
                    acc = 0.0
                    for m in range(12):
                        acc += tmp[a, m] * max(W[k, m], 0.0) * tmp[b, m]
                    H[k, a, b] = acc
                    H[k, b, a] = acc
    for k in range(n):
        j = joints[k]
        pb, cb = jp[j], jc[j]
        for a in range(9):
            grad[pb, 3 + a] += d1s[k] * G[k, a]
            grad[cb, 3 + a] += d1s[k] * G[k, 9 + a]
            for b in range(9):
                diag[pb, 3 + a, 3 + b] += H[k, a, b]
                diag[cb, 3 + a, 3 + b] += H[k, 9 + a, 9 + b]
                pair[j, 3 + a, 3 + b] += H[k, a, 9 + b]


@njit(cache=True, error_model='numpy')
def angle_accumulate(q, jp, jc, nbar, bbar, dj, dK, d_on, d_target, lj, lo, up, lstr,
                     rel_start, grad, diag, pair):
    """Driving.accumulate, then Limit.accumulate (the limit does nothing while every limited
    joint is inside its range). Each term's joints are PSD-projected as one batch."""
    nd = dj.size
    joints = np.empty(max(nd, lj.size), dtype=np.int64)
    d1s = np.empty(max(nd, lj.size))
    d2s = np.empty(max(nd, lj.size))
    for term in range(2):
        n = 0
        if term == 0:
            for k in range(nd):
                if d_on[k]:
                    j = dj[k]
                    x = unwrap(joint_theta(q, jp, jc, nbar, bbar, j), rel_start[j])
                    joints[n] = j
                    d1s[n] = dK[k] * (x - d_target[k])
                    d2s[n] = dK[k]
                    n += 1
        else:
            for k in range(lj.size):
                j = lj[k]
                x = unwrap(joint_theta(q, jp, jc, nbar, bbar, j), rel_start[j])
                if _limit_active(x, lo[k], up[k]):
                    _, d1, d2 = _limit_phi(x, lo[k], up[k], lstr[k])
                    joints[n] = j
                    d1s[n] = d1
                    d2s[n] = d2
                    n += 1
        _angle_term_accumulate(q, jp, jc, nbar, bbar, joints, d1s, d2s, n, grad, diag, pair)


# --------------------------------------------------------------------------- UID 668 + gravity
@njit(cache=True, error_model='numpy')
def _det_inv3(A, inv):
    det = (A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
           - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
           + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]))
    inv[0, 0] = (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) / det
    inv[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) / det
    inv[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) / det
    inv[1, 0] = (A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]) / det
    inv[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) / det
    inv[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) / det
    inv[2, 0] = (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]) / det
    inv[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) / det
    inv[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) / det
    return det


@njit(cache=True, error_model='numpy')
def accelerations(q, fixed, Minv, gravity, has_grav, jp, jc, xbar, tj, tval, ton, skipped):
    """Gravity.acceleration then ExternalTorque.acceleration: a = g_q + M⁻¹F (B,12).
    Bodies skipped by the singular guard are written to `skipped` (parent side of every
    active joint first, then child side, as the reference); returns (a, count)."""
    B = q.shape[0]
    acc = np.zeros((B, 12))
    if has_grav:
        for b in range(B):
            if not fixed[b]:
                for r in range(3):
                    acc[b, r] += gravity[r]
    ns = 0
    T = tj.size
    if T == 0:
        return acc, ns
    F = np.zeros((B, 12))
    any_active = False
    for k in range(T):
        if ton[k] and tval[k] != 0.0:
            any_active = True
    if any_active:
        # ExternalTorque.axes: a raw axis A_k(x̄1 − x̄0) of norm ≤ 1e-12·|x̄1 − x̄0| (or not
        # finite) is unusable: then the other body's is taken for both, and with neither the
        # axis (so the torque) is 0.
        e = np.empty((T, 3))
        es = np.empty((2, 3))
        A = np.empty((3, 3))
        inv = np.empty((3, 3))
        for k in range(T):
            j = tj[k]
            nok = 0
            for side in range(2):
                b = jp[j] if side == 0 else jc[j]
                v0 = v1 = v2 = 0.0
                d2 = 0.0
                for c in range(3):
                    dc = xbar[j, side, 1, c] - xbar[j, side, 0, c]
                    d2 += dc * dc
                    v0 += q[b, 3 + c] * dc
                    v1 += q[b, 6 + c] * dc
                    v2 += q[b, 9 + c] * dc
                nrm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
                if math.isfinite(nrm) and nrm > AXIS_EPS * math.sqrt(d2):
                    es[side, 0], es[side, 1], es[side, 2] = v0 / nrm, v1 / nrm, v2 / nrm
                    nok += 1
                else:
                    es[side, 0] = es[side, 1] = es[side, 2] = 0.0
            half = 0.5 if nok == 2 else 1.0          # one of them is 0 if not both
            for r in range(3):
                e[k, r] = half * (es[0, r] + es[1, r])
        for side in range(2):
            sign = -1.0 if side == 0 else 1.0            # ê_i = −ê_j
            for k in range(T):
                tau = tval[k] if ton[k] else 0.0
                if tau == 0.0:
                    continue
                j = tj[k]
                b = jp[j] if side == 0 else jc[j]
                for r in range(3):
                    for c in range(3):
                        A[r, c] = q[b, 3 + 3 * r + c]
                det = abs(_det_inv3(A, inv))
                scale = 1.0
                for r in range(3):
                    scale *= math.sqrt(A[r, 0] * A[r, 0] + A[r, 1] * A[r, 1] + A[r, 2] * A[r, 2])
                if not det > SINGULAR_RATIO * scale:
                    skipped[ns] = b
                    ns += 1
                    continue
                ex, ey, ez = sign * e[k, 0], sign * e[k, 1], sign * e[k, 2]
                # (τ/2) [ê]× A^{−T}: column c of A^{−T} is row c of A^{−1}
                for c in range(3):
                    w0, w1, w2 = inv[c, 0], inv[c, 1], inv[c, 2]
                    F[b, 3 + c] += 0.5 * tau * (ey * w2 - ez * w1)
                    F[b, 6 + c] += 0.5 * tau * (ez * w0 - ex * w2)
                    F[b, 9 + c] += 0.5 * tau * (ex * w1 - ey * w0)
    for b in range(B):
        for r in range(12):
            s = 0.0
            for c in range(12):
                s += Minv[b, r, c] * F[b, c]
            acc[b, r] += s
    return acc, ns


# --------------------------------------------------------------------------- linear solve
@njit(cache=True, error_model='numpy')
def cholesky_inplace(A, n):
    """Lower Cholesky factor of A[:n,:n] in place (upper part untouched); False if not PD."""
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= A[j, k] * A[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        A[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= A[i, k] * A[j, k]
            A[i, j] = s / d
    return True


@njit(cache=True, error_model='numpy')
def _lower_solve(L, x, n):
    for i in range(n):
        s = x[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True, error_model='numpy')
def _upper_solve(L, x, n):
    """Solve Lᵀ y = x in place."""
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True, error_model='numpy')
def solve_dense(free_idx, jp, jc, pair_joints, slot, diag, pair, grad, dq):
    """LinearSystem.solve, dense path: H over the free bodies, Cholesky; NaN if not PD."""
    nf = free_idx.size
    n = 12 * nf
    H = np.zeros((n, n))
    for s in range(nf):
        b = free_idx[s]
        for r in range(12):
            for c in range(12):
                H[12 * s + r, 12 * s + c] = diag[b, r, c]
    for j in range(jp.size):
        if pair_joints[j]:
            sp, sc = slot[jp[j]], slot[jc[j]]
            for r in range(12):
                for c in range(12):
                    H[12 * sp + r, 12 * sc + c] += pair[j, r, c]
                    H[12 * sc + c, 12 * sp + r] += pair[j, r, c]
    x = np.empty(n)
    for s in range(nf):
        for r in range(12):
            x[12 * s + r] = -grad[free_idx[s], r]
    if not cholesky_inplace(H, n):
        x[:] = np.nan
    else:
        _lower_solve(H, x, n)
        _upper_solve(H, x, n)
    for s in range(nf):
        for r in range(12):
            dq[free_idx[s], r] = x[12 * s + r]


@njit(cache=True, error_model='numpy')
def solve_tree(free_idx, jp, order, eparent, edge_ptr, edge_joint, diag, pair, grad, dq):
    """Block Cholesky along a forest of free bodies, leaves first (no fill-in, linear cost).
    For node k with elimination parent p and U = H[k, p]: L_kk = chol(D_k), X = L_kk⁻¹ U,
    D_p −= XᵀX; forward y_k = L_kk⁻¹ b_k, b_p −= Xᵀ y_k; backward x_k = L_kk⁻ᵀ (y_k − X x_p).
    NaN if not PD (as the banded solver)."""
    nf = free_idx.size
    W = np.empty((nf, 12, 12))
    X = np.zeros((nf, 12, 12))
    y = np.empty((nf, 12))
    for s in range(nf):
        b = free_idx[s]
        for r in range(12):
            y[s, r] = -grad[b, r]
            for c in range(12):
                W[s, r, c] = diag[b, r, c]
    ok = True
    col = np.empty(12)
    for t in range(nf):
        s = order[t]
        if not cholesky_inplace(W[s], 12):
            ok = False
            break
        p = eparent[s]
        _lower_solve(W[s], y[s], 12)
        if p < 0:
            continue
        bs = free_idx[s]
        for e in range(edge_ptr[s], edge_ptr[s + 1]):       # U = H[s, p] = Σ pair or pairᵀ
            j = edge_joint[e]
            if jp[j] == bs:
                for r in range(12):
                    for c in range(12):
                        X[s, r, c] += pair[j, r, c]
            else:
                for r in range(12):
                    for c in range(12):
                        X[s, r, c] += pair[j, c, r]
        for c in range(12):
            for r in range(12):
                col[r] = X[s, r, c]
            _lower_solve(W[s], col, 12)
            for r in range(12):
                X[s, r, c] = col[r]
        for r in range(12):
            for c in range(r, 12):
                acc = 0.0
                for k in range(12):
                    acc += X[s, k, r] * X[s, k, c]
                W[p, r, c] -= acc
                if c != r:
                    W[p, c, r] -= acc
            acc = 0.0
            for k in range(12):
                acc += X[s, k, r] * y[s, k]
            y[p, r] -= acc
    if not ok:
        for s in range(nf):
            for r in range(12):
                dq[free_idx[s], r] = np.nan
        return
    for t in range(nf - 1, -1, -1):
        s = order[t]
        p = eparent[s]
        if p >= 0:
            for r in range(12):
                acc = 0.0
                for c in range(12):
                    acc += X[s, r, c] * y[p, c]
                y[s, r] -= acc
        _upper_solve(W[s], y[s], 12)
    for s in range(nf):
        for r in range(12):
            dq[free_idx[s], r] = y[s, r]


# --------------------------------------------------------------------------- Newton
@njit(cache=True, error_model='numpy')
def _all_finite(x):
    for b in range(x.shape[0]):
        for r in range(x.shape[1]):
            if not math.isfinite(x[b, r]):
                return False
    return True


@njit(cache=True, error_model='numpy')
def kinetic_energy(q, qt, free_idx, M, scale):
    E = 0.0
    for k in range(free_idx.size):
        b = free_idx[k]
        for r in range(12):
            s = 0.0
            for c in range(12):
                s += M[b, r, c] * (q[b, c] - qt[b, c])
            E += s * (q[b, r] - qt[b, r])
    return 0.5 * scale * E


@njit(cache=True, error_model='numpy')
def convergence(dq, free_idx, corners, h, vtol, ttol):
    """(disp, rate, converged): largest corner displacement under Δq and max |Δq[3:12]|."""
    disp = 0.0
    rate = 0.0
    for k in range(free_idx.size):
        b = free_idx[k]
        for i in range(8):
            n2 = 0.0
            for r in range(3):
                m = dq[b, r]
                for c in range(3):
                    m += corners[b, i, c] * dq[b, 3 + 3 * r + c]
                n2 += m * m
            d = math.sqrt(n2)
            if d > disp or d != d:
                disp = d
        for a in range(3, 12):
            x = abs(dq[b, a])
            if x > rate or x != x:
                rate = x
    return disp, rate, disp <= vtol * h and rate <= ttol * h


# --------------------------------------------------------------------------- whole step
@njit(cache=True, error_model='numpy')
def retract(q, dq, alpha, free_idx, group, share, ngroups, out, mean):
    """solver/retraction.py `retract`: out = q ⊕ α·dq, each free body moved along the screw
    motion of its step, the floating groups' mean turn translation removed."""
    nf = len(free_idx)
    for g in range(ngroups):
        mean[g, 0] = mean[g, 1] = mean[g, 2] = 0.0
    for b in range(q.shape[0]):
        for r in range(12):
            out[b, r] = q[b, r] + alpha * dq[b, r]
    W = np.empty((3, 3))
    R = np.empty((3, 3))
    AD = np.empty((3, 3))
    corr_wd = np.empty((3, 3))
    Y = np.empty((3, 3))
    Ainv = np.empty((3, 3))
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
        for i in range(3):
            for j in range(3):
                i1, i2, j1, j2 = (j + 1) % 3, (j + 2) % 3, (i + 1) % 3, (i + 2) % 3
                Ainv[i, j] = (q[b, 3 + 3 * i1 + j1] * q[b, 3 + 3 * i2 + j2]
                              - q[b, 3 + 3 * i1 + j2] * q[b, 3 + 3 * i2 + j1])
        det = q[b, 3] * Ainv[0, 0] + q[b, 4] * Ainv[1, 0] + q[b, 5] * Ainv[2, 0]
        S = np.zeros((3, 3))
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for c in range(3):
                    acc += dq[b, 3 + 3 * i + c] * Ainv[c, j]
                S[i, j] = alpha * acc / det
        w0 = 0.5 * (S[2, 1] - S[1, 2])
        w1 = 0.5 * (S[0, 2] - S[2, 0])
        w2 = 0.5 * (S[1, 0] - S[0, 1])
        W[0, 0] = W[1, 1] = W[2, 2] = 0.0
        W[2, 1], W[1, 2] = w0, -w0
        W[0, 2], W[2, 0] = w1, -w1
        W[1, 0], W[0, 1] = w2, -w2
        th2 = w0 * w0 + w1 * w1 + w2 * w2
        th = math.sqrt(th2)
        if th < SMALL_ANGLE:                  # retraction.screw_coefficients' series
            cb = th2 / 6.0 * (1.0 - th2 / 20.0 * (1.0 - th2 / 42.0))
            cs = 1.0 - cb
            cc = 0.5 - th2 / 24.0 * (1.0 - th2 / 30.0 * (1.0 - th2 / 56.0))
        else:
            cs, cc, cb = math.sin(th) / th, (1.0 - math.cos(th)) / th2, (th - math.sin(th)) / th
        # exp(W)(A + D) − (A + ΔA) = −b W A + s W D + c W²(A + D), D = ΔA − W A: added to
        # q + αΔq (retraction.py: a tiny step rounds like the linear one)
        for i in range(3):
            for j in range(3):
                wa = 0.0
                for c in range(3):
                    wa += W[i, c] * q[b, 3 + 3 * c + j]
                R[i, j] = wa                                          # W A
                AD[i, j] = alpha * dq[b, 3 + 3 * i + j] - wa          # D
        for i in range(3):
            for j in range(3):
                wd = 0.0
                for c in range(3):
                    wd += W[i, c] * AD[c, j]
                corr_wd[i, j] = wd                                    # W D
                Y[i, j] = R[i, j] + wd                                # W (A + D)
        for i in range(3):
            for j in range(3):
                wwad = 0.0
                for c in range(3):
                    wwad += W[i, c] * Y[c, j]
                out[b, 3 + 3 * i + j] += -cb * R[i, j] + cs * corr_wd[i, j] + cc * wwad
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


@njit(cache=True, error_model='numpy')
def step_kernel(mi, mf, q0, v0, qp0, vp0, warm0, angle0, tval, ton, daim, don, dpas, h, bdf2,
                qvw, aw, skipped, info):
    """World._single from the forces to the joint velocities. Writes the new state into the
    caller's arrays (returning arrays would box each: ~1 µs apiece, a tenth of a small
    step): qvw (3,B,12) = q, v, warm_start; aw (2,J) = joint angle, joint velocity;
    skipped[:n_skipped] = bodies skipped by the singular guard; info (7) =
    [status, newton its, line-search its, rotation, post, n_skipped, max joint separation
    after the step (World.max_joint_separation)]; post: 0 ok,
    1 Newton non-finite, 2 step non-finite (the reference's failure strings), 3 refused
    before solving (mi[11] = may_split and the predicted rotation, then in info[3], exceeds
    max_step_rotation; q, v, angles are then not a step). Inputs are only read."""
    (B, J, T, D, L, nf, kind, max_it, ls_max, has_grav, fixed, jp, jc, tj, dj, lj,
     free_idx, slot, order, eparent, edge_ptr, edge_joint, pair_joints, group,
     M, Minv, weight, corners, xbar, K, Hj, nbar, bbar, init, dK, lo, up, lstr, share) = unpack(mi, mf)
    vtol, ttol = mf[0], mf[1]
    gravity = mf[2:5]
    free_mass, max_rot = mf[5], mf[6]
    info[:] = 0.0
    # forces: BDF1 at qⁿ, BDF2 at the extrapolation 2qⁿ − qⁿ⁻¹
    if bdf2:
        qf = 2 * q0 - qp0
    else:
        qf = q0
    acc, ns = accelerations(qf, fixed, Minv, gravity, has_grav, jp, jc, xbar, tj, tval, ton, skipped)
    info[5] = ns
    beta = 4.0 / 9.0
    qt = np.empty((B, 12))
    if bdf2:
        c1 = 2.0 / 9.0 * h
        c2 = beta * h * h
        for b in range(B):
            for r in range(12):
                qt[b, r] = ((4 * q0[b, r] - qp0[b, r]) / 3 + c1 * (4 * v0[b, r] - vp0[b, r])
                            + c2 * acc[b, r])
        scale = 1.0 / beta
    else:
        hh = h * h
        for b in range(B):
            for r in range(12):
                qt[b, r] = q0[b, r] + h * v0[b, r] + hh * acc[b, r]
        scale = 1.0
    for b in range(B):
        if fixed[b]:
            for r in range(12):
                qt[b, r] = q0[b, r]
    g = np.empty(18)
    hh18 = np.empty((1, 1))
    if mi[MI_MAY_SPLIT] != 0 and J > 0:
        # World._single: refuse (before solving) a step whose linearised rotation
        # max_j |∇θ_j(qⁿ)·(q̃ − qⁿ)_j| exceeds max_step_rotation (np.max: NaN wins, and a
        # NaN prediction does not split)
        predicted = 0.0
        for j in range(J):
            joint_theta_derivatives(q0, jp, jc, nbar, bbar, j, g, hh18, False)
            x = 0.0
            for a in range(9):
                x += (g[a] * (qt[jp[j], 3 + a] - q0[jp[j], 3 + a])
                      + g[9 + a] * (qt[jc[j], 3 + a] - q0[jc[j], 3 + a]))
            x = abs(x)
            if x != x:
                predicted = np.nan
            elif predicted == predicted:
                predicted = max(predicted, x)
        if predicted > max_rot:
            info[3], info[4] = predicted, POST_PREDICTED_SPLIT
            return
    # the energy that moving every body by velocity_tol·h costs in the mass metric
    energy_tol = 0.5 * free_mass * (vtol * h) ** 2
    # step context (World._context)
    rel_start = np.empty(J)
    for j in range(J):
        rel_start[j] = angle0[j] - init[j]
    d_target = np.empty(D)
    for k in range(D):
        j = dj[k]
        d_target[k] = rel_start[j] if dpas[k] else daim[k] - init[j]
    # ---- Newton (NewtonSolver.minimize) from q̃ + c h² warm_start (World._single); inlined
    d_on = don
    cw = (beta if bdf2 else 1.0) * h * h
    q = np.empty((B, 12))
    for b in range(B):
        for r in range(12):
            q[b, r] = qt[b, r] + cw * warm0[b, r]
    trial = np.empty_like(q)
    ngroups = mi[12]
    mean = np.empty((max(ngroups, 1), 3))
    ls = 0

    def potential(x):
        E = kinetic_energy(x, qt, free_idx, M, scale)
        E += ortho_energy(x, free_idx, weight, h)
        E += revolute_energy(x, jp, jc, xbar, K)
        E += angle_energy(x, jp, jc, nbar, bbar, dj, dK, d_on, d_target, lj, lo, up, lstr, rel_start)
        return E

    E = potential(q)
    E_other = potential(qt)                    # NewtonSolver.minimize(q_other=q̃)
    if E_other < E:
        q[:] = qt
        E = E_other
    grad = np.empty((B, 12))
    diag = np.empty((B, 12, 12))
    pair = np.empty((J, 12, 12))
    dq = np.zeros((B, 12))
    status = MAX_ITERATIONS
    its = max_it
    for it in range(1, max_it + 1):
        grad[:] = 0.0
        diag[:] = 0.0
        pair[:] = 0.0
        for k in range(nf):
            b = free_idx[k]
            for r in range(12):
                s = 0.0
                for c in range(12):
                    s += M[b, r, c] * (q[b, c] - qt[b, c])
                    diag[b, r, c] = scale * M[b, r, c]
                grad[b, r] = scale * s
        ortho_accumulate(q, free_idx, weight, h, grad, diag)
        revolute_accumulate(q, jp, jc, xbar, K, Hj, grad, diag, pair)
        angle_accumulate(q, jp, jc, nbar, bbar, dj, dK, d_on, d_target, lj, lo, up, lstr,
                         rel_start, grad, diag, pair)
        if kind == KIND_TREE:
            solve_tree(free_idx, jp, order, eparent, edge_ptr, edge_joint, diag, pair, grad, dq)
        else:
            solve_dense(free_idx, jp, jc, pair_joints, slot, diag, pair, grad, dq)
        if not _all_finite(dq):
            status, its = NONFINITE, it
            break
        disp, rate, converged = convergence(dq, free_idx, corners, h, vtol, ttol)
        dec = 0.0
        for k in range(nf):
            b = free_idx[k]
            for r in range(12):
                dec += grad[b, r] * dq[b, r]
        decrement = -0.5 * dec                  # Newton decrement ≈ Π(q) − min Π
        converged = converged and decrement <= scale * energy_tol
        if decrement <= ROUNDOFF * abs(E):
            status, its = CONVERGED, it
            break
        alpha = 1.0
        found = False
        E_new = E
        for _ in range(ls_max):                       # as solver/newton.py
            retract(q, dq, alpha, free_idx, group, share, ngroups, trial, mean)
            E_new = potential(trial)
            if E_new <= E + ROUNDOFF * abs(E):
                found = True
                break
            if converged:
                break
            alpha *= 0.5
            ls += 1
        if not found:
            status, its = (CONVERGED if converged else LINE_SEARCH_FAILED), it
            break
        if not math.isfinite(E_new):
            status, its = NONFINITE, it
            break
        q[:] = trial
        E = E_new
        if converged and alpha == 1.0:
            status, its = CONVERGED, it
            break
    info[0], info[1], info[2] = status, its, ls
    v = np.empty((B, 12))
    angle = np.empty(J)
    omega = np.empty(J)
    warm = np.empty((B, 12))
    if status == NONFINITE or not _all_finite(q):
        info[4] = POST_NEWTON_NONFINITE
        return
    for b in range(B):
        for r in range(12):
            warm[b, r] = (q[b, r] - qt[b, r]) / cw
    for b in range(B):
        for r in range(12):
            if fixed[b]:
                v[b, r] = 0.0
            elif bdf2:
                v[b, r] = (3 * q[b, r] - 4 * q0[b, r] + qp0[b, r]) / (2 * h)
            else:
                v[b, r] = (q[b, r] - q0[b, r]) / h
    rotation = 0.0
    finite = True
    for j in range(J):
        theta = joint_theta_derivatives(q, jp, jc, nbar, bbar, j, g, hh18, False)
        rel = unwrap(theta, rel_start[j])
        om = 0.0
        for a in range(9):
            om += g[a] * v[jp[j], 3 + a] + g[9 + a] * v[jc[j], 3 + a]
        omega[j] = om
        angle[j] = rel + init[j]
        if not math.isfinite(rel):
            finite = False
        da, dw = abs(rel - rel_start[j]), abs(om) * h      # np.maximum/np.max: NaN wins
        if da != da or dw != dw:
            rotation = np.nan
        elif rotation == rotation:
            rotation = max(rotation, da, dw)
    if not finite or not _all_finite(v):
        info[4] = POST_STEP_NONFINITE
        return
    info[3] = rotation
    sep = 0.0
    for j in range(J):                         # max_joint_separation, one dispatch less
        for a in range(2):
            _separation(q, jp[j], jc[j], xbar, j, a, g)
            n = math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
            if n > sep or n != n:
                sep = n
    info[6] = sep
    for b in range(B):
        for r in range(12):
            qvw[0, b, r] = q[b, r]
            qvw[1, b, r] = v[b, r]
            qvw[2, b, r] = warm[b, r]
    for j in range(J):
        aw[0, j] = angle[j]
        aw[1, j] = omega[j]


@njit(cache=True, error_model='numpy')
def max_joint_separation(mi, mf, q):
    """World.max_joint_separation (revolute.joint_separation, max over joints): the largest
    distance between the two bodies' copies of P0 or P1. [m]"""
    (B, J, T, D, L, nf, kind, max_it, ls_max, has_grav, fixed, jp, jc, tj, dj, lj,
     free_idx, slot, order, eparent, edge_ptr, edge_joint, pair_joints, group,
     M, Minv, weight, corners, xbar, K, Hj, nbar, bbar, init, dK, lo, up, lstr, share) = unpack(mi, mf)
    d = np.empty(3)
    out = 0.0
    for j in range(J):
        for a in range(2):
            _separation(q, jp[j], jc[j], xbar, j, a, d)
            n = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            if n > out or n != n:
                out = n
    return out


@njit(cache=True, error_model='numpy')
def batch_kernel(mi, mf, q0, v0, qp0, vp0, warm0, angle0, tval, ton, daim, don, dpas, h, bdf2,
                 bdf2_next, n, max_clean_rotation, max_clean_separation, qvw, aw, skipped, info):
    """Up to n consecutive steps of size h, each exactly `step_kernel` on the previous one's
    output (so bit-identical to n World.step calls), stopping before the first step that is
    not clean: refused, unconverged, non-finite, a skipped torque, a rotation above
    `max_clean_rotation` or a joint separation above `max_clean_separation` (the steps on
    which World.step sub-steps or warns; the caller redoes that one through World.step).
    Step k writes qvw[k] = (q, v, warm_start), aw[k] = (angle, velocity), info[k]. Returns
    the number of clean steps. `bdf2`: the first step's flag; `bdf2_next`: the others'."""
    done = 0
    for k in range(n):
        if k == 0:
            step_kernel(mi, mf, q0, v0, qp0, vp0, warm0, angle0, tval, ton, daim, don, dpas, h,
                        bdf2, qvw[0], aw[0], skipped, info[0])
        elif k == 1:
            step_kernel(mi, mf, qvw[0, 0], qvw[0, 1], q0, v0, qvw[0, 2], aw[0, 0], tval, ton,
                        daim, don, dpas, h, bdf2_next, qvw[1], aw[1], skipped, info[1])
        else:
            step_kernel(mi, mf, qvw[k - 1, 0], qvw[k - 1, 1], qvw[k - 2, 0], qvw[k - 2, 1],
                        qvw[k - 1, 2], aw[k - 1, 0], tval, ton, daim, don, dpas, h, bdf2_next,
                        qvw[k], aw[k], skipped, info[k])
        i = info[k]
        if (i[4] != POST_OK or i[0] != CONVERGED or i[5] != 0.0
                or not i[3] <= max_clean_rotation or not i[6] <= max_clean_separation):
            break
        done += 1
    return done
