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
"""rosbag2 SQLite recordings cut short, damaged, or left with SQLite's journal beside them."""

from __future__ import annotations

from contextlib import closing
from pathlib import Path
import shutil
import sqlite3
import subprocess
import sys

from pmba_ros.errors import BagError
from pmba_ros.io.bags import iter_messages, jazzy_typestore, open_bags, ReadStats
import pytest

N = 300
PAD = 'x' * 300
"""Each message is its number and a pad, so a page holds about ten."""


def write_db3(folder: Path, n: int = N, pad: str = PAD) -> Path:
    """Write ``n`` std_msgs/String messages into a rosbag2 SQLite folder; return its .db3."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    typestore = jazzy_typestore()
    string = typestore.types['std_msgs/msg/String']
    with Writer(folder, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conn = writer.add_connection('/s', 'std_msgs/msg/String', typestore=typestore)
        for i in range(n):
            raw = typestore.serialize_cdr(string(data=f'{i:06d}{pad}'), 'std_msgs/msg/String')
            writer.write(conn, (i + 1) * 10**7, raw)
    return folder / f'{folder.name}.db3'


def numbers(opened: object, pad: str = PAD, damage: ReadStats | None = None) -> list[int]:
    """Return the numbers of the messages read, checking every message's pad."""
    texts = [m.msg.data for m in iter_messages(opened, damage=damage)]  # type: ignore[arg-type]
    assert all(t[6:] == pad for t in texts)
    return [int(t[:6]) for t in texts]


def _pages(db3: Path, kind: str) -> list[int]:
    """Return the numbers of the messages table's pages of one kind (leaf, internal)."""
    import apsw

    db = apsw.Connection(str(db3), flags=apsw.SQLITE_OPEN_READONLY)
    try:
        return [int(p) for (p,) in db.execute(
            "SELECT pageno FROM dbstat WHERE name = 'messages' AND pagetype = ? ORDER BY pageno",
            (kind,))]
    finally:
        db.close()


