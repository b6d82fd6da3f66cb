"""BagWriter: record rclpy messages into a rosbag2 bag (Jazzy, MCAP storage).

A bag is a directory ``<path>/`` with ``metadata.yaml`` and ``<name>_0.mcap`` (``name`` =
basename of ``path``), what ``ros2 bag record -s mcap`` leaves, with every CRC MCAP defines.
Chunks go straight to the file descriptor, so a SIGKILL loses at most the open chunk and
``recover()`` completes the bag. Format, crash behaviour, integrity: docs/bag-format.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib.metadata import version
import io
import itertools
import os
import struct
from pathlib import Path
import time
from types import TracebackType
from typing import Any

from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import CompressionType, IndexType, Writer
from rclpy.serialization import serialize_message

from . import cdr, metadata as md
from .msgdef import (full_type_name, message_class, message_definition, MessageTypeError,
                     type_description_hash)

DEFAULT_CHUNK_SIZE = 64 * 1024    #: bytes of messages per MCAP chunk: the most a SIGKILL loses

PROFILE = 'ros2'
LIBRARY = f"abd_joint_sim.record; mcap-python/{version('mcap')}"

_COMPRESSION = {'none': CompressionType.NONE, 'zstd': CompressionType.ZSTD,
                'lz4': CompressionType.LZ4}
_MEDIA_TYPES = {'.yaml': 'application/yaml', '.yml': 'application/yaml',
                '.json': 'application/json', '.txt': 'text/plain', '.urdf': 'application/xml',
                '.xml': 'application/xml'}


class BagError(RuntimeError):
    """A bag could not be created, written, read or recovered; the message names the bag path
    (and topic) and what happened (never an ``OSError``: a recorder stops, the run goes on)."""


class _FdSink:
    """Unbuffered file sink for ``mcap.Writer`` (which would wrap a file in a
    ``BufferedWriter``): every record reaches the kernel at once."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        while view:
            written = os.write(self.fd, view)
            view = view[written:]
            self.position += written
        return len(data)

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        """Nothing is buffered here."""


_MESSAGE_HEAD = struct.Struct('<BQHIQQ')   # opcode, record length, channel, seq, log, publish
_MESSAGE_OPCODE = 0x05
_MESSAGE_FIELDS = 22                          # record bytes before the data


class _FastMessages:
    """``mcap.Writer.add_message`` for a chunked writer with one ``struct`` pack per message:
    the same writer state and bytes, through ``mcap.Writer``'s private state, so BagWriter
    uses it only if :func:`fast_messages_work` (docs/decisions.md, "Node")."""

    def __init__(self, writer: Writer) -> None:
        self._stats = writer._Writer__statistics                  # noqa: SLF001
        self._chunk = writer._Writer__chunk_builder               # noqa: SLF001
        self._chunk_size = writer._Writer__chunk_size             # noqa: SLF001
        self._finalize = writer._Writer__finalize_chunk           # noqa: SLF001

    def add_many(self, channel_id: int, stamps, datas) -> None:
        """``writer.add_message(channel_id, t, data, publish_time=t, sequence=0)`` for each
        pair in order, with the statistics updated once."""
        if not stamps:
            return
        st = self._stats
        low, high = min(stamps), max(stamps)
        if st.message_count == 0 or low < st.message_start_time:
            st.message_start_time = low
        if high > st.message_end_time:
            st.message_end_time = high
        st.channel_message_counts[channel_id] += len(stamps)
        st.message_count += len(stamps)
        cb, head, size = self._chunk, _MESSAGE_HEAD.pack, self._chunk_size
        for log_time, data in zip(stamps, datas):
            if cb.num_messages == 0 or log_time < cb.message_start_time:
                cb.message_start_time = log_time
            if log_time > cb.message_end_time:
                cb.message_end_time = log_time
            index = cb.message_indices.get(channel_id)
            if not index:
                index = cb.message_indices[channel_id] = _FastMessageIndex(
                    channel_id=channel_id, records=[])
            buffer = cb.record_writer._buffer                     # noqa: SLF001
            index.records.append((log_time, buffer.tell()))
            cb.num_messages += 1
            buffer.write(head(_MESSAGE_OPCODE, _MESSAGE_FIELDS + len(data), channel_id, 0,
                              log_time, log_time))
            buffer.write(data)
            if buffer.tell() > size:
                self._finalize()


