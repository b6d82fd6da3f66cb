"""Assemble and solve H Δq = −g over the free bodies, in one place.

H is block-sparse: a 12x12 block per free body on the diagonal and one per joint between two
free bodies off it (the joint graph). Small systems use a dense Cholesky solve; larger ones a
sparse LU (SuperLU) whose CSC pattern is built once per model and refilled by a fixed
permutation each Newton iteration, with a fill-reducing ordering of A+Aᵀ. For trees (chains
included) such orderings give little fill-in, so cost grows close to linearly with bodies.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

DENSE_MAX_DOF = 96          # up to 8 free bodies: dense is faster than any sparse set-up


class LinearSystem:
    def __init__(self, model):
        self.model = model
        free = ~model.body_fixed
        self.free = np.flatnonzero(free)
        self.slot = np.full(model.body_count, -1)
        self.slot[self.free] = np.arange(len(self.free))
        p, c = model.joint_parent, model.joint_child
        both = free[p] & free[c]
        self.pair_joints = np.flatnonzero(both)
        self.n = 12 * len(self.free)
        self.dense = self.n <= DENSE_MAX_DOF
        sp, sc = self.slot[p[both]], self.slot[c[both]]
        self._sp, self._sc = sp, sc
        if not self.dense and self.n:
            r12 = np.arange(12)
            # block (a,b) -> rows 12a + r, cols 12b + c
            def coords(a, b):
                rows = (12 * a[:, None, None] + r12[None, :, None]) + 0 * r12[None, None, :]
                cols = (12 * b[:, None, None] + r12[None, None, :]) + 0 * r12[None, :, None]
                return rows.ravel(), cols.ravel()
            fb = np.arange(len(self.free))
            rd, cd = coords(fb, fb)
            ru, cu = coords(sp, sc)
            rows = np.concatenate([rd, ru, cu])
            cols = np.concatenate([cd, cu, ru])
            # CSC order is (column, row); entries of several joints between the same two
            # bodies fall on one key and are summed by bincount.
            keys = cols.astype(np.int64) * self.n + rows
            uniq, self._inv = np.unique(keys, return_inverse=True)
            self._indices = (uniq % self.n).astype(np.int32)
            self._indptr = np.searchsorted(uniq // self.n, np.arange(self.n + 1)).astype(np.int32)
            self._nnz = len(uniq)

    def solve(self, diag, pair, grad):
        """Δq (B,12) (zero on fixed bodies) solving H Δq = −grad."""
        out = np.zeros((self.model.body_count, 12))
        if not self.n:
            return out
        g = grad[self.free].ravel()
        D = diag[self.free]
        U = pair[self.pair_joints]
        if self.dense:
            H = np.zeros((self.n, self.n))
            nf = len(self.free)
            H4 = H.reshape(nf, 12, nf, 12)
            H4[np.arange(nf), :, np.arange(nf), :] = D
            for k in range(len(self._sp)):
                H4[self._sp[k], :, self._sc[k], :] += U[k]
                H4[self._sc[k], :, self._sp[k], :] += U[k].T
            try:
                cho = scipy.linalg.cho_factor(H, check_finite=False)
                x = scipy.linalg.cho_solve(cho, -g, check_finite=False)
            except np.linalg.LinAlgError:
                x = np.linalg.lstsq(H, -g, rcond=None)[0]
        else:
            vals = np.concatenate([D.ravel(), U.ravel(), U.ravel()])
            data = np.bincount(self._inv, weights=vals, minlength=self._nnz)
            A = scipy.sparse.csc_matrix((data, self._indices, self._indptr),
                                        shape=(self.n, self.n))
            lu = scipy.sparse.linalg.splu(A, permc_spec='MMD_AT_PLUS_A', diag_pivot_thresh=0.0,
                                          options={'SymmetricMode': True})
            x = lu.solve(-g)
        out[self.free] = x.reshape(-1, 12)
        return out
