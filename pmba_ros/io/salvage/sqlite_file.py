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
"""The readable rows of a rosbag2 SQLite (``.db3``) file that is cut short or damaged.

rosbags counts a ``.db3`` file's messages when it opens it, so a file cut at any byte (a full
disk, an interrupted copy) or with one damaged page is refused whole ("database disk image is
malformed"). SQLite itself refuses a file shorter than its header says unless the connection's
schema is writable (``PRAGMA writable_schema``; the file is still opened read-only and
immutable), and it reads the part of a page past the end of a file cut inside it as zeros:
a message whose bytes end there came back with a zeroed tail, so the file is read through a
VFS that ends it at its last whole page (apsw, which rosbags reads SQLite with).
:func:`salvage_db3` copies the tables a reader needs (topics, message definitions)
and then every message row that reads into a new file: in rowid order, and where a row does not
read, from the next row that does (found by stepping 1, 2, 4, ... rows on and bisecting back),
so the rows after a damaged page are kept too. A row with a NULL column or out of order (a
damaged page read as cells) is taken for such damage.

rosbags reads the messages in timestamp order, through the file's timestamp index. A writer
killed in the middle of a write with rosbag2's default pragmas (``journal_mode=MEMORY``: no
journal on disk) can leave index pages that list fewer rows than the table holds, or more:
the file opens, and messages are missing without a word. :func:`index_damage` compares the
two counts; such a file is salvaged too (by rowid, with a new index).

A recorder killed while SQLite held a write-ahead log (``-wal``, rosbag2's ``resilient``
preset) or a rollback journal (``-journal``) leaves it beside the file; rosbags, opening the
file immutable, ignores it: the log's committed messages were silently missing, the half-written
pages of a rolled-back write were read. :func:`recover_journal` lets SQLite apply it to a copy.
"""

from __future__ import annotations

from collections.abc import Generator, Iterator
from contextlib import closing, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
import shutil
import sqlite3
from typing import Any

import apsw
from pmba_ros.errors import BagError
from pmba_ros.io.salvage.common import Salvaged
from pmba_ros.io.salvage.sqlite_pages import leaf_records

__all__ = ['index_damage', 'journal_of', 'recover_journal', 'salvage_db3']

JOURNAL_SUFFIXES = ('-wal', '-journal')
"""What SQLite appends to a database's name for its write-ahead log and its rollback journal."""

UNREADABLE = (apsw.Error, UnicodeDecodeError)
"""What a read of a damaged file raises: apsw decodes TEXT values as UTF-8, and a damaged byte
there (a table's name, a column that a flipped bit made TEXT) fails as a damaged page does."""

_MAX_ROWID = 2**63 - 1
_ROWS = 'SELECT rowid, * FROM messages WHERE rowid >= ? ORDER BY rowid'
_SHOWN_GAPS = 3
"""Unreadable stretches of rows named in the damage description; the others are counted."""

_VFS = 'pmba_whole_pages'
Row = tuple[Any, ...]


class _WholePagesFile(apsw.VFSFile):
    """A database file that ends at its last whole page."""

    def __init__(self, filename: str | apsw.URIFilename | None, flags: list[int]) -> None:
        super().__init__('', filename, flags)
        head = self.xRead(2, 16)   # the page size, big-endian; 1 stands for 65536
        size = int.from_bytes(head, 'big') if len(head) == 2 else 0
        self._page = 65536 if size == 1 else size

    def xFileSize(self) -> int:
        """Return the file's size without a last page cut short."""
        size = super().xFileSize()
        return size - size % self._page if self._page else size


class _WholePages(apsw.VFS):
    """The default VFS, with files that end at their last whole page."""

    def __init__(self) -> None:
        super().__init__(_VFS, '')

    def xOpen(self, name: str | apsw.URIFilename | None,
              flags: list[int]) -> apsw.VFSFile:
        """Open ``name`` as a :class:`_WholePagesFile`."""
        return _WholePagesFile(name, flags)


