"""`ModelData`: the Model as the compiled step reads it, built once per Solver.

A numba structref (a reference to a struct of named arrays): compiled code reads
`m.joint_parent`, `m.body_M`, ..., and Python passes one object per call. Why not a
namedtuple: numba unboxes every field of a namedtuple on every call (~0.5 µs per array
on this machine, ~15 µs for this model), a structref is one pointer (measured in
docs/physics-code.md). The field list below is the only place the layout is written.

Names follow the Model (`body_*`, `joint_*`, `torque_*`, `drive_*`, `limit_*`) plus what the
solver derives from it once: the free bodies, the linear solve's elimination order, the
screw retraction's floating groups and Newton's settings.
"""
from __future__ import annotations

import numpy as np
from numba.core import types
from numba.experimental import structref

from . import borrowed, linsolve, retraction
from .bdf import BETA_BDF2

# Joint anchors further apart than SEPARATION_WARN x the smaller body's size: the step warns
# (an overloaded joint: torque or speed too large for strength_ratio and dt). Further than
# SEPARATION_FAULT x the larger body's size, the joint has come apart: no joint force of
# UID 18 is stiff enough to make that a valid state, so the step fails.
SEPARATION_WARN = 0.01
SEPARATION_FAULT = 1e3
# The share of a body's smallest inertia, s μ_min(M̄), that the unprojected shape Hessian may
# take away from Newton's matrix (terms/ortho.py, docs/decisions.md).
ORTHO_EXACT_SHARE = 0.5
# The share of it that the unprojected Hessians of the angle terms (UID 19, 670) may take
# together, split evenly among the drives and limits on a body's joints (angles.py,
# docs/decisions.md): with the shape term's, Newton's matrix keeps a quarter of the inertia.
ANGLE_EXACT_SHARE = 0.25

#: (name, meaning) of every field; the values come from `build`.
FIELDS = (
    ('body_fixed', '(B,) bool'),
    ('free_bodies', '(F,) int64: indices of the free bodies'),
    ('body_M', '(B,12,12) mass matrices'),
    ('body_Minv', '(B,12,12) their inverses'),
    ('body_mass', '[kg] (B,)'),
    ('ortho_weight', '(B,) κ v̄ of UID 1 [Pa m³]'),
    ('ortho_exact_bound', '(B,) UID 1\'s Hessian is used unprojected while h² ‖AAᵀ − I‖_F ≤ s × this '
                          '(terms/ortho.py: Newton\'s matrix then keeps 1 − ORTHO_EXACT_SHARE of the '
                          'body\'s smallest inertia)'),
    ('joint_angle_budget', '(J,) a drive\'s or limit\'s Hessian on joint j is used unprojected '
                           'while its most negative eigenvalue is ≥ −s × this (angles.py: '
                           'ANGLE_EXACT_SHARE of the smaller body inertia, shared among the angle '
                           'terms on the body\'s joints)'),
    ('body_corners', '[m] (B,8,3) rest bounding-box corners (convergence test)'),
    ('gravity', '[m/s²] (3,)'),
    ('has_gravity', 'bool'),
    ('joint_parent', '(J,) body i'),
    ('joint_child', '(J,) body j'),
    ('joint_x_bar', '[m] (J,2,2,3) anchors x̄: [joint, side (i, j), anchor (P0, P1), xyz]'),
    ('joint_K', '[kg] (J,) UID 18 stiffness K = γ (m_i + m_j)'),
    ('joint_hessian', '(J,24,24) constant Hessian of the UID 18 energy'),
    ('joint_nbar', '(J,2,3) n̄ per side'),
    ('joint_bbar', '(J,2,3) b̄ per side'),
    ('joint_init_angle', '[rad] (J,)'),
    ('joint_warn_separation', '[m] (J,) anchor separation above which a step warns (overloaded joint)'),
    ('joint_fault_separation', '[m] (J,) anchor separation above which a joint has come apart (a fault)'),
    ('torque_joints', '(T,) joints with UID 668'),
    ('drive_joints', '(D,) joints with UID 19'),
    ('drive_K', '(D,) UID 19 stiffness γ (m_i + m_j)'),
    ('limit_joints', '(L,) joints with UID 670'),
    ('limit_lower', '[rad] (L,) lower bound relative to init_angle'),
    ('limit_upper', '[rad] (L,) upper bound relative to init_angle'),
    ('limit_strength', '(L,) s of UID 670'),
    ('damping_joints', '(P,) joints with viscous damping (terms/damping.py)'),
    ('damping_coeff', '[N m s/rad] (P,) their damping coefficients d'),
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
    ('body_Mbar', '(B,4,4) M̄ of M = M̄ ⊗ I3: the block of row k, [p_k, A_k0, A_k1, A_k2]'),
    ('body_Minv_bar', '(B,3,4,4) M⁻¹\'s blocks, one per row k (not rounded alike)'),
    ('torque_bodies', '(Tb,) bodies of the UID 668 joints, ascending'),
    ('torque_body_ptr', '(Tb+1,) CSR pointer into torque_body_entries per torque body'),
    ('torque_body_entries', '(E,) 2 k + side per torque joint k on the body: parent sides, then child'),
    ('inertia_scales', '(2,) the inertia term\'s scales s: 1 (BDF1) and 1/β (BDF2)'),
    ('constant_diag_inertia', '(2,B,12,12) constant_diag + s M on the free bodies for each of '
                              'inertia_scales: Newton\'s diagonal blocks before the shape and angle terms'),
)

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


