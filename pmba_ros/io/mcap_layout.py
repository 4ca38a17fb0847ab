# Copyright 2026 pmba_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""The record lengths of an MCAP file that rosbags reads by, checked before it reads them.

rosbags reads an MCAP file's header, summary and chunks by the lengths stored in them, with
a file read of that many bytes: a damaged length (flipped bits, a summary offset that no
longer points at a record) asked for a buffer of up to 2**64 bytes, and the bag "could not
be opened: MemoryError", naming no record. :func:`mcap_damage` walks the records rosbags
reads when it opens a file (the header, and the summary, or the data section of a file
without one) and the chunks the summary's chunk indexes point at, reading nine bytes per
record, and names the first whose length runs past the end of the file, or whose chunk index
claims more uncompressed bytes than any compression expands its chunk to; then the chunks
whose records carry a CRC, the first whose records do not match it (rosbags stopped reading
there, "Chunk checksum mismatch.", naming no chunk). Everything else (a record cut short, an
unknown opcode, a chunk that does not decompress) is left to rosbags, which names it itself;
the file is then salvaged as any other that cannot be opened (:mod:`pmba_ros.io.salvage`),
which steps over a chunk whose CRC fails.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
import mmap
from pathlib import Path
import struct
from typing import Any
import zlib

from pmba_ros.errors import BagError, FormatError

__all__ = ['CHUNK_HEAD', 'FOOTER_SIZE', 'MAGIC', 'check_mcap_lengths', 'chunk_body_length',
           'mcap_damage', 'zstd_module']

MAGIC = b'\x89MCAP0\r\n'
_HEADER, _FOOTER, _CHUNK, _CHUNK_INDEX, _SUMMARY_OFFSET = 0x01, 0x02, 0x06, 0x08, 0x0E
FOOTER_SIZE = 1 + 8 + 8 + 8 + 4 + 8
"""Footer record (opcode, length, summary start, summary offset start, CRC) and end magic."""

CHUNK_HEAD = 8 + 8 + 8 + 4 + 4 + 8
"""A chunk record's least body: start and end time, sizes, CRC, compression, records length."""

MAX_EXPANSION = 32768
"""Most uncompressed bytes per compressed byte of a chunk, by any compression MCAP uses.

zstd expands most: its densest block, a run of one byte, is a 3-byte header and that byte
for at most 128 KiB (131072 / 4); lz4 stays below 255, no compression at 1. A chunk index
that claims more was damaged: rosbags failed on the chunk mid-read ("Chunk size mismatch"),
losing its messages, and the mcap reader asked for a buffer of up to 2**64 bytes ("Python
int too large to convert to C ssize_t")."""


def check_mcap_lengths(files: Iterable[Path]) -> None:
    """Refuse an MCAP file with a record length past its section before rosbags reads it.

    rosbags asked for a buffer of the damaged length (MemoryError, naming no record); the
    message names the record and its offset, and the file is salvaged as any other that
    cannot be opened (:func:`pmba_ros.io.bags.open_bags`). Other files are left alone.

    Raises:
        BagError: Naming the file and the damaged record; its cause, a FormatError, names
            the record alone.
    """
    for file in files:
        if file.suffix != '.mcap' or not file.is_file():
            continue
        try:
            damage = mcap_damage(file)
        except (OSError, ValueError):   # unreadable, or empty (mmap): rosbags says so
            continue
        if damage is not None:
            cause = FormatError(damage)
            msg = f'{file}: cannot open bag (not a bag, truncated or corrupt?): {damage}'
            raise BagError(msg) from cause


