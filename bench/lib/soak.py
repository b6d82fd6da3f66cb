"""Soak: many steps of the default scene with changing commands; memory and drift figures.

    python bench/node_load.py soak [--steps 100000] [--every 5000] [--scene default] [--tracemalloc]
    python bench/node_load.py soak --node [--steps 100000]      # the same through sim_node over DDS

Headless mode (default): a ``World`` driven through sim_node's ``CommandBuffer`` (the same
validation, clamping and step-boundary semantics). Every 50 steps a PD law towards a target
that changes every 500 steps gives new torques (some beyond the scene's effort limits, so
they are clamped), every 1000 steps joint enables toggle, and a NaN command is offered (and
rejected) now and then. Printed every ``--every`` steps: simulated time, RSS (VmRSS of this
process), Python heap blocks (``sys.getallocatedblocks``), tracemalloc current size (with
``--tracemalloc``; slower), max |angle|, max |velocity|, the largest joint separation since
the last line, Newton iterations. At the end: memory growth after the warm-up, the maximum
separation, and whether every state was finite.

Node mode: sim_node (real_time_factor 0, publish_rate 100) in a subprocess on localhost DDS;
this process sends the same kind of commands over ``joint_torque_commands`` and samples the
node's VmRSS from /proc/<pid>/status.

``soak()`` is used by test/test_robustness.py with a short run.
"""
from __future__ import annotations

import argparse
import gc
import math
import os
from pathlib import Path
import sys
import time
from typing import Optional

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))


def rss_kib(pid: Optional[int] = None) -> int:
    with open(f'/proc/{pid or "self"}/status') as f:
        for line in f:
            if line.startswith('VmRSS:'):
                return int(line.split()[1])
    return 0


class Commander:
    """Changing commands: a PD law to a target that moves every `hold` steps."""

    def __init__(self, n_joints: int, seed: int = 1, hold: int = 500):
        import numpy as np
        self.rng = np.random.default_rng(seed)
        self.n = n_joints
        self.hold = hold
        self.target = np.zeros(n_joints)

    def torques(self, step: int, angles, velocities):
        import numpy as np
        if step % self.hold == 0:
            self.target = self.rng.uniform(-2.0, 2.0, self.n)
        tau = 80.0 * (self.target - np.asarray(angles)) - 8.0 * np.asarray(velocities)
        return [float(x) for x in tau]


