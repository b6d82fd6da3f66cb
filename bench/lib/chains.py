"""Ours against MuJoCo and PyBullet on the same scenes, in one process, the engines taking
turns round after round (a burst of load on a shared machine falls on all of them): the
default scene, the reference hinge, chains of 1/10/100/1000 links and a branching tree
(µs per step, steps/s, real-time factor, Newton iterations, peak memory), then the KUKA iiwa
URDF of pybullet_data in all three engines and more robots of pybullet_data against MuJoCo
(robot_bench.py). The engines' joint angles are compared on a 3-link chain before anything
is timed; a mismatch exits 1.

`--twice` runs every comparison twice and ends with docs/speed.md's tables: run 1's µs per
step and both runs' ratios, so the tables there are this output, not figures gathered by hand.
"""
from __future__ import annotations

import argparse
import gc
import math
import os
import platform
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from abd_joint_sim import Scene, World                      # noqa: E402
from abd_joint_sim.builders import box_body, chain_scene    # noqa: E402
from engines import make_mujoco, make_pybullet              # noqa: E402
import robot_bench                                          # noqa: E402

SCENES = Path(__file__).resolve().parents[2] / 'abd_joint_sim' / 'scenes'


def tree_scene(depth: int = 3, branching: int = 2, *, dt: float = 0.001, torque: float = 0.1,
               link: float = 0.2) -> dict:
    """A fixed base with a binary (or k-ary) tree of links fanning out in the xy-plane."""
    bodies = [box_body('base', (0.0, 0.0, 0.0), (link, link, link), fixed=True)]
    joints = []
    frontier = [('base', 0.0, 0.0)]
    for level in range(1, depth + 1):
        new = []
        for parent, x, y in frontier:
            for b in range(branching):
                name = f'{parent}_{b}' if parent != 'base' else f'n{b}'
                cy = y + (b - (branching - 1) / 2) * link * 2.0 ** (depth - level)
                cx = x + link
                bodies.append(box_body(name, (cx, cy, 0.0), (0.5 * link, 0.25 * link, 0.25 * link)))
                jx, jy = cx - 0.25 * link, cy
                joints.append(dict(name=f'j_{name}', parent=parent, child=name,
                                   p0=[jx, jy, -0.5 * link], p1=[jx, jy, 0.5 * link],
                                   external_torque=dict(torque=torque, enabled=True)))
                new.append((name, cx, cy))
        frontier = new
    return dict(name=f'tree{depth}x{branching}', dt=dt, gravity=[0.0, 0.0, 0.0], bodies=bodies,
                joints=joints)


def _world(d):
    return World(Scene.from_dict(d))


def time_steps(step, steps, repeats):
    """Per-step seconds of `repeats` runs of `steps` steps each."""
    out = []
    for _ in range(repeats):
        gc.disable()
        t0 = time.perf_counter()
        for _ in range(steps):
            step()
        out.append((time.perf_counter() - t0) / steps)
        gc.enable()
    return out


def bench_ours(d):
    """A world of scene d under its torques (1 N m where none is set), three steps in; and
    the one-step call that records Newton's iterations (`its`)."""
    w = _world(d)
    for name in w.actuated_joint_names:
        w.set_torque(name, w.model.torque_value0[w.actuated_joint_names.index(name)] or 1.0)
    w.step(3)                                # warm-up (and JIT, if any)
    its = []

    def step():
        its.append(w.step().newton_iterations)
    step.its = its
    return w, step


def peak_memory(d):
    tracemalloc.start()
    w2 = _world(d)
    w2.step(3)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak


def check_agreement():
    """3-link chain, 200 steps: the three engines must agree before we time them."""
    ref = _world(chain_scene(3, torque=0.01))
    ref.step(200)
    ok = True
    for name, make in (('MuJoCo', make_mujoco), ('PyBullet', make_pybullet)):
        engine = make(3, tau=0.01)
        if engine is None:
            print(f'{name} not installed: not compared, not timed (its columns show –; '
                  'pip install -r requirements-bench.txt)')
            continue
        step, angles = engine
        for _ in range(200):
            step()
        err = float(np.max(np.abs(angles() - ref.joint_angles())))
        scale = float(np.max(np.abs(ref.joint_angles())))
        print(f'agreement with {name} on a 3-link chain after 0.2 s: max |dθ| = {err:.2e} rad '
              f'(angles up to {scale:.3g} rad)')
        ok &= err < 0.02 * scale
    return ok


