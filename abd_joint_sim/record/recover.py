"""Recover a damaged bag: a recorder that died (SIGKILL, power cut, disk full) before
``close()``, a flipped bit in a chunk, a copy cut inside its summary.

``recover()`` walks the file record by record (:mod:`.integrity`), keeps every intact chunk,
skips each damaged one and writes a complete MCAP and metadata.yaml, keeping a copy of each
file it replaces (docs/bag-format.md, "Recovery").
"""

from __future__ import annotations

from dataclasses import dataclass, field
import io
import os
from pathlib import Path
import shutil
import struct
from typing import Any, Optional

from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk, StreamReader
from mcap.writer import CompressionType, Writer
import yaml

from . import integrity, metadata as md
from .bag import _FdSink, BagError, LIBRARY, PROFILE
from .read import _metadata, mcap_file


@dataclass(frozen=True)
class DroppedChunk:
    """A chunk left out of the recovered bag."""

    index: int                  #: its number in the file (0 = the first chunk)
    offset: int                 #: byte offset of its record in the damaged file
    why: str
    messages: Optional[int]     #: messages it held, from its message indexes (None: not known)


@dataclass(frozen=True)
class RecoveryReport:
    """What ``recover()`` found, kept and dropped."""

    messages: int               #: messages in the recovered bag
    chunks: int                 #: intact chunks kept
    #: bytes after the last readable record (a partial record, or damage that breaks the
    #: record framing)
    bytes_dropped: int
    was_complete: bool          #: the MCAP was intact and complete; only metadata.yaml rewritten
    stopped_because: str        #: why the scan stopped (``'end of data'`` for a complete file)
    dropped_chunks: tuple[DroppedChunk, ...] = ()       #: damaged chunks skipped
    #: other damaged records skipped (an attachment whose CRC fails)
    dropped_records: tuple[str, ...] = ()
    #: topics whose channel record was lost with a damaged chunk, rebuilt from metadata.yaml
    rebuilt_channels: tuple[str, ...] = ()
    #: copies of the replaced files (the damaged MCAP, the previous metadata.yaml)
    backups: tuple[str, ...] = ()

    @property
    def messages_dropped(self) -> int:
        """Messages of the skipped chunks whose count is known."""
        return sum(c.messages or 0 for c in self.dropped_chunks)

    @property
    def lost(self) -> bool:
        """Something of the original did not make it into the recovered bag."""
        return bool(self.dropped_chunks or self.dropped_records or self.bytes_dropped)


def _parse(raw: bytes) -> Any:
    """The mcap record of one top-level record's bytes (opcode, length, content)."""
    return next(StreamReader(io.BytesIO(raw), skip_magic=True, emit_chunks=True).records)


@dataclass
class _Found:
    """What the file holds, in file order, and what is damaged."""

    records: list = field(default_factory=list)      # mcap records to copy, in order
    schemas: dict = field(default_factory=dict)      # id -> Schema
    channels: dict = field(default_factory=dict)     # id -> Channel
    dropped: list = field(default_factory=list)      # [index, offset, why, messages]
    dropped_records: list = field(default_factory=list)
    data_end: bool = False                           # DataEnd reached: the data is whole
    chunks: int = 0
    good_end: int = len(integrity.MAGIC)
    stopped: str = 'end of file'
    record_custom: Optional[dict] = None
    header: Optional[Header] = None


def _collect(data: memoryview, size: int) -> tuple[_Found, bool]:
    """What the file holds, and whether it is intact (:func:`integrity.scan` in one pass)."""
    found = _Found()
    pending: Optional[list] = None      # the dropped chunk whose message indexes follow

    def visit(pos: int, op: int, end: int, damage: Optional[integrity.Damage]) -> None:
        nonlocal pending
        if found.stopped != 'end of file':
            return
        content = data[pos + 9:end]
        if op == integrity.OP_MESSAGE_INDEX and pending is not None:
            try:        # a MessageIndex: channel id, then 16 bytes per message
                pending[3] = (pending[3] or 0) + struct.unpack_from('<I', content, 2)[0] // 16
            except struct.error:
                pass
        else:
            pending = None
        if op == integrity.OP_CHUNK:
            if damage:
                pending = [len(found.dropped) + found.chunks, pos, damage.why, None]
                found.dropped.append(pending)
            else:
                for sub in breakup_chunk(_parse(bytes(data[pos:end])), validate_crc=True):
                    _keep(found, sub)
                found.chunks += 1
        elif op == integrity.OP_DATA_END:
            found.data_end = True
        elif op == integrity.OP_FOOTER:
            found.stopped = 'end of data'
        elif op != integrity.OP_MESSAGE_INDEX:
            try:
                record = _parse(bytes(data[pos:end]))
            except Exception as exc:  # noqa: BLE001 - a damaged record of any kind
                found.stopped = f'the record at byte {pos} is unreadable ({exc})'
                return
            if isinstance(record, Header):
                found.header = record
            if isinstance(record, Attachment) and damage:
                found.dropped_records.append(str(damage))
            else:
                _keep(found, record)
        found.good_end = end

    damage = integrity._scan(data, size, visit)
    if found.stopped == 'end of file' and found.good_end < size and damage:
        found.stopped = str(damage[-1])      # the record that does not fit
    return found, not damage


