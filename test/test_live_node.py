"""sim_node's live view (parameter live_port): a WebSocket client against the node over its
own process (no DDS needed by the client; the node runs on the test's domain)."""
from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from conftest import NodeProcess
from live_client import free_port_pair, LiveClient

import foxglove  # noqa: E402,F401 - requirements-live.txt (in requirements-test.txt): no skip

from abd_joint_sim import Scene  # noqa: E402
from abd_joint_sim.ros.loop import SimLoop  # noqa: E402
from physics_helpers import nearest_rotation, quaternion  # noqa: E402
from abd_joint_sim.ros.params import config_from_values  # noqa: E402


def _wait_log(node: NodeProcess, text: str, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while text not in node.output():
        assert node.alive(), node.output()[-3000:]
        assert time.monotonic() < end, f'no {text!r} in:\n{node.output()[-3000:]}'
        time.sleep(0.1)


def _reference_tf(steps: int):
    """Body poses of demo_arm after `steps` steps with no command (what the node ran)."""
    config = config_from_values({'scene': 'demo_arm'})
    loop = SimLoop(Scene.from_file(config.scene), config)
    assert loop.advance(steps) == steps
    return {n: loop.world.body_pose(n) for n in loop.world.body_names}


@pytest.mark.slow
def test_node_live_view(tmp_path, domain_id):
    port = free_port_pair()
    node = NodeProcess.sim_node(tmp_path, domain_id, {'scene': 'demo_arm', 'live_port': port})
    try:
        _wait_log(node, f'live view ws://127.0.0.1:{port}')
        client = LiveClient(port)
        assert client.topics() == {'/scene', '/tf', '/joint_states', '/status'}
        assert set(client.services) == {'pause', 'unpause', 'step', 'reset'}
        client.subscribe()
        topic, t_ns, tf = client.next_message(10.0, '/tf')
        frames = {t['child_frame_id']: t for t in tf['transforms']}
        assert set(frames) == {'pedestal', 'turntable', 'upper_arm', 'forearm', 'tool_flange'}
        assert frames['tool_flange']['parent_frame_id'] == 'forearm'
        # the poses are the World's at that time: the same run (no command) stepped here
        steps = round(t_ns / 1e6)                              # dt = 1 ms
        for name, (p, A) in _reference_tf(steps).items():
            t = frames[name]
            assert np.max(np.abs(np.array([t['translation'][k] for k in 'xyz']) - p)) <= 1e-9
            q = np.array([t['rotation'][k] for k in 'xyzw'])
            assert np.max(np.abs(q - quaternion(nearest_rotation(A)))) <= 1e-9
        assert client.next_message(5.0, '/scene') is not None

        # paused: nothing is published; a step publishes that step, once
        answer = client.call('pause')
        assert answer['success'], answer
        client.messages_for(0.3)                 # what was on the wire already
        assert client.messages_for(1.0) == []
        answer = client.call('step')
        assert answer['success'], answer
        after = client.messages_for(0.5)
        stamps = {log_time for topic, log_time, _ in after if topic == '/tf'}
        assert len(stamps) == 1, after
        assert client.messages_for(0.5) == []
        assert client.call('reset')['success']
        reset = [m for topic, _, m in client.messages_for(0.5) if topic == '/status']
        assert reset and reset[-1]['sim_time'] == 0.0
        assert client.call('unpause')['success']
        status = client.next_message(5.0, '/status')[2]
        assert not status['paused']
        client.close()

        # 200 clients that connect and drop: the node goes on stepping, at real time
        for i in range(200):
            with socket.create_connection(('127.0.0.1', port), timeout=5) as raw:
                if i % 2:
                    raw.sendall(b'GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n'
                                b'Connection: Upgrade\r\nSec-WebSocket-Key: '
                                b'dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n'
                                b'Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n')
        for _ in range(5):
            LiveClient(port).close()
        client = LiveClient(port)
        client.subscribe('/status')
        first = client.next_message(10.0, '/status')[2]
        time.sleep(2.0)
        client.messages_for(0.2)
        last = client.next_message(10.0, '/status')[2]
        rate = (last['sim_time'] - first['sim_time']) / 2.2
        assert rate > 0.5, (first, last)        # real time on a shared machine: not stalled
        client.close()
        assert node.alive()
    finally:
        code = node.stop()
    assert code == 0, node.output()[-3000:]
    out = node.output()
    assert 'Traceback' not in out
    with socket.socket() as s:       # nobody listens on the port after shutdown (the closed
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)     # connections may linger)
        s.bind(('127.0.0.1', port))
        s.listen(1)


@pytest.mark.slow
def test_node_port_in_use_goes_on_without_the_live_view(tmp_path, domain_id):
    port = free_port_pair()
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', port))
        taken.listen(1)
        node = NodeProcess.sim_node(tmp_path, domain_id,
                                    {'scene': 'default', 'live_port': port})
        try:
            _wait_log(node, 'without the live view')
            time.sleep(0.5)
            assert node.alive()
        finally:
            code = node.stop()
    assert code == 0
    lines = [line for line in node.output().splitlines() if 'live_port' in line]
    assert len(lines) == 1 and f'live_port {port}' in lines[0] and 'in use' in lines[0], lines


@pytest.mark.parametrize('value', ['70000', '-1', '1.5'])
def test_node_live_port_out_of_range(tmp_path, domain_id, value):
    node = NodeProcess.sim_node(tmp_path, domain_id, {'scene': 'default',
                                                       'live_port': float(value)
                                                       if '.' in value else int(value)})
    node.proc.wait(60)
    code = node.stop()
    assert code == 1
    out = node.output()
    assert "parameter 'live_port'" in out and 'Traceback' not in out, out
