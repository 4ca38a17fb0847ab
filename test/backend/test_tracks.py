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
"""Feature-track and keyframe parsing on rosbags (CDR round trip) and mcap_ros2 objects."""

from __future__ import annotations

import array
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
from pmba_ros.backend import outputs
from pmba_ros.backend.msg_backend import RclpyBackend
from pmba_ros.backend.tracks import LAYOUTS, parse_keyframe, parse_tracks, stamp_to_ns, TrackMemory
from pmba_ros.backend.types import CameraModel, TrackFrame
from pmba_ros.errors import MessageError
from pmba_ros.sim.inputs import make_tracks
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

STAMP_NS = 1_700_000_123_456_789
# (layout, num_cams) cases; per_point carries camera 0 only
CASES = [('vins_mono', 1), ('vins_mono', 2), ('vins_fusion', 1), ('vins_fusion', 2),
         ('per_point', 1), ('named', 1), ('named', 3)]


def cdr_roundtrip(ts: Any, msg: Any) -> Any:
    """Serialize to Jazzy CDR and deserialize again."""
    return ts.deserialize_cdr(ts.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__)


def mcap_roundtrip(ts: Any, path: Path, items: list[tuple[str, Any]]) -> dict[str, Any]:
    """Write (topic, msg) pairs to an MCAP bag with rosbags, decode them with mcap_ros2."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns: dict[str, Any] = {}
        for i, (topic, msg) in enumerate(items):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
            writer.write(conns[topic], 1_000 + i, ts.serialize_cdr(msg, msg.__msgtype__))
    with (path / f'{path.name}.mcap').open('rb') as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        return {ch.topic: ros_msg for _, ch, _, ros_msg in reader.iter_decoded_messages()}


def random_frame(rng: np.random.Generator, layout: str, num_cams: int, k: int = 40,
                 ) -> TrackFrame:
    """Return a frame with unique (id, cam) pairs; stereo frames repeat ids across cams."""
    ids = rng.choice(100_000, size=k, replace=False)
    cams = rng.integers(0, num_cams, size=k) if layout != 'per_point' else np.zeros(k, int)
    if num_cams > 1:
        ids[1] = ids[0]
        cams[:2] = [0, 1]
    pixels = rng.uniform([0, 0], [752, 480], size=(k, 2))
    normalized = rng.uniform(-0.8, 0.8, size=(k, 2))
    return TrackFrame(STAMP_NS, 'world', ids, cams, pixels, normalized)


def assert_same(got: TrackFrame, want: TrackFrame) -> None:
    """Compare a parsed frame with the written one (coordinates travel as float32)."""
    assert got.stamp_ns == want.stamp_ns
    assert got.frame_id == want.frame_id
    np.testing.assert_array_equal(got.feature_ids, want.feature_ids)
    np.testing.assert_array_equal(got.camera_ids, want.camera_ids)
    assert got.pixels is not None and want.pixels is not None
    np.testing.assert_allclose(got.pixels, want.pixels, rtol=1e-6, atol=1e-4)
    assert got.normalized is not None and want.normalized is not None
    np.testing.assert_allclose(got.normalized, want.normalized, atol=1e-6)
    assert got.dropped == 0


@pytest.mark.parametrize(('layout', 'num_cams'), CASES)
def test_layout_roundtrip_through_jazzy_cdr(ts: Any, backend: Any, layout: str,
                                            num_cams: int) -> None:
    """Tracks written in a layout parse back to the same frame after Jazzy CDR."""
    frame = random_frame(np.random.default_rng(1), layout, num_cams)
    msg = cdr_roundtrip(ts, make_tracks(frame, layout, backend, num_cams))
    assert_same(parse_tracks(msg, layout, num_cams), frame)


def test_all_layouts_roundtrip_through_mcap_ros2(ts: Any, backend: Any, tmp_path: Path,
                                                 ) -> None:
    """Every layout parses back from mcap_ros2's decoded messages (lists, bytes)."""
    rng = np.random.default_rng(2)
    frames = {f'/{lay}_{n}': (lay, n, random_frame(rng, lay, n)) for lay, n in CASES}
    items = [(topic, make_tracks(f, lay, backend, n))
             for topic, (lay, n, f) in frames.items()]
    decoded = mcap_roundtrip(ts, tmp_path / 'tracks', items)
    assert set(decoded) == set(frames)
    for topic, (lay, n, frame) in frames.items():
        msg = decoded[topic]
        if lay != 'named':
            assert isinstance(msg.channels[0].values, list)  # mcap_ros2 gives lists
        else:
            assert isinstance(msg.data, bytes)
        assert_same(parse_tracks(msg, lay, n), frame)


