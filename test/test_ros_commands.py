"""CommandBuffer, parameter table and message conversion: plain Python, no DDS."""
import math

import pytest

from abd_joint_sim.ros import convert
from abd_joint_sim.ros.commands import CommandBuffer
from abd_joint_sim.ros.params import (check_live_value, coerce, config_from_values, PARAMS,
                                      resolve_scene)


class FakeWorld:
    def __init__(self, names):
        self.time = 0.0
        self.torque = {n: 0.0 for n in names}
        self.enabled = {n: True for n in names}
        self.calls = []

    def set_effort(self, joint, value):
        self.calls.append(('torque', joint, value))
        self.torque[joint] = value

    def set_effort_enabled(self, joint, flag):
        self.calls.append(('enable', joint, flag))
        self.enabled[joint] = flag


def make(order=(), limits=(), timeout=0.0):
    return CommandBuffer(['shoulder', 'elbow'], list(order), list(limits), timeout)


def test_pending_until_apply_and_latest_wins():
    buf, world = make(), FakeWorld(['shoulder', 'elbow'])
    buf.command_torque('shoulder', 1.0)
    buf.command_torque('shoulder', 2.0)
    assert world.calls == []          # nothing reaches the world before the step boundary
    applied = buf.apply(world)
    assert world.torque == {'shoulder': 2.0, 'elbow': 0.0}
    assert applied.torques == {'shoulder': 2.0} and applied.sources == {'shoulder': 'joint'}
    assert not buf.apply(world)       # nothing pending any more


def test_array_order_length_and_nonfinite():
    buf, world = make(order=['elbow', 'shoulder']), FakeWorld(['shoulder', 'elbow'])
    rej, _ = buf.command_array([1.0, 2.0, 3.0])
    assert len(rej) == 1 and 'expected 2 values' in str(rej[0])
    rej, _ = buf.command_array([1.0, math.nan])
    assert rej and 'shoulder' in str(rej[0]) and 'nan' in str(rej[0])
    assert buf.idle        # rejected as a whole
    assert buf.command_array([1.0, 2.0]) == ([], [])
    applied = buf.apply(world)
    assert world.torque == {'shoulder': 2.0, 'elbow': 1.0}
    assert applied.array == [1.0, 2.0]


def test_per_joint_after_array_wins():
    buf, world = make(), FakeWorld(['shoulder', 'elbow'])
    buf.command_array([1.0, 2.0])
    buf.command_torque('elbow', 5.0)
    applied = buf.apply(world)
    assert world.torque == {'shoulder': 1.0, 'elbow': 5.0}
    assert applied.sources == {'shoulder': 'array', 'elbow': 'joint'}


def test_rejects_unknown_and_nonfinite_joint_commands():
    buf = make()
    rej, _ = buf.command_torque('wrist', 1.0)
    assert rej and 'wrist' in str(rej[0]) and 'not an actuated joint' in str(rej[0])
    rej, _ = buf.command_torque('elbow', math.inf)
    assert rej and "'elbow'" in str(rej[0]) and 'inf' in str(rej[0])
    assert buf.command_enable('wrist', True)
    assert buf.idle


def test_effort_limits_clamp_and_say_so():
    buf, world = make(limits=[2.0, 3.0]), FakeWorld(['shoulder', 'elbow'])
    rej, clamps = buf.command_array([5.0, -10.0])
    assert rej == [] and len(clamps) == 2
    assert 'clamped to -3' in str(clamps[1])
    buf.apply(world)
    assert world.torque == {'shoulder': 2.0, 'elbow': -3.0}
    with pytest.raises(ValueError, match='effort_limits'):
        make(limits=[1.0])
    with pytest.raises(ValueError, match='effort_limits'):
        make(limits=[1.0, 0.0])


