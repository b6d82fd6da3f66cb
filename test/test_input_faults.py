"""Bad input gives one clear line naming what is wrong: URDF files, from_urdf options, joint
names the node cannot turn into topics, a parameter deletion (docs/robustness.md, "Input").
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import time
import warnings

import pytest

from abd_joint_sim import Scene
from abd_joint_sim.errors import SceneError
from abd_joint_sim.urdf import MAX_URDF_BYTES, read_urdf_source, resolve_package_uri, UrdfWarning

INERTIAL = ('<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" '
            'ixz="0" iyz="0"/></inertial>')
LIMIT = '<limit lower="-1" upper="1" effort="5" velocity="1"/>'


def link(name: str, inertial: str = INERTIAL) -> str:
    return f'<link name="{name}">{inertial}</link>'


def joint(name: str, parent: str, child: str, limit: str = LIMIT) -> str:
    return (f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child '
            f'link="{child}"/><axis xyz="0 0 1"/>{limit}</joint>')


def robot(*parts: str, name: str = 'r') -> str:
    return f'<robot name="{name}">{"".join(parts)}</robot>'


ARM = robot(link('root'), link('a'), joint('j0', 'root', 'a'))


def one_line_error(source, **options) -> str:
    with pytest.raises(SceneError) as err:
        Scene.from_urdf(source, **options)
    msg = str(err.value)
    assert '\n' not in msg and len(msg) < 600, msg
    return msg


# ----------------------------------------------------------------- URDF files ----
@pytest.mark.parametrize('text, expected', [
    (robot(link('root'), link('a'), link('b'), joint('j1', 'a', 'b'), joint('j2', 'b', 'a')),
     "the joints 'j1', 'j2' form a loop (b -> a -> b) not connected to the root link 'root'"),
    (robot(link('root'), link('a'), joint('j1', 'a', 'a')),
     "the joints 'j1' form a loop (a -> a) not connected to the root link 'root'"),
    (ARM.replace('effort="5"', 'effort="-5"'),
     "joint 'j0' <limit>: effort=\"-5\" is negative"),
    (ARM.replace('ixx="0.01"', 'ixx="1e308"', 1),
     "link 'root' <inertia>: ixx=\"1e+308\" is beyond the supported 1e+21 kg m^2"),
    (ARM.replace('<mass value="1"/>', '<mass value="1e308"/>', 1),
     "link 'root' <mass>: value=\"1e+308\" is beyond the supported 1e+15 kg"),
])
def test_bad_urdf_is_one_line_naming_the_place(text, expected):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        msg = one_line_error(text)
    assert expected in msg, msg
    assert not [w for w in caught if issubclass(w.category, UrdfWarning)], \
        'no bogus repair warning before the error'


def slide(name: str, parent: str, child: str, limit: str = LIMIT) -> str:
    return joint(name, parent, child, limit).replace('type="revolute"', 'type="prismatic"')


@pytest.mark.parametrize('kind', [joint, slide])
def test_a_urdf_limit_with_lower_above_upper_is_no_limit_and_said(kind):
    text = robot(link('root'), link('a'), kind('j0', 'root', 'a',
                                              LIMIT.replace('lower="-1" upper="1"',
                                                            'lower="1" upper="-1"')))
    with pytest.warns(UrdfWarning, match=r"lower > upper taken as no limit \(as PyBullet does\) "
                      r"on 1 joint\(s\): 'j0' \[1, -1\]"):
        scene = Scene.from_urdf(text)
    assert scene.joints[0].limit is None


def held_at(scene, joint_name='j0', steps=300) -> float:
    """The joint's position after `steps` steps pushed by 0.5 N m (or N)."""
    from abd_joint_sim.world import World
    world = World(scene)
    world.set_effort_enabled(joint_name, True)
    world.set_effort(joint_name, 0.5)
    world.step(steps)
    return float(world.joint_positions()[scene.joint_names.index(joint_name)])


