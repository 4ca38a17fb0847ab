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
"""The readable part of an MCAP file that cannot be opened (a recorder killed mid-run).

``ros2 bag record`` writes an MCAP file's index (summary and footer) when it closes it; a
recorder that is killed, or a disk that fills up, leaves a file without one, and rosbags
refuses the whole file ("File end magic is invalid"): every keyframe before the damage was
lost. :func:`salvage_mcap` copies the complete chunks of such a file into a new, indexed
file, as ``mcap recover`` does, and says what was lost. A damaged record is stepped over,
named by its own offset: reading starts again at the next chunk that reads whole (or, with
no chunk after it, at the record after it by its length), and the schemas and channels are
taken from wherever they read (a later chunk, the summary). A chunk whose length field alone
is damaged (past the end of the file: flipped bits) is read by the length its own head
gives, where it reads whole there, and said so: the first chunk holds the schemas and
channels, and its loss had lost every message of the file.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
import io
import mmap
from pathlib import Path
import struct
from typing import Any

from pmba_ros.errors import BagError
from pmba_ros.io.mcap_layout import chunk_body_length, CHUNK_HEAD, MAGIC
from pmba_ros.io.salvage.common import Salvaged
from pmba_ros.io.salvage.mcap_counts import stretch_messages, summary_messages
from pmba_ros.io.salvage.ros1_mcap import is_ros1_channel, ROS1_ENCODING, write_ros1_bag

__all__ = ['salvage_mcap']

_FOOTER, _CHUNK = 0x02, 0x06
_OPCODES = range(0x01, 0x10)
"""The opcodes the MCAP specification defines (0x00 is none: zeroed bytes)."""


def _stream_errors() -> tuple[type[BaseException], ...]:
    """Return what the mcap readers raise on a truncated or corrupt record."""
    from mcap.exceptions import McapError
    # A damaged length asks a buffer for more than it can hold: OverflowError, MemoryError.
    errors: list[type[BaseException]] = [McapError, EOFError, ValueError, KeyError,
                                         StopIteration, struct.error, OSError,
                                         ArithmeticError, MemoryError]
    try:
        import zstandard
        errors.append(zstandard.ZstdError)
    except ImportError:   # the mcap reader then cannot read zstd chunks at all
        pass
    return tuple(errors)


@dataclass
class _Walk:
    """What reading a damaged file met: the stretches skipped, chunks repaired, where it stopped.

    ``repaired`` holds (offset, stored length, length read by) of each chunk record whose
    length field was damaged.
    """

    skipped: list[tuple[int, int]] = field(default_factory=list)
    repaired: list[tuple[int, int, int]] = field(default_factory=list)
    stopped: str = 'at the end of the file'
    partly: dict[int, int] = field(default_factory=dict)
    """Damaged chunks read up to their damage: offset -> messages read."""

    def skip(self, start: int, end: int) -> None:
        """Note the bytes from ``start`` to ``end`` as skipped: one stretch with one before."""
        if self.skipped and self.skipped[-1][1] == start:
            start = self.skipped.pop()[0]
        self.skipped.append((start, end))


def _records(path: Path, walk: _Walk) -> Iterator[Any]:
    """Yield the records of an MCAP file, stepping over damaged ones to the next chunk.

    Record by record, each by its own length: a damaged record is named by its own offset,
    and a chunk whose length field alone is damaged is read by the length its head gives.
    """
    errors = _stream_errors()
    if path.stat().st_size == 0:   # nothing to map
        walk.stopped = 'at once: the file is empty'
        return
    with path.open('rb') as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
        pos: int | None = len(MAGIC)
        if data[:len(MAGIC)] != MAGIC:
            walk.skip(0, len(MAGIC))
        while pos is not None and pos < len(data):
            records, pos = _read(data, pos, walk, errors)
            yield from records


def _read(data: mmap.mmap, pos: int, walk: _Walk,
          errors: tuple[type[BaseException], ...]) -> tuple[list[Any], int | None]:
    """Return the records of the record at ``pos`` and where reading goes on (None: stop)."""
    size = len(data)
    if pos + 9 > size:
        walk.stopped = f'where the file ends, at byte {size}, in the middle of a record'
        return [], None
    opcode = data[pos]
    (length,) = struct.unpack_from('<Q', data, pos + 1)
    if opcode == _FOOTER:   # the end magic follows
        return [], None
    fits = length <= size - pos - 9
    if not opcode:
        why = 'opcode 0x00 is no MCAP record'
    elif fits:
        try:
            return _parsed(data, pos, length), pos + 9 + length
        except errors as err:
            why = f'{type(err).__name__}: {err}'
    elif opcode == _CHUNK and (repaired := _repaired_chunk(data, pos, errors)) is not None:
        records, body = repaired
        walk.repaired.append((pos, length, body))
        return records, pos + 9 + body
    else:
        implied = chunk_body_length(data, pos) if opcode == _CHUNK else length
        cut = implied is None or (length <= size and implied > size - pos - 9)
        # A record no longer than the file may be one a killed recorder was writing.
        why = '' if cut else (f'record 0x{opcode:02x} of {length} bytes runs past the end '
                              'of the file')
    nxt = _next_chunk(data, pos, errors)
    if nxt is None and opcode and fits:
        # No chunk follows, but other records may (the chunk's message indexes, the
        # summary's schemas and channels): reading goes on after this one, by its length.
        nxt = pos + 9 + length
    start = _readable_start(data, pos, length, errors) if opcode == _CHUNK and fits else []
    if start:
        from mcap.records import Message
        walk.partly[pos] = sum(isinstance(r, Message) for r in start)
    if nxt is not None:
        walk.skip(pos, nxt)
    elif why:
        walk.stopped = f'at byte {pos} of {size} ({why})'
    else:
        walk.stopped = f'where the file ends, at byte {size}, in the middle of a record'
    return start, nxt


def _parsed(data: mmap.mmap, pos: int, length: int) -> list[Any]:
    """Return the records of the record at ``pos`` of ``length`` bytes (a chunk's, broken up).

    Raises:
        What :func:`_stream_errors` names: the record does not parse, or is a chunk whose
        records do not fit in it or fail their CRC.
    """
    from mcap.stream_reader import breakup_chunk, StreamReader

    if data[pos] == _CHUNK:
        return breakup_chunk(_chunk(data, pos, length), validate_crc=True)
    if data[pos] not in _OPCODES:   # reserved for later versions or private: skipped
        return []
    reader = StreamReader(io.BytesIO(data[pos:pos + 9 + length]), skip_magic=True)
    return [next(iter(reader.records))]


def _chunk(data: mmap.mmap, pos: int, length: int) -> Any:
    """Return the chunk record at ``pos`` read as ``length`` bytes long.

    Raises:
        ValueError: If its records run past ``length`` (the reader reads what is there).
    """
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk

    body = chunk_body_length(data, pos)
    if body is None or body > length:
        msg = f'the chunk at byte {pos} holds more than its {length} bytes'
        raise ValueError(msg)
    return Chunk.read(ReadDataStream(io.BytesIO(data[pos + 9:pos + 9 + body])))


def _readable_start(data: mmap.mmap, pos: int, length: int,
                    errors: tuple[type[BaseException], ...]) -> list[Any]:
    """Return the records a damaged chunk without a CRC holds before its damage.

    Its records are decompressed and parsed as far as they go; the last complete one is
    left out too, as the damage may start inside it. A chunk with a CRC gives none: that it
    failed says nothing of where its damage is.
    """
    from mcap.stream_reader import StreamReader

    try:
        chunk = _chunk(data, pos, length)
    except errors:
        return []
    if chunk.uncompressed_crc:
        return []
    records: list[Any] = []
    reader = StreamReader(io.BytesIO(_decompressed_start(chunk.compression, chunk.data)),
                          skip_magic=True)
    try:
        records.extend(reader.records)
    except errors:
        pass
    return records[:-1]


_PIECE = 4096
"""Compressed bytes given to a decompressor at a time: its output before the damage stays."""


def _decompressed_start(compression: str, body: bytes) -> bytes:
    """Return a chunk's records decompressed as far as they decompress."""
    if compression == '':
        return body
    if compression == 'zstd':
        import zstandard
        decompressor: Any = zstandard.ZstdDecompressor().decompressobj()
    elif compression == 'lz4':
        import lz4.frame
        decompressor = lz4.frame.LZ4FrameDecompressor()
    else:
        return b''
    out = bytearray()
    try:
        for at in range(0, len(body), _PIECE):
            out += decompressor.decompress(body[at:at + _PIECE])
    except Exception:
        pass
    return bytes(out)


def _whole_chunk(data: mmap.mmap, pos: int, length: int,
                 errors: tuple[type[BaseException], ...]) -> list[Any] | None:
    """Return the records of the chunk at ``pos`` read as ``length`` bytes, if it reads whole.

    Whole: its records decompress to the size its head gives, match its CRC (when it has
    one) and parse. Where reading goes on rests on this, so it is stricter than the reading
    of a chunk met in order.
    """
    from mcap.stream_reader import breakup_chunk, get_chunk_data_stream

    try:
        chunk = _chunk(data, pos, length)
        if get_chunk_data_stream(chunk, validate_crc=True)[1] != chunk.uncompressed_size:
            return None
        records: list[Any] = breakup_chunk(chunk)
    except errors:
        return None
    return records


def _repaired_chunk(data: mmap.mmap, pos: int,
                    errors: tuple[type[BaseException], ...]) -> tuple[list[Any], int] | None:
    """Return the records and body length of the chunk at ``pos``, read by its head's length.

    For a chunk whose length field runs past the end of the file (flipped bits): the length
    its head gives is taken if the chunk then reads whole and its end is one: a record
    starts there, or the file ends, unless its CRC already vouches for its records.
    """
    body = chunk_body_length(data, pos)
    if body is None or body > len(data) - pos - 9:
        return None
    end = pos + 9 + body
    (crc,) = struct.unpack_from('<I', data, pos + 9 + 24)
    if not crc and end < len(data) and data[end] not in _OPCODES:
        return None
    records = _whole_chunk(data, pos, body, errors)
    return None if records is None else (records, body)


def _next_chunk(data: mmap.mmap, start: int,
                errors: tuple[type[BaseException], ...]) -> int | None:
    """Return the offset of the first chunk record after ``start`` that reads whole, or None.

    By its length, or by its head's where that runs past the end of the file.
    """
    at = start
    while (at := data.find(bytes([_CHUNK]), at + 1)) >= 0:
        if at + 9 + CHUNK_HEAD > len(data):
            return None
        (length,) = struct.unpack_from('<Q', data, at + 1)
        if CHUNK_HEAD <= length <= len(data) - at - 9:
            if _whole_chunk(data, at, length, errors) is not None:
                return at
        elif length > len(data) - at - 9 and _repaired_chunk(data, at, errors) is not None:
            return at
    return None


ROSBAGS_SCHEMA_ENCODINGS = ('ros2msg', 'ros2idl', 'omgidl', '')
"""The schema encodings rosbags' MCAP reader parses (any other fails the whole file)."""


def salvage_mcap(path: Path, dest: Path, reason: str) -> Salvaged | None:
    """Copy the readable messages of the MCAP file ``path`` into ``dest``.

    Records are read from the start; a record that is incomplete or corrupt (a chunk cut
    short, a CRC mismatch) is stepped over to the next chunk that reads whole. The schemas
    and channels read anywhere are written first, then the messages of the readable chunks,
    with a summary, so rosbags reads the copy like any recording. A file of ROS 1 messages
    (the ``ros1`` profile) is copied into a ROS 1 bag instead (:mod:`.ros1_mcap`).

    Args:
        path: The damaged MCAP file.
        dest: The file to write.
        reason: Why ``path`` is read this way, the damage description's start.

    Returns:
        What was copied, or None if not a single message could be (``dest`` removed).
    """
    from mcap.records import Channel, Header, Message, Schema
    from mcap.writer import Writer

    header: Any = None
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    walk = _Walk()
    for record in _records(path, walk):   # first the schemas and channels, wherever they are
        if isinstance(record, Header) and header is None:
            header = record
        elif isinstance(record, Schema):
            schemas.setdefault(record.id, record)
        elif isinstance(record, Channel):
            channels.setdefault(record.id, record)
    ros1 = {cid: c for cid, c in channels.items() if is_ros1_channel(c, schemas)}
    if len(ros1) == len(channels) and (ros1 or getattr(header, 'profile', '') == ROS1_ENCODING):
        # Named after the original, which an error about the copy then names too.
        return _ros1_copy(path, dest.with_name(f'{dest.name}.bag'), ros1, schemas, walk)
    # A schema rosbags cannot parse (another encoding) makes the whole copy unreadable too.
    foreign = {cid: c for cid, c in channels.items() if c.schema_id in schemas
               and schemas[c.schema_id].encoding not in ROSBAGS_SCHEMA_ENCODINGS}
    if foreign:
        named = ', '.join(f'{c.topic} ({schemas[c.schema_id].name}, schema encoding '
                          f'{schemas[c.schema_id].encoding!r})' for c in foreign.values())
        reason = f'{reason}; {named} skipped: rosbags reads no such schema'
        channels = {cid: c for cid, c in channels.items() if cid not in foreign}
    messages = 0
    if channels:
        with dest.open('wb') as out:
            writer = Writer(out)
            # Without a header that reads (the file's start damaged): rosbag2's profile.
            writer.start(profile='ros2' if header is None else header.profile,
                         library='pmba_ros salvage' if header is None else header.library)
            schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data)
                          for sid, s in schemas.items()
                          if s.encoding in ROSBAGS_SCHEMA_ENCODINGS}
            channel_ids = {cid: writer.register_channel(c.topic, c.message_encoding,
                                                        schema_ids.get(c.schema_id, 0),
                                                        c.metadata)
                           for cid, c in channels.items()}
            for record in _records(path, _Walk()):
                if isinstance(record, Message) and record.channel_id in channel_ids:
                    writer.add_message(channel_ids[record.channel_id], record.log_time,
                                       record.data, record.publish_time, record.sequence)
                    messages += 1
            writer.finish()
    if not messages:
        dest.unlink(missing_ok=True)
        return None
    return Salvaged(dest, messages, _damage(path, walk, messages, reason))


