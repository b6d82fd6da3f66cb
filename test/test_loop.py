"""The one simulation loop (abd_joint_sim/ros/loop.py) of sim_node and the headless tools,
and the one topic table (abd_joint_sim/ros/topics.py).

* Batching: with commands pending and a command timeout set, the loop still takes clean
  steps in batches (World.step(n, trajectory)), and every state is bit-identical to an independent
  loop written here with World.step one step at a time (commands at their boundaries, the
  timeout at the first boundary at or after it expires).
* The diagnostics key set exists once: the node's and the headless recorder's /diagnostics
  carry exactly DIAGNOSTIC_KEYS.
* The topic table is what the node creates (publishers, subscriptions, QoS) and what the bag
  registers (docs/topics.md is checked against it by test_docs_tables.py).
"""
from __future__ import annotations

from pathlib import Path
import time

import pytest

from abd_joint_sim import Scene, World
from abd_joint_sim.ros import convert
from abd_joint_sim.ros.loop import DIAGNOSTIC_KEYS, LoopOutput
from abd_joint_sim.ros.params import config_from_values, resolve_scene
from abd_joint_sim.ros.topics import BEST_EFFORT, TOPICS
from abd_joint_sim.tools.schedule import Command, Plan, Segment

ROOT = Path(__file__).resolve().parents[1]
MS = 1_000_000


class Collect(LoopOutput):
    """Every step's state as the loop hands it over (batched: no world access)."""

    every_state = True

    def __init__(self):
        self.states: dict[int, tuple] = {}

    def joint_state(self, t_ns, position, velocity, effort):
        self.states[t_ns] = (list(position), list(velocity), list(effort))


def _plan() -> Plan:
    """Torques on both joints of the default scene at odd times, an array command, a
    disable and re-enable, a timeout of 37 ms that fires between commands."""
    return Plan([Segment([
        Command(0, 'torque', 'shoulder', 2.0),
        Command(13 * MS, 'torque', 'elbow', -1.5),
        Command(80 * MS, 'array', None, [1.0, 0.5]),
        Command(150 * MS, 'enable', 'elbow', False),
        Command(171 * MS, 'torque', 'elbow', 3.0),
        Command(200 * MS, 'enable', 'elbow', True),
    ], 300 * MS)])


def _reference(scene, timeout: float) -> dict[int, tuple]:
    """The same plan, written independently: World.step one step at a time; at each step
    boundary the commands due, then the timeout (a joint whose last torque took effect at
    t_cmd gets 0 at the first boundary with t - t_cmd >= timeout)."""
    world = World(scene)
    events = {0: [('torque', 'shoulder', 2.0)], 13: [('torque', 'elbow', -1.5)],
              80: [('torque', 'shoulder', 1.0), ('torque', 'elbow', 0.5)],
              150: [('enable', 'elbow', False)], 171: [('torque', 'elbow', 3.0)],
              200: [('enable', 'elbow', True)]}
    last: dict[str, float] = {}
    done: set[str] = set()
    out = {0: (world.joint_angles().tolist(), world.joint_velocities().tolist(),
               world.applied_torques().tolist())}
    for k in range(300):
        now = world.time
        for kind, joint, value in events.get(k, []):
            if kind == 'torque':
                world.set_torque(joint, value)
                last[joint] = now
                done.discard(joint)
            else:
                world.set_torque_enabled(joint, value)
        for joint, t_cmd in last.items():
            if joint not in done and now - t_cmd >= timeout - 1e-9:
                done.add(joint)
                world.set_torque(joint, 0.0)
        world.step()
        out[round(world.time * 1e9)] = (world.joint_angles().tolist(),
                                        world.joint_velocities().tolist(),
                                        world.applied_torques().tolist())
    return out