@pytest.mark.parametrize('kind', [joint, slide])
@pytest.mark.parametrize('at', [0.0, 0.5])
def test_a_zero_width_limit_holds_the_joint_in_urdf_as_in_yaml(kind, at):
    """lower == upper is a zero-width limit in both formats: the joint is held at that
    position (a URDF says so in a warning); without the limit the same push moves it."""
    text = robot(link('root'), link('a'), kind('j0', 'root', 'a', LIMIT.replace(
        'lower="-1" upper="1"', f'lower="{at}" upper="{at}"').replace(' velocity="1"', '')))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        scene = Scene.from_urdf(text, gravity=[0, 0, 0])
    said = [str(w.message) for w in caught]
    held_line = (r"lower == upper holds the joint at that position .* on 1 joint\(s\): 'j0' "
                 rf"\[{at:g}, {at:g}\]; `joints: \{{name: \{{limit: false\}}\}}` frees it")
    # away from 0 the joint also starts where it is held, and says so
    start_line = rf"'j0': position 0 is outside its limit \[{at:g}, {at:g}\]: it starts at {at:g}"
    expected = [held_line] + ([start_line] if at else [])
    assert len(said) == len(expected) and all(
        any(re.search(e, m) for m in said) for e in expected), said
    lim = scene.joints[0].limit
    assert (lim.lower, lim.upper) == (at, at)
    held = abs(held_at(scene) - at)
    with warnings.catch_warnings():
        warnings.simplefilter('error', UrdfWarning)      # the override: nothing to say
        free = Scene.from_urdf(text, gravity=[0, 0, 0], joints={'j0': {'limit': False}})
    moved = abs(held_at(free))                   # from 0, the free joint's start
    print(f'\n{kind.__name__} at {at}: held within {held:.2e}, free moved {moved:.2e}')
    assert free.joints[0].limit is None and held < 0.05 * moved
    # an explicit start away from the held position is accepted, as in YAML
    with pytest.warns(UrdfWarning, match='lower == upper'):
        Scene.from_urdf(text, gravity=[0, 0, 0], initial_positions={'j0': at + 0.3})
    # the YAML scene of the same robot (its lowered scene) holds it the same way
    data = scene.to_dict()
    data['joints'][0][('init_angle' if kind is joint else 'init_distance')] = at + 0.3
    yaml_scene = Scene.from_dict(data)
    assert (yaml_scene.joints[0].limit.lower, yaml_scene.joints[0].limit.upper) == (at, at)
    pulled = abs(held_at(yaml_scene, steps=600) - at)
    print(f'YAML scene started 0.3 away: within {pulled:.2e} after 600 steps')
    assert pulled < 0.1 * 0.3


def test_a_urdf_limit_without_bounds_is_no_limit():
    """<limit effort velocity/> on a revolute joint: no limit, as PyBullet and MuJoCo load it."""
    text = ARM.replace('lower="-1" upper="1" ', '').replace(' velocity="1"', '')
    with warnings.catch_warnings():
        warnings.simplefilter('error', UrdfWarning)
        scene = Scene.from_urdf(text)
    assert scene.joints[0].limit is None
    assert scene.joints[0].external_torque.effort_limit == 5.0


@pytest.mark.parametrize('options, expected', [
    ({'lock': [['j0']]}, "robot.lock[0]: must be a joint name (a string), got ['j0']"),
    ({'actuated': [{'a': 1}]}, "robot.actuated[0]: must be a joint name (a string), got {'a': 1}"),
    ({'joints': {'j0': {'limit': {'lower': 'a', 'upper': 1.0}}}},
     "robot.joints.j0.limit.lower: must be a finite number, got 'a'"),
    ({'joints': {'j0': {'driving': {'aim_angle': [1]}}}},
     'robot.joints.j0.driving.aim_angle: must be a finite number, got [1]'),
    ({'initial_positions': {('j0',): 1.0}}, "robot.initial_positions: keys must be joint names"),
])
def test_bad_option_types_name_the_field(options, expected):
    assert expected in one_line_error(ARM, **options)


def test_a_yaml_robot_block_with_a_bad_option_type_names_the_field(tmp_path):
    (tmp_path / 'arm.urdf').write_text(ARM)
    scene = tmp_path / 'scene.yaml'
    scene.write_text('robot:\n  urdf: arm.urdf\n  lock: [[j0]]\n')
    with pytest.raises(SceneError, match=r'robot.lock\[0\]: must be a joint name'):
        Scene.from_file(str(scene))