def _ros1_copy(path: Path, dest: Path, channels: dict[int, Any], schemas: dict[int, Any],
               walk: _Walk) -> Salvaged:
    """Copy an MCAP file of ROS 1 messages into the ROS 1 bag ``dest`` (:mod:`.ros1_mcap`).

    A file read whole is no damage: its copy says nothing then. rosbags' refusal of the
    profile is no damage either, so the damage description does not start with it.

    Raises:
        BagError: If a definition does not parse, or not a single message is readable (the
            file's error would say that rosbags reads no such MCAP profile).
    """
    from mcap.records import Message

    try:
        messages = write_ros1_bag(dest, channels, schemas, (
            r for r in _records(path, _Walk()) if isinstance(r, Message)))
    except BagError as err:
        dest.unlink(missing_ok=True)
        msg = f'{path}: {err}'
        raise BagError(msg) from err
    reason = 'an MCAP file of ROS 1 messages, read as a ROS 1 bag'
    if not messages:
        dest.unlink(missing_ok=True)
        msg = f'{path}: {_damage(path, walk, 0, reason)}; not a message is readable'
        raise BagError(msg)
    whole = not walk.skipped and not walk.repaired and walk.stopped == _Walk.stopped
    return Salvaged(dest, messages, '' if whole else _damage(path, walk, messages, reason))


