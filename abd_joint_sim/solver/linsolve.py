"""Solve Newton's system H Δq = −∇Π over the free bodies (docs/physics.md "Newton").

H has a 12x12 block per free body (`diag`) and per joint between free bodies (`pair`, the
(parent, child) block). `structure` chooses once per model: TREE (a forest: chains, trees)
is a block Cholesky leaves first, each tree rooted at its centre (no fill-in, linear cost;
docs/decisions.md); DENSE (closed loops) a dense Cholesky of up to DENSE_MAX_DOF unknowns.
A matrix that is not positive definite gives a NaN step (Newton reports it non-finite).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..jit import flat, kernel
from ..smallmat import cholesky, lower_solve, upper_solve

DENSE, TREE = 0, 1
DENSE_MAX_DOF = 12 * 64     # a loop of 64 free bodies: ~10⁸ flops per Newton iteration


@dataclass(frozen=True)
class Structure:
    kind: int                   #: TREE or DENSE
    order: np.ndarray           #: (F,) elimination order over free slots, leaves first
    parent: np.ndarray          #: (F,) elimination parent slot, -1 at a root
    edge_ptr: np.ndarray        #: (F+1,) CSR pointer into edge_joints
    edge_joints: np.ndarray     #: joints between a slot and its parent
    slot: np.ndarray            #: (B,) slot of each free body, -1 if fixed
    between_free: np.ndarray    #: (J,) bool: both bodies free


def find_root(root, a):
    """The root of node a in the union-find forest `root` (a list of parents), halving paths."""
    while root[a] != a:
        root[a] = root[root[a]]
        a = root[a]
    return a


def _forest(nf, sp, sc):
    """(order, parent) of a children-first elimination over the free-body graph with edges
    (sp, sc) (slots; parallel joints are one edge), or None if it has a cycle. Leaves are
    peeled off in rounds, so each tree's root is its centre."""
    adj = [set() for _ in range(nf)]
    root = list(range(nf))
    for a, b in zip(sp.tolist(), sc.tolist()):
        if b in adj[a]:
            continue
        if a == b:
            return None
        ra, rb = find_root(root, a), find_root(root, b)
        if ra == rb:
            return None
        root[ra] = rb
        adj[a].add(b)
        adj[b].add(a)
    parent = np.full(nf, -1, dtype=np.int64)
    degree = [len(adj[a]) for a in range(nf)]
    removed = [False] * nf
    order = []
    leaves = [a for a in range(nf) if degree[a] <= 1]
    while leaves:
        next_leaves = []
        for a in leaves:
            rest = [b for b in sorted(adj[a]) if not removed[b]]
            removed[a] = True
            order.append(a)
            if rest:                            # (a leaf has one neighbour left at most)
                b = rest[0]
                parent[a] = b
                degree[b] -= 1
                if degree[b] == 1:
                    next_leaves.append(b)
        leaves = next_leaves
    return np.array(order, dtype=np.int64), parent


def structure(model, force_dense: bool = False) -> Structure:
    """How Newton's system of this model is solved (`force_dense`: densely, for the tests);
    ValueError for a closed loop of more than DENSE_MAX_DOF / 12 free bodies."""
    fixed = model.body_fixed
    free_idx = np.flatnonzero(~fixed)
    nf = len(free_idx)
    slot = np.full(model.body_count, -1, dtype=np.int64)
    slot[free_idx] = np.arange(nf)
    p, c = model.joint_parent, model.joint_child
    between = ~fixed[p] & ~fixed[c]
    joints = np.flatnonzero(between)
    sp, sc = slot[p[joints]], slot[c[joints]]
    forest = None if force_dense else _forest(nf, sp, sc)
    if forest is None:
        if 12 * nf > DENSE_MAX_DOF and not force_dense:
            raise ValueError(f'the joints between free bodies form a closed loop and there are '
                             f'{nf} free bodies: at most {DENSE_MAX_DOF // 12} are supported '
                             'with a loop (chains and trees of any size are)')
        z = np.zeros(nf, dtype=np.int64)
        return Structure(DENSE, z, z - 1, np.zeros(nf + 1, dtype=np.int64),
                         np.zeros(0, dtype=np.int64), slot, between)
    order, parent = forest
    edge_ptr = np.zeros(nf + 1, dtype=np.int64)
    edge_joints = []
    for s in range(nf):
        if parent[s] >= 0:
            ends = {s, int(parent[s])}
            edge_joints += [int(j) for j, a, b in zip(joints, sp, sc) if {int(a), int(b)} == ends]
        edge_ptr[s + 1] = len(edge_joints)
    return Structure(TREE, order, parent, edge_ptr, np.array(edge_joints, dtype=np.int64), slot, between)