def torque_incidence(torque_joints, parent, child):
    """(torque_bodies, torque_body_ptr, torque_body_entries): per body, the torque joints acting
    on it in the order terms/torque.py sums their forces (parent sides, then child sides)."""
    per_body = {}
    for side, ends in enumerate((parent, child)):
        for k, j in enumerate(torque_joints):
            per_body.setdefault(int(ends[j]), []).append(2 * k + side)
    bodies = sorted(per_body)
    ptr = np.cumsum([0] + [len(per_body[b]) for b in bodies])
    entries = [e for b in bodies for e in per_body[b]]
    return np.array(bodies, np.int64), np.array(ptr, np.int64), np.array(entries, np.int64)


def constant_hessian(values, B, J):
    """(diag, pair): the UID 18 Hessian blocks, constant over the run, summed once (by the
    term's own accumulate, so the sum is written in one place)."""
    from ..terms import revolute
    fields = dict(values, constant_diag=np.zeros((B, 12, 12)), constant_pair=np.zeros((J, 12, 12)),
                  inertia_scales=np.zeros(2), constant_diag_inertia=np.zeros((2, B, 12, 12)))
    partial = ModelData(*(fields[name] for name, _ in FIELDS))
    diag, pair = np.zeros((B, 12, 12)), np.zeros((J, 12, 12))
    revolute.accumulate(np.zeros((B, 12)), partial, None, np.zeros((B, 12)), diag, pair, True)
    return diag, pair


@structref.register
class ModelDataType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class ModelData(structref.StructRefProxy):
    """Python handle of the compiled model. Python reads the fields from the instance's
    __dict__ (the same arrays the struct refers to: no copy); compiled code from the struct."""


structref.define_proxy(ModelData, ModelDataType, [name for name, _ in FIELDS])


def inertia_min(Mbar):
    """(B,) μ_min(M̄) per body: the least the inertia term s M gives any direction of a body
    in Newton's matrix (per unit s), which the unprojected Hessians may draw on."""
    return np.linalg.eigvalsh(Mbar)[:, 0] if len(Mbar) else np.zeros(0)


def ortho_exact_bound(Mbar, weight):
    """(B,) ORTHO_EXACT_SHARE μ_min(M̄) / (4 κv̄) per body (inf without a shape term): where
    h² ‖AAᵀ − I‖_F is below s times it, the unprojected shape Hessian, whose eigenvalues are
    ≥ −4h²κv̄ ‖AAᵀ − I‖_F, takes at most that share of the inertia term's s μ_min(M̄) away from
    any direction of Newton's matrix (terms/ortho.py)."""
    mu = inertia_min(Mbar)
    with np.errstate(divide='ignore'):
        return np.where(weight > 0.0, ORTHO_EXACT_SHARE * mu / (4.0 * weight), np.inf)


def joint_angle_budget(Mbar, fixed, parent, child, drive_joints, limit_joints, damping_joints=()):
    """(J,) per joint, min over its free bodies of ANGLE_EXACT_SHARE μ_min(M̄_b) / n_b, n_b the
    number of angle terms (drives, limits, dampers) on the joints of body b: the angle terms'
    unprojected Hessians, each ≥ −s × its joint's budget, then take at most that share of
    s μ_min(M̄_b) from any direction of body b in Newton's matrix (angles.py). inf for a joint
    between fixed bodies; 0 (always projected) beside a body without inertia."""
    B, J = len(fixed), len(parent)
    mu = inertia_min(Mbar)
    count = np.zeros(B)
    for j in list(drive_joints) + list(limit_joints) + list(damping_joints):
        count[parent[j]] += 1
        count[child[j]] += 1
    budget = np.full(J, np.inf)
    for j in range(J):
        for b in (parent[j], child[j]):
            if not fixed[b]:
                share = ANGLE_EXACT_SHARE * max(mu[b], 0.0) / max(count[b], 1.0)
                budget[j] = min(budget[j], share)
    return budget


def _arr(x, dtype):
    # writable C-contiguous copies: read-only arrays would be a different numba type
    return np.ascontiguousarray(np.array(x, dtype=dtype, copy=True))


