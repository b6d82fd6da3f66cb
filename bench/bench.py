"""Speed benchmark (issue 6): per-step wall time, steps/s, real-time factor, Newton
iterations and peak memory for the default scene, the reference hinge, chains of
1/10/100/1000 links and a branching tree; with MuJoCo and PyBullet installed
(requirements-bench.txt) the same chains run in them in the same invocation and the table
gives the ratio (noise on a shared machine mostly cancels). The engines' joint angles are
compared on a 3-link chain before anything is timed; a mismatch exits 1. A real robot
description (the KUKA iiwa URDF of pybullet_data) is timed in all three engines loading the
same file, and in sim_node (bench/robot_bench.py), then more robots of pybullet_data against MuJoCo.

    python bench/bench.py [--quick] [--no-peers] [--no-node | --node-only] [--node-old DIR] [--readme]

`--readme` runs the comparisons with the peers twice and ends with the README's speed
tables ("Results"): run 1's µs per step and both runs' ratios, so the table in the README
is this output pasted, not figures gathered by hand.

The node figures (default scene, demo_arm URDF, KUKA iiwa URDF) come two ways: the node's
batched `_advance` against `World.step_clean` in one process (the node's per-step overhead,
with and without recording), and sim_node end to end in its own process over DDS, as users
run it, with the real-time factor it reports on /diagnostics: no subscriber, a subscriber,
recording.
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
# ABD_BENCH_TREE: time another checkout's abd_joint_sim with this bench (`--node-old`).
sys.path.insert(0, os.environ.get('ABD_BENCH_TREE') or str(Path(__file__).resolve().parents[1]))

from abd_joint_sim import Scene, World                      # noqa: E402
from abd_joint_sim.builders import chain_scene, tree_scene  # noqa: E402
from peers import make_mujoco, make_pybullet                # noqa: E402
import robot_bench                                          # noqa: E402

SCENES = Path(__file__).resolve().parents[1] / 'abd_joint_sim' / 'scenes'


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


def node_scenes(kuka_path=None):
    """(label, scene parameter) of the scenes the node is timed on: the default scene, the
    packaged demo_arm URDF and, with pybullet_data, the KUKA iiwa URDF (7 joints)."""
    robots = Path(__file__).resolve().parents[1] / 'abd_joint_sim' / 'robots'
    out = [('default scene', 'default'), ('demo_arm URDF', str(robots / 'demo_arm.urdf'))]
    if kuka_path:
        out.append(('KUKA iiwa URDF', str(kuka_path)))
    return out


def node_overhead(steps, scene='default', rounds=7, start_steps=1000):
    """What sim_node adds per step on top of World's step, in one process: the node's
    `_advance` as fast as possible (the loop's batches of up to AFAP_BATCH_STEPS steps between
    the boundaries that need one; /clock every step, /joint_states at the default 100 Hz, the
    markers at 30 Hz when recording), without and with recording, against
    `World.step_clean` (the compiled batch: the RTF ceiling) on the same trajectory: every
    round starts from the state after `start_steps` steps (nothing commanded: the arms have
    fallen into their joint limits and stay there, as in the end-to-end runs). No subscriber,
    no spinning. CPU time of this process (DDS threads included), rounds interleaved, minimum
    of each kept. Returns µs/step {'world', 'node', 'node_recording'}."""
    import shutil
    import tempfile
    try:
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        os.environ.setdefault('ROS_DOMAIN_ID', str(90 + os.getpid() % 9))
        import rclpy
        from rclpy.parameter import Parameter
        from abd_joint_sim.ros.node import SimNode
    except Exception as exc:  # noqa: BLE001 - optional section
        print(f'node overhead: skipped ({exc})')
        return None
    from abd_joint_sim.ros import node as node_module
    # (an older tree stepped as fast as possible in BATCH_STEPS)
    batch = getattr(node_module, 'AFAP_BATCH_STEPS', node_module.BATCH_STEPS)
    tmp = tempfile.mkdtemp(prefix='bench_node_')
    rclpy.init()
    try:
        params = [Parameter('real_time_factor', value=0.0), Parameter('start_paused', value=True),
                  Parameter('record', value=str(Path(tmp) / 'bag')),
                  Parameter('scene', value=scene)]
        node = SimNode(parameter_overrides=params)
        node.paused = False           # the loop steps only unpaused; nothing spins
        recorder = node.recorder      # taken away for the rounds without recording
        if recorder is None:          # (e.g. without scripts/env.sh: no AMENT_PREFIX_PATH)
            print(f'node overhead ({scene}): recording is off ({node.recording_error}); '
                  'its rounds are not timed', file=sys.stderr)

        node.recorder = None
        while node.steps < start_steps:       # past the start (the arms in their limits)
            node._advance(batch)
        start = node.world.state              # (a World's state is never written in place)

        def run(key):
            node.recorder = recorder if key == 'node_recording' else None
            node.world.state = start
            node.loop.publish_schedule.restart()
            node.loop.marker_schedule.restart()
            gc.disable()
            t0, k = time.process_time(), 0
            while k < steps:
                k += (node.world.step_clean(batch)[0] if key == 'world'
                      else node._advance(batch))
            t = (time.process_time() - t0) / k
            gc.enable()
            return t
        keys = ('world', 'node') + (('node_recording',) if recorder is not None else ())
        for key in keys:
            run(key)                                  # warm-up
        best = {key: math.inf for key in keys}
        for _ in range(rounds):
            for key in keys:
                best[key] = min(best[key], run(key))
        node.recorder = recorder
        node.close()
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
        shutil.rmtree(tmp, ignore_errors=True)
    out = {k: v * 1e6 for k, v in best.items()}
    out.setdefault('node_recording', None)
    return out


def node_end_to_end(seconds, record_dir=None, subscribe=True, extra_args=(), tree=None):
    """sim_node as users run it: its own process, real DDS (loopback only), as fast as
    possible (real_time_factor 0), /clock every step, /joint_states at the default 100 Hz,
    optionally recording, and with `subscribe` a subscriber on both in this process (which
    then shares the 2 cores with the node). Returns the real-time factors the node reports
    on /diagnostics (steps x dt / wall, once a second) after the first report (start-up),
    and the messages the probe received. `tree`: run another checkout's node."""
    try:
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
    except Exception as exc:  # noqa: BLE001 - optional section
        print(f'node end to end: skipped ({exc})')
        return None
    args = ['-p', f'record:={record_dir}'] if record_dir else []
    # (rcl cannot parse an empty `record:=`; the default is off)
    proc, env = _start_node(0.0, args + list(extra_args), tree)
    old_domain = os.environ.get('ROS_DOMAIN_ID')
    os.environ['ROS_DOMAIN_ID'] = env['ROS_DOMAIN_ID']
    rtfs, counts, marks = [], {'clock': 0, 'states': 0}, []
    recording = set()               # what /diagnostics says: whether the node records, why not
    rclpy.init()
    try:
        node = rclpy.create_node('bench_probe')

        def on_diag(msg):
            for st in msg.status:
                kv = {k.key: k.value for k in st.values}
                if 'real_time_factor_achieved' in kv and kv.get('paused') == 'False':
                    rtfs.append(float(kv['real_time_factor_achieved']))
                    recording.add((kv.get('recording'), kv.get('recording_error', '')))
                    marks.append((float(kv['sim_time']), _cpu_seconds(proc.pid)))

        node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
        if subscribe:
            node.create_subscription(Clock, '/clock',
                                     lambda m: counts.__setitem__('clock', counts['clock'] + 1),
                                     QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
            node.create_subscription(JointState, '/joint_states',
                                     lambda m: counts.__setitem__('states', counts['states'] + 1), 10)
        deadline = time.monotonic() + seconds + 15.0
        while time.monotonic() < deadline and len(rtfs) < seconds + 1:
            rclpy.spin_once(node, timeout_sec=0.1)
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
        if old_domain is None:
            os.environ.pop('ROS_DOMAIN_ID', None)
        else:
            os.environ['ROS_DOMAIN_ID'] = old_domain
        _stop_node(proc)
    # Simulated seconds per CPU second of the node's process between the first report and the
    # last: the real-time factor the node would reach on a core of its own (None without /proc).
    cpu_rtf = None
    if len(marks) >= 2 and marks[0][1] is not None and marks[-1][1] is not None \
            and marks[-1][1] > marks[0][1]:
        cpu_rtf = (marks[-1][0] - marks[0][0]) / (marks[-1][1] - marks[0][1])
    if record_dir and recording != {('True', '')}:
        # a node that could not record (e.g. no AMENT_PREFIX_PATH without scripts/env.sh)
        # runs on without: its figures are not those of recording
        return None, sorted(recording), None
    return rtfs[1:], counts, cpu_rtf


def _start_node(real_time_factor, extra_args=(), tree=None):
    """sim_node in a process of its own (loopback DDS, a domain of its own; `tree`: another
    checkout's node) at `real_time_factor`; returns (the process, its environment)."""
    import subprocess
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_DOMAIN_ID=str(80 + os.getpid() % 9),
               PYTHONPATH=os.pathsep.join(filter(None, [
                   str(Path(tree).resolve()) if tree else str(Path(__file__).resolve().parents[1]),
                   os.environ.get('PYTHONPATH')])))
    args = [sys.executable, '-m', 'abd_joint_sim.ros.node', '--ros-args', '-p',
            f'real_time_factor:={float(real_time_factor)}'] + list(extra_args)
    # (in the tree's directory: `python -m` puts the working directory first on sys.path)
    proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            cwd=str(Path(tree).resolve()) if tree else None)
    return proc, env


