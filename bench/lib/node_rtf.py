"""sim_node's cost per step and its real-time factor: the default scene, the packaged
demo_arm URDF and (with pybullet_data) the KUKA iiwa URDF, dt 1 ms.

Three tables: the node's batched `_advance` against `World.step(n, trajectory)` in one
process (what the node adds per step, with and without recording); sim_node end to end in its
own process over DDS (loopback), as fast as possible, with the real-time factor it reports on
/diagnostics (no subscriber, a subscriber on /clock and /joint_states, recording); and its
share of a core in real time (real_time_factor 1). `--other PATH` times another checkout's
node beside this tree's, alternating.
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
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
# ABD_BENCH_TREE: the checkout whose abd_joint_sim the child process of `_node_overhead_process` times
sys.path.insert(0, os.environ.get('ABD_BENCH_TREE') or str(Path(__file__).resolve().parents[2]))

import robot_bench                                          # noqa: E402


def node_scenes(kuka_path=None):
    """(label, scene parameter) of the scenes the node is timed on: the default scene, the
    packaged demo_arm URDF and, with pybullet_data, the KUKA iiwa URDF (7 joints)."""
    robots = Path(__file__).resolve().parents[2] / 'abd_joint_sim' / 'robots'
    out = [('default scene', 'default'), ('demo_arm URDF', str(robots / 'demo_arm.urdf'))]
    if kuka_path:
        out.append(('KUKA iiwa URDF', str(kuka_path)))
    return out


def node_overhead(steps, scene='default', rounds=7, start_steps=1000):
    """What sim_node adds per step on top of World's step, in one process: the node's
    `_advance` as fast as possible (the loop's batches of up to AFAP_BATCH_STEPS steps between
    the boundaries that need one; /clock every step, /joint_states at the default 100 Hz, the
    markers at 30 Hz when recording), without and with recording, against
    `World.step(n, trajectory)` (the compiled batch: the RTF ceiling) on the same trajectory: every
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
    batch = node_module.AFAP_BATCH_STEPS
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

        from abd_joint_sim.world import Trajectory     # a batch fills a caller-owned Trajectory
        rows = Trajectory()

        def clean_batch(n):
            node.world.step(n, rows)
            return rows.count

        def run(key):
            node.recorder = recorder if key == 'node_recording' else None
            node.world.state = start
            node.loop.publish_schedule.restart()
            node.loop.marker_schedule.restart()
            gc.disable()
            t0, k = time.process_time(), 0
            while k < steps:
                k += clean_batch(batch) if key == 'world' else node._advance(batch)
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
                   str(Path(tree).resolve()) if tree else str(Path(__file__).resolve().parents[2]),
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


def node_section(quick, kuka_path=None, other=None):
    """sim_node on each of `node_scenes`: the per-step overhead in one process against the
    World's own batch (`node_overhead`; with `other`, that checkout's too, alternating),
    then end to end in its own process over DDS with no
    subscriber, with a subscriber on /clock and /joint_states, and recording (no subscriber);
    the load average before each."""
    import tempfile
    scenes = node_scenes(kuka_path)
    steps = 1000 if quick else 4000
    print(f'\nsim_node per step in one process, {steps} steps from t = 1 s (CPU time, min of 7 '
          "rounds; the node's `_advance` as fast as possible against the compiled batch "
          "`World.step(n, trajectory)`, the "
          'same trajectory; each tree in its own process' + (f', this tree and {other} '
                                                             'alternating' if other else '')
          + '):')
    head = ['scene', 'World.step batch µs/step (RTF ceiling at dt 1 ms)', 'node µs/step',
            'node overhead', 'recording µs/step', 'recording overhead']
    if other:
        head += ['other: World.step batch', 'other: node', 'other: overhead', 'other: recording',
                 'other: recording overhead']
    print('| ' + ' | '.join(head + ['load']) + ' |')
    print('|' + '---|' * (len(head) + 1))
    for label, scene in scenes:
        load = os.getloadavg()[0]
        trees = [None] + ([other] if other else [])
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
            for tree in [None] + ([other] if other else []):
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
                name = label if tree is None else f'{label}, other tree'
                print(f'| {name} | ' + ' | '.join(cells) + f' | {load:.2f} |', flush=True)
    print('\nsim_node in real time (real_time_factor 1, no subscriber): its process\'s CPU, '
          f'share of one core over {seconds} s (each tick of `time_step` is a round of '
          "rclpy's executor):")
    print('| scene | CPU, % of a core' + (' | other tree' if other else '') + ' | load |')
    print('|---|---|' + ('---|' if other else '') + '---|')
    for label, scene in scenes:
        load = os.getloadavg()[0]
        cells = []
        for tree in [None] + ([other] if other else []):
            share = node_cpu_real_time(scene, seconds, tree)
            cells.append('–' if share is None else f'{100 * share:.0f}')
        print(f'| {label} | ' + ' | '.join(cells) + f' | {load:.2f} |', flush=True)



def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bench/node_load.py rtf', description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='1000 steps and 4 s per run instead of 4000 and 8')
    ap.add_argument('--other', metavar='PATH',
                    help="also time another checkout's node, alternating with this tree's")
    ap.add_argument('--node-overhead', metavar='SCENE', help=argparse.SUPPRESS)
    ap.add_argument('--steps', type=int, default=4000, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.node_overhead:                    # the child process of _node_overhead_process
        import json
        res = node_overhead(args.steps, args.node_overhead)
        print(json.dumps(res))
        return 0 if res else 1
    if args.other and not (Path(args.other) / 'abd_joint_sim' / '__init__.py').is_file():
        print(f'node_load rtf: --other {args.other}: no abd_joint_sim package there', file=sys.stderr)
        return 2
    print(f'machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, '
          f'Python {platform.python_version()}, load {os.getloadavg()[0]:.2f}')
    node_section(args.quick, robot_bench.robot_path(), args.other)
    return 0


if __name__ == '__main__':                   # the child process of _node_overhead_process
    sys.exit(main())