def test_rclpy_style_containers_parse(ts: Any) -> None:
    """array.array sequences (what rclpy messages hold) parse like numpy ones."""
    loader = fake_message_modules(ts)
    frame = random_frame(np.random.default_rng(3), 'vins_fusion', 2)
    for layout in LAYOUTS:
        if layout == 'per_point':
            frame = random_frame(np.random.default_rng(3), 'per_point', 1)
        msg = make_tracks(frame, layout, RclpyBackend(loader), 2)
        if layout == 'named':
            assert isinstance(msg.data, array.array)
        else:
            assert isinstance(msg.channels[0].values, array.array)
        assert_same(parse_tracks(msg, layout, 2), frame)


def fake_message_modules(ts: Any) -> Any:
    """Return a module loader that serves rosbags classes as 'pkg.msg' modules."""
    def load(name: str) -> Any:
        prefix = name.replace('.', '/') + '/'
        return SimpleNamespace(**{k[len(prefix):]: v for k, v in ts.types.items()
                                  if k.startswith(prefix)})
    return load


def point_cloud(ts: Any, points: Any, channels: list[list[float]]) -> Any:
    """Build a sensor_msgs/PointCloud directly from the typestore classes."""
    t = ts.types
    header = t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](sec=3, nanosec=7),
                                      frame_id='world')
    pts = [t['geometry_msgs/msg/Point32'](x=float(p[0]), y=float(p[1]), z=float(p[2]))
           for p in points]
    chans = [t['sensor_msgs/msg/ChannelFloat32'](name='', values=np.asarray(c, np.float32))
             for c in channels]
    return t['sensor_msgs/msg/PointCloud'](header=header, points=pts, channels=chans)


def test_vins_mono_decodes_id_and_camera_with_rounding(ts: Any) -> None:
    """VINS-Mono codes id*num_cams+cam are rounded from float32 and split."""
    # codes 7 and 10 (float32 noise) with NUM_OF_CAM = 2 -> (3, 1) and (5, 0)
    msg = point_cloud(ts, [[0.1, 0.2, 1.0], [0.3, 0.4, 1.0]],
                      [[6.9999, 10.0002], [10, 20], [11, 21], [0, 0], [0, 0]])
    frame = parse_tracks(msg, 'vins_mono', num_cams=2)
    assert frame.stamp_ns == 3_000_000_007
    np.testing.assert_array_equal(frame.feature_ids, [3, 5])
    np.testing.assert_array_equal(frame.camera_ids, [1, 0])


def test_per_point_openvins_zero_normalized_means_missing(ts: Any) -> None:
    """Zero normalized coordinates (OpenVINS) mean none: the pixels are kept alone."""
    cam = CameraModel(400.0, 400.0, 320.0, 240.0, 'plumb_bob', [-0.2, 0.05, 0, 0, 0])
    xy = np.array([[0.1, -0.2], [-0.3, 0.25], [0.0, 0.0]])
    px = cam.denormalize(xy)
    channels = [[0.0, 0.0, u, v, fid] for (u, v), fid in zip(px, [11, 12, 13], strict=True)]
    msg = point_cloud(ts, np.full((3, 3), 5.0), channels)
    frame = parse_tracks(msg, 'per_point')
    assert frame.normalized is None
    assert frame.pixels is not None
    np.testing.assert_array_equal(frame.feature_ids, [11, 12, 13])
    np.testing.assert_allclose(cam.normalize(frame.pixels), xy, atol=1e-5)


def test_per_point_accepts_longer_channels(ts: Any) -> None:
    """Per-point channels with extra trailing values are read."""
    msg = point_cloud(ts, np.zeros((2, 3)),
                      [[0.1, 0.2, 10, 20, 4, 99], [0.3, 0.4, 30, 40, 5, 99, 98]])
    frame = parse_tracks(msg, 'per_point')
    np.testing.assert_array_equal(frame.feature_ids, [4, 5])
    assert frame.normalized is not None
    np.testing.assert_allclose(frame.normalized, [[0.1, 0.2], [0.3, 0.4]], atol=1e-7)


