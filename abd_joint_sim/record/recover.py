"""Recover a bag whose recorder died (SIGKILL, power cut, disk full) before ``close()``.

Such an MCAP file ends in the middle of a record and has no summary, so indexed readers
(rosbag2, rosbags, ``mcap.reader.make_reader``) refuse it, and its metadata.yaml is the
provisional one (counts 0). The python ``mcap`` package has no recovery function (the Go
``mcap recover`` CLI does the same job), so ``recover()`` scans the file record by record,
keeps every complete chunk whose CRC checks, and rewrites a complete MCAP plus a complete
metadata.yaml. The damaged original is kept beside it as ``<name>_0.mcap.orig``.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
from typing import Any

from mcap.records import Attachment, Channel, Chunk, DataEnd, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk, StreamReader
from mcap.writer import CompressionType, Writer
import yaml

from . import metadata as md
from .bag import _FdSink, BagError, LIBRARY, PROFILE
from .read import _metadata, mcap_file


@dataclass(frozen=True)
class RecoveryReport:
    """What ``recover()`` found and kept."""

    messages: int
    """Messages in the recovered bag."""
    chunks: int
    """Complete chunks kept."""
    bytes_dropped: int
    """Bytes after the last complete record (the partial record the writer was in)."""
    was_complete: bool
    """The MCAP was already complete; only metadata.yaml was rewritten."""
    stopped_because: str
    """Why the scan stopped (``'end of data'`` for a complete file)."""


class _Copier:
    """Streams the records of a damaged file into a new MCAP, renumbering ids as it goes."""

    def __init__(self, writer: Writer, summary: md.BagSummary) -> None:
        self.writer = writer
        self.summary = summary
        self.schema_ids: dict[int, int] = {}
        self.schemas: dict[int, Schema] = {}
        self.channel_ids: dict[int, int] = {}
        self.topics: dict[int, md.TopicRecord] = {}

    def add(self, record: Any) -> None:
        if isinstance(record, Schema) and record.id not in self.schema_ids:
            self.schemas[record.id] = record
            self.schema_ids[record.id] = self.writer.register_schema(
                name=record.name, encoding=record.encoding, data=record.data)
        elif isinstance(record, Channel) and record.id not in self.channel_ids:
            schema = self.schemas.get(record.schema_id)
            if schema is None:
                return  # a channel without its schema cannot be decoded; drop it
            self.channel_ids[record.id] = self.writer.register_channel(
                topic=record.topic, message_encoding=record.message_encoding,
                schema_id=self.schema_ids[record.schema_id], metadata=dict(record.metadata))
            topic = md.TopicRecord(
                record.topic, schema.name,
                md.load_qos_profiles(record.metadata.get('offered_qos_profiles', '')),
                record.metadata.get('topic_type_hash', ''))
            self.topics[record.id] = topic
            self.summary.topics.append(topic)
        elif isinstance(record, Message) and record.channel_id in self.channel_ids:
            self.writer.add_message(channel_id=self.channel_ids[record.channel_id],
                                    log_time=record.log_time, data=record.data,
                                    publish_time=record.publish_time, sequence=record.sequence)
            self.topics[record.channel_id].message_count += 1
            self.summary.add_stamp(record.log_time)
        elif isinstance(record, Attachment):
            self.writer.add_attachment(create_time=record.create_time, log_time=record.log_time,
                                       name=record.name, media_type=record.media_type,
                                       data=record.data)
        elif isinstance(record, Metadata) and record.name != 'rosbag2':
            self.writer.add_metadata(record.name, dict(record.metadata))


def recover(path: str | os.PathLike[str]) -> RecoveryReport:
    """Make the bag at ``path`` complete again, keeping every complete chunk.

    Rewrites ``<name>_0.mcap`` (summary, statistics, ``rosbag2`` metadata record) and
    ``metadata.yaml``; the damaged file is kept as ``<name>_0.mcap.orig``. A bag that is
    already complete keeps its MCAP; only its metadata.yaml is rewritten from it.
    """
    bag_dir = Path(path)
    if not bag_dir.is_dir():
        raise BagError(f"bag '{bag_dir}' is not a bag directory")
    file = mcap_file(bag_dir)
    info = _metadata(bag_dir) or {}
    custom_data = {str(k): str(v) for k, v in (info.get('custom_data') or {}).items()}
    summary = md.BagSummary(file_name=file.name)
    tmp = file.with_name(file.name + '.recovering')
    size = file.stat().st_size if file.is_file() else 0
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    except OSError as exc:
        raise BagError(f"bag '{bag_dir}': cannot create {tmp.name}: {exc}") from None
    chunks, good_end, complete, reason = 0, 0, False, 'end of file'
    record_custom: dict[str, str] | None = None
    try:
        writer = Writer(_FdSink(fd), chunk_size=1024 * 1024, compression=CompressionType.ZSTD,
                        enable_data_crcs=True)
        copier = _Copier(writer, summary)
        with open(file, 'rb') as handle:
            records = StreamReader(handle, emit_chunks=True, validate_crcs=True).records
            while True:
                try:
                    record = next(records)
                    inner = breakup_chunk(record, validate_crc=True) \
                        if isinstance(record, Chunk) else [record]
                except StopIteration:
                    break
                except Exception as exc:  # truncated or corrupt record: stop before it
                    reason = f'{type(exc).__name__} {exc}'.strip()
                    break
                if isinstance(record, Header):
                    writer.start(profile=record.profile or PROFILE,
                                 library=f'{LIBRARY} (recovered)')
                for sub in inner:
                    copier.add(sub)
                if isinstance(record, Metadata) and record.name == 'rosbag2':
                    stored = yaml.safe_load(record.metadata.get('serialized_metadata', ''))
                    record_custom = dict((stored or {}).get('custom_data') or {})
                chunks += isinstance(record, Chunk)
                good_end = handle.tell()
                if isinstance(record, DataEnd):
                    complete, reason = True, 'end of data'
                    break
        if good_end == 0:
            raise BagError(f"bag file '{file}' has no readable MCAP header; nothing to recover")
        if not info.get('custom_data') and record_custom:
            custom_data = record_custom
        if not complete:
            writer.add_metadata('rosbag2', {'serialized_metadata': md.dump_yaml(
                md.bag_information(summary, custom_data))})
            writer.finish()
            os.fsync(fd)
    except BagError:
        os.close(fd)
        tmp.unlink(missing_ok=True)
        raise
    except OSError as exc:
        os.close(fd)
        tmp.unlink(missing_ok=True)
        raise BagError(f"bag '{bag_dir}': recovery failed: {exc}") from None
    os.close(fd)
    try:
        if complete:
            tmp.unlink()
        else:
            orig = file.with_name(file.name + '.orig')
            if not orig.exists():
                os.replace(file, orig)
            os.replace(tmp, file)
        meta = bag_dir / 'metadata.yaml'
        meta_tmp = bag_dir / '.metadata.yaml.tmp'
        meta_tmp.write_text(md.metadata_yaml(summary, custom_data), encoding='utf-8')
        os.replace(meta_tmp, meta)
    except OSError as exc:
        raise BagError(f"bag '{bag_dir}': recovery could not replace its files: {exc}") \
            from None
    return RecoveryReport(messages=summary.message_count, chunks=chunks,
                          bytes_dropped=max(0, size - good_end) if not complete else 0,
                          was_complete=complete, stopped_because=reason)
