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
"""The vectorized PointCloud decoder reads what rosbags reads (CDR, ROS 1); misfits: rosbags."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pmba_ros.backend.tracks import parse_tracks
from pmba_ros.io import cloud_decode
from pmba_ros.io.bag_writer import open_writer
from pmba_ros.io.bags import iter_messages, jazzy_typestore, noetic_typestore
import pytest

POINT_CLOUD = cloud_decode.POINT_CLOUD


def _cloud(n: int, n_channels: int, frame: str, sec: int, seed: int, store: Any = None) -> Any:
    store = store or jazzy_typestore()
    types = store.types
    rng = np.random.default_rng(seed)
    seq = {'seq': seed} if 'seq' in dict(store.fielddefs['std_msgs/msg/Header'][1]) else {}
    header = types['std_msgs/msg/Header'](
        **seq, stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=123), frame_id=frame)
    xy = rng.normal(size=(n, 2)).astype(np.float32)
    points = [types['geometry_msgs/msg/Point32'](x=float(x), y=float(y), z=1.0) for x, y in xy]
    channels = [types['sensor_msgs/msg/ChannelFloat32'](
        name='c' * k, values=rng.normal(size=n).astype(np.float32))
        for k in range(n_channels)]
    return types[POINT_CLOUD](header=header, points=points, channels=channels)


def _assert_same(fast: Any, slow: Any) -> None:
    assert fast.header.stamp.sec == slow.header.stamp.sec
    assert fast.header.stamp.nanosec == slow.header.stamp.nanosec
    assert fast.header.frame_id == slow.header.frame_id
    xyz = np.array([[p.x, p.y, p.z] for p in slow.points], dtype=np.float32).reshape(-1, 3)
    assert fast.points.dtype == np.float32 and np.array_equal(fast.points, xyz)
    assert [c.name for c in fast.channels] == [c.name for c in slow.channels]
    for a, b in zip(fast.channels, slow.channels, strict=True):
        assert np.array_equal(a.values, b.values)


@pytest.mark.parametrize('little_endian', [True, False])
@pytest.mark.parametrize(('n', 'n_channels', 'frame'),
                         [(0, 0, ''), (1, 5, 'cam0'), (3, 6, 'c'), (40, 7, 'world_ned')])
def test_decodes_what_rosbags_decodes(little_endian: bool, n: int, n_channels: int,
                                      frame: str) -> None:
    """Both byte orders; empty clouds, odd frame-name and channel-name lengths (padding)."""
    store = jazzy_typestore()
    msg = _cloud(n, n_channels, frame, sec=-7 if n == 3 else 1_700_000_000, seed=n)
    raw = bytes(store.serialize_cdr(msg, POINT_CLOUD, little_endian=little_endian))
    fast = cloud_decode.decode_point_cloud(raw, store)
    assert fast is not None
    _assert_same(fast, store.deserialize_cdr(raw, POINT_CLOUD))


@pytest.mark.parametrize(('n', 'n_channels', 'frame'),
                         [(0, 0, ''), (1, 5, 'cam0'), (3, 6, 'c'), (40, 7, 'world_ned')])
def test_decodes_ros1_as_rosbags_does(n: int, n_channels: int, frame: str) -> None:
    """ROS 1: packed, no encapsulation, strings without NUL, the header's seq."""
    store = noetic_typestore()
    msg = _cloud(n, n_channels, frame, sec=1_300_000_000 + n, seed=n, store=store)
    raw = bytes(store.serialize_ros1(msg, POINT_CLOUD))
    fast = cloud_decode.decode_point_cloud(raw, store, ros1=True)
    assert fast is not None
    slow = store.deserialize_ros1(raw, POINT_CLOUD)
    _assert_same(fast, slow)
    assert fast.header.seq == slow.header.seq == n
    assert cloud_decode.decode_point_cloud(raw[:-1], store, ros1=True) is None
    assert cloud_decode.decode_point_cloud(raw + b'\x00', store, ros1=True) is None


