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
"""The readable chunks of a ROS 1 bag without its index (``rosbag record`` killed).

``rosbag record`` writes ``NAME.bag.active`` and, when it closes it, appends the index
(connection and chunk-info records), writes the index position into the file header and
renames the file ``NAME.bag``. A recorder that is killed leaves index position 0, which
rosbags refuses whole ("Bag is not indexed, reindex before reading."); rosbags has no
reindexing. :func:`salvage_ros1` reads the records one after the other, as ``rosbag reindex``
does (bag format 2.0: chunks, op 0x05, holding connection records, op 0x07, and message data,
op 0x02), with rosbags' own record parsing and chunk decompressors, and copies the connections
and messages into a new, indexed bag with rosbags' writer. Beyond ``rosbag reindex`` it keeps
the messages of an uncompressed chunk the recorder was still writing (sizes still 0) or that
the file ends in, up to the cut, goes on after a chunk that does not decompress, and after a
record that does not read (the bag's header record, a chunk's header: zeroed or overwritten
bytes) at the next chunk whose header reads; the messages of a connection whose record was in
a lost chunk wait for the copy of it in the index at the file's end.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from io import BytesIO
import os
from pathlib import Path
import struct
from typing import Any, BinaryIO, NamedTuple

from pmba_ros.io.salvage.common import Salvaged

__all__ = ['ACTIVE_SUFFIX', 'salvage_ros1']

ACTIVE_SUFFIX = '.active'
"""What ``rosbag record`` appends to a bag's name while it writes it."""

_MAGIC = b'#ROSBAG V2.0\n'


class _Connection(NamedTuple):
    """A connection record: the bag's id for it, then what rosbags' writer takes."""

    conn: int
    topic: str
    msgtype: str
    msgdef: str
    md5sum: str
    callerid: str | None
    latching: int | None


class _Message(NamedTuple):
    """A message data record."""

    conn: int
    time_ns: int
    data: bytes


def _errors() -> tuple[type[BaseException], ...]:
    """Return what reading a cut or corrupt record raises (bz2: OSError, lz4: RuntimeError)."""
    from rosbags.rosbag1 import ReaderError
    return (ReaderError, struct.error, KeyError, ValueError, EOFError, OSError, RuntimeError)


def _rest(src: BinaryIO, header: Any) -> _Connection | _Message | None:
    """Read the data of the record whose ``header`` was just read; None for other records."""
    from rosbags.rosbag1.reader import Header, read_bytes, read_uint32, RecordType
    from rosbags.typesys.msg import normalize_msgtype

    op = header.get_uint8('op')
    if op == RecordType.MSGDATA:
        data = read_bytes(src, read_uint32(src))
        return _Message(header.get_uint32('conn'), header.get_time('time'), data)
    if op == RecordType.CONNECTION:
        info = Header.read(src)   # the data of a connection record is a header itself
        latching = info.get_string('latching') if 'latching' in info else ''
        return _Connection(header.get_uint32('conn'), header.get_string('topic'),
                           normalize_msgtype(info.get_string('type')),
                           info.get_string('message_definition'), info.get_string('md5sum'),
                           info.get_string('callerid') if 'callerid' in info else None,
                           int(latching) if latching else None)
    src.seek(read_uint32(src), os.SEEK_CUR)
    return None


def _records(src: BinaryIO, end: int) -> tuple[list[_Connection | _Message], BaseException | None]:
    """Read the connection and message records from ``src`` up to ``end`` (a chunk's data).

    Returns:
        The records read, and the error that stopped reading before ``end`` (None if none).
    """
    from rosbags.rosbag1.reader import Header

    records: list[_Connection | _Message] = []
    try:
        while src.tell() < end:
            record = _rest(src, Header.read(src))
            if record is not None:
                records.append(record)
    except _errors() as err:
        return records, err
    return records, None


@dataclass
class _Copy:
    """The new bag being written, and what went into it."""

    writer: Any
    connections: dict[int, Any] = field(default_factory=dict)
    added: dict[tuple[Any, ...], Any] = field(default_factory=dict)
    messages: int = 0
    waiting: dict[int, list[_Message]] = field(default_factory=dict)

    @property
    def orphans(self) -> int:
        """Return how many messages no connection record was found for."""
        return sum(len(m) for m in self.waiting.values())

    def add(self, records: list[_Connection | _Message]) -> None:
        """Write ``records``: a connection once, a message once its connection is known.

        A chunk that holds a connection's record may be lost: the messages of later chunks
        wait for the copy of the record in the index at the file's end.
        """
        for record in records:
            if isinstance(record, _Connection):
                key = record[1:]
                if key not in self.added:   # rosbags' writer takes a connection once
                    self.added[key] = self.writer.add_connection(
                        record.topic, record.msgtype, msgdef=record.msgdef,
                        md5sum=record.md5sum, callerid=record.callerid,
                        latching=record.latching)
                self.connections[record.conn] = self.added[key]
                for message in self.waiting.pop(record.conn, []):
                    self._write(message)
            elif record.conn in self.connections:
                self._write(record)
            else:
                self.waiting.setdefault(record.conn, []).append(record)

    def _write(self, message: _Message) -> None:
        self.writer.write(self.connections[message.conn], message.time_ns, message.data)
        self.messages += 1


@dataclass
class _Scan:
    """How far reading got."""

    chunks: int = 0
    undecompressed: int = 0
    unfinished: int = 0
    stopped: str = 'at its end'
    skipped: list[tuple[int, int]] = field(default_factory=list)


