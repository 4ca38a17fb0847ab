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
"""MCAP files of ROS 1 messages (``mcap convert demo.bag demo.mcap``) read as ROS 1 bags."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pmba_ros.errors import BagError
from pmba_ros.io.bags import iter_messages, open_bags, ReadStats
import pytest


def write_ros1_bag(path: Path, n: int) -> None:
    """Write ``n`` PoseStamped on /gt and a PointCloud on /cloud each 100 ms, as ROS 1 records."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import get_typestore, Stores

    ros1 = get_typestore(Stores.ROS1_NOETIC)
    types = ros1.types
    with Writer(path) as writer:
        gt = writer.add_connection('/gt', 'geometry_msgs/msg/PoseStamped', typestore=ros1)
        cloud = writer.add_connection('/cloud', 'sensor_msgs/msg/PointCloud', typestore=ros1)
        for i in range(n):
            t = 1_000_000_000 + i * 100_000_000
            header = types['std_msgs/msg/Header'](
                seq=i, stamp=types['builtin_interfaces/msg/Time'](sec=t // 10**9,
                                                                  nanosec=t % 10**9),
                frame_id='map')
            pose = types['geometry_msgs/msg/PoseStamped'](header=header, pose=types[
                'geometry_msgs/msg/Pose'](position=types['geometry_msgs/msg/Point'](
                    x=float(i), y=0.0, z=0.0), orientation=types[
                    'geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0)))
            writer.write(gt, t, ros1.serialize_ros1(pose, 'geometry_msgs/msg/PoseStamped'))
            points = [types['geometry_msgs/msg/Point32'](x=float(i), y=1.0, z=2.0)]
            msg = types['sensor_msgs/msg/PointCloud'](header=header, points=points, channels=[])
            writer.write(cloud, t, ros1.serialize_ros1(msg, 'sensor_msgs/msg/PointCloud'))


def write_ros1_mcap(bag: Path, dest: Path, chunk_size: int = 1024 * 1024) -> None:
    """Write a ROS 1 bag's messages into MCAP as ``mcap convert`` does (the ``ros1`` profile).

    Schemas named ``package/Type`` hold each connection's full definition; channels carry
    the caller id only (the profile's user data), no MD5 sum.
    """
    from mcap.writer import Writer as McapWriter
    from rosbags.rosbag1 import Reader
    from rosbags.typesys.msg import denormalize_msgtype

    with Reader(bag) as reader, dest.open('wb') as out:
        writer = McapWriter(out, chunk_size=chunk_size)
        writer.start(profile='ros1', library='mcap go')
        schemas: dict[str, int] = {}
        channels: dict[int, int] = {}
        for conn in reader.connections:
            if conn.msgtype not in schemas:
                schemas[conn.msgtype] = writer.register_schema(
                    denormalize_msgtype(conn.msgtype), 'ros1msg', conn.msgdef.data.encode())
            channels[conn.id] = writer.register_channel(
                conn.topic, 'ros1', schemas[conn.msgtype], {'callerid': '/recorder'})
        for conn, t_ns, raw in reader.messages():
            writer.add_message(channels[conn.id], t_ns, raw, t_ns)
        writer.finish()


def _read(paths: list[Path], damage: ReadStats | None = None) -> list[tuple[str, str, int, Any]]:
    with open_bags(paths) as bags:
        return [(m.topic, m.msgtype, m.log_time_ns, m.msg)
                for m in iter_messages(bags, damage=damage)]


@pytest.fixture
def ros1_bag(tmp_path: Path) -> Path:
    """Return a ROS 1 bag of 40 poses and 40 point clouds."""
    bag = tmp_path / 'rec.bag'
    write_ros1_bag(bag, 40)
    return bag


def test_ros1_mcap_reads_as_its_ros1_bag(ros1_bag: Path, tmp_path: Path) -> None:
    """Every message as the bag has it, with ROS 1 types; no damage said (it is whole).

    rosbags alone refuses the file ("Profile is not ros2").
    """
    from rosbags.highlevel import AnyReader, AnyReaderError

    mcap = tmp_path / 'rec.mcap'
    write_ros1_mcap(ros1_bag, mcap)
    with pytest.raises(AnyReaderError, match='ros2'), AnyReader([mcap]):
        pass
    with open_bags([mcap]) as bags:
        assert bags.damage == ()
        assert bags.topics['/gt'].msgtype == 'geometry_msgs/msg/PoseStamped'
        assert bags.topics['/cloud'].count == 40
    want, got = _read([ros1_bag]), _read([mcap])
    assert [m[:3] for m in got] == [m[:3] for m in want] and len(got) == 80
    assert [m[3].pose.position.x for m in got if m[0] == '/gt'] == list(map(float, range(40)))
    assert all(hasattr(m[3].header, 'seq') for m in got)   # decoded as ROS 1 messages


def test_ros1_mcap_md5_sums_are_ros1s(ros1_bag: Path, tmp_path: Path) -> None:
    """The copy's connections carry the MD5 sums ROS 1 gives the types (the file has none)."""
    from pmba_ros.io.salvage.ros1_mcap import _md5sum
    from rosbags.rosbag1 import Reader
    from rosbags.typesys import get_typestore, Stores

    noetic = get_typestore(Stores.ROS1_NOETIC)
    with Reader(ros1_bag) as reader:
        for conn in reader.connections:
            assert _md5sum(conn.msgtype, conn.msgdef.data) == conn.digest == \
                noetic.generate_msgdef(conn.msgtype)[1]


def test_damaged_ros1_mcap_is_read_around_its_damage(ros1_bag: Path, tmp_path: Path) -> None:
    """A cut or zeroed ROS 1 MCAP file: the messages of its whole chunks, the damage named."""
    mcap = tmp_path / 'rec.mcap'
    write_ros1_mcap(ros1_bag, mcap, chunk_size=2000)
    data = mcap.read_bytes()
    want = _read([ros1_bag])
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:len(data) // 2])
    with open_bags([cut]) as bags:
        assert len(bags.damage) == 1 and str(cut) in bags.damage[0]
        assert 'ROS 1' in bags.damage[0] and 'the rest of the file is lost' in bags.damage[0]
    got = _read([cut])
    assert 10 < len(got) < len(want) and [m[:3] for m in got] == [m[:3] for m in want[:len(got)]]
    zeroed = tmp_path / 'zeroed.mcap'
    zeroed.write_bytes(data[:len(data) // 3] + bytes(50) + data[len(data) // 3 + 50:])
    with open_bags([zeroed]) as bags:
        assert len(bags.damage) == 1 and 'skipped (damaged)' in bags.damage[0]
    got = _read([zeroed], ReadStats())
    assert 10 < len(got) < len(want) and {m[:3] for m in got} < {m[:3] for m in want}
    assert any(m[2] > want[len(want) // 2][2] for m in got)   # read on after the damage


def test_ros1_mcap_without_a_readable_message_is_named(ros1_bag: Path, tmp_path: Path) -> None:
    """Cut inside its first chunk: one error naming the file as ROS 1 MCAP, not the profile."""
    mcap = tmp_path / 'rec.mcap'
    write_ros1_mcap(ros1_bag, mcap)
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(mcap.read_bytes()[:100])   # the header, and the chunk's start
    with pytest.raises(BagError) as err, open_bags([cut]):
        pass
    text = str(err.value)
    assert text.startswith(f'{cut}: an MCAP file of ROS 1 messages') and 'not a message' in text
    assert 'Profile' not in text


def test_ros1_mcap_with_a_definition_that_does_not_parse_is_named(tmp_path: Path) -> None:
    """A schema whose ROS 1 definition is garbage: an error naming the file and the type."""
    from mcap.writer import Writer as McapWriter

    bad = tmp_path / 'bad.mcap'
    with bad.open('wb') as out:
        writer = McapWriter(out)
        writer.start(profile='ros1', library='test')
        schema = writer.register_schema('my_msgs/Thing', 'ros1msg', b'int32 ! what\n')
        channel = writer.register_channel('/thing', 'ros1', schema, {})
        writer.add_message(channel, 1, bytes(4), 1)
        writer.finish()
    with pytest.raises(BagError, match=rf'^{bad}: the ROS 1 definition of my_msgs/Thing '
                       'does not parse'), open_bags([bad]):
        pass
