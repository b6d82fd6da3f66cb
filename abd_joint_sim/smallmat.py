"""Small dense matrices inside compiled code: 3x3 SVD, symmetric eigen-decomposition,
Cholesky and triangular solves, 3x3 inverse.

Scalar loops (a LAPACK call on a 3x3 or 12x12 costs more than the arithmetic), in place on
caller-owned arrays, allocating nothing but small scratch.
"""
from __future__ import annotations

import math

import numpy as np

from .jit import kernel

# Jacobi sweeps stop once Σ off-diagonal² ≤ JACOBI_TOL · Σ diagonal²: above the rounding
# floor (~eps² ≈ 5e-32, where 1e-32 ran every 12x12 call to its cap: 36 µs instead of ~5)
JACOBI_TOL = 1e-30


@kernel
def svd3_in(A, U, S, V, work):
    """A = U diag(S) Vᵀ for a 3x3 A (S ≥ 0 descending, U, V orthonormal), work (2,3,3)
    scratch: jacobi_eigh of AᵀA for V, then U from a Gram-Schmidt QR of A V (u3 = u1 × u2),
    so tiny singular values keep full absolute accuracy. ~50x cheaper than LAPACK on a 3x3."""
    Bm = work[0]
    for r in range(3):
        for c in range(3):
            Bm[r, c] = A[0, r] * A[0, c] + A[1, r] * A[1, c] + A[2, r] * A[2, c]
    jacobi_eigh(Bm, S, V, 12)                       # V; S is scratch until the end
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
    b = work[1]                                       # columns A v_k
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


@kernel
def jacobi_eigh(S, w, V, sweeps):
    """Eigen-decomposition S = V diag(w) Vᵀ of a small symmetric matrix by cyclic Jacobi, at
    most `sweeps` sweeps (S is left diagonal). Accurate to round-off like LAPACK's syevd."""
    n = S.shape[0]
    for r in range(n):
        for c in range(n):
            V[r, c] = 1.0 if r == c else 0.0
    for sweep in range(sweeps):
        off = 0.0
        dia = 0.0
        for p in range(n):
            dia += S[p, p] * S[p, p]
            for q in range(p + 1, n):
                off += S[p, q] * S[p, q]
        if off <= JACOBI_TOL * dia:
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


@kernel
def cholesky(A, n):
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


@kernel
def lower_solve(L, x, n):
    """Solve L y = x in place (L lower triangular, the first n rows)."""
    for i in range(n):
        s = x[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]


@kernel
def upper_solve(L, x, n):
    """Solve Lᵀ y = x in place."""
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@kernel(inline='always')
def adjugate3(a):
    """(adj a, det a) of a 3x3 row-major 9-tuple: adj a = A⁻¹ det A, entry (i, j) the cofactor
    a[j+1][i+1] a[j+2][i+2] − a[j+1][i+2] a[j+2][i+1] (mod 3), det a = a00 adj00 + a01 adj10 +
    a02 adj20; scalars, kept in registers (docs/speed.md)."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = a
    adj = (a11 * a22 - a12 * a21, a21 * a02 - a22 * a01, a01 * a12 - a02 * a11,
           a12 * a20 - a10 * a22, a22 * a00 - a20 * a02, a02 * a10 - a00 * a12,
           a10 * a21 - a11 * a20, a20 * a01 - a21 * a00, a00 * a11 - a01 * a10)
    return adj, a00 * adj[0] + a01 * adj[3] + a02 * adj[6]


@kernel(inline='always')
def product3(a, b):
    """a b of two 3x3 matrices held as row-major 9-tuples, each entry summed from 0.0 over
    the inner index in order (the rounding of the loop `acc = 0.0; acc += a_ic b_cj`)."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = a
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = b
    return (0.0 + a00 * b00 + a01 * b10 + a02 * b20, 0.0 + a00 * b01 + a01 * b11 + a02 * b21,
            0.0 + a00 * b02 + a01 * b12 + a02 * b22,
            0.0 + a10 * b00 + a11 * b10 + a12 * b20, 0.0 + a10 * b01 + a11 * b11 + a12 * b21,
            0.0 + a10 * b02 + a11 * b12 + a12 * b22,
            0.0 + a20 * b00 + a21 * b10 + a22 * b20, 0.0 + a20 * b01 + a21 * b11 + a22 * b21,
            0.0 + a20 * b02 + a21 * b12 + a22 * b22)


