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
file, as ``mcap recover`` does, and says what was lost. A damaged record is stepped over:
reading starts again at the next chunk whose record parses and whose CRC holds, and the
schemas and channels are taken from wherever they read (a later chunk, the summary).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
import io
import mmap
from pathlib import Path
import struct
from typing import Any

from pmba_ros.io.salvage.common import Salvaged

__all__ = ['salvage_mcap']

_CHUNK = 0x06
"""The opcode of a chunk record."""

_CHUNK_HEAD = 8 + 8 + 8 + 4 + 4 + 8
"""A chunk record's least body: start and end time, sizes, CRC, compression, records length."""


def _stream_errors() -> tuple[type[BaseException], ...]:
    """Return what the mcap stream reader raises on a truncated or corrupt file."""
    from mcap.exceptions import McapError
    # A damaged length asks a buffer for more than it can hold: OverflowError, MemoryError.
    errors: list[type[BaseException]] = [McapError, EOFError, ValueError, KeyError,
                                         struct.error, OSError, ArithmeticError, MemoryError]
    try:
        import zstandard
        errors.append(zstandard.ZstdError)
    except ImportError:   # the mcap reader then cannot read zstd chunks at all
        pass
    return tuple(errors)


@dataclass
class _Walk:
    """What reading a damaged file met: the stretches skipped and where it stopped."""

    skipped: list[tuple[int, int]] = field(default_factory=list)
    stopped: str = 'at the end of the file'


def _records(path: Path, walk: _Walk) -> Iterator[Any]:
    """Yield the records of an MCAP file, stepping over damaged ones to the next chunk."""
    from mcap.exceptions import EndOfFile
    from mcap.stream_reader import StreamReader

    errors = _stream_errors()
    if path.stat().st_size == 0:   # nothing to map
        walk.stopped = 'at once: the file is empty'
        return
    with path.open('rb') as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
        pos, size = 0, len(data)
        while pos < size:
            fh.seek(pos)
            # No record is longer than the rest of the file: a damaged length beyond it is
            # refused before the reader asks for a buffer of it (up to its 4 GiB limit), and
            # stepped over as other damage is.
            reader = StreamReader(fh, skip_magic=pos > 0, validate_crcs=True,
                                  record_size_limit=size - pos)
            try:
                yield from reader.records
                return
            except EndOfFile:
                walk.stopped = f'where the file ends, at byte {size}, in the middle of a record'
                return
            except errors as err:
                bad = fh.tell()
                nxt = _next_chunk(data, bad, errors)
                if nxt is None:
                    walk.stopped = f'at byte {bad} of {size} ({type(err).__name__}: {err})'
                    return
                walk.skipped.append((bad, nxt))
                pos = nxt


def _next_chunk(data: mmap.mmap, start: int,
                errors: tuple[type[BaseException], ...]) -> int | None:
    """Return the offset of the first chunk record after ``start`` that reads whole, or None."""
    from mcap.records import Chunk
    from mcap.stream_reader import breakup_chunk, StreamReader

    unreadable: tuple[type[BaseException], ...] = (StopIteration, *errors)
    at = start
    while (at := data.find(bytes([_CHUNK]), at + 1)) >= 0:
        if at + 9 + _CHUNK_HEAD > len(data):
            return None
        (length,) = struct.unpack_from('<Q', data, at + 1)
        if not _CHUNK_HEAD <= length <= len(data) - at - 9:
            continue
        try:
            reader = StreamReader(io.BytesIO(data[at:at + 9 + length]), skip_magic=True,
                                  emit_chunks=True)
            record = next(iter(reader.records))
            if isinstance(record, Chunk):
                breakup_chunk(record, validate_crc=True)
                return at
        except unreadable:
            continue
    return None


def salvage_mcap(path: Path, dest: Path, reason: str) -> Salvaged | None:
    """Copy the readable messages of the MCAP file ``path`` into ``dest``.

    Records are read from the start; a record that is incomplete or corrupt (a chunk cut
    short, a CRC mismatch) is stepped over to the next chunk that reads whole. The schemas
    and channels read anywhere are written first, then the messages of the readable chunks,
    with a summary, so rosbags reads the copy like any recording.

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
    messages = 0
    if channels:
        with dest.open('wb') as out:
            writer = Writer(out)
            # Without a header that reads (the file's start damaged): rosbag2's profile.
            writer.start(profile='ros2' if header is None else header.profile,
                         library='pmba_ros salvage' if header is None else header.library)
            schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data)
                          for sid, s in schemas.items()}
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
    skipped = ''.join(f', bytes {a}-{b} skipped (damaged)' for a, b in walk.skipped[:3])
    if len(walk.skipped) > 3:
        skipped += f' and {len(walk.skipped) - 3} more damaged stretches'
    lost = '' if walk.stopped == _Walk.stopped else ', the rest of the file is lost'
    damage = f'{reason}; {messages} messages read{skipped}; reading stopped {walk.stopped}{lost}'
    return Salvaged(dest, messages, damage)