@kernel
def solve(m, diag, pair, grad, dq, ws):
    """dq = −H⁻¹ grad on the free bodies (NaN if H is not positive definite), working in
    ws (workspace.Workspace); diag may be overwritten."""
    if m.solve_kind == TREE:
        solve_tree(m, diag, pair, grad, dq, ws)
    else:
        solve_dense(m, diag, pair, grad, dq, ws)


@kernel
def solve_dense(m, diag, pair, grad, dq, ws):
    """Dense path: H over the free bodies, Cholesky; NaN if not PD."""
    free_idx, jp, jc = m.free_bodies, m.joint_parent, m.joint_child
    pair_joints, slot = m.joint_between_free, m.body_slot
    nf = free_idx.size
    n = 12 * nf
    H = ws.dense_H
    flat.fill(H, 0.0)
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
    x = ws.dense_x
    for s in range(nf):
        for r in range(12):
            x[12 * s + r] = -grad[free_idx[s], r]
    if not cholesky(H, n):
        x[:] = np.nan
    else:
        lower_solve(H, x, n)
        upper_solve(H, x, n)
    for s in range(nf):
        for r in range(12):
            dq[free_idx[s], r] = x[12 * s + r]


@kernel
def factor_block(blocks, b, inv_ds, slot):
    """Lower Cholesky factor of the 12x12 W = blocks[b] in place, inv_d = inv_ds[slot] =
    1/diag(L); False if W is not PD. Three passes (rows 0–2; columns 0–2 of rows 3–11; the
    rest), each entry the row-by-row loop's sum in its order (its bits, test_solver.py), which
    the compiler unrolls completely: twice as fast. (Block kernels take an array and an
    index: a view made in a loop costs two atomic reference counts, docs/speed.md.)"""
    W, inv_d = blocks[b], inv_ds[slot]
    for i in range(3):
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
    for i in range(3, 12):
        for j in range(3):
            s = W[i, j]
            for k in range(j):
                s -= W[i, k] * W[j, k]
            W[i, j] = s * inv_d[j]
    for i in range(3, 12):
        for j in range(3, i + 1):
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


@kernel
def forward_vector12(blocks, b, inv_ds, ys, slot):
    """y = L⁻¹ y for the 12-vector y = ys[slot], L = blocks[b] factored by factor_block (its
    inv_ds[slot]): the loop form (test/physics_helpers.py `forward_block`) with the loop
    bounds known to the compiler (~4x faster); the same operations in the same order."""
    L, inv_d, y = blocks[b], inv_ds[slot], ys[slot]
    for i in range(12):
        acc = y[i]
        for k in range(i):
            acc -= L[i, k] * y[k]
        y[i] = acc * inv_d[i]