def chains(args):
    """The scenes without a URDF: the default scene, the reference hinge, chains of
    1/10/100/1000 links (with the peers) and a tree; prints their tables and returns their
    rows (dicts; s/step: `med` one step per call, `batched` n per call, `mujoco`,
    `mujoco_n`, `pybullet` the peers', None where one did not run)."""
    from abd_joint_sim.scene import load_yaml
    cases = [('default scene', load_yaml((SCENES / 'default.yaml').read_text()), None),
             ('2-body hinge', load_yaml((SCENES / 'hinge.yaml').read_text()), None)]
    links = (1, 10, 100) if args.quick else (1, 10, 100, 1000)
    cases += [(f'chain {n}', chain_scene(n, torque=0.1), n) for n in links]
    cases.append(('tree 4x2 (31 links)', tree_scene(4, 2), None))

    rows = []
    per_step = {}
    for label, d, n in cases:
        big = n is not None and n >= 1000
        steps = 3 if big else (20 if (n or 0) >= 100 else (50 if args.quick else 200))
        repeats = 3 if big else 5
        w, step = bench_ours(d)
        if n is not None:                    # the chains: as many steps per round as the peers
            steps = max(steps, 2000 if n <= 10 else (200 if n <= 100 else 5))
        # name: (call, calls per round, steps per call)
        timed = {'ours': (step, steps, 1), 'ours_n': (lambda: w.step(steps), 1, steps)}
        if n is not None and not args.no_peers:
            for name, make in (('mujoco', make_mujoco), ('pybullet', make_pybullet)):
                engine = make(n, tau=0.1)
                if engine is None:
                    continue
                pstep, _ = engine
                for _ in range(3):
                    pstep()
                timed[name] = (pstep, steps, 1)
                if hasattr(pstep, 'many'):
                    timed[name + '_n'] = (lambda pstep=pstep: pstep.many(steps), 1, steps)
        # The engines take turns, round after round, so that a burst of load on this shared
        # machine falls on all of them rather than on one engine's rounds.
        times = {key: [] for key in timed}
        for _ in range(repeats):
            for key, (call, calls, per_call) in timed.items():
                times[key].append(time_steps(call, calls, 1)[0] / per_call)
        med, best = statistics.median(times['ours']), min(times['ours'])
        per_step[label] = med
        row = dict(label=label, med=med, best=best, sps=1.0 / med, rtf=w.dt / med,
                   its=float(np.mean(step.its)), mem=peak_memory(d),
                   kind='tree' if w.solver.data.solve_kind == 1 else 'dense', mujoco=None,
                   pybullet=None, batched=statistics.median(times['ours_n']), mujoco_n=None)
        for key in ('mujoco', 'pybullet', 'mujoco_n'):
            if key in times:
                row[key] = statistics.median(times[key])
        rows.append(row)
        print(f'  {label}: {med * 1e6:.0f} µs/step', flush=True)

    print()
    print('| scene | solver | µs/step median (min) | steps/s | RTF at dt | Newton it/step | peak MiB '
          '| MuJoCo µs/step | ours/MuJoCo | PyBullet µs/step | ours/PyBullet |')
    print('|' + '---|' * 11)
    for r in rows:
        def peer(key):
            if r[key] is None:
                return '–', '–'
            return f'{r[key] * 1e6:.1f}', f'{r["med"] / r[key]:.2f}'
        mj, mjr = peer('mujoco')
        pb, pbr = peer('pybullet')
        print(f'| {r["label"]} | {r["kind"]} | {r["med"] * 1e6:.0f} ({r["best"] * 1e6:.0f}) | '
              f'{r["sps"]:.0f} | {r["rtf"]:.2f} | {r["its"]:.2f} | {r["mem"] / 2 ** 20:.1f} | '
              f'{mj} | {mjr} | {pb} | {pbr} |')
    print('\nPer step, n steps per call on both sides (ours World.step(n), MuJoCo mj_step(m, d, n)):')
    print('| scene | ours µs/step in step(n) | MuJoCo µs/step in nstep | ours/MuJoCo |')
    print('|---|---|---|---|')
    for r in rows:
        if r['mujoco_n'] is not None:
            print(f'| {r["label"]} | {r["batched"] * 1e6:.1f} | {r["mujoco_n"] * 1e6:.1f} | '
                  f'{r["batched"] / r["mujoco_n"]:.2f} |')
    if 'chain 100' in per_step and 'chain 1000' in per_step:
        a, b = per_step['chain 100'], per_step['chain 1000']
        print(f'\ncost growth 100 -> 1000 links: x{b / a:.1f} (exponent {np.log10(b / a):.2f}; 1 = linear)')
    return rows