@contextmanager
def _read_only(path: Path) -> Iterator[apsw.Connection]:
    """Open ``path`` read-only and immutable, ending at its last whole page, schema writable."""
    vfs = _WholePages()
    try:
        db = apsw.Connection(f'{path.resolve().as_uri()}?mode=ro&immutable=1',
                             flags=apsw.SQLITE_OPEN_READONLY | apsw.SQLITE_OPEN_URI, vfs=_VFS)
        try:
            db.execute('PRAGMA writable_schema = ON')
            yield db
        finally:
            db.close()
    finally:
        vfs.unregister()


def index_damage(path: Path) -> str | None:
    """Return how the timestamp index of ``path`` disagrees with its message rows, if it does.

    Returns:
        None if both count the same rows (or there is no such index), else what differs.
    """
    with _read_only(path) as db:
        try:
            rows = db.execute('SELECT count(*) FROM messages NOT INDEXED').fetchall()[0][0]
            indexed = db.execute('SELECT count(*) FROM messages INDEXED BY timestamp_idx '
                                 'WHERE timestamp >= ?', (-_MAX_ROWID - 1,)).fetchall()[0][0]
        except apsw.SQLError:   # no such index, no messages table: not for this check
            return None
        except UNREADABLE as err:
            return f'its message rows do not all read ({err})'
    if rows == indexed:
        return None
    return (f'its timestamp index, by which rosbags reads the messages, lists {indexed} of its '
            f'{rows} rows')


def journal_of(path: Path) -> Path | None:
    """Return the write-ahead log or rollback journal SQLite left beside ``path``, if any."""
    for suffix in JOURNAL_SUFFIXES:
        journal = path.with_name(path.name + suffix)
        if journal.is_file() and journal.stat().st_size > 0:
            return journal
    return None


def recover_journal(path: Path, journal: Path, dest: Path) -> str:
    """Copy ``path`` and its ``journal`` to ``dest`` and let SQLite apply the journal there.

    A write-ahead log's committed transactions are written into the copy; a rollback journal
    (a write in progress) rolls its pages back. The user's folder is never written to.

    Returns:
        What was wrong and what the copy holds (without the file's name).
    """
    shutil.copyfile(path, dest)
    shutil.copyfile(journal, dest.with_name(dest.name + journal.name[len(path.name):]))
    wal = journal.name.endswith('-wal')
    try:
        with closing(sqlite3.connect(dest)) as db:
            db.execute('SELECT count(*) FROM sqlite_master').fetchone()
            db.execute('PRAGMA journal_mode = DELETE').fetchone()
    except sqlite3.DatabaseError as err:
        return (f'not closed by its recorder ({journal.name} beside it); applying it failed '
                f'({err}), the file was read without it')
    if wal:
        return (f'not closed by its recorder ({journal.name} beside it); read with that '
                'write-ahead log applied, the messages it had not yet committed are lost')
    return (f'not closed by its recorder ({journal.name} beside it: a write in progress); read '
            'with that write rolled back, its messages are lost')


@dataclass
class _Walk:
    """Progress of the walk over the message rows.

    Attributes:
        last: Rowid of the last row taken (rosbag2 numbers its rows from 1).
        read: Rows taken.
        gaps: First and last rowid of each stretch of rows lost.
        lost_after: Rowid after which nothing was readable, if rows there did not read.
        leaf_rows: Rows read from the table-leaf pages, past the damage (:func:`_leaf_rows`).
    """

    last: int = 0
    read: int = 0
    gaps: list[tuple[int, int]] = field(default_factory=list)
    lost_after: int | None = None
    leaf_rows: int = 0

    def take(self, row: Row) -> Row:
        """Count ``row`` (rowid first) and return its columns.

        rosbag2 numbers its rows without gaps: rows skipped since the last are lost ones.
        """
        if row[0] > self.last + 1:
            self.gaps.append((self.last + 1, row[0] - 1))
        self.last = row[0]
        self.read += 1
        return row[1:]


def _plausible(row: Row, after: int) -> bool:
    """Return True unless ``row`` reads as damage: no rowid past ``after``, or a NULL column.

    rosbag2's message columns are all NOT NULL; the zeros of a page past the file's end read
    as rowid 0 with NULL columns.
    """
    return isinstance(row[0], int) and row[0] > after and None not in row