@pytest.mark.parametrize('layout', ['vins_mono', 'vins_fusion', 'per_point', 'named'])
def test_nonfinite_coordinates_are_dropped_and_counted(backend: Any, layout: str) -> None:
    """Observations with a non-finite pixel or coordinate are dropped and counted."""
    frame = random_frame(np.random.default_rng(4), layout, 1, k=10)
    pixels = frame.pixels.copy()  # type: ignore[union-attr]
    normalized = frame.normalized.copy()  # type: ignore[union-attr]
    pixels[2, 0] = np.nan
    pixels[5, 1] = np.inf
    normalized[7, 0] = -np.inf
    bad = TrackFrame(frame.stamp_ns, frame.frame_id, frame.feature_ids, frame.camera_ids,
                     pixels, normalized)
    got = parse_tracks(make_tracks(bad, layout, backend), layout)
    keep = np.setdiff1d(np.arange(10), [2, 5, 7])
    assert got.dropped == 3
    np.testing.assert_array_equal(got.feature_ids, frame.feature_ids[keep])
    assert np.all(np.isfinite(got.pixels)) and np.all(np.isfinite(got.normalized))


def test_nonfinite_id_is_dropped(ts: Any) -> None:
    """An observation with a NaN feature id is dropped and counted."""
    msg = point_cloud(ts, [[0.1, 0.2, 1.0], [0.3, 0.4, 1.0]],
                      [[np.nan, 4], [0, 0], [10, 20], [11, 21], [0, 0], [0, 0]])
    frame = parse_tracks(msg, 'vins_fusion')
    np.testing.assert_array_equal(frame.feature_ids, [4])
    assert frame.dropped == 1


def test_duplicate_ids_without_history_are_dropped_and_stereo_pairs_survive(ts: Any) -> None:
    """A repeated (id, cam) with no previous observation is ambiguous: every copy goes."""
    ids = [5, 6, 5, 5, 6]
    cams = [0, 0, 0, 1, 0]
    us = [1.0, 2.0, 3.0, 4.0, 5.0]
    msg = point_cloud(ts, [[0.0, 0.0, 1.0]] * 5, [ids, cams, us, us, [0] * 5, [0] * 5])
    frame = parse_tracks(msg, 'vins_fusion', num_cams=2)
    np.testing.assert_array_equal(frame.feature_ids, [5])
    np.testing.assert_array_equal(frame.camera_ids, [1])
    assert frame.dropped == 4
    assert frame.drop_reasons == {'ambiguous_duplicate_observations': 4}


def test_duplicate_ids_keep_the_copy_consistent_with_the_track(ts: Any) -> None:
    """With the previous frame remembered, the copy nearest to the track wins, first or not."""
    memory = TrackMemory()
    before = point_cloud(ts, [[0.10, 0.20, 1.0], [0.30, 0.40, 1.0]],
                         [[5, 6], [0, 0], [1, 2], [1, 2], [0, 0], [0, 0]])
    parse_tracks(before, 'vins_fusion', memory=memory)
    garbage_first = point_cloud(
        ts, [[-0.9, 0.8, 1.0], [0.11, 0.21, 1.0], [0.31, 0.41, 1.0], [0.5, -0.7, 1.0]],
        [[5, 5, 6, 6], [0] * 4, [9, 1, 2, 8], [9, 1, 2, 8], [0] * 4, [0] * 4])
    frame = parse_tracks(garbage_first, 'vins_fusion', memory=memory)
    np.testing.assert_array_equal(frame.feature_ids, [5, 6])
    np.testing.assert_allclose(frame.normalized, [[0.11, 0.21], [0.31, 0.41]], atol=1e-6)
    assert frame.drop_reasons == {'duplicate_observations': 2}