def _read_chunk(src: BinaryIO, header: Any, size: int,
                scan: _Scan) -> list[_Connection | _Message]:
    """Read the chunk whose record ``header`` was just read; skip one that does not decompress.

    Raises:
        The reader's errors if a compressed chunk is cut short (nothing readable follows it).
    """
    from rosbags.rosbag1.reader import decompressors, read_bytes, read_uint32

    compression = header.get_string('compression')
    length = read_uint32(src)
    if compression == 'none' and (length == 0 or src.tell() + length > size):
        # A chunk being written (its sizes are filled in when it is closed), or cut short: its
        # records are in the file up to where it ends.
        records, err = _records(src, size)
        scan.unfinished = sum(isinstance(r, _Message) for r in records)
        scan.stopped = ('at the end of the file, inside a chunk' + (
            f' (a record cut at byte {src.tell()})' if err is not None else ''))
        src.seek(size)
        return records
    data = read_bytes(src, length)
    scan.chunks += 1
    try:
        body = decompressors[compression](data)
    except _errors():
        scan.undecompressed += 1
        return []
    records, err = _records(BytesIO(body), len(body))
    scan.undecompressed += err is not None
    return records


def _describe(reason: str, copy: _Copy, scan: _Scan) -> str:
    """Return what :func:`salvage_ros1` found (without the file's name)."""
    text = f'{reason}; {copy.messages} messages read ({scan.chunks} chunk(s)'
    if scan.unfinished:
        text += f', {scan.unfinished} messages of a chunk the file ends in'
    text += ')'
    if scan.undecompressed:
        text += f', {scan.undecompressed} damaged chunk(s) skipped'
    if scan.skipped:
        spans = ', '.join(f'{a}-{b}' for a, b in scan.skipped[:3])
        more = len(scan.skipped) - 3
        text += f', damaged bytes {spans}' + (f' and {more} more' if more > 0 else '') + \
            ' skipped'
    if copy.orphans:
        text += f', {copy.orphans} messages of connections not in the file skipped'
    return f'{text}; reading stopped {scan.stopped}'


_CHUNK_OP = b'op=\x05'
"""The ``op`` field of a chunk record's header (``name=value``, the value one byte)."""

_FIELDS_BEFORE = 64
"""How far before its ``op`` field a chunk header may start (the other fields are short)."""


def _next_chunk(src: BinaryIO, after: int, size: int) -> int | None:
    """Return where the next chunk record whose header reads starts after byte ``after``.

    A record's header is its length, then fields each of their length and ``name=value``;
    writers order the fields differently, so each start up to :data:`_FIELDS_BEFORE` bytes
    before an ``op`` field is tried.
    """
    from rosbags.rosbag1.reader import Header, RecordType

    pos = after + 1
    block_size = 1 << 20
    while pos < size:
        src.seek(pos)
        block = src.read(block_size)
        hit = block.find(_CHUNK_OP)
        if hit < 0:
            pos += max(len(block) - len(_CHUNK_OP), 1)
            continue
        field = pos + hit - 4
        pos += hit + 1
        for start in range(max(field - 4 - _FIELDS_BEFORE, after + 1), field - 3):
            src.seek(start)
            try:
                header = Header.read(src)
                if header.get_uint8('op') == RecordType.CHUNK and src.tell() > field:
                    return start
            except _errors():
                continue
    return None


def _next(src: BinaryIO, size: int, scan: _Scan) -> list[_Connection | _Message] | None:
    """Read the next record at the top level of the file; None at the end of what is readable.

    Raises:
        The reader's errors if the record is cut short or corrupt.
    """
    from rosbags.rosbag1.reader import Header, RecordType

    if src.tell() >= size:
        return None
    header = Header.read(src)
    op = header.get_uint8('op')
    if op == RecordType.CHUNK:
        return _read_chunk(src, header, size, scan)
    if op == RecordType.BAGHEADER and header.get('encryptor'):
        scan.stopped = 'at its start: the bag is encrypted'
        return None
    record = _rest(src, header)   # index records are skipped: the writer makes its own
    return [] if record is None else [record]


def salvage_ros1(path: Path, dest: Path, reason: str) -> Salvaged | None:
    """Copy the readable messages of the unindexed ROS 1 bag ``path`` into ``dest``.

    Args:
        path: The bag (format 2.0) without its index, or cut short.
        dest: The bag to write (``.bag``), indexed.
        reason: Why ``path`` is read this way, the damage description's start.

    Returns:
        What was copied, or None if not a single message could be (``dest`` removed).
    """
    from rosbags.rosbag1 import Writer

    size = path.stat().st_size
    scan = _Scan()
    with path.open('rb') as src:
        if src.readline() != _MAGIC:   # a damaged start: the chunks after it may read
            first = _next_chunk(src, -1, size)
            if first is None:
                return None
            scan.skipped.append((0, first))
            src.seek(first)
        writer = Writer(dest)
        writer.open()
        copy = _Copy(writer)
        try:
            while True:
                start = src.tell()
                try:
                    records = _next(src, size, scan)
                except _errors() as err:
                    # A damaged record (its header, its length): on at the next chunk.
                    resume = _next_chunk(src, start, size)
                    if resume is None:
                        scan.stopped = (f'at byte {start} of {size} ({type(err).__name__}: '
                                        f'{err}), the rest of the file is lost')
                        break
                    scan.skipped.append((start, resume))
                    src.seek(resume)
                    continue
                if records is None:
                    break
                copy.add(records)
        finally:
            if copy.messages:
                writer.close()
            else:
                writer.abort()
    if not copy.messages:
        dest.unlink(missing_ok=True)
        return None
    return Salvaged(dest, copy.messages, _describe(reason, copy, scan))
