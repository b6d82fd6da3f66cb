"""Command flood against sim_node over real DDS (localhost only), with figures.

    python bench/node_load.py flood [--rate 5000] [--duration 10] [--scene hinge] [--rtf 1]

Three processes: sim_node (the scene, ``publish_rate: 0`` so every step is published), a
flooder (this script with ``--flooder``) that publishes ``std_msgs/Float64`` torques on
``/joint_torque/<joint>`` at ``--rate`` Hz for ``--duration`` s, and this process, which
watches ``/joint_states`` and the node's memory (VmRSS and CPU time from /proc/<pid>).

Torque k (k = 0, 1, 2, ...) is ``(-1)**k * (1 + k * 1e-6)`` N m: every value is distinct
and tells which command it was, and the sign alternates so the joint stays near rest. At
each step the effort in ``/joint_states`` must be exactly one of the values sent, and the
command index must never go backwards (the latest command wins, nothing older comes back).
*Lag* of a state = receipt time - the send time of the first command newer than the one it
applied (0 if none was newer): DDS latency both ways + the wait for the next step boundary.

Printed: the rate achieved, the node's real-time factor (from header stamps vs receipt
times) before, during and after the flood, RSS before/after, node CPU, lag percentiles.
Every wait is bounded; all three processes stop by themselves. ``run()`` is used by
test/test_robustness.py with a short flood.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time
from typing import Optional

REPO = Path(__file__).resolve().parents[2]
STEP = 1e-6            # N m per command index in the torque values


def torque_value(k: int) -> float:
    return (-1.0 if k % 2 else 1.0) * (1.0 + k * STEP)


def command_index(value: float) -> Optional[int]:
    """k of a torque value, None if it is not one of torque_value(k)."""
    if value == 0.0:
        return None
    k = int(round((abs(value) - 1.0) / STEP))
    return k if k >= 0 and torque_value(k) == value else -1


def ros_env(domain_id: int, log_dir: str) -> dict:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_LOG_DIR=log_dir, PYTHONUNBUFFERED='1', RCUTILS_COLORIZED_OUTPUT='0')
    env.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    env['PYTHONPATH'] = os.pathsep.join(p for p in (str(REPO), env.get('PYTHONPATH')) if p)
    return env


def proc_status(pid: int) -> dict:
    """VmRSS [kB] and CPU seconds (user + system) of `pid`."""
    out = {}
    with open(f'/proc/{pid}/status') as f:
        for line in f:
            if line.startswith(('VmRSS:', 'VmHWM:')):
                out[line.split(':')[0]] = int(line.split()[1])
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    out['cpu_s'] = (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    return out


# --------------------------------------------------------------------------- flooder ----
def flooder(domain_id: int, topic: str, rate: float, duration: float, out: str) -> int:
    """Publish torque_value(k) on `topic` at `rate` Hz for `duration` s; write send times."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    import numpy as np
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node(f'flooder_{os.getpid()}', context=context)
    pub = node.create_publisher(Float64, topic,
                                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    end = time.monotonic() + 30.0
    while pub.get_subscription_count() == 0 and time.monotonic() < end:
        time.sleep(0.05)
    if pub.get_subscription_count() == 0:
        print('flooder: no subscriber within 30 s', flush=True)
        return 1
    n_max = int(rate * duration) + 10
    sent = np.zeros(n_max)
    msg = Float64()
    t0 = time.monotonic()
    print(f'flooder: start {t0:.6f}', flush=True)
    k = 0
    t_end = t0 + duration
    while True:
        now = time.monotonic()
        if now >= t_end:
            break
        due = min(int((now - t0) * rate) + 1, n_max)
        while k < due:
            msg.data = torque_value(k)
            pub.publish(msg)
            sent[k] = time.monotonic()
            k += 1
        time.sleep(0.0002)
    wall = time.monotonic() - t0
    np.save(out, sent[:k])
    print(f'flooder: sent {k} in {wall:.3f} s = {k / wall:.0f} Hz', flush=True)
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    return 0


# -------------------------------------------------------------------------- observer ----
def _rtf(samples, t_from: float, t_to: float) -> float:
    """Simulated s per wall s from (receipt wall, stamp ns) samples received in [from, to]."""
    window = [(w, s) for w, s, _ in samples if t_from <= w <= t_to]
    if len(window) < 2 or window[-1][0] <= window[0][0]:
        return float('nan')
    return (window[-1][1] - window[0][1]) * 1e-9 / (window[-1][0] - window[0][0])


def run(rate: float = 5000.0, duration: float = 10.0, before: float = 3.0, after: float = 2.0,
        scene: str = 'hinge', joint: str = 'hinge', rtf: float = 1.0,
        domain_id: Optional[int] = None, workdir: Optional[str] = None,
        verbose: bool = True) -> dict:
    """Run the flood; return the figures (also printed when `verbose`)."""
    import numpy as np
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState

    def say(text: str) -> None:
        if verbose:
            print(text, flush=True)

    domain_id = domain_id if domain_id is not None else (os.getpid() * 7) % 100 + 101
    workdir = workdir or tempfile.mkdtemp(prefix='flood_')
    log_dir = os.path.join(workdir, 'ros_log')
    os.makedirs(log_dir, exist_ok=True)
    env = ros_env(domain_id, log_dir)
    node_log = open(os.path.join(workdir, 'node.log'), 'wb')
    node = subprocess.Popen(
        [sys.executable, '-m', 'abd_joint_sim.ros.node', '--ros-args', '-p', f'scene:={scene}',
         '-p', f'real_time_factor:={rtf!r}', '-p', 'publish_rate:=0.0'],
        env=env, cwd=str(REPO), stdout=node_log, stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    probe = rclpy.create_node(f'flood_observer_{os.getpid()}', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(probe)
    samples: list[tuple[float, int, float]] = []   # (receipt wall, stamp ns, effort)
    probe.create_subscription(
        JointState, '/joint_states',
        lambda m: samples.append((time.monotonic(),
                                  m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec,
                                  m.effort[0])), 1000)
    flood = None
    result: dict = {'rate_requested': rate, 'duration': duration, 'scene': scene,
                    'real_time_factor_requested': rtf}

    def spin_for(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.02)

    try:
        end = time.monotonic() + 60.0
        while len(samples) < 20 and time.monotonic() < end and node.poll() is None:
            executor.spin_once(timeout_sec=0.05)
        if len(samples) < 20:
            raise RuntimeError('no /joint_states from the node within 60 s')
        t_before = time.monotonic()
        spin_for(before)
        result['rss_before_kB'] = proc_status(node.pid)['VmRSS']
        cpu0 = proc_status(node.pid)['cpu_s']
        result['rtf_before'] = _rtf(samples, t_before, time.monotonic())
        sendlog = os.path.join(workdir, 'sent.npy')
        flood = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), '--flooder', '--domain',
             str(domain_id), '--topic', f'/joint_torque/{joint}', '--rate', repr(rate),
             '--duration', repr(duration), '--out', sendlog],
            env=env, cwd=str(REPO), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True, stdin=subprocess.DEVNULL)
        rss_peak = result['rss_before_kB']
        end = time.monotonic() + duration + 60.0
        last_rss = 0.0
        while flood.poll() is None and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.02)
            if time.monotonic() - last_rss > 0.5:
                last_rss = time.monotonic()
                rss_peak = max(rss_peak, proc_status(node.pid)['VmRSS'])
        if flood.poll() is None:
            flood.kill()
            raise RuntimeError('flooder did not finish in time')
        flood_out = flood.stdout.read()
        start_line = [ln for ln in flood_out.splitlines() if 'flooder: start' in ln]
        if flood.returncode != 0 or not start_line:
            raise RuntimeError(f'flooder failed: {flood_out}')
        t_flood0 = float(start_line[0].split()[-1])
        sent = np.load(sendlog)
        t_flood1 = float(sent[-1]) if len(sent) else t_flood0
        result['sent'] = int(len(sent))
        result['rate_achieved'] = len(sent) / max(t_flood1 - t_flood0, 1e-9)
        cpu1 = proc_status(node.pid)['cpu_s']
        result['node_cpu_during'] = (cpu1 - cpu0) / max(time.monotonic() - t_before - before,
                                                        1e-9)
        result['rtf_during'] = _rtf(samples, t_flood0, t_flood1)
        t_after = time.monotonic()
        spin_for(after)
        result['rtf_after'] = _rtf(samples, t_after, time.monotonic())
        status = proc_status(node.pid)
        result['rss_after_kB'] = status['VmRSS']
        result['rss_peak_kB'] = max(rss_peak, status['VmRSS'])
        result['node_alive'] = node.poll() is None
        # -- latest command wins ---------------------------------------------------------
        during = [(w, s, e) for w, s, e in samples if w >= t_flood0]
        ks = [command_index(e) for _, _, e in during]
        result['states_checked'] = len(during)
        result['foreign_values'] = sum(1 for k in ks if k == -1 or (k is not None
                                                                    and k >= len(sent)))
        seq = [k for k in ks if k is not None and k >= 0]
        result['went_backwards'] = sum(1 for a, b in zip(seq, seq[1:]) if b < a)
        lags = []
        for (w, _, _), k in zip(during, ks):
            nxt = 0 if k is None else k + 1
            if k is not None and k < 0:
                continue
            if nxt < len(sent) and sent[nxt] < w:
                lags.append(w - sent[nxt])
            else:
                lags.append(0.0)
        lags_ms = np.array(lags) * 1e3
        result['lag_ms_p50'] = float(np.percentile(lags_ms, 50)) if len(lags) else float('nan')
        result['lag_ms_p99'] = float(np.percentile(lags_ms, 99)) if len(lags) else float('nan')
        result['lag_ms_max'] = float(lags_ms.max()) if len(lags) else float('nan')
        result['distinct_commands_applied'] = len(set(seq))
    finally:
        if flood is not None and flood.poll() is None:
            flood.kill()
            flood.wait(5)
        executor.shutdown()
        probe.destroy_node()
        rclpy.try_shutdown(context=context)
        if node.poll() is None:
            node.send_signal(signal.SIGINT)
            try:
                node.wait(20)
            except subprocess.TimeoutExpired:
                node.kill()
                node.wait(5)
        node_log.close()
        result['node_exit'] = node.returncode
        result['node_log'] = os.path.join(workdir, 'node.log')
    say(report(result))
    return result