@pytest.mark.parametrize(('layout', 'bad_id', 'reason'), [
    ('vins_fusion', 2.0 ** 24 + 2, 'feature_ids_inexact'),
    ('vins_fusion', 1e19, 'feature_ids_inexact'),
    ('vins_mono', 2.0 ** 24, 'feature_ids_inexact'),
])
def test_ids_that_cannot_be_exact_in_float32_are_dropped(ts: Any, layout: str, bad_id: float,
                                                         reason: str) -> None:
    """Ids >= 2^24 in float32 channels (neighbours merge; 1e19 overflows int64) are counted."""
    ids = [3.0, bad_id, 4.0]
    if layout == 'vins_mono':
        channels = [ids, [1, 2, 3], [1, 2, 3], [0] * 3, [0] * 3]
    else:
        channels = [ids, [0] * 3, [1, 2, 3], [1, 2, 3], [0] * 3, [0] * 3]
    frame = parse_tracks(point_cloud(ts, [[0.0, 0.0, 1.0]] * 3, channels), layout)
    np.testing.assert_array_equal(frame.feature_ids, [3, 4])
    assert frame.feature_ids.min() >= 0
    assert frame.drop_reasons == {reason: 1} and frame.dropped == 1


@pytest.mark.parametrize('n_pts', [3, 5, 6, 8])
def test_per_point_data_fed_to_vins_fusion_raises(backend: Any, n_pts: int) -> None:
    """Also for 5 and 6 points, where every channel happens to have one value per point."""
    frame = random_frame(np.random.default_rng(n_pts), 'per_point', 1, k=n_pts)
    msg = make_tracks(frame, 'per_point', backend,
                      landmarks_xyz=np.full((n_pts, 3), 4.0))
    for layout in ('vins_fusion', 'vins_mono'):
        with pytest.raises(MessageError, match='wrong layout'):
            parse_tracks(msg, layout)


@pytest.mark.parametrize(('written', 'read'), [('vins_fusion', 'vins_mono'),
                                               ('vins_mono', 'vins_fusion'),
                                               ('vins_fusion', 'per_point'),
                                               ('vins_mono', 'named'),
                                               ('named', 'vins_fusion')])
def test_other_layout_mixups_raise(backend: Any, written: str, read: str) -> None:
    """Another layout's reader: a 'wrong layout' MessageError naming the layout that reads it."""
    frame = random_frame(np.random.default_rng(5), written, 1, k=12)
    with pytest.raises(MessageError, match=f"wrong layout.*it parses in layout '{written}': "
                                           'set feature_layout'):
        parse_tracks(make_tracks(frame, written, backend), read)


def test_channel_of_wrong_length_raises(ts: Any) -> None:
    """A channel shorter than the points is a MessageError naming both lengths."""
    msg = point_cloud(ts, [[0.1, 0.2, 1.0], [0.3, 0.4, 1.0]],
                      [[1, 2], [0, 0], [10, 20], [11], [0, 0], [0, 0]])
    with pytest.raises(MessageError, match=r'one value per point.*\[3\].*\[1\]'):
        parse_tracks(msg, 'vins_fusion')


def test_per_point_short_channel_raises(ts: Any) -> None:
    """A per-point channel with fewer than five values is a MessageError."""
    msg = point_cloud(ts, np.zeros((2, 3)), [[0, 0, 1, 2, 3], [0, 0, 1, 2]])
    with pytest.raises(MessageError, match='>= 5 values'):
        parse_tracks(msg, 'per_point')


def test_non_integral_ids_raise(ts: Any) -> None:
    """Fractional feature ids are a MessageError."""
    msg = point_cloud(ts, [[0.1, 0.2, 1.0]], [[2.5], [0], [10], [11], [0], [0]])
    with pytest.raises(MessageError, match='non-negative integers'):
        parse_tracks(msg, 'vins_fusion')


def test_camera_id_out_of_range_raises(ts: Any) -> None:
    """Camera ids at or above num_cams are a MessageError."""
    msg = point_cloud(ts, [[0.1, 0.2, 1.0]], [[2], [1], [10], [11], [0], [0]])
    with pytest.raises(MessageError, match='num_cams'):
        parse_tracks(msg, 'vins_fusion', num_cams=1)
    assert parse_tracks(msg, 'vins_fusion', num_cams=2).camera_ids.tolist() == [1]


