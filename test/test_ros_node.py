"""sim_node over real DDS: the node in its own process, a probe node in the test process.

Most checks share one node process on the packaged ``hinge`` scene (a free 0.4 m cube on a
vertical hinge, no gravity, I_axis = 24.747 kg m^2, dt = 0.01 s), started paused; every
test begins with pause + reset, so the tests do not depend on their order. The default
scene (two-joint arm) runs in a second process for the array command, effort limits,
recording and SIGTERM.

Tolerance of the magnitude check: with a constant torque tau from rest, the analytic angle
is theta(t) = 1/2 alpha t^2 (alpha = tau / I). BDF1 (implicit Euler) gives, exactly,
theta_n = alpha h^2 n (n + 1) / 2 = 1/2 alpha t^2 + 1/2 alpha h t (docs/physics.md "Analytic references"), so
we allow |theta - 1/2 alpha t^2| <= 1/2 alpha h t + 5 % and the velocity within 5 % + alpha h
of alpha t. The 5 % covers joint compliance and the Newton stopping rule (reference default
velocity_tol = 0.05 m/s, about 1 iteration per step): at tau = 10 N m the core is ~2 % above
the BDF1 solution after 1 s (0.2 rad). A wrong inertia, sign, factor 2 or a torque applied a
step late or early all fail it. Times are the header stamps (simulated time).
"""
from __future__ import annotations

import math
from pathlib import Path
import signal
import time

import pytest

from conftest import NodeProcess, Probe, next_domain_id

