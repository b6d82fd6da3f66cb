"""Where the µs of a step go: each part of the compiled step timed on its own, called in a
loop from compiled code (no Python between calls), on chains of 1/10/100/1000 links and the
KUKA iiwa URDF with gravity (dt 1 ms, torque 1 N m on every joint, state after 3 steps). For
docs/speed.md.

    python bench/profiler.py step [--links 1 10 100] [--no-kuka]

Columns are µs of CPU time per call, the fastest of 5 rounds. First table, Newton's parts:
`solve` is assemble + solve minus assemble (the solve factors the assembled blocks in place);
`step` is one whole compiled step (kernel `step.steps`, n = 1) called from Python. Second table, the step outside Newton (sections 1, 2
and 4 of solver/step.py): `forces` (gravity, torque axes, A⁻¹, M⁻¹F), `predict` (q̃),
`pred_rot` (the predicted rotation), `velocity`, `angles` (θ, θ̇, unwrap), `separations`,
`store` (q and warm start into the output), `finite` (one all_finite pass); `newton` the
Newton solve from the step's own start point; `step_c` the whole step from a compiled loop,
`outside` = step_c − newton, and `dispatch` = `step` − step_c, what the call from Python costs.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from abd_joint_sim import Scene, World                          # noqa: E402
from abd_joint_sim.builders import chain_scene                  # noqa: E402
from abd_joint_sim.solver import linsolve, newton, step as kernel  # noqa: E402
from abd_joint_sim.solver.retraction import retract             # noqa: E402
from abd_joint_sim.jit import subnormals                         # noqa: E402
from abd_joint_sim.solver import bdf                             # noqa: E402
from abd_joint_sim.terms import inertia, ortho, revolute, torque  # noqa: E402

PARTS = ('potential', 'assemble', 'ortho', 'revolute', 'inertia', 'solve', 'retract',
         'newton', 'torque', 'step')
OUTSIDE = ('forces', 'predict', 'pred_rot', 'velocity', 'angles', 'separations', 'store', 'finite',
           'newton', 'step_c', 'outside', 'dispatch')


@njit
def _run(which, m, ctx, q, ws, c_tv, c_te, skipped, n):
    acc = 0.0
    saved = subnormals.enter()          # as in the step
    for _ in range(n):
        if which == 0:
            acc += newton.potential(q, m, ctx)
        elif which == 1:
            newton.assemble(q, m, ctx, ws.grad, ws.diag, ws.pair)
        elif which == 2:
            ortho.accumulate(q, m, ctx, ws.grad, ws.diag, ws.pair, True)
        elif which == 3:
            revolute.accumulate_gradient(q, m, ctx, ws.grad)
        elif which == 4:
            inertia.accumulate(q, m, ctx, ws.grad, ws.diag, ws.pair, True)
        elif which == 5:
            joint_blocks = newton.assemble(q, m, ctx, ws.grad, ws.diag, ws.pair)[0]
            linsolve.solve(m, ws.diag, joint_blocks, ws.grad, ws.dq, ws)
        elif which == 6:
            retract(q, ws.dq, 1.0, m, ws, ws.trial)
        elif which == 7:
            ws.q_new[:] = q
            newton.minimize(m, ctx, ws.q_new, ws, False)
        elif which == 8:
            ws.acc[:] = 0.0
            torque.add_acceleration(q, m, c_tv, c_te, ws.acc, skipped, ws.torque_axes)
    subnormals.leave(saved)
    return acc


@njit
def _outside(which, m, ctx, q, v, q_prev, v_prev, start, tv, te, ws, qvw, aw, skipped, h, n):
    """Times part `which` of OUTSIDE (the step's own functions, on its own arrays)."""
    acc = 0.0
    saved = subnormals.enter()          # as in the step
    for _ in range(n):
        if which == 0:
            acc += kernel.forces(m, q, q_prev, False, tv, te, ws, skipped)
        elif which == 1:
            acc += bdf.predict(m, q, v, q_prev, v_prev, ws.acc, h, False, ws.q_tilde)
        elif which == 2:
            acc += kernel.predicted_rotation(m, q, ws.q_tilde)
        elif which == 3:
            bdf.velocity(m, ws.q_new, q, q_prev, h, False, qvw[1])
        elif which == 4:
            acc += kernel.joint_rates(m, ws.q_new, qvw[1], ws.zero, ctx.angle_start, h, aw, ws.angle_work)[0]
        elif which == 5:
            acc += revolute.check_separations(ws.q_new, m)[0]
        elif which == 6:
            kernel.store(ws.q_new, ws.q_tilde, h * h, qvw)
        elif which == 7:
            acc += newton.all_finite(ws.q_new)
        elif which == 8:
            ws.q_new[:] = start
            newton.minimize(m, ctx, ws.q_new, ws, False)
    subnormals.leave(saved)
    return acc


ROUNDS = 5     # each figure is the fastest of this many rounds: the machine is shared


def timed(call, n):
    """µs per iteration of call(k) (which runs k iterations): this process's CPU time (time
    waiting for a core on a shared machine does not count), the fastest of ROUNDS rounds of n."""
    call(2)
    best = math.inf
    for _ in range(ROUNDS):
        t0 = time.process_time()
        call(n)
        best = min(best, (time.process_time() - t0) / n * 1e6)
    return best


def outside(w, n):
    """µs per call of each OUTSIDE part of World w's next step (BDF1, may split)."""
    sv, st, c = w.solver, w.state, w.control
    m, ws = sv.data, sv.work
    qvw, aw = np.empty((1, 3) + st.q.shape), np.empty((1, 2, w.model.joint_count))
    args = _one_step_args(w, qvw, aw)
    kernel.steps(*args)                               # leaves q̃ and the solved q in ws
    q_tilde = ws.q_tilde.copy()
    # Newton's start in the step (BDF1: c = 1; the warm start extrapolated over three steps)
    assert st.extrapolation_order(w.dt) == 2
    start = q_tilde + w.dt * w.dt * (3.0 * st.warm_start - 3.0 * st.warm_start_prev + st.warm_start_prev2)
    ctx = sv.context(st, c, w.dt, q_tilde=q_tilde)
    out = {}
    for i, name in enumerate(OUTSIDE[:9]):
        call = (i, m, ctx, st.q, st.v, st.q_prev, st.v_prev, start, c.torque_value, c.torque_enabled,
                ws, qvw[0], aw[0], sv._skipped, w.dt)
        out[name] = timed(lambda k, call=call: _outside(*call, k), n)
    out['step_c'] = timed(lambda k: _step_loop(k, *args), n)
    out['dispatch'] = timed(lambda k: [kernel.steps(*args) for _ in range(k)], n) - out['step_c']
    out['outside'] = out['step_c'] - out['newton']
    return out


def _one_step_args(w, qvw, aw):
    """The arguments of `step.steps` for World w's next step alone (BDF1, may split, n = 1)."""
    sv, st, c = w.solver, w.state, w.control
    return (sv.data, st.q, st.v, st.q_prev, st.v_prev, st.warm_start, st.warm_start_prev,
            st.warm_start_prev2, st.joint_angle, c.torque_value, c.torque_enabled, c.drive_aim,
            c.drive_enabled, c.drive_passive, w.dt, False, False, True, st.extrapolation_order(w.dt),
            True, 1, 0.1, 1.0, sv.work, qvw, aw, sv._skipped, sv._outcomes)


@njit
def _step_loop(n, m, q, v, q_prev, v_prev, warm_start, warm_start_prev, warm_start_prev2, joint_angle,
               torque_value, torque_enabled, drive_aim, drive_enabled, drive_passive, h, bdf2_first,
               bdf2_next, uniform_first, order_first, may_split, steps, clean_rotation, keep_rotation,
               ws, new_qvw, new_angles, skipped, outcome):
    for _ in range(n):
        kernel.steps(m, q, v, q_prev, v_prev, warm_start, warm_start_prev, warm_start_prev2,
                     joint_angle, torque_value, torque_enabled, drive_aim, drive_enabled,
                     drive_passive, h, bdf2_first, bdf2_next, uniform_first, order_first, may_split,
                     steps, clean_rotation, keep_rotation, ws, new_qvw, new_angles, skipped, outcome)


def world(links):
    """A World on a chain of `links` links, or on the KUKA iiwa URDF (links = 0), torque 1 N m on
    every joint, after 3 steps."""
    if links:
        w = World(Scene.from_dict(chain_scene(links)))
    else:
        import pybullet_data
        w = World(Scene.from_urdf(os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa', 'model.urdf')))
    for j in w.actuated_joint_names:
        w.set_torque(j, 1.0)
    w.step(3)
    return w


def profile(links):
    w = world(links)
    sv, st, c = w.solver, w.state, w.control
    m, ws = sv.data, sv.work
    ctx = sv.context(st, c, w.dt)
    q = st.q.copy()
    n = max(20000 // max(links, 7), 5)
    out = {}
    for i, name in enumerate(PARTS[:-1]):
        out[name] = timed(lambda k, i=i: _run(i, m, ctx, q, ws, c.torque_value, c.torque_enabled,
                                              sv._skipped, k), n)
    qvw, aw = np.empty((1, 3) + q.shape), np.empty((1, 2, w.model.joint_count))
    args = _one_step_args(w, qvw, aw)
    out['step'] = timed(lambda k: [kernel.steps(*args) for _ in range(k)], n)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(prog='bench/profiler.py step', description=__doc__.split('\n\n')[0])
    ap.add_argument('--links', type=int, nargs='*', default=[1, 10, 100, 1000])
    ap.add_argument('--no-kuka', action='store_true', help='skip the KUKA iiwa rows')
    args = ap.parse_args(argv)
    scenes = list(args.links) + ([] if args.no_kuka else [0])
    label = {0: 'KUKA iiwa'}
    print(f'load {os.getloadavg()[0]:.2f}; µs per call')
    print('| links | ' + ' | '.join(PARTS) + ' |')
    print('|' + '---|' * (len(PARTS) + 1))
    for links in scenes:
        r = profile(links)
        r['solve'] -= r['assemble']
        print(f'| {label.get(links, links)} | ' + ' | '.join(f'{r[p]:.2f}' for p in PARTS) + ' |', flush=True)
    print(f'\noutside Newton (load {os.getloadavg()[0]:.2f}); µs per call')
    print('| links | ' + ' | '.join(OUTSIDE) + ' |')
    print('|' + '---|' * (len(OUTSIDE) + 1))
    for links in scenes:
        r = outside(world(links), max(20000 // max(links, 7), 5))
        cells = ' | '.join(f'{r[p]:.2f}' for p in OUTSIDE)
        print(f'| {label.get(links, links)} | {cells} |', flush=True)


if __name__ == '__main__':
    main()