def test_enable_all_then_per_joint():
    buf, world = make(), FakeWorld(['shoulder', 'elbow'])
    buf.command_enable_all(False)
    buf.command_enable('elbow', True)
    applied = buf.apply(world)
    assert world.enabled == {'shoulder': False, 'elbow': True}
    assert applied.enable_all is False


def test_command_timeout_in_simulated_time():
    buf, world = make(timeout=0.5), FakeWorld(['shoulder', 'elbow'])
    buf.command_torque('shoulder', 3.0)
    buf.apply(world)
    world.time = 0.49
    assert not buf.apply(world).timed_out
    world.time = 0.5
    assert buf.apply(world).timed_out == ['shoulder']
    assert world.torque['shoulder'] == 0.0
    world.time = 0.7
    assert not buf.apply(world).timed_out   # reported once
    buf.command_torque('shoulder', 1.0)      # a new command restarts it
    buf.apply(world)
    assert world.torque['shoulder'] == 1.0
    world.time = 1.2
    assert buf.apply(world).timed_out == ['shoulder']


def test_timeout_off_and_bad_joint_order():
    buf, world = make(), FakeWorld(['shoulder', 'elbow'])
    buf.command_torque('shoulder', 3.0)
    buf.apply(world)
    world.time = 100.0
    assert not buf.apply(world) and world.torque['shoulder'] == 3.0
    with pytest.raises(ValueError, match='not actuated'):
        make(order=['wrist'])
    with pytest.raises(ValueError, match='duplicate'):
        make(order=['elbow', 'elbow'])


def test_parameter_table_and_coercion():
    names = [p.name for p in PARAMS]
    for needed in ('scene', 'time_step', 'real_time_factor', 'publish_rate', 'start_paused',
                   'command_timeout', 'effort_limits', 'joints', 'record', 'frame_id'):
        assert needed in names
    assert all(p.description for p in PARAMS)
    cfg = config_from_values({'real_time_factor': 0, 'effort_limits': [3, 4.5],
                              'joints': None, 'scene': ''})
    assert cfg.real_time_factor == 0.0 and isinstance(cfg.real_time_factor, float)
    assert cfg.effort_limits == [3.0, 4.5] and cfg.joints == []
    assert cfg.scene.endswith('default.yaml')
    assert resolve_scene('hinge').endswith('scenes/hinge.yaml')
    with pytest.raises(ValueError, match="'publish_rate'"):
        coerce('publish_rate', -1.0)
    with pytest.raises(ValueError, match="'real_time_factor'"):
        coerce('real_time_factor', 'fast')
    assert check_live_value('scene', 'x.yaml') and 'read-only' in check_live_value('scene', 'x')
    assert check_live_value('real_time_factor', 2.0) is None
    assert 'needs 2 values' in check_live_value('effort_limits', [1.0], n_joints=2)
    assert check_live_value('use_sim_time', True) is None


def test_convert_messages():
    msg = convert.joint_state_msg(1_500_000_000, ['a', 'b'], [0.1, 0.2], [1.0, 2.0],
                                  [0.0, 3.0], 'base')
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_000)
    assert len(msg.name) == len(msg.position) == len(msg.velocity) == len(msg.effort) == 2
    with pytest.raises(ValueError, match='differ in length'):
        convert.joint_state_msg(0, ['a'], [0.1, 0.2], [1.0], [0.0])
    assert convert.seconds_to_ns(0.1 * 3) == 300_000_000
    assert convert.time_msg_to_ns(convert.clock_msg(123456789012).clock) == 123456789012
    arr = convert.float64_array_msg([1.0, 2.0])
    assert convert.array_values(arr) == [1.0, 2.0]
    d = convert.diagnostics_msg(0, 'x', 'y', False, 'm', {'converged': False, 'it': 3})
    assert d.status[0].values[0].value == 'False'