NODE = '/abd_joint_sim'
I_AXIS = 24.747     # kg m^2, hinge scene (0.4 m cube, rho 1000, axis 0.6 m away)
DT = 0.01           # s, hinge scene


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class Session:
    """Probe-side handles to one running sim_node."""

    def __init__(self, probe: Probe, node: NodeProcess, actuated: list[str]):
        from rcl_interfaces.srv import SetParameters
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, Float64, Float64MultiArray
        from std_srvs.srv import Trigger
        self.probe, self.node = probe, node
        n = probe.node
        self.states: list = []
        self.clocks: list[int] = []
        self.state_wall: list[float] = []
        n.create_subscription(JointState, '/joint_states', self._on_state, 100)
        n.create_subscription(Clock, '/clock', lambda m: self.clocks.append(_ns(m.clock)),
                              QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.torque = {j: n.create_publisher(Float64, f'/joint_torque/{j}', 10)
                       for j in actuated}
        self.enable = {j: n.create_publisher(Bool, f'/joint_torque_enable/{j}', 10)
                       for j in actuated}
        self.enable_all = n.create_publisher(Bool, '/joint_torque_enable', 10)
        self.array = n.create_publisher(Float64MultiArray, '/joint_torque_commands', 10)
        self.srv = {name: n.create_client(Trigger, f'{NODE}/{name}')
                    for name in ('pause', 'unpause', 'step', 'reset')}
        self.set_params = n.create_client(SetParameters, f'{NODE}/set_parameters')
        self.Trigger, self.Float64, self.Bool = Trigger, Float64, Bool
        self.Float64MultiArray = Float64MultiArray
        for pub in [*self.torque.values(), *self.enable.values(), self.enable_all, self.array]:
            probe.wait_matched_subscriber(pub, log=node)
        probe.wait_for(lambda: n.count_publishers('/joint_states') > 0, 20.0,
                       'the node\'s /joint_states publisher', node)

    def _on_state(self, msg) -> None:
        self.states.append(msg)
        self.state_wall.append(time.monotonic())

    # -- actions ---------------------------------------------------------------------
    def call(self, name: str, expect_success: bool = True):
        res = self.probe.call(self.srv[name], self.Trigger.Request(), log=self.node)
        if expect_success:
            assert res.success, f'{name}: {res.message}'
        return res

    def clear(self) -> None:
        self.states.clear()
        self.clocks.clear()
        self.state_wall.clear()

    def restart(self) -> None:
        """Paused, reset to t = 0, nothing received yet except the reset state."""
        self.call('pause')
        self.probe.spin_for(0.1)
        self.clear()
        self.call('reset')
        self.probe.wait_for(lambda: any(_ns(s.header.stamp) == 0 for s in self.states), 10.0,
                            'the joint state published by ~/reset', self.node)
        self.clear()

    def publish_torque(self, joint: str, value: float) -> None:
        self.torque[joint].publish(self.Float64(data=float(value)))

    def set_parameter(self, name: str, value):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
        return self.probe.call(self.set_params, req, log=self.node).results[0]

    def step_until_effort(self, joint_index: int, value: float, max_steps: int = 5) -> int:
        """Step (paused) until the published effort shows `value`; return the stamp [ns] at
        which that torque started to act (the step boundary before it)."""
        self.probe.spin_for(0.3)        # reliable delivery on localhost takes milliseconds
        for _ in range(max_steps):
            before = len(self.states)
            t_start = self.latest_stamp()
            self.call('step')
            self.probe.wait_for(lambda: len(self.states) > before, 10.0, 'a stepped state',
                                self.node)
            if abs(self.states[-1].effort[joint_index] - value) < 1e-9:
                return t_start
        raise AssertionError(f'effort never became {value}: {self.states[-1]}\n'
                             + self.node.output()[-3000:])

    def latest_stamp(self) -> int:
        return _ns(self.states[-1].header.stamp) if self.states else 0

    def run_until(self, t_ns: int, timeout: float = 20.0) -> None:
        """Unpause, wait for a state stamped >= t_ns, pause."""
        self.call('unpause')
        self.probe.wait_for(lambda: self.states and self.latest_stamp() >= t_ns, timeout,
                            f'a joint state stamped >= {t_ns * 1e-9:.3f} s', self.node)
        self.call('pause')
        self.probe.spin_for(0.2)

    def output(self) -> str:
        return self.node.output()


@pytest.fixture(scope='module')
def hinge(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('hinge_node')
    domain = next_domain_id()
    node = NodeProcess.sim_node(tmp, domain, {
        'scene': 'hinge', 'start_paused': True, 'real_time_factor': 1.0,
        'publish_rate': 0.0})
    probe = Probe(domain)
    try:
        session = Session(probe, node, ['hinge'])
        yield session
        assert node.alive(), 'sim_node died during the tests:\n' + node.output()[-3000:]
        rc = node.stop(signal.SIGINT)
        assert rc == 0, f'sim_node exit status {rc} after SIGINT:\n' + node.output()[-3000:]
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)


def test_start_line_and_initial_state(hinge):
    hinge.restart()
    hinge.call('step')
    hinge.probe.wait_for(lambda: hinge.states, 10.0, 'a state after ~/step', hinge.node)
    out = hinge.output()
    assert 'hinge.yaml' in out and "actuated ['hinge']" in out and 'paused' in out
    assert '/joint_torque_commands' in out and 'recording off' in out
    # what is not simulated, up front: the hinge scene has no gravity, and no body collides
    assert '| no gravity |' in out and 'not simulated: contact and collision' in out
    msg = hinge.states[0]
    assert list(msg.name) == ['hinge']
    assert len(msg.position) == len(msg.velocity) == len(msg.effort) == 1
    # Solver status on /diagnostics (1 Hz, wall time).
    from diagnostic_msgs.msg import DiagnosticArray
    diags = []
    hinge.probe.node.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 10)
    hinge.probe.wait_for(lambda: diags, 10.0, 'a /diagnostics message', hinge.node)
    values = {kv.key: kv.value for kv in diags[-1].status[0].values}
    for key in ('newton_iterations', 'converged', 'max_joint_separation', 'sim_time', 'paused'):
        assert key in values, values
    assert values['paused'] == 'True'