def test_unknown_layout_and_bad_num_cams_raise(ts: Any) -> None:
    """An unknown layout or num_cams below one is a MessageError."""
    msg = point_cloud(ts, [], [])
    with pytest.raises(MessageError, match="unknown feature layout 'orb'"):
        parse_tracks(msg, 'orb')
    with pytest.raises(MessageError, match='num_cams'):
        parse_tracks(msg, 'vins_mono', num_cams=0)


@pytest.mark.parametrize('layout', LAYOUTS)
def test_empty_cloud_gives_empty_frame(ts: Any, backend: Any, layout: str) -> None:
    """An empty cloud in any layout gives an empty frame with the message's stamp."""
    empty = TrackFrame.empty(STAMP_NS, 'world')
    msg = cdr_roundtrip(ts, make_tracks(empty, layout, backend))
    frame = parse_tracks(msg, layout)
    assert len(frame) == 0
    assert frame.stamp_ns == STAMP_NS
    assert frame.dropped == 0


def test_empty_pointcloud_without_channels(ts: Any) -> None:
    """A PointCloud without points and channels gives an empty frame."""
    assert len(parse_tracks(point_cloud(ts, [], []), 'vins_fusion')) == 0


def named_cloud(backend: Any, columns: dict[str, Any], **kwargs: Any) -> Any:
    """Build a named PointCloud2 from columns."""
    return outputs.make_point_cloud2_named(STAMP_NS, 'cam0', columns, backend, **kwargs)


@pytest.mark.parametrize('missing', ['id', 'u'])
def test_named_missing_field_raises(backend: Any, missing: str) -> None:
    """A named cloud without id, u or v is a MessageError listing the fields needed."""
    cols = {'id': np.array([1, 2], np.uint32), 'cam': np.zeros(2, np.uint8),
            'u': np.ones(2, np.float32), 'v': np.ones(2, np.float32)}
    del cols[missing]
    with pytest.raises(MessageError, match='needs PointCloud2 fields'):
        parse_tracks(named_cloud(backend, cols), 'named')


def test_named_big_endian_float64_extra_fields_and_no_cam(ts: Any, backend: Any) -> None:
    """Named clouds may be big-endian, float64, padded and without a cam field."""
    cols = {'x': np.arange(3, dtype=np.float32), 'id': np.array([7, 8, 9], np.float64),
            'pad': np.zeros(3, np.uint8), 'x_n': np.array([0.1, 0.2, 0.3], np.float64),
            'y_n': np.array([0.4, 0.5, 0.6], np.float64)}
    msg = cdr_roundtrip(ts, named_cloud(backend, cols, big_endian=True))
    assert msg.is_bigendian
    frame = parse_tracks(msg, 'named')
    np.testing.assert_array_equal(frame.feature_ids, [7, 8, 9])
    np.testing.assert_array_equal(frame.camera_ids, [0, 0, 0])
    assert frame.pixels is None
    np.testing.assert_allclose(frame.normalized, [[0.1, 0.4], [0.2, 0.5], [0.3, 0.6]])


def test_named_organized_cloud_with_row_padding(ts: Any) -> None:
    """An organized cloud (height 2, width 2) with 4 padding bytes per row parses."""
    t = ts.types
    point = np.dtype([('id', '<u4'), ('cam', 'u1'), ('pad', 'u1', 3), ('u', '<f4'),
                      ('v', '<f4')])
    rows = np.zeros((2, 2), point)
    rows['id'] = [[1, 2], [3, 4]]
    rows['u'] = [[10, 20], [30, 40]]
    rows['v'] = [[11, 21], [31, 41]]
    data = b''.join(r.tobytes() + b'\xff' * 4 for r in rows)
    field = t['sensor_msgs/msg/PointField']
    fields = [field(name='id', offset=0, datatype=6, count=1),
              field(name='cam', offset=4, datatype=2, count=1),
              field(name='u', offset=8, datatype=7, count=1),
              field(name='v', offset=12, datatype=7, count=1)]
    header = t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](sec=1, nanosec=2),
                                      frame_id='cam')
    msg = t['sensor_msgs/msg/PointCloud2'](
        header=header, height=2, width=2, fields=fields, is_bigendian=False, point_step=16,
        row_step=36, data=np.frombuffer(data, np.uint8), is_dense=True)
    frame = parse_tracks(cdr_roundtrip(ts, msg), 'named')
    np.testing.assert_array_equal(frame.feature_ids, [1, 2, 3, 4])
    np.testing.assert_array_equal(frame.pixels, [[10, 11], [20, 21], [30, 31], [40, 41]])
    short = t['sensor_msgs/msg/PointCloud2'](
        header=header, height=2, width=2, fields=fields, is_bigendian=False, point_step=16,
        row_step=36, data=np.frombuffer(data[:60], np.uint8), is_dense=True)
    with pytest.raises(MessageError, match='need 68'):
        parse_tracks(short, 'named')


