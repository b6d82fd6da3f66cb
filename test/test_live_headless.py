"""run_headless --live: the run paced at real time with the live view, pausable and steppable
through the live server's services, and recording the same bag as without --live."""
from __future__ import annotations

import glob
import socket
import subprocess
import sys
import time

import pytest

from conftest import REPO, ros_env
from live_client import free_port_pair, LiveClient

import foxglove  # noqa: E402,F401 - requirements-live.txt (in requirements-test.txt): no skip

SCHEDULE = REPO / 'test' / 'data' / 'default_schedule.yaml'


def _run_headless(tmp_path, *args, **kw):
    env = ros_env(0, tmp_path)
    return subprocess.Popen([sys.executable, '-m', 'abd_joint_sim.tools.run_headless', *args],
                            env=env, cwd=str(REPO), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL, **kw)


def _messages(bag) -> list:
    from mcap.reader import make_reader
    out = []
    for path in sorted(glob.glob(f'{bag}/*.mcap')):
        with open(path, 'rb') as f:
            for _schema, channel, message in make_reader(f).iter_messages():
                out.append((channel.topic, message.log_time, message.data))
    return out


@pytest.mark.slow
def test_run_headless_live_is_paced_pausable_and_records_the_same_bag(tmp_path):
    port = free_port_pair()
    proc = _run_headless(tmp_path, '--schedule', str(SCHEDULE), '--out',
                         str(tmp_path / 'live'), '--duration', '3', '--live', str(port))
    try:
        client = LiveClient(port, timeout=60)
        assert set(client.services) == {'pause', 'unpause', 'step', 'reset'}
        client.subscribe()
        status = client.next_message(10.0, '/status')[2]
        assert status['source'] == 'run_headless'
        assert client.call('pause')['success']
        client.messages_for(0.3)
        assert client.messages_for(0.8) == []            # paused: nothing published
        frozen = proc.poll()
        assert frozen is None                            # a 3 s run waits while paused
        assert client.call('step')['success']
        stepped = [m for topic, _, m in client.messages_for(0.5) if topic == '/status']
        assert len(stepped) == 1
        answer = client.call('reset')
        assert not answer['success'] and 'no reset' in answer['message']
        t0 = time.monotonic()
        assert client.call('unpause')['success']
        client.close()
        out, err = proc.communicate(timeout=60)
        wall = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert wall >= 1.5, f'{wall:.2f} s: not paced at real time'
    assert f'live view ws://127.0.0.1:{port}' in err
    # the same bag as the run without --live, message for message
    plain = _run_headless(tmp_path, '--schedule', str(SCHEDULE), '--out',
                          str(tmp_path / 'plain'), '--duration', '3')
    plain.communicate(timeout=120)
    assert plain.returncode == 0
    # (the states byte for byte; the commands by topic and time: rclpy leaves their CDR
    # padding bytes uninitialised)
    live_msgs = [m for m in _messages(tmp_path / 'live') if m[0] != '/diagnostics']
    plain_msgs = [m for m in _messages(tmp_path / 'plain') if m[0] != '/diagnostics']
    exact = ('/clock', '/joint_states', '/markers')
    assert [m for m in live_msgs if m[0] in exact] == [m for m in plain_msgs if m[0] in exact]
    assert [m[:2] for m in live_msgs] == [m[:2] for m in plain_msgs]


@pytest.mark.slow
def test_run_headless_live_bad_port(tmp_path):
    port = free_port_pair()
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', port))
        taken.listen(1)
        proc = _run_headless(tmp_path, '--schedule', str(SCHEDULE), '--out',
                             str(tmp_path / 'bag'), '--live', str(port))
        out, err = proc.communicate(timeout=120)
    assert proc.returncode == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f'live_port {port}' in lines[0] and 'in use' in lines[0], err
    assert not (tmp_path / 'bag').exists()
    for bad in ('70000', '0'):
        proc = _run_headless(tmp_path, '--schedule', str(SCHEDULE), '--out',
                             str(tmp_path / 'bag'), '--live', bad)
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 2 and '--live' in err and 'Traceback' not in err, err