class _FastMessageIndex(MessageIndex):
    """A chunk's message index written with one ``struct`` pack for all its entries."""

    def write(self, stream) -> None:
        records = self.records
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(records) * 16)
        stream.write(struct.pack(f'<{2 * len(records)}Q',
                                 *itertools.chain.from_iterable(records)))
        stream.finish_record()


def _add_messages(writer: Writer, fast: _FastMessages | None, channel_id: int, stamps,
                  datas) -> None:
    if fast is not None:
        fast.add_many(channel_id, stamps, datas)
        return
    for t, data in zip(stamps, datas):
        writer.add_message(channel_id=channel_id, log_time=t, data=data, publish_time=t,
                           sequence=0)


_FAST_MESSAGES_OK: bool | None = None


def fast_messages_work() -> bool:
    """True if :class:`_FastMessages` writes the very bytes ``mcap.Writer.add_message``
    writes (checked once per process on a small file of several chunks, two channels, and
    times out of order)."""
    global _FAST_MESSAGES_OK
    if _FAST_MESSAGES_OK is None:
        try:
            files = []
            for fast in (False, True):
                out = io.BytesIO()
                w = Writer(out, chunk_size=200, compression=CompressionType.NONE,
                           index_types=IndexType.ALL, enable_crcs=True, enable_data_crcs=True)
                w.start(profile=PROFILE, library='check')
                sid = w.register_schema(name='s', encoding='ros2msg', data=b'int32 a')
                ch = [w.register_channel(topic=f'/t{k}', message_encoding='cdr',
                                         schema_id=sid) for k in range(2)]
                adder = _FastMessages(w) if fast else None
                for k, t in enumerate((5, 3, 9, 9, 1, 20, 7, 30, 2, 40, 41, 42)):
                    _add_messages(w, adder, ch[k % 2], (t,), (bytes(range(k % 3 + 10)),))
                _add_messages(w, adder, ch[1], [50, 49, 60, 61, 62, 63, 70, 71, 72],
                              [bytes(range(k % 4 + 8)) for k in range(9)])  # across chunks
                w.finish()
                files.append(out.getvalue())
            _FAST_MESSAGES_OK = files[0] == files[1]
        except Exception:  # noqa: BLE001 - another mcap version: its own add_message
            _FAST_MESSAGES_OK = False
    return _FAST_MESSAGES_OK


@dataclass
class _Topic:
    record: md.TopicRecord
    channel_id: int
    cls: Any