def test_named_field_beyond_point_step_raises(backend: Any) -> None:
    """A field that does not fit in point_step is a MessageError naming it."""
    msg = named_cloud(backend, {'id': np.array([1], np.uint32), 'u': np.ones(1, np.float32),
                                'v': np.ones(1, np.float32)})
    msg.point_step = 8
    with pytest.raises(MessageError, match="field 'v'"):
        parse_tracks(msg, 'named')


def test_keyframe_odometry_and_pose_stamped(ts: Any, backend: Any, tmp_path: Path) -> None:
    """Odometry and PoseStamped keyframes parse back from CDR and mcap_ros2."""
    cov = np.diag([1e-4] * 3 + [1e-5] * 3)
    quat = np.array([0.1, -0.2, 0.3, 0.9])
    odom = outputs.make_odometry(STAMP_NS, 'world', 'body', [1, 2, 3], quat, cov, backend)
    pose = outputs.make_pose_stamped(STAMP_NS + 1, 'odom', [4, 5, 6], quat, backend)
    decoded = mcap_roundtrip(ts, tmp_path / 'kf', [('/odom', odom), ('/pose', pose)])
    for msg_odom, msg_pose in [(cdr_roundtrip(ts, odom), cdr_roundtrip(ts, pose)),
                               (decoded['/odom'], decoded['/pose'])]:
        kf = parse_keyframe(msg_odom, 'odometry')
        assert (kf.stamp_ns, kf.frame_id, kf.child_frame_id) == (STAMP_NS, 'world', 'body')
        np.testing.assert_allclose(kf.position, [1, 2, 3])
        np.testing.assert_allclose(kf.quat_xyzw, quat / np.linalg.norm(quat))
        kf = parse_keyframe(msg_pose, 'pose_stamped')
        assert (kf.stamp_ns, kf.frame_id, kf.child_frame_id) == (STAMP_NS + 1, 'odom', '')
        np.testing.assert_allclose(kf.position, [4, 5, 6])


def test_keyframe_pose_with_covariance(ts: Any, backend: Any) -> None:
    """A PoseWithCovarianceStamped (ROVIO's, AMCL's): its pose and covariance, no child."""
    cov = np.diag([1e-4] * 3 + [1e-5] * 3)
    odom = outputs.make_odometry(STAMP_NS, 'world', 'body', [1, 2, 3], [0.1, -0.2, 0.3, 0.9],
                                 cov, backend)
    msg = cdr_roundtrip(ts, backend.new('geometry_msgs/msg/PoseWithCovarianceStamped',
                                        header=odom.header, pose=odom.pose))
    kf = parse_keyframe(msg, 'pose_with_covariance')
    ref = parse_keyframe(odom, 'odometry')
    assert (kf.stamp_ns, kf.frame_id, kf.child_frame_id) == (STAMP_NS, 'world', '')
    np.testing.assert_array_equal(kf.position, ref.position)
    np.testing.assert_array_equal(kf.quat_xyzw, ref.quat_xyzw)
    assert kf.covariance is not None and ref.covariance is not None
    np.testing.assert_array_equal(kf.covariance, ref.covariance)
    with pytest.raises(MessageError, match='expects geometry_msgs/msg/PoseWithCovarianceStamped'):
        parse_keyframe(outputs.make_pose_stamped(STAMP_NS, 'odom', [0, 0, 0], [0, 0, 0, 1],
                                                 backend), 'pose_with_covariance')


