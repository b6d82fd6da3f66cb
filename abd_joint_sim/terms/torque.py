"""External joint torque, libuipc UID 668 (docs/physics.md "External joint torque (UID 668)"):
a generalized force without energy, entering the prediction q̃ only. For each enabled joint
with torque τ:

    ẽ_k = normalize(A_k (x̄1_k − x̄0_k))        each body from its OWN anchors and A
    ê_j = ½(ẽ_i + ẽ_j),   ê_i = −ê_j            same-order anchors: exact third law
    F_k = [0₃ ; vec((τ/2) [ê_k]× A_k^{−T})]      vec = row-major into q[3:12]

Virtual work: for δA = [δω]× A, F^A : δA = τ ê·δω. Positive τ turns the child about +t, so
it increases the joint angle. Guards: a raw axis of norm ≤ AXIS_EPS |x̄1 − x̄0| (or not
finite) is unusable and the other body's axis is used for both (neither: no torque); a
near-singular A_k (|det A| / (|a1||a2||a3|) < SINGULAR_RATIO) gets no torque, and the step
reports the body.
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import flat, kernel
from ..smallmat import adjugate3
from . import select

NAME = 'external_torque'    #: in Solver.terms
#: a scene joint's keys that put the term on it (jit/warmup.py's scenes)
EXAMPLE = dict(external_torque=dict(torque=1.0, enabled=True))
FIELDS = (
    ('torque_joints', '(T,) joints with UID 668'),
    ('torque_bodies', '(Tb,) bodies of the UID 668 joints, ascending'),
    ('torque_body_ptr', '(Tb+1,) CSR pointer into torque_body_entries per torque body'),
    ('torque_body_entries', '(E,) 2 k + side per torque joint k on the body: parent sides, then child'),
)
SINGULAR_RATIO = 1e-6
AXIS_EPS = 1e-12


def used(model) -> bool:
    return len(model.torque_joints) > 0


def from_scene(scene, model) -> dict:
    """The Model's fields of this term: torque_joints (T,), the revolute joints with UID 668;
    torque_value0 [N m], torque_enabled0 and torque_effort_limit [N m] (inf: none), (T,)."""
    tj = select.joints(scene, model, False, lambda j: j.external_torque is not None)
    spec = [scene.joints[k].external_torque for k in tj]
    return dict(torque_joints=tj, torque_value0=np.array([s.torque for s in spec], float),
                torque_enabled0=np.array([s.enabled for s in spec], bool),
                torque_effort_limit=np.array([s.effort_limit for s in spec], float))


def incidence(torque_joints, parent, child):
    """(torque_bodies, torque_body_ptr, torque_body_entries): per body, the torque joints acting
    on it in the order `add_acceleration` sums their forces (parent sides, then child sides)."""
    per_body = {}
    for side, ends in enumerate((parent, child)):
        for k, j in enumerate(torque_joints):
            per_body.setdefault(int(ends[j]), []).append(2 * k + side)
    bodies = sorted(per_body)
    ptr = np.cumsum([0] + [len(per_body[b]) for b in bodies])
    entries = [e for b in bodies for e in per_body[b]]
    return np.array(bodies, np.int64), np.array(ptr, np.int64), np.array(entries, np.int64)


def build(model, data) -> dict:
    bodies, ptr, entries = incidence(model.torque_joints, model.joint_parent, model.joint_child)
    return dict(torque_joints=flat.array(model.torque_joints, np.int64),
                torque_bodies=flat.array(bodies, np.int64), torque_body_ptr=flat.array(ptr, np.int64),
                torque_body_entries=flat.array(entries, np.int64))


@kernel
def axis(q, m, j, e):
    """e = ê_j (3,) of joint j, the child's torque axis (0 when neither raw axis is usable)."""
    axis_at(q, m.joint_parent, m.joint_child, m.joint_x_bar, j, e, np.empty((2, 3)))


