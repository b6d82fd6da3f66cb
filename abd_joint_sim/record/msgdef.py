"""Message definitions, type hashes and classes, looked up the way rosbag2 Jazzy does: from
the installed ``.msg`` and ``<Type>.json`` files of the package share directories, never from
a copy (docs/bag-format.md, "The MCAP file")."""

from __future__ import annotations

import functools
import importlib
import json
from pathlib import Path
import re
from typing import Any

from ament_index_python.packages import get_package_share_directory, PackageNotFoundError

DELIMITER = '=' * 80    #: separates the dependencies' definitions in a ``ros2msg`` schema

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
        raise MessageTypeError(f"message type '{msg_type}' is not of the form 'pkg/msg/Type'")
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


def msg_dependencies(text: str, package: str) -> list[str]:
    """Return the message types a ``.msg`` text uses, sorted, as written (``pkg/Type``);
    unqualified names are resolved in ``package``, as in ``rosidl_adapter``."""
    deps: set[str] = set()
    for line in text.splitlines():
        line = line.split('#', 1)[0]
        match = _FIELD_TYPE.match(line)
        if match is None or not line[match.end():].strip() or match[1] in PRIMITIVE_TYPES:
            continue  # blank, comment-only, not a 'type name' line, or a builtin type
        deps.add(match[1] if '/' in match[1] else f'{package}/{match[1]}')
    return sorted(deps)


@functools.cache
def message_definition(msg_type: str) -> str:
    """Return the ``ros2msg`` schema text rosbag2 Jazzy writes for ``msg_type``
    (rosbag2_cpp's ``LocalMessageDefinitionSource::get_full_text``): the root text, then
    depth first for each dependency not seen yet: ``\\n``, the 80 ``=`` line,
    ``MSG: pkg/Type`` and that type's text with its own unseen dependencies."""
    seen: set[str] = set()

    def expand(name: str, depth: int) -> str:
        if depth <= 0:
            raise MessageTypeError(f"message type '{msg_type}': dependency cycle at '{name}'")
        out = text = _share_file(name, '.msg').read_text(encoding='utf-8')
        for dep in msg_dependencies(text, split_type(name)[0]):
            if dep not in seen:
                seen.add(dep)
                out += f'\n{DELIMITER}\nMSG: {dep}\n' + expand(dep, depth - 1)
        return out

    return expand(msg_type, 50)


@functools.cache
def type_description_hash(msg_type: str) -> str:
    """Return the ``RIHS01_<sha256>`` type hash installed with ``msg_type``, or ``''`` (what
    rosbag2 stores when it does not know a hash)."""
    full_name = full_type_name(msg_type)
    try:
        path = _share_file(msg_type, '.json')
        hashes = json.loads(path.read_text(encoding='utf-8'))['type_hashes']
    except (MessageTypeError, OSError, ValueError, KeyError):
        return ''
    return next((str(e.get('hash_string', '')) for e in hashes
                 if e.get('type_name') == full_name), '')


def full_type_name(msg_type: str) -> str:
    """Normalise ``pkg/Type`` to ``pkg/msg/Type`` (the form rosbag2 writes)."""
    package, name = split_type(msg_type)
    return f'{package}/msg/{name}'


@functools.cache
def message_class(msg_type: str) -> Any:
    """Return the rclpy message class of ``msg_type`` (e.g. ``sensor_msgs.msg.JointState``)."""
    package, name = split_type(msg_type)
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError) as exc:
        raise MessageTypeError(f"message type '{msg_type}': no Python class ({exc})") from None
