"""Two term Hessians timed alone against the loops they replaced at stop 33, ns per call, in
compiled loops (docs/speed-rounds.md, "The eighteenth round"):

- the shape term's (UID 1) `ortho.accumulate` on bodies near SO(3), where it adds the exact
  9x9 Hessian, against the same function with the Hessian's 4-deep loop nest;
- the exact angle Hessian of a drive or limit (`angles._add_exact_angle_hessian`) against
  its triangle-and-mirror loops.

Both "before" forms are compiled here from their loops, and each pair is first checked to
give the same bits.

    python bench/term_hessians.py [--rounds 5]

Times are the fastest of the rounds.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abd_joint_sim import Scene, World                         # noqa: E402
from abd_joint_sim.terms import angle as angles               # noqa: E402
from abd_joint_sim.builders import chain_scene                 # noqa: E402
from abd_joint_sim.jit import slp as vectorize                 # noqa: E402
from abd_joint_sim.terms import ortho                          # noqa: E402
from abd_joint_sim.terms.ortho import _aat, _ata               # noqa: E402


@njit(cache=False, error_model='numpy')
def nest_ortho_accumulate(q, free_bodies, weight, hh, grad, diag):
    """ortho.accumulate before stop 33 on bodies near SO(3) (its exact path): the gradient,
    ‖C‖² and the Hessian's 4-deep loop nest."""
    E = 0.0
    for b in free_bodies:
        C = (_aat(q, b, 0, 0) - 1.0, _aat(q, b, 0, 1), _aat(q, b, 0, 2),
             _aat(q, b, 1, 0), _aat(q, b, 1, 1) - 1.0, _aat(q, b, 1, 2),
             _aat(q, b, 2, 0), _aat(q, b, 2, 1), _aat(q, b, 2, 2) - 1.0)
        w = 4.0 * hh * weight[b]
        for r in range(3):
            for c in range(3):
                grad[b, 3 + 3 * r + c] += w * (C[3 * r] * q[b, 3 + c] + C[3 * r + 1] * q[b, 6 + c]
                                               + C[3 * r + 2] * q[b, 9 + c])
        c2 = 0.0
        for r in range(9):
            c2 += C[r] * C[r]
        E += weight[b] * c2
        AtA = (_ata(q, b, 0, 0), _ata(q, b, 0, 1), _ata(q, b, 0, 2),
               _ata(q, b, 1, 0), _ata(q, b, 1, 1), _ata(q, b, 1, 2),
               _ata(q, b, 2, 0), _ata(q, b, 2, 1), _ata(q, b, 2, 2))
        for i in range(3):
            for k in range(3):
                for j in range(3):
                    for l in range(3):
                        x = q[b, 3 + 3 * i + l] * q[b, 3 + 3 * j + k]
                        if i == j:
                            x += AtA[3 * l + k]
                        if k == l:
                            x += C[3 * i + j]
                        diag[b, 3 + 3 * i + k, 3 + 3 * j + l] += w * x
    return hh * E


@njit(cache=False, error_model='numpy')
def triangle_angle_hessian(work, c, s, r, o00, o01, o10, o11, nbi, bbi, nbj, bbj, e1, e2,
                           i_body, j_body, j, diag, pair):
    """angles._add_exact_angle_hessian before stop 33."""
    dc, ds, G = work[4], work[5], work[8]
    Dr = work[7]
    for a in range(18):
        Dr[a] = (c * dc[a] + s * ds[a]) / r
    k1 = e1 / r
    kx = e1 / (2.0 * r)
    for a in range(9):
        ga, ra = G[a], Dr[a]
        gj, rj = G[9 + a], Dr[9 + a]
        for b in range(a, 9):
            xi = e2 * (ga * G[b]) - k1 * (ga * Dr[b] + ra * G[b])
            xj = e2 * (gj * G[9 + b]) - k1 * (gj * Dr[9 + b] + rj * G[9 + b])
            diag[i_body, 3 + a, 3 + b] += xi
            diag[j_body, 3 + a, 3 + b] += xj
            if b != a:
                diag[i_body, 3 + b, 3 + a] += xi
                diag[j_body, 3 + b, 3 + a] += xj
        ca = a % 3
        for b in range(9):
            x = e2 * (ga * G[9 + b]) - k1 * (ga * Dr[9 + b] + ra * G[9 + b])
            if a // 3 == b // 3:
                cb = b % 3
                x += kx * (nbi[ca] * (o00 * nbj[cb] + o01 * bbj[cb])
                           + bbi[ca] * (o10 * nbj[cb] + o11 * bbj[cb]))
            pair[j, 3 + a, 3 + b] += x