@pytest.mark.parametrize('quat', [[np.nan, 0, 0, 1], [0, 0, np.inf, 1], [0, 0, 0, 0]])
def test_keyframe_rejects_bad_quaternion(backend: Any, quat: list[float]) -> None:
    """Keyframe poses with a non-finite or zero quaternion are a MessageError."""
    msg = outputs.make_pose_stamped(STAMP_NS, 'odom', [0, 0, 0], [0, 0, 0, 1], backend)
    msg.pose.orientation.x, msg.pose.orientation.y = quat[0], quat[1]
    msg.pose.orientation.z, msg.pose.orientation.w = quat[2], quat[3]
    with pytest.raises(MessageError, match=r'non-finite|zero-norm'):
        parse_keyframe(msg, 'pose_stamped')


@pytest.mark.parametrize('w', [5.0, 0.0, 1e30, 0.99])
def test_keyframe_rejects_a_quaternion_off_unit_norm(backend: Any, w: float) -> None:
    """A quaternion whose squared norm is off 1 by over 0.01 (tf2's limit) is refused."""
    msg = outputs.make_pose_stamped(STAMP_NS, 'odom', [0, 0, 0], [0, 0, 0, 1], backend)
    msg.pose.orientation.x, msg.pose.orientation.w = 0.3, w
    with pytest.raises(MessageError, match='not a rotation'):
        parse_keyframe(msg, 'pose_stamped')
    # Float32 rounding or a slightly drifted integration: normalized and taken.
    q = np.array([0.3, 0.0, 0.0, np.sqrt(1 - 0.09)]) * 1.004
    msg.pose.orientation.x, msg.pose.orientation.w = q[0], q[3]
    np.testing.assert_allclose(parse_keyframe(msg, 'pose_stamped').quat_xyzw, q / 1.004)


def test_keyframe_wrong_kind_or_type_raises(backend: Any) -> None:
    """A keyframe of the wrong message type or an unknown kind is a MessageError."""
    msg = outputs.make_pose_stamped(STAMP_NS, 'odom', [0, 0, 0], [0, 0, 0, 1], backend)
    with pytest.raises(MessageError, match='expects nav_msgs/msg/Odometry'):
        parse_keyframe(msg, 'odometry')
    with pytest.raises(MessageError, match='unknown keyframe kind'):
        parse_keyframe(msg, 'tf')


def test_stamp_to_ns_is_exact_int() -> None:
    """Stamps convert to integer ns without float rounding; non-stamps are refused."""
    stamp = SimpleNamespace(sec=1_700_000_000, nanosec=999_999_999)
    assert stamp_to_ns(stamp) == 1_700_000_000_999_999_999
    with pytest.raises(MessageError, match='Time'):
        stamp_to_ns(object())
    assert stamp_to_ns(SimpleNamespace(sec=0, nanosec=0)) == 0
    # A front-end clock gone negative: every message had been refused with no reason given.
    with pytest.raises(MessageError, match=r'header stamp -99.000000000 s is negative'):
        stamp_to_ns(SimpleNamespace(sec=-99, nanosec=0))


def test_trackframe_validates_and_freezes() -> None:
    """A TrackFrame copies its arrays read-only and refuses inconsistent rows."""
    ids = np.array([1, 2])
    frame = TrackFrame(0, 'w', ids, [0, 0], None, [[0.0, 0.0], [1.0, 1.0]])
    ids[0] = 99
    assert frame.feature_ids[0] == 1  # copied
    assert not frame.feature_ids.flags.writeable
    with pytest.raises(MessageError, match='rows'):
        TrackFrame(0, 'w', [1, 2], [0, 0], [[0.0, 0.0]], None)
    with pytest.raises(MessageError, match='pixels or normalized'):
        TrackFrame(0, 'w', [1], [0], None, None)


def test_repeated_camera_info_gives_the_model_it_gave() -> None:
    """The same CameraInfo fields give the same model again; other fields are judged anew."""
    def info(k0: float = 400.0, d: tuple[float, ...] = (0.1, 0, 0, 0, 0),
             model: str = 'plumb_bob') -> SimpleNamespace:
        return SimpleNamespace(k=np.array([k0, 0, 320, 0, 400, 240, 0, 0, 1.0]),
                               d=array.array('d', d), distortion_model=model, width=640,
                               height=480)

    first = CameraModel.from_camera_info(info())
    again = CameraModel.from_camera_info(info())
    assert again is first
    other = CameraModel.from_camera_info(info(410.0))
    assert other.fx == 410.0 and other is not first
    assert CameraModel.from_camera_info(info(d=(0.0,) * 5)).distortion_model == 'none'
    for _ in range(2):   # a rejected message is rejected every time
        with pytest.raises(MessageError):
            CameraModel.from_camera_info(info(-1.0))
        with pytest.raises(MessageError):
            CameraModel.from_camera_info(info(model='fisheye62'))
    for i in range(40):   # the memory stays small
        CameraModel.from_camera_info(info(300.0 + i))
    from pmba_ros.backend import types
    assert len(types._CAMERA_INFOS) <= types._CAMERA_INFOS_KEPT


