"""Where the µs of one `World.step()` call go: the same
steps from the same state in `World.step(n)` (one compiled call), one `World.step()` call
each (the state kept in the solver's ring, solver/resident.py) and one `Solver.step` call
each on immutable States; World.step()'s excess over
step(n) split into leaving and re-entering compiled code (the compiled `step_resident`
called once from Python against the same call in a compiled loop), unboxing its
argument (a compiled no-op with its signature) and the rest, the Python around (the
binding check, the outcome row, the StepReport). Chains of 1 and 10 links and
the KUKA iiwa URDF, dt 1 ms, torque on every joint; fastest of 9 rounds, wall time.

    python bench/profiler.py calls
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
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import robot_bench                                              # noqa: E402
from abd_joint_sim import Scene, World                          # noqa: E402
from abd_joint_sim.builders import chain_scene                  # noqa: E402
from abd_joint_sim.solver import step as kernel                 # noqa: E402


@njit
def _loop(n, io):
    for _ in range(n):
        kernel.step_resident(io)


@njit
def _noop(n, io):
    return n


def _best(f, calls, rounds=9):
    best = float('inf')
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(calls):
            f()
        best = min(best, (time.perf_counter() - t0) / calls)
    return best * 1e6


def _run(w, start, steps, how, rounds=9):
    """µs per step over the same `steps` steps from `start`, fastest of `rounds`: `how` is
    'n' (World.step(n)), '1' (World.step()) or 'state' (Solver.step on States)."""
    best = float('inf')
    for _ in range(rounds):
        w.state = start.copy()
        t0 = time.perf_counter()
        if how == 'n':
            w.step(steps)
        elif how == '1':
            for _ in range(steps):
                w.step()
        else:
            s, solver, c = w.state, w.solver, w.control
            for _ in range(steps):
                s, _ = solver.step(s, c)
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
    """µs: World.step(n) per step, World.step() per call, Solver.step on States per call,
    and World.step()'s excess over step(n) in parts: leaving and re-entering compiled code,
    unboxing, the Python around."""
    w = world(name)
    w.step(200)
    start = w.state.copy()
    steps = 4000 if name == 'chain 1' else 1000
    best = {'n': float('inf'), '1': float('inf'), 'state': float('inf')}
    for _ in range(7):                  # the three alternating, so that a burst of load hits all
        for how in best:
            best[how] = min(best[how], _run(w, start, steps, how, rounds=1))
    batched, single, on_states = best['n'], best['1'], best['state']
    # the parts, on one state (the compiled step called again and again on the same slots)
    w.state = start.copy()
    w.step()
    s, r, c = w.solver, w._resident, w.control
    assert r.io_key[1] is c.torque_value                 # (bound by the step above)
    args = (r.io,)
    _loop(1, *args)
    _noop(1, *args)
    loop = _loop.overloads[_loop.signatures[0]].entry_point
    noop = _noop.overloads[_noop.signatures[0]].entry_point
    calls = 20000 if name == 'chain 1' else 4000
    unbox = _best(lambda: noop(1, *args), calls)
    in_loop = _best(lambda: loop(20, *args), calls // 20) / 20
    leave = _best(lambda: loop(1, *args), calls) - unbox - in_loop
    return (batched, single, on_states, single - batched, leave, unbox,
            single - batched - leave - unbox)


def main(argv=None) -> int:
    import argparse
    argparse.ArgumentParser(prog='bench/profiler.py calls',
                            description=__doc__.split('\n\n')[0]).parse_args(argv)
    warnings.simplefilter('ignore')
    print(f'load {os.getloadavg()[0]:.2f}; µs per World.step() call')
    print('| scene | `World.step(n)` µs/step | `World.step()` µs/call | `Solver.step` on States µs/call '
          '| World.step() − step(n) | of it: leaving and re-entering compiled code | unboxing the '
          'argument | the Python around (binding check, report) |')
    print('|---|---|---|---|---|---|---|---|')
    for name in ('chain 1', 'chain 10', 'KUKA iiwa'):
        if name == 'KUKA iiwa' and robot_bench.robot_path() is None:
            continue
        parts = budget(name)
        print(f'| {name} | ' + ' | '.join(f'{x:.2f}' for x in parts) + ' |', flush=True)
    return 0
