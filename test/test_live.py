"""The live view (abd_joint_sim/live, docs/live.md): a real Foxglove WebSocket server (the
foxglove-sdk package) read by a real WebSocket client (test/live_client.py), in process over
a SimLoop and in sim_node over DDS."""
from __future__ import annotations

import json
import socket
import time
import urllib.error
import urllib.request

import numpy as np
import pytest

from conftest import REPO
from live_client import free_port_pair, LiveClient

import foxglove  # noqa: E402,F401 - requirements-live.txt (in requirements-test.txt): no skip

from abd_joint_sim import Scene  # noqa: E402
from abd_joint_sim.live import check_port, LiveError, LiveServer  # noqa: E402
from abd_joint_sim.live.scene import urdf_link_frames  # noqa: E402
from abd_joint_sim.ros.loop import SimLoop  # noqa: E402
from abd_joint_sim.ros.markers import MarkerBuilder  # noqa: E402
from physics_helpers import nearest_rotation, quaternion  # noqa: E402
from abd_joint_sim.ros.params import config_from_values  # noqa: E402

DEMO_ARM = REPO / 'abd_joint_sim' / 'robots' / 'demo_arm.urdf'
TOPICS = {'/scene', '/tf', '/joint_states', '/status'}


def _loop(scene_name='demo_arm'):
    config = config_from_values({'scene': scene_name})
    scene = Scene.from_file(config.scene)
    return scene, SimLoop(scene, config)


def _body_frames(tf: dict) -> dict:
    return {t['child_frame_id']: t for t in tf['transforms']}


def _check_poses(tf: dict, world, tol: float = 1e-9) -> None:
    frames = _body_frames(tf)
    for name in world.body_names:
        p, A = world.body_pose(name)
        t = frames[name]
        assert t['parent_frame_id'] == 'world'
        got = [t['translation'][k] for k in 'xyz']
        assert np.max(np.abs(np.array(got) - p)) <= tol, name
        q = np.array([t['rotation'][k] for k in 'xyzw'])
        want = np.array(quaternion(nearest_rotation(A)))
        assert np.max(np.abs(q - want)) <= tol, name


@pytest.fixture
def served():
    scene, loop = _loop()
    port = free_port_pair()
    calls = []
    live = LiveServer(scene, loop.joint_names, port, source='test', services={
        'pause': lambda: calls.append('pause') or (True, 'paused')}).start()
    yield scene, loop, live, port, calls
    live.close()


def test_channels_messages_and_poses_in_process(served):
    scene, loop, live, port, calls = served
    client = LiveClient(port)
    try:
        assert client.topics() == TOPICS
        by_topic = {c['topic']: c for c in client.channels.values()}
        assert by_topic['/scene']['schemaName'] == 'foxglove.SceneUpdate'
        assert by_topic['/tf']['schemaName'] == 'foxglove.FrameTransforms'
        assert all(c['encoding'] == 'json' for c in client.channels.values())
        assert set(client.services) == {'pause'}
        client.subscribe()
        deadline = time.monotonic() + 5
        while not live.wanted and time.monotonic() < deadline:
            time.sleep(0.01)
        loop.advance(250)
        assert live.publish_loop(loop, force=True)
        got = {}
        while len(got) < 4:
            item = client.next_message(5.0)
            assert item is not None, f'only {sorted(got)} arrived'
            got[item[0]] = item
        t_ns = int(round(loop.world.time * 1e9))
        assert all(log_time == t_ns for _, log_time, _ in got.values())
        _check_poses(got['/tf'][2], loop.world)
        # every URDF link has a frame: bodies in the world, the merged `tool_flange` in forearm
        frames = _body_frames(got['/tf'][2])
        assert frames['tool_flange']['parent_frame_id'] == 'forearm'
        assert set(frames) == set(loop.world.body_names) | {'tool_flange'}
        ((body, link, t, R),) = urdf_link_frames(scene)
        assert (body, link) == ('forearm', 'tool_flange')
        tool = [frames['tool_flange']['translation'][k] for k in 'xyz']
        assert tool == pytest.approx(t, abs=1e-12)
        js = got['/joint_states'][2]
        assert js['name'] == loop.joint_names
        assert js['position'] == loop.world.joint_angles().tolist()       # JSON: exact
        assert js['velocity'] == loop.world.joint_velocities().tolist()
        status = got['/status'][2]
        assert status['steps'] == 250 and status['paused'] is False
        assert status['sim_time'] == loop.world.time
        # the scene: one entity per body, in its frame, the markers' parts
        entities = got['/scene'][2]['entities']
        assert [e['frame_id'] for e in entities] == list(loop.world.body_names)
        parts = MarkerBuilder(scene).parts
        assert sum(len(e['cubes']) + len(e['spheres']) + len(e['cylinders']) + len(e['models'])
                   for e in entities) == len(parts)
        client.messages_for(0.3)                # the server time follows the messages
        assert client.times and client.times[-1] == t_ns
        # a service call reaches the owner's callable and answers
        assert client.call('pause') == {'success': True, 'message': 'paused'}
        assert calls == ['pause']
    finally:
        client.close()