@kernel
def eigh_ql_in(S, w, V, e):
    """Eigen-decomposition S = V diag(w) Vᵀ of a small symmetric matrix, e (n,) scratch:
    EISPACK tred2/tql2 (~n³ flops against Jacobi's ~6 sweeps of 3n³); False, after
    jacobi_eigh on S, if QL does not converge in 30 iterations per eigenvalue."""
    n = S.shape[0]
    for r in range(n):
        for c in range(n):
            V[r, c] = S[r, c]
    a = V
    d = w
    for i in range(n - 1, 0, -1):             # tred2: a becomes the orthogonal transform
        l = i - 1
        h = 0.0
        scale = 0.0
        if l > 0:
            for k in range(l + 1):
                scale += abs(a[i, k])
            if scale == 0.0:
                e[i] = a[i, l]
            else:
                for k in range(l + 1):
                    a[i, k] /= scale
                    h += a[i, k] * a[i, k]
                f = a[i, l]
                g = -math.sqrt(h) if f >= 0.0 else math.sqrt(h)
                e[i] = scale * g
                h -= f * g
                a[i, l] = f - g
                f = 0.0
                for j in range(l + 1):
                    a[j, i] = a[i, j] / h
                    g = 0.0
                    for k in range(j + 1):
                        g += a[j, k] * a[i, k]
                    for k in range(j + 1, l + 1):
                        g += a[k, j] * a[i, k]
                    e[j] = g / h
                    f += e[j] * a[i, j]
                hh = f / (h + h)
                for j in range(l + 1):
                    f = a[i, j]
                    g = e[j] - hh * f
                    e[j] = g
                    for k in range(j + 1):
                        a[j, k] -= f * e[k] + g * a[i, k]
        else:
            e[i] = a[i, l]
        d[i] = h
    d[0] = 0.0
    e[0] = 0.0
    for i in range(n):
        if d[i] != 0.0:
            for j in range(i):
                g = 0.0
                for k in range(i):
                    g += a[i, k] * a[k, j]
                for k in range(i):
                    a[k, j] -= g * a[k, i]
        d[i] = a[i, i]
        a[i, i] = 1.0
        for j in range(i):
            a[j, i] = 0.0
            a[i, j] = 0.0
    for i in range(1, n):                      # tqli on d, e; eigenvectors into V
        e[i - 1] = e[i]
    e[n - 1] = 0.0
    for l in range(n):
        it = 0
        while True:
            m = l
            while m < n - 1:
                dd = abs(d[m]) + abs(d[m + 1])
                if abs(e[m]) + dd == dd:
                    break
                m += 1
            if m == l:
                break
            it += 1
            if it > 30:
                jacobi_eigh(S, w, V, 50)
                return False
            g = (d[l + 1] - d[l]) / (2.0 * e[l])
            r = math.hypot(g, 1.0)
            g = d[m] - d[l] + e[l] / (g + (r if g >= 0.0 else -r))
            s = 1.0
            c = 1.0
            p = 0.0
            i = m - 1
            underflow = False
            while i >= l:
                f = s * e[i]
                b = c * e[i]
                r = math.hypot(f, g)
                e[i + 1] = r
                if r == 0.0:
                    d[i + 1] -= p
                    e[m] = 0.0
                    underflow = True
                    break
                s = f / r
                c = g / r
                g = d[i + 1] - p
                r = (d[i] - g) * s + 2.0 * c * b
                p = s * r
                d[i + 1] = g + p
                g = c * r - b
                for k in range(n):
                    f = V[k, i + 1]
                    V[k, i + 1] = s * V[k, i] + c * f
                    V[k, i] = c * V[k, i] - s * f
                i -= 1
            if underflow:
                continue
            d[l] -= p
            e[l] = g
            e[m] = 0.0
    return True


