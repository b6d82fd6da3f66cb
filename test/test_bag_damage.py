"""Damaged bags: every reader names the damage, bag_recover never makes a bag worse.

The bags are damaged the way files are: a flipped bit in a chunk or in the summary, a copy
cut short, a recorder killed with its first chunk later damaged. The expected messages come
from the undamaged file, read with the MCAP maintainers' python reader, never from the code
under test; the CRCs are recomputed here from the bytes (zlib), record by record.
"""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import struct
import subprocess
import sys
import zlib

from abd_joint_sim.record import (BagDamageError, BagError, BagWriter, read_attachments,
                                  read_messages, recover)
from mcap.reader import make_reader
import pytest
from std_msgs.msg import Float64MultiArray
import yaml
import zstandard

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / 'test' / 'data'
MAGIC = b'\x89MCAP0\r\n'


def records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of each top-level record, up to and including the footer."""
    out, pos = [], len(MAGIC)
    while pos + 9 <= len(data):
        op = data[pos]
        (length,) = struct.unpack_from('<Q', data, pos + 1)
        out.append((pos, op, length))
        if op == 0x02:
            break
        pos += 9 + length
    return out


def chunk_offsets(data: bytes) -> list[int]:
    return [pos for pos, op, _ in records(data) if op == 0x06]


def write_bag(path: Path, count: int = 1000, close: bool = True,
              snapshot: Path | None = None) -> BagWriter:
    """`count` messages of /e (data = [k] * 4, log time k ms) in ~4 KiB chunks; with
    `snapshot`, a copy of the open bag (no summary: what a SIGKILL leaves) is taken after
    the first half has been flushed in chunks."""
    bag = BagWriter(path, custom_data={'scene': 'x: 1'}, attachments={'scene.yaml': b'x: 1'},
                    chunk_size=4096)
    bag.open()
    bag.add_topic('/e', 'std_msgs/msg/Float64MultiArray')
    bag.add_topic('/f', 'std_msgs/msg/Float64MultiArray')
    for k in range(count):
        bag.write('/e', k * 1_000_000, Float64MultiArray(data=[float(k)] * 4))
        if snapshot is not None and k == count // 2:
            bag.flush()
            shutil.copytree(path, snapshot)
    if close:
        bag.close()
    return bag


def values_of(path) -> list[float]:
    return [m.data[0] for topic, _, _, m in read_messages(path) if topic == '/e']


def flip(file: Path, offset: int) -> None:
    data = bytearray(file.read_bytes())
    data[offset] ^= 0x04
    file.write_bytes(bytes(data))


def cli(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    return subprocess.run([sys.executable, '-m', *args], capture_output=True, text=True,
                          env=env, cwd=str(REPO), timeout=120)


def chunk_times(file: Path) -> list[tuple[int, int]]:
    """(first, last) log time of each chunk, from the intact file's chunk indexes."""
    with open(file, 'rb') as f:
        summary = make_reader(f).get_summary()
    return [(c.message_start_time, c.message_end_time) for c in summary.chunk_indexes]


# ----------------------------------------------------------------- bag_recover ----
@pytest.mark.broken_bags
def test_recover_skips_a_damaged_chunk_and_keeps_every_intact_one(tmp_path):
    bag = tmp_path / 'b'
    write_bag(bag)
    file = bag / 'b_0.mcap'
    times = chunk_times(file)
    assert len(times) >= 5
    offsets = chunk_offsets(file.read_bytes())
    flip(file, offsets[0] + 120)
    damaged = file.read_bytes()
    with pytest.raises(BagDamageError, match=r'chunk 0 at byte \d+.*bag_recover'):
        values_of(bag)
    out = cli('abd_joint_sim.tools.bag_recover', str(bag))
    print(out.stdout + out.stderr)
    lost = [k for k in range(1000) if times[0][0] <= k * 1_000_000 <= times[0][1]]
    assert out.returncode == 1, out.stdout + out.stderr
    assert f'dropped chunk 0 at byte {offsets[0]} ({len(lost)} message(s)): ' in out.stdout
    assert values_of(bag) == [float(k) for k in range(1000) if k not in lost]
    assert (bag / 'b_0.mcap.orig').read_bytes() == damaged, 'the damaged original is kept'
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['message_count'] == 1000 - len(lost)
    assert info['starting_time']['nanoseconds_since_epoch'] == (lost[-1] + 1) * 1_000_000
    assert yaml.safe_load((bag / 'metadata.yaml.orig').read_text())[
        'rosbag2_bagfile_information']['message_count'] == 1000
    again = cli('abd_joint_sim.tools.bag_recover', str(bag))
    assert again.returncode == 0 and 'intact and complete already' in again.stdout, again