def test_clock_encoder_gives_rclpys_bytes():
    """sim_node publishes /clock as bytes from convert.ClockEncoder: they must be exactly what
    rclpy.serialization makes of the same Clock, and deserialise to the same stamp."""
    from rclpy.serialization import deserialize_message, serialize_message
    from rosgraph_msgs.msg import Clock
    enc = convert.ClockEncoder()
    assert enc.checked
    stamps = [0, 1, 999_999_999, 1_000_000_000, 1_500_000_001, 86_400 * 10 ** 9 + 7,
              (2 ** 31 - 1) * 10 ** 9 + 999_999_999]
    stamps += [int(convert.seconds_to_ns(k * 1e-3)) for k in range(0, 5000, 7)]
    for ns in stamps:
        raw = enc.encode(ns)
        assert raw == serialize_message(convert.clock_msg(ns)), ns
        assert convert.time_msg_to_ns(deserialize_message(raw, Clock).clock) == ns
    # a batch's run of steps at once (sim_node's and the headless recorder's `clocks`)
    assert enc.encode_many(stamps) == [serialize_message(convert.clock_msg(ns)) for ns in stamps]
    with pytest.raises(Exception, match='format requires'):     # beyond int32 seconds
        enc.encode_many([0, 2 ** 31 * 10 ** 9])
    enc.checked = False                     # the fallback path: rclpy itself
    assert enc.encode(123) == serialize_message(convert.clock_msg(123))
    assert enc.encode_many([123, 4]) == [serialize_message(convert.clock_msg(ns))
                                         for ns in (123, 4)]


def test_joint_state_refill_matches_a_new_message():
    msg = convert.joint_state_msg(0, ['a', 'b'], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0])
    convert.fill_joint_state(msg, 2_250_000_000, [0.1, 0.2], [1.0, 2.0], [0.0, 3.0], 'base')
    assert msg == convert.joint_state_msg(2_250_000_000, ['a', 'b'], [0.1, 0.2], [1.0, 2.0],
                                          [0.0, 3.0], 'base')
    with pytest.raises(ValueError, match='differ in length'):
        convert.fill_joint_state(msg, 0, [0.1], [1.0, 2.0], [0.0, 3.0], '')


def test_scene_limits_combine_with_parameter_limits():
    buf = CommandBuffer(['shoulder', 'elbow'], [], [10.0, 10.0], 0.0,
                        scene_limits={'shoulder': 50.0, 'elbow': 5.0})
    assert buf.limits == {'shoulder': 10.0, 'elbow': 5.0}
    _, clamps = buf.command_torque('elbow', 7.0)
    assert clamps and clamps[0].applied == 5.0
    buf.set_effort_limits([])
    assert buf.limits == {'shoulder': 50.0, 'elbow': 5.0}


def test_absurd_torque_rejected_without_limit_clamped_with_one():
    from abd_joint_sim.ros.commands import MAX_ABS_TORQUE
    buf = make()
    rej, _ = buf.command_torque('shoulder', 2 * MAX_ABS_TORQUE)
    assert rej and 'beyond' in rej[0].reason and 'effort_limits' in rej[0].reason
    rej, _ = buf.command_array([1.0, -1e300])
    assert len(rej) == 1 and rej[0].joint == 'elbow' and 'whole array' in rej[0].reason
    assert buf.idle
    assert buf.command_torque('shoulder', MAX_ABS_TORQUE) == ([], [])
    limited = make(limits=[10.0, 5.0])
    rej, clamps = limited.command_torque('elbow', -1e300)
    assert rej == [] and clamps[0].applied == -5.0


