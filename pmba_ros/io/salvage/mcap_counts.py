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
"""How many messages a damaged MCAP file, or a stretch of it, held: what a salvage lost.

A chunk that does not read loses its messages, and the salvage says how many where the
file still counts them: the message index records a writer puts after each chunk (one per
channel, one entry per message; ``ros2 bag record`` writes them), which stay readable when
the chunk itself is not, and the message count of the summary's statistics record, when
the file has a summary. A count is given only when it is whole: a stretch whose records do
not follow each other to its end, or a chunk without its message indexes, has none.
"""

from __future__ import annotations

import mmap
import struct

from pmba_ros.io.mcap_layout import chunk_body_length, FOOTER_SIZE, MAGIC

__all__ = ['stretch_messages', 'summary_messages']

_FOOTER, _MESSAGE, _CHUNK, _MESSAGE_INDEX, _STATISTICS = 0x02, 0x05, 0x06, 0x07, 0x0B
_OPCODES = range(0x01, 0x10)
"""The opcodes the MCAP specification defines; a damaged stretch holding another is not counted."""

_INDEX_ENTRY = 8 + 8
"""A message index entry: the message's log time and its offset in the chunk."""


def stretch_messages(data: mmap.mmap, start: int, end: int) -> int | None:
    """Return how many messages the records from ``start`` to ``end`` hold, or None if unknown.

    The chunks are counted by the message index records after each, a message outside a
    chunk as one. A chunk record whose length runs past ``end`` is stepped over by the length
    its head gives.
    """
    pos, count, unindexed = start, 0, False
    while pos < end:
        if pos + 9 > end or data[pos] not in _OPCODES:
            return None
        opcode = data[pos]
        (length,) = struct.unpack_from('<Q', data, pos + 1)
        if opcode == _CHUNK and length > end - pos - 9:
            length = chunk_body_length(data, pos) or length
        if length > end - pos - 9:
            return None
        if opcode == _CHUNK:
            if unindexed:
                return None
            unindexed = True
        elif opcode == _MESSAGE_INDEX:
            entries = _index_entries(data, pos, length)
            if entries is None:
                return None
            count += entries
            unindexed = False
        elif opcode == _MESSAGE:
            count += 1
        pos += 9 + length
    if unindexed:   # the stretch ends with the chunk: its message indexes may follow
        following = _following_indexes(data, pos)
        return None if following is None else count + following
    return count


def _following_indexes(data: mmap.mmap, pos: int) -> int | None:
    """Return the entries of the message index records from ``pos`` on, or None if none is."""
    count = None
    while pos + 9 <= len(data) and data[pos] == _MESSAGE_INDEX:
        (length,) = struct.unpack_from('<Q', data, pos + 1)
        entries = _index_entries(data, pos, length) if length <= len(data) - pos - 9 else None
        if entries is None:
            return None
        count = (count or 0) + entries
        pos += 9 + length
    return count


def _index_entries(data: mmap.mmap, pos: int, length: int) -> int | None:
    """Return the entries of the message index record at ``pos``, or None if it is damaged."""
    if length < 2 + 4:   # channel id (u16), entries' byte length (u32)
        return None
    (size,) = struct.unpack_from('<I', data, pos + 9 + 2)
    if size % _INDEX_ENTRY or size > length - 6:
        return None
    return size // _INDEX_ENTRY


def summary_messages(data: mmap.mmap) -> int | None:
    """Return the message count of the file's summary statistics, or None without them.

    Only from a summary whose records follow each other from its start to the footer.
    """
    footer = len(data) - FOOTER_SIZE
    if footer < len(MAGIC) or data[-len(MAGIC):] != MAGIC or data[footer] != _FOOTER:
        return None
    (pos,) = struct.unpack_from('<Q', data, footer + 9)
    if pos < len(MAGIC):   # 0: no summary
        return None
    count = None
    while pos < footer:
        if pos + 9 > footer:
            return None
        (length,) = struct.unpack_from('<Q', data, pos + 1)
        if length > footer - pos - 9:
            return None
        if data[pos] == _STATISTICS and length >= 8:
            (count,) = struct.unpack_from('<Q', data, pos + 9)
        pos += 9 + length
    return count
