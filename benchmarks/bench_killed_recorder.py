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
"""Recordings damaged as killed recorders and full disks leave them, and what is read back.

Run::

    python benchmarks/bench_killed_recorder.py [--runs 20] [--messages 2000] [--seed 0]

Four cases, ``--runs`` times each, on recordings of ``--messages`` std_msgs/String messages
(each its number and a 300-byte pad):

* ``db3 cut``: a rosbag2 SQLite file cut at a random byte;
* ``db3 killed``: a writer with rosbag2's default pragmas (``journal_mode=MEMORY``,
  ``synchronous=OFF``) writing a transaction a batch of 500 messages, as rosbag2 flushes its
  cache, killed (SIGKILL) up to 0.2 s after its first commit;
* ``ros1 cut`` / ``ros1 cut lz4``: a ROS 1 bag without its index (``rosbag record`` killed),
  chunks of about 20 messages, cut at a random byte.

Per case it prints how many runs rosbags opened, how many runs ``open_bags`` read, the
messages read against the reference (``db3 cut``: the share of the messages the cut keeps of
the file; ``ros1``: the messages in the chunks before the cut; ``db3 killed``: the committed
ones) and how many messages read differ from what was written.

With ``--timing-messages M`` it then times, on a .db3 of M such messages, the check of a
``.db3`` given alone (:func:`~pmba_ros.io.salvage.sqlite_file.index_damage`) and the salvage
of that file cut at 90 %.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import random
import signal
import subprocess
import sys
import tempfile
import time

from pmba_ros.errors import BagError
from pmba_ros.io.bags import (
    any_reader,
    iter_messages,
    jazzy_typestore,
    noetic_typestore,
    open_bags,
    ReadStats,
)

PAD = 'x' * 300

_KILLED_WRITER = """if True:
    import sqlite3, sys
    db = sqlite3.connect(sys.argv[1], isolation_level=None)
    db.execute('PRAGMA journal_mode = MEMORY')
    db.execute('PRAGMA synchronous = OFF')
    db.execute('PRAGMA cache_size = 16')
    template = bytes.fromhex(sys.argv[2])
    for start in range(0, 999_000, 500):
        db.execute('BEGIN')
        db.executemany(
            'INSERT INTO messages (topic_id, timestamp, data) VALUES (1, ?, ?)',
            [((i + 1) * 10**7, template.replace(b'000000', b'%06d' % i))
             for i in range(start, start + 500)])
        db.execute('COMMIT')
        print(start + 500, flush=True)
"""
"""A rosbag2-like writer: a transaction a batch, each batch larger than SQLite's page cache
(as rosbag2's cache, 100 MiB by default, against SQLite's 2 MB), so pages of a batch reach the
file before its commit."""


def _raw(i: int, ros1: bool) -> bytes:
    """Return message ``i`` serialized."""
    store = noetic_typestore() if ros1 else jazzy_typestore()
    msg = store.types['std_msgs/msg/String'](data=f'{i:06d}{PAD}')
    if ros1:
        return bytes(store.serialize_ros1(msg, 'std_msgs/msg/String'))
    return bytes(store.serialize_cdr(msg, 'std_msgs/msg/String'))


def write_db3(folder: Path, n: int) -> Path:
    """Write ``n`` messages into a rosbag2 SQLite folder; return its .db3 file."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    with Writer(folder, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conn = writer.add_connection('/s', 'std_msgs/msg/String', typestore=jazzy_typestore())
        for i in range(n):
            writer.write(conn, (i + 1) * 10**7, _raw(i, False))
    return folder / f'{folder.name}.db3'


def write_bag(path: Path, n: int, compression: str) -> list[tuple[int, int]]:
    """Write ``n`` messages into a ROS 1 bag; return ``(chunk end, messages so far)``."""
    from rosbags.rosbag1 import Reader, Writer

    writer = Writer(path)
    if compression != 'none':
        writer.set_compression(Writer.CompressionFormat[compression.upper()])
    writer.chunk_threshold = 20 * len(_raw(0, True))
    with writer:
        conn = writer.add_connection('/s', 'std_msgs/msg/String', typestore=noetic_typestore())
        for i in range(n):
            writer.write(conn, (i + 1) * 10**7, _raw(i, True))
    with Reader(path) as reader:
        ends = [info.pos for info in reader.chunk_infos[1:]]
        counts = [sum(info.connection_counts.values()) for info in reader.chunk_infos]
    total, out = 0, []
    for end, count in zip([*ends, path.stat().st_size], counts, strict=True):
        total += count
        out.append((end, total))
    return out