def damage_qos(file: Path, topic: bytes) -> None:
    """Makes the offered_qos_profiles text of `topic`'s channel record in the summary
    unparsable YAML (an opening quote never closed), in place, its length kept."""
    data = bytearray(file.read_bytes())
    damaged = 0
    for pos, op, length in records(bytes(data)):
        record = bytes(data[pos:pos + 9 + length])
        if op == 0x04 and topic in record:
            key = record.index(b'offered_qos_profiles')
            value = pos + key + len(b'offered_qos_profiles') + 4     # (uint32 length first)
            assert data[value:value + 2] == b'- '
            data[value] = ord('"')
            damaged += 1
    assert damaged == 1, 'the summary holds the channel once (the data section, in a chunk)'
    file.write_bytes(bytes(data))


@pytest.mark.broken_bags
@pytest.mark.parametrize('with_metadata', [True, False])
def test_recover_a_channel_whose_qos_text_is_damaged(tmp_path, with_metadata):
    """A channel whose QoS text is damaged (in the summary, its copy in the first chunk lost
    with that chunk) is one line of the report at most: the profiles come back from
    metadata.yaml, or the topic keeps none and the report names it."""
    bag = tmp_path / 'b'
    write_bag(bag)
    file = bag / 'b_0.mcap'
    times = chunk_times(file)
    kept = [float(k) for k in range(1000) if not times[0][0] <= k * 1_000_000 <= times[0][1]]
    flip(file, chunk_offsets(file.read_bytes())[0] + 120)
    before = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    qos = {t['topic_metadata']['name']: t['topic_metadata']['offered_qos_profiles']
           for t in before['topics_with_message_count']}
    assert qos['/e']
    damage_qos(file, b'/e')
    if not with_metadata:
        (bag / 'metadata.yaml').unlink()
    report = recover(bag)
    assert values_of(bag) == kept
    with open(file, 'rb') as f:
        channels = {c.topic: c for c in make_reader(f).get_summary().channels.values()}
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    after = {t['topic_metadata']['name']: t['topic_metadata']['offered_qos_profiles']
             for t in info['topics_with_message_count']}
    got = yaml.safe_load(channels['/e'].metadata['offered_qos_profiles'] or '[]')
    if with_metadata:
        assert after['/e'] == qos['/e'] and got == qos['/e']
        assert report.dropped_records == ()
    else:
        assert after['/e'] == [] and got == []
        assert report.dropped_records == ("the QoS profiles of topic '/e' (damaged, and not "
                                          'in metadata.yaml)',)
    assert after['/f'] == qos['/f']


@pytest.mark.broken_bags
def test_recover_never_overwrites_a_backup(tmp_path):
    """An existing ``.orig`` (an earlier backup, or a file of the user's) stays as it is:
    backups are numbered; so are the metadata.yaml copies."""
    bag = tmp_path / 'b'
    write_bag(bag)
    file = bag / 'b_0.mcap'
    (bag / 'b_0.mcap.orig').write_bytes(b'an earlier backup')
    (bag / 'metadata.yaml.orig').write_text('an earlier metadata backup')
    for k, where in enumerate((1, 0)):      # (the recovered file has fewer chunks)
        offsets = chunk_offsets(file.read_bytes())
        flip(file, offsets[where] + 100)
        damaged = file.read_bytes()
        meta = (bag / 'metadata.yaml').read_text()
        report = recover(bag)
        assert report.lost and len(report.dropped_chunks) == 1
        assert (bag / f'b_0.mcap.orig.{k + 1}').read_bytes() == damaged
        assert (bag / f'metadata.yaml.orig.{k + 1}').read_text() == meta
    assert (bag / 'b_0.mcap.orig').read_bytes() == b'an earlier backup'
    assert (bag / 'metadata.yaml.orig').read_text() == 'an earlier metadata backup'
    assert values_of(bag) == [], 'the one chunk of the recovered file was damaged'


