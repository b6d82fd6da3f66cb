"""Where a scene's `World.step(n)` spends its time, per compiled function, sampled by Linux
`perf`.

numba's JIT code has no symbols, so `perf report` shows bare addresses. This script compiles
the kernels afresh into a temporary cache (a kernel loaded from the on-disk cache carries no
LLVM module to name its functions), writes a perf map (/tmp/perf-<pid>.map: start, size and
name of every compiled function, sizes taken as the gap to the next one), samples itself with
`perf record -p <pid>` while it steps, and prints the functions by share of the samples,
numba's mangled names shortened to module.function.

    python bench/profiler.py perf [chain1|chain10|chain100|default|kuka|panda-sliding|panda-locked|<file>.urdf] [--seconds 10] [--top 40]

A URDF is a path, or one relative to pybullet_data (a1/a1.urdf), run under
`bench/peers.py robots`' torques with the importer's options of that bench. panda-sliding and
panda-locked are the Panda of `bench/peers.py sliding`: its first finger sliding (the second,
a mimic joint, locked), or both fingers locked, under the same torques (−0.6 N on the finger).

The first minute is the compile. Needs `perf` on the PATH and perf_event_paranoid ≤ 2 (a
process may sample itself); it says so otherwise.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _world(name):
    from abd_joint_sim import Scene, World
    from abd_joint_sim.builders import chain_scene
    if name in ('panda-sliding', 'panda-locked'):
        import pybullet_data
        sys.path.insert(0, str(ROOT / 'bench' / 'lib'))
        from robot_bench import torques
        from slide_bench import FINGERS, PANDA
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')             # the importer's repairs (docs/urdf.md)
            w = World(Scene.from_urdf(os.path.join(pybullet_data.getDataPath(), PANDA), dt=1e-3,
                                      lock=FINGERS[1:] if name == 'panda-sliding' else FINGERS))
        w.set_efforts(torques(len(w.actuated_joint_names)))
        return w
    if name == 'kuka':
        import pybullet_data
        w = World(Scene.from_urdf(os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa', 'model.urdf'),
                                  dt=1e-3))
    elif name.endswith('.urdf'):
        import warnings
        import pybullet_data
        sys.path.insert(0, str(ROOT / 'bench' / 'lib'))
        from robot_bench import ROBOT_OPTIONS, torques
        path = name if os.path.exists(name) else os.path.join(pybullet_data.getDataPath(), name)
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')             # the importer's repairs (docs/urdf.md)
            w = World(Scene.from_urdf(path, dt=1e-3, **ROBOT_OPTIONS.get(name, {})))
        w.set_torques(torques(len(w.actuated_joint_names)))
        return w
    elif name == 'default':
        w = World(Scene.from_yaml(str(ROOT / 'abd_joint_sim' / 'scenes' / 'default.yaml')))
    else:
        w = World(Scene.from_dict(chain_scene(int(name[5:]))))
    for j in w.actuated_joint_names:
        w.set_torque(j, 1.0)
    return w


def _functions():
    """{address: name} of every function of every compiled overload in this process."""
    import gc
    from numba.core.registry import CPUDispatcher
    out = {}
    for obj in gc.get_objects():
        if not isinstance(obj, CPUDispatcher):
            continue
        for cres in obj.overloads.values():
            module = getattr(cres.library, '_final_module', None)
            if module is None:                  # loaded from a cache: no names to give
                continue
            for f in module.functions:
                if f.is_declaration:
                    continue
                try:
                    address = cres.library.get_pointer_to_function(f.name)
                except Exception:  # noqa: BLE001 - a name the engine does not export
                    continue
                if address:
                    out[address] = f.name
    return out


def short(name: str) -> str:
    """numba's mangled _ZN<len><part><len><part>...B<digits>v<n>B<hash>... as module.function.
    Read by the lengths, with no regular expression over the whole name: the earlier pattern
    backtracked exponentially on some names and hung the script after the compile."""
    if not name.startswith('_ZN'):
        return name[:80]
    parts, i = [], 3
    while i < len(name) and name[i].isdigit():
        j = i
        while j < len(name) and name[j].isdigit():
            j += 1
        k = int(name[i:j])
        parts.append(name[j:j + k])
        i = j + k
    return '.'.join(p for p in parts if p != 'abd_joint_sim') or name[:80]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bench/profiler.py perf', description=__doc__.split('\n\n')[0])
    ap.add_argument('scene', nargs='?', default='chain1')
    ap.add_argument('--seconds', type=float, default=10.0)
    ap.add_argument('--top', type=int, default=40)
    args = ap.parse_args(argv)
    perf = shutil.which('perf')
    if perf is None:
        print('perf is not installed: nothing to sample with (apt install linux-perf, or linux-tools)')
        return 1
    if not (args.scene in ('default', 'kuka', 'panda-sliding', 'panda-locked') or args.scene.endswith('.urdf')
            or (args.scene.startswith('chain') and args.scene[5:].isdigit())):
        print(f'perf_profile: unknown scene {args.scene!r}: chain<N>, default, kuka, panda-sliding, '
              'panda-locked or a .urdf file')
        return 2
    cache = tempfile.mkdtemp(prefix='abd_perf_cache_')
    os.environ['ABD_KERNEL_CACHE'] = cache      # before the package is imported
    sys.path.insert(0, str(ROOT))
    from abd_joint_sim.errors import SceneError
    try:
        w = _world(args.scene)
    except (SceneError, OSError) as exc:
        print(f'perf_profile: cannot load {args.scene!r}: {exc}')
        shutil.rmtree(cache, ignore_errors=True)
        return 2
    w.step(200)
    functions = _functions()
    addresses = sorted(functions)
    map_path = Path(f'/tmp/perf-{os.getpid()}.map')
    with map_path.open('w') as fh:
        for i, a in enumerate(addresses):
            size = min(addresses[i + 1] - a, 1 << 16) if i + 1 < len(addresses) else 4096
            fh.write(f'{a:x} {size:x} {short(functions[a])}\n')
    data = Path(cache) / 'perf.data'
    rec = subprocess.Popen([perf, 'record', '-q', '-F', '4999', '-p', str(os.getpid()), '-o', str(data)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    time.sleep(0.5)
    t0, steps = time.time(), 0
    while time.time() - t0 < args.seconds:
        w.step(1000)
        steps += 1000
    rec.send_signal(2)
    _, err = rec.communicate(timeout=60)
    if not data.exists():
        print(f'perf record failed: {err.decode().strip()[:300]} (perf_event_paranoid is '
              f'{Path("/proc/sys/kernel/perf_event_paranoid").read_text().strip()})')
        return 1
    report = subprocess.run([perf, 'report', '-i', str(data), '--no-children', '--sort', 'symbol',
                             '--stdio'], capture_output=True, text=True).stdout
    print(f'{args.scene}: {steps} steps in {args.seconds:g} s ({1e6 * args.seconds / steps:.2f} µs per '
          f'step, sampling included), {len(addresses)} compiled functions mapped')
    rows = [line for line in report.splitlines() if '%' in line and not line.startswith('#')]
    for line in rows[:args.top]:
        share, _, symbol = line.split(None, 2)
        print(f'{share:>8}  {symbol.split("  ")[0].strip()}')
    map_path.unlink(missing_ok=True)
    shutil.rmtree(cache, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
