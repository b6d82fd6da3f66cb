"""Check an MCAP file's framing and every CRC before anything of it is trusted, record by
record (no summary needed): the magic at both ends, every record inside the file and inside
each chunk, each chunk's size and CRC, each attachment's CRC, the data-section and summary
CRCs; a stored CRC of 0 ("not computed") is not checked (docs/bag-format.md, "Damage: what
our readers check")."""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import stat
import struct
import zlib

from .bag import BagError

MAGIC = b'\x89MCAP0\r\n'
OP_HEADER, OP_FOOTER, OP_CHUNK, OP_MESSAGE_INDEX = 0x01, 0x02, 0x06, 0x07
OP_ATTACHMENT, OP_DATA_END = 0x09, 0x0F

RECOVER_HINT = ('run `ros2 run abd_joint_sim bag_recover {bag}` (or `python -m '
                'abd_joint_sim.tools.bag_recover {bag}`) to keep its intact chunks')


class BagDamageError(BagError):
    """The bag file is damaged (CRC mismatch, truncation, broken framing)."""

    def __init__(self, message: str, damage: list['Damage']) -> None:
        super().__init__(message)
        self.damage = damage


@dataclass(frozen=True)
class Damage:
    """One damaged place: what (``'chunk 3'``, ``'attachment scene.yaml'``, ``'summary'``),
    the byte offset of its record and why."""

    what: str
    offset: int
    why: str

    def __str__(self) -> str:
        return f'{self.what} at byte {self.offset}: {self.why}'


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == '':
        return data
    if compression == 'zstd':
        import zstandard
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == 'lz4':
        import lz4.frame
        return lz4.frame.decompress(data)
    raise ValueError(f'unknown compression {compression!r}')


def _mismatch(actual: int, stored: int, where: str = '') -> str:
    """'' if the CRC `stored` is 0 ("not computed") or `actual`, else the mismatch."""
    return '' if stored in (0, actual) else \
        f'CRC {actual:#010x} computed, {stored:#010x} stored{where}'