@kernel(inline='always')
def axis_at(q, parent, child, x_bar, j, e, es):
    """axis() on the model's arrays, es (2,3) a work array (it runs once per joint)."""
    usable = 0
    for side in range(2):
        b = parent[j] if side == 0 else child[j]
        v0 = v1 = v2 = 0.0
        d2 = 0.0
        for c in range(3):
            dc = x_bar[j, side, 1, c] - x_bar[j, side, 0, c]
            d2 += dc * dc
            v0 += q[b, 3 + c] * dc
            v1 += q[b, 6 + c] * dc
            v2 += q[b, 9 + c] * dc
        nrm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        if math.isfinite(nrm) and nrm > AXIS_EPS * math.sqrt(d2):
            es[side, 0], es[side, 1], es[side, 2] = v0 / nrm, v1 / nrm, v2 / nrm
            usable += 1
        else:
            es[side, 0] = es[side, 1] = es[side, 2] = 0.0
    half = 0.5 if usable == 2 else 1.0          # one of them is 0 if not both
    for r in range(3):
        e[r] = half * (es[0, r] + es[1, r])


@kernel
def clamp_command(value, effort_limit):
    """A commanded torque clamped to [−effort_limit, effort_limit] (the one place of this rule)."""
    return min(max(value, -effort_limit), effort_limit)


@kernel
def clamp_commands(values, effort_limit, out):
    """out[k] = values[k] clamped to ±effort_limit[k] (World.set_torques: a fifth of numpy's
    cost); a non-finite value changes nothing and its index is returned, else −1."""
    for k in range(values.size):
        if not math.isfinite(values[k]):
            return k
    for k in range(values.size):
        out[k] = clamp_command(values[k], effort_limit[k])
    return -1


@kernel
def any_active(m, torque_value, torque_enabled):
    """Whether some joint's torque is enabled and nonzero (else F = 0)."""
    return _any_active(torque_value, torque_enabled, m.torque_joints.size)


@kernel
def _any_active(torque_value, torque_enabled, T):
    """Over the T UID 668 rows (the effort arrays' rows after them are UID 667's forces)."""
    for k in range(T):
        if torque_enabled[k] and torque_value[k] != 0.0:
            return True
    return False


@kernel
def _inverse_if_regular(q, b):
    """(regular, A_b⁻¹ row-major as 9 scalars): regular False (no torque on the body) if
    |det A| ≤ SINGULAR_RATIO |a1||a2||a3|."""
    a00, a01, a02 = q[b, 3], q[b, 4], q[b, 5]
    a10, a11, a12 = q[b, 6], q[b, 7], q[b, 8]
    a20, a21, a22 = q[b, 9], q[b, 10], q[b, 11]
    adj, det = adjugate3((a00, a01, a02, a10, a11, a12, a20, a21, a22))
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = adj
    scale = (math.sqrt(a00 * a00 + a01 * a01 + a02 * a02) * math.sqrt(a10 * a10 + a11 * a11 + a12 * a12)
             * math.sqrt(a20 * a20 + a21 * a21 + a22 * a22))
    return (abs(det) > SINGULAR_RATIO * scale,
            c00 / det, c01 / det, c02 / det, c10 / det, c11 / det, c12 / det, c20 / det, c21 / det, c22 / det)