def test_publish_schedule_and_parameter_events():
    from abd_joint_sim.ros.recording import (parameter_changes, parameter_event_msg,
                                             PublishSchedule)
    sched = PublishSchedule()
    due = [t for t in range(0, 100_000_000, 3_000_000) if sched.due(t, 100.0)]
    # 100 Hz on a 3 ms grid: the first step at or after each 10 ms grid point.
    assert due[:4] == [0, 12_000_000, 21_000_000, 30_000_000]
    assert sched.due(31_000_000, 100.0, force=True)
    assert all(sched.due(t, 0.0) for t in range(5))
    sched.restart()
    assert sched.due(1, 100.0)
    msg = parameter_event_msg(1_500_000_000, '/abd_joint_sim', {
        'command_timeout': 0.25, 'effort_limits': [1.0, 2.0], 'publish_rate': 50.0})
    assert msg.stamp.sec == 1 and msg.stamp.nanosec == 500_000_000
    assert parameter_changes(msg) == {'command_timeout': 0.25, 'effort_limits': [1.0, 2.0],
                                      'publish_rate': 50.0}
    empty = parameter_changes(parameter_event_msg(0, '/n', {'effort_limits': []}))
    assert coerce('effort_limits', empty['effort_limits']) == []


# -- parameter ranges and scene names -----------------------------------------------------
@pytest.mark.parametrize('name,value', [
    ('publish_rate', 1e-300), ('publish_rate', 5e-300), ('publish_rate', 1e300),
    ('real_time_factor', 1e-300), ('real_time_factor', 1e300),
    ('time_step', 1e-300), ('time_step', 10.0), ('command_timeout', 1e300),
])
def test_numeric_parameters_out_of_range_are_refused(name, value):
    with pytest.raises(ValueError, match=rf"parameter '{name}': .* is outside the supported range"):
        coerce(name, value)
    reason = check_live_value(name, value)
    if name in ('publish_rate', 'real_time_factor', 'command_timeout'):
        assert reason and 'outside the supported range' in reason
    assert coerce(name, 0) == 0.0          # 0 keeps its meaning (off / auto / every step)


def test_effort_limit_beyond_largest_torque_refused():
    with pytest.raises(ValueError, match=r"entry 1 is 1e\+300, beyond"):
        coerce('effort_limits', [1.0, 1e300])
    assert coerce('effort_limits', [1.0, 1e9]) == [1.0, 1e9]


def test_unknown_packaged_scene_lists_them_and_suggests():
    from abd_joint_sim.errors import SceneError
    with pytest.raises(SceneError) as err:
        resolve_scene('hinj')
    msg = str(err.value)
    assert "'hinj' is no packaged scene (did you mean 'hinge'?" in msg, msg
    assert 'default, free_pair, hinge' in msg, msg
    # Packaged scenes, then packaged URDF robots (demo_arm).
    with pytest.raises(SceneError, match=r'packaged: default, free_pair, hinge, demo_arm; or give'):
        resolve_scene('zzzz')
    with pytest.raises(SceneError):
        config_from_values({'scene': 'hinj'})


def test_parameter_source_conflicts_and_undeclared_names(tmp_path):
    from abd_joint_sim.ros.params import conflicting_parameter_sources, undeclared_parameters
    f = tmp_path / 'p.yaml'
    f.write_text('/**:\n  ros__parameters: {record: "", use_sim_time: true}\n'
                 'other_node:\n  ros__parameters: {publish_rate: 1.0}\n'
                 'abd_joint_sim:\n  ros__parameters: {publish_rate: 50.0}\n')
    argv = ['node', '--ros-args', '-p', 'record:=bag', '-p', 'publish_rate:=50.0',
            '--params-file', str(f), '-p', 'abd_joint_sim:scene:=hinge', '-p', 'x:frame_id:=f',
            '--', '-p', 'record:=ignored']
    got = conflicting_parameter_sources(argv, 'abd_joint_sim')
    assert got == {'record': [('-p record:=bag', 'bag'), (f'--params-file {f}', '')]}, got
    assert conflicting_parameter_sources(['node', '-p', 'a:=1', '-p', 'a:=2']) == {}
    assert undeclared_parameters(['real_time_factr', 'use_sim_time', 'scene',
                                  'qos_overrides./clock.publisher.depth']) == ['real_time_factr']
