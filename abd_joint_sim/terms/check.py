"""Derivative checks for energy terms (after MuJoCo's minimize.check_norm).

`check_term` compares a term's gradient with central finite differences of its energy and
its (unprojected) Hessian with finite differences of its gradient, checks symmetry, and
that the projected Hessian is PSD. It raises ValueError with a specific message, so a
broken term cannot pass silently (test/test_terms.py feeds it broken terms on purpose).
"""
from __future__ import annotations

import numpy as np


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), np.max(np.abs(a)), 1e-300))


def check_term(term, model, q, ctx, *, eps=1e-6, rtol=1e-5, free_only=True):
    """Raise ValueError if `term`'s derivatives at q disagree with finite differences."""
    E, g, H = term.dense(model, q, ctx, project=False)
    _, _, Hp = term.dense(model, q, ctx, project=True)
    dofs = np.arange(q.size)
    if free_only:
        dofs = np.concatenate([np.arange(12 * b, 12 * b + 12) for b in np.flatnonzero(~model.body_fixed)])
    flat = q.ravel()
    g_fd = np.zeros(len(dofs))
    H_fd = np.zeros((len(dofs), len(dofs)))
    for k, d in enumerate(dofs):
        step = eps * max(1.0, abs(flat[d]))
        qp, qm = flat.copy(), flat.copy()
        qp[d] += step
        qm[d] -= step
        qp, qm = qp.reshape(q.shape), qm.reshape(q.shape)
        g_fd[k] = (term.energy(qp, ctx) - term.energy(qm, ctx)) / (2 * step)
        H_fd[:, k] = (term.dense(model, qp, ctx, project=False)[1][dofs]
                      - term.dense(model, qm, ctx, project=False)[1][dofs]) / (2 * step)
    if not np.all(np.isfinite(g)) or not np.all(np.isfinite(H)):
        raise ValueError(f'{term.name}: non-finite gradient or Hessian')
    err = _rel(g[dofs], g_fd)
    if err > rtol:
        raise ValueError(f'{term.name}: gradient disagrees with finite differences (rel. error {err:.2e})')
    Hs = H[np.ix_(dofs, dofs)]
    err = _rel(Hs, H_fd)
    if err > rtol:
        raise ValueError(f'{term.name}: Hessian disagrees with finite differences (rel. error {err:.2e})')
    if _rel(Hs, Hs.T) > 1e-12:
        raise ValueError(f'{term.name}: Hessian is not symmetric')
    w = np.linalg.eigvalsh(Hp[np.ix_(dofs, dofs)])
    if w.min() < -1e-9 * max(1.0, abs(w).max()):
        raise ValueError(f'{term.name}: projected Hessian is not PSD (min eigenvalue {w.min():.3e})')
    return E
