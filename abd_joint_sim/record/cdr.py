"""The exact length of a message's CDR stream, to drop the slack ``serialize_message`` leaves,
and templates that pack new field values into a serialised message.

``serialize_message`` returns a buffer as long as its size estimate, which aligns the absent
elements of an empty sequence of 8-byte values; readers that check the length (``rosbags``)
refuse the slack (docs/bag-format.md, "Empty sequences"). The rules (XCDR1 little endian,
alignment counted after the 4-byte encapsulation header): a primitive of size n is aligned
to n; a string is a uint32 length (with the NUL), the bytes and the NUL; a sequence is a
uint32 count then its elements (nothing aligned for none); a fixed array is its elements,
a nested message its fields in order.
"""
from __future__ import annotations

import importlib
import struct
from typing import Any, Iterable, Sequence

HEADER = 4      #: bytes of the encapsulation header before the CDR stream

_PRIMITIVE = {
    'boolean': 1, 'octet': 1, 'char': 1, 'uint8': 1, 'int8': 1,
    'int16': 2, 'uint16': 2, 'wchar': 2,
    'int32': 4, 'uint32': 4, 'float': 4,
    'int64': 8, 'uint64': 8, 'double': 8,
}

_plans: dict[type, list] = {}

# Field kinds of a compiled plan (one tuple per field: attribute, kind, size, class).
_PRIM, _STR, _MSG, _PRIM_SEQ, _STR_SEQ, _MSG_SEQ = range(6)


def _align(pos: int, n: int) -> int:
    return pos + (-pos) % n


def _plan(cls: type) -> list:
    """[(attribute, kind, element size, nested class, counted), ...] of a message class,
    compiled once from its rosidl types (counted: a sequence, with its uint32 count)."""
    plan = _plans.get(cls)
    if plan is not None:
        return plan
    from rosidl_parser import definition as d

    def kind(t) -> tuple[int, int, Any]:
        if isinstance(t, d.BasicType):
            return _PRIM, _PRIMITIVE[t.typename], None
        if isinstance(t, (d.UnboundedString, d.BoundedString)):
            return _STR, 4, None
        if isinstance(t, d.NamespacedType):
            return _MSG, 0, getattr(importlib.import_module('.'.join(t.namespaces)), t.name)
        raise TypeError(f'no CDR size rule for {t!r}')
    plan = []
    for attr, t in zip(cls.__slots__, cls.SLOT_TYPES):
        counted = isinstance(t, (d.UnboundedSequence, d.BoundedSequence))
        seq = counted or isinstance(t, d.Array)
        k, n, sub = kind(t.value_type if seq else t)
        plan.append((attr, k + 3 * seq, n, sub, counted))     # _PRIM -> _PRIM_SEQ, ...
    _plans[cls] = plan
    return plan


def stream_length(msg: Any, pos: int = 0) -> int:
    """Bytes of the CDR stream of `msg` (without the encapsulation header); the position
    after it when serialised from `pos`. :func:`_walk` without its bookkeeping, 2.4 times
    faster (5 µs for a JointState; BagWriter.write)."""
    for attr, kind, n, sub, counted in _plan(type(msg)):
        value = getattr(msg, attr)
        if kind == _PRIM:
            pos += (-pos) % n + n
        elif kind == _STR:
            pos += (-pos) % 4 + 5 + len(value.encode('utf-8'))
        elif kind == _MSG:
            pos = stream_length(value, pos)
        else:
            if counted:
                pos += (-pos) % 4 + 4
            if len(value) == 0:
                continue            # no elements: nothing aligned for them
            if kind == _PRIM_SEQ:
                pos += (-pos) % n + n * len(value)
            elif kind == _STR_SEQ:
                for item in value:
                    pos += (-pos) % 4 + 5 + len(item.encode('utf-8'))
            else:
                for item in value:
                    pos = stream_length(item, pos)
    return pos


def trimmed(data: bytes, msg: Any) -> bytes:
    """`data` (``serialize_message(msg)``) without the slack beyond the stream padded to 4
    bytes; unchanged if it has none, or if `msg` holds a type without a size rule here."""
    try:
        end = HEADER + _align(stream_length(msg), 4)
    except (TypeError, AttributeError, ImportError, KeyError):
        return data
    return data[:end] if len(data) > end else data


def field_offsets(msg: Any) -> dict[tuple, int]:
    """Byte offsets, in ``serialize_message(msg)`` (encapsulation header included), of every
    primitive field of `msg` and of the first element of every non-empty primitive sequence,
    keyed by path: ``('header', 'stamp', 'sec')``, ``('position',)``, ``('markers', 2,
    'pose', 'position', 'x')``, ``('markers', 5, 'points', 0, 'x')``."""
    out: dict[tuple, int] = {}
    _walk(msg, 0, (), out, [])
    return {path: HEADER + pos for path, pos in out.items()}


