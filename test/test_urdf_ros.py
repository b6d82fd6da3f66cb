"""URDF robots in the ROS plumbing: the joint_commands (sensor_msgs/JointState) command,
bags that store the URDF and replay, and sim_node started from robot_description."""
from __future__ import annotations

import math
import os
from pathlib import Path
import signal
import subprocess
import sys

import pytest

from abd_joint_sim import Scene, World
from abd_joint_sim.ros.commands import CommandBuffer
from conftest import NodeProcess, Probe, next_domain_id, ros_env

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / 'abd_joint_sim' / 'robots' / 'demo_arm.urdf'
JOINTS = ['shoulder_pan', 'shoulder_lift', 'elbow']


def buffer_for(scene, world):
    scene_limits = dict(zip(world.actuated_joint_names, world.model.torque_effort_limit))
    return CommandBuffer(world.actuated_joint_names, [], scene_limits=scene_limits,
                         driven=[j.name for j in scene.joints if j.driving])


@pytest.mark.slow
def test_joint_commands_effort_position_and_refusals():
    scene = Scene.from_urdf(str(DEMO), joints={'elbow': {'driving': {'enabled': True}}})
    world = World(scene)
    buf = buffer_for(scene, world)
    # effort on a subset, clamped to the URDF effort limit (elbow: 15 N m)
    rej, clamps = buf.command_joint_state(['elbow', 'shoulder_pan'], [], [], [-40.0, 1.5])
    assert rej == [] and len(clamps) == 1 and clamps[0].applied == -15.0
    applied = buf.apply(world)
    assert applied.torques == {'elbow': -15.0, 'shoulder_pan': 1.5}
    assert applied.sources['elbow'] == 'joint_state'
    # position -> the driving aim where the joint has driving; refused elsewhere, rest applies
    rej, _ = buf.command_joint_state(['elbow', 'shoulder_pan'], [0.4, 0.1], [], [])
    assert len(rej) == 1 and rej[0].joint == 'shoulder_pan' and 'no driving' in rej[0].reason
    applied = buf.apply(world)
    assert applied.aims == {'elbow': 0.4}
    assert world.control.drive_aim[0] == 0.4
    # velocity refused (one rejection), unknown names refused per entry
    rej, _ = buf.command_joint_state(['elbow', 'ghost'], [], [1.0, 1.0], [1.0, 2.0])
    reasons = [str(r) for r in rej]
    assert any('velocity commands are not supported' in r for r in reasons)
    assert any("joint 'ghost'" in r and 'not an actuated joint' in r for r in reasons)
    assert buf.apply(world).torques == {'elbow': 1.0}
    # length mismatch and NaN reject the whole message
    rej, _ = buf.command_joint_state(['elbow', 'shoulder_pan'], [], [], [1.0])
    assert len(rej) == 1 and 'joint_commands command' in str(rej[0]) and '1 effort values for 2' in str(rej[0])
    rej, _ = buf.command_joint_state(['elbow'], [], [], [math.nan])
    assert len(rej) == 1 and 'finite' in rej[0].reason
    assert not buf.apply(world)
    # an aim beyond the scene format's angle range (1e4 rad) is refused, not queued: World
    # would refuse it at the step boundary, and 1e300 would hold the joint still silently
    rej, _ = buf.command_joint_state(['elbow'], [1e300], [], [])
    assert len(rej) == 1 and rej[0].joint == 'elbow' and '|aim| beyond 10000 rad' in rej[0].reason
    assert not buf.apply(world) and world.control.drive_aim[0] == 0.4
    rej, _ = buf.command_joint_state(['elbow'], [-1e4], [], [])
    assert rej == [] and buf.apply(world).aims == {'elbow': -1e4}