def test_a_binned_and_cropped_camera_maps_its_pixels_to_the_sensors(backend: Any) -> None:
    """Binning and ROI of a CameraInfo (REP 104): K is the sensor's, the pixels the image's.

    Pixel-only tracks of a camera publishing half-size images were read as full-size ones
    (ATE 19.6x the front-end's on a simulated recording, 0.14x with the same tracks unbinned).
    """
    from pmba_ros.backend.config import BackendConfig
    from pmba_ros.backend.logic import BackendLogic
    from pmba_ros.sim.inputs import make_camera_info

    d = np.array([-0.2, 0.05, 0.001, -0.002, 0.0])
    full = CameraModel(400.0, 390.0, 320.0, 240.0, 'plumb_bob', d, 640, 480)
    binned = CameraModel(400.0, 390.0, 320.0, 240.0, 'plumb_bob', full.d, 640, 480,
                         binning=(2, 2), offset=(100, 50))
    msg = make_camera_info(0, 'cam', binned, backend)
    read = CameraModel.from_camera_info(backend.typestore.deserialize_cdr(
        backend.serialize(msg), msg.__msgtype__))
    assert (read.binning, read.offset) == ((2, 2), (100, 50))
    assert 'binning=2x2 roi_offset=100,50' in read.describe()
    xy = np.random.default_rng(3).uniform(-0.4, 0.4, (50, 2))
    sensor_px = full.denormalize(xy)
    image_px = read.denormalize(xy)
    np.testing.assert_allclose(image_px, (sensor_px - [100, 50]) / 2, atol=1e-9)
    np.testing.assert_allclose(read.normalize(image_px), xy, atol=1e-9)
    bearings = np.column_stack([xy, np.ones(50)])
    bearings /= np.linalg.norm(bearings, axis=1)[:, None]
    jac_full, jac_image = full.pixel_jacobian(bearings), read.pixel_jacobian(bearings)
    assert jac_full is not None and jac_image is not None
    np.testing.assert_allclose(jac_image, jac_full / 2)
    logic = BackendLogic(BackendConfig(), backend)
    logic.on_camera_info(msg)
    assert (logic.estimator.fx, logic.estimator.cx) == (200.0, 110.0)
    with pytest.raises(MessageError, match='binning must be >= 1'):
        CameraModel(400.0, 390.0, 320.0, 240.0, binning=(0, 1))


@pytest.mark.parametrize('layout', ['vins_fusion', 'named'])
def test_pixels_in_the_normalized_fields_are_refused_by_name(backend: Any, layout: str) -> None:
    """Normalized coordinates in the hundreds: refused, naming the fields and the angle.

    Read as rays 89.8 degrees off the axis they had failed every initialization (13 tries of
    7-9 s each on an 80-keyframe street) and passed the front-end through in silence. A wide
    fisheye's rays (median 3, 72 degrees) are not refused, and the check can be left out.
    """
    rng = np.random.default_rng(3)
    pixels = rng.uniform([0, 0], [640, 480], (40, 2))
    frame = TrackFrame(STAMP_NS, 'camera', np.arange(40), np.zeros(40, dtype=int), pixels,
                       pixels)
    msg = make_tracks(frame, layout, backend)
    with pytest.raises(MessageError, match=r'look like pixels: .* 89\.\d degrees off the'):
        parse_tracks(msg, layout)
    assert len(parse_tracks(msg, layout, check_rays=False)) == 40
    wide = TrackFrame(STAMP_NS, 'camera', np.arange(40), np.zeros(40, dtype=int), pixels,
                      rng.uniform(-6.0, 6.0, (40, 2)))
    assert len(parse_tracks(make_tracks(wide, layout, backend), layout)) == 40
