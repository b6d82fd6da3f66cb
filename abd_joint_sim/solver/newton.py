"""Newton's method with backtracking line search on the incremental potential.

    Π(q) = (s/2) Σ_free (q − q̃)ᵀ M (q − q̃) + Σ_terms E(q)

with s = 1 (BDF1) or 1/β = 9/4 (BDF2) (PHYSICS.md §2). Each iteration solves H Δq = −∇Π with
H the sum of PSD(-projected) term Hessians plus sM (so H is positive definite on free DOFs),
then halves α until Π(q ⊕ αΔq) ≤ Π(q) (roundoff slack ROUNDOFF·|Π|), where q ⊕ Δq applies
each body's step as a screw motion (solver/retraction.py; = q + Δq to first order).
Convergence (libuipc defaults): every free body's bounding-box corners move less than
velocity_tol·h under Δq, and max |Δq[3:12]| ≤ transrate_tol·h; and (ours) the Newton
decrement −½∇Πᵀ Δq, the predicted distance in energy to the minimum, is below what moving
all bodies by velocity_tol·h costs in the mass metric, s·½Σm(velocity_tol·h)². When H ≈ sM
the two tests agree; with a stiff mode (the ortho twist of a stretched A, large dt) a
step-size test alone accepts tiny steps far from the minimiser (docs/decisions.md). Hitting max_iterations, a
failed line search or a non-finite value is returned as a Status, never hidden.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from .retraction import ScrewRetraction

# Every term of Π is nonnegative and computed without cancellation, so Π's rounding error
# is a small multiple of eps·Π; below this relative decrement Newton cannot improve q.
ROUNDOFF = 1e-12


class Status(enum.Enum):
    CONVERGED = 'converged'
    MAX_ITERATIONS = 'max_iterations'
    LINE_SEARCH_FAILED = 'line_search_failed'
    NONFINITE = 'nonfinite'


@dataclass(frozen=True)
class NewtonResult:
    q: np.ndarray
    status: Status
    iterations: int
    line_search_iterations: int
    last_step_size: float       #: [m] largest corner displacement in the last Newton step


class NewtonSolver:
    def __init__(self, model, terms, system):
        self.model = model
        self.terms = terms
        self.system = system
        self.free = ~model.body_fixed
        self.retract = ScrewRetraction(model)
        self.M_free = np.ascontiguousarray(model.body_M[self.free])

    def potential(self, q, q_tilde, scale, ctx) -> float:
        d = (q - q_tilde)[self.free]
        E = 0.5 * scale * float(np.sum(np.matmul(self.M_free, d[:, :, None])[:, :, 0] * d))
        for term in self.terms:
            E += term.energy(q, ctx)
        return E

    def minimize(self, q_start, q_tilde, scale, ctx, q_other=None) -> NewtonResult:
        """Minimise Π from q_start, or from `q_other` if Π is lower there (World._single
        passes the warm start and q̃: the better guess wins, so a warm start never starts
        Newton at a higher Π than the plain prediction would)."""
        m = self.model
        spec = m.newton
        h = ctx.h
        B, J = m.body_count, m.joint_count
        q = q_start.copy()
        free = self.free
        corners = m.body_corners[free]
        ls_total = 0
        E = self.potential(q, q_tilde, scale, ctx)
        if q_other is not None:
            E_other = self.potential(q_other, q_tilde, scale, ctx)
            if E_other < E:
                q, E = q_other.copy(), E_other
        disp = np.inf
        # the energy that moving every body by velocity_tol·h costs in the mass metric
        energy_tol = 0.5 * float(np.sum(m.body_mass[free])) * (spec.velocity_tol * h) ** 2
        for it in range(1, spec.max_iterations + 1):
            grad = np.zeros((B, 12))
            diag = np.zeros((B, 12, 12))
            pair = np.zeros((J, 12, 12))
            grad[free] = scale * np.matmul(self.M_free, (q - q_tilde)[free][:, :, None])[:, :, 0]
            diag[free] = scale * self.M_free
            for term in self.terms:
                term.accumulate(q, ctx, grad, diag, pair)
            dq = self.system.solve(diag, pair, grad)
            if not np.all(np.isfinite(dq)):
                return NewtonResult(q, Status.NONFINITE, it, ls_total, np.inf)
            dqf = dq[free]
            move = dqf[:, None, :3] + np.matmul(corners, dqf[:, 3:12].reshape(-1, 3, 3).transpose(0, 2, 1))
            disp = float(np.max(np.linalg.norm(move, axis=2))) if len(dqf) else 0.0
            rate = float(np.max(np.abs(dqf[:, 3:12]))) if len(dqf) else 0.0
            decrement = -0.5 * float(np.sum(grad[free] * dqf))      # ≈ Π(q) − min Π
            converged = (disp <= spec.velocity_tol * h and rate <= spec.transrate_tol * h
                         and decrement <= scale * energy_tol)
            # At the roundoff floor the line search cannot see a decrease any more: when the
            # predicted decrease −½gᵀΔq is below the rounding error of Π, q is as good as
            # double precision allows, whatever the tolerances ask.
            if decrement <= ROUNDOFF * abs(E):
                return NewtonResult(q, Status.CONVERGED, it, ls_total, disp)
            alpha = 1.0
            # The step follows rigid screw motions (solver/retraction.py): a stiff body turns
            # without stretching. Once the tolerances hold only the full step is tried:
            # whether it lowers Π is then decided by rounding, and halving would only spend
            # iterations.
            for _ in range(spec.line_search_max):
                trial = self.retract(q, alpha * dq)
                E_new = self.potential(trial, q_tilde, scale, ctx)
                if E_new <= E + ROUNDOFF * abs(E):
                    break
                if converged:      # the step is below tolerance: q is as good
                    return NewtonResult(q, Status.CONVERGED, it, ls_total, disp)
                alpha *= 0.5
                ls_total += 1
            else:
                return NewtonResult(q, Status.LINE_SEARCH_FAILED, it, ls_total, disp)
            if not np.isfinite(E_new):
                return NewtonResult(q, Status.NONFINITE, it, ls_total, disp)
            q = trial
            E = E_new
            if converged and alpha == 1.0:     # a cut step left part of Δq undone: go on
                return NewtonResult(q, Status.CONVERGED, it, ls_total, disp)
        return NewtonResult(q, Status.MAX_ITERATIONS, spec.max_iterations, ls_total, disp)