def _string(buf, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from('<I', buf, pos)
    return bytes(buf[pos + 4:pos + 4 + n]).decode('utf-8', errors='replace'), pos + 4 + n


def check_chunk(content) -> str:
    """'' if a Chunk record's content (after opcode and length) is intact, else why not."""
    try:
        _start, _end, size, crc = struct.unpack_from('<QQQI', content, 0)
        compression, pos = _string(content, 28)
        (n,) = struct.unpack_from('<Q', content, pos)
        pos += 8
        if pos + n > len(content):
            return f'its records field ({n} bytes) runs past the record'
        data = _decompress(compression, bytes(content[pos:pos + n]), size)
    except Exception as exc:  # noqa: BLE001 - zstd/lz4/struct errors of every kind
        return f'does not decompress ({type(exc).__name__}: {exc})'.replace(' ()', '')
    if len(data) != size:
        return f'decompresses to {len(data)} bytes, {size} stated'
    if why := _mismatch(zlib.crc32(data) if crc else 0, crc):
        return why
    pos = 0
    while pos < len(data):
        if pos + 9 > len(data):
            return f'a record inside it is cut at byte {pos}'
        (length,) = struct.unpack_from('<Q', data, pos + 1)
        pos += 9 + length
        if pos > len(data):
            return f'a record inside it runs past its end ({length} bytes)'
    return ''


def _check_attachment(content) -> tuple[str, str]:
    """(name, '' or why) for an Attachment record's content."""
    try:
        pos = 16
        name, pos = _string(content, pos)
        _media, pos = _string(content, pos)
        (n,) = struct.unpack_from('<Q', content, pos)
        pos += 8 + n
        (crc,) = struct.unpack_from('<I', content, pos)
    except struct.error:
        return '?', 'its fields run past the record'
    return name, _mismatch(zlib.crc32(content[:pos]) if crc else 0, crc)


def scan(file: str | os.PathLike[str]) -> list[Damage]:
    """The damage found in `file`, in file order (none: it is intact and complete)."""
    path = Path(file)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BagError(f"bag file '{path}': {exc.strerror or exc}") from None
    if not data:
        return [Damage('file', 0, 'it is empty (0 bytes)')]
    return _scan(memoryview(data), len(data))


def _scan(buf, size: int, visit=None) -> list[Damage]:
    """:func:`scan` of the bytes `buf`; ``visit(pos, opcode, end, damage)`` (if given) is
    called for each record that fits in the file, up to the Footer (`damage`: the chunk's or
    attachment's :class:`Damage`, else None)."""
    if size < len(MAGIC) or bytes(buf[:len(MAGIC)]) != MAGIC:
        return [Damage('file', 0, 'it does not start with the MCAP magic')]
    damage: list[Damage] = []
    chunk_no, pos, data_crc = 0, len(MAGIC), zlib.crc32(buf[:len(MAGIC)])
    in_data = True
    complete = False
    while pos < size:
        if pos + 9 > size:
            damage.append(Damage('record', pos, f'cut: {size - pos} byte(s) left of its '
                                 'opcode and length (the file is truncated)'))
            break
        op = buf[pos]
        (length,) = struct.unpack_from('<Q', buf, pos + 1)
        end = pos + 9 + length
        if end > size:
            what = f'chunk {chunk_no}' if op == OP_CHUNK else f'record (opcode {op:#04x})'
            damage.append(Damage(what, pos, f'its {length} bytes run past the end of the '
                                 f'file ({size} bytes; truncated, or its length is damaged)'))
            break
        content = buf[pos + 9:end]
        if op == OP_DATA_END:
            in_data = False
            (stored,) = struct.unpack_from('<I', content, 0) if length >= 4 else (0,)
            why = _mismatch(data_crc, stored, f' in DataEnd at byte {pos}')
            if why and not damage:
                damage.append(Damage('data section', 0, why))
        elif in_data:
            data_crc = zlib.crc32(buf[pos:end], data_crc)
        hurt = None
        if op == OP_CHUNK:
            why = check_chunk(content)
            hurt = Damage(f'chunk {chunk_no}', pos, why) if why else None
            chunk_no += 1
        elif op == OP_ATTACHMENT:
            name, why = _check_attachment(content)
            hurt = Damage(f'attachment {name!r}', pos, why) if why else None
        if hurt:
            damage.append(hurt)
        if visit is not None:
            visit(pos, op, end, hurt)
        if op == OP_FOOTER:
            if length < 20:
                damage.append(Damage('footer', pos, f'{length} bytes long, 20 expected'))
                break
            summary_start, _offsets, crc = struct.unpack_from('<QQI', content, 0)
            if summary_start and summary_start > pos:
                damage.append(Damage('footer', pos, f'summary start {summary_start} lies '
                                     'after the footer'))
            elif crc != 0:
                begin = summary_start or pos
                if why := _mismatch(zlib.crc32(buf[begin:pos + 9 + 16]), crc, ' in the footer'):
                    damage.append(Damage('summary', begin, why))
            pos = end
            if size - pos != len(MAGIC) or bytes(buf[pos:]) != MAGIC:
                damage.append(Damage('file end', pos, 'the closing MCAP magic is missing or '
                                     'followed by other bytes'))
            else:
                complete = not in_data
            break
        pos = end
    else:
        damage.append(Damage('file end', size, 'no footer (the file is truncated)'))
    if not complete and not damage:
        damage.append(Damage('file end', size, 'incomplete'))
    return damage


_checked: dict[tuple, list[Damage]] = {}


def check(file: str | os.PathLike[str], bag: str | os.PathLike[str] | None = None) -> None:
    """Raise :class:`BagDamageError` naming the first damaged record, its byte offset and the
    ``bag_recover`` command for `bag` (default: the file's directory) if `file` is damaged;
    the result is cached per file identity."""
    path = Path(file)
    try:
        st = path.stat()
    except OSError as exc:
        raise BagError(f"bag file '{path}': {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise BagError(f"bag file '{path}' is not a regular file")
    key = (str(path.resolve()), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    damage = _checked.get(key)
    if damage is None:
        damage = scan(path)
        if len(_checked) > 64:
            _checked.clear()
        _checked[key] = damage
    if not damage:
        return
    bag = Path(bag) if bag is not None else path
    if bag.is_file():           # bag_recover takes the bag's directory
        bag = bag.parent
    more = len(damage) - 1
    also = f' (and {more} more damaged record{"s" if more != 1 else ""})' if more else ''
    raise BagDamageError(f"bag file '{path}' is damaged: {damage[0]}{also}; "
                         + RECOVER_HINT.format(bag=bag), list(damage))
