"""`ModelData`: the Model as the compiled step reads it, built once per Solver.

A numba structref: one pointer per call, where a namedtuple's every field is unboxed on
every call (~0.5 µs per array, ~15 µs for this model; docs/physics-code.md). Its fields are
BASE_FIELDS followed by each term's FIELDS (built in its module) in terms.TERMS' order.
"""
from __future__ import annotations

import numpy as np
from numba.core import types
from numba.experimental import structref

from ..jit import flat, refcounts
from ..terms import ENERGY_TERMS, TERMS, inertia, joints, revolute
from . import linsolve, retraction
from .bdf import BETA_BDF2

# The share of a body's smallest inertia the unprojected angle Hessians (UID 19, 670,
# damping) may take together, split evenly among them (terms/angle.py, docs/decisions.md)
ANGLE_EXACT_SHARE = 0.25

#: (name, meaning) of the fields every model has; the values come from `build`.
BASE_FIELDS = (
    ('body_fixed', '(B,) bool'),
    ('free_bodies', '(F,) int64: indices of the free bodies'),
    ('body_M', '(B,12,12) mass matrices'),
    ('body_Minv', '(B,12,12) their inverses'),
    ('body_mass', '[kg] (B,)'),
    ('body_Mbar', '(B,4,4) M̄ of M = M̄ ⊗ I3: the block of row k, [p_k, A_k0, A_k1, A_k2]'),
    ('body_Minv_bar', '(B,3,4,4) M⁻¹\'s blocks, one per row k (not rounded alike)'),
    ('body_corners', '[m] (B,8,3) rest bounding-box corners (convergence test)'),
    ('joint_parent', '(J,) body i'),
    ('joint_child', '(J,) body j'),
    ('joint_nbar', '(J,2,3) n̄ per side'),
    ('joint_bbar', '(J,2,3) b̄ per side'),
    ('joint_init_angle', '[rad] (J,)'),
    ('joint_angle_budget', '(J,) an angle term\'s Hessian on joint j is used unprojected while '
                           'its λ_min ≥ −s × this (`joint_angle_budget`)'),
    ('solve_kind', 'linsolve.TREE or linsolve.DENSE'),
    ('tree_order', '(F,) elimination order over free-body slots, leaves first'),
    ('tree_parent', '(F,) elimination parent slot, -1 at a root'),
    ('tree_edge_ptr', '(F+1,) CSR pointer into tree_edge_joints per slot'),
    ('tree_edge_joints', '(E,) joints on the edge slot -> tree_parent[slot]'),
    ('body_slot', '(B,) slot of a free body in free_bodies, -1 if fixed'),
    ('joint_between_free', '(J,) bool: both bodies free (an off-diagonal block)'),
    ('body_group', '(B,) floating group of the screw retraction, -1: anchored'),
    ('group_share', '(B,) m_b / Σ m of its floating group'),
    ('group_count', 'int'),
    ('velocity_tol', '[m/s] Newton'),
    ('transrate_tol', '[1/s] Newton'),
    ('max_iterations', 'int Newton'),
    ('line_search_max', 'int Newton'),
    ('max_step_rotation', '[rad] sub-stepping threshold'),
    ('free_mass', '[kg] Σ m over free bodies (Newton energy tolerance)'),
    ('constant_diag', '(B,12,12) the constant Hessian blocks (UID 18) Newton starts from'),
    ('constant_pair', '(J,12,12) the same, off the diagonal'),
    ('pair_constant', 'bool: the joint blocks are constant_pair (no term the model uses adds '
                      'to them: `pair_constant`)'),
    ('inertia_scales', '(2,) the inertia term\'s scales s: 1 (BDF1) and 1/β (BDF2)'),
    ('constant_diag_inertia', '(2,B,12,12) constant_diag + s M per inertia_scales entry'),
)
#: (name, meaning) of every field, in the struct's order
FIELDS = BASE_FIELDS + tuple(field for term in TERMS for field in term.FIELDS)

#: q indices of the row-k block [p_k, A_k0, A_k1, A_k2] of a body (q = [p, vec A], vec row-major)
BLOCK_ROWS = np.array([[k, 3 + 3 * k, 4 + 3 * k, 5 + 3 * k] for k in range(3)])


def mass_blocks(body_M, body_Minv):
    """(M̄ (B,4,4), M⁻¹'s blocks (B,3,4,4)) with M = M̄ ⊗ I3 in q's layout; raises
    ValueError if a mass matrix lacks that structure (model.mass_matrix always builds it)."""
    B = body_M.shape[0]
    Mbar = body_M[:, BLOCK_ROWS[0][:, None], BLOCK_ROWS[0][None, :]]
    Minv_bar = np.stack([body_Minv[:, i[:, None], i[None, :]] for i in BLOCK_ROWS], axis=1)
    full, full_inv = np.zeros((B, 12, 12)), np.zeros((B, 12, 12))
    for k, i in enumerate(BLOCK_ROWS):
        full[:, i[:, None], i[None, :]] = Mbar
        full_inv[:, i[:, None], i[None, :]] = Minv_bar[:, k]
    if not (np.array_equal(full, body_M) and np.array_equal(full_inv, body_Minv)):
        raise ValueError('a body mass matrix or its inverse is not M̄ ⊗ I3 (model.mass_matrix)')
    return Mbar, Minv_bar


