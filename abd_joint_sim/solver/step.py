"""One (sub-)step, compiled (docs/physics.md "Time integration", "Newton"):

    1. forces: a = g_q + M⁻¹F at qⁿ (BDF1) or 2qⁿ − qⁿ⁻¹ (BDF2)     terms/gravity, torque, prismatic_force
    2. prediction q̃ (bdf.predict); may_split: refuse a step whose linearised joint rotation
       ∇θ(qⁿ)·(q̃ − qⁿ) exceeds max_step_rotation (only the prediction can see it)
    3. Newton minimises Π from q̃ + c h² w (c = 1 BDF1, β BDF2), w the last three
       corrections extrapolated (3 w_n − 3 w_(n−1) + w_(n−2), or linearly), or from
       q̃ + c h² warm_start or q̃ where Π is lower                          newton.minimize
    4. velocities (bdf.velocity), warm start (q − q̃)/(c h²), joint angles and θ̇ = ∇θ·v
       (prismatic: d, ḋ = ∇d·v), the step's largest joint rotation, joint separations.

`one_step` writes the new state into the caller's arrays and what happened into an `outcome`
row (columns below; solver.py makes a StepReport). Entries called from Python: `steps`
(n ≥ 1 steps, bit-identical to n calls with n = 1) and `step_resident` (`World.step()`).
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import flat, kernel, refcounts, subnormals
from ..terms import angle, damping, gravity, prismatic, prismatic_driving, prismatic_force, revolute, torque
from . import bdf, newton

# columns of a step's outcome row
OUT_STATUS = 0           #: newton status code
OUT_NEWTON = 1           #: Newton iterations
OUT_LINE_SEARCH = 2      #: line-search halvings
OUT_ROTATION = 3         #: [rad] largest joint rotation (or the predicted one when refused)
OUT_FAILURE = 4          #: one of the FAIL_* codes
OUT_SKIPPED = 5          #: bodies the torque's singular guard skipped (listed in `skipped`)
OUT_SEPARATION = 6       #: [m] largest joint separation after the step
OUT_OVERLOADED = 7       #: 1 if a joint's separation exceeds its warning limit
OUT_APART_JOINT = 8      #: the first joint that came apart (FAIL_JOINT_APART), else -1
OUT_COLUMNS = 9
FAIL_NONE, FAIL_NEWTON_NONFINITE, FAIL_STEP_NONFINITE, FAIL_PREDICTED_ROTATION, FAIL_JOINT_APART = 0, 1, 2, 3, 4


@kernel
def predicted_rotation(m, q, q_tilde):
    """max_j |∇θ_j(qⁿ)·(q̃ − qⁿ)_j| (NaN wins, and then no split is asked)."""
    parent, child, nbar, bbar = m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar
    out = 0.0
    for j in range(parent.size):
        x = abs(angle.cos_sin_slope_at(q, q_tilde, q, parent, child, nbar, bbar, j)[2])
        if x != x:
            out = np.nan
        elif out == out:
            out = max(out, x)
    return out


@kernel
def forces(m, q, q_prev, bdf2, torque_value, torque_enabled, ws, skipped):
    """Section 1: ws.acc = g_q + M⁻¹F, the torque at qⁿ (BDF1) or 2qⁿ − qⁿ⁻¹ (BDF2, ws.q_force,
    formed only when a torque acts); returns the number of bodies the torque skipped."""
    acc = ws.acc
    flat.fill(acc, 0.0)
    gravity.add_acceleration(q, m, acc)
    if m.prismatic_force_joints.size and prismatic_force.any_active(m, torque_value, torque_enabled):
        if bdf2:                            # (UID 667: rows T.. of the effort arrays)
            bdf.force_point(q, q_prev, bdf2, ws.q_force)
            prismatic_force.add_acceleration(ws.q_force, m, torque_value, torque_enabled, acc)
        else:
            prismatic_force.add_acceleration(q, m, torque_value, torque_enabled, acc)
    if not torque.any_active(m, torque_value, torque_enabled):
        return 0
    if bdf2:
        bdf.force_point(q, q_prev, bdf2, ws.q_force)
        return torque.add_acceleration(ws.q_force, m, torque_value, torque_enabled, acc, skipped,
                                       ws.torque_axes)
    return torque.add_acceleration(q, m, torque_value, torque_enabled, acc, skipped, ws.torque_axes)


@kernel
def joint_rates(m, q_new, v_new, zero, angle_start, h, new_angles, work):
    """Section 4's joint angles: new_angles (2,J) = unwrapped θ + init_angle, θ̇ = ∇θ·v (a
    prismatic joint: d + init_distance, ḋ = ∇d·v); returns (the largest |θ − θ_start| or
    |θ̇| h over the revolute joints, NaN wins; whether every θ and d is finite). work: (≥ 16,
    ≥ 3) scratch (the step's angle_work)."""
    parent, child, nbar, bbar = m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar
    init_angle = m.joint_init_angle
    slot = m.prismatic_slot
    rotation = 0.0
    finite = True
    for j in range(parent.size):
        if slot[j] >= 0:
            d, rate = prismatic.distance_and_rate(q_new, v_new, parent[j], child[j], m.prismatic_frame,
                                                  slot[j], work)
            new_angles[0, j] = d + init_angle[j]
            new_angles[1, j] = rate
            if not (math.isfinite(d) and math.isfinite(rate)):
                finite = False
            continue
        c, s, rate = angle.cos_sin_slope_at(q_new, v_new, zero, parent, child, nbar, bbar, j)   # θ̇ = ∇θ·v
        th = math.atan2(s, c)
        rel = angle.unwrap(th, angle_start[j])
        new_angles[0, j] = rel + init_angle[j]
        new_angles[1, j] = rate
        if not math.isfinite(rel):
            finite = False
        turn, swept = abs(rel - angle_start[j]), abs(rate) * h     # NaN wins
        if turn != turn or swept != swept:
            rotation = np.nan
        elif rotation == rotation:
            rotation = max(rotation, turn, swept)
    return rotation, finite


@kernel
def store(q_new, q_tilde, cw, new_qvw):
    """new_qvw[0] = q, new_qvw[2] = the next warm start (q − q̃)/(c h²) (cw = c h²)."""
    for b in range(q_new.shape[0]):
        for r in range(12):
            new_qvw[0, b, r] = q_new[b, r]
            new_qvw[2, b, r] = (q_new[b, r] - q_tilde[b, r]) / cw


@kernel
def one_step(m, q, v, q_prev, v_prev, warm_start, warm_start_prev, warm_start_prev2, joint_angle,
             torque_value, torque_enabled, drive_aim, drive_enabled, drive_passive, h, bdf2, order,
             may_split, ws, new_qvw, new_angles, skipped, outcome):
    """One step of size h in ws (workspace.Workspace): new_qvw (3,B,12) = new q, v,
    warm_start; new_angles (2,J) = joint angle, velocity; skipped[:outcome[OUT_SKIPPED]] =
    bodies without torque. `order` (State.extrapolation_order): warm starts extrapolated over
    (0, 1 or 2). The entries flush subnormals around it (jit/subnormals.py)."""
    # the caller keeps these alive: no reference counts below (refcounts.py)
    m, ws = refcounts.struct(m), refcounts.struct(ws)
    q, v, q_prev, v_prev = refcounts.array(q), refcounts.array(v), refcounts.array(q_prev), refcounts.array(v_prev)
    warm_start, warm_start_prev = refcounts.array(warm_start), refcounts.array(warm_start_prev)
    warm_start_prev2, joint_angle = refcounts.array(warm_start_prev2), refcounts.array(joint_angle)
    torque_value, torque_enabled = refcounts.array(torque_value), refcounts.array(torque_enabled)
    drive_aim, drive_enabled = refcounts.array(drive_aim), refcounts.array(drive_enabled)
    drive_passive, skipped = refcounts.array(drive_passive), refcounts.array(skipped)
    new_qvw, new_angles, outcome = refcounts.array(new_qvw), refcounts.array(new_angles), refcounts.array(outcome)
    B, J = q.shape[0], m.joint_parent.size
    flat.fill(outcome, 0.0)
    outcome[OUT_APART_JOINT] = -1.0
    # 1. forces
    outcome[OUT_SKIPPED] = forces(m, q, q_prev, bdf2, torque_value, torque_enabled, ws, skipped)
    # 2. prediction
    q_tilde = ws.q_tilde
    scale = bdf.predict(m, q, v, q_prev, v_prev, ws.acc, h, bdf2, q_tilde)
    if may_split and J > 0:
        predicted = predicted_rotation(m, q, q_tilde)
        if predicted > m.max_step_rotation:
            outcome[OUT_ROTATION], outcome[OUT_FAILURE] = predicted, FAIL_PREDICTED_ROTATION
            return
    # 3. Newton
    init_angle = m.joint_init_angle
    angle_start = ws.angle_start
    for j in range(J):
        angle_start[j] = joint_angle[j] - init_angle[j]
    drive_joints = m.drive_joints
    drive_target = ws.drive_target
    for k in range(drive_joints.size):
        j = drive_joints[k]
        drive_target[k] = angle_start[j] if drive_passive[k] else drive_aim[k] - init_angle[j]
    if m.prismatic_drive_joints.size:       # UID 21: rows D.. of the drive arrays
        prismatic_driving.targets(m, angle_start, drive_aim, drive_passive, drive_target)
    cw = h * h / scale
    q_new, q_alt = ws.q_new, ws.q_alt
    # Newton starts from the correction extrapolated quadratically (Mini Cheetah: 1.96 -> 1.16
    # iterations per step), linearly for all bodies where the second difference exceeds the
    # first, or from w_n or q̃ where Π is lower (docs/decisions.md)
    extrapolate = order > 0
    quadratic = order == 2
    if quadratic:
        first = second = 0.0
        for b in range(B):
            for r in range(12):
                d1 = warm_start[b, r] - warm_start_prev[b, r]
                d2 = d1 - (warm_start_prev[b, r] - warm_start_prev2[b, r])
                first += d1 * d1
                second += d2 * d2
        quadratic = second <= first
    for b in range(B):
        for r in range(12):
            w = warm_start[b, r]
            if extrapolate:                 # (q_alt is read only then)
                q_alt[b, r] = q_tilde[b, r] + cw * w
                if quadratic:
                    w = 3.0 * w - 3.0 * warm_start_prev[b, r] + warm_start_prev2[b, r]
                else:
                    w = 2.0 * w - warm_start_prev[b, r]
            q_new[b, r] = q_tilde[b, r] + cw * w
    newton.references(m, q_new, q_prev, angle_start, h, bdf2, ws.angle_work, ws.angle_ref)
    ctx = refcounts.struct(ws.ctx)          # (built here, it would be copied into every term call)
    ctx.h, ctx.scale = h, scale
    drive_on = ctx.drive_on
    for k in range(drive_on.size):
        drive_on[k] = drive_enabled[k]
    status, iterations, halvings = newton.minimize(m, ctx, q_new, ws, extrapolate)
    v_new = new_qvw[1]
    repeat = 0
    while True:
        outcome[OUT_STATUS], outcome[OUT_NEWTON], outcome[OUT_LINE_SEARCH] = status, iterations, halvings
        if status == newton.NONFINITE or not newton.all_finite(q_new):
            outcome[OUT_FAILURE] = FAIL_NEWTON_NONFINITE
            return
        # 4. velocities, joint angles, checks
        v_finite = bdf.velocity(m, q_new, q, q_prev, h, bdf2, v_new)
        rotation, finite = joint_rates(m, q_new, v_new, ws.zero, angle_start, h, new_angles,
                                       ws.angle_work)
        if not finite or not v_finite:
            outcome[OUT_FAILURE] = FAIL_STEP_NONFINITE
            return
        # the dampers' linearisation checked at the answer; where it missed, Newton goes on
        if m.damping_joints.size == 0 or repeat == damping.RELINEARISE_MAX or \
                damping.linearisation_holds(m, q_new, new_angles[0], ws.angle_ref, m.transrate_tol * h):
            break
        damping.references(m, q_new, q_prev, angle_start, h, bdf2, ws.angle_work, ws.angle_ref)
        status, its, halved = newton.minimize(m, ctx, q_new, ws, False)
        iterations += its
        halvings += halved
        repeat += 1
    outcome[OUT_ROTATION] = rotation
    separation, overloaded, apart = revolute.check_separations(q_new, m)
    if m.prismatic_joints.size:
        s2, o2, a2 = prismatic.check_separations(q_new, m)
        if s2 > separation or s2 != s2:
            separation = s2
        overloaded = overloaded or o2
        if apart < 0:
            apart = a2
    outcome[OUT_SEPARATION] = separation
    outcome[OUT_OVERLOADED] = 1.0 if overloaded else 0.0
    if apart >= 0:
        outcome[OUT_APART_JOINT], outcome[OUT_FAILURE] = apart, FAIL_JOINT_APART
    store(q_new, q_tilde, cw, new_qvw)


@kernel
def clean(o, clean_rotation):
    """Whether outcome row o is clean: no failure, converged, no torque skipped, no joint
    turned more than `clean_rotation` (the accuracy warning's) or overloaded."""
    return (o[OUT_FAILURE] == FAIL_NONE and o[OUT_STATUS] == newton.CONVERGED and o[OUT_SKIPPED] == 0.0
            and o[OUT_ROTATION] <= clean_rotation and o[OUT_OVERLOADED] == 0.0)


@kernel
def kept(o, keep_rotation):
    """Whether outcome row o is kept without sub-steps (Solver._decode's rule): no failure,
    converged, no joint turned more than `keep_rotation` (max_step_rotation)."""
    return (o[OUT_FAILURE] == FAIL_NONE and o[OUT_STATUS] == newton.CONVERGED
            and o[OUT_ROTATION] <= keep_rotation)


#: step_resident's return value for a step kept with warnings (its report names them)
KEPT_WITH_WARNINGS = -2


@kernel
def step_resident(io):
    """`World.step()`: `one_step` on a Resident's ring (io: resident.ResidentIO). A `clean`
    or `kept` step advances the Resident (slot cur + 1, the clock by h, known warm starts as
    solver._history) and returns its Newton iterations (≥ 1), −1 if its line search halved,
    or KEPT_WITH_WARNINGS; any other returns 0, only slot cur + 1 and the outcome changed.
    Per call 2.5 µs against 6.8 for `Solver.step` on one link, 11.3 / 16.6 on a 10-link
    chain, 10.9 / 16.0 on the KUKA iiwa (one process; `bench/profiler.py devices`)."""
    io = refcounts.struct(io)
    slots, clock, h = io.slots, io.clock, io.h
    cur, known = slots[0], slots[1]
    uniform = clock[1] == h
    outcome = io.outcome
    # the state is slot cur of the ring, its history the slots before it (modulo 4)
    prev, prev2, nxt = (cur + 3) % 4, (cur + 2) % 4, (cur + 1) % 4
    ring, angles = refcounts.array(io.ring), refcounts.array(io.angles)
    saved = subnormals.enter()
    one_step(io.model, ring[cur, 0], ring[cur, 1], ring[prev, 0], ring[prev, 1], ring[cur, 2], ring[prev, 2],
             ring[prev2, 2], angles[cur, 0], io.torque_value, io.torque_enabled, io.drive_aim,
             io.drive_enabled, io.drive_passive, h, io.bdf2 and uniform, known if uniform else 0,
             io.may_split, io.work, ring[nxt], angles[nxt], io.skipped, outcome)
    subnormals.leave(saved)
    if clean(outcome, io.clean_rotation):
        code = int(outcome[OUT_NEWTON]) if outcome[OUT_LINE_SEARCH] == 0.0 else -1
    elif kept(outcome, io.keep_rotation):
        code = KEPT_WITH_WARNINGS
    else:
        return 0
    slots[0] = (cur + 1) % 4
    slots[1] = min(known + 1, 2) if uniform else 0
    slots[2] += 1
    clock[0] += h
    clock[1] = h
    return code


@kernel
def steps(m, q, v, q_prev, v_prev, warm_start, warm_start_prev, warm_start_prev2, joint_angle,
          torque_value, torque_enabled, drive_aim, drive_enabled, drive_passive, h, bdf2_first,
          bdf2_next, uniform_first, order_first, may_split, n, clean_rotation, keep_rotation, ws,
          new_qvw, new_angles, skipped, outcome):
    """Up to n steps, each `one_step` on the previous one's output, stopping before the first
    neither `clean` nor `kept` with keep_rotation (< 0: before any warning too); a kept step
    that skipped a torque ends the batch. Step k writes new_qvw[k], new_angles[k],
    outcome[k]; returns the count. Warm-start history as solver._history (`uniform_first`,
    `order_first`: the input's last step size was h, its extrapolation_order)."""
    # the caller keeps these alive: no reference counts for them or their views (refcounts.py)
    q, v, q_prev, v_prev = refcounts.array(q), refcounts.array(v), refcounts.array(q_prev), refcounts.array(v_prev)
    warm_start, warm_start_prev = refcounts.array(warm_start), refcounts.array(warm_start_prev)
    new_qvw, new_angles, outcome = refcounts.array(new_qvw), refcounts.array(new_angles), refcounts.array(outcome)
    done = 0
    saved = subnormals.enter()              # once for all n steps (jit/subnormals.py)
    for k in range(n):
        if k == 0:
            one_step(m, q, v, q_prev, v_prev, warm_start, warm_start_prev, warm_start_prev2, joint_angle,
                 torque_value, torque_enabled, drive_aim, drive_enabled, drive_passive, h, bdf2_first,
                 order_first, may_split, ws, new_qvw[0], new_angles[0], skipped, outcome[0])
        else:
            if k == 1:                      # the step before is the input's
                qp, vp, prev = q, v, warm_start if uniform_first else new_qvw[0, 2]
                prev2 = warm_start_prev if uniform_first and order_first > 0 else prev
                order = (2 if order_first > 0 else 1) if uniform_first else 0
            else:
                qp, vp, prev = new_qvw[k - 2, 0], new_qvw[k - 2, 1], new_qvw[k - 2, 2]
                prev2 = new_qvw[k - 3, 2] if k > 2 else (warm_start if uniform_first else prev)
                order = 2 if k > 2 or uniform_first else 1
            one_step(m, new_qvw[k - 1, 0], new_qvw[k - 1, 1], qp, vp, new_qvw[k - 1, 2], prev,
                 prev2, new_angles[k - 1, 0], torque_value, torque_enabled, drive_aim, drive_enabled,
                 drive_passive, h, bdf2_next, order, may_split, ws, new_qvw[k], new_angles[k],
                 skipped, outcome[k])
        if clean(outcome[k], clean_rotation):
            done += 1
        elif kept(outcome[k], keep_rotation):
            done += 1
            if outcome[k, OUT_SKIPPED] != 0.0:
                break
        else:
            break
    subnormals.leave(saved)
    return done
