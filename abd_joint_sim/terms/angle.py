"""Joint angle θ of a revolute joint, shared by UID 668 (angle readout), UID 19 and UID 670
(docs/physics.md "Joint angle").

With n_k = A_k n̄_k, b_k = A_k b̄_k (not normalised):

    cos θ = (n_i·n_j + b_i·b_j)/2,   sin θ = (b_i·n_j − n_i·b_j)/2,   θ = atan2(sin, cos).

Rotating the child by +φ about +t = (P1 − P0)/|P1 − P0| gives θ = +φ (b = t × n).
Derivatives are with respect to x = [vec A_i, vec A_j] (18,) (vec row-major: q[3:12]).
`unwrap` picks the branch of θ nearest to the previous step's angle (multi-turn angle).
`accumulate_angle_joint` adds the gradient and the (PSD-projected) Hessian of any E(θ) on one
joint (UID 19, UID 670, damping): with `project`, E''∇θ∇θᵀ where |E'| > GAUSS_NEWTON_RANGE·E'',
else E''∇θ∇θᵀ + E'∇²θ projected in closed form up to a 4x4 eigenproblem.
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import kernel
from ..smallmat import eigh_ql_in

TWO_PI = 2.0 * np.pi
# [rad] where |E'/E''| exceeds this, the Hessian is the Gauss-Newton E''∇θ∇θᵀ: E'∇²θ shears
# A far from the minimum (docs/decisions.md)
GAUSS_NEWTON_RANGE = 0.1
WORK_SHAPE = (8, 18)     #: work array of theta_derivatives_at


@kernel
def unwrap(theta, reference):
    """The branch of θ nearest to `reference`: reference + ((θ − reference + π) mod 2π) − π;
    fmod is skipped within a turn, where the remainder is x itself (the same bits)."""
    x = theta - reference + np.pi
    if not (0.0 <= x < TWO_PI):
        x = x % TWO_PI
    return reference + x - np.pi


@kernel
def frames(q, i_body, j_body, nbar, bbar, j, fr):
    """fr[0..3] = n_i, n_j, b_i, b_j of joint j in world axes (`_at` functions take the model's
    arrays, not m: a structref field lookup per joint costs more than the math)."""
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


@kernel
def cos_sin(fr):
    """(cos θ, sin θ) of the frames (not normalised: |(c, s)| = 1 only for rigid A)."""
    c = 0.5 * ((fr[0, 0] * fr[1, 0] + fr[0, 1] * fr[1, 1] + fr[0, 2] * fr[1, 2])
               + (fr[2, 0] * fr[3, 0] + fr[2, 1] * fr[3, 1] + fr[2, 2] * fr[3, 2]))
    s = 0.5 * ((fr[2, 0] * fr[1, 0] + fr[2, 1] * fr[1, 1] + fr[2, 2] * fr[1, 2])
               - (fr[0, 0] * fr[3, 0] + fr[0, 1] * fr[3, 1] + fr[0, 2] * fr[3, 2]))
    return c, s


@kernel
def theta(q, m, j):
    """Wrapped θ ∈ (−π, π] of joint j, relative to the rest pose."""
    return theta_at(q, m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar, j)


@kernel
def theta_at(q, parent, child, nbar, bbar, j):
    """θ of joint j from the frames' dot products, without a work array."""
    c, s = cos_sin_at(q, parent, child, nbar, bbar, j)
    return math.atan2(s, c)


@kernel
def cos_sin_at(q, parent, child, nbar, bbar, j):
    """(c, s) of joint j: θ = atan2(s, c), both scaled alike by the bodies' stretch."""
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
    return 0.5 * (ninj + bibj), 0.5 * (binj - nibj)


@kernel
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


@kernel(inline='always')
def cos_sin_slope_at(q, d_plus, d_minus, parent, child, nbar, bbar, j):
    """(c, s, ∇θ(q)·d) of joint j along d = d_plus − d_minus, without atan2 or ∇θ:
    dθ = (c ds − s dc)/(c² + s²), dc = ½(Δn_i·n_j + n_i·Δn_j + Δb_i·b_j + b_i·Δb_j)."""
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


# -- the angle terms' Hessian, joint by joint ---------------------------------------------------
ANGLE_WORK_SHAPE = (25, 18)     #: work array of accumulate_angle_joint
_TINY_SPLIT = 1e-150            # below this |a + bR|/|a − bR| the v± pair carries nothing