def mcap_damage(path: Path) -> str | None:
    """Return which record of an MCAP file has a length past the end of the file, or None.

    Only the records rosbags reads at opening, and the chunks it reads messages from, are
    checked (see the module docstring), and only against the end of the file: a length that
    stays inside it asks for no more than the file holds, and rosbags reads it or names
    what is wrong. None for a file too short or without the end magic, which rosbags
    refuses itself.

    Raises:
        OSError: If the file cannot be read.
    """
    size = path.stat().st_size
    if size < len(MAGIC) + 9 + FOOTER_SIZE:
        return None
    with path.open('rb') as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
        footer = size - FOOTER_SIZE
        if data[:8] != MAGIC or data[-8:] != MAGIC or data[footer] != _FOOTER:
            return None
        if data[len(MAGIC)] != _HEADER:
            return None   # rosbags: "Unexpected record"
        if (damage := _overrun(data, len(MAGIC))) is not None:
            return damage
        (header_length,) = struct.unpack_from('<Q', data, len(MAGIC) + 1)
        data_start = len(MAGIC) + 9 + header_length
        (summary_start,) = struct.unpack_from('<Q', data, footer + 9)
        if not summary_start:   # rosbags scans the data section
            damage, data_end = _walk(data, data_start, footer, summary=False), footer
        elif not data_start <= summary_start <= footer:
            return None   # rosbags: "Invalid MCAP summary offset"
        else:
            damage = _walk(data, summary_start, footer, summary=True)
            data_end = summary_start
        return damage or _failed_crc(data, data_start, data_end)


def chunk_body_length(data: mmap.mmap, pos: int) -> int | None:
    """Return the body length of the chunk record at ``pos`` by its own head, or None.

    The head's compression name and records length give it whatever the record's length
    field says: the field damaged, the chunk still reads. None if the head runs past the end
    of ``data``.
    """
    body = pos + 9
    if body + CHUNK_HEAD > len(data):
        return None
    (name_size,) = struct.unpack_from('<I', data, body + 28)
    if body + CHUNK_HEAD + name_size > len(data):
        return None
    (records,) = struct.unpack_from('<Q', data, body + 32 + name_size)
    return CHUNK_HEAD + name_size + records


def _overrun(data: mmap.mmap, pos: int) -> str | None:
    """Return the message for the record at ``pos`` if its length runs past the file's end."""
    left = len(data) - pos - 9
    if left < 0:
        return None   # cut short: rosbags reads the nine bytes and says so
    (length,) = struct.unpack_from('<Q', data, pos + 1)
    if length <= left:
        return None
    return (f'the MCAP record at byte {pos} (opcode 0x{data[pos]:02x}) is damaged: its length '
            f'{length} runs {length - left} bytes past the end of the file ({len(data)} bytes)')


def _walk(data: mmap.mmap, pos: int, end: int, summary: bool) -> str | None:
    """Check the records from ``pos`` up to ``end``, as rosbags reads them.

    In the ``summary``, up to a footer or summary offset record, and the chunks its chunk
    indexes point at too.
    """
    while pos < end:
        if summary and data[pos] in (_FOOTER, _SUMMARY_OFFSET):
            return None   # where rosbags stops reading the summary
        if (damage := _overrun(data, pos)) is not None or pos + 9 > end:
            return damage
        (length,) = struct.unpack_from('<Q', data, pos + 1)
        if summary and data[pos] == _CHUNK_INDEX:
            if (damage := _indexed_chunk(data, pos, length)) is not None:
                return damage
        pos += 9 + length
    return None


