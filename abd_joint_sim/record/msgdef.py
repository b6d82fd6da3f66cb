"""Message definitions, type hashes and classes, looked up the way rosbag2 Jazzy does.

rosbag2's ``LocalMessageDefinitionSource`` stores, as the MCAP schema of a topic, the
installed ``.msg`` text of the type followed by every message type it depends on
(recursively, each once, in sorted order per level), each introduced by a line of 80 ``=``
and ``MSG: pkg/Type``. Readers without the message packages installed (Foxglove,
``mcap_ros2``, ``rosbags``) decode the bag from that text alone, so it must be the real,
installed definition: we read it from the package share directory, never from a copy.

The type hash (``RIHS01_...``) is the one ``rosidl_generator_type_description`` computed at
build time and installed beside the ``.msg`` as ``<Type>.json``; rcl uses the same value.
"""

from __future__ import annotations

import functools
import importlib
import json
from pathlib import Path
import re
from typing import Any

from ament_index_python.packages import get_package_share_directory, PackageNotFoundError

DELIMITER = '=' * 80
"""Line that separates the definitions of the dependencies in a ``ros2msg`` schema."""

# Field types the .msg grammar treats as builtins (rosidl_adapter's PRIMITIVE_TYPES plus the
# ROS 1 aliases rosbag2's regex also knows). Everything else names a message.
PRIMITIVE_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring', 'time', 'duration',
})

_TYPE_NAME = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)/(?:(msg)/)?([A-Za-z][A-Za-z0-9_]*)$')
# First token of a field or constant line: 'pkg/Type[<=3]', 'string<=10', 'float64[4]', ...
_FIELD_TYPE = re.compile(r'^\s*([A-Za-z][A-Za-z0-9_/]*)')


class MessageTypeError(LookupError):
    """A message type name is malformed or its definition is not installed."""


def split_type(msg_type: str) -> tuple[str, str]:
    """Return ``(package, Type)`` for ``pkg/msg/Type`` or ``pkg/Type``."""
    match = _TYPE_NAME.match(msg_type)
    if match is None:
        raise MessageTypeError(
            f"message type '{msg_type}' is not of the form 'pkg/msg/Type'")
    return match.group(1), match.group(3)


def _share_file(msg_type: str, suffix: str) -> Path:
    package, name = split_type(msg_type)
    try:
        share = get_package_share_directory(package)
    except (PackageNotFoundError, ValueError) as exc:
        raise MessageTypeError(
            f"message type '{msg_type}': package '{package}' is not in the ament index "
            f'(AMENT_PREFIX_PATH): {exc}') from None
    except OSError:                         # ament_index_python's "AMENT_PREFIX_PATH is not set"
        raise MessageTypeError(
            f"message type '{msg_type}': AMENT_PREFIX_PATH is not set, so the installed message "
            "definitions cannot be found; run `source scripts/env.sh` (or a ROS 2 setup file) "
            'first') from None
    path = Path(share) / 'msg' / f'{name}{suffix}'
    if not path.is_file():
        raise MessageTypeError(f"message type '{msg_type}': {path} does not exist")
    return path


@functools.cache
def msg_text(msg_type: str) -> str:
    """Return the installed ``.msg`` text of ``msg_type``, byte for byte."""
    return _share_file(msg_type, '.msg').read_text(encoding='utf-8')


def msg_dependencies(text: str, package: str) -> list[str]:
    """Return the message types a ``.msg`` text uses, sorted, as written (``pkg/Type``).

    Unqualified names are resolved in ``package``, as in ``rosidl_adapter``. ROS 2 ``.msg``
    files have no implicit ``Header``; a bare ``Header`` would mean ``<package>/Header``.
    """
    deps: set[str] = set()
    for line in text.splitlines():
        line = line.split('#', 1)[0]
        match = _FIELD_TYPE.match(line)
        if match is None or not line[match.end():].strip():
            continue  # blank, comment-only, or not a 'type name' line
        base = match.group(1)
        if base in PRIMITIVE_TYPES:
            continue
        deps.add(base if '/' in base else f'{package}/{base}')
    return sorted(deps)


@functools.cache
def message_definition(msg_type: str) -> str:
    """Return the ``ros2msg`` schema text rosbag2 Jazzy writes for ``msg_type``.

    Same algorithm as rosbag2_cpp's ``LocalMessageDefinitionSource::get_full_text``: the
    root text, then depth first for each dependency not seen yet: ``\\n``, the 80 ``=``
    line, ``MSG: pkg/Type`` and that type's text with its own unseen dependencies.
    """
    seen: set[str] = set()

    def expand(name: str, depth: int) -> str:
        if depth <= 0:
            raise MessageTypeError(f"message type '{msg_type}': dependency cycle at '{name}'")
        text = msg_text(name)
        out = text
        for dep in msg_dependencies(text, split_type(name)[0]):
            if dep not in seen:
                seen.add(dep)
                out += f'\n{DELIMITER}\nMSG: {dep}\n' + expand(dep, depth - 1)
        return out

    return expand(msg_type, 50)


@functools.cache
def type_description_hash(msg_type: str) -> str:
    """Return the ``RIHS01_<sha256>`` type hash installed with ``msg_type``, or ``''``.

    ``''`` is what rosbag2 stores when it does not know a hash (and what older message
    packages without ``<Type>.json`` give).
    """
    package, name = split_type(msg_type)
    try:
        path = _share_file(msg_type, '.json')
        hashes = json.loads(path.read_text(encoding='utf-8'))['type_hashes']
    except (MessageTypeError, OSError, ValueError, KeyError):
        return ''
    full_name = f'{package}/msg/{name}'
    for entry in hashes:
        if entry.get('type_name') == full_name:
            return str(entry.get('hash_string', ''))
    return ''


def full_type_name(msg_type: str) -> str:
    """Normalise ``pkg/Type`` to ``pkg/msg/Type`` (the form rosbag2 writes)."""
    package, name = split_type(msg_type)
    return f'{package}/msg/{name}'


@functools.cache
def message_class(msg_type: str) -> Any:
    """Return the rclpy message class of ``msg_type`` (e.g. ``sensor_msgs.msg.JointState``)."""
    try:  # rosidl_runtime_py is not shipped with the PyPI wheels; use it where installed.
        from rosidl_runtime_py.utilities import get_message  # type: ignore[import-not-found]
    except ImportError:
        get_message = None
    if get_message is not None:
        try:
            return get_message(full_type_name(msg_type))
        except (AttributeError, ModuleNotFoundError, ValueError) as exc:
            raise MessageTypeError(f"message type '{msg_type}': {exc}") from None
    package, name = split_type(msg_type)
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError) as exc:
        raise MessageTypeError(
            f"message type '{msg_type}': no Python class ({exc})") from None
