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
"""The rows of a SQLite file's table-leaf pages, read without the B-tree above them.

A table that grows gets its new interior pages at the end of the file: cut short, a large
``.db3`` file loses the pages that lead to its leaves, and no query reaches a row the leaves
still hold. This reads every whole page of the file as SQLite's file format lays it out
(sqlite.org/fileformat2.html): table-leaf pages (type 13), their cells (payload size, rowid,
the record's local part, then overflow pages), and each record's serial types and values.
Pages that are not table leaves, cells whose record or overflow chain does not read (a
page past the cut, a damaged byte), and records of another shape are passed over.
"""

from __future__ import annotations

from collections.abc import Iterator
import mmap
from pathlib import Path
import struct
from typing import Any

__all__ = ['leaf_records']

_TABLE_LEAF = 13
_LEAF_HEADER = 8
_FILE_HEADER = 100
_INT_SIZES = {1: 1, 2: 2, 3: 3, 4: 4, 5: 6, 6: 8}


class _Bad(Exception):
    """A cell or record that does not read (damaged, or its overflow past the file's end)."""


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    """Return a SQLite varint at ``pos`` (1-9 bytes, big-endian) and the position after it."""
    value = 0
    for i in range(8):
        if pos + i >= len(buf):
            raise _Bad
        byte = buf[pos + i]
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, pos + i + 1
    if pos + 8 >= len(buf):
        raise _Bad
    return (value << 8) | buf[pos + 8], pos + 9


def _record(payload: bytes) -> tuple[Any, ...]:
    """Return the values of a record (serial types after its header size; text as bytes)."""
    size, pos = _varint(payload, 0)
    if size > len(payload):
        raise _Bad
    types = []
    while pos < size:
        serial, pos = _varint(payload, pos)
        types.append(serial)
    values: list[Any] = []
    body = size
    for serial in types:
        if serial == 0:
            values.append(None)
        elif serial in _INT_SIZES:
            n = _INT_SIZES[serial]
            values.append(int.from_bytes(payload[body:body + n], 'big', signed=True))
            body += n
        elif serial == 7:
            values.append(struct.unpack_from('>d', payload, body)[0])
            body += 8
        elif serial in (8, 9):
            values.append(serial - 8)
        elif serial >= 12:
            n = (serial - 12) // 2
            values.append(payload[body:body + n])
            body += n
        else:
            raise _Bad
        if body > len(payload):
            raise _Bad
    return tuple(values)


class _Pages:
    """The whole pages of a SQLite file."""

    def __init__(self, data: mmap.mmap) -> None:
        size = int.from_bytes(data[16:18], 'big')
        self.size = 65536 if size == 1 else size
        if self.size < 512 or self.size & (self.size - 1):
            raise _Bad
        self.usable = self.size - data[20]
        self.count = len(data) // self.size
        self.data = data

    def page(self, number: int) -> bytes:
        """Return page ``number`` (1-based)."""
        if not 1 <= number <= self.count:
            raise _Bad
        return self.data[(number - 1) * self.size:number * self.size]

    def payload(self, page: bytes, pos: int) -> tuple[int, bytes]:
        """Return the rowid and whole payload of the table-leaf cell at ``pos``."""
        total, pos = _varint(page, pos)
        rowid, pos = _varint(page, pos)
        u = self.usable
        most = u - 35
        if total <= most:
            local = total
        else:
            least = (u - 12) * 32 // 255 - 23
            local = least + (total - least) % (u - 4)
            local = local if local <= most else least
        parts = [page[pos:pos + local]]
        if len(parts[0]) < local:
            raise _Bad
        got = local
        if total > local:
            nxt = int.from_bytes(page[pos + local:pos + local + 4], 'big')
            seen = set()
            while got < total:
                if nxt in seen:
                    raise _Bad
                seen.add(nxt)
                over = self.page(nxt)
                nxt = int.from_bytes(over[:4], 'big')
                part = over[4:4 + min(u - 4, total - got)]
                parts.append(part)
                got += len(part)
        return rowid, b''.join(parts)


def leaf_records(path: Path, columns: int) -> Iterator[tuple[int, tuple[Any, ...]]]:
    """Yield ``(rowid, values)`` of every readable record of ``columns`` values in ``path``.

    In page order, from every table-leaf page of every table (the caller tells its rows by
    their shape); a rowid may repeat (an old copy of a page SQLite rewrote elsewhere).
    """
    with path.open('rb') as fh:
        if fh.seek(0, 2) < _FILE_HEADER:
            return
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
            yield from _records(data, columns)


def _records(data: mmap.mmap, columns: int) -> Iterator[tuple[int, tuple[Any, ...]]]:
    """Yield the records of :func:`leaf_records` from the file's bytes."""
    try:
        pages = _Pages(data)
    except _Bad:
        return
    for number in range(1, pages.count + 1):
        page = pages.page(number)
        head = _FILE_HEADER if number == 1 else 0
        if page[head] != _TABLE_LEAF:
            continue
        cells = int.from_bytes(page[head + 3:head + 5], 'big')
        pointers = head + _LEAF_HEADER
        for i in range(cells):
            pos = int.from_bytes(page[pointers + 2 * i:pointers + 2 * i + 2], 'big')
            if not pointers + 2 * cells <= pos < pages.usable:
                continue
            try:
                rowid, payload = pages.payload(page, pos)
                values = _record(payload)
            except (_Bad, struct.error):
                continue
            if len(values) == columns:
                yield rowid, values