@kernel
def nearest_rotation_in(A, R, work):
    """R = the rotation nearest the 3x3 A (Frobenius norm), det +1: U diag(1, 1, det(U Vᵀ)) Vᵀ
    from svd3_in. work: (5, 3, 3) scratch."""
    U, V = work[0], work[1]
    S = work[2, 0]
    svd3_in(A, U, S, V, work[3:5])
    d = (U[0, 0] * (U[1, 1] * U[2, 2] - U[1, 2] * U[2, 1])
         - U[0, 1] * (U[1, 0] * U[2, 2] - U[1, 2] * U[2, 0])
         + U[0, 2] * (U[1, 0] * U[2, 1] - U[1, 1] * U[2, 0]))
    e = (V[0, 0] * (V[1, 1] * V[2, 2] - V[1, 2] * V[2, 1])
         - V[0, 1] * (V[1, 0] * V[2, 2] - V[1, 2] * V[2, 0])
         + V[0, 2] * (V[1, 0] * V[2, 1] - V[1, 1] * V[2, 0]))
    flip = -1.0 if d * e < 0.0 else 1.0
    for r in range(3):
        for c in range(3):
            R[r, c] = U[r, 0] * V[c, 0] + U[r, 1] * V[c, 1] + flip * U[r, 2] * V[c, 2]


@kernel
def quaternion_in(R, out):
    """out[:4] = (x, y, z, w) of the rotation R, w ≥ 0, by Shepperd's method (the largest of
    w, x, y, z first, so no division by a small number)."""
    t = R[0, 0] + R[1, 1] + R[2, 2]
    k, best = 0, t
    for i in range(3):
        if R[i, i] > best:
            k, best = i + 1, R[i, i]
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + t)
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif k == 1:
        s = 2.0 * math.sqrt(max(1.0 + R[0, 0] - R[1, 1] - R[2, 2], 1e-300))
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif k == 2:
        s = 2.0 * math.sqrt(max(1.0 + R[1, 1] - R[0, 0] - R[2, 2], 1e-300))
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(max(1.0 + R[2, 2] - R[0, 0] - R[1, 1], 1e-300))
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    out[0], out[1], out[2], out[3] = x, y, z, w


@kernel
def frame_poses(P, A, body, t, Rv, ends_body, ends, poses, points):
    """Poses of frames attached to affine bodies (x = A x̄ + p per body: P (B,3), A (B,3,3)):
    poses[i] = (x, y, z, qx, qy, qz, qw) of frame i on body[i] at body-frame offset t[i] (3,)
    with rotation Rv[i] (3,3): position A t + p, orientation R Rv with R the rotation nearest
    A; points[i] = A x + p of each point ends[i] (3,) on body ends_body[i]. The rotation of a
    body is computed once. Returns False (outputs partly written) if an input is not finite."""
    B = P.shape[0]
    for b in range(B):
        for r in range(3):
            if not math.isfinite(P[b, r]):
                return False
            for c in range(3):
                if not math.isfinite(A[b, r, c]):
                    return False
    work = np.empty((5, 3, 3))
    R = np.empty((B, 3, 3))
    done = np.zeros(B, dtype=np.bool_)
    Rp = np.empty((3, 3))
    for i in range(body.size):
        b = body[i]
        if not done[b]:
            nearest_rotation_in(A[b], R[b], work)
            done[b] = True
        for r in range(3):
            poses[i, r] = A[b, r, 0] * t[i, 0] + A[b, r, 1] * t[i, 1] + A[b, r, 2] * t[i, 2] + P[b, r]
            for c in range(3):
                Rp[r, c] = R[b, r, 0] * Rv[i, 0, c] + R[b, r, 1] * Rv[i, 1, c] + R[b, r, 2] * Rv[i, 2, c]
        quaternion_in(Rp, poses[i, 3:7])
    for i in range(ends_body.size):
        b = ends_body[i]
        for r in range(3):
            points[i, r] = A[b, r, 0] * ends[i, 0] + A[b, r, 1] * ends[i, 1] + A[b, r, 2] * ends[i, 2] + P[b, r]
    return True
