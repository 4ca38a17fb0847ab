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
"""Tests of pmba_ros.io.bags: reading, the QoS-mismatch fallback, writing, bad bags."""

from __future__ import annotations

from pathlib import Path
import struct

import numpy as np
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.backend.outputs import make_pose_stamped
from pmba_ros.errors import BagError
from pmba_ros.io.bag_writer import open_writer
from pmba_ros.io.bags import (
    iter_messages,
    jazzy_typestore,
    list_topics,
    require_topics,
)
import pytest

from ..conftest import shared_file


def _write_poses(path: Path, n: int = 5, topic: str = '/gt') -> None:
    """Write ``n`` PoseStamped messages, 0.1 s apart."""
    backend = RosbagsBackend(jazzy_typestore())
    with open_writer(path) as writer:
        for i in range(n):
            msg = make_pose_stamped(i * 10**8, 'map', np.array([i, 0.0, 0.0]),
                                    np.array([0.0, 0.0, 0.0, 1.0]), backend)
            writer.write(topic, msg, i * 10**8)


def _first_chunk_payload(data: bytes) -> tuple[int, int]:
    """Byte range of the (compressed) records of the first MCAP chunk record."""
    pos = 8  # magic
    while pos < len(data):
        opcode = data[pos]
        (length,) = struct.unpack_from('<Q', data, pos + 1)
        body = pos + 9
        if opcode == 0x06:  # Chunk: 3 u64, u32 crc, compression string, u64 records length
            (name_len,) = struct.unpack_from('<I', data, body + 28)
            start = body + 32 + name_len + 8
            return start, body + length
        pos = body + length
    msg = 'no chunk record'
    raise AssertionError(msg)


