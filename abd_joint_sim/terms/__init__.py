"""The constitutions, one module each, compiled (docs/physics.md). `TERMS` lists them once.

Every term module holds:
- NAME (as `Solver.terms` lists it; None for the inertia, which every scene has), `used(model)`;
- `from_scene(scene, model)`, its fields of the Model (model.compile_scene asks every term in
  TERMS' order), with the scene checks that belong to it;
- FIELDS, the fields of the compiled model (solver/model_data.py) it owns, as (name, meaning),
  and `build(model, data)`, their values for a Model;
- energy terms of the incremental potential Π: `energy(q, m, ctx)` and
  `accumulate(q, m, ctx, grad, diag, pair, project)`, which returns E(q) with `energy`'s
  bits; CONSTANT_HESSIAN (Newton then adds only `accumulate_gradient`, the Hessian being in
  the constant blocks) and STORED (E/h² is stored energy, World.mechanical_energy);
- forces without energy, which enter only the prediction q̃: `add_acceleration`.

`m` is the compiled model (solver/model_data.py), `ctx` the step's `StepContext`
(terms/context.py). Hessians go into 12x12 blocks: `diag` (B,12,12) per body, `pair`
(J,12,12) per joint (parent row, child column). `project` asks for the PSD-projected
Hessian (Newton's; the tests also check the raw one). angle.py's joint angle and
prismatic.py's distance are shared by the angle and prismatic terms; select.py picks
the joints a term is on.

numba cannot loop over modules: solver/newton.py `potential` and `assemble` call the energy
terms one by one, in ENERGY_TERMS' order (the order Π is summed in), and
test_terms.py checks them against this list.
"""
from . import (damping, driving, gravity, inertia, limit, ortho, prismatic, prismatic_damping,
               prismatic_driving, prismatic_force, prismatic_limit, revolute, torque)

#: the terms of the incremental potential Π, in the order Newton sums them
ENERGY_TERMS = (inertia, ortho, revolute, driving, limit, damping, prismatic, prismatic_driving,
                prismatic_limit, prismatic_damping)
#: the forces without energy, which enter only the prediction
FORCE_TERMS = (gravity, torque, prismatic_force)
#: every term
TERMS = ENERGY_TERMS + FORCE_TERMS
#: the terms that write rows of StepContext.angle_ref once per step (`references`, called by
#: solver/newton.py `references`), in the order of their rows
REFERENCE_TERMS = tuple(t for t in ENERGY_TERMS if hasattr(t, 'references'))


def reference_shape(model) -> tuple:
    """Shape of StepContext.angle_ref for a Model: a row per joint of each term in
    REFERENCE_TERMS (its first field lists its joints), as many columns as the widest
    of those the model uses (at least 3)."""
    used = [t for t in REFERENCE_TERMS if t.used(model)]
    rows = sum(len(getattr(model, t.FIELDS[0][0])) for t in used)
    return rows, max([3] + [t.REFERENCE_COLUMNS for t in used])
