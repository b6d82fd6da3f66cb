"""Joint limit, libuipc UID 670 (docs/physics.md "Limit (UID 670)"): a cubic barrier outside
[l, u] on the unwrapped joint angle x (relative to init_angle), with w = u − l and strength s:

    x > u:  E = s ((x − u)/w)³          x < l:  E = s ((l − x)/w)³          inside: E = 0
    w = 0:  E = s |x − l|³ (a locked joint)

E' and E'' follow; gradient and Hessian via angle.accumulate_angle_joint (PSD-projected, or
exact where the bodies' inertia keeps Newton's matrix positive definite).

`inside` shows a limit inside its range (contributing nothing) without atan2, only where the
angle is at least INSIDE_SAFETY from both bounds: the same bits.
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import flat, kernel
from . import angle, select

NAME = 'limit'              #: in Solver.terms
STORED = True               #: E/h² is stored energy (World.mechanical_energy)
CONSTANT_HESSIAN = False
ANGLE_BUDGET = True          #: shares its bodies' inertia (model_data.joint_angle_budget)
#: a scene joint's keys that put the term on it (jit/warmup.py's scenes)
EXAMPLE = dict(limit=dict(lower=-0.1, upper=0.1))
FIELDS = (
    ('limit_joints', '(L,) joints with UID 670'),
    ('limit_lower', '[rad] (L,) lower bound relative to init_angle'),
    ('limit_upper', '[rad] (L,) upper bound relative to init_angle'),
    ('limit_strength', '(L,) s of UID 670'),
)


def used(model) -> bool:
    return len(model.limit_joints) > 0


def from_scene(scene, model, prefix='limit_', sliding=False) -> dict:
    """The Model's fields of this term (prismatic_limit's with its `prefix`, on the sliding
    joints): the joints with a limit, (n,); their lower and upper bounds (absolute: rad, or m
    sliding) and strength, (n,)."""
    ks = select.joints(scene, model, sliding, lambda j: j.limit is not None)
    spec = [scene.joints[k].limit for k in ks]
    return {prefix + 'joints': ks, prefix + 'lower': np.array([s.lower for s in spec], float),
            prefix + 'upper': np.array([s.upper for s in spec], float),
            prefix + 'strength': np.array([s.strength for s in spec], float)}


def build(model, data, prefix='limit_') -> dict:
    """FIELDS' values (prismatic_limit's with its `prefix`), bounds relative to the init value."""
    lj, lower, upper, strength = (getattr(model, prefix + n)
                                  for n in ('joints', 'lower', 'upper', 'strength'))
    init = model.joint_init_angle[lj]
    return {prefix + 'joints': flat.array(lj, np.int64),
            prefix + 'lower': flat.array(lower - init, np.float64),
            prefix + 'upper': flat.array(upper - init, np.float64),
            prefix + 'strength': flat.array(strength, np.float64)}


@kernel
def phi(x, lower, upper, s):
    """(E, E', E'') of the limit at angle x."""
    w = upper - lower
    if w == 0.0:
        e = x - lower
        return s * abs(e) ** 3, 3 * s * abs(e) * e, 6 * s * abs(e)
    if x > upper:
        a = (x - upper) / w
        return s * a ** 3, 3 * s * a * a / w, 6 * s * a / w ** 2
    if x < lower:
        b = (lower - x) / w
        return s * b ** 3, -3 * s * b * b / w, 6 * s * b / w ** 2
    return 0.0, 0.0, 0.0


@kernel
def active(x, lower, upper):
    """Outside the range, or off a zero-width limit."""
    return x > upper or x < lower or (lower == upper and x != lower)


@kernel
def angle_of(c, s, start):
    """x from the joint frames' (c, s): atan2 unwrapped about the step's start angle. [rad]"""
    return angle.unwrap(math.atan2(s, c), start)


#: [rad] `inside` answers "inside" only this far within both bounds (x's rounding is ~1e-12)
INSIDE_SAFETY = 1e-9
#: the columns of its rows of StepContext.angle_ref (`references`)
REFERENCE_COLUMNS = 3


@kernel
def references(m, q0, q_prev, angle_start, h, bdf2, work, ref):
    """ref (≥ L, ≥ 3) for `inside`, per limit k (row k): cos x₀, sin x₀ of its joint's angle at the step's
    start x₀ = angle_start[j], and an upper bound T of cos μ, μ = min(x₀ − l, u − x₀) −
    INSIDE_SAFETY the start's margin inside [l, u]: T = 1 − μ²/2 + μ⁴/24 (≥ cos μ for every
    μ, so no third trigonometric call), 2 where there is no margin (the start outside or on a
    bound, a locked joint: `inside` then never answers), −2 where μ ≥ π (any angle within
    half a turn of the start, as unwrap picks it, is inside). Returns ref."""
    limit_joints, lower, upper = m.limit_joints, m.limit_lower, m.limit_upper
    for k in range(limit_joints.size):
        x0 = angle_start[limit_joints[k]]
        margin = min(x0 - lower[k], upper[k] - x0) - INSIDE_SAFETY
        if not (lower[k] < upper[k] and margin > 0.0):
            ref[k, 2] = 2.0
        elif margin >= math.pi:
            ref[k, 2] = -2.0
        else:
            ref[k, 0] = math.cos(x0)
            ref[k, 1] = math.sin(x0)
            mm = margin * margin
            ref[k, 2] = min(1.0 - 0.5 * mm + mm * mm / 24.0, 1.0)
    return ref


@kernel
def inside(c, s, ref, k):
    """Whether limit k's joint angle x, atan2(s, c) from its frames' (c, s) unwrapped about the
    step's start x₀, is shown strictly inside [l, u] without atan2: x = x₀ + δ, |δ| ≤ π as
    unwrap picks it, and |δ| < μ holds where cos δ > T ≥ cos μ, with r cos δ = c cos x₀ +
    s sin x₀, r = |(c, s)| (compared squared: no square root). False means "not shown": the
    caller computes x from the same (c, s)."""
    T = ref[k, 2]
    if T > 1.0:
        return False
    if T < -1.0:
        return True
    d = c * ref[k, 0] + s * ref[k, 1]          # r cos δ
    t = T * T * (c * c + s * s)                # (r T)²
    if T >= 0.0:
        return d > 0.0 and d * d > t
    return d >= 0.0 or d * d < t


@kernel
def energy(q, m, ctx):
    lower, upper, strength = m.limit_lower, m.limit_upper, m.limit_strength
    parent, child, nbar, bbar = m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar
    ref, start = ctx.angle_ref, ctx.angle_start
    E = 0.0
    for k in range(lower.size):
        j = m.limit_joints[k]
        c, s = angle.cos_sin_at(q, parent, child, nbar, bbar, j)
        if inside(c, s, ref, k):
            continue
        x = angle_of(c, s, start[j])
        if active(x, lower[k], upper[k]):
            E += phi(x, lower[k], upper[k], strength[k])[0]
    return E


@kernel
def accumulate(q, m, ctx, grad, diag, pair, project):
    """∇E and the (projected) Hessian of the active limits via `phi` and
    angle.accumulate_angle_joint (in ctx.angle_work); returns E (`energy`'s bits)."""
    limit_joints, lower, upper, strength = m.limit_joints, m.limit_lower, m.limit_upper, m.limit_strength
    parent, child, nbar, bbar = m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar
    budget = m.joint_angle_budget
    work, ref, start = ctx.angle_work, ctx.angle_ref, ctx.angle_start
    E = 0.0
    for k in range(limit_joints.size):
        j = limit_joints[k]
        c, s = angle.cos_sin_at(q, parent, child, nbar, bbar, j)
        if inside(c, s, ref, k):
            continue
        x = angle_of(c, s, start[j])
        if active(x, lower[k], upper[k]):
            e, d1, d2 = phi(x, lower[k], upper[k], strength[k])
            E += e
            angle.accumulate_angle_joint(q, parent, child, nbar, bbar, j, d1, d2, grad, diag, pair,
                                          project, work, ctx.scale * budget[j])
    return E
