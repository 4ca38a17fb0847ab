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
"""Recordings that cannot be opened whole are read in the parts that can."""

from __future__ import annotations

from pathlib import Path
import struct

import numpy as np
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.backend.outputs import make_pose_stamped
from pmba_ros.errors import BagError
from pmba_ros.io.bags import iter_messages, jazzy_typestore, open_bags, ReadStats
import pytest


def write_chunked(path: Path, n: int, topic: str = '/gt', t0: int = 0,
                  compressed: bool = True) -> None:
    """Write ``n`` PoseStamped messages 0.1 s apart into many small MCAP chunks.

    ``ros2 bag record`` closes a chunk every 768 KiB: a long recording has many.
    """
    from mcap.writer import CompressionType, Writer

    typestore = jazzy_typestore()
    backend = RosbagsBackend(typestore)
    msgdef = typestore.generate_msgdef('geometry_msgs/msg/PoseStamped', ros_version=2)[0]
    with path.open('wb') as out:
        writer = Writer(out, chunk_size=512, compression=CompressionType.ZSTD if compressed
                        else CompressionType.NONE)
        writer.start(profile='ros2', library='test')
        schema = writer.register_schema('geometry_msgs/msg/PoseStamped', 'ros2msg',
                                        msgdef.encode())
        channel = writer.register_channel(topic, 'cdr', schema)
        for i in range(n):
            stamp = t0 + i * 10**8
            msg = make_pose_stamped(stamp, 'map', np.array([i, 0.0, 0.0]),
                                    np.array([0.0, 0.0, 0.0, 1.0]), backend)
            raw = typestore.serialize_cdr(msg, 'geometry_msgs/msg/PoseStamped')
            writer.add_message(channel, stamp, bytes(raw), stamp)
        writer.finish()


def _xs(opened: object) -> list[float]:
    return [m.msg.pose.position.x for m in iter_messages(opened)]  # type: ignore[arg-type]


def test_truncated_mcap_is_read_up_to_the_damage(tmp_path: Path) -> None:
    """A file without its index (a recorder killed) gives its messages before the cut."""
    whole = tmp_path / 'whole.mcap'
    write_chunked(whole, 200)
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size * 6 // 10])
    with pytest.raises(BagError, match='cannot open bag'):
        list(iter_messages([cut]))   # reading without open_bags stays strict
    with open_bags([cut]) as opened:
        xs = _xs(opened)
        assert len(opened.damage) == 1 and str(cut) in opened.damage[0]
        assert 'the rest of the file is lost' in opened.damage[0]
        assert opened.topics['/gt'].count == len(xs)
    assert 80 < len(xs) < 200 and xs == list(range(len(xs)))


def test_record_length_past_any_file_is_damage_read_up_to(tmp_path: Path) -> None:
    """A record of 2**63 bytes (flipped bits) in a killed recorder's file: the messages before.

    The record is in a chunk whose CRC is zero (not computed, which MCAP allows), so the
    reader meets its length.
    """
    bad = tmp_path / 'bad.mcap'
    write_chunked(bad, 200, compressed=False)
    data = bytearray(bad.read_bytes())
    pos = 8   # past the magic: opcode (u8), length (u64), body, record by record
    chunks = 0
    while chunks < 30 or data[pos] != 0x06:   # to the 31st chunk, past the 30th's indexes
        chunks += data[pos] == 0x06
        pos += 9 + struct.unpack_from('<Q', data, pos + 1)[0]
    # The chunk's body: start and end time, uncompressed size (u64 each), CRC (u32),
    # compression (an empty string: u32 0), records length (u64), then the records.
    data[pos + 33:pos + 37] = bytes(4)
    first = pos + 9 + 8 + 8 + 8 + 4 + 4 + 8
    data[first:first + 9] = b'\x7f' + struct.pack('<Q', 2**63 + 5)   # an unknown record
    bad.write_bytes(bytes(data[:pos + 2000]))   # no summary: a killed recorder
    with open_bags([bad]) as opened:
        xs = _xs(opened)
        damage = opened.damage[0]
    # The damaged chunk's messages are lost; those of the chunks before and after are read.
    assert xs == sorted(xs) and xs[:50] == list(range(50)) and 150 < len(xs) < 200
    lost = len(set(range(int(xs[-1]) + 1)) - set(xs))
    assert 0 < lost < 10
    # Named from the chunk's own offset (before: from its end, where reading failed), with
    # the messages its message indexes count (before: not counted).
    assert f'bytes {pos}-' in damage and f'skipped (damaged) with their {lost} messages' in damage