def test_nothing_built_without_a_subscriber(served):
    scene, loop, live, port, calls = served
    loop.advance(10)
    assert not live.publish_loop(loop, force=True)
    client = LiveClient(port)           # connected but subscribed to nothing
    try:
        loop.advance(10)
        assert not live.publish_loop(loop, force=True)
        assert live.published == 0
    finally:
        client.close()


def test_rate_limit_holds_publishes_within_the_period(served):
    scene, loop, live, port, calls = served
    client = LiveClient(port)
    try:
        client.subscribe('/tf')
        deadline = time.monotonic() + 5
        while not live.wanted and time.monotonic() < deadline:
            time.sleep(0.01)
        sent = sum(live.publish_loop(loop) for _ in range(50) if loop.advance(1))
        assert 1 <= sent <= 3           # 50 quick steps: one publish per 1/60 s of wall
    finally:
        client.close()


def test_port_in_use_and_out_of_range(served):
    scene, loop, live, port, calls = served
    with pytest.raises(LiveError, match=f'live_port {port}: cannot listen on 127.0.0.1:{port}'):
        LiveServer(scene, loop.joint_names, port).start()
    for bad in (0, -1, 65536, 1.5, True, 'x'):
        with pytest.raises(ValueError, match='live_port'):
            check_port(bad)


def test_garbage_from_a_client_is_answered_and_the_server_goes_on(served):
    scene, loop, live, port, calls = served
    bad = LiveClient(port)
    bad.ws.send('this is not json {')
    bad.ws.send(b'\xff\x00\x01garbage')
    bad.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [{'id': 1, 'channelId': 999}]}))
    bad.messages_for(0.5)
    assert bad.statuses, 'the server should answer garbage with a status message'
    bad.close()
    with socket.create_connection(('127.0.0.1', port), timeout=5) as raw:
        raw.sendall(b'\x00\x01\x02 not http at all\r\n\r\n')
        raw.recv(100)
    good = LiveClient(port)
    try:
        good.subscribe('/status')
        deadline = time.monotonic() + 5
        while not live.wanted and time.monotonic() < deadline:
            time.sleep(0.01)
        loop.advance(5)
        assert live.publish_loop(loop, force=True)
        assert good.next_message(5.0, '/status') is not None
    finally:
        good.close()


def test_page_and_its_files(served):
    scene, loop, live, port, calls = served
    base = f'http://127.0.0.1:{port + 1}'
    page = urllib.request.urlopen(base + '/', timeout=5).read().decode()
    assert 'abd_joint_sim' in page
    config = json.loads(urllib.request.urlopen(base + '/config.json', timeout=5).read())
    assert config['ws_port'] == port
    for path in ('/three/../server.py', '/three/../../live/server.py', '/nothing'):
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(base + path, timeout=5)
        assert err.value.code == 404


def test_page_says_how_to_install_three_when_missing(monkeypatch, served):
    scene, loop, live, port, calls = served
    from abd_joint_sim.live import server
    monkeypatch.setattr(server, 'THREE_DIR', str(REPO / 'no_such_dir'))
    page = urllib.request.urlopen(f'http://127.0.0.1:{port + 1}/', timeout=5).read().decode()
    assert 'npm ci' in page and 'three.js' in page


def test_non_loopback_host_warns():
    scene, loop = _loop()
    logged = []
    live = LiveServer(scene, loop.joint_names, free_port_pair(), host='0.0.0.0', page=False,
                      log=lambda level, text: logged.append((level, text)))
    try:
        live.start()
        assert logged and logged[0][0] == 'warn' and 'anyone who can reach' in logged[0][1]
    finally:
        live.close()