@pytest.mark.slow
def test_batches_with_pending_commands_and_timeout_are_bit_identical():
    from abd_joint_sim.tools.sim import HeadlessSim
    scene = Scene.from_yaml(resolve_scene('default'))
    sim = HeadlessSim(scene, config_from_values({'scene': 'default',
                                                 'command_timeout': 0.037}))
    calls = []
    real_step = sim.world.step

    def counting_step(n=1, trajectory=None):
        result = real_step(n, trajectory)
        if trajectory is not None:
            calls.append((n, trajectory.count))
        return result
    sim.world.step = counting_step
    out = Collect()
    sim.run(_plan(), out)
    ref = _reference(scene, 0.037)
    assert sorted(out.states) == sorted(ref)
    for t_ns, state in ref.items():
        assert out.states[t_ns] == state, f't={t_ns} ns differs'   # bit-identical
    # Batched although a command timeout is set and commands come every few ms.
    batched = sum(count for _, count in calls)
    print(f'\n{batched} of {sim.steps} steps in {len(calls)} batches')
    assert batched > 200 and max(count for _, count in calls) >= 10
    # The timeout took the shoulder's torque to 0 at the first boundary >= 37 ms (after 2 N m
    # at t=0), while the elbow's (13 ms) lasted to 50 ms.
    effort = {t: s[2] for t, s in out.states.items()}
    assert effort[37 * MS][0] == 2.0 and effort[38 * MS][0] == 0.0
    assert effort[50 * MS][1] == -1.5 and effort[51 * MS][1] == 0.0


def test_reference_loop_can_tell_a_late_timeout():
    """The comparison above can fail: a timeout one step late gives other states."""
    scene = Scene.from_yaml(resolve_scene('default'))
    a, b = _reference(scene, 0.037), _reference(scene, 0.038)
    assert a[60 * MS] != b[60 * MS]


def test_node_loop_batches_while_commands_are_pending():
    """The loop as the node drives it (advance(n) per timer round, a command arriving
    between rounds): batches of more than one step, states equal to single steps."""
    from abd_joint_sim.ros.loop import SimLoop
    scene = Scene.from_yaml(resolve_scene('default'))
    results = []
    for batch in (16, 1):
        config = config_from_values({'scene': 'default', 'command_timeout': 0.01,
                                     'publish_rate': 0.0})
        out = Collect()
        loop = SimLoop(scene, config, output=out)
        takes = []

        def counting(n=1, trajectory=None, real=loop.world.step):
            result = real(n, trajectory)
            if trajectory is not None:
                takes.append(trajectory.count)
            return result
        loop.world.step = counting
        for round_ in range(20):
            if round_ % 4 != 3:         # every 4th round no command: the timeout fires
                loop.commands.command_torque('shoulder', 10.0 * (round_ % 3) - 5.0)
            if batch == 1:
                for _ in range(16):
                    loop.step_once()
            else:
                assert loop.advance(batch) == 16
        results.append(out.states)
        if batch == 16:
            assert max(takes) >= 8, takes
    assert len(results[0]) == 320 and results[0] == results[1]


def test_diagnostics_keys_once(tmp_path):
    """The headless recorder's /diagnostics carries exactly DIAGNOSTIC_KEYS (the node's is
    checked in test_diagnostic_keys_of_the_node below)."""
    from abd_joint_sim.record import read_messages
    from abd_joint_sim.tools.sim import BagRecorder, HeadlessSim
    scene_path = resolve_scene('hinge')
    scene = Scene.from_yaml(scene_path)
    sim = HeadlessSim(scene, config_from_values({'scene': 'hinge'}))
    rec = BagRecorder(str(tmp_path / 'bag'), sim, scene_path, scene.source_text)
    sim.run(Plan([Segment([], 2100 * MS)]), rec)
    rec.close()
    diags = [(t, m) for topic, _, t, m in read_messages(tmp_path / 'bag')
             if topic == '/diagnostics']
    assert [t for t, _ in diags] == [1000 * MS, 2000 * MS]
    for _, msg in diags:
        assert tuple(kv.key for kv in msg.status[0].values) == DIAGNOSTIC_KEYS