def test_parse_tracks_reads_both_forms_alike() -> None:
    """A vins_fusion frame parses to the same observations from either decoder."""
    store = jazzy_typestore()
    msg = _cloud(25, 6, 'cam0', 5, seed=3)
    msg.channels[0].values[:] = np.arange(25)
    msg.channels[1].values[:] = 0
    raw = bytes(store.serialize_cdr(msg, POINT_CLOUD))
    fast = parse_tracks(cloud_decode.decode_point_cloud(raw, store), 'vins_fusion')
    slow = parse_tracks(store.deserialize_cdr(raw, POINT_CLOUD), 'vins_fusion')
    assert fast.feature_ids.size == 25
    assert np.array_equal(fast.feature_ids, slow.feature_ids)
    assert np.array_equal(fast.normalized, slow.normalized)
    assert np.array_equal(fast.pixels, slow.pixels)


@pytest.mark.parametrize('cut', [1, 3, 4, 9, 20, 60])
def test_misfits_are_left_to_rosbags(cut: int) -> None:
    """Truncated buffers, extra bytes, bad encapsulation and counts past the end give None."""
    store = jazzy_typestore()
    raw = bytes(store.serialize_cdr(_cloud(4, 6, 'cam0', 1, seed=0), POINT_CLOUD))
    assert cloud_decode.decode_point_cloud(raw[:-cut], store) is None
    assert cloud_decode.decode_point_cloud(raw + bytes(8 + cut), store) is None
    assert cloud_decode.decode_point_cloud(b'\x01\x01' + raw[2:], store) is None
    huge = bytearray(raw)
    huge[4 + 12 + 8:4 + 12 + 12] = (2**31).to_bytes(4, 'little')  # the point count
    assert cloud_decode.decode_point_cloud(bytes(huge), store) is None


def test_only_standard_definitions_take_the_fast_path() -> None:
    """A bag defining PointCloud (or a type in it) differently keeps rosbags' decoder."""
    reference = jazzy_typestore()
    assert cloud_decode.fast_decoder(reference, POINT_CLOUD, reference) is not None
    assert cloud_decode.fast_decoder(reference, 'sensor_msgs/msg/PointCloud2', reference) is None

    class _Custom:
        def __init__(self) -> None:
            self.fielddefs = dict(reference.fielddefs)
            self.fielddefs['geometry_msgs/msg/Point32'] = ([], [('x', (1, 'float64'))])
    assert cloud_decode.fast_decoder(_Custom(), POINT_CLOUD, reference) is None


def test_ros1_bag_reading_yields_the_same_tracks(tmp_path: Path) -> None:
    """A ROS 1 bag's clouds, read with points as arrays, equal rosbags' own decoding."""
    from rosbags.rosbag1 import Writer

    store = noetic_typestore()
    clouds = [_cloud(10 + i, 5, 'cam0', i + 1, seed=i, store=store) for i in range(3)]
    path = tmp_path / 'vins.bag'
    with Writer(path) as writer:
        conn = writer.add_connection('/feature_tracker/feature', POINT_CLOUD, typestore=store)
        for i, msg in enumerate(clouds):
            writer.write(conn, (i + 1) * 10**9, store.serialize_ros1(msg, POINT_CLOUD))
    read = [m.msg for m in iter_messages([path], points_as_arrays=True)]
    assert len(read) == 3
    for fast, msg in zip(read, clouds, strict=True):
        assert isinstance(fast.points, np.ndarray)
        _assert_same(fast, store.deserialize_ros1(store.serialize_ros1(msg, POINT_CLOUD),
                                                  POINT_CLOUD))


@pytest.mark.parametrize('name', ['folder_bag', 'bare.mcap'])
def test_replay_reading_yields_the_same_tracks(tmp_path: Path, name: str) -> None:
    """Read back from a written bag, the clouds equal rosbags' own decoding."""
    store = jazzy_typestore()
    clouds = [_cloud(10 + i, 6, 'cam0', i + 1, seed=i) for i in range(3)]
    with open_writer(tmp_path / name) as writer:
        for i, msg in enumerate(clouds):
            writer.write('/feature', msg, (i + 1) * 10**9)
    read = [m.msg for m in iter_messages([tmp_path / name], points_as_arrays=True)]
    assert len(read) == 3
    for fast, msg in zip(read, clouds, strict=True):
        assert isinstance(fast.points, np.ndarray)
        raw = bytes(store.serialize_cdr(msg, POINT_CLOUD))
        _assert_same(fast, store.deserialize_cdr(raw, POINT_CLOUD))
    plain = next(iter_messages([tmp_path / name])).msg   # by default: rosbags' messages
    assert bytes(store.serialize_cdr(plain, POINT_CLOUD)) == bytes(
        store.serialize_cdr(clouds[0], POINT_CLOUD))