def constant_blocks(values, B, J):
    """(constant_diag, constant_pair, inertia_scales, constant_diag_inertia): the Hessian
    blocks constant over a run, UID 18's, then + s M per BDF scale s (adding it per iteration's
    bits)."""
    diag, pair = np.zeros((B, 12, 12)), np.zeros((J, 12, 12))
    revolute.add_constant_hessian(values['joint_parent'], values['joint_child'],
                                  values['joint_hessian'], diag, pair)
    scales = np.array([1.0, 1.0 / BETA_BDF2])
    with_inertia = np.stack([diag] * len(scales))
    for k, scale in enumerate(scales):
        inertia.add_hessian(values['free_bodies'], values['body_Mbar'], scale, with_inertia[k])
    return diag, pair, scales, with_inertia


@structref.register
class ModelDataType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class ModelData(structref.StructRefProxy):
    """Python handle of the compiled model. Python reads the fields from the instance's
    __dict__ (the same arrays the struct refers to: no copy); compiled code from the struct."""


structref.define_proxy(ModelData, ModelDataType, [name for name, _ in FIELDS])


def joint_angle_budget(model, Mbar) -> np.ndarray:
    """(J,) per joint, min over its free bodies b of ANGLE_EXACT_SHARE μ_min(M̄_b) / n_b, n_b
    the angle terms (ANGLE_BUDGET) on b's joints; inf between fixed bodies, 0 beside a body
    without inertia."""
    fixed, parent, child = model.body_fixed, model.joint_parent, model.joint_child
    B, J = len(fixed), len(parent)
    mu = inertia.min_eigenvalue(Mbar)
    count = np.zeros(B)
    for t in ENERGY_TERMS:
        for j in getattr(model, joints(t)) if getattr(t, 'ANGLE_BUDGET', False) else ():
            count[parent[j]] += 1
            count[child[j]] += 1
    budget = np.full(J, np.inf)
    for j in range(J):
        for b in (parent[j], child[j]):
            if not fixed[b]:
                share = ANGLE_EXACT_SHARE * max(mu[b], 0.0) / max(count[b], 1.0)
                budget[j] = min(budget[j], share)
    return budget


def pair_constant(model) -> bool:
    """Whether Newton's joint blocks are the constant ones: no joint term without a constant
    Hessian is used by the model."""
    return not any(t.used(model) for t in ENERGY_TERMS if not t.CONSTANT_HESSIAN and joints(t))


def build(model, force_dense: bool = False) -> ModelData:
    """The ModelData of a Model (raises ValueError for a linear system too large to solve
    densely that is not a forest; see linsolve.structure)."""
    m, arr = model, flat.array
    fixed = m.body_fixed
    free = np.flatnonzero(~fixed)
    st = linsolve.structure(m, force_dense)
    group, share, groups = retraction.floating_groups_and_shares(m)
    Mbar, Minv_bar = mass_blocks(m.body_M, m.body_Minv)
    values = {name: arr(getattr(m, name), np.float64) for name in (
        'body_M', 'body_Minv', 'body_mass', 'body_corners', 'joint_nbar', 'joint_bbar',
        'joint_init_angle')}
    values.update({name: arr(getattr(m, name), np.int64) for name in ('joint_parent',
                                                                      'joint_child')})
    values.update(
        body_fixed=arr(fixed, np.bool_),
        free_bodies=arr(free, np.int64),
        body_Mbar=arr(Mbar, np.float64),
        body_Minv_bar=arr(Minv_bar, np.float64),
        solve_kind=int(st.kind),
        tree_order=arr(st.order, np.int64),
        tree_parent=arr(st.parent, np.int64),
        tree_edge_ptr=arr(st.edge_ptr, np.int64),
        tree_edge_joints=arr(st.edge_joints, np.int64),
        body_slot=arr(st.slot, np.int64),
        joint_between_free=arr(st.between_free, np.bool_),
        body_group=arr(group, np.int64),
        group_share=arr(share, np.float64),
        group_count=int(groups),
        velocity_tol=float(m.newton.velocity_tol),
        transrate_tol=float(m.newton.transrate_tol),
        max_iterations=int(m.newton.max_iterations),
        line_search_max=int(m.newton.line_search_max),
        max_step_rotation=float(m.newton.max_step_rotation),
        free_mass=float(np.sum(m.body_mass[free])),     # (np.sum's order, whatever the layout)
    )
    values['joint_angle_budget'] = arr(joint_angle_budget(m, Mbar), np.float64)
    for term in TERMS:
        values.update(term.build(m, values))
    values['pair_constant'] = pair_constant(m)
    (values['constant_diag'], values['constant_pair'], values['inertia_scales'],
     values['constant_diag_inertia']) = constant_blocks(values, m.body_count, m.joint_count)
    data = ModelData(*(values[name] for name, _ in FIELDS))
    data.__dict__.update(values)
    return refcounts.borrow(data)