@pytest.mark.slow
def test_headless_run_with_joint_commands_records_the_urdf_and_replays(tmp_path):
    schedule = tmp_path / 's.yaml'
    schedule.write_text(
        'duration: 0.2\nevents:\n'
        '  - {t: 0.0, torque: {shoulder_pan: 2.0}}\n'
        '  - {t: 0.05, joint_command: {effort: {shoulder_lift: 5.0, elbow: -40.0}}}\n'
        '  - {t: 0.1, torque: [1.0, 2.0, 3.0]}\n')
    bag = tmp_path / 'bag'
    env = dict(os.environ, PYTHONPATH=str(REPO))
    run = subprocess.run([sys.executable, '-m', 'abd_joint_sim.tools.run_headless', '--scene',
                          'demo_arm', '--schedule', str(schedule), '--out', str(bag)],
                         capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr
    assert 'clamped to -15' in run.stderr
    from abd_joint_sim.record import read_attachments, read_custom_data
    assert read_custom_data(str(bag))['abd_joint_sim.urdf'] == DEMO.read_text()
    assert read_attachments(str(bag))['robot.urdf'] == DEMO.read_bytes()
    from abd_joint_sim.tools.bagrun import load_bag
    kinds = [c.kind for seg in load_bag(str(bag)).plan.segments for c in seg.commands]
    assert kinds.count('joint_state') == 1
    check = subprocess.run([sys.executable, '-m', 'abd_joint_sim.tools.replay_check', str(bag)],
                           capture_output=True, text=True, env=env, timeout=300)
    assert check.returncode == 0, check.stdout + check.stderr
    again = subprocess.run([sys.executable, '-m', 'abd_joint_sim.tools.run_headless',
                            '--from-bag', str(bag), '--out', str(tmp_path / 'bag2')],
                           capture_output=True, text=True, env=env, timeout=300)
    assert again.returncode == 0, again.stderr
    assert read_custom_data(str(tmp_path / 'bag2'))['abd_joint_sim.urdf'] == DEMO.read_text()
    # replay must be able to fail: drop the joint_commands message -> deviation
    from abd_joint_sim.tools import bagrun
    run_ = bagrun.load_bag(str(bag))
    for seg in run_.plan.segments:
        seg.commands = [c for c in seg.commands if c.kind != 'joint_state']
    from abd_joint_sim.tools.sim import HeadlessSim
    scene = bagrun.scene_from_text(run_.scene_text, 'bag')
    sim = HeadlessSim(scene, bagrun.config_for(run_.parameters), clamp=False)

    class Last:
        def on_state(self, sim, segment, force):
            self.q = list(sim.world.joint_angles())

        def on_applied(self, sim, applied):
            pass
    last = Last()
    sim.run(run_.plan, last)
    recorded = run_.states[-1][max(run_.states[-1])][-1].position
    assert max(abs(a - b) for a, b in zip(last.q, recorded)) > 1e-3


@pytest.mark.slow
@pytest.mark.parametrize('how', ['robot_description', 'scene'])
def test_sim_node_from_robot_description(tmp_path, how):
    """robot_description (URDF text) or scene:=demo_arm is the scene: /joint_states names
    are the URDF's, joint_commands efforts act; the bag stores the URDF and replays."""
    domain = next_domain_id()
    bag = tmp_path / 'bag'
    # As robot_state_publisher gets it from a launch file or a params file (the command line:
    # test_robot_description_on_the_command_line).
    import yaml
    params = tmp_path / 'params.yaml'
    source = ({'robot_description': DEMO.read_text()} if how == 'robot_description'
              else {'scene': 'demo_arm'})
    params.write_text(yaml.safe_dump({'abd_joint_sim': {'ros__parameters': {
        **source, 'real_time_factor': 0.0, 'publish_rate': 0.0, 'record': str(bag)}}}))
    (tmp_path / 'log').mkdir()
    node = NodeProcess([sys.executable, '-m', 'abd_joint_sim.ros.node', '--ros-args',
                        '--params-file', str(params)], ros_env(domain, tmp_path / 'log'),
                       tmp_path / 'node.log')
    probe = Probe(domain)
    try:
        from sensor_msgs.msg import JointState
        states = []
        probe.node.create_subscription(JointState, '/joint_states', states.append, 100)
        pub = probe.node.create_publisher(JointState, '/joint_commands', 10)
        probe.wait_for(lambda: states, 30.0, 'a first /joint_states message', node)
        assert list(states[0].name) == JOINTS
        probe.wait_matched_subscriber(pub, log=node)
        pub.publish(JointState(name=['shoulder_pan', 'elbow'], effort=[3.0, 50.0]))
        probe.wait_for(lambda: list(states[-1].effort) == [3.0, 0.0, 15.0], 30.0,
                       'the commanded efforts in /joint_states', node)
        t_end = states[-1].header.stamp.sec + 0.2
        probe.wait_for(lambda: states[-1].header.stamp.sec + states[-1].header.stamp.nanosec
                       * 1e-9 > t_end, 60.0, '0.2 s more', node)
        assert states[-1].velocity[0] > 0.0, 'positive effort must turn shoulder_pan positively'
        pub.publish(JointState(name=['elbow'], velocity=[1.0], effort=[1.0]))
        probe.wait_for(lambda: 'velocity commands are not supported' in node.output(), 30.0,
                       'the velocity refusal', node)
        assert node.stop(signal.SIGINT) == 0, node.output()[-3000:]
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)
    out = node.output()
    assert ('scene robot_description' if how == 'robot_description' else 'demo_arm.urdf') in out
    assert 'clamped to 15' in out
    # the start-up line's gravity, and the ignored speed limits said once, as a warning
    assert 'gravity (0, 0, -9.81) m/s²' in out
    assert out.count('<limit velocity> is not enforced') == 1, out[-3000:]
    from abd_joint_sim.record import read_custom_data
    assert read_custom_data(str(bag))['abd_joint_sim.urdf'] == DEMO.read_text()
    env = ros_env(domain, tmp_path)
    check = subprocess.run([sys.executable, '-m', 'abd_joint_sim.tools.replay_check', str(bag)],
                           capture_output=True, text=True, env=env, timeout=300)
    assert check.returncode == 0, check.stdout + check.stderr