def _keep(found: _Found, record: Any) -> None:
    if isinstance(record, Schema):
        found.schemas.setdefault(record.id, record)
    elif isinstance(record, Channel):
        found.channels.setdefault(record.id, record)
    elif isinstance(record, Metadata) and record.name == 'rosbag2':
        if found.record_custom is None:
            try:
                stored = yaml.safe_load(record.metadata.get('serialized_metadata', ''))
                found.record_custom = dict((stored or {}).get('custom_data') or {})
            except (yaml.YAMLError, AttributeError, TypeError, ValueError):
                pass
    elif not found.data_end and isinstance(record, (Message, Attachment, Metadata)):
        found.records.append(record)


def _rebuild_channels(found: _Found, info: dict[str, Any]) -> list[str]:
    """Channels that messages use but whose records were in damaged chunks: our writers
    number channels 1, 2, ... in the order metadata.yaml lists the topics, so channel k is
    the k-th topic there; its schema is the installed message definition."""
    from .msgdef import message_definition, MessageTypeError
    topics = info.get('topics_with_message_count') or []
    used = {r.channel_id for r in found.records if isinstance(r, Message)}
    rebuilt = []
    next_schema = max(found.schemas, default=0) + 1
    for cid in sorted(used - set(found.channels)):
        try:
            meta = topics[cid - 1]['topic_metadata']
            name, msg_type = str(meta['name']), str(meta['type'])
            qos = meta.get('offered_qos_profiles') or []
            type_hash = str(meta.get('type_description_hash') or '')
        except (IndexError, KeyError, TypeError):
            continue
        schema = next((s for s in found.schemas.values() if s.name == msg_type), None)
        if schema is None:
            try:
                text = message_definition(msg_type)
            except (MessageTypeError, ValueError):
                continue
            schema = Schema(id=next_schema, name=msg_type, encoding='ros2msg',
                            data=text.encode('utf-8'))
            found.schemas[next_schema] = schema
            next_schema += 1
        found.channels[cid] = Channel(
            id=cid, topic=name, message_encoding=md.SERIALIZATION_FORMAT,
            schema_id=schema.id,
            metadata=md.channel_metadata(qos if isinstance(qos, list) else [], type_hash))
        rebuilt.append(name)
    return rebuilt


def _readable_qos(found: _Found, info: dict[str, Any]) -> None:
    """A channel whose offered_qos_profiles text no longer parses (a damaged byte outside any
    CRC) takes the profiles metadata.yaml lists for its topic; without those it keeps none,
    and found.dropped_records says so."""
    listed = {}
    for topic in info.get('topics_with_message_count') or []:
        meta = topic.get('topic_metadata') if isinstance(topic, dict) else None
        if isinstance(meta, dict) and isinstance(meta.get('offered_qos_profiles'), list):
            listed[str(meta.get('name'))] = meta['offered_qos_profiles']
    for cid, channel in found.channels.items():
        try:
            md.load_qos_profiles(channel.metadata.get('offered_qos_profiles', ''))
            continue
        except yaml.YAMLError:
            qos = listed.get(channel.topic, [])
        if not qos:
            found.dropped_records.append(f"the QoS profiles of topic '{channel.topic}' "
                                         '(damaged, and not in metadata.yaml)')
        metadata = {**channel.metadata, **md.channel_metadata(
            qos, channel.metadata.get('topic_type_hash', ''))}
        found.channels[cid] = Channel(id=cid, topic=channel.topic, schema_id=channel.schema_id,
                                      message_encoding=channel.message_encoding,
                                      metadata=metadata)