@njit(cache=False, error_model='numpy')
def _run_ortho(which, q, m, ctx, grad, diag, n):
    E = 0.0
    for _ in range(n):
        if which == 1:
            E += ortho.accumulate(q, m, ctx, grad, diag, diag, True)
        else:
            E += nest_ortho_accumulate(q, m.free_bodies, m.ortho_weight, ctx.h * ctx.h, grad, diag)
    return E


@njit(cache=False, error_model='numpy')
def _run_angle(which, work, v, fr, diag, pair, n):
    for _ in range(n):
        if which == 1:
            angles._add_exact_angle_hessian(work, v[0], v[1], v[2], v[3], v[4], v[5], v[6], fr[0], fr[1],
                                            fr[2], fr[3], v[7], v[8], 0, 1, 0, diag, pair)
        else:
            triangle_angle_hessian(work, v[0], v[1], v[2], v[3], v[4], v[5], v[6], fr[0], fr[1], fr[2],
                                   fr[3], v[7], v[8], 0, 1, 0, diag, pair)


def _best(f, args, n, rounds):
    f(*args, 10)
    best = math.inf
    for _ in range(rounds):
        t = time.process_time()
        f(*args, n)
        best = min(best, time.process_time() - t)
    return best / n * 1e9


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--rounds', type=int, default=5)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(1)
    # a chain of 10 links under torque, a few steps in: every body near SO(3)
    w = World(Scene.from_dict(chain_scene(10)))
    for name in w.actuated_joint_names:
        w.set_torque(name, 1.0)
    w.step(20)
    q, m, ctx = w.state.q.copy(), w.solver.data, w.solver.context(w.state, w.control, w.dt)
    B, F = q.shape[0], len(m.free_bodies)
    with vectorize.enabled():
        # same bits first
        d_new, d_old, g_new, g_old = np.zeros((B, 12, 12)), np.zeros((B, 12, 12)), np.zeros((B, 12)), np.zeros((B, 12))
        same_ortho = _run_ortho(1, q, m, ctx, g_new, d_new, 1) == _run_ortho(2, q, m, ctx, g_old, d_old, 1)
        same_ortho = same_ortho and np.array_equal(d_new, d_old) and np.array_equal(g_new, g_old)
        same_ortho = same_ortho and np.abs(d_new).max() > 0.0
        work = rng.standard_normal(angles.ANGLE_WORK_SHAPE)
        c, s = 0.6, 0.7
        v = np.array([c, s, math.hypot(c, s), 0.3, -0.4, 0.5, 0.8, 1.3, 2.1])
        fr = rng.standard_normal((4, 3))
        start_d, start_p = rng.standard_normal((2, 12, 12)), rng.standard_normal((1, 12, 12))
        dn, pn, do, po = start_d.copy(), start_p.copy(), start_d.copy(), start_p.copy()
        _run_angle(1, work, v, fr, dn, pn, 1)
        _run_angle(2, work, v, fr, do, po, 1)
        same_angle = np.array_equal(dn, do) and np.array_equal(pn, po)
        n = 100_000
        t_new = _best(_run_ortho, (1, q, m, ctx, g_new, d_new), n // F, args.rounds) / F
        t_old = _best(_run_ortho, (2, q, m, ctx, g_old, d_old), n // F, args.rounds) / F
        a_new = _best(_run_angle, (1, work, v, fr, dn, pn), n, args.rounds)
        a_old = _best(_run_angle, (2, work, v, fr, do, po), n, args.rounds)
    print(f'same bits: shape Hessian {"yes" if same_ortho else "NO"}, angle Hessian {"yes" if same_angle else "NO"}')
    print('| kernel | ns per call |')
    print('|---|---|')
    print(f'| ortho.accumulate near SO(3), per body (gradient, C, ‖C‖ and the exact Hessian) | {t_new:.0f} |')
    print(f'| the same with the Hessian as its 4-deep nest (before stop 33), per body | {t_old:.0f} |')
    print(f'| angles._add_exact_angle_hessian | {a_new:.0f} |')
    print(f'| its triangle-and-mirror loops (before stop 33) | {a_old:.0f} |')
    return 0 if same_ortho and same_angle else 1


if __name__ == '__main__':
    sys.exit(main())
