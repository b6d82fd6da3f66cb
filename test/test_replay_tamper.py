"""Blind spots of recording and replay_check, closed with bags altered one field at a time.

A copy of a golden bag with one thing changed (every 10th joint state dropped; one
velocity; one effort) must fail ``replay_check`` for that reason alone, while the faithful
copy made the same way passes. A fresh headless recording must hold every message its
publish schedule says was published, counted from dt and the rates chosen here.
"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys

from mcap.reader import NonSeekingReader
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
import yaml

REPO = Path(__file__).resolve().parents[1]
GOLDEN = REPO / 'test' / 'data' / 'golden_default'


def copy_bag(src: Path, dst: Path, edit=None) -> None:
    """Write `src`'s messages (file order, same log times, bytes, custom data, attachments)
    into a new bag `dst`; `edit(k, msg)` gets the k-th /joint_states message and returns it
    changed, or None to leave it out."""
    from abd_joint_sim.record import BagWriter, read_attachments
    info = yaml.safe_load((src / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    with BagWriter(dst, custom_data=dict(info['custom_data']),
                   attachments=read_attachments(src)) as bag:
        for entry in info['topics_with_message_count']:
            meta = entry['topic_metadata']
            qos = meta['offered_qos_profiles'][0]
            bag.add_topic(meta['name'], meta['type'], qos=qos['reliability'],
                          depth=qos['depth'])
        k = 0
        with open(next(src.glob('*.mcap')), 'rb') as f:
            for _s, channel, message in NonSeekingReader(f).iter_messages(
                    log_time_order=False):
                if channel.topic == '/joint_states' and edit is not None:
                    msg = edit(k, deserialize_message(message.data, JointState))
                    k += 1
                    if msg is not None:
                        bag.write(channel.topic, message.log_time, msg)
                    continue
                bag.write_serialized(channel.topic, message.log_time, bytes(message.data))


def replay_check(bag: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    return subprocess.run([sys.executable, '-m', 'abd_joint_sim.tools.replay_check', str(bag)],
                          capture_output=True, text=True, env=env, cwd=str(REPO), timeout=300)


def field_lines(out: str) -> dict[str, str]:
    return {ln.split()[0]: ln for ln in out.splitlines() if ln.startswith('  ')
            and ln.split()[0] in ('position', 'velocity', 'effort')}


def test_a_faithful_copy_replays(tmp_path):
    copy_bag(GOLDEN, tmp_path / 'same', edit=lambda k, m: m)
    out = replay_check(tmp_path / 'same')
    assert out.returncode == 0 and 'OK: replay reproduces' in out.stdout, out.stdout


def test_a_gap_in_the_joint_states_is_reported(tmp_path):
    info = yaml.safe_load((GOLDEN / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    n = next(e['message_count'] for e in info['topics_with_message_count']
             if e['topic_metadata']['name'] == '/joint_states')
    dropped = [k for k in range(n - 1) if k % 10 == 9]      # every 10th, not the last
    copy_bag(GOLDEN, tmp_path / 'gaps', edit=lambda k, m: None if k in dropped else m)
    out = replay_check(tmp_path / 'gaps')
    print(out.stdout)
    assert out.returncode == 1, out.stdout + out.stderr
    assert f'compared {n - len(dropped)} of {n - len(dropped)}' in out.stdout
    assert f'GAP: {len(dropped)} joint state(s) the publish schedule says were published ' \
        'are not in the bag' in out.stdout
    assert 'MISMATCH' in out.stdout and 'OK:' not in out.stdout


@pytest.mark.parametrize('name, index, delta', [('velocity', 0, 1e-3), ('effort', 1, 0.01)])
def test_one_field_tampered_alone_is_caught(tmp_path, name, index, delta):
    """Position untouched: only the tampered field's tolerance can catch it."""
    def edit(k, msg):
        if k == 12:
            values = list(getattr(msg, name))
            values[index] += delta
            setattr(msg, name, values)
        return msg
    copy_bag(GOLDEN, tmp_path / name, edit)
    out = replay_check(tmp_path / name)
    print(out.stdout)
    assert out.returncode == 1, out.stdout + out.stderr
    lines = field_lines(out.stdout)
    assert 'FAIL: 1 value(s) beyond' in lines[name], lines[name]
    assert all(lines[f].endswith(': ok') for f in lines if f != name), lines
    assert f'MISMATCH: {name} of joint' in out.stdout


def test_a_headless_bag_holds_every_scheduled_message(tmp_path):
    """hinge, 1 s, dt from the scene, /joint_states at 50 Hz, markers at 30 Hz: /clock at
    start and after every step, the states and markers on their grids (first step at or
    after each k / rate) and at start, diagnostics once per simulated second."""
    from abd_joint_sim import Scene
    from abd_joint_sim.ros.params import resolve_scene
    sched = tmp_path / 'sched.yaml'
    sched.write_text('- {t: 0.0, torque: {hinge: 5.0}}\n')
    bag = tmp_path / 'counted'
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    run = subprocess.run([sys.executable, '-m', 'abd_joint_sim.tools.run_headless', '--scene',
                          'hinge', '--schedule', str(sched), '--out', str(bag), '--duration',
                          '1.0', '--publish-rate', '50', '-q'], capture_output=True, text=True,
                         env=env, cwd=str(REPO), timeout=300)
    assert run.returncode == 0, run.stderr
    dt_ns = round(Scene.from_file(resolve_scene('hinge')).dt * 1e9)
    steps = 1_000_000_000 // dt_ns
    times = [k * dt_ns for k in range(steps + 1)]

    def on_grid(rate: float) -> list[int]:
        period = round(1e9 / rate)
        return sorted({next(t for t in times if t >= g)
                       for g in range(0, times[-1] + 1, period)})
    counts: dict[str, list[int]] = {}
    with open(next(bag.glob('*.mcap')), 'rb') as f:
        for _s, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
            counts.setdefault(channel.topic, []).append(message.log_time)
    assert counts['/clock'] == times
    assert counts['/joint_states'] == on_grid(50.0)
    assert counts['/markers'] == on_grid(30.0)
    assert counts['/diagnostics'] == [1_000_000_000]
    assert counts['/joint_torque/hinge'] == [0]
