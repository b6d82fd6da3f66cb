"""Round trips of abd_joint_sim.record bags through independent readers (rosbags, mcap_ros2).

Every check compares against values the test chose, not against what the writer wrote
earlier; ``test_checks_catch_a_wrong_value`` proves the comparison helpers can fail.
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
import time

from abd_joint_sim.record import (BagError, BagWriter, read_attachments, read_custom_data,
                                  read_messages, recover)
from abd_joint_sim.record.metadata import INFINITE
from abd_joint_sim.record.msgdef import DELIMITER
from ament_index_python.packages import get_package_share_directory
from builtin_interfaces.msg import Time
from mcap.reader import make_reader, NonSeekingReader
from mcap_ros2.reader import read_ros2_messages
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray, MultiArrayDimension
import yaml

REPO = Path(__file__).resolve().parents[1]
JOINTS = ['shoulder', 'elbow', 'wrist']
STEP_NS = 10_000_000  # 10 ms
STEPS = 400
SCENE = 'bodies:\n  - name: base\n    fixed: true\njoints: []\n'
TOPICS = {
    '/joint_states': ('sensor_msgs/msg/JointState', 'reliable', 10),
    '/clock': ('rosgraph_msgs/msg/Clock', 'best_effort', 1),
    '/effort_commands': ('std_msgs/msg/Float64MultiArray', 'reliable', 10),
    '/enable': ('std_msgs/msg/Bool', 'reliable', 10),
}


def stamp(t_ns: int) -> Time:
    return Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)


def expected_messages() -> list[tuple[str, int, dict]]:
    """The plain values the test records: (topic, log time, fields)."""
    out = []
    for k in range(STEPS):
        t = k * STEP_NS
        out.append(('/clock', t, {'t': t}))
        out.append(('/joint_states', t, {
            't': t,
            'position': [0.001 * k + i for i in range(3)],
            'velocity': [0.5 - 0.01 * k * i for i in range(3)],
            'effort': [float(k % 7) - i for i in range(3)],
        }))
        if k % 50 == 0:
            out.append(('/effort_commands', t, {'data': [1.5 * k, -2.0, 0.25]}))
        if k % 100 == 0:
            out.append(('/enable', t, {'data': k % 200 == 0}))
    return out


def to_ros(topic: str, fields: dict):
    if topic == '/clock':
        return Clock(clock=stamp(fields['t']))
    if topic == '/joint_states':
        msg = JointState(name=list(JOINTS), position=fields['position'],
                         velocity=fields['velocity'], effort=fields['effort'])
        msg.header.stamp = stamp(fields['t'])
        msg.header.frame_id = 'world'
        return msg
    if topic == '/effort_commands':
        msg = Float64MultiArray(data=fields['data'])
        msg.layout.dim = [MultiArrayDimension(label='joints', size=3, stride=3)]
        return msg
    return Bool(data=fields['data'])


def from_any(topic: str, msg) -> dict:
    """Fields of a decoded message (rclpy, rosbags or mcap_ros2 object) in plain types."""
    if topic == '/clock':
        return {'t': msg.clock.sec * 1_000_000_000 + msg.clock.nanosec}
    if topic == '/joint_states':
        assert list(msg.name) == JOINTS, f'joint names {list(msg.name)} != {JOINTS}'
        assert msg.header.frame_id == 'world'
        return {'t': msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                'position': [float(x) for x in msg.position],
                'velocity': [float(x) for x in msg.velocity],
                'effort': [float(x) for x in msg.effort]}
    if topic == '/effort_commands':
        dims = [(d.label, d.size, d.stride) for d in msg.layout.dim]
        assert dims == [('joints', 3, 3)], f'layout {dims}'
        return {'data': [float(x) for x in msg.data]}
    return {'data': bool(msg.data)}


def assert_same(got: list[tuple[str, int, dict]], want: list[tuple[str, int, dict]]) -> None:
    """Same messages (exact float equality: CDR is lossless), log times never decreasing."""
    times = [t for _, t, _ in got]
    assert times == sorted(times), 'log times are not in order'
    key = lambda item: (item[1], item[0])  # noqa: E731 - order within one instant is free
    got_sorted, want_sorted = sorted(got, key=key), sorted(want, key=key)
    assert len(got_sorted) == len(want_sorted), f'{len(got_sorted)} messages, want {len(want)}'
    for g, w in zip(got_sorted, want_sorted):
        assert g == w, f'message {g} != expected {w}'


def write_bag(path: Path, **kwargs) -> list[tuple[str, int, dict]]:
    want = expected_messages()
    with BagWriter(path, custom_data={'scene': SCENE, 'parameters': 'time_step: 0.01\n'},
                   attachments={'scene.yaml': SCENE.encode()}, **kwargs) as bag:
        for topic, (msg_type, qos, depth) in TOPICS.items():
            bag.add_topic(topic, msg_type, qos=qos, depth=depth)
        for topic, t, fields in want:
            bag.write(topic, t, to_ros(topic, fields))
    return want


@pytest.fixture(scope='module')
def bag(tmp_path_factory) -> tuple[Path, list]:
    path = tmp_path_factory.mktemp('bags') / 'run'
    return path, write_bag(path, chunk_size=4096)


# -- independent readers ---------------------------------------------------------------------

def test_rosbags_reads_every_message(bag):
    path, want = bag
    typestore = get_typestore(Stores.ROS2_JAZZY)
    got = []
    with AnyReader([path], default_typestore=typestore) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == {topic: spec[0] for topic, spec in TOPICS.items()}
        for conn, t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            got.append((conn.topic, t, from_any(conn.topic, msg)))
    assert_same(got, want)


def test_rosbags_parses_metadata(bag):
    path, want = bag
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert reader.message_count == len(want)
        assert reader.start_time == 0
        assert reader.end_time == (STEPS - 1) * STEP_NS + 1  # rosbags: end is exclusive
        (rosbag,) = reader.readers
        assert rosbag.ros_distro == 'jazzy'
        assert rosbag.storage.metadata.custom == {'scene': SCENE,
                                                  'parameters': 'time_step: 0.01\n'}
        by_topic = {c.topic: c for c in reader.connections}
        clock_qos = by_topic['/clock'].ext.offered_qos_profiles[0]
        assert clock_qos.reliability.name == 'BEST_EFFORT' and clock_qos.depth == 1
        js_qos = by_topic['/joint_states'].ext.offered_qos_profiles[0]
        assert js_qos.reliability.name == 'RELIABLE' and js_qos.depth == 10
        assert js_qos.durability.name == 'VOLATILE' and js_qos.history.name == 'KEEP_LAST'
        typestore = get_typestore(Stores.ROS2_JAZZY)
        for topic, conn in by_topic.items():
            # rosbags computes RIHS01 itself: an independent check of the installed hash.
            assert conn.digest == typestore.hash_rihs01(TOPICS[topic][0]), topic


def test_mcap_ros2_reads_every_message(bag):
    path, want = bag
    got = []
    with open(path / 'run_0.mcap', 'rb') as f:
        for item in read_ros2_messages(f):
            assert item.schema.name == TOPICS[item.channel.topic][0]
            assert item.publish_time_ns == item.log_time_ns
            got.append((item.channel.topic, item.log_time_ns,
                        from_any(item.channel.topic, item.ros_msg)))
    assert_same(got, want)


def test_own_reader_returns_rclpy_messages(bag):
    path, want = bag
    got = []
    for topic, msg_type, t, msg in read_messages(path):
        assert msg_type == TOPICS[topic][0]
        assert type(msg).__name__ == msg_type.rsplit('/', 1)[1]
        got.append((topic, t, from_any(topic, msg)))
    assert_same(got, want)
    only = [m for m in read_messages(path, topics=['/enable'])]
    assert [m[3].data for m in only] == [True, False, True, False]
    assert read_custom_data(path)['scene'] == SCENE
    assert read_attachments(path) == {'scene.yaml': SCENE.encode()}


def test_checks_catch_a_wrong_value(bag):
    """The comparison is not vacuous: one changed value, one dropped message, disorder."""
    _, want = bag
    wrong = [list(x) for x in want]
    wrong[5] = (wrong[5][0], wrong[5][1], {**wrong[5][2], 'effort': [9.0, 9.0, 9.0]})
    with pytest.raises(AssertionError, match='expected'):
        assert_same([tuple(x) for x in wrong], want)
    with pytest.raises(AssertionError, match='messages'):
        assert_same(want[:-1], want)
    with pytest.raises(AssertionError, match='order'):
        assert_same(list(reversed(want)), want)


# -- MCAP and metadata details ---------------------------------------------------------------

def test_mcap_records_follow_rosbag2(bag):
    path, want = bag
    with open(path / 'run_0.mcap', 'rb') as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        assert header.profile == 'ros2' and header.library.startswith('abd_joint_sim')
        assert summary.statistics.message_count == len(want)
        assert summary.statistics.chunk_count > 1, 'chunk_size=4096 should give many chunks'
        assert len(summary.chunk_indexes) == summary.statistics.chunk_count
        for schema in summary.schemas.values():
            assert schema.encoding == 'ros2msg'
        for channel in summary.channels.values():
            msg_type, qos, depth = TOPICS[channel.topic]
            assert summary.schemas[channel.schema_id].name == msg_type
            assert channel.message_encoding == 'cdr'
            profiles = yaml.safe_load(channel.metadata['offered_qos_profiles'])
            assert profiles == [{
                'history': 'keep_last', 'depth': depth, 'reliability': qos,
                'durability': 'volatile', 'deadline': INFINITE, 'lifespan': INFINITE,
                'liveliness': 'automatic', 'liveliness_lease_duration': INFINITE,
                'avoid_ros_namespace_conventions': False}]
            assert channel.metadata['topic_type_hash'].startswith('RIHS01_')
        (record,) = [m for m in reader.iter_metadata() if m.name == 'rosbag2']
        stored = yaml.safe_load(record.metadata['serialized_metadata'])
        assert stored['version'] == 9 and stored['message_count'] == len(want)
        assert stored['custom_data']['scene'] == SCENE


def test_joint_state_schema_has_dependencies(bag):
    path, _ = bag
    with open(path / 'run_0.mcap', 'rb') as f:
        schemas = {s.name: s.data.decode() for s in make_reader(f).get_summary().schemas.values()}
    text = schemas['sensor_msgs/msg/JointState']
    assert len(DELIMITER) == 80 and set(DELIMITER) == {'='}
    header = f'\n{DELIMITER}\nMSG: std_msgs/Header\n'
    time_ = f'\n{DELIMITER}\nMSG: builtin_interfaces/Time\n'
    assert header in text and time_ in text
    assert text.index(header) < text.index(time_)
    assert text.count(DELIMITER) == 2, 'each dependency appears once'
    installed = Path(get_package_share_directory('sensor_msgs'), 'msg', 'JointState.msg')
    assert text.startswith(installed.read_text() + f'\n{DELIMITER}\n'), 'installed text first'
    assert 'float64[] effort' in text and 'int32 sec' in text
    multi = schemas['std_msgs/msg/Float64MultiArray']
    assert 'MSG: std_msgs/MultiArrayLayout\n' in multi
    assert 'MSG: std_msgs/MultiArrayDimension\n' in multi


def test_metadata_yaml_is_rosbag2_v9(bag):
    path, want = bag
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert list(info) == [
        'version', 'storage_identifier', 'duration', 'starting_time', 'message_count',
        'topics_with_message_count', 'compression_format', 'compression_mode',
        'relative_file_paths', 'files', 'custom_data', 'ros_distro']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['ros_distro'] == 'jazzy'
    assert info['compression_format'] == '' and info['compression_mode'] == ''
    assert info['relative_file_paths'] == ['run_0.mcap']
    assert info['message_count'] == len(want)
    assert info['duration'] == {'nanoseconds': (STEPS - 1) * STEP_NS}
    assert info['starting_time'] == {'nanoseconds_since_epoch': 0}
    assert info['files'] == [{'path': 'run_0.mcap',
                              'starting_time': {'nanoseconds_since_epoch': 0},
                              'duration': {'nanoseconds': (STEPS - 1) * STEP_NS},
                              'message_count': len(want)}]
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == {topic: sum(1 for x in want if x[0] == topic) for topic in TOPICS}
    assert counts['/clock'] == STEPS and counts['/enable'] == 4
    for entry in info['topics_with_message_count']:
        meta = entry['topic_metadata']
        assert meta['type'] == TOPICS[meta['name']][0]
        assert meta['serialization_format'] == 'cdr'
        assert isinstance(meta['offered_qos_profiles'], list)  # v9: a list, not a string
        assert meta['offered_qos_profiles'][0]['reliability'] == TOPICS[meta['name']][1]
        assert meta['type_description_hash'].startswith('RIHS01_')
    assert info['custom_data'] == {'scene': SCENE, 'parameters': 'time_step: 0.01\n'}


@pytest.mark.parametrize('compression', ['none', 'lz4', 'zstd'])
def test_every_compression_round_trips(tmp_path, compression):
    want = write_bag(tmp_path / 'bag', chunk_size=2048, compression=compression)
    got = []
    with AnyReader([tmp_path / 'bag'],
                   default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            got.append((conn.topic, t, from_any(conn.topic, msg)))
    assert_same(got, want)


# -- lifecycle and errors --------------------------------------------------------------------

def test_provisional_metadata_exists_after_open(tmp_path):
    bag = BagWriter(tmp_path / 'b', custom_data={'scene': SCENE})
    bag.open()
    try:
        info = yaml.safe_load((tmp_path / 'b/metadata.yaml').read_text())
        info = info['rosbag2_bagfile_information']
        assert info['version'] == 9 and info['message_count'] == 0
        assert info['custom_data'] == {'scene': SCENE}
        bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock', qos='best_effort', depth=1)
        info = yaml.safe_load((tmp_path / 'b/metadata.yaml').read_text())
        names = [t['topic_metadata']['name']
                 for t in info['rosbag2_bagfile_information']['topics_with_message_count']]
        assert names == ['/clock'], 'add_topic refreshes the provisional metadata'
    finally:
        bag.close()
    bag.close()  # idempotent


def test_refuses_to_overwrite(tmp_path):
    (tmp_path / 'taken').mkdir()
    with pytest.raises(BagError, match=r"taken' exists already, not overwriting"):
        BagWriter(tmp_path / 'taken').open()
    assert list((tmp_path / 'taken').iterdir()) == []


def test_unwritable_path_gives_bag_error(tmp_path):
    (tmp_path / 'file').write_text('not a directory')
    with pytest.raises(BagError, match=r"file/bag': cannot create the directory"):
        BagWriter(tmp_path / 'file' / 'bag').open()


def test_misuse_gives_bag_error(tmp_path):
    with BagWriter(tmp_path / 'b') as bag:
        bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock', qos='best_effort', depth=1)
        with pytest.raises(BagError, match="topic '/nope' was not added"):
            bag.write('/nope', 0, Clock())
        with pytest.raises(BagError, match="'/clock' records rosgraph_msgs/msg/Clock, got"):
            bag.write('/clock', 0, Bool())
        with pytest.raises(BagError, match='stamp_ns -1'):
            bag.write('/clock', -1, Clock())
        with pytest.raises(BagError, match='stamp_ns -1'):
            bag.write_serialized('/clock', -1, b'\x00\x01\x00\x00' + bytes(8))
        with pytest.raises(BagError, match='must be bytes, got Clock'):
            bag.write_serialized('/clock', 0, Clock())
        with pytest.raises(BagError, match="topic '/nope' was not added"):
            bag.write_serialized('/nope', 0, b'')
        with pytest.raises(BagError, match="'/clock' is registered already"):
            bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
        with pytest.raises(BagError, match="reliability 'fast'"):
            bag.add_topic('/x', 'std_msgs/msg/Bool', qos='fast')
        with pytest.raises(BagError, match="package 'no_such_msgs'"):
            bag.add_topic('/y', 'no_such_msgs/msg/Thing')
        with pytest.raises(BagError, match='must map str to str'):
            bag.set_custom_data('k', 3)
    with pytest.raises(BagError, match='closed, not open'):
        bag.write('/clock', 0, Clock())


def run_child(code: str, **popen) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get('PYTHONPATH', ''),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return subprocess.Popen([sys.executable, '-c', textwrap.dedent(code)], env=env,
                            cwd=REPO, **popen)


def test_disk_full_raises_bag_error_and_keeps_the_bag(tmp_path):
    """A file-size limit (EFBIG) stands in for a full disk; the caller survives it."""
    child = run_child(f'''
        import resource, signal
        from abd_joint_sim.record import BagError, BagWriter
        from std_msgs.msg import Float64MultiArray
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        bag = BagWriter({str(tmp_path / 'full')!r}, chunk_size=1024, compression='none')
        bag.open()
        bag.add_topic('/effort_commands', 'std_msgs/msg/Float64MultiArray')
        resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))
        try:
            for k in range(100000):
                bag.write('/effort_commands', k, Float64MultiArray(data=[float(k)] * 8))
        except BagError as exc:
            print('BagError', k, exc, flush=True)
        bag.close()
        bag.close()
        print('survived', flush=True)
    ''', stdout=subprocess.PIPE, text=True)
    out, _ = child.communicate(timeout=60)
    assert child.returncode == 0, out
    assert 'BagError' in out and 'full' in out and 'recording stopped' in out, out
    assert out.rstrip().endswith('survived'), out
    report = recover(tmp_path / 'full')
    values = [m.data[0] for _, _, _, m in read_messages(tmp_path / 'full')]
    assert report.messages == len(values) > 0
    assert values == [float(k) for k in range(len(values))], 'a gap-free prefix survives'


def test_sigkill_mid_run_is_recoverable(tmp_path):
    path = tmp_path / 'killed'
    child = run_child(f'''
        import sys
        from abd_joint_sim.record import BagWriter
        from std_msgs.msg import Float64MultiArray
        from rosgraph_msgs.msg import Clock
        from builtin_interfaces.msg import Time
        bag = BagWriter({str(path)!r}, custom_data={{'scene': 'x: 1'}},
                        attachments={{'scene.yaml': b'x: 1'}}, chunk_size=2048)
        bag.open()
        bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock', qos='best_effort', depth=1)
        bag.add_topic('/effort_commands', 'std_msgs/msg/Float64MultiArray')
        print('open', flush=True)
        k = 0
        while True:  # until killed
            bag.write('/clock', k * 1000, Clock(clock=Time(sec=0, nanosec=k * 1000)))
            bag.write('/effort_commands', k * 1000, Float64MultiArray(data=[float(k)]))
            k += 1
    ''', stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == 'open'
        mcap = path / 'killed_0.mcap'
        deadline = time.monotonic() + 30
        while mcap.stat().st_size < 50_000 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=10)
    assert child.returncode == -signal.SIGKILL
    assert mcap.stat().st_size >= 50_000

    # Before recovery: provisional metadata.yaml, and a linear scan reads complete chunks.
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['message_count'] == 0 and info['custom_data'] == {'scene': 'x: 1'}
    assert len(info['topics_with_message_count']) == 2
    scanned = []
    with open(mcap, 'rb') as f:
        try:
            for _, channel, _ in NonSeekingReader(f).iter_messages(log_time_order=False):
                scanned.append(channel.topic)
        except Exception:
            pass  # the truncated tail
    assert len(scanned) > 100
    with pytest.raises(BagError, match='recover'):
        list(read_messages(path))

    report = recover(path)
    assert not report.was_complete and report.chunks > 1
    assert (path / 'killed_0.mcap.orig').is_file(), 'the damaged original is kept'
    assert report.messages >= len(scanned)
    values = [m.data[0] for topic, _, _, m in read_messages(path) if topic == '/effort_commands']
    assert values == [float(k) for k in range(len(values))], 'a gap-free prefix survives'
    assert len(values) > 50
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert reader.message_count == report.messages
        assert reader.readers[0].storage.metadata.custom == {'scene': 'x: 1'}
    with open(mcap, 'rb') as f:
        assert sum(1 for _ in read_ros2_messages(f)) == report.messages
    assert read_attachments(path) == {'scene.yaml': b'x: 1'}
    again = recover(path)
    assert again.was_complete and again.messages == report.messages


# -- empty sequences, and every recorded topic in both readers ----------------------------
def _all_topics_in_both_readers(bag: Path) -> dict[str, list]:
    """Decode every message of every topic with rosbags and mcap_ros2; both must succeed,
    agree with metadata.yaml on the counts and with rclpy on the values. topic -> rclpy
    messages."""
    from abd_joint_sim.record import read_messages
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    meta = {e['topic_metadata']['name']: e['message_count']
            for e in info['topics_with_message_count'] if e['message_count']}
    ours: dict[str, list] = {}
    for topic, _, _t, m in read_messages(bag):
        ours.setdefault(topic, []).append(m)
    counts: dict[str, int] = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)      # raises on a size mismatch
            k = counts.get(conn.topic, 0)
            counts[conn.topic] = k + 1
            mine = ours[conn.topic][k]
            if conn.topic == '/joint_states':
                assert list(msg.name) == list(mine.name)
                assert list(msg.position) == list(mine.position)
                assert list(msg.effort) == list(mine.effort)
            elif conn.topic == '/parameter_events':
                assert [p.name for p in msg.changed_parameters] == \
                    [p.name for p in mine.changed_parameters]
                assert [list(p.value.double_array_value) for p in msg.changed_parameters] == \
                    [list(p.value.double_array_value) for p in mine.changed_parameters]
    seen: dict[str, int] = {}
    for m in read_ros2_messages(str(next(bag.glob('*.mcap')))):
        seen[m.channel.topic] = seen.get(m.channel.topic, 0) + 1
    assert counts == meta == seen == {k: len(v) for k, v in ours.items()}, (counts, meta, seen)
    return ours


@pytest.mark.slow
def test_every_topic_decodes_in_both_readers_with_empty_sequences(tmp_path):
    """A live parameter change (ParameterEvent: empty int64[]/float64[] sequences in every
    ParameterValue) and a scene without joints (JointState with empty float64[]): rclpy's
    serialize_message leaves 8 bytes of slack after those streams, which rosbags refuses
    ("CDR message size mismatch"); the bag must hold the stream only."""
    from abd_joint_sim import Scene
    from abd_joint_sim.ros.params import config_from_values, resolve_scene
    from abd_joint_sim.tools.schedule import Command, Plan, Segment
    from abd_joint_sim.tools.sim import BagRecorder, HeadlessSim
    scene_path = resolve_scene('hinge')
    scene = Scene.from_yaml(scene_path)
    sim = HeadlessSim(scene, config_from_values({'scene': 'hinge', 'publish_rate': 0.0}))
    plan = Plan([Segment([Command(0, 'enable', 'hinge', True), Command(0, 'torque', 'hinge', 5.0),
                          Command(10_000_000, 'array', None, [2.0]),
                          Command(20_000_000, 'parameter', None, {'command_timeout': 0.2}),
                          Command(30_000_000, 'parameter', None, {'effort_limits': [3.0]}),
                          Command(40_000_000, 'enable_all', None, True)], 1_100_000_000)])
    bag = tmp_path / 'params'
    rec = BagRecorder(str(bag), sim, scene_path, scene.source_text)
    sim.run(plan, rec)
    rec.close()
    ours = _all_topics_in_both_readers(bag)
    assert len(ours['/parameter_events']) == 2 and len(ours['/diagnostics']) == 1
    assert {'/joint_states', '/clock', '/joint_torque/hinge', '/joint_torque_commands',
            '/joint_torque_enable/hinge'} <= set(ours)

    lone = Scene.from_dict({'name': 'lone', 'dt': 0.01, 'bodies': [
        {'name': 'cube', 'box': [0.2, 0.2, 0.2], 'density': 1000.0, 'velocity': [0.1, 0, 0]}]})
    sim = HeadlessSim(lone, config_from_values({'publish_rate': 0.0}))
    bag = tmp_path / 'no_joints'
    rec = BagRecorder(str(bag), sim, '<dict>', lone.source_text)
    sim.run(Plan([Segment([], 30_000_000)]), rec)
    rec.close()
    ours = _all_topics_in_both_readers(bag)
    assert len(ours['/joint_states']) == 4 and list(ours['/joint_states'][0].position) == []


def test_cdr_stream_length_matches_an_independent_encoder():
    """abd_joint_sim.record.cdr against rosbags' own CDR serializer (written by others):
    same stream length for messages with empty and non-empty sequences, strings of odd
    lengths and nested messages; the trimmed bytes decode to the same message in rclpy."""
    from rclpy.serialization import deserialize_message, serialize_message
    from abd_joint_sim.record.cdr import HEADER, stream_length, trimmed
    from abd_joint_sim.ros import convert
    from abd_joint_sim.ros.recording import parameter_event_msg
    store = get_typestore(Stores.ROS2_JAZZY)
    msgs = [parameter_event_msg(1, '/abd_joint_sim', {'command_timeout': 0.2}),
            parameter_event_msg(1, '/n', {'effort_limits': [1.0, 2.0], 'publish_rate': 5.0}),
            parameter_event_msg(1, '/n', {'effort_limits': []}),
            convert.joint_state_msg(0, [], [], [], []),
            convert.joint_state_msg(7, ['a', 'bbb'], [1.0, 2.0], [3.0, 4.0], [5.0, 6.0], 'f'),
            convert.float64_array_msg([]), convert.float64_array_msg([1.0, -2.0, 3.0]),
            convert.diagnostics_msg(0, 'name', 'hw', False, 'msg', {'a': 1.0, 'bb': 'x'}),
            convert.bool_msg(True), convert.float64_msg(2.5), convert.clock_msg(3)]
    slack = 0
    for m in msgs:
        name = f'{type(m).__module__.split(".")[0]}/msg/{type(m).__name__}'
        raw = serialize_message(m)
        cut = trimmed(raw, m)
        theirs = store.serialize_cdr(store.deserialize_cdr(cut, name), name)
        assert stream_length(m) + HEADER <= len(cut) <= stream_length(m) + HEADER + 3, name
        assert len(theirs) - HEADER in range(stream_length(m), stream_length(m) + 4), name
        assert deserialize_message(cut, type(m)) == m, name
        slack += len(raw) - len(cut)
    assert slack > 0        # the slack exists (else this test would prove nothing)


def test_fast_message_path_writes_the_bytes_of_mcaps_add_message(tmp_path, monkeypatch):
    """BagWriter adds messages without mcap's per-field record writer (bag._FastMessages):
    the same messages through it and through ``mcap.Writer.add_message`` give
    byte-identical MCAP files (several chunks, interleaved topics, times out of order), the
    bag reads back in rosbags; and the once-per-process check can fail."""
    from abd_joint_sim.record import bag as bagmod
    from abd_joint_sim.ros import convert
    assert bagmod.fast_messages_work()
    files = []
    # fast/slow: one write per message; 'many': the /clock runs between two joint states in
    # one write_serialized_many call (sim_node's batches), with and without the fast path
    for mode in ('fast', 'slow', 'many', 'many_slow'):
        path = tmp_path / mode / 'bag'     # same name: the name is in the metadata
        with BagWriter(path, chunk_size=4096, custom_data={'k': 'v'}) as w:
            if mode in ('slow', 'many_slow'):
                w._fast = None
            w.add_topic('/clock', 'rosgraph_msgs/msg/Clock', qos='best_effort', depth=1)
            w.add_topic('/joint_states', 'sensor_msgs/msg/JointState')
            enc = convert.ClockEncoder()
            held = ([], [])
            for k in range(3000):
                t = k * 1_000_000 if k != 1500 else 7
                if mode.startswith('many'):
                    held[0].append(t)
                    held[1].append(enc.encode(t))
                else:
                    w.write_serialized('/clock', t, enc.encode(t))
                if k % 10 == 0:
                    if held[0]:
                        w.write_serialized_many('/clock', *held)
                        held = ([], [])
                    w.write('/joint_states', t, convert.joint_state_msg(
                        t, JOINTS, [k * 1e-3] * 3, [1.0] * 3, [-2.0] * 3))
            w.write_serialized_many('/clock', *held)
        files.append((path / f'{path.name}_0.mcap').read_bytes())
    assert len(files[0]) > 3 * 4096 and files[0] == files[1] == files[2] == files[3]
    with BagWriter(tmp_path / 'bad') as w:
        w.add_topic('/clock', 'rosgraph_msgs/msg/Clock', qos='best_effort', depth=1)
        with pytest.raises(BagError, match='2 stamps for 1 messages'):
            w.write_serialized_many('/clock', [1, 2], [b'x'])
        with pytest.raises(BagError, match='stamp_ns -5 is not an int >= 0'):
            w.write_serialized_many('/clock', [1, -5], [enc.encode(1), enc.encode(2)])
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with AnyReader([tmp_path / 'fast' / 'bag'], default_typestore=typestore) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        stamps = [t for _, t, _ in reader.messages()]
    assert counts == {'/clock': 3000, '/joint_states': 300}
    assert min(stamps) == 0 and max(stamps) == 2_999_000_000

    monkeypatch.setattr(bagmod, '_FAST_MESSAGES_OK', None)
    monkeypatch.setattr(bagmod, '_MESSAGE_OPCODE', 0x06)       # a wrong record opcode
    assert not bagmod.fast_messages_work()
    with BagWriter(tmp_path / 'slow_check') as w:
        assert w._fast is None                                 # mcap's own add_message