def _probe(src: apsw.Connection, start: int, walk: _Walk) -> tuple[bool, Row | None]:
    """Return whether the first row from rowid ``start`` on reads, and that row (None: none)."""
    try:
        row = src.execute(f'{_ROWS} LIMIT 1', (start,)).fetchone()
    except UNREADABLE:
        return False, None
    if row is None:
        return True, None
    return _plausible(row, max(walk.last, start - 1)), row


def _run(src: apsw.Connection, start: int, walk: _Walk) -> Generator[Row, None, bool]:
    """Yield the rows from rowid ``start`` on up to the first that does not read.

    Returns:
        True if the table's end was reached.
    """
    try:
        for row in src.execute(_ROWS, (start,)):
            if not _plausible(row, walk.last):
                return False
            yield walk.take(row)
    except UNREADABLE:
        return False
    return True


def _next_readable(src: apsw.Connection, bad: int, walk: _Walk) -> int | None:
    """Return the first rowid after ``bad`` (a rowid that does not read) that reads.

    Steps 1, 2, 4, ... rows on, then bisects back; None if nothing after ``bad`` reads.
    """
    step = 1
    while True:
        probe = min(bad + step, _MAX_ROWID)
        readable, row = _probe(src, probe, walk)
        if readable:
            break
        if probe == _MAX_ROWID:
            return None
        bad, step = probe, 2 * step
    good = probe
    while good - bad > 1:
        mid = (bad + good) // 2
        readable, found = _probe(src, mid, walk)
        if readable:
            good, row = mid, found
        else:
            bad = mid
    return None if row is None else int(row[0])


def _message_rows(src: apsw.Connection, walk: _Walk) -> Iterator[Row]:
    """Yield every message row of ``src`` that reads, in rowid order, skipping damaged ones."""
    start = 1
    while not (yield from _run(src, start, walk)):
        # The cursor reads a row ahead: the rows up to the damaged one are taken singly.
        floor = max(walk.last + 1, start)
        readable, row = _probe(src, floor, walk)
        while readable and row is not None:
            yield walk.take(row)
            floor = walk.last + 1
            readable, row = _probe(src, floor, walk)
        if readable:
            return
        start_next = _next_readable(src, floor, walk)
        if start_next is None:
            walk.lost_after = walk.last
            return
        start = start_next


def _leaf_rows(path: Path, src: apsw.Connection, out: sqlite3.Connection, walk: _Walk) -> _Walk:
    """Add the message rows of ``path``'s table-leaf pages that the walk did not reach.

    Where the pages above the leaves are lost (a large file cut short) no query reaches
    them (:mod:`.sqlite_pages`). A row counts as a message by its shape: the messages
    table's columns, none NULL but its rowid alias, integers and blobs where declared, of a
    topic the copy has. Returns the walk over every row the copy then holds.
    """
    columns = src.execute('PRAGMA table_info(messages)').fetchall()
    names = [str(c[1]) for c in columns]
    kinds = [str(c[2]).upper() for c in columns]
    keys = [i for i, c in enumerate(columns) if int(c[5] or 0) > 0]
    key = keys[0] if len(keys) == 1 and kinds[keys[0]] == 'INTEGER' else None  # rowid alias
    topic = names.index('topic_id') if 'topic_id' in names else None
    topics = {row[0] for row in out.execute('SELECT id FROM topics')}
    wanted = {'INTEGER': int, 'BLOB': bytes}

    def rows() -> Iterator[Row]:
        for rowid, values in leaf_records(path, len(columns)):
            row = list(values)
            if key is not None:
                if row[key] is not None:   # SQLite stores the alias as NULL
                    continue
                row[key] = rowid
            if any(v is None or not isinstance(v, wanted.get(k, object))
                   for v, k in zip(row, kinds, strict=True)):
                continue
            if topic is None or row[topic] in topics:
                yield tuple(row)

    before = out.total_changes
    out.executemany(f'INSERT OR IGNORE INTO messages VALUES ({", ".join("?" * len(columns))})',
                    rows())
    found = out.total_changes - before
    merged = _Walk(leaf_rows=found)
    for (rowid,) in out.execute('SELECT rowid FROM messages ORDER BY rowid'):
        merged.take((rowid,))
    if walk.lost_after is not None and merged.last <= walk.lost_after:
        merged.lost_after = walk.lost_after
    return merged