@kernel
def accumulate_angle_joint(q, parent, child, nbar, bbar, j, d1, d2, grad, diag, pair, project,
                           work, exact_bound):
    """Adds ∇E = E'∇θ to grad and H = E''∇θ∇θᵀ + E'∇²θ (PSD-projected with `project`) to the
    blocks on q[3:12], for joint j with E' = d1, E'' = d2 (`work`: ANGLE_WORK_SHAPE). With
    `project`, H is taken exact where its most negative eigenvalue is ≥ −exact_bound (s times
    joint_angle_budget; 0.0 projects always)."""
    G = work[8]
    tw = work[0:8]
    i_body, j_body = parent[j], child[j]
    if not project:                         # the raw Hessian, from ∇²θ (tests; Newton projects)
        hh = np.empty((18, 18))
        theta_derivatives_at(q, parent, child, nbar, bbar, j, G, hh, True, tw)
    else:
        theta_derivatives_at(q, parent, child, nbar, bbar, j, G, tw, False, tw)
    for a in range(9):
        grad[i_body, 3 + a] += d1 * G[a]
        grad[j_body, 3 + a] += d1 * G[9 + a]
    if not project:
        for a in range(9):
            for b in range(9):
                diag[i_body, 3 + a, 3 + b] += d2 * (G[a] * G[b]) + d1 * hh[a, b]
                diag[j_body, 3 + a, 3 + b] += d2 * (G[9 + a] * G[9 + b]) + d1 * hh[9 + a, 9 + b]
                pair[j, 3 + a, 3 + b] += d2 * (G[a] * G[9 + b]) + d1 * hh[a, 9 + b]
        return
    curvature = 0.0 if abs(d1) > GAUSS_NEWTON_RANGE * d2 else d1
    if curvature == 0.0 and d2 >= 0.0:      # E''∇θ∇θᵀ is PSD: nothing to project
        for a in range(9):
            for b in range(9):
                diag[i_body, 3 + a, 3 + b] += d2 * (G[a] * G[b])
                diag[j_body, 3 + a, 3 + b] += d2 * (G[9 + a] * G[9 + b])
                pair[j, 3 + a, 3 + b] += d2 * (G[a] * G[9 + b])
        return
    fr = tw[0:4, 0:3]                       # n_i, n_j, b_i, b_j, left there by theta_derivatives_at
    c, s = cos_sin(fr)
    angle_hessian_projected(fr, c, s, nbar[j, 0], bbar[j, 0], nbar[j, 1], bbar[j, 1],
                            curvature, d2, i_body, j_body, j, diag, pair, work, exact_bound)


