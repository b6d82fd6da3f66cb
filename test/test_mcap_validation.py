"""Our bags against the official MCAP reader (@mcap/core, test/mcap_validator/), and the
portable paths a bag stores. conftest.py runs the same validator on every bag the tests
leave behind; here it must also reject damaged and CRC-less files, or that check proves
nothing."""
from __future__ import annotations

from pathlib import Path
import signal

from mcap.writer import Writer
import pytest
import yaml

from conftest import NodeProcess, next_domain_id, validate_mcap
from abd_joint_sim.record import BagWriter


def _write_bag(path: Path) -> Path:
    from std_msgs.msg import Float64
    with BagWriter(path, attachments={'scene.yaml': b'name: x\n'}) as bag:
        bag.add_topic('/x', 'std_msgs/msg/Float64')
        for i in range(2000):
            bag.write('/x', i * 1_000_000, Float64(data=float(i)))
    return path / f'{path.name}_0.mcap'


@pytest.mark.broken_bags
def test_validator_passes_a_good_bag_and_rejects_flipped_bytes(tmp_path):
    good = _write_bag(tmp_path / 'good')
    [result] = validate_mcap([good])
    assert result['ok'], result
    assert result['messages'] == 2000 and result['attachments'] == 1
    assert result['dataSectionCrc'] != 0
    data = good.read_bytes()
    damaged = []
    # Header, attachment, inside the chunks, the summary: one flipped bit each.
    for frac in (0.01, 0.05, 0.3, 0.5, 0.8, 0.95, 0.99):
        i = int(len(data) * frac)
        bad = bytearray(data)
        bad[i] ^= 0x10
        path = tmp_path / f'flip_{i}.mcap'
        path.write_bytes(bytes(bad))
        damaged.append(path)
    results = validate_mcap(damaged)
    accepted = [r['file'] for r in results if r['ok']]
    assert not accepted, f'damaged files accepted: {accepted}'


@pytest.mark.broken_bags
def test_validator_requires_the_data_section_crc(tmp_path):
    path = tmp_path / 'no_data_crc.mcap'
    with open(path, 'wb') as f:
        writer = Writer(f)          # mcap's default: no data-section CRC
        writer.start(profile='ros2', library='test')
        writer.finish()
    [result] = validate_mcap([path])
    assert not result['ok']
    assert any('data-section CRC' in e for e in result['errors']), result


@pytest.mark.broken_bags
def test_validator_rejects_a_truncated_bag(tmp_path):
    good = _write_bag(tmp_path / 'whole')
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    [result] = validate_mcap([cut])
    assert not result['ok']


@pytest.mark.slow
def test_bag_stores_no_absolute_paths(tmp_path):
    """scene_path and the stored parameters name the scene and the bag by base name only."""
    from abd_joint_sim import Scene
    from abd_joint_sim.ros.params import config_from_values, resolve_scene
    from abd_joint_sim.tools.sim import BagRecorder, HeadlessSim
    bag = tmp_path / 'portable'
    scene_path = resolve_scene('hinge')
    config = config_from_values({'scene': 'hinge', 'record': str(bag)})
    sim = HeadlessSim(Scene.from_yaml(scene_path), config)
    rec = BagRecorder(str(bag), sim, scene_path, Path(scene_path).read_text())
    rec.close()
    meta = (bag / 'metadata.yaml').read_text()
    custom = yaml.safe_load(meta)['rosbag2_bagfile_information']['custom_data']
    assert custom['abd_joint_sim.scene_path'] == 'hinge'
    params = yaml.safe_load(custom['abd_joint_sim.parameters_yaml'])
    stored = params['abd_joint_sim']['ros__parameters']
    assert stored['scene'] == 'hinge' and stored['record'] == 'portable'
    for root in {str(tmp_path), str(Path(scene_path).parent)}:
        assert root not in meta, f'{root} stored in metadata.yaml'
        assert root.encode() not in (bag / 'portable_0.mcap').read_bytes()
    # A user's own scene file: its base name.
    from abd_joint_sim.ros.recording import portable_scene_path
    assert portable_scene_path(str(tmp_path / 'sub' / 'my_arm.yaml')) == 'my_arm.yaml'


@pytest.mark.slow
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM, signal.SIGINT])
def test_stop_signal_mid_run_leaves_a_valid_bag(tmp_path, sig):
    """SIGINT or SIGTERM at an arbitrary moment of a fast recorded run (markers, joint
    states, /clock written all the time): exit 0 and a complete bag, which conftest's
    @mcap/core check validates (a KeyboardInterrupt raised inside a bag write must not leave
    the MCAP statistics one message ahead of the chunks)."""
    import random
    import time
    from abd_joint_sim.record import read_messages
    bag = tmp_path / 'stopped'
    node = NodeProcess.sim_node(tmp_path, next_domain_id(), {
        'scene': 'hinge', 'real_time_factor': 0.0, 'time_step': 0.002, 'record': str(bag),
        'marker_rate': 500.0})
    try:
        deadline = time.monotonic() + 60.0
        while 'recording' not in node.output() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(random.uniform(0.5, 1.5))
        assert node.stop(sig) == 0, node.output()[-3000:]
    finally:
        if node.alive():
            node.stop(signal.SIGKILL)
    assert sum(1 for _ in read_messages(bag)) > 0