def _read_before_damage(walk: _Walk, start: int, end: int) -> str:
    """Return the words on the messages read from before the damage of chunks in a stretch."""
    n = sum(count for at, count in walk.partly.items() if start <= at < end)
    return f' ({n} of them read, from before the damage)' if n else ''


def _damage(path: Path, walk: _Walk, messages: int, reason: str) -> str:
    """Return what was wrong with ``path``, what was repaired and what reading it lost.

    The messages lost are counted where the file still counts them
    (:mod:`.mcap_counts`): in all by its summary, in a skipped stretch by its message
    indexes.
    """
    with path.open('rb') as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
        total = summary_messages(data)
        held = [stretch_messages(data, a, b) for a, b in walk.skipped]
    read = f'{messages} messages read'
    if total is not None:
        read += f' of the {total} its summary counts ({max(total - messages, 0)} lost)'
    repaired = ''.join(f', the chunk at byte {at} read by the length its head gives ({body} '
                       f'bytes: its record length {stored} is damaged)'
                       for at, stored, body in walk.repaired[:3])
    if len(walk.repaired) > 3:
        repaired += f' and {len(walk.repaired) - 3} more chunks so'
    skipped = ''.join(f', bytes {a}-{b} skipped (damaged)'
                      + ('' if n is None else f' with their {n} messages' if n else
                         ' holding no message')
                      + _read_before_damage(walk, a, b)
                      for (a, b), n in zip(walk.skipped[:3], held, strict=False))
    if len(walk.skipped) > 3:
        skipped += f' and {len(walk.skipped) - 3} more damaged stretches'
        if None not in held[3:]:
            skipped += f' with {sum(n for n in held[3:] if n is not None)} messages'
    lost = '' if walk.stopped == _Walk.stopped else ', the rest of the file is lost'
    return f'{reason}; {read}{repaired}{skipped}; reading stopped {walk.stopped}{lost}'