def test_size_bounds_and_non_regular_files(tmp_path):
    big = tmp_path / 'big.urdf'
    with open(big, 'wb') as f:
        f.write(ARM[:-len('</robot>')].encode())
        f.write(b' ' * MAX_URDF_BYTES)
        f.write(b'</robot>')
    t0 = time.monotonic()
    assert 'URDF larger than 8388608 bytes' in one_line_error(str(big))
    assert 'URDF larger than' in one_line_error(big.read_text())
    assert time.monotonic() - t0 < 5.0
    assert 'not a regular file' in one_line_error('/dev/zero')
    assert 'not a regular file' in one_line_error(str(tmp_path))     # a directory
    fifo = tmp_path / 'fifo.urdf'
    os.mkfifo(fifo)
    assert 'not a regular file' in one_line_error(str(fifo))    # (no hang on open)
    many = robot(link('root'), *(link(f'l{k}', '') for k in range(70_000)))
    assert 'XML elements, more than the 200000' in one_line_error(many.replace(
        '<link name="l0"></link>', '<link name="l0">' + '<x/>' * 150_000 + '</link>'))


def visual_robot(links: int, visuals: int) -> str:
    """A chain of `links` links, each with `visuals` boxes (about 90 bytes each)."""
    vis = ''.join(f'<visual><origin xyz="{k * 1e-3:.4f} 0.01 0.02" rpy="0.1 0.2 0.3"/>'
                  '<geometry><box size="0.01 0.02 0.03"/></geometry></visual>'
                  for k in range(visuals))
    return robot(*(link(f'l{i}', INERTIAL + vis) for i in range(links)),
                 *(joint(f'j{i}', f'l{i - 1}', f'l{i}') for i in range(1, links)))


def test_a_large_robot_loads_in_time_proportional_to_its_size(tmp_path):
    """15 000 visuals (1.75 MB) cost per visual what 1 500 do; the scene's YAML text (the
    lowered scene a bag records, seconds to write for such a robot) is written only when
    asked for, and is then the lowered scene's `yaml.dump`."""
    import pickle
    import yaml
    from abd_joint_sim.scene import _DUMPER, _plain
    from abd_joint_sim.urdf import scene_data_from_urdf
    from abd_joint_sim.world import World
    files = {}
    for n in (30, 300):
        files[n] = tmp_path / f'r{n}.urdf'
        files[n].write_text(visual_robot(50, n))
    assert files[300].stat().st_size > 1_000_000

    def load(path):
        t0 = time.perf_counter()
        world = World(Scene.from_urdf(str(path)))
        return time.perf_counter() - t0, world
    load(files[30])                         # compiled kernels loaded once
    small = min(load(files[30])[0] for _ in range(3))
    big, world = load(files[300])
    world.step(2)
    per_visual = (big / 15_000) / (small / 1_500)
    print(f'\nload + World: 1500 visuals {small:.3f} s, 15000 visuals {big:.3f} s; '
          f'per visual x{per_visual:.2f}')
    assert per_visual <= 3.0
    assert not world.scene._text.written          # loading and stepping never wrote it
    scene = Scene.from_urdf(str(files[30]))
    sent = pickle.loads(pickle.dumps(scene))          # (a sweep's worker) the text unwritten
    data = scene_data_from_urdf(str(files[30]), {})[0]
    text = yaml.dump(_plain(data), Dumper=_DUMPER, sort_keys=False)
    assert not sent._text.written and sent.source_text == text
    assert scene.source_text == text and scene._text.written and scene == sent


def test_small_ones(tmp_path):
    # a 1 MB attribute is quoted by its first characters
    msg = one_line_error(ARM.replace('ixx="0.01"', 'ixx="' + '9' * 1_000_000 + 'x"', 1))
    assert 'more characters' in msg and len(msg) < 400
    # bytes that are not UTF-8: refused, naming the offset, never silently replaced
    raw = ARM.encode().replace(b'name="r"', b'name="\xff"')
    assert 'not utf-8 text (byte 0xff at offset 13' in one_line_error(raw)
    # a path with '<' in it is a path
    odd = tmp_path / 'a<b.urdf'
    odd.write_text(ARM)
    assert list(Scene.from_urdf(str(odd)).joint_names) == ['j0']
    # a declared encoding is honoured
    latin = tmp_path / 'latin.urdf'
    latin.write_bytes(('<?xml version="1.0" encoding="ISO-8859-1"?>\n'
                       + ARM.replace('name="r"', 'name="gelenk_\xe4"')).encode('latin-1'))
    text, _ = read_urdf_source(str(latin))
    assert 'gelenk_\xe4' in text
    assert list(Scene.from_urdf(str(latin)).joint_names) == ['j0']
    # package:// stays inside the package
    with pytest.raises(SceneError, match="leads outside the package 'abd_joint_sim'"):
        resolve_package_uri('package://abd_joint_sim/../../../etc/passwd', '.')
    assert resolve_package_uri('package://abd_joint_sim/robots/demo_arm.urdf', '.') \
        .endswith(os.path.join('robots', 'demo_arm.urdf'))