def _write(fd: int, found: _Found, summary: md.BagSummary,
           custom_data: dict[str, str]) -> None:
    writer = Writer(_FdSink(fd), chunk_size=1024 * 1024, compression=CompressionType.ZSTD,
                    enable_crcs=True, enable_data_crcs=True)
    writer.start(profile=found.header.profile or PROFILE, library=f'{LIBRARY} (recovered)')
    schema_ids = {sid: writer.register_schema(name=s.name, encoding=s.encoding, data=s.data)
                  for sid, s in sorted(found.schemas.items())}
    channel_ids: dict[int, int] = {}
    topics: dict[int, md.TopicRecord] = {}
    for cid, channel in sorted(found.channels.items()):
        schema = found.schemas.get(channel.schema_id)
        if schema is None:
            continue    # a channel without its schema cannot be decoded; dropped
        channel_ids[cid] = writer.register_channel(
            topic=channel.topic, message_encoding=channel.message_encoding,
            schema_id=schema_ids[channel.schema_id], metadata=dict(channel.metadata))
        topics[cid] = md.TopicRecord(
            channel.topic, schema.name,
            md.load_qos_profiles(channel.metadata.get('offered_qos_profiles', '')),
            channel.metadata.get('topic_type_hash', ''))
        summary.topics.append(topics[cid])
    for record in found.records:
        if isinstance(record, Message):
            if record.channel_id in channel_ids:
                writer.add_message(channel_id=channel_ids[record.channel_id],
                                   log_time=record.log_time, data=record.data,
                                   publish_time=record.publish_time, sequence=record.sequence)
                topics[record.channel_id].message_count += 1
                summary.add_stamp(record.log_time)
        elif isinstance(record, Attachment):
            writer.add_attachment(create_time=record.create_time, log_time=record.log_time,
                                  name=record.name, media_type=record.media_type,
                                  data=record.data)
        elif isinstance(record, Metadata) and record.name != 'rosbag2':
            writer.add_metadata(record.name, dict(record.metadata))
    writer.add_metadata('rosbag2', {'serialized_metadata': md.dump_yaml(
        md.bag_information(summary, custom_data))})
    writer.finish()


def backup(path: Path) -> Path:
    """Keep a copy of `path` under the first free name of ``<path>.orig``,
    ``<path>.orig.1``, ``<path>.orig.2``, ... (a hard link: created only if the name is
    free, so no earlier copy is ever overwritten). Returns the copy's path."""
    for k in range(10000):
        name = path.with_name(path.name + ('.orig' if k == 0 else f'.orig.{k}'))
        try:
            os.link(path, name)
            return name
        except FileExistsError:
            continue
        except OSError:         # no hard links here: copy into a new file (O_EXCL)
            try:
                fd = os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                continue
            with os.fdopen(fd, 'wb') as out, open(path, 'rb') as src:
                shutil.copyfileobj(src, out)
                out.flush()
                os.fsync(out.fileno())
            return name
    raise OSError(f'no free backup name for {path}')


def recover(path: str | os.PathLike[str]) -> RecoveryReport:
    """Make the bag at ``path`` complete and intact again, keeping every intact chunk.

    Rewrites ``<name>_0.mcap`` (summary, statistics, ``rosbag2`` metadata record) and
    ``metadata.yaml``; the replaced files are kept (:func:`backup`). A bag that is intact
    and complete keeps its MCAP; only its metadata.yaml is rewritten from it (the previous
    one kept when it differs).
    """
    bag_dir = Path(path)
    if not bag_dir.is_dir():
        raise BagError(f"bag '{bag_dir}' is not a bag directory")
    file = mcap_file(bag_dir)
    info = _metadata(bag_dir) or {}
    custom_data = {str(k): str(v) for k, v in (info.get('custom_data') or {}).items()}
    summary = md.BagSummary(file_name=file.name)
    try:
        raw = file.read_bytes()
    except OSError as exc:
        raise BagError(f"bag file '{file}': {exc.strerror or exc}") from None
    found, intact = _collect(memoryview(raw), len(raw))
    if found.header is None:
        raise BagError(f"bag file '{file}' has no readable MCAP header; nothing to recover")
    if not info.get('custom_data') and found.record_custom:
        custom_data = found.record_custom
    rebuilt = _rebuild_channels(found, info)
    _readable_qos(found, info)
    tmp = file.with_name(file.name + '.recovering')
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    except OSError as exc:
        raise BagError(f"bag '{bag_dir}': cannot create {tmp.name}: {exc}") from None
    try:
        _write(fd, found, summary, custom_data)
        os.fsync(fd)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise BagError(f"bag '{bag_dir}': recovery failed: {exc}") from None
    finally:
        os.close(fd)
    backups = []
    try:
        if intact:
            tmp.unlink()
        else:
            backups.append(str(backup(file)))
            os.replace(tmp, file)
        meta = bag_dir / 'metadata.yaml'
        text = md.metadata_yaml(summary, custom_data)
        old = meta.read_text(encoding='utf-8', errors='replace') if meta.is_file() else None
        if old != text:
            if old is not None:
                backups.append(str(backup(meta)))
            meta_tmp = bag_dir / '.metadata.yaml.tmp'
            meta_tmp.write_text(text, encoding='utf-8')
            os.replace(meta_tmp, meta)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise BagError(f"bag '{bag_dir}': recovery could not replace its files: {exc}") \
            from None
    return RecoveryReport(
        summary.message_count, found.chunks,
        0 if intact or found.data_end else max(0, len(raw) - found.good_end), intact,
        'end of data' if intact else found.stopped,
        tuple(DroppedChunk(*d) for d in found.dropped), tuple(found.dropped_records),
        tuple(rebuilt), tuple(backups))