def _strip_index(path: Path) -> int:
    """Set the bag's index position to 0, as a killed ``rosbag record`` leaves it."""
    data = bytearray(path.read_bytes())
    field = data.index(b'index_pos=') + len(b'index_pos=')
    index_pos = int.from_bytes(data[field: field + 8], 'little')
    data[field: field + 8] = bytes(8)
    path.write_bytes(data[:index_pos])
    return index_pos


def _read(path: Path) -> tuple[bool, list[int] | None, int]:
    """Return whether rosbags opens ``path``, the numbers read, and how many differ.

    Read as ``pmba replay`` reads: past damage met while reading.
    """
    try:
        with any_reader([path]):
            opened = True
    except BagError:
        opened = False
    try:
        with open_bags([path]) as bags:
            texts = [m.msg.data for m in iter_messages(bags, damage=ReadStats())]
    except BagError:
        return opened, None, 0
    numbers = [int(t[:6]) if t[6:] == PAD and t[:6].isdigit() else -1 for t in texts]
    return opened, numbers, sum(n < 0 for n in numbers)


def _db3_killed(tmp: Path, rng: random.Random) -> tuple[Path, int]:
    """Kill a rosbag2-like SQLite writer at a random moment; return its file and commits."""
    db3 = write_db3(tmp / f'killed{rng.random()}', 0)
    child = subprocess.Popen([sys.executable, '-c', _KILLED_WRITER, str(db3),
                              _raw(0, False).hex()], stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None
    child.stdout.readline()   # its first commit
    time.sleep(rng.random() * 0.2)
    child.send_signal(signal.SIGKILL)
    out, _ = child.communicate()
    return db3, int(out.split()[-1]) if out.split() else 500


def main() -> int:
    """Run the cases and print a line each."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--runs', type=int, default=20)
    parser.add_argument('--messages', type=int, default=2000)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--timing-messages', type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        whole_db3 = write_db3(tmp / 'whole', args.messages).read_bytes()
        bags = {}
        for compression in ('none', 'lz4'):
            bag = tmp / f'whole_{compression}.bag'
            chunks = write_bag(bag, args.messages, compression)
            _strip_index(bag)
            bags[compression] = (bag.read_bytes(), chunks)
        print(f'{"case":14} {"rosbags":>8} {"read":>5} {"messages read / reference":>26} '
              f'{"differ":>7}')
        for case in ('db3 cut', 'db3 killed', 'ros1 cut', 'ros1 cut lz4'):
            opened = readable = got = reference = differ = 0
            for run in range(args.runs):
                if case == 'db3 killed':
                    path, ref = _db3_killed(tmp, rng)
                elif case == 'db3 cut':
                    path = tmp / f'cut{run}.db3'
                    path.write_bytes(whole_db3[: rng.randrange(len(whole_db3))])
                    ref = args.messages * len(path.read_bytes()) // len(whole_db3)
                else:
                    data, chunks = bags['lz4' if case.endswith('lz4') else 'none']
                    path = tmp / f'cut{run}.bag'
                    cut = rng.randrange(len(data))
                    path.write_bytes(data[:cut])
                    ref = max([count for end, count in chunks if end <= cut], default=0)
                ok, numbers, wrong = _read(path)
                opened += ok
                readable += numbers is not None
                got += len(numbers or [])
                reference += ref
                differ += wrong
            print(f'{case:14} {opened:>8} {readable:>5} {f"{got} / {reference}":>26} '
                  f'{differ:>7}')
        if args.timing_messages:
            _timing(tmp, args.timing_messages)
    return 0


def _timing(tmp: Path, n: int) -> None:
    """Time the index check and the salvage of a cut file on a .db3 of ``n`` messages."""
    from pmba_ros.io.salvage.sqlite_file import index_damage, salvage_db3

    db3 = write_db3(tmp / 'big', n)
    size = db3.stat().st_size
    start = time.perf_counter()
    index_damage(db3)
    check = time.perf_counter() - start
    cut = tmp / 'big_cut.db3'
    cut.write_bytes(db3.read_bytes()[: size * 9 // 10])
    start = time.perf_counter()
    saved = salvage_db3(cut, tmp / 'big_saved.db3', 'cut')
    salvage = time.perf_counter() - start
    print(f'{size / 2**20:.0f} MiB .db3, {n} messages: index check {check:.2f} s; cut at 90 %: '
          f'{saved.messages if saved else 0} messages salvaged in {salvage:.2f} s')


if __name__ == '__main__':
    sys.exit(main())