@pytest.mark.broken_bags
def test_recover_killed_bag_whose_first_chunk_is_damaged(tmp_path):
    """No summary (the recorder was killed) and chunk 0, which holds the schema and channel
    records, damaged: the later chunks' messages are kept, their channel rebuilt from the
    provisional metadata.yaml; the partial tail and the chunk are reported; exit 1."""
    killed = tmp_path / 'killed'
    bag = write_bag(tmp_path / 'full', close=True, snapshot=killed)
    assert bag.message_count == 1000
    file = killed / 'full_0.mcap'
    data = file.read_bytes()
    assert records(data)[-1][1] != 0x02, 'no footer: what a killed recorder leaves'
    offsets = chunk_offsets(data)
    assert len(offsets) >= 4
    times = chunk_times(tmp_path / 'full' / 'full_0.mcap')
    flip(file, offsets[0] + 150)
    out = cli('abd_joint_sim.tools.bag_recover', str(killed))
    print(out.stdout + out.stderr)
    assert out.returncode == 1, out.stdout + out.stderr
    assert 'dropped chunk 0' in out.stdout and 'topic /e: channel record lost' in out.stdout
    kept = values_of(killed)
    # every message of the intact complete chunks 1.. (those that reached the copy)
    n_chunks = len(offsets) - 1 if records(data)[-1][0] + 9 + records(data)[-1][2] > \
        len(data) else len(offsets)
    expected = [float(k) for k in range(1000)
                if any(times[c][0] <= k * 1_000_000 <= times[c][1]
                       for c in range(1, n_chunks))]
    assert kept == expected and len(kept) > 200
    with pytest.raises(BagDamageError):
        values_of(killed / 'full_0.mcap.orig')


@pytest.mark.broken_bags
def test_bag_cut_inside_its_summary_is_repaired_without_loss(tmp_path):
    bag = tmp_path / 'b'
    write_bag(bag)
    file = bag / 'b_0.mcap'
    data = file.read_bytes()
    data_end = next(pos for pos, op, _ in records(data) if op == 0x0F)
    file.write_bytes(data[:data_end + 13 + 40])       # DataEnd, then 40 summary bytes
    with pytest.raises(BagDamageError, match='bag_recover'):
        values_of(bag)
    out = cli('abd_joint_sim.tools.bag_recover', str(bag))
    assert out.returncode == 0 and 'recovered 1000 messages' in out.stdout, out
    assert values_of(bag) == [float(k) for k in range(1000)]
    assert read_attachments(bag) == {'scene.yaml': b'x: 1'}


@pytest.mark.broken_bags
def test_recover_refuses_a_file_without_header(tmp_path):
    bag = tmp_path / 'b'
    write_bag(bag, count=10)
    (bag / 'b_0.mcap').write_bytes(b'')
    out = cli('abd_joint_sim.tools.bag_recover', str(bag))
    assert out.returncode == 2 and out.stderr.count('\n') == 1, out
    assert 'no readable MCAP header' in out.stderr
    assert not (bag / 'b_0.mcap.orig').exists()