def without_padding(data: bytes, msg: Any) -> bytes:
    """`data` (the CDR bytes of `msg`) with every alignment padding byte set to 0, and cut
    to the stream padded to 4 bytes (:func:`trimmed`): the serialiser leaves padding bytes
    as it finds them, so two serialisations of one message compare equal only after this."""
    pads: list[tuple[int, int]] = []
    end = _walk(msg, 0, (), {}, pads)
    pads.append((end, _align(end, 4)))
    out = bytearray(data[:HEADER + _align(end, 4)])
    for a, b in pads:
        out[HEADER + a:HEADER + b] = bytes(b - a)
    return bytes(out)


def _walk(msg: Any, pos: int, path: tuple, out: dict, pads: list) -> int:
    """:func:`stream_length` that also notes field offsets (`out`) and padding (`pads`)."""
    def align(pos: int, n: int) -> int:
        pad = (-pos) % n
        if pad:
            pads.append((pos, pos + pad))
        return pos + pad
    for attr, kind, n, sub, counted in _plan(type(msg)):
        value = getattr(msg, attr)
        here = path + (attr.lstrip('_'),)       # rosidl slots are '_' + the field name
        if kind == _PRIM:
            pos = align(pos, n)
            out[here] = pos
            pos += n
        elif kind == _STR:
            pos = align(pos, 4) + 5 + len(value.encode('utf-8'))
        elif kind == _MSG:
            pos = _walk(value, pos, here, out, pads)
        else:
            if counted:
                pos = align(pos, 4) + 4
            if len(value) == 0:
                continue
            if kind == _PRIM_SEQ:
                pos = align(pos, n)
                out[here] = pos
                pos += n * len(value)
            elif kind == _STR_SEQ:
                for item in value:
                    pos = align(pos, 4) + 5 + len(item.encode('utf-8'))
            else:
                for i, item in enumerate(value):
                    pos = _walk(item, pos, here + (i,), out, pads)
    return pos


def serialized(msg: Any) -> bytes:
    """``serialize_message(msg)`` as the bag stores it and a :class:`Template` packs it:
    trimmed to the stream padded to 4 bytes, every padding byte 0 (:func:`without_padding`)."""
    from rclpy.serialization import serialize_message
    return without_padding(serialize_message(msg), msg)


class Template:
    """The CDR bytes of a message of fixed layout, re-packed with new values of a few of its
    primitive fields (sim_node's /clock, joint states and markers at every step).

    `msg` is serialised once (:func:`serialized`); `fields` names the fields that change,
    each by its :func:`field_offsets` path and a ``struct`` code of what starts there, e.g.
    ``(('header', 'stamp', 'sec'), 'iI')`` (a Time: int32 sec, uint32 nanosec) or
    ``(('position',), '3d')`` (the elements of a float64[] of length 3). :meth:`pack` then
    builds the bytes with one ``struct`` call. :meth:`matches` compares it with
    :func:`serialized` of filled messages, so an encoder can fall back to serialising.
    """

    def __init__(self, msg: Any, fields: Sequence[tuple[tuple, str]]) -> None:
        self.data = serialized(msg)
        offsets = field_offsets(msg)
        spans = sorted((offsets[path], code, k) for k, (path, code) in enumerate(fields))
        fmt, args, self._slots, cut = '<', [], [slice(0)] * len(fields), 0
        for at, code, k in spans:
            if at < cut:
                raise ValueError(f'CDR template: field {fields[k][0]} overlaps the one before')
            if at > cut:
                fmt += f'{at - cut}s'
                args.append(self.data[cut:at])
            current = struct.unpack_from('<' + code, self.data, at)
            self._slots[k] = slice(len(args), len(args) + len(current))
            args += current
            fmt += code
            cut = at + struct.calcsize('<' + code)
        if cut < len(self.data):
            fmt += f'{len(self.data) - cut}s'
            args.append(self.data[cut:])
        self._struct = struct.Struct(fmt)
        self._args = args
        if len(fields) == 1:                # /clock after every step: one call, no list
            pack, slot = self._struct.pack, self._slots[0]
            before, after = tuple(args[:slot.start]), tuple(args[slot.stop:])
            self.pack = lambda value: pack(*before, *value, *after)

    def pack(self, *values: Sequence) -> bytes:
        """The message's bytes with each field of `fields` set to its entry of `values` (a
        sequence of as many numbers as its code packs)."""
        args = self._args.copy()
        for slot, value in zip(self._slots, values):
            args[slot] = value
        return self._struct.pack(*args)

    def matches(self, cases: Iterable[tuple[Sequence, Any]]) -> bool:
        """True if ``pack(*values)`` is ``serialized(msg)`` for every (values, msg)."""
        return all(self.pack(*values) == serialized(msg) for values, msg in cases)
