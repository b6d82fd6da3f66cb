"""The inertia part of the incremental potential (docs/physics.md "Time integration"):

    E = (s/2) Σ_free (q − q̃)ᵀ M (q − q̃),   ∇E = s M (q − q̃),   ∇²E = s M

with s = 1 (BDF1) or 1/β = 9/4 (BDF2). It makes Newton's matrix positive definite on the
free bodies.
"""
from __future__ import annotations

from numba import njit


@njit(cache=True, error_model='numpy')
def energy(q, m, ctx):
    q_tilde, M = ctx.q_tilde, m.body_M
    E = 0.0
    for b in m.free_bodies:
        for r in range(12):
            Md = 0.0
            for c in range(12):
                Md += M[b, r, c] * (q[b, c] - q_tilde[b, c])
            E += Md * (q[b, r] - q_tilde[b, r])
    return 0.5 * ctx.scale * E


@njit(cache=True, error_model='numpy')
def accumulate(q, m, ctx, grad, diag, pair, project):
    q_tilde, M, s = ctx.q_tilde, m.body_M, ctx.scale
    for b in m.free_bodies:
        for r in range(12):
            Md = 0.0
            for c in range(12):
                Md += M[b, r, c] * (q[b, c] - q_tilde[b, c])
                diag[b, r, c] += s * M[b, r, c]
            grad[b, r] += s * Md


@njit(cache=True, error_model='numpy')
def accumulate_gradient(q, m, ctx, grad):
    """∇E only (Newton with a reused factorisation needs no Hessian)."""
    q_tilde, M, s = ctx.q_tilde, m.body_M, ctx.scale
    for b in m.free_bodies:
        for r in range(12):
            Md = 0.0
            for c in range(12):
                Md += M[b, r, c] * (q[b, c] - q_tilde[b, c])
            grad[b, r] += s * Md