class BagWriter:
    """Write a rosbag2 (MCAP) bag; use as a context manager or ``open()``/``close()``.

    Not thread-safe: call it from one thread (the node's single-threaded executor).

    :param path: bag directory to create; must not exist.
    :param custom_data: strings stored in ``metadata.yaml`` ``custom_data`` and in the MCAP
        ``rosbag2`` metadata record.
    :param attachments: files stored as MCAP attachments at open, e.g. ``{'scene.yaml': b...}``.
    :param attachment_time_ns: the attachments' MCAP ``create_time`` [ns]; None = the wall
        clock at open (a fixed value makes a bag's bytes a function of its content alone).
    :param chunk_size: uncompressed bytes per MCAP chunk; the most a SIGKILL can lose.
    :param compression: chunk compression, ``'zstd'`` (default), ``'lz4'`` or ``'none'``.
    """

    def __init__(self, path: str | os.PathLike[str], *,
                 custom_data: dict[str, str] | None = None,
                 attachments: dict[str, bytes] | None = None,
                 attachment_time_ns: int | None = None,
                 chunk_size: int = DEFAULT_CHUNK_SIZE,
                 compression: str = 'zstd') -> None:
        self.path = Path(path)
        if not self.path.name or self.path.name in ('.', '..'):
            raise BagError(f"bag path '{path}' has no usable basename to name the bag file")
        self.mcap_path = self.path / f'{self.path.name}_0.mcap'
        self.metadata_path = self.path / 'metadata.yaml'
        for key, value in (custom_data or {}).items():
            self._check_custom(key, value)
        self._custom_data: dict[str, str] = dict(custom_data or {})
        self._attachments = dict(attachments or {})
        self._attachment_time_ns = attachment_time_ns
        for name, data in self._attachments.items():
            if not isinstance(name, str) or not isinstance(data, (bytes, bytearray)):
                raise self._error(f'attachment {name!r} must map a str name to bytes, got '
                                  f'{type(data).__name__}')
        if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
            raise self._error(f'chunk_size {chunk_size!r} is not an int >= 1')
        if compression not in _COMPRESSION:
            raise self._error(f"compression '{compression}' is not one of "
                              f'{sorted(_COMPRESSION)}')
        self._chunk_size = chunk_size
        self._compression = _COMPRESSION[compression]
        self._summary = md.BagSummary(file_name=self.mcap_path.name)
        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[str, int] = {}
        self._writer: Writer | None = None
        self._fast: _FastMessages | None = None
        self._fd: int | None = None
        self._state = 'new'  # new -> open -> closed | failed -> closed
        self._log_offset = 0  # added to every stamp: log times never decrease (restart_time)
        self.error: str | None = None
        """Why recording stopped, once a write has failed; ``None`` while healthy."""

    def open(self) -> None:
        """Create the bag directory, the MCAP file (header, attachments) and metadata.yaml."""
        if self._state != 'new':
            raise BagError(f"bag '{self.path}' cannot be opened: it is {self._state}")
        try:
            self.path.mkdir(parents=True, exist_ok=False)
        except FileExistsError:
            raise BagError(f"bag '{self.path}' exists already, not overwriting") from None
        except OSError as exc:
            raise self._error(f'cannot create the directory: {exc}') from None
        try:
            self._fd = os.open(self.mcap_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL
                               | getattr(os, 'O_CLOEXEC', 0), 0o644)
            writer = Writer(_FdSink(self._fd), chunk_size=self._chunk_size,
                            compression=self._compression, index_types=IndexType.ALL,
                            repeat_channels=True, repeat_schemas=True, use_chunking=True,
                            use_statistics=True, use_summary_offsets=True,
                            enable_crcs=True, enable_data_crcs=True)
            writer.start(profile=PROFILE, library=LIBRARY)
            self._fast = _FastMessages(writer) if fast_messages_work() else None
            now = time.time_ns() if self._attachment_time_ns is None \
                else int(self._attachment_time_ns)
            # log_time 0: the attachment belongs before the first simulated instant.
            for name, data in self._attachments.items():
                writer.add_attachment(create_time=now, log_time=0, name=name, data=bytes(data),
                                      media_type=_MEDIA_TYPES.get(Path(name).suffix.lower(),
                                                                  'application/octet-stream'))
        except OSError as exc:
            self._release()
            self._state = 'failed'
            raise self._error(f'cannot write {self.mcap_path.name}: {exc}') from None
        self._writer = writer
        self._state = 'open'
        try:
            self._write_metadata_yaml()
        except BagError:
            self._release()  # open() failed: no context manager will close us
            raise

    def close(self) -> None:
        """Finish the MCAP (summary, statistics, indexes) and write the final metadata.yaml.
        Idempotent; after a failed write it only releases the file (use ``recover()``)."""
        if self._state != 'open':
            self._release()
            self._state = 'closed'
            return
        try:
            self._writer.add_metadata(
                'rosbag2', {'serialized_metadata': md.dump_yaml(
                    md.bag_information(self._summary, self._custom_data))})
            self._writer.finish()
            os.fsync(self._fd)
        except OSError as exc:
            self._fail(f'finishing {self.mcap_path.name} failed: {exc}')
            raise self._error(self.error) from None
        finally:
            self._release()
            self._state = 'closed'
        self._write_metadata_yaml()

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def add_topic(self, topic: str, msg_type: str, qos: str = 'reliable',
                  depth: int = 10) -> None:
        """Register ``topic`` with ``msg_type`` (``'sensor_msgs/msg/JointState'``).

        :param qos: reliability the topic is published with, ``'reliable'`` or
            ``'best_effort'`` (``/clock``); durability is volatile, history keep-last.
        :param depth: history depth of the publisher.
        """
        self._require_open(topic)
        if not isinstance(topic, str) or not topic.startswith('/'):
            raise self._error(f"topic {topic!r} is not a fully qualified name (it must start "
                              "with '/')")
        if topic in self._topics:
            raise self._error(f"topic '{topic}' is registered already (as "
                              f'{self._topics[topic].record.msg_type})')
        try:
            profile = md.qos_profile(qos, depth)
            full_type = full_type_name(msg_type)
            schema_text = message_definition(full_type)  # names the package if it is missing
            cls = message_class(full_type)
        except (ValueError, MessageTypeError) as exc:
            raise self._error(f"topic '{topic}': {exc}") from None
        type_hash = type_description_hash(full_type)
        record = md.TopicRecord(topic, full_type, [profile], type_hash)
        try:
            if full_type not in self._schema_ids:
                self._schema_ids[full_type] = self._writer.register_schema(
                    name=full_type, encoding='ros2msg', data=schema_text.encode('utf-8'))
            channel_id = self._writer.register_channel(
                topic=topic, message_encoding=md.SERIALIZATION_FORMAT,
                schema_id=self._schema_ids[full_type],
                metadata=md.channel_metadata(record.qos_profiles, type_hash))
        except OSError as exc:
            raise self._fail(f"registering topic '{topic}' failed: {exc}") from None
        self._topics[topic] = _Topic(record, channel_id, cls)
        self._summary.topics.append(record)
        self._write_metadata_yaml()

    def restart_time(self) -> None:
        """The simulation's time restarts (``~/reset``): from now on a message's log (=
        publish) time is its stamp plus the latest log time written so far, so log times never
        decrease (docs/bag-format.md, "Resets"). Without a restart, log time = stamp."""
        self._require_open()
        self._log_offset = self._summary.end_ns or 0

    def write(self, topic: str, stamp_ns: int, msg: Any) -> None:
        """Record ``msg`` on ``topic`` at simulation time ``stamp_ns`` (log = publish time
        = ``stamp_ns`` + the time recorded before the last :meth:`restart_time`); a BagError
        if the bytes cannot be written stops the recording."""
        entry = self._entry(topic)
        if type(msg) is not entry.cls:
            raise self._error(f"topic '{topic}' records {entry.record.msg_type}, got "
                              f'{type(msg).__module__}.{type(msg).__name__}')
        try:
            data = cdr.trimmed(serialize_message(msg), msg)   # the stream, not rmw's slack
        except Exception as exc:  # rclpy raises TypeError/ValueError/RuntimeError variants
            raise self._error(f"topic '{topic}': cannot serialise: {exc}") from None
        self._add(topic, entry, (self._stamp(topic, stamp_ns),), (data,))

    def write_serialized(self, topic: str, stamp_ns: int, data: bytes) -> None:
        """Record CDR bytes already serialised for ``topic``'s type (what a publisher sent,
        e.g. sim_node's /clock, convert.ClockEncoder). Same checks and errors as write()."""
        entry = self._entry(topic)
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise self._error(f"topic '{topic}': serialized data must be bytes, got "
                              f'{type(data).__name__}')
        self._add(topic, entry, (self._stamp(topic, stamp_ns),), (data,))

    def write_serialized_many(self, topic: str, stamps: list, datas: list) -> None:
        """``write_serialized(topic, t, data)`` for each pair in order, in one call: the same
        bytes in the bag (sim_node's /clock of a batch of steps, `ros.recording.Recording`)."""
        entry = self._entry(topic)
        if len(stamps) != len(datas):
            raise self._error(f"topic '{topic}': {len(stamps)} stamps for {len(datas)} messages")
        if not all(type(t) is int and t >= 0 for t in stamps) \
                or not all(isinstance(d, (bytes, bytearray, memoryview)) for d in datas):
            for t, data in zip(stamps, datas):      # one by one: the same checks and errors
                self.write_serialized(topic, t, data)
            return
        self._add(topic, entry, stamps, datas)

    def _entry(self, topic: str) -> _Topic:
        entry = self._topics.get(topic) if self._state == 'open' else None
        if entry is None:
            self._require_open(topic)
            raise self._error(f"topic '{topic}' was not added (add_topic)")
        return entry

    def _stamp(self, topic: str, stamp_ns: Any) -> int:
        if isinstance(stamp_ns, bool) or not isinstance(stamp_ns, int) or stamp_ns < 0:
            raise self._error(f"topic '{topic}': stamp_ns {stamp_ns!r} is not an int >= 0 "
                              '(nanoseconds)')
        return stamp_ns

    def _add(self, topic: str, entry: _Topic, stamps, datas) -> None:
        """Add messages of checked stamps and bytes, in order, at log time stamp + offset."""
        if self._log_offset:
            stamps = [t + self._log_offset for t in stamps]
        try:
            _add_messages(self._writer, self._fast, entry.channel_id, stamps, datas)
        except OSError as exc:
            raise self._fail(f"writing on '{topic}' failed: {exc}") from None
        if stamps:
            entry.record.message_count += len(stamps)
            self._summary.add_stamp(min(stamps))
            self._summary.add_stamp(max(stamps))

    def flush(self) -> None:
        """Close the open chunk and hand it to the kernel (e.g. when the simulation pauses)."""
        self._require_open()
        try:
            self._writer.flush()
        except OSError as exc:
            raise self._fail(f'flushing failed: {exc}') from None

    def set_custom_data(self, key: str, value: str) -> None:
        """Set one ``custom_data`` entry (strings only, as rosbag2 stores them)."""
        if self._state not in ('new', 'open'):
            raise BagError(f"bag '{self.path}' is {self._state}: cannot set custom_data")
        self._check_custom(key, value)
        self._custom_data[key] = value
        if self._state == 'open':
            self._write_metadata_yaml()

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return self._summary.message_count

    def _error(self, what: str) -> BagError:
        return BagError(f"bag '{self.path}': {what}")

    def _check_custom(self, key: Any, value: Any) -> None:
        if not isinstance(key, str) or not isinstance(value, str):
            raise self._error(f'custom_data {key!r}: {value!r} must map str to str (rosbag2 '
                              'stores strings only)')

    def _require_open(self, topic: str | None = None) -> None:
        if self._state == 'open':
            return
        where = f"bag '{self.path}'" + (f" topic '{topic}'" if topic else '')
        if self._state == 'failed':
            raise BagError(f'{where}: recording stopped after an error: {self.error}')
        raise BagError(f'{where}: the bag is {self._state}, not open')

    def _fail(self, reason: str) -> BagError:
        """Stop recording (no further writes) and return the error to raise."""
        self._state = 'failed'
        self.error = reason
        return self._error(f'{reason}; recording stopped (the chunks written before are kept; '
                           'see recover())')

    def _release(self) -> None:
        self._writer = None
        self._fast = None
        if self._fd is not None:
            try:
                os.close(self._fd)
            except OSError:
                pass
            self._fd = None

    def _write_metadata_yaml(self) -> None:
        """Write metadata.yaml atomically (temp file + rename), so it is never half written."""
        text = md.metadata_yaml(self._summary, self._custom_data)
        tmp = self.metadata_path.with_name('.metadata.yaml.tmp')
        try:
            tmp.write_text(text, encoding='utf-8')
            os.replace(tmp, self.metadata_path)
        except OSError as exc:
            if self._state == 'open':
                raise self._fail(f'writing metadata.yaml failed: {exc}') from None
            raise self._error(f'writing metadata.yaml failed: {exc}') from None