@kernel
def angle_hessian_projected(fr, c, s, nbi, bbi, nbj, bbj, e1, e2, i_body, j_body, j, diag, pair,
                            work, exact_bound):
    """Adds the PSD projection of H = e2 ∇θ∇θᵀ + e1 ∇²θ (e1 = E', e2 = E'') to the blocks,
    from its structure instead of a 12x12 eigenproblem (docs/physics-code.md "The angle
    terms' projected Hessian"): H itself where its Weyl bound λ_min ≥ −exact_bound, else
    β Π_pos + V (H_W⁺ − β E_pos) Vᵀ with a 4x4 eigenproblem. `work` must hold what
    theta_derivatives_at left there (∇c, ∇s in rows 4, 5; ∇θ in row 8)."""
    r = math.sqrt(c * c + s * s)
    o00, o01, o10, o11 = -s / r, -c / r, c / r, -s / r
    h = math.sqrt(0.5)
    P = work[17]                    # rows of a − bR at [2k, 2k+1], of a + bR at [6+2k, 7+2k]
    ss = dd = 0.0
    for k in range(3):
        ni, nj, bi, bj = fr[0, k], fr[1, k], fr[2, k], fr[3, k]
        t0 = o00 * nj + o01 * bj              # row k of X_j Oᵀ
        t1 = o10 * nj + o11 * bj
        a0, a1 = h * (ni + t0), h * (bi + t1)
        b0, b1 = h * (ni - t0), h * (bi - t1)
        u0, u1 = a0 - b1, a1 + b0             # a − bR  (yR = [y1, −y0] per row)
        v0, v1 = a0 + b1, a1 - b0             # a + bR
        P[2 * k], P[2 * k + 1], P[6 + 2 * k], P[7 + 2 * k] = u0, u1, v0, v1
        ss += u0 * u0 + u1 * u1
        dd += v0 * v0 + v1 * v1
    S = math.sqrt(ss)
    dl = math.sqrt(dd)
    inv_u = h / S
    inv_v = h / dl if dl > _TINY_SPLIT * S else 0.0
    beta = abs(e1) / (2.0 * r)
    # λ_min(H) ≥ −β + λ_min(rank-2 part) (Weyl); gθ ⟂ gr, so that part's eigenvalues are
    # those of the 2x2 [[e2 |gθ|², −(e1/r)|gθ||gr|], [·, 0]] (written without cancellation)
    a = e2 * (2.0 * (ss + dd)) / (16.0 * r * r)         # e2 |gθ|²
    b = 4.0 * (e1 / r) ** 2 * (2.0 * (ss + dd)) ** 2 / (256.0 * r * r)   # 4 (e1/r)² |gθ|² |gr|²
    if a >= 0.0:
        low = -b / (2.0 * (a + math.sqrt(a * a + b))) if b > 0.0 else 0.0
    else:
        low = 0.5 * (a - math.sqrt(a * a + b))
    if beta - low <= exact_bound:           # H itself: the inertia keeps Newton's matrix PD
        _add_exact_angle_hessian(work, c, s, r, o00, o01, o10, o11, nbi, bbi, nbj, bbj, e1, e2,
                                 i_body, j_body, j, diag, pair)
        return
    HW = work[21, 0:16].reshape((4, 4))
    V4 = work[22, 0:16].reshape((4, 4))
    Fm = work[23, 0:16].reshape((4, 4))
    w4 = work[24, 0:4]
    gt = work[24, 4:8]
    gr = work[24, 8:12]
    gt[0], gt[1], gt[2], gt[3] = S / (4.0 * r), -S / (4.0 * r), dl / (4.0 * r), -dl / (4.0 * r)
    gr[0], gr[1], gr[2], gr[3] = 0.25 * S, 0.25 * S, -0.25 * dl, -0.25 * dl
    half = e1 / (2.0 * r)
    k1 = e1 / r
    for p in range(4):
        for t in range(p, 4):
            x = e2 * (gt[p] * gt[t]) - k1 * (gr[p] * gt[t] + gt[p] * gr[t])
            HW[p, t] = x
            HW[t, p] = x
        HW[p, p] += half if p % 2 == 0 else -half
    Vx = work[9:13]                 # u+, u−, v+, v− as x = [vec A_i, vec A_j]
    for k in range(3):
        u0, u1, v0, v1 = P[2 * k], P[2 * k + 1], P[6 + 2 * k], P[7 + 2 * k]
        for t in range(4):
            if t == 0:
                y0, y1, sg = u0 * inv_u, u1 * inv_u, 1.0
            elif t == 1:
                y0, y1, sg = u1 * inv_u, -u0 * inv_u, -1.0
            elif t == 2:
                y0, y1, sg = v0 * inv_v, v1 * inv_v, 1.0
            else:
                y0, y1, sg = -v1 * inv_v, v0 * inv_v, -1.0
            z0 = sg * (o00 * y0 + o10 * y1)   # X_i = y/√2, X_j = ±y O/√2 (the h is in y)
            z1 = sg * (o01 * y0 + o11 * y1)
            for cc in range(3):               # A = X Fᵀ, F = [n̄ b̄]
                Vx[t, 3 * k + cc] = y0 * nbi[cc] + y1 * bbi[cc]
                Vx[t, 9 + 3 * k + cc] = z0 * nbj[cc] + z1 * bbj[cc]
    eigh_ql_in(HW, w4, V4, work[24, 12:16])
    for p in range(4):
        for t in range(p, 4):
            x = 0.0
            for l in range(4):
                if w4[l] > 0.0:
                    x += V4[p, l] * w4[l] * V4[t, l]
            Fm[p, t] = x
            Fm[t, p] = x
    first = 0 if e1 > 0.0 else 1           # u+, v+ span the positive space when E' > 0
    Fm[first, first] -= beta
    Fm[first + 2, first + 2] -= beta
    Wp = work[13:17]
    for t in range(4):
        for a in range(18):
            Wp[t, a] = (Fm[t, 0] * Vx[0, a] + Fm[t, 1] * Vx[1, a]
                        + Fm[t, 2] * Vx[2, a] + Fm[t, 3] * Vx[3, a])
    kd = abs(e1) / (4.0 * r)                # β Π_pos = I3 ⊗ (|e1|/(4r) F Fᵀ on each body,
    ko = e1 / (4.0 * r)                     #                 e1/(4r) F_i O F_jᵀ across)
    for a in range(9):
        ca = a % 3
        for b in range(a, 9):
            cb = b % 3
            xi = Vx[0, a] * Wp[0, b] + Vx[1, a] * Wp[1, b] + Vx[2, a] * Wp[2, b] + Vx[3, a] * Wp[3, b]
            xj = (Vx[0, 9 + a] * Wp[0, 9 + b] + Vx[1, 9 + a] * Wp[1, 9 + b]
                  + Vx[2, 9 + a] * Wp[2, 9 + b] + Vx[3, 9 + a] * Wp[3, 9 + b])
            if a // 3 == b // 3:
                xi += kd * (nbi[ca] * nbi[cb] + bbi[ca] * bbi[cb])
                xj += kd * (nbj[ca] * nbj[cb] + bbj[ca] * bbj[cb])
            diag[i_body, 3 + a, 3 + b] += xi
            diag[j_body, 3 + a, 3 + b] += xj
            if b != a:
                diag[i_body, 3 + b, 3 + a] += xi
                diag[j_body, 3 + b, 3 + a] += xj
        for b in range(9):
            cb = b % 3
            x = (Vx[0, a] * Wp[0, 9 + b] + Vx[1, a] * Wp[1, 9 + b]
                 + Vx[2, a] * Wp[2, 9 + b] + Vx[3, a] * Wp[3, 9 + b])
            if a // 3 == b // 3:
                x += ko * (nbi[ca] * (o00 * nbj[cb] + o01 * bbj[cb])
                           + bbi[ca] * (o10 * nbj[cb] + o11 * bbj[cb]))
            pair[j, 3 + a, 3 + b] += x