@pytest.mark.parametrize('name', ['folder_bag', 'bare.mcap'])
def test_written_bag_reads_back_with_rosbags_and_mcap_ros2(tmp_path: Path, name: str) -> None:
    """A folder bag and a bare .mcap both read back through rosbags and mcap_ros2."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out = tmp_path / name
    _write_poses(out)
    assert list_topics([out])['/gt'].count == 5
    xs = [m.msg.pose.position.x for m in iter_messages([out])]
    assert xs == [0.0, 1.0, 2.0, 3.0, 4.0]
    storage = out if out.is_file() else out / f'{out.name}.mcap'
    with storage.open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = [m.pose.position.x for *_, m in reader.iter_decoded_messages()]
    assert decoded == xs
    if out.is_dir():
        assert (out / 'metadata.yaml').read_text().count(f'{out.name}.mcap') == 2


def test_writer_refuses_existing_output_unless_overwrite(tmp_path: Path) -> None:
    """An existing output is an error unless ``overwrite`` is set."""
    out = tmp_path / 'b.mcap'
    _write_poses(out, 2)
    with pytest.raises(BagError, match='exists already'):
        _write_poses(out, 2)
    backend = RosbagsBackend(jazzy_typestore())
    with open_writer(out, overwrite=True) as writer:
        writer.write('/x', make_pose_stamped(0, 'map', np.zeros(3), np.array([0, 0, 0, 1.0]),
                                             backend), 0)
    assert list(list_topics([out])) == ['/x']


def test_writer_finalizes_bag_when_the_block_raises(tmp_path: Path) -> None:
    """An exception inside the writer block still leaves a readable bag (summary written)."""
    out = tmp_path / 'partial.mcap'
    backend = RosbagsBackend(jazzy_typestore())
    with pytest.raises(KeyboardInterrupt), open_writer(out) as writer:
        for i in range(3):
            writer.write('/gt', make_pose_stamped(i, 'map', np.zeros(3),
                                                  np.array([0, 0, 0, 1.0]), backend), i)
        raise KeyboardInterrupt
    assert sum(1 for _ in iter_messages([out])) == 3
    assert not any(p.name.startswith('.') for p in tmp_path.iterdir())


def test_truncated_bag_raises_bag_error(tmp_path: Path) -> None:
    """Half an MCAP file gives one clear BagError."""
    good = tmp_path / 'good.mcap'
    _write_poses(good, 20)
    bad = tmp_path / 'truncated.mcap'
    bad.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(BagError, match=r'truncated\.mcap: cannot open bag .*truncated or corrupt'):
        list(iter_messages([bad]))


def test_garbage_bytes_raise_bag_error(tmp_path: Path) -> None:
    """A file that is not a bag gives a BagError naming it."""
    bad = tmp_path / 'garbage.mcap'
    bad.write_bytes(b'not a bag at all' * 64)
    with pytest.raises(BagError, match=r'garbage\.mcap: cannot open bag'):
        list_topics([bad])


def test_corrupt_chunk_raises_bag_error(tmp_path: Path) -> None:
    """Damaged bytes in the middle raise BagError while reading, not a raw exception."""
    good = tmp_path / 'good.mcap'
    _write_poses(good, 200)
    data = bytearray(good.read_bytes())
    lo, hi = _first_chunk_payload(bytes(data))
    middle = (lo + hi) // 2
    data[middle - 20:middle + 20] = b'\xff' * 40
    bad = tmp_path / 'corrupt.mcap'
    bad.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r'corrupt\.mcap'):
        list(iter_messages([bad]))


def test_missing_bag_and_missing_topic(tmp_path: Path) -> None:
    """A missing path and a missing topic each give a BagError naming them."""
    with pytest.raises(BagError, match='no such bag'):
        list_topics([tmp_path / 'nope'])
    out = tmp_path / 'b.mcap'
    _write_poses(out)
    topics = list_topics([out])
    with pytest.raises(BagError, match=r"topic '/tracks' is not in the bag \(topics: /gt"):
        require_topics(topics, {'/tracks': ()}, [out])
    with pytest.raises(BagError, match='has type geometry_msgs/msg/PoseStamped, expected'):
        require_topics(topics, {'/gt': ('nav_msgs/msg/Odometry',)}, [out])


def test_qos_mismatch_folder_falls_back_to_storage_file(tmp_path: Path) -> None:
    """metadata.yaml QoS differing from the storage file (ros2_notes §4.4.6) is handled."""
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )
    from rosbags.rosbag2 import StoragePlugin, Writer

    out = tmp_path / 'qos_bag'
    backend = RosbagsBackend(jazzy_typestore())
    ts = jazzy_typestore()
    zero = QosTime(0, 0)
    qos = Qos(QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE, QosDurability.VOLATILE, zero,
              zero, QosLiveliness.AUTOMATIC, zero, False)
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection('/gt', 'geometry_msgs/msg/PoseStamped', typestore=ts,
                                     offered_qos_profiles=[qos])
        for i in range(4):
            msg = make_pose_stamped(i, 'map', np.zeros(3), np.array([0, 0, 0, 1.0]), backend)
            writer.write(conn, i, ts.serialize_cdr(msg, msg.__msgtype__))
    meta = out / 'metadata.yaml'
    text = meta.read_text()
    assert 'depth: 10' in text
    meta.write_text(text.replace('depth: 10', 'depth: 11'))
    from rosbags.highlevel import AnyReader
    with AnyReader([out], default_typestore=ts) as reader:
        assert sum(1 for _ in reader.messages()) == 0  # the pitfall itself
    assert sum(1 for _ in iter_messages([out])) == 4


def test_reads_ros1_bag_without_leading_slash() -> None:
    """The ROS 1 example bag of evo reads through the same API."""
    bag = shared_file('bags', 'ROS_example.bag')
    topics = list_topics([bag])
    assert topics['groundtruth'].msgtype == 'geometry_msgs/msg/PoseStamped'
    first = next(iter_messages([bag], topics=['groundtruth']))
    assert first.msg.header.stamp.sec > 1_400_000_000


@pytest.mark.parametrize(('parts', 'topic', 'count'), [
    (('bags', 'tf_example'), '/tf', 517),
    (('bags', 'nav2_turtlebot.mcap'), '/odom', 2639),
])
def test_reads_shared_rosbag2_recordings(parts: tuple[str, ...], topic: str,
                                         count: int) -> None:
    """A sqlite3 rosbag2 folder and a bare MCAP recorded by ROS 2 read completely."""
    bag = shared_file(*parts)
    assert list_topics([bag])[topic].count == count
    assert sum(1 for _ in iter_messages([bag], topics=[topic])) == count


def test_folder_without_metadata(tmp_path: Path) -> None:
    """An empty folder is not a bag; a folder holding only an .mcap file is read."""
    empty = tmp_path / 'empty'
    empty.mkdir()
    with pytest.raises(BagError, match=r'empty: not a bag \(no metadata.yaml'):
        list_topics([empty])
    loose = tmp_path / 'loose'
    loose.mkdir()
    _write_poses(loose / 'x.mcap', 3)
    assert sum(1 for _ in iter_messages([loose])) == 3


def test_a_split_its_metadata_does_not_list_is_read_and_named(tmp_path: Path) -> None:
    """A storage file the folder's metadata.yaml does not list (a later split) is read too.

    rosbags reads the listed files only: half a split recording was replayed, complete.
    """
    from pmba_ros.io.bags import open_bags, ReadStats

    folder = tmp_path / 'rec'
    _write_poses(folder, 4)                     # rec/metadata.yaml + rec/rec.mcap
    _write_poses(tmp_path / 'later.mcap', 3, '/later')
    (tmp_path / 'later.mcap').rename(folder / 'rec_1.mcap')
    with open_bags([folder]) as bags:
        assert any('rec_1.mcap not listed in its metadata.yaml' in d for d in bags.damage)
        stats = ReadStats()
        topics = sorted(m.topic for m in iter_messages(bags, damage=stats))
    assert topics == ['/gt'] * 4 + ['/later'] * 3


@pytest.mark.parametrize('storage', ['mcap', 'db3'])
def test_per_message_compressed_storage_file_read_alone_is_decompressed(
        tmp_path: Path, storage: str) -> None:
    """rosbag2's per-message zstd: the file without its metadata.yaml (alone, or salvaged).

    Only the metadata says the messages are compressed: every one was undecodable.
    """
    from pmba_ros.io.bags import open_bags, ReadStats
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    typestore = jazzy_typestore()
    string = typestore.types['std_msgs/msg/String']
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    folder = tmp_path / 'rec'
    writer = Writer(folder, version=9, storage_plugin=plugin)
    writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection('/s', 'std_msgs/msg/String', typestore=typestore)
        for i in range(5):
            writer.write(conn, (i + 1) * 10**7, typestore.serialize_cdr(
                string(data=f'message {i}'), 'std_msgs/msg/String'))
    (alone,) = folder.glob(f'*.{storage}')
    for given in (folder, alone):
        damage = ReadStats()
        with open_bags([given]) as bags:
            texts = [m.msg.data for m in iter_messages(bags, damage=damage)]
        assert texts == [f'message {i}' for i in range(5)] and damage.undecodable == 0


def test_reading_resumes_after_a_corrupt_chunk(tmp_path: Path) -> None:
    """With `damage`, a corrupt first chunk is skipped and the next chunk is still read."""
    from pmba_ros.backend.outputs import make_point_cloud2_xyz
    from pmba_ros.io.bags import ReadStats

    backend = RosbagsBackend(jazzy_typestore())
    good = tmp_path / 'chunks.mcap'
    rng = np.random.default_rng(0)
    with open_writer(good) as writer:  # 40 x 36 kB of random points: two 1 MB chunks
        for i in range(40):
            cloud = make_point_cloud2_xyz(i * 10**8, 'map', rng.normal(size=(3000, 3)), backend)
            writer.write('/cloud', cloud, i * 10**8)
    data = bytearray(good.read_bytes())
    lo, _ = _first_chunk_payload(bytes(data))
    data[lo:lo + 16] = b'\xff' * 16  # the zstd frame header of chunk 1
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(bytes(data))
    with pytest.raises(BagError, match='corrupt or truncated'):
        list(iter_messages([bad]))
    damage = ReadStats()
    stamps = [m.log_time_ns for m in iter_messages([bad], damage=damage)]
    assert 0 < len(stamps) < 40
    assert stamps == sorted(stamps) and stamps[-1] == 39 * 10**8
    assert damage.damaged_parts == 1
    assert 'bad.mcap: bag is corrupt or truncated' in str(damage.first_damage)


def test_open_bags_reads_what_paths_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Opened bags list the topics and read the same messages, without opening again."""
    from pmba_ros.io import bags as bags_mod

    out = tmp_path / 'b.mcap'
    _write_poses(out)
    by_path = [repr(m) for m in iter_messages([out])]
    with bags_mod.open_bags([out]) as opened:
        assert opened.topics == list_topics([out])
        opens = []
        real = bags_mod.any_reader
        monkeypatch.setattr(bags_mod, 'any_reader', lambda paths: opens.append(1) or real(paths))
        assert [repr(m) for m in iter_messages(opened)] == by_path
        assert not opens


