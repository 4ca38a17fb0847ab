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
"""ROS 1 bags without their index, as ``rosbag record`` leaves them when it is killed."""

from __future__ import annotations

from pathlib import Path
import struct

from pmba_ros.errors import BagError
from pmba_ros.io.bags import iter_messages, noetic_typestore, open_bags
import pytest
from rosbags.rosbag1 import Reader, Writer

N = 120
PAD = 'x' * 100


def write_bag(path: Path, compression: str) -> list[int]:
    """Write ``N`` std_msgs/String messages in small chunks; return the chunks' positions."""
    typestore = noetic_typestore()
    string = typestore.types['std_msgs/msg/String']
    writer = Writer(path)
    if compression != 'none':
        writer.set_compression(Writer.CompressionFormat[compression.upper()])
    writer.chunk_threshold = 1500   # ten chunks and more, as a long recording has
    with writer:
        conn = writer.add_connection('/s', 'std_msgs/msg/String', typestore=typestore)
        for i in range(N):
            writer.write(conn, (i + 1) * 10**7,
                         typestore.serialize_ros1(string(data=f'{i:06d}{PAD}'),
                                                  'std_msgs/msg/String'))
    with Reader(path) as reader:
        return [info.pos for info in reader.chunk_infos]


def killed(data: bytes) -> tuple[bytearray, int]:
    """Return the bag as a killed recorder leaves it (index position 0, no index records).

    Also returns the index's position: where the chunks end.
    """
    out = bytearray(data)
    field = out.index(b'index_pos=') + len(b'index_pos=')
    (index_pos,) = struct.unpack_from('<Q', out, field)
    out[field: field + 8] = bytes(8)
    return out[:index_pos], index_pos


def numbers(opened: object) -> list[int]:
    """Return the numbers of the messages read, checking every message's pad."""
    texts = [m.msg.data for m in iter_messages(opened)]  # type: ignore[arg-type]
    assert all(t[6:] == PAD for t in texts)
    return [int(t[:6]) for t in texts]


@pytest.mark.parametrize('compression', ['none', 'bz2', 'lz4'])
def test_killed_recorder_bag_is_read_whole(tmp_path: Path, compression: str) -> None:
    """``NAME.bag.active`` killed between chunks: every message, the damage named.

    Before, rosbags refused it whole ("Bag is not indexed"), and ``.bag.active`` was taken
    for an unknown ROS 2 storage format.
    """
    write_bag(tmp_path / 'rec.bag', compression)
    data, _ = killed((tmp_path / 'rec.bag').read_bytes())
    active = tmp_path / 'run.bag.active'
    active.write_bytes(data)
    with pytest.raises(BagError):
        list(iter_messages([active]))   # reading without open_bags stays strict
    with open_bags([active]) as opened:
        assert numbers(opened) == list(range(N))
        assert opened.topics['/s'].count == N
        (damage,) = opened.damage
    assert damage.startswith(f'{active}: not closed by its recorder (no index')
    assert active.read_bytes() == data