def soak(steps: int = 100_000, every: int = 5000, scene: str = 'default',
         use_tracemalloc: bool = False, warmup: Optional[int] = None,
         verbose: bool = True) -> dict:
    """Run the headless soak; return the samples and the summary."""
    import numpy as np
    from abd_joint_sim import Scene, World
    from abd_joint_sim.ros.commands import CommandBuffer
    from abd_joint_sim.ros.params import resolve_scene
    if use_tracemalloc:
        import tracemalloc
        tracemalloc.start()
    world = World(Scene.from_yaml(resolve_scene(scene)))
    actuated = list(world.actuated_joint_names)
    limits = getattr(world.model, 'torque_effort_limit', None)
    scene_limits = {} if limits is None else dict(zip(actuated, map(float, limits)))
    buf = CommandBuffer(actuated, actuated, scene_limits=scene_limits)
    commander = Commander(len(actuated))
    warmup = every if warmup is None else warmup
    samples = []
    max_sep = max_sep_window = 0.0
    max_angle = max_vel = 0.0
    finite = True
    clamps = rejections = 0
    wall0 = time.monotonic()
    head = (f'{"step":>8} {"t [s]":>8} {"RSS MiB":>8} {"blocks":>8} '
            f'{"traced KiB":>10} {"max|angle|":>10} {"max|vel|":>9} {"max sep [m]":>11} '
            f'{"newton":>6}')
    if verbose:
        print(f'soak: scene {scene}, dt {world.dt:g} s, {steps} steps, joints {actuated}',
              flush=True)
        print(head, flush=True)
    for step in range(steps + 1):
        if step % every == 0 or step == steps:
            gc.collect()
            traced = tracemalloc.get_traced_memory()[0] / 1024 if use_tracemalloc else math.nan
            sample = dict(step=step, t=world.time, rss_kib=rss_kib(),
                          blocks=sys.getallocatedblocks(), traced_kib=traced,
                          max_angle=max_angle, max_velocity=max_vel,
                          max_separation=max_sep_window,
                          newton=getattr(world.last_step, 'newton_iterations', 0)
                          if getattr(world, 'last_step', None) else 0)
            samples.append(sample)
            max_sep_window = 0.0
            if verbose:
                print(f'{step:8d} {sample["t"]:8.2f} {sample["rss_kib"] / 1024:8.1f} '
                      f'{sample["blocks"]:8d} {traced:10.1f} {max_angle:10.3f} '
                      f'{max_vel:9.3f} {sample["max_separation"]:11.3e} {sample["newton"]:6d}',
                      flush=True)
            if step == steps:
                break
        angles, vels = world.joint_angles(), world.joint_velocities()
        if step % 50 == 0:
            r, c = buf.command_array(commander.torques(step, angles, vels))
            clamps += len(c)
            rejections += len(r)
        if step % 1000 == 500:
            r = buf.command_enable(actuated[-1], (step // 1000) % 2 == 0)
            rejections += len(r)
        if step % 777 == 0:
            r, _ = buf.command_torque(actuated[0], math.nan)     # must be rejected
            rejections += len(r)
        buf.apply(world)
        report = world.step()
        sep = float(report.max_joint_separation)
        max_sep = max(max_sep, sep)
        max_sep_window = max(max_sep_window, sep)
        a, v = world.joint_angles(), world.joint_velocities()
        if not (np.isfinite(a).all() and np.isfinite(v).all()
                and np.isfinite(world.applied_torques()).all()):
            finite = False
        max_angle = max(max_angle, float(np.abs(a).max()))
        max_vel = max(max_vel, float(np.abs(v).max()))
    wall = time.monotonic() - wall0
    if use_tracemalloc:
        tracemalloc.stop()
    base = next((s for s in samples if s['step'] >= warmup), samples[0])
    last = samples[-1]
    summary = dict(
        steps=steps, wall_s=wall, sim_s=world.time, finite=finite, max_separation=max_sep,
        max_angle=max_angle, max_velocity=max_vel, clamps=clamps, rejections=rejections,
        rss_growth_kib=last['rss_kib'] - base['rss_kib'],
        blocks_growth=last['blocks'] - base['blocks'],
        traced_growth_kib=last['traced_kib'] - base['traced_kib'],
        warmup_step=base['step'])
    if verbose:
        print(f'soak: {steps} steps ({world.time:.2f} s simulated) in {wall:.1f} s wall; '
              f'all states finite: {finite}; max joint separation {max_sep:.3e} m; '
              f'max |angle| {max_angle:.3f} rad; {clamps} clamps, {rejections} rejections',
              flush=True)
        print(f'soak: memory after step {base["step"]}: RSS {summary["rss_growth_kib"]:+d} KiB, '
              f'Python blocks {summary["blocks_growth"]:+d}'
              + ('' if not use_tracemalloc
                 else f', traced {summary["traced_growth_kib"]:+.1f} KiB'), flush=True)
    return dict(samples=samples, summary=summary)


def soak_node(steps: int = 100_000, every_s: float = 10.0, scene: str = 'default') -> int:
    """sim_node as fast as possible, commanded over DDS; node RSS over time."""
    import signal
    import subprocess
    import tempfile
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    sys.path.insert(0, str(REPO / 'bench' / 'lib'))
    from flood import ros_env
    domain = (os.getpid() * 11) % 100 + 101
    work = tempfile.mkdtemp(prefix='soak_node_')
    os.makedirs(os.path.join(work, 'log'))
    log = open(os.path.join(work, 'node.log'), 'wb')
    node = subprocess.Popen([sys.executable, '-m', 'abd_joint_sim.ros.node', '--ros-args',
                             '-p', f'scene:={scene}', '-p', 'real_time_factor:=0.0'],
                            env=ros_env(domain, os.path.join(work, 'log')), cwd=str(REPO),
                            stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    probe = rclpy.create_node('soak_probe', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(probe)
    last = {}
    probe.create_subscription(JointState, '/joint_states', lambda m: last.update(m=m), 10)
    pub = probe.create_publisher(Float64MultiArray, '/joint_torque_commands', 10)
    commander = None
    print(f'soak --node: scene {scene}, {steps} steps more; node log {work}/node.log',
          flush=True)
    print(f'{"wall s":>7} {"sim t":>8} {"node RSS MiB":>12} {"max|angle|":>10}', flush=True)
    try:
        end = time.monotonic() + 60
        while 'm' not in last and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.1)
        if 'm' not in last:
            print('soak --node: no joint states within 60 s')
            return 1
        n = len(last['m'].name)
        commander = Commander(n)
        from abd_joint_sim import Scene
        from abd_joint_sim.ros.params import resolve_scene
        dt = float(Scene.from_yaml(resolve_scene(scene)).dt)
        m0 = last['m']
        t_first = m0.header.stamp.sec + m0.header.stamp.nanosec * 1e-9
        t0 = time.monotonic()
        next_print = t0
        max_angle = 0.0
        k = 0
        while True:
            ex.spin_once(timeout_sec=0.01)
            m = last['m']
            t = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
            max_angle = max(max_angle, max(abs(x) for x in m.position))
            pub.publish(Float64MultiArray(data=commander.torques(k * 50, m.position,
                                                                  m.velocity)))
            k += 1
            now = time.monotonic()
            if now >= next_print:
                print(f'{now - t0:7.1f} {t:8.2f} {rss_kib(node.pid) / 1024:12.1f} '
                      f'{max_angle:10.3f}', flush=True)
                next_print = now + every_s
            if node.poll() is not None:
                print('soak --node: the node died', flush=True)
                return 1
            if t - t_first >= steps * dt or now - t0 > 3600:
                break
        print(f'soak --node: done at t={t:.2f} s; node RSS {rss_kib(node.pid) / 1024:.1f} MiB',
              flush=True)
        return 0
    finally:
        ex.shutdown()
        probe.destroy_node()
        rclpy.try_shutdown(context=ctx)
        if node.poll() is None:
            node.send_signal(signal.SIGINT)
            try:
                node.wait(20)
            except subprocess.TimeoutExpired:
                node.kill()
        log.close()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='bench/node_load.py soak', description=__doc__.split('\n\n')[0])
    p.add_argument('--steps', type=int, default=100_000)
    p.add_argument('--every', type=int, default=5000, help='print every N steps')
    p.add_argument('--scene', default='default')
    p.add_argument('--tracemalloc', action='store_true', help='also trace Python allocations')
    p.add_argument('--node', action='store_true', help='drive sim_node over DDS instead')
    args = p.parse_args(argv)
    if args.node:
        return soak_node(args.steps, scene=args.scene)
    s = soak(args.steps, args.every, args.scene, args.tracemalloc)['summary']
    return 0 if s['finite'] else 1


if __name__ == '__main__':
    sys.exit(main())
