"""Assemble and solve H Δq = −g over the free bodies, in one place.

H is block-sparse: a 12x12 block per free body on the diagonal and one per joint between two
free bodies off it (the joint graph). The solver is chosen once per model, by structure:
- dense Cholesky for up to DENSE_MAX_DOF unknowns (set-up cost dominates there);
- banded Cholesky (LAPACK pbtrf) when a reverse Cuthill-McKee ordering of the body graph
  gives a block bandwidth ≤ BAND_MAX_BLOCKS: chains and near-chains, cost O(n kd²), linear;
- otherwise sparse LU (SuperLU, symmetric mode, minimum-degree ordering of A+Aᵀ).
The sparsity pattern and the scatter of blocks into it are computed once per model; each
Newton iteration refills values with one bincount.

BLAS runs single-threaded inside the banded and sparse solves: OpenBLAS's threaded pbtrf
took 250-800 ms instead of 0.05 ms for a 120-DOF band on a loaded 2-core machine (its
threads spin on every panel). Dense solves are too small for OpenBLAS to thread.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg
from threadpoolctl import ThreadpoolController

DENSE_MAX_DOF = 96          # up to 8 free bodies: dense is faster than any sparse set-up
BAND_MAX_BLOCKS = 3         # block bandwidth up to which banded Cholesky beats SuperLU
_THREADS = None             # ThreadpoolController, made on first structured solve (scans libs once)


def _single_thread():
    global _THREADS
    if _THREADS is None:
        _THREADS = ThreadpoolController()
    return _THREADS.limit(limits=1, user_api='blas')


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
        self.kind = 'dense' if self.dense else 'sparse'
        if not self.dense and self.n:
            self._setup_banded(len(self.free), sp, sc) or self._setup_sparse(len(self.free), sp, sc)

    @staticmethod
    def _coords(a, b):
        """Row and column indices of the 144 entries of blocks (a_k, b_k): (len(a),12,12)."""
        r12 = np.arange(12)
        rows = 12 * a[:, None, None] + r12[None, :, None] + 0 * r12[None, None, :]
        cols = 12 * b[:, None, None] + r12[None, None, :] + 0 * r12[None, :, None]
        return rows, cols

    def _setup_banded(self, nf, sp, sc):
        adj = scipy.sparse.coo_matrix((np.ones(len(sp)), (sp, sc)), shape=(nf, nf)).tocsr()
        order = scipy.sparse.csgraph.reverse_cuthill_mckee(adj + adj.T, symmetric_mode=True)
        pos = np.empty(nf, dtype=np.int64)
        pos[order] = np.arange(nf)
        width = int(np.max(np.abs(pos[sp] - pos[sc]))) if len(sp) else 0
        if width > BAND_MAX_BLOCKS:
            return False
        self.kind = 'banded'
        self.kd = kd = 12 * (width + 1) - 1
        self._dof = (12 * pos[:, None] + np.arange(12)).ravel()       # old DOF -> new DOF
        fb = np.arange(nf)
        rd, cd = self._coords(pos[fb], pos[fb])
        ru, cu = self._coords(pos[sp], pos[sc])
        rows = np.concatenate([rd.ravel(), ru.ravel()])
        cols = np.concatenate([cd.ravel(), cu.ravel()])
        lo, hi = np.minimum(rows, cols), np.maximum(rows, cols)
        # upper storage ab[kd + i - j, j] = H[i, j], i <= j; keep the diagonal blocks' upper
        # triangles and every off-diagonal block (mirrored if it sits below the diagonal)
        keep = np.concatenate([(rd <= cd).ravel(), np.ones(ru.size, bool)])
        self._keep = keep
        self._band_index = (kd + lo - hi) * self.n + hi
        self._band_index = self._band_index[keep]
        return True

    def _setup_sparse(self, nf, sp, sc):
        self.kind = 'sparse'
        fb = np.arange(nf)
        rd, cd = self._coords(fb, fb)
        ru, cu = self._coords(sp, sc)
        rows = np.concatenate([rd.ravel(), ru.ravel(), cu.ravel()])
        cols = np.concatenate([cd.ravel(), cu.ravel(), ru.ravel()])
        # CSC order is (column, row); entries of several joints between the same two
        # bodies fall on one key and are summed by bincount.
        keys = cols.astype(np.int64) * self.n + rows
        uniq, self._inv = np.unique(keys, return_inverse=True)
        self._indices = (uniq % self.n).astype(np.int32)
        self._indptr = np.searchsorted(uniq // self.n, np.arange(self.n + 1)).astype(np.int32)
        self._nnz = len(uniq)
        return True

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
        elif self.kind == 'banded':
            vals = np.concatenate([D.ravel(), U.ravel()])[self._keep]
            ab = np.bincount(self._band_index, weights=vals,
                             minlength=(self.kd + 1) * self.n).reshape(self.kd + 1, self.n)
            rhs = np.empty(self.n)
            rhs[self._dof] = -g
            try:
                with _single_thread():
                    cb = scipy.linalg.cholesky_banded(ab, lower=False, check_finite=False)
                    y = scipy.linalg.cho_solve_banded((cb, False), rhs, check_finite=False)
            except np.linalg.LinAlgError:
                y = np.full(self.n, np.nan)    # not PD: reported as a non-finite Newton step
            x = y[self._dof]
        else:
            vals = np.concatenate([D.ravel(), U.ravel(), U.ravel()])
            data = np.bincount(self._inv, weights=vals, minlength=self._nnz)
            A = scipy.sparse.csc_matrix((data, self._indices, self._indptr),
                                        shape=(self.n, self.n))
            with _single_thread():
                lu = scipy.sparse.linalg.splu(A, permc_spec='MMD_AT_PLUS_A', diag_pivot_thresh=0.0,
                                              options={'SymmetricMode': True})
                x = lu.solve(-g)
        out[self.free] = x.reshape(-1, 12)
        return out