def _indexed_chunk(data: mmap.mmap, pos: int, length: int) -> str | None:
    """Check the read of the chunk a chunk index record at ``pos`` points at.

    rosbags reads the chunk's compressed records by the index's ``compressed_size``, past
    the chunk's head at the index's ``chunk_start_offset`` (not by the chunk record's own
    length, which it does not read).
    """
    body = pos + 9
    if length < 40:
        return None   # rosbags' parse of the record fails without reading the file
    (start,) = struct.unpack_from('<Q', data, body + 16)
    (offsets_size,) = struct.unpack_from('<I', data, body + 32)
    at = body + 36 + offsets_size + 8   # past the message index offsets and their length
    if at + 4 > body + length:
        return None
    (name_size,) = struct.unpack_from('<I', data, at)
    at += 4 + name_size
    if at + 8 > body + length:
        return None
    (compressed_size,) = struct.unpack_from('<Q', data, at)
    first = start + 9 + 40 + name_size   # where rosbags starts reading the compressed bytes
    if first + compressed_size > len(data):
        return (f'the MCAP chunk index at byte {pos} is damaged: its chunk at byte {start} '
                f'with {compressed_size} compressed bytes runs past the end of the file '
                f'({len(data)} bytes)')
    if at + 16 > body + length:
        return None
    (uncompressed_size,) = struct.unpack_from('<Q', data, at + 8)
    return _expansion(f'the MCAP chunk index at byte {pos}', compressed_size, uncompressed_size)


def _expansion(what: str, compressed_size: int, uncompressed_size: int) -> str | None:
    """Return the damage of a chunk claiming more than :data:`MAX_EXPANSION` times its data."""
    if uncompressed_size <= MAX_EXPANSION * compressed_size:
        return None
    return (f'{what} is damaged: its {uncompressed_size} uncompressed bytes are more than '
            f'{MAX_EXPANSION} times its {compressed_size} compressed bytes, more than any '
            'compression expands to')


def _failed_crc(data: mmap.mmap, pos: int, end: int) -> str | None:
    """Return the damage of the first chunk from ``pos`` to ``end`` whose records fail their CRC.

    A chunk without a CRC (0: not computed), or that does not decompress, is left to rosbags;
    so is a record length past ``end``. Decompressing every chunk once more costs little
    beside reading its messages, and only chunks with a CRC are.
    """
    while pos + 9 <= end:
        (length,) = struct.unpack_from('<Q', data, pos + 1)
        if length > end - pos - 9:
            return None
        if data[pos] == _CHUNK and length >= 40:
            body = pos + 9
            start, stop, size, crc, name_size = struct.unpack_from('<QQQII', data, body)
            at = body + 32 + name_size
            records = struct.unpack_from('<Q', data, at)[0] if at + 8 <= body + length else -1
            decompress = _DECOMPRESS.get(bytes(data[body + 32:at]))
            if crc and decompress is not None and 0 <= records <= body + length - at - 8:
                raw = _decompressed(decompress, data[at + 8:at + 8 + records], size)
                if raw is not None and zlib.crc32(raw) != crc:
                    return (f'the MCAP chunk at byte {pos} (log times {start} to {stop} ns) is '
                            f'damaged: its records do not match their CRC (0x{crc:08x}, '
                            f'computed 0x{zlib.crc32(raw):08x})')
        pos += 9 + length
    return None


def zstd_module() -> Any:
    """Return the zstd module rosbags decompresses MCAP chunks with."""
    try:
        from compression import zstd  # type: ignore[import-not-found, unused-ignore]
    except ImportError:   # Python < 3.14
        from backports import zstd  # type: ignore[import-not-found, no-redef, unused-ignore]
    return zstd


def _lz4(data: bytes) -> bytes:
    from lz4.frame import decompress
    out: bytes = decompress(data)
    return out


_DECOMPRESS: dict[bytes, Callable[[bytes], bytes]] = {
    b'': bytes, b'zstd': lambda data: bytes(zstd_module().decompress(data)), b'lz4': _lz4}
"""A chunk's decompression by its compression's name: the three MCAP has, as rosbags reads them."""


def _decompressed(decompress: Callable[[bytes], bytes], data: bytes, size: int) -> bytes | None:
    """Return a chunk's records decompressed, or None where that fails (rosbags then says so)."""
    try:
        raw = decompress(data)
    except (ValueError, RuntimeError, MemoryError, OverflowError, EOFError,
            zstd_module().ZstdError):
        return None
    return raw if len(raw) == size else None
