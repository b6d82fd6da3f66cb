"""What each compiler device pays: µs per step with it and without it, side by side.

    python bench/profiler.py devices [--rounds 15] [chain1 chain100 chain1000 kuka]

Each device switched off by a compile switch (cache.SWITCHES: ABD_REFCOUNTS=0, ABD_FLAT=0,
ABD_SLP=0, ABD_FLUSH_SUBNORMALS=0) runs in a worker process of its own, with its own kernel
cache (`<cache>/variants/NAME=0`, compiled on its first run), beside a worker with every
device in. The ring behind `World.step()` (solver/resident.py) is measured in the default
worker: one `World.step()` per call against one `Solver.step` per call on States. The
workers take turns, round after round (after one untimed round; the order of the turns
rotates), each timing the same steps from the same state (its
own: the state after 10 steps of the scene), CPU time; a cell is the default build's µs per
step -> the build without the device (median of the rounds), and the median of the per-round
ratios without/with: above 1, the device pays. `World.step(n)` takes n steps in one call,
"one per call" n calls of `World.step()`. "same bits": whether the build without the device
ends on the default build's bits (subnormals flushed to zero change bits where there are
subnormals, and only there). Scenes: chains of 1, 100 and 1000 links (0.2 m, dt 1 ms, 1 N m
on every joint; at 1000 links the far links' entries fall into the subnormal range) and the
KUKA iiwa URDF of pybullet_data (1 N m on every joint: it swings into its limits).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

#: steps timed per round and scene
STEPS = {'chain1': 3000, 'chain100': 60, 'chain1000': 6, 'kuka': 600}
#: device -> the switch that compiles it out ('' for the ring: no switch, another call path)
DEVICES = {'refcounts': 'ABD_REFCOUNTS', 'flat': 'ABD_FLAT', 'slp': 'ABD_SLP',
           'subnormals': 'ABD_FLUSH_SUBNORMALS', 'resident': ''}
#: steps taken before timing (the state every round starts from)
SETTLE = 10


# -- the worker: one build, its scenes, timed on request ------------------------------------

def _world(name: str):
    import warnings
    warnings.simplefilter('ignore')         # (the KUKA URDF's unenforced velocity limits)
    sys.path.insert(0, str(REPO))
    from abd_joint_sim import Scene, World
    from abd_joint_sim.builders import chain_scene
    if name == 'kuka':
        import pybullet_data
        w = World(Scene.from_urdf(os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa',
                                               'model.urdf'), dt=1e-3))
    else:
        w = World(Scene.from_dict(chain_scene(int(name[5:]))))
    for j in w.actuated_joint_names:
        w.set_torque(j, 1.0)
    w.step(SETTLE)
    return w


def _time(w, start, steps: int, how: str):
    """µs of CPU time per step over `steps` steps from `start`, and the end state's q."""
    w.state = start
    t = time.process_time()
    if how == 'n':
        w.step(steps)
    elif how == 'one':
        step = w.step
        for _ in range(steps):
            step()
    else:                                   # 'state': Solver.step on States, no ring
        s, solver, control = start, w.solver, w.control
        for _ in range(steps):
            s, _ = solver.step(s, control)
        w.state = s
    return (time.process_time() - t) / steps * 1e6, w.state.q


def worker() -> int:
    """Answers lines 'scene how steps' on stdin with one JSON line: µs per step, a hash of
    the end state, the subnormal entries of the start state."""
    import numpy as np
    worlds = {}
    for line in sys.stdin:
        name, how, steps = line.split()
        if name not in worlds:
            w = _world(name)
            worlds[name] = w, w.state
        w, start = worlds[name]
        us, q = _time(w, start, int(steps), how)
        a = np.abs(start.q)
        tiny = int(((a > 0) & (a < np.finfo(float).tiny)).sum())
        print(json.dumps([us, hashlib.sha256(q.tobytes()).hexdigest()[:16], tiny]), flush=True)
    return 0


# -- the parent: workers side by side ---------------------------------------------------------

class Worker:
    def __init__(self, switch: str, cache: Path):
        env = dict(os.environ)
        if switch:
            env[switch] = '0'
            env['ABD_KERNEL_CACHE'] = str(cache / 'variants' / f'{switch}=0')
            (cache / 'variants').mkdir(mode=0o700, parents=True, exist_ok=True)
        self.proc = subprocess.Popen([sys.executable, __file__, '--worker'], env=env, text=True,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE)

    def ask(self, scene: str, how: str, steps: int):
        self.proc.stdin.write(f'{scene} {how} {steps}\n')
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f'bench/profiler.py devices: a worker ended (exit '
                             f'{self.proc.wait()}); its stderr is above')
        return json.loads(line)

    def close(self):
        self.proc.stdin.close()
        self.proc.wait()