def test_pause_step_reset_and_clock(hinge):
    hinge.restart()
    hinge.probe.spin_for(0.5)
    assert hinge.states == [], 'paused node must not publish new states'
    # ~/step: exactly one step of dt per call, while paused.
    for k in (1, 2, 3):
        hinge.call('step')
        hinge.probe.wait_for(lambda: len(hinge.states) >= k, 10.0, f'state after step {k}')
    assert [_ns(s.header.stamp) for s in hinge.states] == [10_000_000, 20_000_000, 30_000_000]
    # Running: /clock advances with the joint state stamps; rate ~ real time.
    hinge.clear()
    hinge.call('step', expect_success=True)
    res = hinge.call('unpause')
    assert 'running' in res.message
    res = hinge.call('step', expect_success=False)
    assert not res.success and 'not paused' in res.message
    hinge.probe.wait_for(lambda: hinge.states and hinge.latest_stamp() >= 540_000_000, 20.0,
                         'sim time 0.54 s')
    hinge.call('pause')
    hinge.probe.spin_for(0.3)
    stamps = [_ns(s.header.stamp) for s in hinge.states]
    assert all(b - a == 10_000_000 for a, b in zip(stamps, stamps[1:])), stamps
    clocks = hinge.clocks
    assert clocks == sorted(clocks) and clocks, 'clock must not go backwards while running'
    clock_set = set(clocks)
    missing = [t for t in stamps if t not in clock_set]
    # /clock is best effort: allow a few drops, but stamps and clock must be the same times.
    assert len(missing) <= len(stamps) // 10, (missing, clocks[:20])
    assert clocks[-1] == stamps[-1]
    # Real-time factor 1: 0.5 s of simulated time in roughly 0.5 s of wall time.
    i0 = next(i for i, t in enumerate(stamps) if t >= 100_000_000)
    i1 = next(i for i, t in enumerate(stamps) if t >= 500_000_000)
    wall = hinge.state_wall[i1] - hinge.state_wall[i0]
    assert 0.2 < wall < 1.5, f'0.4 s of sim time took {wall:.3f} s of wall time at rtf 1'
    # Paused: nothing more.
    n = len(hinge.states)
    hinge.probe.spin_for(0.4)
    assert len(hinge.states) == n
    # ~/reset: back to t = 0 and the initial angle; /clock goes back to 0 too.
    hinge.clear()
    hinge.call('reset')
    hinge.probe.wait_for(lambda: hinge.states, 10.0, 'state after reset')
    assert _ns(hinge.states[-1].header.stamp) == 0
    assert hinge.states[-1].position[0] == pytest.approx(0.0, abs=1e-9)
    hinge.probe.wait_for(lambda: hinge.clocks and hinge.clocks[-1] == 0, 5.0, '/clock = 0')


def test_torque_raises_angle_by_half_alpha_t_squared(hinge):
    hinge.restart()
    tau = 10.0
    alpha = tau / I_AXIS
    hinge.publish_torque('hinge', tau)
    t0 = hinge.step_until_effort(0, tau)
    i0 = len(hinge.states) - 1
    hinge.run_until(t0 + 1_000_000_000)
    theta0 = 0.0            # from rest at the reset angle; states before t0 are at rest
    checked = 0
    for s in hinge.states[i0:]:
        t = (_ns(s.header.stamp) - t0) * 1e-9
        if t < 0.1 - 1e-9:
            continue
        theta = s.position[0] - theta0
        exact = 0.5 * alpha * t * t
        assert abs(theta - exact) <= 0.5 * alpha * DT * t + 0.05 * exact, (t, theta, exact)
        assert s.velocity[0] == pytest.approx(alpha * t, rel=0.05, abs=alpha * DT)
        assert s.effort[0] == tau
        checked += 1
    assert checked >= 85, f'only {checked} states in [0.1, 1.0] s'
    # The sign follows the torque: -tau from rest turns the other way.
    hinge.restart()
    hinge.publish_torque('hinge', -tau)
    t0 = hinge.step_until_effort(0, -tau)
    hinge.run_until(t0 + 300_000_000)
    assert hinge.states[-1].position[0] < -0.5 * 0.5 * alpha * 0.3 ** 2


