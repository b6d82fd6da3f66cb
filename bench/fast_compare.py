"""numpy vs numba backend: µs per World.step, speed-up, and agreement, per scene.

    python bench/fast_compare.py            # default, hinge, chains of 1/10/100, tree
    python bench/fast_compare.py --big      # also the 1000-link chain

Columns: wall time per step (median of --repeats timed runs) for each backend, the speed-up,
the numba time spent in `fast.step.single` alone (the compiled step; the rest of World.step
is shared Python: state copies, the joint-separation diagnostic), Newton iterations per
step, and max |Δq| between the backends after the timed steps (round-off level expected).
Both backends run the same scene from the same state; the machine's load adds noise, so
compare ratios from one invocation.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abd_joint_sim import Scene, World, fast  # noqa: E402
from abd_joint_sim.builders import chain_scene, tree_scene  # noqa: E402
from abd_joint_sim.scene import load_yaml  # noqa: E402
from abd_joint_sim.world import StepReport  # noqa: E402

SCENES = Path(__file__).resolve().parents[1] / 'abd_joint_sim' / 'scenes'


def _scene(name):
    return load_yaml((SCENES / f'{name}.yaml').read_text())


def _world(d, backend):
    w = World(Scene.from_dict(d), backend=backend)
    for j in w.actuated_joint_names:
        w.set_torque(j, 1.0 if 'hinge' not in w.joint_names else 100.0)
    return w


def _time_steps(w, steps, repeats):
    w.step(3)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        w.step(steps)
        times.append((time.perf_counter() - t) / steps)
    return statistics.median(times), min(times)


def _time_single(w, steps):
    from abd_joint_sim.fast.step import single
    r = StepReport()
    saved = w.state.copy()
    t = time.perf_counter()
    for _ in range(steps):
        single(w, w.dt, r)
    out = (time.perf_counter() - t) / steps
    w.state = saved
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--big', action='store_true', help='include the 1000-link chain')
    ap.add_argument('--repeats', type=int, default=5)
    args = ap.parse_args(argv)
    info = fast.warm_up()
    print(f'numba warm-up {info["seconds"]:.2f} s ({"loaded from cache" if info["cache_hits"] else "compiled"})')
    cases = [('default', _scene('default')), ('hinge', _scene('hinge')),
             ('chain1', chain_scene(1)), ('chain10', chain_scene(10)),
             ('chain100', chain_scene(100)), ('tree3x2', tree_scene(3, 2))]
    if args.big:
        cases.append(('chain1000', chain_scene(1000)))
    head = f'{"scene":10s} {"bodies":>6s} {"numpy us":>10s} {"numba us":>10s} {"speed-up":>8s} ' \
           f'{"single us":>9s} {"its":>4s} {"RTF numba":>9s} {"max|dq|":>9s}'
    print(head)
    print('-' * len(head))
    for name, d in cases:
        wn, wf = _world(d, 'numpy'), _world(d, 'numba')
        nb = wn.model.body_count
        budget = 0.4                                  # seconds of numpy stepping per repeat
        n_np = max(3, min(300, int(budget / (0.002 * max(1, nb ** 0.5)))))
        t_np, _ = _time_steps(wn, n_np, args.repeats)
        n_fast = max(10, int(n_np * min(50.0, max(1.0, 0.002 / max(t_np / 10, 1e-6)))))
        n_fast = min(n_fast, 20000 if nb < 20 else 2000 if nb < 200 else 100)
        t_nb, _ = _time_steps(wf, n_fast, args.repeats)
        t_single = _time_single(wf, min(n_fast, 2000)) if wf.backend == 'numba' else float('nan')
        # agreement: same number of steps on both from the start
        a, b = _world(d, 'numpy'), _world(d, 'numba')
        k = min(n_np, 100)
        a.step(k)
        b.step(k)
        dq = float(np.abs(a.state.q - b.state.q).max())
        its = b.last_step.newton_iterations
        print(f'{name:10s} {nb:6d} {t_np * 1e6:10.1f} {t_nb * 1e6:10.1f} {t_np / t_nb:8.1f} '
              f'{t_single * 1e6:9.1f} {its:4d} {wf.dt / t_nb:9.1f} {dq:9.1e}', flush=True)


if __name__ == '__main__':
    main()
