"""Sliding joints through the ROS plumbing: the live sim_node with a prismatic scene (the
per-joint topic taking newtons, `joint_commands` position as the UID 21 aim, `/joint_states`
in m, m/s and N, the sliding link's marker moved by d along the axis), and a bag recorded
with a prismatic joint that replays, while a tampered copy does not."""
from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys

import numpy as np
import pytest
import yaml

from abd_joint_sim import Scene, World
from conftest import NodeProcess, Probe, next_domain_id
from physics_helpers import box
from test_replay_tamper import copy_bag, replay_check

REPO = Path(__file__).resolve().parents[1]
FORCE = 2.0         # [N] on `push`
AIM = 0.05          # [m] for `aim`
STEPS = 10


def _scene_file(tmp_path: Path) -> Path:
    """A fixed base with two sliders: `push` along +x under an external force (UID 667), `aim`
    along +y with a drive (UID 21) and a limit; no gravity."""
    data = dict(
        dt=0.001, gravity=[0.0, 0.0, 0.0],
        bodies=[box('base', (0, 0, 0), fixed=True), box('a', (0.6, 0, 0), size=(0.2, 0.2, 0.2)),
                box('b', (0, 0.6, 0), size=(0.2, 0.2, 0.2))],
        joints=[dict(name='push', type='prismatic', parent='base', child='a', p0=[0.3, 0, 0], p1=[1.3, 0, 0],
                     external_force=dict(force=0.0, enabled=True, effort_limit=50.0)),
                dict(name='aim', type='prismatic', parent='base', child='b', p0=[0, 0.3, 0], p1=[0, 1.3, 0],
                     driving=dict(aim_distance=0.0, enabled=True, strength_ratio=5.0),
                     limit=dict(lower=-0.2, upper=0.2))])
    path = tmp_path / 'sliders.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def _reference(scene_path: Path):
    """A World stepped as the node is commanded: FORCE on push, AIM for aim, STEPS steps."""
    world = World(Scene.from_yaml(scene_path))
    world.set_effort('push', FORCE)
    world.set_drive('aim', aim=AIM)
    world.step(STEPS)
    return world


@pytest.mark.slow
def test_sliding_joint_topics_markers_and_units_on_the_live_node(tmp_path):
    """sim_node (paused, the slider scene) advanced by ~/step after a force of FORCE N on
    `/joint_torque/push` and a `joint_commands` position AIM m on `aim`: `/joint_states`
    reports the joints as a World commanded with set_effort / set_drive (distance in m,
    effort FORCE N), and each sliding body's marker is its creation pose moved by d t̂."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    from std_srvs.srv import Trigger
    from visualization_msgs.msg import MarkerArray
    scene_path = _scene_file(tmp_path)
    domain = next_domain_id()
    node = NodeProcess.sim_node(tmp_path, domain, {'scene': str(scene_path), 'start_paused': True})
    probe = Probe(domain)
    states: list = []
    markers: list = []
    try:
        n = probe.node
        n.create_subscription(JointState, '/joint_states', states.append, 50)
        n.create_subscription(MarkerArray, '/markers', markers.append, 50)
        force = n.create_publisher(Float64, '/joint_torque/push', 10)
        commands = n.create_publisher(JointState, '/joint_commands', 10)
        probe.wait_matched_subscriber(force, log=node)
        probe.wait_matched_subscriber(commands, log=node)
        step = n.create_client(Trigger, '/abd_joint_sim/step')
        force.publish(Float64(data=FORCE))
        commands.publish(JointState(name=['aim'], position=[AIM]))
        probe.spin_for(1.0)     # delivered before the first step (it is paused)
        for _ in range(STEPS):
            assert probe.call(step, Trigger.Request(), log=node).success
        t_end = STEPS * 1_000_000

        def stamp(msg):
            return msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
        probe.wait_for(lambda: any(stamp(m) == t_end for m in states)
                       and any(m.markers and stamp(m.markers[0]) == t_end for m in markers),
                       20.0, 'the last step\'s joint state and markers', node)
        assert node.stop(signal.SIGINT) == 0, node.output()[-3000:]
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)
    world = _reference(scene_path)
    last = next(m for m in states if stamp(m) == t_end)
    assert list(last.name) == ['push', 'aim']
    np.testing.assert_allclose(last.position, world.joint_positions(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(last.velocity, world.joint_velocities(), rtol=0, atol=1e-10)
    assert list(last.effort) == [FORCE, 0.0]            # the applied force, N
    d_push, d_aim = world.joint_positions()
    # FORCE N on 8 kg for 10 ms: d ≈ f t²/(2m) ≈ 1.2e-5 m; the drive pulls `aim` toward AIM
    assert 0.5e-5 < d_push < 2e-5 and 0.0 < d_aim < AIM
    body = next(m for m in markers if m.markers and stamp(m.markers[0]) == t_end)
    poses = {m.ns.split('/', 1)[1]: m for m in body.markers if m.ns.startswith('bodies/')}
    for name, start, axis, d in (('a', (0.6, 0, 0), (1, 0, 0), d_push), ('b', (0, 0.6, 0), (0, 1, 0), d_aim)):
        p = poses[name].pose.position
        moved = np.array([p.x, p.y, p.z]) - start
        # along the axis by d (to the body's own strain: an affine body pulled at the joint's
        # point stretches by a few 1e-3 of d), nothing across it
        np.testing.assert_allclose(moved, d * np.array(axis), rtol=0, atol=0.01 * abs(d))
        assert np.linalg.norm(moved - np.dot(moved, axis) * np.array(axis)) < 1e-9
        np.testing.assert_allclose([p.x, p.y, p.z], world.body_pose(name)[0], rtol=0, atol=1e-12)


@pytest.mark.slow
def test_a_bag_recorded_with_a_sliding_joint_replays_and_a_tampered_copy_fails(tmp_path):
    """run_headless records the slider scene under a force (N) and a joint_commands position
    (m); replay_check reproduces it, and a copy with one distance moved by 1e-3 m fails."""
    scene_path = _scene_file(tmp_path)
    schedule = tmp_path / 'schedule.yaml'
    schedule.write_text('duration: 0.1\nevents:\n'
                        f'  - {{t: 0.0, torque: {{push: {FORCE}}}}}\n'
                        f'  - {{t: 0.02, joint_command: {{position: {{aim: {AIM}}}}}}}\n'
                        '  - {t: 0.05, joint_command: {effort: {push: -80.0}}}\n')
    bag = tmp_path / 'bag'
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    run = subprocess.run([sys.executable, '-m', 'abd_joint_sim.tools.run_headless', '--scene', str(scene_path),
                          '--schedule', str(schedule), '--out', str(bag), '--publish-every', '1'],
                         capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr
    assert 'clamped to -50' in run.stderr                   # the effort limit, in N
    from abd_joint_sim.record import read_messages
    states = [msg for _, _, _, msg in read_messages(bag, ['/joint_states'])]
    assert [s.effort[0] for s in states[-3:]] == [-50.0] * 3 and states[-1].position[1] > 0.0
    ok = replay_check(bag)
    assert ok.returncode == 0 and 'OK: replay reproduces' in ok.stdout, ok.stdout + ok.stderr

    def tamper(k, msg):
        if k == 40:
            msg.position = [msg.position[0] + 1e-3, msg.position[1]]
        return msg
    copy_bag(bag, tmp_path / 'tampered', edit=tamper)
    bad = replay_check(tmp_path / 'tampered')
    assert bad.returncode == 1 and "MISMATCH: position of joint 'push'" in bad.stdout, bad.stdout