def build(model, force_dense: bool = False) -> ModelData:
    """The ModelData of a Model (raises ValueError for a linear system too large to solve
    densely that is not a forest; see linsolve.structure)."""
    m = model
    J = m.joint_count
    fixed = m.body_fixed
    free = np.flatnonzero(~fixed)
    st = linsolve.structure(m, force_dense)
    group, share, groups = retraction.floating_groups_and_shares(m)
    init = m.joint_init_angle
    size = m.body_size
    lj = m.limit_joints
    values = dict(
        body_fixed=_arr(fixed, np.bool_),
        free_bodies=_arr(free, np.int64),
        body_M=_arr(m.body_M, np.float64),
        body_Minv=_arr(m.body_Minv, np.float64),
        body_mass=_arr(m.body_mass, np.float64),
        ortho_weight=_arr(m.body_kappa * m.body_volume, np.float64),
        body_corners=_arr(m.body_corners, np.float64),
        gravity=_arr(m.gravity, np.float64),
        has_gravity=bool(m.has_gravity),
        joint_parent=_arr(m.joint_parent, np.int64),
        joint_child=_arr(m.joint_child, np.int64),
        joint_x_bar=_arr(np.stack([m.joint_anchor0, m.joint_anchor1], axis=2).reshape(J, 2, 2, 3),
                         np.float64),
        joint_K=_arr(m.joint_K, np.float64),
        joint_hessian=_arr(m.joint_hessian, np.float64),
        joint_nbar=_arr(m.joint_nbar, np.float64),
        joint_bbar=_arr(m.joint_bbar, np.float64),
        joint_init_angle=_arr(init, np.float64),
        joint_warn_separation=_arr(SEPARATION_WARN * np.minimum(size[m.joint_parent], size[m.joint_child]),
                                   np.float64),
        joint_fault_separation=_arr(SEPARATION_FAULT * np.maximum(size[m.joint_parent], size[m.joint_child]),
                                    np.float64),
        torque_joints=_arr(m.torque_joints, np.int64),
        drive_joints=_arr(m.drive_joints, np.int64),
        drive_K=_arr(m.drive_K, np.float64),
        limit_joints=_arr(lj, np.int64),
        limit_lower=_arr(m.limit_lower - init[lj], np.float64),
        limit_upper=_arr(m.limit_upper - init[lj], np.float64),
        limit_strength=_arr(m.limit_strength, np.float64),
        damping_joints=_arr(m.damping_joints, np.int64),
        damping_coeff=_arr(m.damping_coeff, np.float64),
        solve_kind=int(st.kind),
        tree_order=_arr(st.order, np.int64),
        tree_parent=_arr(st.parent, np.int64),
        tree_edge_ptr=_arr(st.edge_ptr, np.int64),
        tree_edge_joints=_arr(st.edge_joints, np.int64),
        body_slot=_arr(st.slot, np.int64),
        joint_between_free=_arr(st.between_free, np.bool_),
        body_group=_arr(group, np.int64),
        group_share=_arr(share, np.float64),
        group_count=int(groups),
        velocity_tol=float(m.newton.velocity_tol),
        transrate_tol=float(m.newton.transrate_tol),
        max_iterations=int(m.newton.max_iterations),
        line_search_max=int(m.newton.line_search_max),
        max_step_rotation=float(m.newton.max_step_rotation),
        # as numpy sums it (np.sum's pairwise order): the tolerance must not depend on layout
        free_mass=float(np.sum(m.body_mass[free])),
    )
    values['body_Mbar'], values['body_Minv_bar'] = (_arr(x, np.float64)
                                                    for x in mass_blocks(m.body_M, m.body_Minv))
    values['ortho_exact_bound'] = _arr(ortho_exact_bound(values['body_Mbar'], values['ortho_weight']),
                                       np.float64)
    values['joint_angle_budget'] = _arr(joint_angle_budget(values['body_Mbar'], m.body_fixed,
                                                           m.joint_parent, m.joint_child,
                                                           m.drive_joints, m.limit_joints,
                                                           m.damping_joints), np.float64)
    values['torque_bodies'], values['torque_body_ptr'], values['torque_body_entries'] = (
        _arr(x, np.int64) for x in torque_incidence(m.torque_joints, m.joint_parent, m.joint_child))
    values['constant_diag'], values['constant_pair'] = constant_hessian(values, m.body_count, J)
    # s M added to the constant blocks as the inertia term adds it (one rounding per entry,
    # c + s·M): the same numbers as adding it every iteration
    scales = np.array([1.0, 1.0 / BETA_BDF2])
    base = np.stack([values['constant_diag']] * 2)
    for k, scale in enumerate(scales):
        base[k, free] = values['constant_diag'][free] + scale * m.body_M[free]
    values['inertia_scales'], values['constant_diag_inertia'] = scales, _arr(base, np.float64)
    data = ModelData(*(values[name] for name, _ in FIELDS))
    data.__dict__.update(values)
    return borrowed.borrow(data)