def measure(scenes, devices, rounds: int, cache: Path) -> dict:
    """{(device, scene, how): (µs with, µs without, median ratio without/with, same bits)}."""
    switches = [DEVICES[d] for d in devices if DEVICES[d]]
    workers = {s: Worker(s, cache) for s in ['', *switches]}
    try:
        t = {}
        tiny = {}
        for scene in scenes:
            jobs = [(s, how) for s in workers for how in ('n', 'one')]
            if 'resident' in devices:
                jobs.append(('', 'state'))
            for r in range(-1, rounds):           # round -1 warms up, untimed
                for s, how in jobs[r % len(jobs):] + jobs[:r % len(jobs)]:   # turns rotate
                    us, bits, tiny[s, scene] = workers[s].ask(scene, how, STEPS[scene])
                    if r >= 0:
                        t.setdefault((s, scene, how), []).append((us, bits))
    finally:
        for w in workers.values():
            w.close()
    out = {}
    for d in devices:
        s = DEVICES[d]
        for scene in scenes:
            for how, off in ((('one', ('', 'state')),) if not s else
                             (('n', (s, 'n')), ('one', (s, 'one')))):
                on, without = t['', scene, how], t[off[0], scene, off[1]]
                out[d, scene, how] = (statistics.median(u for u, _ in on),
                                      statistics.median(u for u, _ in without),
                                      statistics.median(b[0] / a[0] for a, b in zip(on, without)),
                                      on[-1][1] == without[-1][1])
    return out, tiny


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bench/profiler.py devices',
                                 description=__doc__.split('\n\n')[0],
                                 epilog=__doc__.split('\n\n', 2)[2],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--rounds', type=int, default=15, help='rounds of turns (default 15)')
    ap.add_argument('--devices', default=','.join(DEVICES),
                    help=f'comma-separated, of {", ".join(DEVICES)} (default all)')
    root = os.environ.get('ABD_KERNEL_CACHE') or os.path.join(
        os.environ.get('XDG_CACHE_HOME') or os.path.expanduser('~/.cache'), 'abd_joint_sim')
    ap.add_argument('--cache', type=Path, default=Path(root),
                    help='kernel cache root; the builds without a device live under its variants/ '
                         f'(default {root})')
    ap.add_argument('scenes', nargs='*', default=list(STEPS), help=f'any of {", ".join(STEPS)}')
    args = ap.parse_args(argv)
    prog = 'bench/profiler.py devices'
    devices = [d.strip() for d in args.devices.split(',') if d.strip()]
    bad = [s for s in args.scenes if s not in STEPS]
    if bad:
        print(f'{prog}: unknown scene(s) {", ".join(bad)}; scenes: {", ".join(STEPS)}', file=sys.stderr)
        return 2
    bad = [d for d in devices if d not in DEVICES]
    if bad or not devices:
        print(f'{prog}: unknown device(s) {", ".join(bad) or "(none given)"}; devices: '
              f'{", ".join(DEVICES)}', file=sys.stderr)
        return 2
    if args.rounds < 1:
        print(f'{prog}: --rounds must be at least 1, got {args.rounds}', file=sys.stderr)
        return 2
    load = os.getloadavg()[0]
    out, tiny = measure(args.scenes, devices, args.rounds, args.cache)
    print(f'load {load:.2f} -> {os.getloadavg()[0]:.2f}; µs per step (CPU time, median of '
          f'{args.rounds} rounds), with the device -> without it (median of the ratios without/with)')
    print('| device | scene | World.step(n) | one World.step() per call | same bits |')
    print('|---|---|---|---|---|')
    for d in devices:
        for scene in args.scenes:
            cells = []
            for how in ('n', 'one'):
                r = out.get((d, scene, how))
                cells.append('–' if r is None else f'{r[0]:.2f} -> {r[1]:.2f} ({r[2]:.2f})')
            same = out[d, scene, 'one'][3]
            print(f'| {d} | {scene} | ' + ' | '.join(cells) + f' | {"yes" if same else "no"} |')
    for (s, scene), n in sorted(tiny.items()):
        if n:
            print(f'{scene}: {n} subnormal entries in the start state of the build '
                  f'{s + "=0" if s else "default"}')
    print('resident: without it, one Solver.step per call on States (World.step(n) does not use it)')
    return 0


if __name__ == '__main__':
    sys.exit(worker() if sys.argv[1:] == ['--worker'] else main())
