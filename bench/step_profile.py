"""Where the µs of a step go: each part of the compiled step timed on its own, called in a
loop from compiled code (no Python between calls), on chains of 1/10/100/1000 links
(dt 1 ms, torque 1 N m on every joint, state after 3 steps). For docs/speed.md.

    python bench/step_profile.py [--links 1 10 100]

Columns are µs per call; `solve` is assemble + solve minus assemble (the solve factors the
assembled blocks in place); `step` is one whole compiled step (kernel `step.step`).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abd_joint_sim import Scene, World                          # noqa: E402
from abd_joint_sim.builders import chain_scene                  # noqa: E402
from abd_joint_sim.solver import linsolve, newton, step as kernel  # noqa: E402
from abd_joint_sim.solver.retraction import retract             # noqa: E402
from abd_joint_sim.terms import inertia, ortho, revolute, torque  # noqa: E402

PARTS = ('potential', 'assemble', 'ortho', 'revolute', 'inertia', 'solve', 'retract',
         'newton', 'torque', 'step')


@njit
def _run(which, m, ctx, q, ws, c_tv, c_te, skipped, n):
    acc = 0.0
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
            newton.assemble(q, m, ctx, ws.grad, ws.diag, ws.pair)
            linsolve.solve(m, ws.diag, ws.pair, ws.grad, ws.dq, ws)
        elif which == 6:
            retract(q, ws.dq, 1.0, m, ws.trial)
        elif which == 7:
            ws.q_new[:] = q
            newton.minimize(m, ctx, ws.q_new, ws)
        elif which == 8:
            ws.acc[:] = 0.0
            torque.add_acceleration(q, m, c_tv, c_te, ws.acc, skipped)
    return acc


def profile(links):
    w = World(Scene.from_dict(chain_scene(links)))
    for j in w.actuated_joint_names:
        w.set_torque(j, 1.0)
    w.step(3)
    sv, st, c = w.solver, w.state, w.control
    m, ws = sv.data, sv.work
    ctx = sv.context(st, c, w.dt)
    q = st.q.copy()
    n = max(20000 // links, 5)
    out = {}
    for i, name in enumerate(PARTS[:-1]):
        _run(i, m, ctx, q, ws, c.torque_value, c.torque_enabled, sv._skipped, 2)
        t0 = time.perf_counter()
        _run(i, m, ctx, q, ws, c.torque_value, c.torque_enabled, sv._skipped, n)
        out[name] = (time.perf_counter() - t0) / n * 1e6
    qvw, aw = np.empty((3,) + q.shape), np.empty((2, w.model.joint_count))
    args = (m, st.q, st.v, st.q_prev, st.v_prev, st.warm_start, st.joint_angle, c.torque_value,
            c.torque_enabled, c.drive_aim, c.drive_enabled, c.drive_passive, w.dt, False, True, ws,
            qvw, aw, sv._skipped, sv._outcome)
    kernel.step(*args)
    t0 = time.perf_counter()
    for _ in range(n):
        kernel.step(*args)
    out['step'] = (time.perf_counter() - t0) / n * 1e6
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--links', type=int, nargs='*', default=[1, 10, 100, 1000])
    args = ap.parse_args(argv)
    print(f'load {os.getloadavg()[0]:.2f}; µs per call')
    print('| links | ' + ' | '.join(PARTS) + ' |')
    print('|' + '---|' * (len(PARTS) + 1))
    for links in args.links:
        r = profile(links)
        r['solve'] -= r['assemble']
        print(f'| {links} | ' + ' | '.join(f'{r[p]:.2f}' for p in PARTS) + ' |', flush=True)


if __name__ == '__main__':
    main()
