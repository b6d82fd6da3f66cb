"""Another checkout's physics core against this tree's, in one process, taking turns: Newton's
linear solve alone (compiled loops of assemble + solve minus assemble alone), and whole steps
(`World.step(n)` and one `World.step()` per call), CPU time, median of the per-round ratios.

    git worktree add /tmp/old <commit>
    python bench/inprocess_ab.py --old /tmp/old [--rounds 15] [chain1 chain10 chain100 kuka default]

Small differences (a few per cent) drown in the machine's noise between processes; in one
process, alternating rounds, they show (bench/side_by_side.py runs each checkout in its own
process instead, which also compares checkouts whose World differs). The other checkout's
package is copied and renamed `abd_old` (its own kernel cache), so both import side by side.
`same` says whether both ended on the same bits. `kuka` is the KUKA iiwa URDF of
pybullet_data with its joint damping; torque 1 N m on every joint, 3 steps first.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))

STEPS = {'chain1': 3000, 'default': 3000, 'chain10': 600, 'kuka': 600, 'chain100': 60,
         'chain1000': 6}


def import_old(checkout: Path, where: Path):
    """The checkout's abd_joint_sim copied to where/abd_old with its names changed."""
    dst = where / 'abd_old'
    shutil.copytree(checkout / 'abd_joint_sim', dst,
                    ignore=shutil.ignore_patterns('__pycache__', '*.nbi', '*.nbc'))
    for f in dst.rglob('*.py'):
        text = f.read_text()
        f.write_text(text.replace('abd_joint_sim', 'abd_old')
                     .replace('ABD_KERNEL_CACHE', 'ABD_OLD_KERNEL_CACHE'))
    os.environ.setdefault('ABD_OLD_KERNEL_CACHE', str(where / 'cache'))
    sys.path.insert(0, str(where))
    import abd_old
    return abd_old


def world(mod, name):
    from abd_joint_sim.builders import chain_scene
    if name.startswith('chain'):
        w = mod.World(mod.Scene.from_dict(chain_scene(int(name[5:]))))
    elif name == 'kuka':
        import pybullet_data
        w = mod.World(mod.Scene.from_urdf(
            os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa', 'model.urdf'), dt=1e-3))
    else:
        w = mod.World(mod.Scene.from_yaml(os.path.join(os.path.dirname(mod.__file__), 'scenes',
                                                       'default.yaml')))
    for j in w.actuated_joint_names:
        w.set_torque(j, 1.0)
    w.step(3)
    return w


def solve_loop(mod):
    """A compiled loop of Newton's assembly (and solve) of `mod`."""
    from numba import njit
    newton = sys.modules[mod.__name__ + '.solver.newton']
    linsolve = sys.modules[mod.__name__ + '.solver.linsolve']
    subnormals = (sys.modules.get(mod.__name__ + '.jit.subnormals')
                  or sys.modules[mod.__name__ + '.solver.subnormals'])
    assemble, solve, enter, leave = newton.assemble, linsolve.solve, subnormals.enter, subnormals.leave

    @njit
    def blocks_only(q, m, ctx, ws):         # (since stop 33 assemble returns (blocks, Π))
        return assemble(q, m, ctx, ws.grad, ws.diag, ws.pair)[0]

    @njit
    def blocks_itself(q, m, ctx, ws):       # (before it, the blocks)
        return assemble(q, m, ctx, ws.grad, ws.diag, ws.pair)

    def make_loop(blocks_of):
        @njit
        def loop(with_solve, m, ctx, q, ws, n):
            saved = enter()
            for _ in range(n):
                blocks = blocks_of(q, m, ctx, ws)
                if with_solve:
                    solve(m, ws.diag, blocks, ws.grad, ws.dq, ws)
            leave(saved)
        return loop

    chosen = []

    def run(with_solve, m, ctx, q, ws, n):
        if not chosen:
            returns_energy = isinstance(assemble(q, m, ctx, ws.grad, ws.diag, ws.pair), tuple)
            chosen.append(make_loop(blocks_only if returns_energy else blocks_itself))
        return chosen[0](with_solve, m, ctx, q, ws, n)
    return run


def solve_args(w):
    sv = w.solver
    return sv.data, sv.context(w.state, w.control, w.dt), w.state.q.copy(), sv.work


def per_step(w, start, steps, one_per_call):
    w.state = start.copy()
    t = time.process_time()
    if one_per_call:
        step = w.step
        for _ in range(steps):
            step()
    else:
        w.step(steps)
    return (time.process_time() - t) / steps * 1e6


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--old', required=True, type=Path, help='the other checkout')
    ap.add_argument('--rounds', type=int, default=15)
    ap.add_argument('scenes', nargs='*', default=['chain1', 'chain10', 'chain100', 'kuka', 'default'])
    args = ap.parse_args(argv)
    import abd_joint_sim.solver.linsolve        # noqa: F401  (solve_loop looks the modules up)
    import abd_joint_sim.solver.newton          # noqa: F401
    import abd_joint_sim as new
    with tempfile.TemporaryDirectory() as tmp:
        old = import_old(args.old.resolve(), Path(tmp))
        import abd_old.solver.linsolve          # noqa: F401
        import abd_old.solver.newton            # noqa: F401
        mods = {'old': old, 'new': new}
        loops = {k: solve_loop(mod) for k, mod in mods.items()}
        print(f'load {os.getloadavg()[0]:.2f}; µs (CPU time), old -> new (median of the ratios)')
        print('| scene | solve | World.step() per call | World.step(n) | same bits |')
        print('|---|---|---|---|---|')
        for name in args.scenes:
            ws = {k: world(mod, name) for k, mod in mods.items()}
            sa = {k: solve_args(w) for k, w in ws.items()}
            starts = {k: w.state.copy() for k, w in ws.items()}
            n_solve = max(4 * STEPS[name], 40)
            t = {(k, part): [] for k in mods for part in ('solve', 'one', 'n')}
            for _ in range(args.rounds):
                for k in mods:
                    f, a = loops[k], sa[k]
                    f(1, *a, 2)
                    f(0, *a, 2)
                    t0 = time.process_time()
                    f(1, *a, n_solve)
                    t1 = time.process_time()
                    f(0, *a, n_solve)
                    t2 = time.process_time()
                    t[k, 'solve'].append(((t1 - t0) - (t2 - t1)) / n_solve * 1e6)
                    t[k, 'one'].append(per_step(ws[k], starts[k], STEPS[name], True))
                    t[k, 'n'].append(per_step(ws[k], starts[k], STEPS[name], False))
            cells = []
            for part in ('solve', 'one', 'n'):
                o, n = np.array(t['old', part]), np.array(t['new', part])
                cells.append(f'{np.median(o):.2f} -> {np.median(n):.2f} ({np.median(n / o):.2f})')
            same = np.array_equal(ws['old'].state.q, ws['new'].state.q)
            print(f'| {name} | ' + ' | '.join(cells) + f' | {"yes" if same else "no"} |', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