def test_sim_node_bad_urdf_is_one_line(tmp_path):
    bad = tmp_path / 'bad.urdf'
    bad.write_text(DEMO.read_text().replace('type="fixed"', 'type="planar"'))
    node = NodeProcess.sim_node(tmp_path, next_domain_id(), {'scene': str(bad)})
    try:
        node.proc.wait(60)
    finally:
        if node.alive():
            node.stop(signal.SIGKILL)
    out = node.output()
    assert node.proc.returncode == 1, out
    assert "cannot start:" in out and "joint 'tool_mount' is planar" in out and 'lock: [tool_mount]' in out
    assert 'Traceback' not in out


def test_position_commands_drive_the_joints_along_a_trajectory():
    """joint_commands positions, as a position controller sends them (a smooth trajectory,
    small steps per cycle), move joints that have driving (robot option `driving:` on all)
    to the commanded angles; the joint without a command holds its pose."""
    scene = Scene.from_urdf(str(DEMO), gravity=[0, 0, 0], driving={'enabled': True})
    assert all(j.driving is not None and j.driving.enabled for j in scene.joints)
    world = World(scene)
    buf = buffer_for(scene, world)
    for k in range(1, 31):
        rej, _ = buf.command_joint_state(['elbow', 'shoulder_pan'], [0.01 * k, -0.005 * k], [], [])
        assert rej == []
        buf.apply(world)
        world.step(5)
    world.step(200)
    q = world.joint_angles()
    assert q[2] == pytest.approx(0.30, abs=2e-3) and q[0] == pytest.approx(-0.15, abs=2e-3)
    assert abs(q[1]) < 2e-3


@pytest.mark.slow
def test_robot_description_on_the_command_line(tmp_path):
    """`-p robot_description:="$(cat robot.urdf)"`, as users start robot_state_publisher:
    rcl would parse the URDF text as YAML (": " in a comment ends it); the node moves it into
    a params file first, so any URDF text arrives whole."""
    from abd_joint_sim.ros.node import _robot_description_to_params_file
    text = DEMO.read_text().replace('<robot name', '<!-- note: a comment # with YAML trouble -->\n<robot name')
    args, path = _robot_description_to_params_file(['x', '--ros-args', '-p', 'a:=1', '-p',
                                                    f'robot_description:={text}', '-p', 'b:=2'])
    try:
        assert args == ['x', '--ros-args', '-p', 'a:=1', '--params-file', path, '-p', 'b:=2']
        import yaml
        assert yaml.safe_load(Path(path).read_text())['/**']['ros__parameters'][
            'robot_description'] == text
    finally:
        os.unlink(path)
    domain = next_domain_id()
    (tmp_path / 'log').mkdir()
    node = NodeProcess([sys.executable, '-m', 'abd_joint_sim.ros.node', '--ros-args', '-p',
                        f'robot_description:={text}', '-p', 'start_paused:=true'],
                       ros_env(domain, tmp_path / 'log'), tmp_path / 'node.log')
    probe = Probe(domain)
    try:
        probe.wait_for(lambda: 'scene robot_description' in node.output() or not node.alive(),
                       60.0, 'the start line', node)
        assert node.alive(), node.output()
        assert "joints ['shoulder_pan', 'shoulder_lift', 'elbow']" in node.output()
        assert node.stop(signal.SIGINT) == 0
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)
    # and a -p value rcl cannot parse is one line, not a traceback
    bad = subprocess.run([sys.executable, '-m', 'abd_joint_sim.ros.node', '--ros-args', '-p',
                          'time_step:=[1: 2'], capture_output=True, text=True, timeout=60,
                         env=ros_env(domain, tmp_path / 'log'))
    assert bad.returncode == 2 and 'cannot start' in bad.stderr and 'Traceback' not in bad.stderr