# --------------------------------------------------------------------- node ----
@pytest.fixture
def context(domain_id):
    import rclpy
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    yield ctx
    rclpy.shutdown(context=ctx)


@pytest.mark.parametrize('name', ['my joint', '1st', 'x' * 300])
def test_a_joint_name_that_is_no_topic_name_is_one_line(context, name):
    from rclpy.parameter import Parameter
    from abd_joint_sim.ros.node import SimNode
    urdf = robot(link('root'), link('a'), joint(name, 'root', 'a'))
    with pytest.raises(ValueError) as err:
        SimNode(context=context, parameter_overrides=[
            Parameter('robot_description', value=urdf), Parameter('start_paused', value=True)])
    msg = str(err.value)
    assert '\n' not in msg and len(msg) < 500, msg
    assert f'joint {name[:80]!r}'.rstrip("'") in msg and 'a ROS topic name has only' in msg


def test_deleting_a_parameter_is_refused(context):
    from rclpy.parameter import Parameter
    from abd_joint_sim.ros.node import SimNode
    node = SimNode(context=context, parameter_overrides=[
        Parameter('scene', value='hinge'), Parameter('start_paused', value=True)])
    try:
        before = node.get_parameter('effort_limits').value
        result = node.set_parameters([Parameter('effort_limits', Parameter.Type.NOT_SET)])[0]
        assert not result.successful
        assert "parameter 'effort_limits' cannot be deleted" in result.reason
        assert node.has_parameter('effort_limits')
        assert node.get_parameter('effort_limits').value == before
    finally:
        node.destroy_node()


def test_a_flood_of_unknown_joint_names_is_one_short_line_and_no_stall():
    """One JointState with 10,000 unknown names, then 200 messages of fresh names: a handful
    of warning lines (one kind of refusal), each short, and the node keeps stepping."""
    from sensor_msgs.msg import JointState
    from test_robustness import InProcess
    run = InProcess(scene='hinge', real_time_factor=1.0, publish_rate=50.0)
    try:
        pub = run.probe.create_publisher(JointState, '/joint_commands', 10)
        run.spin_until(lambda: pub.get_subscription_count() > 0, 10.0, 'the subscription')
        run.spin_until(lambda: len(run.states) > 3, 10.0, 'joint states')
        seen: list = []
        run.probe.create_subscription(JointState, '/joint_states',
                                      lambda m: seen.append(time.monotonic()), 100)
        run.spin_for(0.3)
        names = [f'nope_{k}' for k in range(10_000)]
        pub.publish(JointState(name=names, effort=[1.0] * len(names)))
        for k in range(200):
            pub.publish(JointState(name=[f'fresh_{k}_{i}' for i in range(50)],
                                   effort=[1.0] * 50))
            run.executor.spin_once(timeout_sec=0.0)
        run.spin_for(1.0)
        warned = [t for lv, t in run.log.lines if lv.startswith('warn') and 'rejected' in t]
        print('\n'.join(warned))
        assert 1 <= len(warned) <= 2, warned
        assert all(len(t) < 700 for t in warned)
        assert "10000 entries rejected, joints 'nope_0', 'nope_1'" in warned[0]
        assert 'and 9995 more' in warned[0] and 'not an actuated joint' in warned[0]
        gaps = [b - a for a, b in zip(seen, seen[1:])]
        assert len(seen) > 10 and max(gaps) < 1.0, max(gaps)    # the stepping never stalled
    finally:
        run.close()


def test_duplicate_names_in_one_joint_command_are_refused():
    from abd_joint_sim.ros.commands import CommandBuffer
    buf = CommandBuffer(['a', 'b'], ['a', 'b'], [], 0.0)
    rejections, _ = buf.command_joint_state(['a', 'b', 'a'], [], [], [1.0, 2.0, 3.0])
    assert len(rejections) == 1 and "['a']" in str(rejections[0])
    assert 'given more than once; whole joint_commands message ignored' in str(rejections[0])
    assert buf.idle


def test_a_long_rejected_array_is_shown_by_its_head():
    from abd_joint_sim.ros.commands import CommandBuffer
    buf = CommandBuffer(['a', 'b'], ['a', 'b'], [], 0.0)
    rejections, _ = buf.command_array([1.0] * 100_000)
    text = str(rejections[0])
    assert len(text) < 300 and '(100000 values)' in text, text
