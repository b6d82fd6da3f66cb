"""replay_bag BAG --live PORT: a recorded run simulated again at real time into the live view,
pausable, resettable (a seek to 0), with Foxglove's playback control advertised."""
from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from conftest import REPO, ros_env
from live_client import free_port_pair, LiveClient

import foxglove  # noqa: E402,F401 - requirements-live.txt (in requirements-test.txt): no skip

SCHEDULE = REPO / 'test' / 'data' / 'default_schedule.yaml'


def _tool(tmp_path, module, *args):
    return subprocess.Popen([sys.executable, '-m', f'abd_joint_sim.tools.{module}', *args],
                            env=ros_env(0, tmp_path), cwd=str(REPO), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)


@pytest.mark.slow
def test_replay_bag_live(tmp_path):
    from abd_joint_sim.tools.bagrun import load_bag
    bag = tmp_path / 'run'
    # every step recorded, so that every state the live view sends (after some step, at a
    # wall-clock rate) has its recorded twin; long enough that the replay, at real time, is
    # still running when the client has connected on a slow start
    rec = _tool(tmp_path, 'run_headless', '--schedule', str(SCHEDULE), '--out', str(bag),
                '--duration', '10', '--publish-every', '1')
    assert rec.wait(120) == 0, rec.stderr.read()
    recorded = load_bag(str(bag)).states[0]
    port = free_port_pair()
    proc = _tool(tmp_path, 'replay_bag', str(bag), '--live', str(port))
    try:
        client = LiveClient(port, timeout=60)
        assert 'playbackControl' in client.server_info['capabilities']
        client.subscribe()
        msgs = client.messages_for(1.5)
        status = [m for topic, _, m in msgs if topic == '/status']
        assert status and status[-1]['source'].startswith('replay_bag')
        # the replayed joint states are the recorded ones, where the stamps meet
        matched = 0
        for topic, t_ns, m in msgs:
            if topic == '/joint_states' and t_ns in recorded:
                assert m['position'] == recorded[t_ns][0].position
                matched += 1
        assert matched >= 1, ('no replayed state at a recorded stamp',
                              [t for tp, t, _ in msgs if tp == '/joint_states'][:8])
        assert client.call('pause')['success']
        client.messages_for(0.3)
        assert client.messages_for(0.8) == []
        answer = client.call('reset')
        assert answer['success'], answer
        assert client.call('unpause')['success']
        after = [m for topic, _, m in client.messages_for(0.6) if topic == '/status']
        assert after and after[0]['sim_time'] < 0.5, after[:1]

        # Foxglove's playback bar: pause, then seek forward and play at double speed
        state = client.playback('pause')
        assert state['status'] == 'paused' and not state['did_seek'], state
        client.messages_for(0.3)
        assert client.messages_for(0.8) == []
        state = client.playback('play', speed=2.0, seek_ns=6_000_000_000)
        assert state['did_seek'] and state['current_time'] == 6_000_000_000, state
        msgs = client.messages_for(1.0)
        times = [m['sim_time'] for topic, _, m in msgs if topic == '/status']
        assert times and times[0] >= 6.0 - 1e-9, times[:3]
        # twice real time: ~2 s simulated per wall second (loose: a loaded machine lags)
        assert 0.5 < times[-1] - times[0] < 2.5, (times[0], times[-1])
        # the states after the seek are still the recorded ones
        after_seek = [(t_ns, m) for topic, t_ns, m in msgs
                      if topic == '/joint_states' and t_ns in recorded]
        assert after_seek and all(m['position'] == recorded[t_ns][0].position
                                  for t_ns, m in after_seek)
        client.close()
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert 'Traceback' not in err


@pytest.mark.parametrize('args, text', [
    (['no_such_bag', '--live', '8765'], 'no_such_bag'),
    (['BAG', '--live', '70000'], '--live'),
    (['BAG', '--live', '8765', '--speed', '0'], '--speed'),
])
def test_replay_bag_bad_input(tmp_path, args, text):
    bag = tmp_path / 'run'
    rec = _tool(tmp_path, 'run_headless', '--schedule', str(SCHEDULE), '--out', str(bag),
                '--duration', '0.1')
    assert rec.wait(120) == 0
    args = [str(bag) if a == 'BAG' else a for a in args]
    proc = _tool(tmp_path, 'replay_bag', *args)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 2
    assert len(err.strip().splitlines()) == 1 and text in err and 'Traceback' not in err, err