def test_types_defined_as_in_jazzy_read_with_its_typestore(tmp_path: Path) -> None:
    """A type defined as in Jazzy reads as the reader would; others are left to the reader.

    Also when only a nested type differs.
    """
    from pmba_ros.io.typestores import deserializer
    from rosbags.highlevel import AnyReader, AnyReaderError

    out = tmp_path / 'b.mcap'
    _write_poses(out, 3)
    with AnyReader([out], default_typestore=jazzy_typestore()) as reader:
        (conn,) = reader.connections
        raws = [raw for _, _, raw in reader.messages()]
        read = deserializer(reader, conn.msgtype)
        assert read.__name__ == 'deserialize'   # the Jazzy typestore's
        assert [repr(read(raw)) for raw in raws] == \
            [repr(reader.deserialize(raw, conn.msgtype)) for raw in raws]
        with pytest.raises(AnyReaderError, match='Invalid or unsupported CDR'):
            read(b'\x07\x07' + raws[0][2:])
        point = reader.typestore.fielddefs['geometry_msgs/msg/Point']
        reader.typestore.fielddefs['geometry_msgs/msg/Point'] = (point[0], point[1][:2])
        try:
            assert deserializer(reader, conn.msgtype).func == reader.deserialize
        finally:
            reader.typestore.fielddefs['geometry_msgs/msg/Point'] = point