@kernel
def forward_block12(blocks, b, inv_ds, Xs, slot, src, j, transposed):
    """X = L⁻¹ U into X = Xs[slot], U = src[j] (or its transpose; src may be Xs, j = slot),
    L = blocks[b], inv_d = inv_ds[slot]: the copy (0.0 + U) and the loop form (`forward_block`
    with 12 columns) in one pass, their bits (test_solver.py). Row i in 12 locals: the SLP
    vectoriser (jit/slp.py) makes each run of 4 columns one vector operation."""
    L, inv_d, X, U = blocks[b], inv_ds[slot], Xs[slot], src[j]
    for i in range(12):
        if transposed:
            x0, x1, x2, x3 = 0.0 + U[0, i], 0.0 + U[1, i], 0.0 + U[2, i], 0.0 + U[3, i]
            x4, x5, x6, x7 = 0.0 + U[4, i], 0.0 + U[5, i], 0.0 + U[6, i], 0.0 + U[7, i]
            x8, x9, x10, x11 = 0.0 + U[8, i], 0.0 + U[9, i], 0.0 + U[10, i], 0.0 + U[11, i]
        else:
            x0, x1, x2, x3 = 0.0 + U[i, 0], 0.0 + U[i, 1], 0.0 + U[i, 2], 0.0 + U[i, 3]
            x4, x5, x6, x7 = 0.0 + U[i, 4], 0.0 + U[i, 5], 0.0 + U[i, 6], 0.0 + U[i, 7]
            x8, x9, x10, x11 = 0.0 + U[i, 8], 0.0 + U[i, 9], 0.0 + U[i, 10], 0.0 + U[i, 11]
        for k in range(i):
            lik = L[i, k]
            x0 -= lik * X[k, 0]
            x1 -= lik * X[k, 1]
            x2 -= lik * X[k, 2]
            x3 -= lik * X[k, 3]
            x4 -= lik * X[k, 4]
            x5 -= lik * X[k, 5]
            x6 -= lik * X[k, 6]
            x7 -= lik * X[k, 7]
            x8 -= lik * X[k, 8]
            x9 -= lik * X[k, 9]
            x10 -= lik * X[k, 10]
            x11 -= lik * X[k, 11]
        di = inv_d[i]
        X[i, 0] = x0 * di
        X[i, 1] = x1 * di
        X[i, 2] = x2 * di
        X[i, 3] = x3 * di
        X[i, 4] = x4 * di
        X[i, 5] = x5 * di
        X[i, 6] = x6 * di
        X[i, 7] = x7 * di
        X[i, 8] = x8 * di
        X[i, 9] = x9 * di
        X[i, 10] = x10 * di
        X[i, 11] = x11 * di


@kernel
def schur_update12(Xs, ys, slot, blocks, bp, p):
    """W −= XᵀX (lower half only: the upper keeps stale values) and b −= Xᵀy, X = Xs[slot],
    y = ys[slot], W = blocks[bp], b = ys[p]: a child eliminated into its parent. Rows 0–3
    over columns 0–3, 4–7 over 0–7, 8–11 over all, held in locals: runs of 4 columns the SLP
    vectoriser (jit/slp.py) makes one vector operation (a third of the square's work); each
    entry's subtractions in the order of k, a loop's bits."""
    X, y, W, b = Xs[slot], ys[slot], blocks[bp], ys[p]
    for r in range(4):
        w0, w1, w2, w3 = W[r, 0], W[r, 1], W[r, 2], W[r, 3]
        br = b[r]
        for k in range(12):
            xkr = X[k, r]
            w0 -= xkr * X[k, 0]
            w1 -= xkr * X[k, 1]
            w2 -= xkr * X[k, 2]
            w3 -= xkr * X[k, 3]
            br -= xkr * y[k]
        W[r, 0], W[r, 1], W[r, 2], W[r, 3] = w0, w1, w2, w3
        b[r] = br
    for r in range(4, 8):
        w0, w1, w2, w3 = W[r, 0], W[r, 1], W[r, 2], W[r, 3]
        w4, w5, w6, w7 = W[r, 4], W[r, 5], W[r, 6], W[r, 7]
        br = b[r]
        for k in range(12):
            xkr = X[k, r]
            w0 -= xkr * X[k, 0]
            w1 -= xkr * X[k, 1]
            w2 -= xkr * X[k, 2]
            w3 -= xkr * X[k, 3]
            w4 -= xkr * X[k, 4]
            w5 -= xkr * X[k, 5]
            w6 -= xkr * X[k, 6]
            w7 -= xkr * X[k, 7]
            br -= xkr * y[k]
        W[r, 0], W[r, 1], W[r, 2], W[r, 3] = w0, w1, w2, w3
        W[r, 4], W[r, 5], W[r, 6], W[r, 7] = w4, w5, w6, w7
        b[r] = br
    for r in range(8, 12):
        w0, w1, w2, w3, w4, w5 = W[r, 0], W[r, 1], W[r, 2], W[r, 3], W[r, 4], W[r, 5]
        w6, w7, w8, w9, w10, w11 = W[r, 6], W[r, 7], W[r, 8], W[r, 9], W[r, 10], W[r, 11]
        br = b[r]
        for k in range(12):
            xkr = X[k, r]
            w0 -= xkr * X[k, 0]
            w1 -= xkr * X[k, 1]
            w2 -= xkr * X[k, 2]
            w3 -= xkr * X[k, 3]
            w4 -= xkr * X[k, 4]
            w5 -= xkr * X[k, 5]
            w6 -= xkr * X[k, 6]
            w7 -= xkr * X[k, 7]
            w8 -= xkr * X[k, 8]
            w9 -= xkr * X[k, 9]
            w10 -= xkr * X[k, 10]
            w11 -= xkr * X[k, 11]
            br -= xkr * y[k]
        W[r, 0], W[r, 1], W[r, 2], W[r, 3], W[r, 4], W[r, 5] = w0, w1, w2, w3, w4, w5
        W[r, 6], W[r, 7], W[r, 8], W[r, 9], W[r, 10], W[r, 11] = w6, w7, w8, w9, w10, w11
        b[r] = br


