"""Where the µs of one `World.step()` call go (docs/speed.md, "The eighth round"): the same
steps from the same state in `World.step(n)` (one compiled call) and one `World.step()` call
each; their difference split into leaving and re-entering compiled code (the compiled step
called once from Python against the same step in a compiled loop, on one state), unboxing
the step's 23 arguments (a compiled no-op with its signature) and the rest, the Python
around (output arrays, views, the new State, the StepReport). Chains of 1 and 10 links and
the KUKA iiwa URDF, dt 1 ms, torque on every joint; fastest of 9 rounds, wall time.

    python bench/call_cost.py
"""
from __future__ import annotations

import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import robot_bench                                              # noqa: E402
from abd_joint_sim import Scene, World                          # noqa: E402
from abd_joint_sim.builders import chain_scene                  # noqa: E402
from abd_joint_sim.solver import step as kernel                 # noqa: E402


@njit
def _loop(n, m, q, v, qp, vp, w, w1, w2, ja, tv, te, da, de, dp, h, bdf2, order, may, ws, qvw, aw,
          sk, out):
    for _ in range(n):
        kernel.step(m, q, v, qp, vp, w, w1, w2, ja, tv, te, da, de, dp, h, bdf2, order, may, ws,
                    qvw, aw, sk, out)


@njit
def _noop(n, m, q, v, qp, vp, w, w1, w2, ja, tv, te, da, de, dp, h, bdf2, order, may, ws, qvw, aw,
          sk, out):
    return n


def _best(f, calls, rounds=9):
    best = float('inf')
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(calls):
            f()
        best = min(best, (time.perf_counter() - t0) / calls)
    return best * 1e6


def _run(w, start, steps, one_per_call, rounds=9):
    """µs per step over the same `steps` steps from `start`, fastest of `rounds`."""
    best = float('inf')
    for _ in range(rounds):
        w.state = start.copy()
        t0 = time.perf_counter()
        if one_per_call:
            for _ in range(steps):
                w.step()
        else:
            w.step(steps)
        best = min(best, (time.perf_counter() - t0) / steps)
    return best * 1e6


def world(name):
    if name == 'KUKA iiwa':
        w = World(Scene.from_urdf(robot_bench.robot_path(), dt=1e-3))
        for j, tau in zip(w.actuated_joint_names, robot_bench.torques(7)):
            w.set_torque(j, tau)
        return w
    return World(Scene.from_dict(chain_scene(int(name.split()[1]))))


def budget(name):
    """(µs per step in World.step(n), per World.step() call, and the difference's parts:
    return to Python, unboxing, the Python around)."""
    w = world(name)
    w.step(200)
    start = w.state.copy()
    steps = 4000 if name == 'chain 1' else 1000
    batched = _run(w, start, steps, False)
    single = _run(w, start, steps, True)
    # the parts, on one state (the compiled step called again and again from the same start)
    s, st, c = w.solver, w.state, w.control
    h = w.model.dt
    args = (s.data, st.q, st.v, st.q_prev, st.v_prev, st.warm_start, st.warm_start_prev,
            st.warm_start_prev2, st.joint_angle, c.torque_value, c.torque_enabled, c.drive_aim,
            c.drive_enabled, c.drive_passive, h, w.model.integrator == 'bdf2',
            st.extrapolation_order(h), True, s.work, np.empty(s._qvw_shape), np.empty(s._aw_shape),
            s._skipped, s._outcome)
    _loop(1, *args)
    _noop(1, *args)
    loop = _loop.overloads[_loop.signatures[0]].entry_point
    noop = _noop.overloads[_noop.signatures[0]].entry_point
    calls = 20000 if name == 'chain 1' else 4000
    unbox = _best(lambda: noop(1, *args), calls)
    in_loop = _best(lambda: loop(20, *args), calls // 20) / 20
    leave = _best(lambda: loop(1, *args), calls) - unbox - in_loop
    return batched, single, single - batched, leave, unbox, single - batched - leave - unbox


def main():
    warnings.simplefilter('ignore')
    print(f'load {os.getloadavg()[0]:.2f}; µs per World.step() call')
    print('| scene | `World.step(n)` µs/step | `World.step()` µs/call | difference | of it: leaving and '
          're-entering compiled code | unboxing 23 arguments | the Python around (arrays, State, report) |')
    print('|---|---|---|---|---|---|---|')
    for name in ('chain 1', 'chain 10', 'KUKA iiwa'):
        if name == 'KUKA iiwa' and robot_bench.robot_path() is None:
            continue
        parts = budget(name)
        print(f'| {name} | ' + ' | '.join(f'{x:.2f}' for x in parts) + ' |', flush=True)


if __name__ == '__main__':
    main()
