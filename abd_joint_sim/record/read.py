"""Read our bags back as rclpy messages, through the MCAP summary (chunk indexes), after
checking every CRC (:mod:`.integrity`). A bag whose writer was killed has no summary:
``recover()`` it first."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
import os
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from rclpy.serialization import deserialize_message
import yaml

from .bag import BagError
from .integrity import check
from .msgdef import message_class, MessageTypeError


def mcap_file(path: str | os.PathLike[str]) -> Path:
    """Return the MCAP file of a bag directory (from metadata.yaml) or ``path`` itself."""
    path = Path(path)
    if path.is_file():
        return path
    if not path.is_dir():
        if path.exists():
            raise BagError(f"bag '{path}' is not a regular file or a directory")
        raise BagError(f"bag '{path}' does not exist")
    info = _metadata(path)
    names = (info or {}).get('relative_file_paths') or []
    if names:
        return path / names[0]
    found = sorted(path.glob('*.mcap'))
    if not found:
        raise BagError(f"bag '{path}' has no .mcap file")
    return found[0]


def _metadata(bag_dir: Path) -> dict[str, Any] | None:
    meta = bag_dir / 'metadata.yaml'
    if not meta.is_file():
        return None
    try:
        loaded = yaml.safe_load(meta.read_text(encoding='utf-8'))
        return dict(loaded['rosbag2_bagfile_information'])
    except (OSError, yaml.YAMLError, KeyError, TypeError) as exc:
        raise BagError(f"bag '{bag_dir}': metadata.yaml is unreadable: {exc}") from None


@contextmanager
def _indexed(file: Path, failed: str) -> Iterator[Any]:
    """The indexed reader of `file` once :func:`.integrity.check` passed; an error while it
    is open is a BagError naming `file` (``'<failed> failed: ...'`` if no BagError)."""
    try:
        with open(file, 'rb') as handle:
            check(file)     # framing and every CRC: damage is named, never read as data
            try:
                reader = make_reader(handle)
                summary = reader.get_summary()
            except Exception as exc:  # truncated file: the footer bytes are garbage of any kind
                raise BagError(f"bag file '{file}' has no valid summary ({type(exc).__name__}: "
                               f'{exc}); was the recorder killed? run '
                               'abd_joint_sim.record.recover() on the bag') from None
            if summary is None:
                raise BagError(f"bag file '{file}' has no summary; run recover() on the bag")
            yield reader
    except BagError:
        raise
    except MessageTypeError as exc:
        raise BagError(f"bag file '{file}': {exc}") from None
    except Exception as exc:  # mcap raises McapError, struct.error, EndOfFile, ...
        raise BagError(f"bag file '{file}': {failed} failed: {type(exc).__name__}: {exc}") \
            from None


def read_messages(path: str | os.PathLike[str], topics: Iterable[str] | None = None,
                  log_time_order: bool = True) -> Iterator[tuple[str, str, int, Any]]:
    """Yield ``(topic, msg_type, log_time_ns, message)`` in log-time order, or in the order
    the recorder wrote them with ``log_time_order=False`` (what a replay applies).

    :param path: bag directory or its ``.mcap`` file.
    :param topics: only these topics (all when ``None``).
    """
    file = mcap_file(path)
    wanted = None if topics is None else list(topics)
    classes: dict[str, Any] = {}
    with _indexed(file, 'reading') as reader:
        for schema, channel, message in reader.iter_messages(topics=wanted,
                                                             log_time_order=log_time_order):
            if schema is None:
                raise BagError(f"bag file '{file}': topic '{channel.topic}' has no schema")
            cls = classes.get(schema.name)
            if cls is None:
                cls = classes[schema.name] = message_class(schema.name)
            yield (channel.topic, schema.name, message.log_time,
                   deserialize_message(message.data, cls))


def read_custom_data(path: str | os.PathLike[str]) -> dict[str, str]:
    """Return ``custom_data`` from metadata.yaml (or, for a bare ``.mcap``, its rosbag2 record)."""
    path = Path(path)
    info = _metadata(path) if path.is_dir() else None
    if info is not None:
        return dict(info.get('custom_data') or {})
    file = mcap_file(path)
    with _indexed(file, 'reading metadata') as reader:
        for record in reader.iter_metadata():
            if record.name == 'rosbag2':
                info = yaml.safe_load(record.metadata.get('serialized_metadata', '')) or {}
                return dict(info.get('custom_data') or {})
    return {}


def read_attachments(path: str | os.PathLike[str]) -> dict[str, bytes]:
    """Return the MCAP attachments by name (e.g. ``{'scene.yaml': b'...'}``)."""
    file = mcap_file(path)
    with _indexed(file, 'reading attachments') as reader:
        return {a.name: bytes(a.data) for a in reader.iter_attachments()}
