"""This tree's physics core against another checkout's, in one process, taking turns: µs per
step of `World.step(n)` (n steps in one call) and of one `World.step()` per call, CPU time,
median over rounds of each side and of the per-round ratios; and whether both ended on the
same bits.

    git worktree add /tmp/other <commit>
    python bench/ab.py --other /tmp/other [--rounds 15] [chain1 chain10 chain100 chain1000 kuka default]

Differences of a few per cent drown in a shared machine's noise between processes; in one
process, alternating rounds, they show. The other checkout's package is copied and renamed
`abd_other` (with its own kernel cache: the first run compiles its kernels, ~1-2 min), so both
import side by side; only their public API is used (Scene, World). Every scene has a torque
of 1 N m on every actuated joint and takes 3 steps before timing. `kuka` is the KUKA iiwa
URDF of pybullet_data (its joint damping, gravity; the torques swing it into its limits).
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))

STEPS = {'chain1': 3000, 'default': 3000, 'chain10': 600, 'kuka': 600, 'chain100': 60,
         'chain1000': 6}
OTHER_CACHE = Path(os.environ.get('XDG_CACHE_HOME', Path.home() / '.cache')) / 'abd_joint_sim_ab'


def import_other(checkout: Path, where: Path):
    """The checkout's abd_joint_sim, copied to where/abd_other with its names changed."""
    dst = where / 'abd_other'
    shutil.copytree(checkout / 'abd_joint_sim', dst,
                    ignore=shutil.ignore_patterns('__pycache__', '*.nbi', '*.nbc'))
    for f in dst.rglob('*.py'):
        text = f.read_text()
        f.write_text(text.replace('abd_joint_sim', 'abd_other')
                     .replace('ABD_KERNEL_CACHE', 'ABD_OTHER_KERNEL_CACHE'))
    os.environ.setdefault('ABD_OTHER_KERNEL_CACHE', str(OTHER_CACHE))
    sys.path.insert(0, str(where))
    import abd_other
    return abd_other


def world(mod, name: str):
    """Scene `name` in package `mod` (this tree's builders make the chains for both)."""
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


def per_step(w, start, steps: int, one_per_call: bool) -> float:
    """µs of CPU time per step over `steps` steps from `start`."""
    w.state = start
    t = time.process_time()
    if one_per_call:
        step = w.step
        for _ in range(steps):
            step()
    else:
        w.step(steps)
    return (time.process_time() - t) / steps * 1e6


def compare(mods: dict, name: str, rounds: int, scale: float = 1.0) -> dict:
    """{'one': (this µs, other µs, median ratio), 'n': (...), 'same': bool} for scene `name`."""
    steps = max(1, int(STEPS[name] * scale))
    ws = {k: world(mod, name) for k, mod in mods.items()}
    starts = {k: w.state for k, w in ws.items()}
    t = {(k, part): [] for k in mods for part in ('one', 'n')}
    for _ in range(rounds):
        for k in mods:
            t[k, 'one'].append(per_step(ws[k], starts[k], steps, True))
            t[k, 'n'].append(per_step(ws[k], starts[k], steps, False))
    out = {}
    for part in ('one', 'n'):
        this, other = t['this', part], t['other', part]
        out[part] = (statistics.median(this), statistics.median(other),
                     statistics.median(a / b for a, b in zip(this, other)))
    out['same'] = bool((ws['this'].state.q == ws['other'].state.q).all())
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bench/ab.py', description=__doc__.split('\n\n')[0])
    ap.add_argument('--other', required=True, type=Path,
                    help='the other checkout (a directory holding abd_joint_sim/)')
    ap.add_argument('--rounds', type=int, default=15)
    ap.add_argument('--scale', type=float, default=1.0, help=argparse.SUPPRESS)
    ap.add_argument('scenes', nargs='*', default=['chain1', 'chain10', 'chain100', 'kuka', 'default'],
                    help=f'any of {", ".join(STEPS)}')
    args = ap.parse_args(argv)
    other = args.other.expanduser().resolve()
    if not (other / 'abd_joint_sim' / '__init__.py').is_file():
        print(f'bench/ab.py: --other {args.other}: no abd_joint_sim package there', file=sys.stderr)
        return 2
    unknown = [s for s in args.scenes if s not in STEPS]
    if unknown:
        print(f'bench/ab.py: unknown scene(s) {", ".join(unknown)}; scenes: {", ".join(STEPS)}',
              file=sys.stderr)
        return 2
    if args.rounds < 1:
        print(f'bench/ab.py: --rounds must be at least 1, got {args.rounds}', file=sys.stderr)
        return 2
    import abd_joint_sim as this
    with tempfile.TemporaryDirectory() as tmp:
        mods = {'this': this, 'other': import_other(other, Path(tmp))}
        print(f'this tree {HERE} against {other}; load {os.getloadavg()[0]:.2f}; µs per step '
              f'(CPU time, median of {args.rounds} rounds), other -> this (median of the ratios this/other)')
        print('| scene | World.step(n) | one World.step() per call | same bits |')
        print('|---|---|---|---|')
        for name in args.scenes:
            r = compare(mods, name, args.rounds, args.scale)
            cells = [f'{o:.2f} -> {t:.2f} ({q:.2f})' for t, o, q in (r['n'], r['one'])]
            print(f'| {name} | ' + ' | '.join(cells) + f' | {"yes" if r["same"] else "no"} |',
                  flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
