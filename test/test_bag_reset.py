"""A reset while recording: log times run on, stamps restart, the tools still see the reset.

The headless recorder (the node's layout and rules, tools/sim.py) records a hinge run of
three segments separated by ``~/reset``; the expectations are the segment lengths this test
chooses. sim_node's side is checked in test_headless_replay.py::test_live_node_bag_replays.
"""

from __future__ import annotations

from pathlib import Path

from mcap.reader import NonSeekingReader
import pytest
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
import yaml

MS = 1_000_000
SEGMENTS_MS = (300, 200, 250)       # simulated length of each segment


def record(path: Path, segments_ms=SEGMENTS_MS) -> None:
    from abd_joint_sim import Scene
    from abd_joint_sim.ros.params import resolve_scene
    from abd_joint_sim.tools.bagrun import config_for
    from abd_joint_sim.tools.schedule import Command, Plan, Segment
    from abd_joint_sim.tools.sim import BagRecorder, HeadlessSim
    scene_path = resolve_scene('hinge')
    scene = Scene.from_file(scene_path)
    sim = HeadlessSim(scene, config_for({'publish_rate': 50.0}, scene_path=scene_path))
    plan = Plan([Segment([Command(100 * MS, 'torque', 'hinge', 20.0 * (k + 1))], n * MS)
                 for k, n in enumerate(segments_ms)])
    recorder = BagRecorder(str(path), sim, scene_path, scene.source_text)
    try:
        sim.run(plan, recorder)
    finally:
        recorder.close()


def stamp_ns(t) -> int:
    return t.sec * 1_000_000_000 + t.nanosec


def file_order(bag: Path) -> list[tuple[str, int, object]]:
    """(topic, log time, message) in the order the recorder wrote them (mcap's reader)."""
    out = []
    with open(next(bag.glob('*.mcap')), 'rb') as f:
        for _schema, channel, message in NonSeekingReader(f).iter_messages(
                log_time_order=False):
            cls = {'/clock': Clock, '/joint_states': JointState}.get(channel.topic)
            out.append((channel.topic, message.log_time,
                        deserialize_message(message.data, cls) if cls else None))
    return out


@pytest.fixture(scope='module')
def reset_bag(tmp_path_factory) -> Path:
    bag = tmp_path_factory.mktemp('reset') / 'three_segments'
    record(bag)
    return bag


def test_log_times_never_decrease_and_stamps_keep_simulated_time(reset_bag):
    msgs = file_order(reset_bag)
    logs = [t for _, t, _ in msgs]
    assert logs == sorted(logs), 'log times decrease somewhere in the file'
    ends = [sum(SEGMENTS_MS[:k]) * MS for k in range(len(SEGMENTS_MS) + 1)]
    # each /clock and joint state: stamp = log time - the length of the earlier segments
    clocks = [(t, stamp_ns(m.clock)) for topic, t, m in msgs if topic == '/clock']
    states = [(t, stamp_ns(m.header.stamp)) for topic, t, m in msgs if topic == '/joint_states']
    for kind, pairs in (('clock', clocks), ('states', states)):
        seg, offsets = 0, []
        for k, (log, stamp) in enumerate(pairs):
            if k and stamp <= pairs[k - 1][1]:
                seg += 1
            offsets.append(log - stamp)
            assert log - stamp == ends[seg], (kind, k, log, stamp)
        assert seg == len(SEGMENTS_MS) - 1, f'{kind}: {seg + 1} segments'
    assert clocks[-1] == (ends[-1], SEGMENTS_MS[-1] * MS)
    info = yaml.safe_load((reset_bag / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']
    assert info['duration']['nanoseconds'] == ends[-1], 'duration = the whole recording'
    assert info['starting_time']['nanoseconds_since_epoch'] == 0
    # A reader ordering by log time (rosbags, as ros2 bag play and Foxglove do) gets the
    # segments one after another, not interleaved.
    with AnyReader([reset_bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections if c.topic == '/joint_states']
        by_log = [stamp_ns(reader.deserialize(raw, c.msgtype).header.stamp)
                  for c, _t, raw in reader.messages(connections=conns)]
    assert by_log == [s for _, s in states]


def test_replay_check_and_plot_bag_find_the_resets(reset_bag):
    from abd_joint_sim.tools.plot_bag import read_run
    from abd_joint_sim.tools.replay_check import replay
    result = replay(str(reset_bag))
    assert result.ok and result.segments == 3, result.report()
    assert all(result.worst[f].deviation == 0.0 for f in ('position', 'velocity', 'effort'))
    assert result.commands == 3
    run = read_run(reset_bag)
    assert run.resets == pytest.approx([0.3, 0.5])
    assert run.t == sorted(run.t) and run.t[-1] == pytest.approx(0.74)   # 0.5 + the 50 Hz grid point 0.24
    assert run.marker_segment[0] == 0 and run.marker_segment[-1] == 2
    first_after = [run.marker_segment.index(k) for k in (1, 2)]
    assert [run.markers[i][0] for i in first_after] == pytest.approx([0.3, 0.5])


def test_without_reset_log_time_is_the_stamp(tmp_path):
    """A run without reset is logged at its stamps (log time = stamp): the golden bags,
    which have no reset, keep their bytes (test_headless_replay.py replays them exactly)."""
    bag = tmp_path / 'one'
    record(bag, (200,))
    for topic, log, msg in file_order(bag):
        if topic == '/clock':
            assert log == stamp_ns(msg.clock)
        elif topic == '/joint_states':
            assert log == stamp_ns(msg.header.stamp)