def _copy_table(src: apsw.Connection, out: sqlite3.Connection, name: str) -> bool:
    """Copy the rows of the small table ``name``; False if not all of them read.

    A row that reads as damage (a NULL in a NOT NULL column, a repeated key: the zeros of a page
    past the file's end) is left out.
    """
    quoted = '"{}"'.format(name.replace('"', '""'))
    try:
        rows = src.execute(f'SELECT * FROM {quoted}').fetchall()
    except UNREADABLE:
        return False
    if not rows:
        return True
    before = out.total_changes
    marks = ', '.join('?' * len(rows[0]))
    out.executemany(f'INSERT OR IGNORE INTO {quoted} VALUES ({marks})', rows)
    return out.total_changes - before == len(rows)


def _describe(reason: str, walk: _Walk, unreadable: list[str]) -> str:
    """Return what :func:`salvage_db3` found (without the file's name)."""
    text = f'{reason}; {walk.read} messages read'
    if walk.leaf_rows:
        text += (f" ({walk.leaf_rows} of them from table pages the file's index pages no longer "
                 'lead to)')
    if walk.gaps:
        shown = ', '.join(f'{a}-{b}' if b > a else f'{a}' for a, b in walk.gaps[:_SHOWN_GAPS])
        more = len(walk.gaps) - _SHOWN_GAPS
        text += f', unreadable rows {shown}' + (f' and {more} more stretches' if more > 0 else '')
    if unreadable:
        text += f', table(s) {", ".join(unreadable)} damaged'
    if walk.lost_after is not None:
        text += f'; nothing after row {walk.lost_after} reads, the rest of the file is lost'
    return text


def salvage_db3(path: Path, dest: Path, reason: str) -> Salvaged | None:
    """Copy the readable rows of the SQLite file ``path`` into ``dest``.

    Args:
        path: The damaged ``.db3`` file.
        dest: The file to write (same tables, same schema version).
        reason: Why ``path`` is read this way, the damage description's start.

    Returns:
        What was copied, or None if not a single message could be (``dest`` removed).

    Raises:
        BagError: If ``dest`` cannot be written.
    """
    with _read_only(path) as src:
        try:
            schema = [(str(kind), str(name), str(sql)) for kind, name, sql in src.execute(
                'SELECT type, name, sql FROM sqlite_master WHERE sql IS NOT NULL')
                if not str(name).startswith('sqlite_')]   # SQLite's own, made by itself
            width = len(src.execute('PRAGMA table_info(messages)').fetchall())
        except UNREADABLE:   # not SQLite, or its schema unreadable
            return None
        tables = [name for kind, name, _ in schema if kind == 'table']
        if not width or 'topics' not in tables:
            return None
        walk = _Walk()
        try:
            with closing(sqlite3.connect(dest)) as out:
                out.execute('PRAGMA journal_mode = OFF')   # a scratch copy: nothing to roll back
                for kind, _, sql in sorted(schema, key=lambda entry: entry[0] != 'table'):
                    if kind == 'table':
                        out.execute(sql)
                unreadable = [name for name in tables
                              if name != 'messages' and not _copy_table(src, out, name)]
                if 'topics' not in unreadable:
                    out.executemany(f'INSERT INTO messages VALUES ({", ".join("?" * width)})',
                                    _message_rows(src, walk))
                    if walk.gaps or walk.lost_after is not None:
                        walk = _leaf_rows(path, src, out, walk)
                for kind, _, sql in schema:
                    if kind != 'table':
                        out.execute(sql)
                out.commit()
        except sqlite3.DatabaseError as err:
            dest.unlink(missing_ok=True)
            msg = f'{dest}: cannot write the readable copy of {path}: {err}'
            raise BagError(msg) from err
    if not walk.read:
        dest.unlink(missing_ok=True)
        return None
    return Salvaged(dest, walk.read, _describe(reason, walk, unreadable))
