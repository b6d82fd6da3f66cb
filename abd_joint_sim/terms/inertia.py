"""The inertia part of the incremental potential (docs/physics.md "Time integration"):

    E = (s/2) Σ_free (q − q̃)ᵀ M (q − q̃),   ∇E = s M (q − q̃),   ∇²E = s M

with s = 1 (BDF1) or 1/β = 9/4 (BDF2). It makes Newton's matrix positive definite on the
free bodies.

M = M̄ ⊗ I3: spatial row k couples only [p_k, A_k0, A_k1, A_k2] through the 4x4
M̄ = [[m, m c̄ᵀ], [m c̄, S̄]] (m.body_Mbar): 48 nonzero entries, summed in the dense
product's order (its bits). s M is added into Newton's constant blocks once per model
(`add_hessian`, model_data.constant_blocks); the step adds only `accumulate_gradient`.
"""
from __future__ import annotations

import numpy as np

from ..jit import kernel

NAME = None                 #: not listed in Solver.terms (every scene has it)
STORED = False              #: World.mechanical_energy counts the kinetic energy itself
CONSTANT_HESSIAN = True     #: Newton adds only the gradient (accumulate_gradient)
FIELDS = ()                 #: none (it reads body_Mbar and free_bodies)


def used(model) -> bool:
    return True


def from_scene(scene, model) -> dict:
    """No Model fields of its own: it reads the bodies'."""
    return {}


def min_eigenvalue(Mbar):
    """(B,) μ_min(M̄) per body: the least the inertia term s M gives any direction of a body
    in Newton's matrix (per unit s), which the unprojected Hessians may draw on."""
    return np.linalg.eigvalsh(Mbar)[:, 0] if len(Mbar) else np.zeros(0)


def build(model, data) -> dict:
    return {}


@kernel
def _row_products(q, q_tilde, b, k, Mb):
    """(d, M̄d) of spatial row k of body b, d = (q − q̃)[p_k, A_k0, A_k1, A_k2], as 8 scalars."""
    d0 = q[b, k] - q_tilde[b, k]
    d1 = q[b, 3 + 3 * k] - q_tilde[b, 3 + 3 * k]
    d2 = q[b, 4 + 3 * k] - q_tilde[b, 4 + 3 * k]
    d3 = q[b, 5 + 3 * k] - q_tilde[b, 5 + 3 * k]
    m0 = Mb[0, 0] * d0 + Mb[0, 1] * d1 + Mb[0, 2] * d2 + Mb[0, 3] * d3
    m1 = Mb[1, 0] * d0 + Mb[1, 1] * d1 + Mb[1, 2] * d2 + Mb[1, 3] * d3
    m2 = Mb[2, 0] * d0 + Mb[2, 1] * d1 + Mb[2, 2] * d2 + Mb[2, 3] * d3
    m3 = Mb[3, 0] * d0 + Mb[3, 1] * d1 + Mb[3, 2] * d2 + Mb[3, 3] * d3
    return d0, d1, d2, d3, m0, m1, m2, m3


@kernel(inline='always')
def _add_body_energy(E, r0, r1, r2):
    """E + (M d)ᵀd of one body from its three spatial rows' `_row_products`, summed in q's
    order r = 0..11 (the positions' rows, then A's: the same sum as the dense product)."""
    E += r0[4] * r0[0]
    E += r1[4] * r1[0]
    E += r2[4] * r2[0]
    for d0, d1, d2, d3, m0, m1, m2, m3 in (r0, r1, r2):
        E += m1 * d1
        E += m2 * d2
        E += m3 * d3
    return E


@kernel
def energy(q, m, ctx):
    q_tilde, Mbar = ctx.q_tilde, m.body_Mbar
    E = 0.0
    for b in m.free_bodies:
        Mb = Mbar[b]
        E = _add_body_energy(E, _row_products(q, q_tilde, b, 0, Mb), _row_products(q, q_tilde, b, 1, Mb),
                             _row_products(q, q_tilde, b, 2, Mb))
    return 0.5 * ctx.scale * E


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E and s·M; returns E (the bits of `energy`)."""
    E = accumulate_gradient(q, m, ctx, grad)
    add_hessian(m.free_bodies, m.body_Mbar, ctx.scale, diag)
    return E


@kernel
def add_hessian(free_bodies, Mbar, s, diag):
    """s M of every free body added into its block of diag (its 48 nonzero entries)."""
    for b in free_bodies:
        Mb = Mbar[b]
        s00, s01, s02, s03 = s * Mb[0, 0], s * Mb[0, 1], s * Mb[0, 2], s * Mb[0, 3]
        s10, s11, s12, s13 = s * Mb[1, 0], s * Mb[1, 1], s * Mb[1, 2], s * Mb[1, 3]
        s20, s21, s22, s23 = s * Mb[2, 0], s * Mb[2, 1], s * Mb[2, 2], s * Mb[2, 3]
        s30, s31, s32, s33 = s * Mb[3, 0], s * Mb[3, 1], s * Mb[3, 2], s * Mb[3, 3]
        D = diag[b]
        for k in range(3):
            p, a0, a1, a2 = k, 3 + 3 * k, 4 + 3 * k, 5 + 3 * k
            D[p, p] += s00
            D[p, a0] += s01
            D[p, a1] += s02
            D[p, a2] += s03
            D[a0, p] += s10
            D[a0, a0] += s11
            D[a0, a1] += s12
            D[a0, a2] += s13
            D[a1, p] += s20
            D[a1, a0] += s21
            D[a1, a1] += s22
            D[a1, a2] += s23
            D[a2, p] += s30
            D[a2, a0] += s31
            D[a2, a1] += s32
            D[a2, a2] += s33


@kernel
def accumulate_gradient(q, m, ctx, grad):
    """∇E only: Newton's assembly starts from s·M summed into the constant blocks once per
    model (add_hessian). Returns E (the bits of `energy`)."""
    q_tilde, Mbar, s = ctx.q_tilde, m.body_Mbar, ctx.scale
    E = 0.0
    for b in m.free_bodies:
        E = _body_gradient(q, q_tilde, b, Mbar[b], s, grad, E)
    return 0.5 * s * E


@kernel
def _body_gradient(q, q_tilde, b, Mb, s, grad, E):
    """grad[b] += s M (q − q̃)_b, row block by row block; returns E plus the body's (M d)ᵀd."""
    r0 = _row_products(q, q_tilde, b, 0, Mb)
    r1 = _row_products(q, q_tilde, b, 1, Mb)
    r2 = _row_products(q, q_tilde, b, 2, Mb)
    for k, (d0, d1, d2, d3, m0, m1, m2, m3) in enumerate((r0, r1, r2)):
        grad[b, k] += s * m0
        grad[b, 3 + 3 * k] += s * m1
        grad[b, 4 + 3 * k] += s * m2
        grad[b, 5 + 3 * k] += s * m3
    return _add_body_energy(E, r0, r1, r2)