# ------------------------------------------------------------------- topic table ----
def test_bag_registers_the_table():
    from abd_joint_sim.ros.recording import add_node_topics, resolve_root

    class Writer:
        def __init__(self):
            self.topics = {}

        def add_topic(self, name, msg_type, qos='reliable', depth=10):
            self.topics[name] = (msg_type, qos, depth)
    w = Writer()
    add_node_topics(w, resolve_root, ['a', 'b'], markers=True)
    expected = {}
    for t in TOPICS:
        for name in ([t.name.format(joint=j) for j in 'ab'] if '{joint}' in t.name
                     else [t.name]):
            expected[resolve_root(name)] = (t.type, t.reliability, t.depth)
    assert w.topics == expected


def test_node_creates_the_table(domain_id):
    """A live node's publishers and subscriptions: names, types and QoS as in the table;
    and its /diagnostics values are DIAGNOSTIC_KEYS."""
    import rclpy
    from rclpy.parameter import Parameter
    from abd_joint_sim.ros.node import SimNode
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = SimNode(context=context, parameter_overrides=[
        Parameter('scene', value='default'), Parameter('start_paused', value=True)])
    try:
        ours = {}
        for pub in node.publishers:
            ours[pub.topic_name] = ('out', pub.qos_profile)
        for sub in node.subscriptions:
            ours[sub.topic_name] = ('in', sub.qos_profile)
        expected = set()
        for t in TOPICS:
            names = ([t.name.format(joint=j) for j in node.actuated] if '{joint}' in t.name
                     else [t.name])
            for name in names:
                full = node.resolve_topic_name(name)
                expected.add(full)
                direction, qos = ours[full]
                assert direction == t.direction, full
                assert qos.depth == t.depth, full
                assert (qos.reliability.name == 'BEST_EFFORT') == (t.reliability == BEST_EFFORT)
        # Nothing beyond the table but rclpy's own /rosout.
        assert set(ours) - expected <= {'/rosout'}
        node._publish_diagnostics()
        msg = node.loop.diagnostics_msg(0, 'x', real_time_factor_requested=1.0,
                                        real_time_factor_achieved=0.0, recording=False)
        assert tuple(kv.key for kv in msg.status[0].values) == DIAGNOSTIC_KEYS
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize('module', ['abd_joint_sim/ros/node.py', 'abd_joint_sim/tools/sim.py'])
def test_no_second_diagnostics_key_list(module):
    """The key set is written in ros/loop.py only."""
    text = (ROOT / module).read_text()
    assert "'not_converged_steps_total'" not in text and "'max_joint_separation'" not in text


class Record(LoopOutput):
    """Everything the loop hands over, in order, as the node gets it: /clock every step, the
    joint state at publish_rate, the markers as CDR bytes (wanted, as while recording)."""

    markers_wanted = True
    markers_serialized = True

    def __init__(self):
        self.events: list[tuple] = []

    def clock(self, t_ns):
        self.events.append(('clock', t_ns))

    def joint_state(self, t_ns, position, velocity, effort):
        self.events.append(('joint_state', t_ns, list(position), list(velocity), list(effort)))

    def markers(self, t_ns, data):
        self.events.append(('markers', t_ns, bytes(data)))


@pytest.mark.parametrize('scene_name', ['default', 'demo_arm'])
def test_batched_publishing_is_what_single_steps_publish(scene_name):
    """The loop's batched path (the node as fast as possible: advance(64) in one compiled
    batch, the markers built from the batch's states, the Trajectory's q) hands over exactly
    the events of one step at a time: every /clock, the joint states at 100 Hz (the default
    publish_rate) and the 30 Hz markers with the same stamps, values and bytes, in the same
    order."""
    from abd_joint_sim.ros.loop import SimLoop
    path = resolve_scene(scene_name)
    scene = Scene.from_file(path)
    runs = []
    for batched in (True, False):
        out = Record()
        loop = SimLoop(scene, config_from_values({'scene': scene_name}), output=out)
        loop.publish_state(force=True)
        takes = []
        real = loop.world.step

        def counting(n=1, trajectory=None, real=real):
            if trajectory is not None:
                takes.append(n)
            return real(n, trajectory)
        loop.world.step = counting
        for round_ in range(6):
            loop.commands.command_array([1.5 * (-1) ** round_] * len(loop.commands.order))
            if batched:
                assert loop.advance(64) == 64
            else:
                for _ in range(64):
                    assert loop.step_once()
        runs.append(out.events)
        assert (min(takes) == 64) if batched else not takes     # no batch ends at a marker
    kinds = [e[0] for e in runs[0]]
    assert kinds.count('clock') == 6 * 64 + 1 and kinds.count('markers') >= 12
    assert kinds.count('joint_state') >= 38
    assert runs[0] == runs[1]


