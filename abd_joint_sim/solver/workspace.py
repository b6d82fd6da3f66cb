"""`Workspace`: the arrays one step works in, allocated once per Solver (a numba structref,
like ModelData; an allocation in a kernel costs a few hundred flops). Nothing in them carries
from one step to the next (a fresh Workspace gives the same result).
"""
from __future__ import annotations

import numpy as np
from numba.core import types
from numba.experimental import structref

from ..jit import refcounts
from ..terms import angle, reference_shape
from ..terms.context import StepContext
from . import linsolve

#: (name, meaning) of every field; the shapes come from `build`.
FIELDS = (
    ('q_force', '(B,12) where the explicit forces are evaluated'),
    ('acc', '(B,12) their acceleration'),
    ('q_tilde', '(B,12) prediction q̃'),
    ('q_new', '(B,12) Newton iterate'),
    ('q_alt', "(B,12) Newton's other start: q̃ + c h² warm_start, not extrapolated"),
    ('angle_start', '(J,) joint angle at the start of the step minus init_angle'),
    ('drive_target', '(D + Ds,) UID 19 targets, then UID 21\'s'),
    ('angle_ref', 'StepContext.angle_ref, terms.reference_shape'),
    ('grad', '(B,12) ∇Π'),
    ('diag', '(B,12,12) diagonal blocks of ∇²Π'),
    ('pair', '(J,12,12) joint blocks of ∇²Π'),
    ('dq', '(B,12) Newton step'),
    ('trial', '(B,12) line-search point'),
    ('tree_X', '(F,12,12) tree solve: L⁻¹ U of each edge'),
    ('tree_y', '(F,12) tree solve: right-hand side / solution'),
    ('tree_inv_d', '(F,12) tree solve: 1 / diagonal of each factor'),
    ('dense_H', '(n,n) dense solve: the matrix (n = 12 F, or 0 with the tree solve)'),
    ('dense_x', '(n,) dense solve: right-hand side / solution'),
    ('zero', '(B,12) zeros, never written (a direction d = d_plus − 0)'),
    ('torque_axes', '(T+2,3) UID 668 torque axes ê of the T torque joints, and 2 rows of scratch'),
    ('group_mean', "(G,3) the retraction's mean turn translation of each floating group (G ≥ 1)"),
    ('angle_work', '(25,18) angle.ANGLE_WORK_SHAPE: where the drives and limits work (StepContext)'),
    ('drive_on', '(D + Ds,) bool: which drives (UID 19, then UID 21) are on in this step (StepContext.drive_on)'),
    ('ctx', "the step's StepContext over the fields above (the step sets h and scale)"),
)


@structref.register
class WorkspaceType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class Workspace(structref.StructRefProxy):
    """Python handle of a step's work arrays."""


structref.define_proxy(Workspace, WorkspaceType, [name for name, _ in FIELDS])


def build(model, data) -> Workspace:
    """The Workspace of a Model whose ModelData is `data`."""
    B, J = model.body_count, model.joint_count
    D = len(model.drive_joints) + len(model.prismatic_drive_joints)
    F = int(data.free_bodies.size)
    n = 12 * F if data.solve_kind == linsolve.DENSE else 0
    shapes = dict(q_force=(B, 12), acc=(B, 12), q_tilde=(B, 12), q_new=(B, 12), q_alt=(B, 12),
                  angle_start=(J,), drive_target=(D,), angle_ref=reference_shape(model),
                  grad=(B, 12), diag=(B, 12, 12), pair=(J, 12, 12), dq=(B, 12), trial=(B, 12),
                  tree_X=(F, 12, 12), tree_y=(F, 12), tree_inv_d=(F, 12), dense_H=(n, n),
                  dense_x=(n,), zero=(B, 12), torque_axes=(len(model.torque_joints) + 2, 3),
                  group_mean=(max(int(data.group_count), 1), 3), angle_work=angle.ANGLE_WORK_SHAPE)
    values = {name: np.zeros(shapes[name]) for name, _ in FIELDS if name in shapes}
    values['drive_on'] = np.zeros(D, dtype=np.bool_)
    values['ctx'] = refcounts.borrow(StepContext(0.0, 1.0, *(values[name] for name in (
        'q_tilde', 'angle_start', 'drive_target', 'drive_on', 'angle_work', 'angle_ref'))))
    ws = Workspace(*(values[name] for name, _ in FIELDS))
    ws.__dict__.update(values)
    return refcounts.borrow(ws)