def test_disable_stops_torque_and_enable_restores_it(hinge):
    hinge.restart()
    hinge.publish_torque('hinge', 10.0)
    hinge.step_until_effort(0, 10.0)
    hinge.run_until(300_000_000)
    hinge.enable['hinge'].publish(hinge.Bool(data=False))
    hinge.probe.spin_for(0.3)
    hinge.clear()
    hinge.run_until(hinge_time(hinge) + 400_000_000)
    efforts = [s.effort[0] for s in hinge.states]
    assert efforts and all(e == 0.0 for e in efforts), efforts
    v = [s.velocity[0] for s in hinge.states]
    assert v[0] > 0.1
    # No torque: the velocity of the free cube stays constant (momentum conserved).
    assert max(abs(x - v[0]) for x in v) <= 1e-3 * abs(v[0]) + 1e-9, (v[0], min(v), max(v))
    # All-joints enable: the stored torque acts again.
    hinge.enable_all.publish(hinge.Bool(data=True))
    hinge.step_until_effort(0, 10.0)


def hinge_time(session: Session) -> int:
    session.probe.spin_for(0.1)
    return session.latest_stamp()


def test_command_timeout_zeroes_torque(hinge):
    result = hinge.set_parameter('command_timeout', 0.3)
    assert result.successful, result.reason
    try:
        hinge.restart()
        hinge.publish_torque('hinge', 5.0)
        t_cmd = hinge.step_until_effort(0, 5.0)
        hinge.run_until(t_cmd + 600_000_000)
        first_zero = next(_ns(s.header.stamp) for s in hinge.states
                          if _ns(s.header.stamp) > t_cmd and s.effort[0] == 0.0)
        # Zero from the first step boundary at t_cmd + 0.3 s, visible in the state after it.
        assert first_zero - t_cmd == pytest.approx(0.3e9 + DT * 1e9, abs=DT * 1e9 + 1e3)
        assert "joint 'hinge': no torque command for 0.3 s" in hinge.output()
    finally:
        assert hinge.set_parameter('command_timeout', 0.0).successful


def test_bad_commands_rejected_and_node_keeps_running(hinge):
    hinge.restart()
    hinge.array.publish(hinge.Float64MultiArray(data=[1.0, 2.0]))
    hinge.publish_torque('hinge', math.nan)
    hinge.probe.spin_for(0.5)
    hinge.call('step')
    hinge.probe.wait_for(lambda: hinge.states, 10.0, 'state after step')
    assert hinge.states[-1].effort[0] == 0.0
    out = hinge.output()
    assert 'array command' in out and 'expected 1 values' in out and 'got 2' in out
    assert "joint 'hinge': nan rejected" in out
    # A valid array of the right length still works.
    hinge.array.publish(hinge.Float64MultiArray(data=[3.0]))
    hinge.step_until_effort(0, 3.0)
    # Live parameter vetting: a negative real-time factor is refused with a reason.
    result = hinge.set_parameter('real_time_factor', -1.0)
    assert not result.successful and 'real_time_factor' in result.reason
    result = hinge.set_parameter('scene', 'other.yaml')
    assert not result.successful
    assert hinge.node.alive()


@pytest.mark.slow
def test_default_scene_array_limits_recording_and_sigterm(tmp_path):
    """Default arm: array command in `joints` order, effort limits clamp (and say so),
    recording on, SIGTERM finalises the bag."""
    domain = next_domain_id()
    bag = tmp_path / 'bag'
    node = NodeProcess.sim_node(tmp_path, domain, {
        'joints': ['elbow', 'shoulder'], 'effort_limits': [2.0, 5.0],
        'real_time_factor': 0.0, 'publish_rate': 0.0, 'record': str(bag)})
    probe = Probe(domain)
    try:
        s = Session(probe, node, ['shoulder', 'elbow'])
        probe.wait_for(lambda: s.states, 20.0, 'a first /joint_states message', node)
        names = list(s.states[0].name)
        assert names == ['shoulder', 'elbow']
        s.array.publish(s.Float64MultiArray(data=[-10.0, 10.0]))   # elbow, shoulder
        probe.wait_for(lambda: s.states[-1].effort[0] == 5.0, 20.0, 'shoulder effort 5', node)
        assert list(s.states[-1].effort) == [5.0, -2.0]
        t_end = s.latest_stamp() + 200_000_000
        probe.wait_for(lambda: s.latest_stamp() >= t_end, 60.0, '0.2 s more', node)
        last = s.states[-1]
        assert last.position[0] > 0.0, 'positive shoulder torque must raise its angle'
        out = node.output()
        assert 'clamped to 5' in out and 'clamped to -2' in out
        rc = node.stop(signal.SIGTERM)
        assert rc == 0, node.output()[-3000:]
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)
    assert 'bag closed' in node.output()
    _check_bag(bag)