def test_node_publishes_every_clock_of_a_batch_once_someone_subscribes(domain_id):
    """As fast as possible the node publishes a batch's clock-only steps only when a /clock
    subscriber is matched as the batch begins (real DDS: the count comes from the middleware).
    Counted at the node's publish call: with a subscriber, one /clock per step; without, none
    in the batches, one for a single step (~/step)."""
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from abd_joint_sim.ros.node import SimNode
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = SimNode(context=context, parameter_overrides=[
        Parameter('scene', value='default'), Parameter('start_paused', value=True)])
    listener = None
    try:
        sent = []
        raw = node.clock_publish_raw
        node.clock_publish_raw = lambda data: sent.append(data) or raw(data)
        node.paused = False
        published = []
        for subscribed in (False, True):
            if subscribed:
                listener = rclpy.create_node('clock_listener', context=context)
                listener.create_subscription(
                    Clock, '/clock', lambda m: None,
                    QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
                deadline = time.monotonic() + 10.0
                while node.clock_pub.get_subscription_count() == 0:
                    assert time.monotonic() < deadline, 'the subscriber never matched'
                    time.sleep(0.01)
            sent.clear()
            first = convert.seconds_to_ns(node.world.time + node.world.dt)
            assert node._advance(200) == 200
            published.append((len(sent), sent[:1], sent[-1:], first,
                              convert.seconds_to_ns(node.world.time)))
        (without, *_), (with_, first_sent, last_sent, first, last) = published
        assert without == 0 and with_ == 200
        sent.clear()
        listener.destroy_node()
        listener = None
        deadline = time.monotonic() + 10.0
        while node.clock_pub.get_subscription_count():
            assert time.monotonic() < deadline, 'the subscriber never went away'
            time.sleep(0.01)
        node.paused = True
        assert node._step_once(force_publish=True) and len(sent) == 1
        assert (first_sent, last_sent) == ([node.clock_encoder.encode(first)],
                                           [node.clock_encoder.encode(last)])
    finally:
        if listener is not None:
            listener.destroy_node()
        node.close()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_as_fast_as_possible_batches_follow_the_measured_step_time():
    """As fast as possible the node takes about a quarter of its AFAP_BATCH_WALL round per
    compiled call: a small scene up to AFAP_BATCH_STEPS steps, a large one few enough to hand
    the executor back in time, one step before any was measured."""
    from types import SimpleNamespace
    from abd_joint_sim.ros import node as node_module
    steps = node_module.SimNode._afap_steps
    round_ = node_module.AFAP_BATCH_WALL
    assert steps(SimpleNamespace(_wall_per_step=0.0)) == 1
    assert steps(SimpleNamespace(_wall_per_step=1e-6)) == node_module.AFAP_BATCH_STEPS
    assert steps(SimpleNamespace(_wall_per_step=round_ / 40)) == 10
    assert steps(SimpleNamespace(_wall_per_step=2e-3)) * 2e-3 <= 0.25 * round_
    assert steps(SimpleNamespace(_wall_per_step=1.0)) == 1


def test_stepping_thread_paces_real_time_and_stops_with_pause_and_close(domain_id):
    """sim_node's stepping thread (what `main` starts): in real time it steps about as many
    steps as wall time allows, none while paused, and `close` ends it; a command published
    while it runs takes effect (the callbacks share its lock)."""
    import rclpy
    from rclpy.parameter import Parameter
    from std_srvs.srv import Trigger
    from abd_joint_sim.ros.node import SimNode
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = SimNode(context=context, parameter_overrides=[
        Parameter('scene', value='default'), Parameter('real_time_factor', value=1.0)])
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def spin_for(seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.01)
    try:
        node.start_stepping_thread()
        stepper = node._stepper
        assert stepper is not None and stepper.is_alive()
        steps0, t0 = node.steps, time.monotonic()
        spin_for(0.5)
        taken, wall = node.steps - steps0, time.monotonic() - t0
        assert 0.5 * wall / node.world.dt < taken <= wall / node.world.dt + 2, (taken, wall)
        with node._lock:
            node.commands.command_array([3.0, -1.0])
        spin_for(0.05)
        assert list(node.world.applied_torques()) == [3.0, -1.0]
        node._srv_pause(Trigger.Request(), Trigger.Response())
        paused_at = node.steps
        spin_for(0.2)
        assert node.steps == paused_at
        node._srv_unpause(Trigger.Request(), Trigger.Response())
        spin_for(0.2)
        assert node.steps > paused_at
    finally:
        node.close()
        assert node._stepper is None or not node._stepper.is_alive()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_a_prismatic_joint_is_published_in_m_and_n_and_commanded_by_force():
    """/joint_states carries a sliding joint's distance [m], rate [m/s] and applied force [N];
    a joint_commands effort on it is a force (clamped to its effort_limit in N); beside it a
    revolute joint keeps rad and N m."""
    from abd_joint_sim.ros.loop import SimLoop
    cube = dict(box=[0.4, 0.4, 0.4], density=1000.0)      # 64 kg
    scene = Scene.from_dict(dict(dt=0.01, bodies=[
        dict(name='base', position=[0, 0, 0], fixed=True, **cube),
        dict(name='cart', position=[0.6, 0, 0], **cube),
        dict(name='arm', position=[0.6, 0, 0.6], **cube)], joints=[
        dict(name='rail', type='prismatic', parent='base', child='cart', p0=[0.3, 0, 0], p1=[1.3, 0, 0],
             external_force=dict(enabled=True, effort_limit=64.0)),
        dict(name='hinge', parent='cart', child='arm', p0=[0.4, 0, 0.4], p1=[0.8, 0, 0.4],   # along the rail
             external_torque=dict(enabled=True))]))
    out = Collect()
    loop = SimLoop(scene, config_from_values({'scene': 'default', 'publish_rate': 0.0}), output=out)
    # the actuated joints: those with a torque, then those with a force
    assert loop.world.actuated_joint_names == ('hinge', 'rail')
    assert loop.world.effort_limits.tolist() == [float('inf'), 64.0]
    loop.commands.command_torque('rail', 100.0)           # clamped to 64 N
    for _ in range(20):
        loop.step_once()
    t_ns = max(out.states)
    position, velocity, effort = out.states[t_ns]
    assert effort == [64.0, 0.0]
    # 64 N on 128 kg (the arm rides on the cart): d = ½ a t² (+ BDF1's ½ a h t)
    t, h = t_ns * 1e-9, loop.world.dt
    assert position[0] == pytest.approx(0.5 * 0.5 * t * t + 0.5 * 0.5 * h * t, rel=2e-2)
    assert velocity[0] == pytest.approx(0.5 * t, rel=2e-2)


def test_a_disabled_prismatic_force_is_warned_in_newtons():
    from abd_joint_sim.ros.loop import SimLoop

    class Logged(Collect):
        def __init__(self):
            super().__init__()
            self.lines = []

        def log(self, level, text, key=None):
            self.lines.append((level, text))
    cube = dict(box=[0.4, 0.4, 0.4], density=1000.0)
    scene = Scene.from_dict(dict(dt=0.01, bodies=[
        dict(name='base', position=[0, 0, 0], fixed=True, **cube), dict(name='cart', position=[0.6, 0, 0], **cube)],
        joints=[dict(name='rail', type='prismatic', parent='base', child='cart', p0=[0.3, 0, 0], p1=[1.3, 0, 0],
                     external_force=dict(enabled=False))]))
    out = Logged()
    loop = SimLoop(scene, config_from_values({'scene': 'default', 'publish_rate': 0.0}), output=out)
    loop.commands.command_torque('rail', 5.0)
    loop.step_once()
    assert any(level == 'warn' and "joint 'rail': force 5 N stored but the force is disabled" in text
               for level, text in out.lines), out.lines