def _stop_node(proc):
    """SIGINT (the node finalises its bag), then wait; kill after 20 s."""
    import signal
    import subprocess
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def node_cpu_real_time(scene, seconds, tree=None, warmup=5.0):
    """CPU share of a core that sim_node's process uses stepping `scene` at
    real_time_factor 1 (no subscriber): /proc CPU time over `seconds` after `warmup`
    seconds of start-up. None without /proc."""
    proc, _ = _start_node(1.0, ['-p', f'scene:={scene}'], tree)
    try:
        time.sleep(warmup)
        a, t0 = _cpu_seconds(proc.pid), time.monotonic()
        time.sleep(seconds)
        b, t1 = _cpu_seconds(proc.pid), time.monotonic()
    finally:
        _stop_node(proc)
    if a is None or b is None or proc.returncode not in (0, None):
        return None
    return (b - a) / (t1 - t0)


def _cpu_seconds(pid):
    """User + system CPU seconds of process `pid` so far (Linux /proc), None elsewhere."""
    try:
        with open(f'/proc/{pid}/stat') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, ValueError, IndexError):
        return None


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
    three engines (bench/robot_bench.py `run`) and more robots of pybullet_data against MuJoCo
    (`robots`); returns {'chains': rows, 'robot': figures or None, 'robots': rows, 'load'}."""
    load = os.getloadavg()[0]
    rows = chains(args)
    # URDF robot (issue 11): a real robot description in all three engines
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


def print_readme_tables(runs):
    """The README's speed tables ("Results"), from the runs of `--readme`: the µs of run 1
    and the ratios of every run, side by side."""
    loads = ', '.join(f'{r["load"]:.2f}' for r in runs)
    print(f'\n## README tables ({len(runs)} runs, loads {loads}; µs per step of run 1, '
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer steps and no 1000-link chain')
    ap.add_argument('--no-peers', action='store_true', help='skip MuJoCo and PyBullet')
    ap.add_argument('--no-node', action='store_true', help='skip the ROS node overhead')
    ap.add_argument('--node-only', action='store_true',
                    help='only the sim_node section (default scene, demo_arm, KUKA iiwa)')
    ap.add_argument('--node-old', metavar='CHECKOUT',
                    help="also time another checkout's node in one process, side by side")
    ap.add_argument('--node-overhead', metavar='SCENE', help=argparse.SUPPRESS)
    ap.add_argument('--steps', type=int, default=4000, help=argparse.SUPPRESS)
    ap.add_argument('--readme', action='store_true',
                    help='run the peer comparisons twice and print the README\'s speed tables')
    args = ap.parse_args(argv)
    if args.node_overhead:                    # the child process of _node_overhead_process
        import json
        res = node_overhead(args.steps, args.node_overhead)
        print(json.dumps(res))
        return 0 if res else 1
    if args.node_only:
        print(f'machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, '
              f'Python {platform.python_version()}, load {os.getloadavg()[0]:.2f}')
        node_section(args.quick, robot_bench.robot_path(), args.node_old)
        return 0

    print(f'machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, '
          f'Python {platform.python_version()}, numpy {np.__version__}, load {os.getloadavg()[0]:.2f}, '
          'compiled physics step')
    if not args.no_peers and not check_agreement():
        print('ERROR: engines disagree on the 3-link chain; not timing.')
        return 1

    runs = []
    for run in range(2 if args.readme else 1):
        if args.readme:
            print(f'\n## Run {run + 1} of 2 (load {os.getloadavg()[0]:.2f})')
        runs.append(run_engines(args))
    if args.readme:
        print_readme_tables(runs)
    if not args.no_node:
        node_section(args.quick, runs[0]['robot']['path'] if runs[0]['robot'] else robot_bench.robot_path(),
                     args.node_old)
    return 0


def _node_overhead_process(tree, scene, steps):
    """`node_overhead` in a process of its own (`tree`: another checkout, None: this one)."""
    import json
    import subprocess
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    if tree:
        env['ABD_BENCH_TREE'] = str(Path(tree).resolve())
    out = subprocess.run([sys.executable, __file__, '--node-overhead', scene, '--steps',
                          str(steps)], env=env, capture_output=True, text=True, timeout=900)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith('{')]
    if out.returncode or not lines:
        print(f'node overhead ({scene}, {tree or "this tree"}): failed: '
              f'{(out.stderr or out.stdout).strip().splitlines()[-1:]}')
        return None
    return json.loads(lines[-1])


def node_section(quick, kuka_path=None, old_tree=None):
    """sim_node on each of `node_scenes`: the per-step overhead in one process against the
    World's own batch (`node_overhead`; with `old_tree`, that checkout's too, alternating),
    then end to end in its own process over DDS with no
    subscriber, with a subscriber on /clock and /joint_states, and recording (no subscriber);
    the load average before each."""
    import tempfile
    scenes = node_scenes(kuka_path)
    steps = 1000 if quick else 4000
    print(f'\nsim_node per step in one process, {steps} steps from t = 1 s (CPU time, min of 7 '
          "rounds; the node's `_advance` as fast as possible against `World.step_clean`, the "
          'same trajectory; each tree in its own process' + (f', this tree and {old_tree} '
                                                             'alternating' if old_tree else '')
          + '):')
    head = ['scene', 'World.step_clean µs/step (RTF ceiling at dt 1 ms)', 'node µs/step',
            'node overhead', 'recording µs/step', 'recording overhead']
    if old_tree:
        head += ['old tree: World.step_clean', 'old: node', 'old: overhead', 'old: recording',
                 'old: recording overhead']
    print('| ' + ' | '.join(head + ['load']) + ' |')
    print('|' + '---|' * (len(head) + 1))
    for label, scene in scenes:
        load = os.getloadavg()[0]
        trees = [None] + ([old_tree] if old_tree else [])
        best = {t: None for t in trees}
        for _ in range(2):                    # alternating, the better of two processes each
            for tree in trees:
                res = _node_overhead_process(tree, scene, steps)
                if res and (best[tree] is None or res['node'] < best[tree]['node']):
                    best[tree] = res
        cells = []
        for tree in trees:
            res = best[tree]
            if res is None:
                cells += ['–'] * 5
                continue
            w, n, r = res['world'], res['node'], res['node_recording']
            cells += [f'{w:.1f}' + (f' ({1e3 / w:.0f})' if tree is None else ''), f'{n:.1f}',
                      f'{n - w:.1f}'] + (['not recorded'] * 2 if r is None else
                                         [f'{r:.1f}', f'{r - w:.1f}'])
        print(f'| {label} | ' + ' | '.join(cells) + f' | {load:.2f} |', flush=True)
    seconds = 4 if quick else 8
    print(f'\nsim_node end to end (own process, DDS on loopback, as fast as possible, dt 1 ms, '
          f'/clock every step, /joint_states at 100 Hz; the real-time factor it reports on '
          f'/diagnostics, median (min–max) of {seconds} one-second reports after the first; '
          'and simulated seconds per CPU second of the node process over the same reports, '
          'the RTF on a core of its own):')
    print('| scene | no subscriber | a subscriber on /clock and /joint_states | recording, no '
          'subscriber | load |')
    print('|---|---|---|---|---|')
    with tempfile.TemporaryDirectory() as tmp:
        for k, (label, scene) in enumerate(scenes):
            for tree in [None] + ([old_tree] if old_tree else []):
                load = os.getloadavg()[0]
                cells = []
                for mode, (rec, sub) in enumerate(((None, False), (None, True),
                                                   (str(Path(tmp) / f'bag{k}_{tree is None}'),
                                                    False))):
                    res = node_end_to_end(seconds, rec, sub, ['-p', f'scene:={scene}'], tree)
                    if res and res[0]:
                        rtfs, counts, cpu_rtf = res
                        cells.append(f'{statistics.median(rtfs):.1f} ({min(rtfs):.1f}–'
                                     f'{max(rtfs):.1f})' + (f'; per CPU s {cpu_rtf:.1f}'
                                                            if cpu_rtf else ''))
                    elif res and rec:
                        cells.append(f'not recorded ({res[1]})')
                    else:
                        cells.append('no report')
                name = label if tree is None else f'{label}, old tree'
                print(f'| {name} | ' + ' | '.join(cells) + f' | {load:.2f} |', flush=True)
    print('\nsim_node in real time (real_time_factor 1, no subscriber): its process\'s CPU, '
          f'share of one core over {seconds} s (each tick of `time_step` is a round of '
          "rclpy's executor):")
    print('| scene | CPU, % of a core' + (' | old tree' if old_tree else '') + ' | load |')
    print('|---|---|' + ('---|' if old_tree else '') + '---|')
    for label, scene in scenes:
        load = os.getloadavg()[0]
        cells = []
        for tree in [None] + ([old_tree] if old_tree else []):
            share = node_cpu_real_time(scene, seconds, tree)
            cells.append('–' if share is None else f'{100 * share:.0f}')
        print(f'| {label} | ' + ' | '.join(cells) + f' | {load:.2f} |', flush=True)


if __name__ == '__main__':
    sys.exit(main())