def test_a_compressed_chunk_without_crc_is_read_up_to_its_damage(tmp_path: Path) -> None:
    """Zeroed bytes in a recording of one big zstd chunk: its messages before them are read.

    The chunk decompresses block by block up to the damage. Before, reading on by time
    stepped over the whole chunk: not a message was read.
    """
    from pmba_ros.sim.bag import write_sequence_bag
    from pmba_ros.sim.sequence import simulate_sequence

    whole = tmp_path / 'street.mcap'
    write_sequence_bag(simulate_sequence('street', n_keyframes=120, seed=0), whole)
    data = whole.read_bytes()
    pos = 8 + 9 + struct.unpack_from('<Q', data, 9)[0]   # past the magic and the header
    assert data[pos] == 0x06 and struct.unpack_from('<I', data, pos + 9 + 24)[0] == 0
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(data[:len(data) // 2] + bytes(50) + data[len(data) // 2 + 50:])
    damage = ReadStats()
    with open_bags([whole]) as opened:
        announced = sum(t.count for t in opened.topics.values())
        times = [m.log_time_ns for m in iter_messages(opened)]
    with open_bags([bad]) as opened:
        read = [m.log_time_ns for m in iter_messages(opened, damage=damage)]
    assert 0.3 * announced < len(read) < 0.6 * announced
    assert read == times[:len(read)]   # the messages before the damage, in order
    assert damage.damaged_parts == 1
    assert f'({len(read)} of them read, from before the damage)' in (damage.first_damage or '')


def test_damaged_start_of_file_reads_every_chunk(tmp_path: Path) -> None:
    """The magic and the header record zeroed (the file's first 20 bytes): every message."""
    bad = tmp_path / 'bad.mcap'
    write_chunked(bad, 200)
    bad.write_bytes(bytes(20) + bad.read_bytes()[20:])
    with open_bags([bad]) as opened:
        xs = _xs(opened)
        assert 'bytes 0-' in opened.damage[0]   # the magic's own offset, not after it
        assert '200 messages read of the 200 its summary counts (0 lost)' in opened.damage[0]
    assert xs == list(range(200))


def test_nothing_readable_stays_the_open_error(tmp_path: Path) -> None:
    """A cut inside the first chunk leaves no message: the error names the file."""
    whole = tmp_path / 'whole.mcap'
    write_chunked(whole, 20)
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(whole.read_bytes()[:300])
    with pytest.raises(BagError, match=r'cut\.mcap: cannot open bag'), open_bags([cut]):
        pass
    empty = tmp_path / 'empty.mcap'
    empty.write_bytes(b'')
    with pytest.raises(BagError, match=r'empty\.mcap: cannot open bag'), open_bags([empty]):
        pass


def test_salvaged_parts_that_do_not_open_name_the_recording(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The error names the file given and its damage, not the copy in a temporary folder."""
    from pmba_ros.io import salvage
    whole = tmp_path / 'whole.mcap'
    write_chunked(whole, 20)
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(whole.read_bytes()[:-100])
    garbage = tmp_path / 'scratch' / '1_cut.mcap'
    garbage.parent.mkdir()
    garbage.write_bytes(b'\x89MCAP0\r\n' + bytes(64))
    monkeypatch.setattr(salvage, 'readable_parts',
                        lambda *_: ([garbage], (f'{cut}: the summary is damaged',)))
    with pytest.raises(BagError) as err, open_bags([cut]):
        pass
    text = str(err.value)
    assert text.startswith(f'{cut}: cannot open bag, not even the parts salvaged')
    assert 'the summary is damaged' in text and 'scratch' not in text


def test_folder_listing_a_missing_file_reads_the_others(tmp_path: Path) -> None:
    """A split recording with a part gone: the parts there are, and the damage named."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    typestore = jazzy_typestore()
    backend = RosbagsBackend(typestore)
    bag = tmp_path / 'split'
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection('/gt', 'geometry_msgs/msg/PoseStamped', typestore=typestore)
        for i in range(5):
            msg = make_pose_stamped(i * 10**8, 'map', np.array([i, 0.0, 0.0]),
                                    np.array([0.0, 0.0, 0.0, 1.0]), backend)
            writer.write(conn, i * 10**8, typestore.serialize_cdr(msg, conn.msgtype))
    meta = bag / 'metadata.yaml'
    meta.write_text(meta.read_text().replace('- split.mcap', '- split.mcap\n  - split_1.mcap'))
    with pytest.raises(BagError, match='missing'):
        list(iter_messages([bag]))
    with open_bags([bag]) as opened:
        assert _xs(opened) == [0.0, 1.0, 2.0, 3.0, 4.0]
        assert len(opened.damage) == 1 and 'split_1.mcap' in opened.damage[0]


def _records(data: bytes | bytearray, pos: int) -> list[tuple[int, int]]:
    """Return the (offset, opcode) of the MCAP records from ``pos`` to the footer's."""
    out = []
    while data[pos] != 0x02:
        out.append((pos, data[pos]))
        pos += 9 + struct.unpack_from('<Q', data, pos + 1)[0]
    return out


def test_damaged_summary_length_names_the_record_and_is_salvaged(tmp_path: Path) -> None:
    """A summary record of 2**40 bytes (flipped bits): the error names it, the data is read.

    rosbags asked for a 1 TiB buffer ("cannot open bag (...): MemoryError", no record named).
    """
    bad = tmp_path / 'bad.mcap'
    write_chunked(bad, 200)
    data = bytearray(bad.read_bytes())
    summary = struct.unpack_from('<Q', data, len(data) - 37 + 9)[0]
    schema = next(pos for pos, op in _records(data, summary) if op == 0x03)
    data[schema + 1:schema + 9] = struct.pack('<Q', 2**40)
    bad.write_bytes(bytes(data))
    named = (rf'the MCAP record at byte {schema} \(opcode 0x03\) is damaged: its length '
             rf'1099511627776 runs \d+ bytes past the end of the file \({len(data)} bytes\)')
    xs, damage = _named_and_salvaged(bad, named,
                                     f'the MCAP record at byte {schema} (opcode 0x03) is damaged')
    assert xs == list(range(200)) and len(damage) == 1


def _named_and_salvaged(bad: Path, named: str, start: str) -> tuple[list[float], tuple[str, ...]]:
    """Check the damage of ``bad`` is named (regex ``named``), then return what open_bags reads.

    Reading without open_bags stays strict; open_bags salvages the file and says why, in words
    starting with ``start``. Returns the messages' x and the damage lines.
    """
    with pytest.raises(BagError, match=r'bad\.mcap: cannot open bag .*' + named):
        list(iter_messages([bad]))
    with open_bags([bad]) as opened:
        assert opened.damage[0].startswith(f'{bad}: cannot be opened ({start}')
        return _xs(opened), opened.damage


def _killed_with_chunk_length(bad: Path, which: int, length: int,
                              records_length: int | None = None) -> int:
    """Write to ``bad`` a killed recorder's file whose ``which``-th chunk has a damaged length.

    200 messages in many chunks, without the summary; the chunk's record length is
    ``length``, and its head's records length ``records_length`` if given. Returns the
    chunk's offset.
    """
    write_chunked(bad, 200)
    data = bytearray(bad.read_bytes())
    chunk = [pos for pos, op in _records(data, 8) if op == 0x06][which]
    struct.pack_into('<Q', data, chunk + 1, length)
    if records_length is not None:   # past the head's times, sizes, CRC and compression
        name_size = struct.unpack_from('<I', data, chunk + 9 + 28)[0]
        struct.pack_into('<Q', data, chunk + 9 + 32 + name_size, records_length)
    summary = struct.unpack_from('<Q', data, len(data) - 37 + 9)[0]
    bad.write_bytes(bytes(data[:summary]))
    return chunk


def test_chunk_length_past_the_file_is_stepped_over(tmp_path: Path) -> None:
    """A killed recorder's chunk of 1 GiB, its head damaged too: the chunks after it are read.

    Below the mcap reader's 4 GiB limit, the length asked for a 1 GiB buffer and the file's
    end was taken to be there: every message after the damaged chunk was lost. The bytes
    skipped start at the chunk's own offset (before: after its length field).
    """
    bad = tmp_path / 'bad.mcap'
    chunk = _killed_with_chunk_length(bad, 10, 2**30, records_length=2**40)
    with open_bags([bad]) as opened:
        xs = _xs(opened)
        assert f'bytes {chunk}-' in opened.damage[0]
        assert 'skipped (damaged)' in opened.damage[0]
    assert xs == sorted(xs) and xs[-1] == 199 and 180 < len(xs) < 200


@pytest.mark.parametrize('length', [2**63, 2**40])
@pytest.mark.parametrize('which', [0, -1])
def test_chunk_length_past_the_file_is_read_by_its_head(tmp_path: Path, which: int,
                                                        length: int) -> None:
    """A killed recorder's first or last chunk with a length past the file: read, and said so.

    Its head (compression name, records length) gives the length; the chunk is taken as it
    reads whole there. Before, a damaged first chunk, which holds the schemas and channels,
    refused the whole file ("cannot open bag (...): File end magic is invalid."), and a
    damaged last chunk's messages were lost (reading stopped at RecordLengthLimitExceeded).
    """
    bad = tmp_path / 'bad.mcap'
    chunk = _killed_with_chunk_length(bad, which, length)
    with open_bags([bad]) as opened:
        assert _xs(opened) == list(range(200))
        assert (f'the chunk at byte {chunk} read by the length its head gives (' in
                opened.damage[0])
        assert f'its record length {length} is damaged' in opened.damage[0]
        assert 'skipped' not in opened.damage[0]


@pytest.mark.parametrize('which', [10, -1])
def test_chunk_failing_its_crc_is_named_and_skipped(tmp_path: Path, which: int) -> None:
    """A bit flipped in a chunk's records (its CRC computed): the chunk named, the others read.

    rosbags stopped reading at it ("bag is corrupt or truncated: Chunk checksum mismatch.",
    no chunk or byte named); now the file is salvaged as one with a corrupt chunk is: that
    chunk's messages are lost, and said so. The last chunk too: no chunk follows, and
    reading goes on after it by its length (before: it stopped there, "the rest of the file
    is lost").
    """
    bad = tmp_path / 'bad.mcap'
    write_chunked(bad, 200, compressed=False)
    data = bytearray(bad.read_bytes())
    chunk = [pos for pos, op in _records(data, 8) if op == 0x06][which]
    assert struct.unpack_from('<I', data, chunk + 9 + 24)[0] != 0   # the CRC is computed
    length = struct.unpack_from('<Q', data, chunk + 1)[0]
    data[chunk + 9 + length - 30] ^= 0x10   # in the chunk's last message
    bad.write_bytes(bytes(data))
    named = (rf'the MCAP chunk at byte {chunk} \(log times \d+ to \d+ ns\) is damaged: its '
             r'records do not match their CRC')
    xs, damage = _named_and_salvaged(bad, named, f'the MCAP chunk at byte {chunk} ')
    assert xs == sorted(xs) and (xs[-1] == 199) == (which != -1) and 190 < len(xs) < 200
    # The chunk's own bytes (before: the bytes after the chunk), and the messages lost as the
    # summary and the message indexes count them (before: not counted).
    lost = 200 - len(xs)
    assert (f'{len(xs)} messages read of the 200 its summary counts ({lost} lost), '
            f'bytes {chunk}-') in damage[0]
    assert f'skipped (damaged) with their {lost} messages' in damage[0]
    assert damage[0].endswith('reading stopped at the end of the file')


def _chunk_index_sizes(data: bytearray, pos: int) -> int:
    """Return the offset of the (compressed, uncompressed) sizes of a chunk index at ``pos``."""
    body = pos + 9
    offsets_size = struct.unpack_from('<I', data, body + 32)[0]
    at = body + 36 + offsets_size + 8
    return at + 4 + struct.unpack_from('<I', data, at)[0]


def test_absurd_chunk_uncompressed_size_names_the_index_and_is_salvaged(tmp_path: Path) -> None:
    """A chunk index claiming 2**64 - 1 uncompressed bytes: named, and every message read.

    More than any compression expands its chunk to; rosbags failed on it mid-read ("Chunk
    size mismatch"), and the mcap reader with "Python int too large to convert to C ssize_t".
    """
    bad = tmp_path / 'bad.mcap'
    write_chunked(bad, 200)
    data = bytearray(bad.read_bytes())
    summary = struct.unpack_from('<Q', data, len(data) - 37 + 9)[0]
    index = [pos for pos, op in _records(data, summary) if op == 0x08][10]
    struct.pack_into('<Q', data, _chunk_index_sizes(data, index) + 8, 2**64 - 1)
    bad.write_bytes(bytes(data))
    with open_bags([bad]) as opened:
        assert _xs(opened) == list(range(200))
        assert opened.damage[0].startswith(
            f'{bad}: cannot be opened (the MCAP chunk index at byte {index} is damaged: its '
            '18446744073709551615 uncompressed bytes are more than 32768 times its')


def test_a_topic_of_a_schema_rosbags_cannot_parse_is_skipped_and_named(tmp_path: Path) -> None:
    """One channel whose schema has another encoding: the other topics read, it is named.

    rosbags' MCAP reader fails on such a schema: the whole bag was refused ("unknown").
    """
    from .test_bags import write_mcap_strings

    bag = tmp_path / 'mixed.mcap'
    write_mcap_strings(bag, 5, other=('/status', 'my_msgs/msg/Status', 'unknown'))
    with open_bags([bag]) as bags:
        assert [m.msg.data for m in iter_messages(bags)] == [f'm{i}' for i in range(5)]
        assert "/status (my_msgs/msg/Status, schema encoding 'unknown') skipped" in \
            bags.damage[0]
        assert 'KeyError' in bags.damage[0]