def _check_bag(bag: Path) -> None:
    assert (bag / 'metadata.yaml').is_file() and list(bag.glob('*.mcap'))
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)
    counts: dict[str, int] = {}
    array_log_times = []
    t_applied = None          # stamp of the first recorded state with the new effort
    with AnyReader([bag], default_typestore=store) as reader:
        for conn, log_ns, raw in reader.messages():
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic == '/joint_states' and t_applied is None:
                state = reader.deserialize(raw, conn.msgtype)
                if state.effort[0] == 5.0:
                    t_applied = state.header.stamp.sec * 10 ** 9 + state.header.stamp.nanosec
            if conn.topic == '/joint_torque_commands':
                msg = reader.deserialize(raw, conn.msgtype)
                assert list(msg.data) == [-2.0, 5.0]     # as applied (clamped), joints order
                array_log_times.append(log_ns)
    assert counts.get('/joint_states', 0) > 10 and counts.get('/clock', 0) > 10, counts
    # Log time = the simulated time at which the command took effect: the step starting
    # there produced the first state with the new effort one dt later. (Taken from the bag,
    # which has every state: the probe, fed at thousands of states per second into a
    # depth-10 queue, may miss the first one.)
    assert len(array_log_times) == 1
    assert array_log_times[0] == t_applied - 1_000_000, (array_log_times, t_applied)


@pytest.mark.slow
def test_recording_failure_keeps_simulating(tmp_path):
    """A bag path that exists already: recording is refused with an error, the node runs."""
    domain = next_domain_id()
    existing = tmp_path / 'taken'
    existing.mkdir()
    node = NodeProcess.sim_node(tmp_path, domain, {
        'scene': 'hinge', 'real_time_factor': 0.0, 'record': str(existing)})
    probe = Probe(domain)
    try:
        from sensor_msgs.msg import JointState
        states = []
        probe.node.create_subscription(JointState, '/joint_states', states.append, 10)
        probe.wait_for(lambda: len(states) >= 5, 30.0, 'joint states', node)
        out = node.output()
        assert 'recording to' in out and 'disabled' in out and 'recording off' in out
        assert node.stop(signal.SIGINT) == 0
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)
    assert list(existing.iterdir()) == []


# -- start-up parameters and use_sim_time -------------------------------------------------
def _node_cmd(*ros_args: str) -> list[str]:
    import sys
    return [sys.executable, '-m', 'abd_joint_sim.ros.node', '--ros-args', *ros_args]


def _start(tmp_path: Path, domain: int, name: str, *ros_args: str) -> NodeProcess:
    from conftest import ros_env
    log_dir = tmp_path / f'{name}_ros_log'
    log_dir.mkdir(exist_ok=True)
    return NodeProcess(_node_cmd(*ros_args), ros_env(domain, log_dir), tmp_path / f'{name}.log')