# ------------------------------------------------------------------- readers ----
@pytest.mark.broken_bags
@pytest.mark.parametrize('where', ['chunk', 'summary', 'attachment', 'cut'])
def test_replay_check_and_plot_bag_name_damage(tmp_path, where):
    """A flipped byte is damage, not a physics MISMATCH or a partial picture: exit 2, one
    line naming file, record and offset, and the bag_recover command."""
    bag = tmp_path / 'g'
    shutil.copytree(DATA / 'golden_default', bag)
    file = bag / 'golden_default_0.mcap'
    data = file.read_bytes()
    recs = records(data)
    if where == 'chunk':
        offset = chunk_offsets(data)[0]
        flip(file, offset + 200)
        expected = f'chunk 0 at byte {offset}'
    elif where == 'attachment':
        offset = next(pos for pos, op, _ in recs if op == 0x09)
        flip(file, offset + 60)
        expected = f"attachment 'scene.yaml' at byte {offset}"
    elif where == 'summary':
        data_end = next(pos for pos, op, _ in recs if op == 0x0F)
        flip(file, data_end + 13 + 30)
        expected = 'summary at byte'
    else:
        file.write_bytes(data[:len(data) // 2])
        expected = 'run past the end of the file'
    for args in (['abd_joint_sim.tools.replay_check', str(bag)],
                 ['abd_joint_sim.tools.plot_bag', str(bag), '--out', str(tmp_path / 'png')]):
        out = cli(*args)
        lines = out.stderr.strip().splitlines()
        assert out.returncode == 2 and len(lines) == 1, out.stdout + out.stderr
        assert 'is damaged' in lines[0] and expected in lines[0], lines[0]
        assert f'bag_recover {bag}' in lines[0] and 'MISMATCH' not in out.stdout, lines[0]
    assert not (tmp_path / 'png').exists()
    with pytest.raises(BagDamageError, match='is damaged'):
        next(iter(read_messages(bag)))


@pytest.mark.broken_bags
def test_replay_check_on_an_empty_file_says_so(tmp_path):
    bag = tmp_path / 'e'
    shutil.copytree(DATA / 'golden_default', bag)
    (bag / 'golden_default_0.mcap').write_bytes(b'')
    out = cli('abd_joint_sim.tools.replay_check', str(bag))
    assert out.returncode == 2 and 'is empty (0 bytes)' in out.stderr, out.stderr


def test_a_bag_file_that_is_not_a_regular_file_is_refused(tmp_path):
    with pytest.raises(BagError, match='not a regular file'):
        next(iter(read_messages('/dev/zero')))


# --------------------------------------------------------- every CRC, recomputed ----
def crc_report(file: Path) -> dict[str, list[tuple[int, int]]]:
    """kind -> [(stored, computed)] for every CRC MCAP defines, recomputed with zlib from
    the file's bytes (independent of abd_joint_sim.record.integrity)."""
    data = file.read_bytes()
    assert data[:8] == MAGIC and data[-8:] == MAGIC
    out: dict[str, list[tuple[int, int]]] = {'chunk': [], 'attachment': [], 'data': [],
                                             'summary': []}
    for pos, op, length in records(data):
        content = data[pos + 9:pos + 9 + length]
        if op == 0x06:
            size, crc = struct.unpack_from('<QI', content, 16)
            (n,) = struct.unpack_from('<I', content, 28)
            compression = content[32:32 + n].decode()
            (m,) = struct.unpack_from('<Q', content, 32 + n)
            body = content[40 + n:40 + n + m]
            raw = {'': lambda b: b, 'zstd': lambda b: zstandard.ZstdDecompressor()
                   .decompress(b, max_output_size=size)}[compression](body)
            out['chunk'].append((crc, zlib.crc32(raw)))
        elif op == 0x09:
            p = 16
            for _ in range(2):
                (n,) = struct.unpack_from('<I', content, p)
                p += 4 + n
            (n,) = struct.unpack_from('<Q', content, p)
            p += 8 + n
            out['attachment'].append((struct.unpack_from('<I', content, p)[0],
                                      zlib.crc32(content[:p])))
        elif op == 0x0F:
            out['data'].append((struct.unpack_from('<I', content)[0], zlib.crc32(data[:pos])))
        elif op == 0x02:
            start, _, crc = struct.unpack_from('<QQI', content)
            out['summary'].append((crc, zlib.crc32(data[start:pos + 25])))
    return out


def test_every_crc_in_our_bags_is_present_and_right(tmp_path):
    """Chunk, attachment, data-section and summary CRCs: none 0 ("not computed" to MCAP
    readers), each equal to the CRC-32 of its bytes; in the golden bags, a fresh bag and a
    recovered one (docs/bag-format.md, "Integrity")."""
    bag = tmp_path / 'b'
    write_bag(bag)
    shutil.copytree(bag, tmp_path / 'r')
    (tmp_path / 'r' / 'b_0.mcap').write_bytes((bag / 'b_0.mcap').read_bytes()[:-30])
    assert recover(tmp_path / 'r').messages == 1000
    files = [DATA / 'golden_default' / 'golden_default_0.mcap',
             DATA / 'golden_three_link' / 'golden_three_link_0.mcap',
             bag / 'b_0.mcap', tmp_path / 'r' / 'b_0.mcap']
    for file in files:
        report = crc_report(file)
        for kind, pairs in report.items():
            assert pairs, f'{file.name}: no {kind} CRC'
            for stored, computed in pairs:
                assert stored != 0, f'{file.name}: a {kind} CRC is 0 (not computed)'
                assert stored == computed, f'{file.name}: {kind} CRC {stored:#x} != ' \
                    f'{computed:#x}'
    # the check can fail: a flipped byte in a chunk changes its recomputed CRC
    data = bytearray((bag / 'b_0.mcap').read_bytes())
    data[chunk_offsets(bytes(data))[1] + 80] ^= 1
    (tmp_path / 'x.bin').write_bytes(bytes(data))
    bad = crc_report(tmp_path / 'x.bin')
    assert any(s != c for s, c in bad['chunk']) or any(s != c for s, c in bad['data'])