def run_engines(args):
    """One run of everything timed against the peers: `chains`, then the KUKA iiwa URDF in all
    three engines (robot_bench.py `run`) and more robots of pybullet_data against MuJoCo
    (`robots`); returns {'chains': rows, 'robot': figures or None, 'robots': rows, 'load'}."""
    load = os.getloadavg()[0]
    rows = chains(args)
    # a real robot description in all three engines
    robot = robot_bench.run(args.quick, peers=not args.no_peers)
    robots = robot_bench.robots(args.quick, peers=not args.no_peers)
    return dict(chains=rows, robot=robot, robots=robots, load=load)


def _us(x):
    return '–' if x is None else (f'{x * 1e6:,.0f}'.replace(',', ' ') if x >= 1e-4 else f'{x * 1e6:.1f}')


def _ratios(pairs):
    """'**r1**, r2' of (ours, peer) per run; '–' where a peer did not run."""
    cells = [f'{a / b:.2f}' if a is not None and b else '–' for a, b in pairs]
    return ', '.join([f'**{cells[0]}**'] + cells[1:])


def _against(same, ours, peer, with_ours=True):
    """Cells '[ours µs |] peer µs | ratios' of one scene's figures in every run (`same`, dicts;
    the µs are run 1's)."""
    cells = [_us(same[0][peer]), _ratios([(x[ours], x[peer]) for x in same])]
    return ' | '.join(([_us(same[0][ours])] if with_ours else []) + cells)


def print_twice_tables(runs):
    """docs/speed.md's tables, from the runs of `--twice`: the µs of run 1 and the ratios
    of every run, side by side."""
    loads = ', '.join(f'{r["load"]:.2f}' for r in runs)
    print(f'\n## Tables ({len(runs)} runs, loads {loads}; µs per step of run 1, '
          'ours/peer of each run)\n')
    print('| scene | ours, one step per call | MuJoCo | **ours/MuJoCo** | ours, n per call | MuJoCo, n '
          'per call | **ours/MuJoCo**, n per call | PyBullet | ours/PyBullet |')
    print('|' + '---|' * 9)
    for k, r in enumerate(runs[0]['chains']):
        if r['mujoco'] is None and r['pybullet'] is None:
            continue
        same = [run['chains'][k] for run in runs]
        print(f'| {r["label"]} | {_against(same, "med", "mujoco")} | {_against(same, "batched", "mujoco_n")} '
              f'| {_against(same, "med", "pybullet", False)} |')
    if runs[0]['robot']:
        same = [run['robot'] for run in runs]
        print(f'| KUKA iiwa URDF ¹ | {_against(same, "one", "mj_one")} | {_against(same, "n", "mj_n")} | '
              f'{_against(same, "one", "pb_one", False)} |')
        print(f'| KUKA iiwa, a Python PD controller ² | {_against(same, "pd", "mj_pd")} | – | – | – | '
              f'{_against(same, "pd", "pb_pd", False)} |')
    if runs[0]['robots']:
        print('\n| robot | bodies | Newton it/step | ours µs/step | MuJoCo µs/step | **ours/MuJoCo** |')
        print('|' + '---|' * 6)
        for k, r in enumerate(runs[0]['robots']):
            same = [run['robots'][k] for run in runs]
            print(f'| {r["name"]} | {r["bodies"]} | {r["its"]:.2f} | {r["ours"] * 1e6:.1f} | '
                  f'{r["mj_cell"]} | {_ratios([(x["ours"], x["mujoco"]) for x in same])} |')



def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bench/peers.py chains', description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer steps and no 1000-link chain')
    ap.add_argument('--no-peers', action='store_true', help='ours alone (no MuJoCo, no PyBullet)')
    ap.add_argument('--twice', action='store_true',
                    help="run every comparison twice and print docs/speed.md's tables")
    args = ap.parse_args(argv)
    print(f'machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, '
          f'Python {platform.python_version()}, numpy {np.__version__}, load {os.getloadavg()[0]:.2f}')
    if not args.no_peers and not check_agreement():
        print('ERROR: engines disagree on the 3-link chain; not timing.')
        return 1
    runs = []
    for run in range(2 if args.twice else 1):
        if args.twice:
            print(f'\n## Run {run + 1} of 2 (load {os.getloadavg()[0]:.2f})')
        runs.append(run_engines(args))
    if args.twice:
        print_twice_tables(runs)
    return 0