@pytest.mark.parametrize('given', ['file', 'folder'])
def test_cut_db3_keeps_the_rows_before_the_cut(tmp_path: Path, given: str) -> None:
    """A file cut inside a page: the rows before it, none read past the cut as zeros.

    Before, the whole file was refused ("database disk image is malformed"); reading past
    the cut, SQLite filled the cut page's tail with zeros and one message came back with it.
    """
    db3 = write_db3(tmp_path / 'rec')
    data = db3.read_bytes()
    cut = tmp_path / 'cut'
    cut.mkdir()
    part = cut / 'cut_0.db3'
    part.write_bytes(data[: len(data) * 6 // 10 + 1234])
    with pytest.raises(BagError, match='malformed'):
        list(iter_messages([part]))
    with open_bags([part if given == 'file' else cut]) as opened:
        read = numbers(opened)
        assert opened.topics['/s'].count == len(read)
        assert opened.damage[0].startswith(f'{part}: cannot be opened')
        assert 'the rest of the file is lost' in opened.damage[0]
    assert N // 3 < len(read) < N and read == list(range(len(read)))
    assert part.stat().st_size == len(data) * 6 // 10 + 1234   # the user's file untouched


def test_damaged_page_skipped_rows_after_it_kept(tmp_path: Path) -> None:
    """A leaf page of the messages overwritten: the rows before and after it are read."""
    db3 = write_db3(tmp_path / 'rec')
    leaves = _pages(db3, 'leaf')
    page = leaves[len(leaves) // 2]
    data = bytearray(db3.read_bytes())
    data[(page - 1) * 4096: page * 4096] = b'\xff' * 4096
    bad = tmp_path / 'bad.db3'
    bad.write_bytes(bytes(data))
    with open_bags([bad]) as opened:
        read = numbers(opened)
        (damage,) = opened.damage
    lost = sorted(set(range(N)) - set(read))
    assert 0 < len(lost) < 30 and lost == list(range(lost[0], lost[-1] + 1))
    assert 0 < lost[0] and lost[-1] < N - 1 and read == sorted(read)
    assert f'unreadable rows {lost[0] + 1}-{lost[-1] + 1}' in damage   # rowids count from 1


def test_nothing_readable_names_the_file(tmp_path: Path) -> None:
    """The file cut in its header: one clear error."""
    db3 = write_db3(tmp_path / 'rec')
    bad = tmp_path / 'header.db3'
    bad.write_bytes(db3.read_bytes()[:50])
    with pytest.raises(BagError, match=r'header\.db3: cannot'), open_bags([bad]):
        pass


def test_rows_the_index_pages_no_longer_lead_to_are_read_from_the_leaves(
        tmp_path: Path) -> None:
    """The messages' root page gone, or a large file cut short: the leaves' rows are read.

    SQLite puts a growing table's new interior pages at the file's end: an 8,000-message file
    cut at 70 % lost them and no query reached a row (before: "no message in it is
    readable"); with the root page zeroed the same.
    """
    db3 = write_db3(tmp_path / 'rec')
    (root,) = _pages(db3, 'internal')[:1]
    data = bytearray(db3.read_bytes())
    data[(root - 1) * 4096: root * 4096] = bytes(4096)
    noroot = tmp_path / 'noroot.db3'
    noroot.write_bytes(bytes(data))
    with open_bags([noroot]) as opened:
        assert numbers(opened) == list(range(N))
        assert f'{N} of them from table pages' in opened.damage[0]
    n = 8000   # deeper than a root over the leaves
    big = write_db3(tmp_path / 'big', n)
    internal = _pages(big, 'internal')
    size = big.stat().st_size
    assert (internal[-1] - 1) * 4096 > 0.7 * size   # allocated as the tree grew deeper
    cut = tmp_path / 'cut.db3'
    cut.write_bytes(big.read_bytes()[:size * 7 // 10])
    with open_bags([cut]) as opened:
        read = numbers(opened)
    assert 0.6 * n < len(read) < n and read == list(range(len(read)))


@pytest.mark.parametrize(('table', 'update', 'match'), [
    ('topics', "UPDATE topics SET name = CAST(X'2fff73' AS TEXT)", r"utf-8 b'/\\xffs'"),
    ('sqlite_master', ("UPDATE sqlite_master SET sql = CAST(X'ff' AS TEXT) || sql "
                       "WHERE name = 'timestamp_idx'"), 'malformed database schema'),
])
def test_text_that_is_not_utf8_names_the_file(tmp_path: Path, table: str, update: str,
                                              match: str) -> None:
    """A damaged byte in a topic's name or the schema: one clear error (was a traceback)."""
    db3 = write_db3(tmp_path / 'rec')
    with closing(sqlite3.connect(db3)) as db:
        if table == 'sqlite_master':
            db.execute('PRAGMA writable_schema = ON')
        db.execute(update)
        db.commit()
    with pytest.raises(BagError, match=rf'rec\.db3: cannot open bag .*{match}'), open_bags([db3]):
        pass


def test_index_missing_rows_is_rebuilt(tmp_path: Path) -> None:
    """A timestamp index that lists fewer rows than the table: every row read, damage named.

    A writer killed in a write with rosbag2's default ``journal_mode=MEMORY`` leaves such
    index pages (``benchmarks/bench_killed_recorder.py``); here an index made over the first
    250 rows is declared whole. Before, rosbags read (and counted) the 250 rows it lists.
    """
    db3 = write_db3(tmp_path / 'rec')
    db = sqlite3.connect(db3)
    db.executescript("""
        DROP INDEX timestamp_idx;
        CREATE INDEX timestamp_idx ON messages (timestamp ASC) WHERE id <= 250;
        PRAGMA writable_schema = ON;
        UPDATE sqlite_master SET sql = 'CREATE INDEX timestamp_idx ON messages (timestamp ASC)'
            WHERE name = 'timestamp_idx';
    """)
    db.close()
    assert numbers([db3]) == list(range(250))   # read without open_bags
    with open_bags([db3]) as opened:
        assert numbers(opened) == list(range(N)) and opened.topics['/s'].count == N
        (damage,) = opened.damage
    assert 'by which rosbags reads the messages, lists 250 of its 300 rows' in damage


def test_damage_met_while_reading_is_read_around(tmp_path: Path) -> None:
    """A file that opens but has a damaged page its messages lead to: no SQLite error escapes.

    An overflow page (the rest of a long message) pointing past the file: rosbags opens the
    file (its counts read no message data), then apsw's CorruptError ended the reading with a
    traceback. Now it is the reader's corrupt-storage error, and read around when asked to.
    """
    pad = 'y' * 10_000   # three pages a message
    db3 = write_db3(tmp_path / 'rec', 40, pad)
    page = _pages(db3, 'overflow')[40]
    data = bytearray(db3.read_bytes())
    data[(page - 1) * 4096: (page - 1) * 4096 + 4] = (10**6).to_bytes(4, 'big')
    db3.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r'rec\.db3: bag is corrupt or truncated: database disk'):
        list(iter_messages([db3]))
    stats = ReadStats()
    read = numbers([db3], pad, stats)
    assert stats.damaged_parts == 1 and 'malformed' in str(stats.first_damage)
    assert 0 < len(read) < 40 and read[-1] == 39


@pytest.mark.parametrize('mode', ['WAL', 'DELETE'])
def test_journal_left_by_a_killed_writer_is_applied_on_a_copy(
        tmp_path: Path, mode: str) -> None:
    """A write-ahead log's committed rows are read; a rollback journal's write is undone.

    Before, rosbags read the file without them: the log's committed rows were missing, and
    the pages a write in progress had written (without a commit) were read.
    """
    db3 = write_db3(tmp_path / 'rec')
    # A writer that commits a second copy of the rows and is killed in the middle of a third.
    code = f"""if True:
        import os, sqlite3
        db = sqlite3.connect({str(db3)!r}, isolation_level=None)
        db.execute('PRAGMA journal_mode = {mode}')
        db.execute('PRAGMA cache_size = 2')
        for shift in (10**10, 2 * 10**10):
            db.execute('BEGIN')
            db.execute('INSERT INTO messages (topic_id, timestamp, data) '
                       'SELECT topic_id, timestamp + ?, data FROM messages WHERE id <= ?',
                       (shift, {N}))
            if shift == 10**10:
                db.execute('COMMIT')
        os._exit(0)
    """
    subprocess.run([sys.executable, '-c', code], check=True)
    journal = db3.with_name(db3.name + ('-wal' if mode == 'WAL' else '-journal'))
    assert journal.stat().st_size > 0
    before = {p.name: p.read_bytes() for p in db3.parent.iterdir()}
    with open_bags([db3]) as opened:
        read = numbers(opened)
        (damage,) = opened.damage
    assert read == list(range(N)) * 2
    assert f'{journal.name} beside it' in damage
    assert {p.name: p.read_bytes() for p in db3.parent.iterdir()} == before


def test_folder_without_metadata_is_read_and_reported(tmp_path: Path) -> None:
    """``ros2 bag record`` killed before writing metadata.yaml: its files read, damage named.

    A storage file given alone is read as it is, with no damage reported.
    """
    db3 = write_db3(tmp_path / 'rec')
    (db3.parent / 'metadata.yaml').unlink()
    split = db3.with_name('rec_1.db3')
    shutil.copyfile(db3, split)
    with open_bags([db3.parent]) as opened:
        assert numbers(opened) == sorted(list(range(N)) * 2)
        (damage,) = opened.damage
        assert damage.startswith(f'{db3.parent}: no metadata.yaml')
    with open_bags([split]) as opened:
        assert numbers(opened) == list(range(N)) and not opened.damage


@pytest.mark.parametrize('pad', ['', PAD, 'y' * 5000, 'z' * 70_000])
def test_leaf_records_are_sqlites_rows(tmp_path: Path, pad: str) -> None:
    """The page reader against SQLite: every row, local or spilling into overflow pages."""
    from pmba_ros.io.salvage.sqlite_pages import leaf_records

    db3 = write_db3(tmp_path / 'rec', 40, pad)
    with closing(sqlite3.connect(db3)) as db:
        rows = db.execute('SELECT id, topic_id, timestamp, data FROM messages').fetchall()
    found = {rowid: values for rowid, values in leaf_records(db3, 4)
             if values[0] is None and isinstance(values[3], bytes)}
    assert sorted(found) == [r[0] for r in rows]
    assert all(found[r[0]][1:] == r[1:] for r in rows)