@kernel
def _add_exact_angle_hessian(work, c, s, r, o00, o01, o10, o11, nbi, bbi, nbj, bbj, e1, e2,
                             i_body, j_body, j, diag, pair):
    """angle_hessian_projected's exact branch: adds H = e2 ∇θ∇θᵀ − (e1/r)(∇θ∇rᵀ + ∇r∇θᵀ) +
    I3 ⊗ e1/(2r) F_i O F_jᵀ (across the pair) to the blocks on q[3:12]; ∇r = (c∇c + s∇s)/r."""
    dc, ds, G = work[4], work[5], work[8]
    Dr = work[7]
    for a in range(18):
        Dr[a] = (c * dc[a] + s * ds[a]) / r
    k1 = e1 / r
    kx = e1 / (2.0 * r)
    # ∇θ, ∇r in locals and whole rows with constant bounds, for the SLP vectoriser (jit/slp.py);
    # each block's whole square has the mirrored triangle's bits, in ~60 % of the time
    Gi = (G[0], G[1], G[2], G[3], G[4], G[5], G[6], G[7], G[8])
    Gj = (G[9], G[10], G[11], G[12], G[13], G[14], G[15], G[16], G[17])
    Ri = (Dr[0], Dr[1], Dr[2], Dr[3], Dr[4], Dr[5], Dr[6], Dr[7], Dr[8])
    Rj = (Dr[9], Dr[10], Dr[11], Dr[12], Dr[13], Dr[14], Dr[15], Dr[16], Dr[17])
    for a in range(9):
        ga, ra = Gi[a], Ri[a]
        gj, rj = Gj[a], Rj[a]
        for b in range(9):
            diag[i_body, 3 + a, 3 + b] += e2 * (ga * Gi[b]) - k1 * (ga * Ri[b] + ra * Gi[b])
        for b in range(9):
            diag[j_body, 3 + a, 3 + b] += e2 * (gj * Gj[b]) - k1 * (gj * Rj[b] + rj * Gj[b])
        # across: row a of body i, column b of body j, plus e1/(2r) F_i O F_jᵀ on the 3x3
        # diagonal blocks of I3 ⊗ (...): row a % 3, column b % 3
        ca = a % 3
        X0 = kx * (nbi[ca] * (o00 * nbj[0] + o01 * bbj[0]) + bbi[ca] * (o10 * nbj[0] + o11 * bbj[0]))
        X1 = kx * (nbi[ca] * (o00 * nbj[1] + o01 * bbj[1]) + bbi[ca] * (o10 * nbj[1] + o11 * bbj[1]))
        X2 = kx * (nbi[ca] * (o00 * nbj[2] + o01 * bbj[2]) + bbi[ca] * (o10 * nbj[2] + o11 * bbj[2]))
        for b in range(9):
            x = e2 * (ga * Gj[b]) - k1 * (ga * Rj[b] + ra * Gj[b])
            if b // 3 == a // 3:
                x += X0 if b % 3 == 0 else (X1 if b % 3 == 1 else X2)
            pair[j, 3 + a, 3 + b] += x