@pytest.mark.slow
def test_use_sim_time_does_not_freeze_the_node(tmp_path):
    """use_sim_time:=true (as a launch file may set for every node): the node's clock would
    follow /clock, which only this node moves; it must step on wall time regardless."""
    from sensor_msgs.msg import JointState
    domain = next_domain_id()
    node = _start(tmp_path, domain, 'simtime', '-p', 'scene:=hinge', '-p', 'use_sim_time:=true',
                  '-p', 'publish_rate:=0.0')
    probe = Probe(domain)
    stamps: list[int] = []
    try:
        probe.node.create_subscription(JointState, '/joint_states',
                                       lambda m: stamps.append(_ns(m.header.stamp)), 100)
        probe.wait_for(lambda: stamps and max(stamps) >= 0.3e9, 30.0,
                       'joint states stamped >= 0.3 s (the node stepping)', node)
        assert 'ignores use_sim_time for its own pacing' in node.output()
        assert node.stop(signal.SIGINT) == 0, node.output()[-3000:]
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)


@pytest.mark.slow
def test_misspelt_and_overridden_parameters_are_reported(tmp_path):
    """-p real_time_factr:=0.5 (typo) is warned about, naming the closest parameter; a
    --params-file whose record: "" overrides -p record:=<bag> says recording is off."""
    repo = Path(__file__).resolve().parents[1]
    bag = tmp_path / 'bag'
    node = _start(tmp_path, next_domain_id(), 'typo', '-p', 'scene:=hinge',
                  '-p', 'real_time_factr:=0.5', '-p', f'record:={bag}',
                  '--params-file', str(repo / 'config' / 'sim.yaml'), '-p', 'start_paused:=true')
    try:
        end = time.monotonic() + 30.0
        while time.monotonic() < end and 'real-time factor' not in node.output():
            time.sleep(0.1)
        out = node.output()
        assert ("parameter 'real_time_factr' is not a parameter of this node and is ignored "
                "(did you mean 'real_time_factor'?)") in out, out[-3000:]
        assert "parameter 'record' is given more than once" in out, out[-3000:]
        assert f"-p record:={bag}" in out and "in effect: '' -> recording is OFF" in out, out[-3000:]
        assert 'recording off' in out and not bag.exists()
        assert node.stop(signal.SIGINT) == 0
    finally:
        if node.alive():
            node.stop(signal.SIGKILL)


def _refused_at_start(tmp_path, name, *args) -> str:
    """Start sim_node with `args`, which it must refuse: exit 1, no traceback; its output."""
    node = _start(tmp_path, next_domain_id(), name, *args)
    try:
        node.proc.wait(60)
    finally:
        if node.alive():
            node.stop(signal.SIGKILL)
    out = node.output()
    assert node.proc.returncode == 1 and 'Traceback' not in out, out[-3000:]
    return out


@pytest.mark.parametrize('name,value', [('publish_rate', '1e-300'), ('time_step', '1e-300'),
                                        ('real_time_factor', '1e300')])
def test_absurd_start_parameter_is_one_line_exit_1(tmp_path, name, value):
    out = _refused_at_start(tmp_path, 'absurd', '-p', 'scene:=hinge', '-p', f'{name}:={value}')
    assert f"cannot start: parameter '{name}': {float(value)!r} is outside the supported range" in out, out


@pytest.mark.parametrize('arg,expected', [
    ('frame_id:=5', "cannot start: parameter 'frame_id': expected a string, got 5 (-p values are "
                    "parsed as YAML: quote a string that looks like a number or a boolean, "
                    "-p frame_id:=\"'5'\")"),
    ('start_paused:=yes_please', "cannot start: parameter 'start_paused': expected true or false, "
                                 "got 'yes_please'"),
])
def test_start_parameter_of_the_wrong_type_is_one_line_exit_1(tmp_path, arg, expected):
    """A string or bool parameter given another YAML type (a bag named 2024, `yes` for a
    bool) was rclpy's InvalidParameterTypeException traceback."""
    out = _refused_at_start(tmp_path, 'wrongtype', '-p', 'scene:=hinge', '-p', arg)
    assert expected in out, out


def test_unknown_scene_name_lists_packaged_scenes(tmp_path):
    out = _refused_at_start(tmp_path, 'hinj', '-p', 'scene:=hinj')
    assert ("cannot start: parameter 'scene': 'hinj' is no packaged scene (did you mean "
            "'hinge'? packaged: default, free_pair, hinge") in out, out