@pytest.mark.parametrize('compression', ['none', 'bz2', 'lz4'])
def test_bag_cut_in_a_chunk_keeps_the_chunks_before(tmp_path: Path, compression: str) -> None:
    """Cut inside a chunk: the chunks before it; an uncompressed one's complete records too."""
    chunks = write_bag(tmp_path / 'rec.bag', compression)
    data, _ = killed((tmp_path / 'rec.bag').read_bytes())
    cut = tmp_path / 'cut.bag'
    cut.write_bytes(data[: (chunks[-3] + chunks[-2]) // 2])
    with open_bags([cut]) as opened:
        read = numbers(opened)
        (damage,) = opened.damage
    assert read == list(range(len(read)))
    with Reader(tmp_path / 'rec.bag') as whole:
        before = sum(info.connection_counts[0] for info in whole.chunk_infos[:-3])
    if compression == 'none':
        assert before < len(read) < N and 'messages of a chunk the file ends in' in damage
    else:
        assert len(read) == before and 'the rest of the file is lost' in damage


def test_chunk_being_written_keeps_its_records(tmp_path: Path) -> None:
    """The recorder killed while writing a chunk (sizes still 0): its complete records kept.

    ``rosbag reindex`` stops at such a chunk.
    """
    chunks = write_bag(tmp_path / 'rec.bag', 'none')
    data, _ = killed((tmp_path / 'rec.bag').read_bytes())
    pos = chunks[-2]
    (header_len,) = struct.unpack_from('<I', data, pos)
    size_at = data.index(b'size=', pos) + len(b'size=')   # the chunk header's field
    data[size_at: size_at + 4] = bytes(4)
    length_at = pos + 4 + header_len
    (length,) = struct.unpack_from('<I', data, length_at)
    data[length_at: length_at + 4] = bytes(4)
    active = tmp_path / 'run.bag.active'
    active.write_bytes(data[: length_at + 4 + length * 2 // 3])
    with open_bags([active]) as opened:
        read = numbers(opened)
        (damage,) = opened.damage
    with Reader(tmp_path / 'rec.bag') as whole:
        before = sum(info.connection_counts[0] for info in whole.chunk_infos[:-2])
        in_chunk = whole.chunk_infos[-2].connection_counts[0]
    assert read == list(range(len(read)))
    assert before + in_chunk // 2 <= len(read) < before + in_chunk
    assert f'{len(read) - before} messages of a chunk the file ends in' in damage


def test_damaged_chunk_is_skipped(tmp_path: Path) -> None:
    """A compressed chunk that does not decompress: the chunks after it are read too."""
    chunks = write_bag(tmp_path / 'rec.bag', 'bz2')
    data, _ = killed((tmp_path / 'rec.bag').read_bytes())
    middle = chunks[len(chunks) // 2]
    data[middle + 80: middle + 90] = b'\xff' * 10   # inside its compressed data
    bad = tmp_path / 'bad.bag'
    bad.write_bytes(data)
    with open_bags([bad]) as opened:
        read = numbers(opened)
        (damage,) = opened.damage
    assert 0 < N - len(read) < 30 and read[-1] == N - 1 and read == sorted(read)
    assert '1 damaged chunk(s) skipped' in damage


def test_nothing_readable_names_the_file(tmp_path: Path) -> None:
    """A bag cut inside its first chunk's header, or not a bag: one error naming the file."""
    write_bag(tmp_path / 'rec.bag', 'lz4')
    data, _ = killed((tmp_path / 'rec.bag').read_bytes())
    for name, content in (('cut.bag.active', data[:4200]), ('text.bag', b'not a bag\n')):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(BagError, match=rf'{name}: (cannot|not closed)'), open_bags(
                [tmp_path / name]):
            pass


@pytest.mark.parametrize('compression', ['none', 'lz4'])
def test_damaged_header_and_records_are_read_around(tmp_path: Path, compression: str) -> None:
    """The bag's header record zeroed, a chunk's header zeroed, the first chunk lost.

    Reading goes on at the next chunk whose header reads (before: refused whole, or the rest
    of the file lost); messages whose connection record was in a lost chunk take the copy in
    the index at the file's end.
    """
    chunks = write_bag(tmp_path / 'rec.bag', compression)
    whole = (tmp_path / 'rec.bag').read_bytes()
    header = bytearray(whole)
    header[len(b'#ROSBAG V2.0\n'):chunks[0]] = bytes(chunks[0] - 13)
    middle = bytearray(whole)
    middle[chunks[4]:chunks[4] + 40] = bytes(40)
    first = bytearray(whole)
    first[:chunks[1]] = bytes(chunks[1])   # the magic and the chunk with the connection
    for name, data, lost in (('header.bag', header, 0), ('middle.bag', middle, 1),
                             ('first.bag', first, 1)):
        bad = tmp_path / name
        bad.write_bytes(bytes(data))
        with open_bags([bad]) as opened:
            read = numbers(opened)
            damage = ' '.join(opened.damage)
        assert read == sorted(read) and read[-1] == N - 1, name
        assert len(read) == N if not lost else 0 < N - len(read) < N // 4, name
        assert 'damaged bytes ' in damage and 'skipped' in damage, name
        assert len(damage) < 1000, name   # the reader's message quoted the zeroed bytes
