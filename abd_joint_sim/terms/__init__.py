"""The constitutions, one module each, compiled (docs/physics.md):

- energy terms of the incremental potential Π (`energy(q, m, ctx)` and
  `accumulate(q, m, ctx, grad, diag, pair, project)`): `inertia` (the kinetic part),
  `ortho` (UID 1), `revolute` (UID 18), `driving` (UID 19), `limit` (UID 670), `damping`
  (joint damping, not a libuipc term). `accumulate` returns E(q) with the bits of `energy`,
  from the quantities its gradient needs: Newton's first assembly gives Π at its start;
- forces without energy, which enter only the prediction q̃ (`add_acceleration`):
  `gravity`, `torque` (UID 668).

`m` is the compiled model (solver/model_data.py), `ctx` the step's `StepContext`
(terms/context.py). Hessians are accumulated as 12x12 blocks: `diag` (B,12,12) per body
and `pair` (J,12,12) per joint for its (parent row, child column) block, the block
pattern the linear solver factorises. `project` asks for the PSD-projected Hessian (Newton
always does; the derivative tests also check the raw one). The step's list of terms is
solver/newton.py `potential` and `assemble`.
"""
