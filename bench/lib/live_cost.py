"""Cost and latency of the live view (docs/live.md "Cost"): the server's share of the step
time with nobody connected and with one client, on the KUKA iiwa (pybullet_data) or, without
it, demo_arm; sim_node's real-time factor as fast as possible on that robot with one client;
and the median latency from a publish (right after a step) to the page drawing it, in
Debian's headless chromium.

    python bench/node_load.py live [--steps 4000] [--no-browser]

In process, the loop is stepped as sim_node's real-time thread steps it (batches of at most
16 steps; here 1 step per advance, the worst case: one publish check per step).
"""
import argparse
import os
from pathlib import Path
import statistics
import subprocess
import sys
import textwrap
import time
import timeit

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test'))
from abd_joint_sim import Scene  # noqa: E402
from abd_joint_sim.live import LiveServer  # noqa: E402
from abd_joint_sim.ros.loop import SimLoop  # noqa: E402
from abd_joint_sim.ros.params import config_from_values  # noqa: E402
from live_client import free_port_pair, LiveClient  # noqa: E402

parser = argparse.ArgumentParser(prog='bench/node_load.py live', description=__doc__.splitlines()[0])
parser.add_argument('--steps', type=int, default=4000)
parser.add_argument('--no-browser', action='store_true')


def robot():
    try:
        import pybullet_data
        path = os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa', 'model.urdf')
        if os.path.isfile(path):
            return 'KUKA iiwa', path
    except ImportError:
        pass
    return 'demo_arm', str(ROOT / 'abd_joint_sim' / 'robots' / 'demo_arm.urdf')


def per_step(live=None, steps=None):
    """(wall per step, wall in publish_loop / wall in advance) over `steps` steps."""
    steps = steps or args.steps
    loop = SimLoop(scene, config)
    loop.advance(50)                        # warm
    in_step = in_live = 0.0
    clock = time.perf_counter
    for _ in range(steps):
        t0 = clock()
        loop.advance(1)
        t1 = clock()
        if live is not None:
            live.publish_loop(loop)
        in_step += t1 - t0
        in_live += clock() - t1
    return in_step / steps, in_live / in_step


def main(argv=None) -> int:
    global args, name, path, config, scene
    args = parser.parse_args(argv)
    name, path = robot()
    config = config_from_values({'scene': path})
    scene = Scene.from_file(path)
    port = free_port_pair()
    loop0 = SimLoop(scene, config)
    live = LiveServer(scene, loop0.joint_names, port, page=False).start()
    idle_loop = SimLoop(scene, config)
    idle_ns = min(timeit.repeat(lambda: live.publish_loop(idle_loop), number=100000, repeat=5)) \
        / 100000 * 1e9
    drain = subprocess.Popen([sys.executable, '-c', textwrap.dedent(f"""
        import sys; sys.path.insert(0, {str(ROOT / 'test')!r})
        from live_client import LiveClient
        c = LiveClient({port}); c.subscribe(); n = 0
        while True:
            if c.next_message(1.0) is not None: n += 1
        """)], stdin=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while not live.wanted:
        time.sleep(0.01)
    LONG = 10 * args.steps            # ~1-2 s: some 60-120 publishes per run
    one = min((per_step(live, LONG) for _ in range(3)), key=lambda r: r[0])
    wall_run = LONG * one[0] * (1 + one[1])
    published = live.published / 3
    drain.kill()
    drain.wait()
    live.close()
    print(f'live view on {name} ({len(scene.bodies)} bodies), {args.steps} steps as fast as possible '
          '(the best of 3-5 runs), one publish check per step; shared machine: noisy')
    print(f'| step | {one[0] * 1e6:.1f} us |')
    share = 100 * idle_ns * 1e-9 / one[0]
    print(f'| nobody connected: one publish check | {idle_ns:.0f} ns = {share:.2f} % '
          f'of a step (sim_node checks once per batch of up to 16 steps) |')
    print(f'| one client, all channels: time in the live server / time stepping | {100 * one[1]:.2f} % '
          f'({published:.0f} publishes in {wall_run:.2f} s, '
          f'{1e3 * one[1] * LONG * one[0] / max(published, 1):.2f} ms each) |')
    env = dict(os.environ, ROS_DOMAIN_ID=str(os.getpid() % 90 + 5), PYTHONPATH=str(ROOT))
    port = free_port_pair()
    node = subprocess.Popen([sys.executable, '-m', 'abd_joint_sim.ros.node', '--ros-args', '-p',
                             f'scene:={path}', '-p', 'real_time_factor:=0', '-p',
                             f'live_port:={port}'], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    try:
        client = LiveClient(port, timeout=60)
        client.subscribe()
        time.sleep(3.0)
        client.messages_for(0.2)
        rtfs = [m['real_time_factor'] for topic, _, m in client.messages_for(4.0)
                if topic == '/status']
        client.close()
        print(f'| sim_node as fast as possible, one client | RTF {statistics.median(rtfs):.1f} '
              f'(median of {len(rtfs)} /status) |')
    finally:
        node.send_signal(2)
        node.wait(30)
    if not args.no_browser:
        from playwright.sync_api import sync_playwright
        from test_live_browser import CHROMIUM, CHROMIUM_FLAGS, install_three
        import tempfile
        install_three()
        port = free_port_pair()
        demo = str(ROOT / 'abd_joint_sim' / 'robots' / 'demo_arm.urdf')
        node = subprocess.Popen([sys.executable, '-m', 'abd_joint_sim.ros.node', '--ros-args',
                                 '-p', f'scene:={demo}', '-p', f'live_port:={port}'], env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                stdin=subprocess.DEVNULL)
        try:
            LiveClient(port, timeout=60).close()
            with sync_playwright() as pw, tempfile.TemporaryDirectory() as profile:
                ctx = pw.chromium.launch_persistent_context(
                    profile, executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS,
                    viewport={'width': 1280, 'height': 720})
                page = ctx.pages[0] if ctx.pages else ctx.new_page()
                page.goto(f'http://127.0.0.1:{port + 1}/')
                page.wait_for_function('window.live && window.live.connected', timeout=30000)
                time.sleep(8.0)
                lat = page.evaluate('window.live.latencies')[-300:]
                ctx.close()
            print(f'| publish -> drawn in the page (demo_arm, headless chromium, software GL) | '
                  f'median {1e3 * statistics.median(lat):.1f} ms, p90 '
                  f'{1e3 * sorted(lat)[int(0.9 * len(lat))]:.1f} ms ({len(lat)} frames) |')
        finally:
            node.send_signal(2)
            node.wait(30)
    return 0
