"""The numba backend's per-step driver: `single(world, h, report, may_split)` is `World._single`.

Same contract and side effects as the numpy `World._single` (world.py): it takes one
(sub-)step of size h from `world.state` with `world.control`, adds to `report` the Newton and
line-search iterations, the singular-guard warnings, `max_step_rotation`, `status` and
`converged`, replaces `world.state` (q_prev/v_prev = the old q/v, history_dt = h, unwrapped
joint angles, joint_velocity = ∇θ·v), and returns None or the same failure string the numpy
step returns (the caller sub-steps on it). Everything from the forces to the joint
velocities runs in one compiled call (`kernels.step_kernel`); this module only packs the
model once per World and turns the kernel's output into State/StepReport.

Linear solve: a block Cholesky along the free-body graph when it is a forest (chains, trees:
linear cost, any size), else a dense Cholesky up to `linsolve.DENSE_MAX_DOF` unknowns. Any
other structure (a loop of more than 8 free bodies) is not supported: `supports(model)` is
False and the World keeps the numpy backend.
"""
from __future__ import annotations

import numpy as np

from ..solver.linsolve import DENSE_MAX_DOF
from ..solver.newton import Status
from ..solver.retraction import ScrewRetraction
from ..state import State
from ..terms.forces import SINGULAR_RATIO
from . import kernels

_STATUS = {kernels.CONVERGED: Status.CONVERGED, kernels.MAX_ITERATIONS: Status.MAX_ITERATIONS,
           kernels.LINE_SEARCH_FAILED: Status.LINE_SEARCH_FAILED, kernels.NONFINITE: Status.NONFINITE}


class Packed:
    """The model as the kernels read it (see `kernels.unpack`). `mi_split` is `mi` with the
    may_split flag set (header slot `kernels.MI_MAY_SPLIT`): one vector per flag value, so a
    step passes the flag without a new kernel argument and without writing into `mi`."""

    def __init__(self, mi, mf):
        self.mi, self.mf = mi, mf
        self.mi_split = mi.copy()
        self.mi_split[kernels.MI_MAY_SPLIT] = 1
        # step_kernel's scratch outputs, read right after each call
        self.info = np.zeros(7)
        self.skipped = np.zeros(2 * int(mi[2]), dtype=np.int64)


def _forest(nf, sp, sc):
    """(order, eparent) of an elimination order children-first over the free-body graph
    with edges (sp, sc) in slot numbers, or None if the graph has a cycle (several joints
    between the same two bodies are one edge)."""
    adj = [set() for _ in range(nf)]
    root = list(range(nf))

    def find(a):
        while root[a] != a:
            root[a] = root[root[a]]
            a = root[a]
        return a

    for a, b in zip(sp.tolist(), sc.tolist()):
        if b in adj[a]:
            continue
        if a == b:
            return None
        ra, rb = find(a), find(b)
        if ra == rb:
            return None
        root[ra] = rb
        adj[a].add(b)
        adj[b].add(a)
    eparent = np.full(nf, -1, dtype=np.int64)
    order = []
    seen = np.zeros(nf, bool)
    for r in range(nf):
        if seen[r]:
            continue
        seen[r] = True
        stack, pre = [r], []
        while stack:                       # iterative DFS; reversed preorder = children first
            a = stack.pop()
            pre.append(a)
            for b in sorted(adj[a]):
                if not seen[b]:
                    seen[b] = True
                    eparent[b] = a
                    stack.append(b)
        order += pre[::-1]
    return np.array(order, dtype=np.int64), eparent