@kernel
def solve_tree(m, diag, pair, grad, dq, ws):
    """Block Cholesky along a forest of free bodies, leaves first (no fill-in, linear cost).
    For node k with elimination parent p and U = H[k, p]: L_kk = chol(D_k), X = L_kk⁻¹ U,
    D_p −= XᵀX; forward y_k = L_kk⁻¹ b_k, b_p −= Xᵀ y_k; backward x_k = L_kk⁻ᵀ (y_k − X x_p).
    NaN if not PD. `diag` is factored in place (a copy would double the memory traffic)."""
    free_idx, jp, order, eparent = m.free_bodies, m.joint_parent, m.tree_order, m.tree_parent
    edge_ptr, edge_joint = m.tree_edge_ptr, m.tree_edge_joints
    nf = free_idx.size
    X, y, inv_d = ws.tree_X, ws.tree_y, ws.tree_inv_d
    for s in range(nf):
        b = free_idx[s]
        for r in range(12):
            y[s, r] = -grad[b, r]
    ok = True
    for t in range(nf):
        s = order[t]
        bs = free_idx[s]
        if not factor_block(diag, bs, inv_d, s):
            ok = False
            break
        forward_vector12(diag, bs, inv_d, y, s)
        p = eparent[s]
        if p < 0:
            continue
        e0 = edge_ptr[s]
        j = edge_joint[e0]
        if edge_ptr[s + 1] == e0 + 1:       # U = H[s, p]: the joint's block, or its transpose
            forward_block12(diag, bs, inv_d, X, s, pair, j, jp[j] != bs)
        else:                               # several joints: U = Σ pair or pairᵀ, summed in X
            for e in range(e0, edge_ptr[s + 1]):
                j = edge_joint[e]
                for r in range(12):
                    for c in range(12):
                        u = pair[j, r, c] if jp[j] == bs else pair[j, c, r]
                        X[s, r, c] = u if e == e0 else X[s, r, c] + u
            forward_block12(diag, bs, inv_d, X, s, X, s, False)
        schur_update12(X, y, s, diag, free_idx[p], p)      # D_p −= XᵀX, b_p −= Xᵀy
    if not ok:
        for s in range(nf):
            for r in range(12):
                dq[free_idx[s], r] = np.nan
        return
    for t in range(nf - 1, -1, -1):
        s = order[t]
        p = eparent[s]
        b = free_idx[s]
        if p >= 0:
            for r in range(12):
                acc = 0.0
                for c in range(12):
                    acc += X[s, r, c] * y[p, c]
                y[s, r] -= acc
        for i in range(11, -1, -1):     # Lᵀ x = y, k downwards: no chain of dependent sums
            acc = y[s, i]
            for k in range(11, i, -1):
                acc -= diag[b, k, i] * y[s, k]
            y[s, i] = acc * inv_d[s, i]
    for s in range(nf):
        for r in range(12):
            dq[free_idx[s], r] = y[s, r]
