"""Newton's method with a backtracking line search on the incremental potential
(docs/physics.md "Newton"):

    Π(q) = (s/2) Σ_free (q − q̃)ᵀ M (q − q̃) + Σ_terms E(q)

Each iteration solves H Δq = −∇Π (H = sM + the PSD-projected term Hessians); a step within
the tolerances is taken whole and ends Newton, any other is halved until Π(q ⊕ αΔq) ≤ Π(q) +
ROUNDOFF·|Π| (⊕: each body's screw motion, retraction.py). Converged: every free body's
bounding-box corners move less than velocity_tol·h, max |Δq[3:12]| ≤ transrate_tol·h, and
the decrement −½∇ΠᵀΔq ≤ s·½Σm(velocity_tol·h)²; or a decrement below ROUNDOFF·|Π|. Max
iterations, a failed line search and a non-finite value are returned as a status.

`potential`, `assemble` and `references` loop over the lists of terms (terms/__init__.py),
written out before compiling (jit/unroll.py).
"""
from __future__ import annotations

import math

from ..jit import flat, kernel
from ..jit.unroll import unrolled
from ..terms import ENERGY_TERMS, REFERENCE_TERMS, inertia, joints
from . import linsolve
from .retraction import retract

ROUNDOFF = 1e-12        # Π's relative rounding (its terms are ≥ 0, without cancellation)
# status codes (report.Status)
CONVERGED, MAX_ITERATIONS, LINE_SEARCH_FAILED, NONFINITE = 0, 1, 2, 3


@kernel
@unrolled
def potential(q, m, ctx):
    """Π(q): the terms' energies summed in ENERGY_TERMS' order."""
    E = 0.0
    for term in ENERGY_TERMS:
        # a term the model lacks is not called (the call costs reference counts, docs/speed.md)
        if joints(term) is None or getattr(m, joints(term)).size:
            E += term.energy(q, m, ctx)
    return E


@kernel
@unrolled
def references(m, q0, q_prev, angle_start, h, bdf2, work, ref):
    """The step's rows of StepContext.angle_ref (ref), each term of terms.REFERENCE_TERMS
    writing its own: the limits' margins at the step's start, the dampers' linearisations
    at Newton's start q0 (and, with bdf2, q_prev). Returns ref."""
    for term in REFERENCE_TERMS:
        if getattr(m, joints(term)).size:
            term.references(m, q0, q_prev, angle_start, h, bdf2, work, ref)
    return ref


@kernel
@unrolled
def assemble(q, m, ctx, grad, diag, pair):
    """∇Π into grad (B,12) and the PSD-projected ∇²Π into diag; returns (joint blocks, Π(q)
    with `potential`'s bits). The joint blocks are `pair`, or m.constant_pair itself when no
    term adds to it (no copy). The constant Hessians (UID 18, s·M) are summed once per model
    (model_data.constant_blocks); their terms (CONSTANT_HESSIAN) add only gradients here."""
    flat.fill(grad, 0.0)
    scales = m.inertia_scales
    k = 0 if ctx.scale == scales[0] else (1 if ctx.scale == scales[1] else -1)
    if k >= 0:
        flat.copy(diag, m.constant_diag_inertia[k])
        E = inertia.accumulate_gradient(q, m, ctx, grad)
    else:                                   # another s (a caller's own context)
        flat.copy(diag, m.constant_diag)
        E = inertia.accumulate(q, m, ctx, grad, diag, pair, True)
    if m.pair_constant:
        pair = m.constant_pair              # read only: no term below adds to it
    else:
        flat.copy(pair, m.constant_pair)
    for term in ENERGY_TERMS:
        if term is not inertia and (joints(term) is None or getattr(m, joints(term)).size):
            if term.CONSTANT_HESSIAN:
                E += term.accumulate_gradient(q, m, ctx, grad)
            else:
                E += term.accumulate(q, m, ctx, grad, diag, pair, True)
    return pair, E


@kernel
def all_finite(x):
    for b in range(x.shape[0]):
        for r in range(x.shape[1]):
            if not math.isfinite(x[b, r]):
                return False
    return True


@kernel
def step_within_tolerance(dq, m, h):
    """libuipc's tests: the largest bounding-box corner displacement under Δq ≤ velocity_tol·h
    and max |Δq[3:12]| ≤ transrate_tol·h."""
    disp2 = 0.0             # the largest squared displacement: one square root, at the end
    rate = 0.0
    corners = m.body_corners
    for b in m.free_bodies:
        for i in range(8):
            n2 = 0.0
            for r in range(3):
                x = dq[b, r]
                for c in range(3):
                    x += corners[b, i, c] * dq[b, 3 + 3 * r + c]
                n2 += x * x
            if n2 > disp2 or n2 != n2:
                disp2 = n2
        for a in range(3, 12):
            x = abs(dq[b, a])
            if x > rate or x != x:
                rate = x
    # (sqrt is monotone and correctly rounded: the root of the largest is the largest root)
    return math.sqrt(disp2) <= m.velocity_tol * h and rate <= m.transrate_tol * h


@kernel
def minimize(m, ctx, q, ws, try_alt):
    """Minimise Π from q (overwritten with the result) or from q̃ if Π is lower there; with
    `try_alt` (q extrapolated, ws.q_alt plain) where q̃ beats q, from the lowest of the
    three. Returns (status, iterations, line-search halvings)."""
    h, scale = ctx.h, ctx.scale
    grad, diag, pair, dq, trial = ws.grad, ws.diag, ws.pair, ws.dq, ws.trial
    joint_blocks, E = assemble(q, m, ctx, grad, diag, pair)     # (q: nearly always the start)
    E_tilde = potential(ctx.q_tilde, m, ctx)
    moved = False
    if try_alt and E_tilde < E:
        E_alt = potential(ws.q_alt, m, ctx)
        if E_alt < E:
            flat.copy(q, ws.q_alt)
            E = E_alt
            moved = True
    if E_tilde < E:
        flat.copy(q, ctx.q_tilde)
        E = E_tilde
        moved = True
    energy_tol = 0.5 * m.free_mass * (m.velocity_tol * h) ** 2
    flat.fill(dq, 0.0)                          # fixed bodies' rows are never solved for
    halvings = 0
    for it in range(1, m.max_iterations + 1):
        if it > 1 or moved:
            joint_blocks = assemble(q, m, ctx, grad, diag, pair)[0]
        linsolve.solve(m, diag, joint_blocks, grad, dq, ws)
        if not all_finite(dq):
            return NONFINITE, it, halvings
        dec = 0.0
        for b in m.free_bodies:
            for r in range(12):
                dec += grad[b, r] * dq[b, r]
        decrement = -0.5 * dec                  # ≈ Π(q) − min Π
        converged = step_within_tolerance(dq, m, h) and decrement <= scale * energy_tol
        if decrement <= ROUNDOFF * abs(E):
            return CONVERGED, it, halvings
        if converged:                           # the full step, without Π there
            retract(q, dq, 1.0, m, ws, trial)
            flat.copy(q, trial)
            return CONVERGED, it, halvings
        alpha = 1.0
        found = False
        E_new = E
        for _ in range(m.line_search_max):
            retract(q, dq, alpha, m, ws, trial)
            E_new = potential(trial, m, ctx)
            if E_new <= E + ROUNDOFF * abs(E):
                found = True
                break
            alpha *= 0.5
            halvings += 1
        if not found:
            return LINE_SEARCH_FAILED, it, halvings
        if not math.isfinite(E_new):
            return NONFINITE, it, halvings
        flat.copy(q, trial)
        E = E_new
    return MAX_ITERATIONS, m.max_iterations, halvings
