"""The tree solve's 12x12 block kernels timed alone, ns per call, in a compiled loop over
fresh copies of random positive definite blocks (docs/speed-rounds.md, "The seventeenth round").

`factor_block` is timed against the textbook row-by-row Cholesky loop it replaced (the same
bits, compiled here from its one loop nest), alone and two blocks per call, to show what
writing it as three nests that the compiler unrolls is worth; the other rows are the
kernels the elimination of an edge calls after it.

    python bench/block_kernels.py [--rounds 5]

Times are the fastest of the rounds, the loop's copy of the inputs subtracted.
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

from abd_joint_sim.solver import linsolve                  # noqa: E402


@njit(cache=False, error_model='numpy')
def textbook_factor(blocks, b, inv_ds, slot):
    """factor_block before stop 32: one row-by-row loop nest (the compiler kept it as loops)."""
    W, inv_d = blocks[b], inv_ds[slot]
    for i in range(12):
        for j in range(i + 1):
            s = W[i, j]
            for k in range(j):
                s -= W[i, k] * W[j, k]
            if j < i:
                W[i, j] = s * inv_d[j]
            elif not s > 0.0:
                return False
            else:
                d = math.sqrt(s)
                W[i, i] = d
                inv_d[i] = 1.0 / d
    return True


@njit(cache=False, error_model='numpy')
def _run(which, src, blocks, inv_d, X, y, n):
    ok = True
    for _ in range(n):
        for q in range(2):                  # fresh inputs each call (the factor works in place)
            for r in range(12):
                y[q, r] = src[q, r, 0]
                for c in range(12):
                    blocks[q, r, c] = src[q, r, c]
        if which == 1:
            ok &= linsolve.factor_block(blocks, 0, inv_d, 0)
        elif which == 2:
            ok &= textbook_factor(blocks, 0, inv_d, 0)
        elif which == 3:
            ok &= linsolve.factor_block(blocks, 0, inv_d, 0) and linsolve.factor_block(blocks, 1, inv_d, 1)
        elif which == 4:
            ok &= textbook_factor(blocks, 0, inv_d, 0) and textbook_factor(blocks, 1, inv_d, 1)
        elif which == 5:
            linsolve.forward_vector12(blocks, 0, inv_d, y, 0)
        elif which == 6:
            linsolve.forward_block12(blocks, 0, inv_d, X, 0, blocks, 1, False)
        elif which == 7:
            linsolve.schur_update12(X, y, 0, blocks, 1, 1)
    return ok


ROWS = ((1, 'factor_block'), (2, 'the textbook loop (before stop 32)'),
        (3, 'factor_block, two blocks'), (4, 'the textbook loop, two blocks'),
        (5, 'forward_vector12 (y = L⁻¹y)'), (6, 'forward_block12 (X = L⁻¹U)'),
        (7, 'schur_update12 (D −= XᵀX, b −= Xᵀy)'))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--rounds', type=int, default=5)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(1)
    src = np.empty((2, 12, 12))
    for q in range(2):
        a = rng.standard_normal((12, 12))
        src[q] = a @ a.T + 12.0 * np.eye(12)
    blocks, inv_d, X, y = np.empty((2, 12, 12)), np.empty((2, 12)), np.empty((2, 12, 12)), np.empty((2, 12))
    # the same bits: the factor against the textbook loop
    _run(1, src, blocks, inv_d, X, y, 1)
    new = np.tril(blocks[0]).copy(), inv_d[0].copy()
    _run(2, src, blocks, inv_d, X, y, 1)
    same = np.array_equal(new[0], np.tril(blocks[0])) and np.array_equal(new[1], inv_d[0])
    # the later kernels read a factored block: factor once, and time them on it
    for which, _ in ROWS:
        _run(which, src, blocks, inv_d, X, y, 1)
    n = 200_000
    best = {which: math.inf for which, _ in ROWS}
    base = math.inf
    for _ in range(args.rounds):
        t = time.process_time()
        _run(0, src, blocks, inv_d, X, y, n)
        base = min(base, time.process_time() - t)
        for which, _ in ROWS:
            t = time.process_time()
            _run(which, src, blocks, inv_d, X, y, n)
            best[which] = min(best[which], time.process_time() - t)
    print(f'factor_block gives the textbook loop\'s bits: {"yes" if same else "NO"}')
    print('| kernel | ns per call |')
    print('|---|---|')
    for which, label in ROWS:
        print(f'| {label} | {(best[which] - base) / n * 1e9:.0f} |')
    return 0 if same else 1


if __name__ == '__main__':
    sys.exit(main())