def structure(model):
    """(kind, order, eparent, edge_ptr, edge_joint) of the linear solve, or None if the
    model's free-body graph is neither a forest nor small enough for the dense solve."""
    fixed = model.body_fixed
    free_idx = np.flatnonzero(~fixed)
    nf = len(free_idx)
    slot = np.full(model.body_count, -1, dtype=np.int64)
    slot[free_idx] = np.arange(nf)
    p, c = model.joint_parent, model.joint_child
    both = ~fixed[p] & ~fixed[c]
    joints = np.flatnonzero(both)
    sp, sc = slot[p[joints]], slot[c[joints]]
    forest = _forest(nf, sp, sc)
    if forest is None:
        if 12 * nf > DENSE_MAX_DOF:
            return None
        z = np.zeros(nf, dtype=np.int64)
        return kernels.KIND_DENSE, z, z - 1, np.zeros(nf + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order, eparent = forest
    edge_ptr = np.zeros(nf + 1, dtype=np.int64)
    edge_joint = []
    for s in range(nf):
        if eparent[s] >= 0:
            ends = {s, int(eparent[s])}
            edge_joint += [int(j) for j, a, b in zip(joints, sp, sc) if {int(a), int(b)} == ends]
        edge_ptr[s + 1] = len(edge_joint)
    return kernels.KIND_TREE, order, eparent, edge_ptr, np.array(edge_joint, dtype=np.int64)


def supports(model) -> bool:
    return structure(model) is not None


def pack_model(model) -> Packed:
    st = structure(model)
    if st is None:
        raise ValueError('the numba backend needs a forest of free bodies or at most '
                         f'{DENSE_MAX_DOF // 12} free bodies')
    kind, order, eparent, edge_ptr, edge_joint = st
    m = model
    B, J = m.body_count, m.joint_count
    T, D, L = len(m.torque_joints), len(m.drive_joints), len(m.limit_joints)
    fixed = m.body_fixed
    free_idx = np.flatnonzero(~fixed)
    slot = np.full(B, -1, dtype=np.int64)
    slot[free_idx] = np.arange(len(free_idx))
    head = np.zeros(kernels.HEADER_INTS, dtype=np.int64)
    head[:11] = [B, J, T, D, L, len(free_idx), kind, m.newton.max_iterations,
                 m.newton.line_search_max, int(m.has_gravity), len(edge_joint)]
    screw = ScrewRetraction(m)
    group = np.full(B, -1, dtype=np.int64)
    share = np.zeros(B)
    floating = screw.bodies[screw.floating]
    group[floating], share[floating] = screw.group, screw.share
    head[12] = screw.groups
    pair = (~fixed[m.joint_parent] & ~fixed[m.joint_child]) if J else np.zeros(0, bool)
    mi = np.concatenate([head, fixed.astype(np.int64), m.joint_parent, m.joint_child,
                         m.torque_joints, m.drive_joints, m.limit_joints, free_idx, slot,
                         order, eparent, edge_ptr, edge_joint, pair.astype(np.int64), group]).astype(np.int64)
    fh = np.zeros(kernels.HEADER_FLOATS)
    # Newton's energy_tol = ½ Σ_free m_b (velocity_tol·h)²: the mass sum as numpy sums it
    fh[:7] = [m.newton.velocity_tol, m.newton.transrate_tol, *m.gravity,
              float(np.sum(m.body_mass[~fixed])), m.newton.max_step_rotation]
    xbar = np.stack([m.joint_anchor0, m.joint_anchor1], axis=2)      # (J, side, anchor, 3)
    init = m.joint_init_angle
    lj = m.limit_joints
    mf = np.concatenate([fh, m.body_M.ravel(), m.body_Minv.ravel(),
                         (m.body_kappa * m.body_volume).ravel(), m.body_corners.ravel(),
                         xbar.ravel(), m.joint_K.ravel(), m.joint_hessian.ravel(),
                         m.joint_nbar.ravel(), m.joint_bbar.ravel(), init.ravel(),
                         m.drive_K.ravel(), (m.limit_lower - init[lj]).ravel(),
                         (m.limit_upper - init[lj]).ravel(), m.limit_strength.ravel(), share]).astype(np.float64)
    return Packed(np.ascontiguousarray(mi), np.ascontiguousarray(mf))


def packed_for(world) -> Packed:
    pk = world.__dict__.get('_fast_packed')
    if pk is None or pk.model is not world.model:
        pk = pack_model(world.model)
        pk.model = world.model
        world._fast_packed = pk
    return pk


def max_joint_separation(world) -> float:
    """`World.max_joint_separation` compiled (~1 µs instead of ~50-250 µs of numpy calls):
    for World.step to call when `world.backend == 'numba'` (see docs/fast-backend.md)."""
    if not world.model.joint_count:
        return 0.0
    pk = packed_for(world)
    return float(kernels.max_joint_separation(pk.mi, pk.mf, world.state.q))


def single(world, h, report, may_split=False):
    """One (sub-)step; returns None or a failure description (state then invalid).
    The numba twin of `World._single` (same report fields, warnings, failure strings).
    `may_split`: a step predicted to turn a joint more than max_step_rotation is refused
    before solving (state unchanged). The kernel only reads its inputs: the new State gets
    new q/v/angle arrays, and the old State's arrays (kept by World.step to undo a step) are
    never written."""
    m, s, c = world.model, world.state, world.control
    pk = packed_for(world)
    bdf2 = m.integrator == 'bdf2' and s.history_dt == h
    # the new state's arrays: q, v, warm_start and joint angle, velocity (views of two buffers)
    qvw = np.empty((3, m.body_count, 12))
    aw = np.empty((2, m.joint_count))
    info = pk.info
    kernels.step_kernel(
        pk.mi_split if may_split else pk.mi, pk.mf, s.q, s.v, s.q_prev, s.v_prev, s.warm_start,
        s.joint_angle, c.torque_value, c.torque_enabled, c.drive_aim, c.drive_enabled,
        c.drive_passive, float(h), bdf2, qvw, aw, pk.skipped, info)
    status_code, iterations, ls_its, rotation, post, n_skipped, separation = info.tolist()
    for b in pk.skipped[:int(n_skipped)]:
        report.warnings.append(f'body {m.body_names[b]!r}: affine matrix near-singular '
                               f'(|det A|/(|a1||a2||a3|) < {SINGULAR_RATIO}); joint torque not applied')
    if post == kernels.POST_PREDICTED_SPLIT:
        return (f'a joint is predicted to turn {rotation:.3g} rad in one step (limit '
                f'{m.newton.max_step_rotation:.3g})')
    status, iterations = _STATUS[int(status_code)], int(iterations)
    report.newton_iterations += iterations
    report.line_search_iterations += int(ls_its)
    if post == kernels.POST_NEWTON_NONFINITE:
        return 'Newton produced a non-finite state'
    if post == kernels.POST_STEP_NONFINITE:
        return 'step produced a non-finite state'
    report.max_step_rotation = max(report.max_step_rotation, rotation)
    # (indexing: unpacking an ndarray by iteration costs three times as much)
    world.state = State(time=s.time + h, q=qvw[0], v=qvw[1], q_prev=s.q, v_prev=s.v,
                        joint_angle=aw[0],
                        joint_velocity=aw[1] if m.joint_count else s.joint_velocity,
                        step_count=s.step_count + 1, history_dt=h, warm_start=qvw[2])
    # World.step reads the separation of the final state from here (the last single() that
    # set world.state took the final step): one compiled call less per step
    report.max_joint_separation = separation
    if rotation > m.newton.max_step_rotation:
        return (f'a joint turned {rotation:.3g} rad in one step (limit '
                f'{m.newton.max_step_rotation:.3g})')
    if status is not Status.CONVERGED:
        report.status, report.converged = status.value, False
        return f'Newton stopped: {status.value} after {iterations} iterations'
    return None


def clean_steps(world, n):
    """Up to n steps of size dt in one compiled call (`kernels.batch_kernel`), stopping before
    the first step on which World.step would sub-step, warn or fail; returns
    (count, times, joint angles (count,J), joint velocities (count,J)) and leaves world.state
    and world.last_step as `count` World.step calls would (bit-identical: the same kernel on
    the same inputs). Only for World.step_clean."""
    from ..world import ACCURACY_ROTATION, StepReport
    m, s, c = world.model, world.state, world.control
    pk = packed_for(world)
    h = m.dt
    B, J = m.body_count, m.joint_count
    qvw = np.empty((n, 3, B, 12))
    aw = np.empty((n, 2, J))
    info = np.empty((n, 7))
    bdf2_ok = m.integrator == 'bdf2'
    done = kernels.batch_kernel(
        pk.mi_split if m.newton.max_substep_depth > 0 else pk.mi, pk.mf, s.q, s.v, s.q_prev,
        s.v_prev, s.warm_start, s.joint_angle, c.torque_value, c.torque_enabled, c.drive_aim,
        c.drive_enabled, c.drive_passive, float(h), bdf2_ok and s.history_dt == h, bdf2_ok, n,
        min(m.newton.max_step_rotation, ACCURACY_ROTATION[m.integrator]),
        world._separation_warn, qvw, aw, pk.skipped, info)
    if done == 0:
        return 0, [], aw[:0, 0], aw[:0, 1]
    times = []
    t = s.time
    for _ in range(done):
        t = t + h                                  # as World.step accumulates it
        times.append(t)
    k = done - 1
    world.state = State(time=t, q=qvw[k, 0], v=qvw[k, 1],
                        q_prev=qvw[k - 1, 0] if k else s.q, v_prev=qvw[k - 1, 1] if k else s.v,
                        joint_angle=aw[k, 0], joint_velocity=aw[k, 1] if J else s.joint_velocity,
                        step_count=s.step_count + done, history_dt=h, warm_start=qvw[k, 2])
    status, iterations, ls_its, rotation, _, _, separation = info[k].tolist()
    world.last_step = StepReport(time=t, newton_iterations=int(iterations),
                                 line_search_iterations=int(ls_its),
                                 max_joint_separation=separation,
                                 max_step_rotation=max(0.0, rotation))
    return done, times, aw[:done, 0], aw[:done, 1]