def test_live_absurd_publish_rate_refused_node_lives(hinge):
    hinge.restart()
    for value in (5e-300, 1e-300, 1e300):
        result = hinge.set_parameter('publish_rate', value)
        assert not result.successful and 'outside the supported range' in result.reason, result
    hinge.call('step')
    hinge.probe.wait_for(lambda: hinge.states, 10.0, 'a state after ~/step', hinge.node)
    assert hinge.node.alive()


@pytest.mark.slow
def test_recorded_bytes_are_what_dds_delivers_for_empty_sequences(tmp_path):
    """Who is right about empty sequences: a scene without joints publishes JointState with
    empty float64[] sequences. What DDS delivers (and so what `ros2 bag record` stores) is
    the CDR stream, 36 bytes here; rclpy's serialize_message returns 8 more. The node's bag
    must hold the DDS length, and rosbags must decode it."""
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState
    scene = tmp_path / 'lone.yaml'
    scene.write_text('name: lone\ndt: 0.01\nbodies:\n'
                     '  - {name: cube, box: [0.2, 0.2, 0.2], density: 1000.0}\n')
    bag = tmp_path / 'lone_bag'
    domain = next_domain_id()
    node = NodeProcess.sim_node(tmp_path, domain, {'scene': str(scene), 'record': str(bag)})
    probe = Probe(domain)
    raw: list[bytes] = []
    try:
        probe.node.create_subscription(JointState, '/joint_states', raw.append, 10, raw=True)
        probe.wait_for(lambda: len(raw) >= 3, 30.0, 'raw joint states', node)
        assert node.stop(signal.SIGINT) == 0, node.output()[-3000:]
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)
    msg = deserialize_message(raw[0], JointState)
    assert list(msg.name) == [] and list(msg.position) == []
    assert len(serialize_message(msg)) == len(raw[0]) + 8      # rclpy's slack exists
    from mcap.reader import make_reader
    with open(next(bag.glob('*.mcap')), 'rb') as f:
        reader = make_reader(f)
        lengths = {len(m.data) for _s, ch, m in reader.iter_messages()
                   if ch.topic == '/joint_states'}
    assert lengths == {len(raw[0])}, (lengths, len(raw[0]))
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        n = sum(1 for c, _t, data in reader.messages() if reader.deserialize(data, c.msgtype))
    assert n > 3


_SIGNAL_WHILE_LOCKED = r'''
import signal, sys, time
import rclpy
from abd_joint_sim.ros import node as sim
rclpy.init()
ctx = rclpy.get_default_context()
# The signal lands while the main thread is inside Context.ok(), i.e. holding the context's
# non-reentrant lock (the node calls ok() between steps): the handler must not need it.
with ctx._lock:
    sim._shutdown_on_signal(signal.SIGTERM, None)
print('handler returned', flush=True)
n = sim.SimNode()
t0 = time.monotonic()
rclpy.spin(n)                       # the node's next timer shuts the context down
print(f'spin returned after {time.monotonic() - t0:.2f} s', flush=True)
n.close()
n.destroy_node()
rclpy.try_shutdown()
'''


@pytest.mark.slow
def test_stop_signal_while_the_context_lock_is_held_does_not_hang(tmp_path):
    """SIGINT/SIGTERM only note the signal; a handler that shut the context down itself
    deadlocked when the signal arrived inside Context.ok() (seen as a node that ignored
    SIGTERM for 15 s under load). The node's timers then end spin() promptly."""
    import subprocess
    import sys
    from conftest import ros_env
    log_dir = tmp_path / 'log'
    log_dir.mkdir()
    res = subprocess.run([sys.executable, '-c', _SIGNAL_WHILE_LOCKED], capture_output=True,
                         text=True, timeout=60, env=ros_env(next_domain_id(), log_dir),
                         stdin=subprocess.DEVNULL)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    assert 'handler returned' in res.stdout and 'spin returned after' in res.stdout, res.stdout
    waited = float(res.stdout.split('spin returned after ')[1].split(' s')[0])
    assert waited < 5.0, res.stdout
