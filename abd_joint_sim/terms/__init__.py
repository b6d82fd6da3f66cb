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
- forces without energy, which enter only the prediction q̃: `add_acceleration`;
- a joint term: EXAMPLE, the scene joint keys that put it on a joint (the warm-up's scene,
  jit/warmup.py); ANGLE_BUDGET where its Hessian on the joint angle shares the bodies'
  inertia (model_data.joint_angle_budget); `references` and REFERENCE_COLUMNS where it keeps
  rows of StepContext.angle_ref per step.

`m` is the compiled model (solver/model_data.py), `ctx` the step's `StepContext`
(terms/context.py). Hessians go into 12x12 blocks: `diag` (B,12,12) per body, `pair`
(J,12,12) per joint (parent row, child column). `project` asks for the PSD-projected
Hessian (Newton's; the tests also check the raw one). angle.py's joint angle and
prismatic.py's distance are shared by the angle and prismatic terms; select.py picks
the joints a term is on.

solver/newton.py's `potential`, `assemble` and `references` loop over ENERGY_TERMS and
REFERENCE_TERMS; the loops are written out before compiling (jit/unroll.py), a term whose
joints (`joints`) a model lacks left uncalled. A term in the lists is thereby in Newton's sums.
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


def joints(term) -> str | None:
    """The field listing the joints a term is on (its first, by convention), or None for a
    term on every body (inertia, shape)."""
    name = term.FIELDS[0][0] if term.FIELDS else ''
    return name if name.endswith('_joints') else None


def reference_shape(model) -> tuple:
    """Shape of StepContext.angle_ref for a Model: a row per joint of each term in
    REFERENCE_TERMS (`joints`), as many columns as the widest
    of those the model uses (at least 3)."""
    used = [t for t in REFERENCE_TERMS if t.used(model)]
    rows = sum(len(getattr(model, joints(t))) for t in used)
    return rows, max([3] + [t.REFERENCE_COLUMNS for t in used])