def report(r: dict) -> str:
    return '\n'.join([
        f'flood: {r["sent"]} torque commands in {r["duration"]:g} s -> '
        f'{r["rate_achieved"]:.0f} Hz achieved (requested {r["rate_requested"]:.0f} Hz), '
        f'scene {r["scene"]}, real_time_factor {r["real_time_factor_requested"]:g}',
        f'  node real-time factor: before {r["rtf_before"]:.3f}, during {r["rtf_during"]:.3f}, '
        f'after {r["rtf_after"]:.3f}; node CPU during {100 * r["node_cpu_during"]:.0f} % '
        'of one core',
        f'  node RSS: before {r["rss_before_kB"] / 1024:.1f} MiB, after '
        f'{r["rss_after_kB"] / 1024:.1f} MiB, peak {r["rss_peak_kB"] / 1024:.1f} MiB',
        f'  latest wins: {r["states_checked"]} joint states checked, '
        f'{r["distinct_commands_applied"]} distinct commands applied, '
        f'{r["went_backwards"]} went backwards, {r["foreign_values"]} efforts not a sent '
        f'value; lag p50 {r["lag_ms_p50"]:.1f} ms, p99 {r["lag_ms_p99"]:.1f} ms, max '
        f'{r["lag_ms_max"]:.1f} ms',
        f'  node alive after the flood: {r["node_alive"]}; exit status on SIGINT '
        f'{r["node_exit"]}',
    ])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='bench/node_load.py flood', description=__doc__.split('\n\n')[0])
    p.add_argument('--rate', type=float, default=5000.0, help='commands per second')
    p.add_argument('--duration', type=float, default=10.0, help='seconds of flood')
    p.add_argument('--scene', default='hinge')
    p.add_argument('--joint', default=None, help='joint to flood (default: first actuated)')
    p.add_argument('--rtf', type=float, default=1.0, help='real_time_factor of the node')
    p.add_argument('--json', help='also write the figures to this JSON file')
    p.add_argument('--flooder', action='store_true', help=argparse.SUPPRESS)
    p.add_argument('--domain', type=int, help=argparse.SUPPRESS)
    p.add_argument('--topic', help=argparse.SUPPRESS)
    p.add_argument('--out', help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.flooder:
        return flooder(args.domain, args.topic, args.rate, args.duration, args.out)
    joint = args.joint or {'hinge': 'hinge', 'default': 'shoulder'}.get(args.scene, 'hinge')
    r = run(args.rate, args.duration, scene=args.scene, joint=joint, rtf=args.rtf)
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1))
    ok = (r['node_alive'] and r['went_backwards'] == 0 and r['foreign_values'] == 0
          and r['node_exit'] == 0)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