@kernel
def _body_force(q, b, ptr0, ptr1, entries, e, torque_value, torque_enabled):
    """(status, F_b[3:12] as 9 scalars): Σ over the torque joints k of body b (entries[ptr0:ptr1]
    of m.torque_body_entries, 2 k + side) of (τ_k/2) [±ê_k]× A_b^{−T}, in that order (A_b⁻¹
    once per body). status -1: no torque acts on b, 0: the singular guard skips it, 1: F_b."""
    f0 = f1 = f2 = f3 = f4 = f5 = f6 = f7 = f8 = 0.0
    active = False
    for i in range(ptr0, ptr1):
        k = entries[i] >> 1
        if torque_enabled[k] and torque_value[k] != 0.0:
            active = True
    if not active:
        return -1, f0, f1, f2, f3, f4, f5, f6, f7, f8
    regular, i00, i01, i02, i10, i11, i12, i20, i21, i22 = _inverse_if_regular(q, b)
    if not regular:
        return 0, f0, f1, f2, f3, f4, f5, f6, f7, f8
    for i in range(ptr0, ptr1):
        k, side = entries[i] >> 1, entries[i] & 1
        tau = torque_value[k] if torque_enabled[k] else 0.0
        if tau == 0.0:
            continue
        sign = -1.0 if side == 0 else 1.0            # ê_i = −ê_j
        ex, ey, ez = sign * e[k, 0], sign * e[k, 1], sign * e[k, 2]
        # (τ/2) [ê]× A^{−T}: column c of A^{−T} is row c of A^{−1}; f[3r + c] = F_b[3 + 3r + c]
        t = 0.5 * tau
        f0 += t * (ey * i02 - ez * i01)
        f3 += t * (ez * i00 - ex * i02)
        f6 += t * (ex * i01 - ey * i00)
        f1 += t * (ey * i12 - ez * i11)
        f4 += t * (ez * i10 - ex * i12)
        f7 += t * (ex * i11 - ey * i10)
        f2 += t * (ey * i22 - ez * i21)
        f5 += t * (ez * i20 - ex * i22)
        f8 += t * (ex * i21 - ey * i20)
    return 1, f0, f1, f2, f3, f4, f5, f6, f7, f8


@kernel
def _axes(q, torque_joints, parent, child, x_bar, torque_value, torque_enabled, e):
    """e[:T] = ê of the active torque joints (others unset); e (T+2,3), the last two scratch."""
    T = torque_joints.size
    es = e[T:]
    for k in range(T):
        if torque_enabled[k] and torque_value[k] != 0.0:
            axis_at(q, parent, child, x_bar, torque_joints[k], e[k], es)


@kernel
def _list_skipped(q, torque_joints, parent, child, torque_value, torque_enabled, skipped):
    """The bodies the singular guard skips, once per (side, joint) in that order (parent side
    of every joint first); returns their count. Runs only when some body was skipped."""
    n_skipped = 0
    for side in range(2):
        for k in range(torque_joints.size):
            tau = torque_value[k] if torque_enabled[k] else 0.0
            if tau == 0.0:
                continue
            j = torque_joints[k]
            b = parent[j] if side == 0 else child[j]
            if not _inverse_if_regular(q, b)[0]:
                skipped[n_skipped] = b
                n_skipped += 1
    return n_skipped


@kernel
def add_acceleration(q, m, torque_value, torque_enabled, acc, skipped, e):
    """acc += M⁻¹F of the UID 668 torques on the free bodies; returns the number of skipped
    bodies. F_b is nonzero only in A's rows, so (M⁻¹F)_r is a 3-term sum (m.body_Minv_bar),
    in the dense product's order. e (T+2,3): work for the axes (Workspace.torque_axes)."""
    if not _any_active(torque_value, torque_enabled, m.torque_joints.size):
        return 0
    tj, parent, child = m.torque_joints, m.joint_parent, m.joint_child
    _axes(q, tj, parent, child, m.joint_x_bar, torque_value, torque_enabled, e)
    bodies, ptr, entries = m.torque_bodies, m.torque_body_ptr, m.torque_body_entries
    Minv_bar, fixed = m.body_Minv_bar, m.body_fixed
    any_skipped = False
    for t in range(bodies.size):
        b = bodies[t]
        if fixed[b]:
            continue
        status, f0, f1, f2, f3, f4, f5, f6, f7, f8 = _body_force(q, b, ptr[t], ptr[t + 1], entries, e,
                                                                 torque_value, torque_enabled)
        if status == 0:
            any_skipped = True
        if status != 1:
            continue
        for k in range(3):
            Mi = Minv_bar[b, k]
            g0, g1, g2 = (f0, f1, f2) if k == 0 else ((f3, f4, f5) if k == 1 else (f6, f7, f8))
            acc[b, k] += Mi[0, 1] * g0 + Mi[0, 2] * g1 + Mi[0, 3] * g2
            for i in range(3):
                acc[b, 3 + 3 * k + i] += Mi[1 + i, 1] * g0 + Mi[1 + i, 2] * g1 + Mi[1 + i, 3] * g2
    if not any_skipped:
        return 0
    return _list_skipped(q, tj, parent, child, torque_value, torque_enabled, skipped)