def write_mcap_strings(path: Path, n: int, schema_text: bytes = b'string data',
                       other: tuple[str, str, str] | None = None,
                       schema_name: str = 'std_msgs/msg/String') -> None:
    """Write std_msgs/String messages 'm0', 'm1', ... on /s with the mcap library's writer.

    ``schema_text``: the String schema's data; ``other``: (topic, schema name, schema
    encoding) of a second channel, 8 zero bytes beside each message; ``schema_name``: the
    name the String schema is recorded under.
    """
    from mcap.writer import Writer

    typestore = jazzy_typestore()
    string = typestore.types['std_msgs/msg/String']
    with path.open('wb') as out:
        writer = Writer(out)
        writer.start(profile='ros2', library='test')
        channel = writer.register_channel('/s', 'cdr', writer.register_schema(
            schema_name, 'ros2msg', schema_text))
        second = None if other is None else writer.register_channel(
            other[0], 'cdr', writer.register_schema(other[1], other[2], b''))
        for i in range(n):
            raw = bytes(typestore.serialize_cdr(string(data=f'm{i}'), 'std_msgs/msg/String'))
            writer.add_message(channel, (i + 1) * 10**7, raw, (i + 1) * 10**7)
            if second is not None:
                writer.add_message(second, (i + 1) * 10**7, bytes(8), (i + 1) * 10**7)
        writer.finish()


def test_schemas_recorded_without_their_text_are_read_as_jazzys(tmp_path: Path) -> None:
    """A ``ros2msg`` schema with empty data is read as the Jazzy type of that name.

    It defines no fields: every message had been undecodable ("CDR message size mismatch").
    """
    from pmba_ros.io.bags import open_bags, ReadStats

    bag = tmp_path / 'bare.mcap'
    write_mcap_strings(bag, 3, schema_text=b'')
    damage = ReadStats()
    with open_bags([bag]) as bags:
        assert [m.msg.data for m in iter_messages(bags, damage=damage)] == ['m0', 'm1', 'm2']
    assert damage.undecodable == 0


def test_ros2_types_recorded_under_ros1_names_read_by_their_ros2_names(tmp_path: Path) -> None:
    """A ``ros2msg`` schema named ``std_msgs/String`` reads as ``std_msgs/msg/String``.

    That is the name the replay's layouts and checks compare. Before, the replay's tracks
    topic "has type sensor_msgs/PointCloud", which no layout reads; and with the ROS 2 name
    asked of the reader, every message was a KeyError.
    """
    from pmba_ros.io.bags import open_bags, ReadStats, ros2_type_name

    assert ros2_type_name('std_msgs/String') == 'std_msgs/msg/String'
    for name in ('std_msgs/msg/String', 'std_srvs/srv/Trigger', 'String', 'a/b/c/d'):
        assert ros2_type_name(name) == name
    bag = tmp_path / 'ros1_names.mcap'
    write_mcap_strings(bag, 3, schema_name='std_msgs/String')
    damage = ReadStats()
    with open_bags([bag]) as bags:
        assert bags.topics['/s'].msgtype == 'std_msgs/msg/String'
        read = list(iter_messages(bags, damage=damage))
    want = [('std_msgs/msg/String', f'm{i}') for i in range(3)]
    assert [(m.msgtype, m.msg.data) for m in read] == want
    assert damage.undecodable == 0
