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
"""Message builders: Jazzy CDR serialization, mcap_ros2 read-back, camera models vs OpenCV."""

from __future__ import annotations

import array
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
from pmba_ros.backend import outputs
from pmba_ros.backend.msg_backend import RclpyBackend
from pmba_ros.backend.tracks import parse_camera_info
from pmba_ros.backend.types import CameraModel, TrackFrame
from pmba_ros.errors import MessageError
from pmba_ros.sim.inputs import make_camera_info, make_point_cloud, make_tracks
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from ..conftest import run_python

T_NS = 42_000_000_007
QUATS = np.array([[0.0, 0.0, 0.0, 2.0], [0.1, 0.2, -0.3, 0.9], [0.5, 0.5, 0.5, 0.5]])
POSITIONS = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [-1.5, 0.25, 9.0]])
COV = np.diag([1e-3, 1e-3, 2e-3, 1e-4, 1e-4, 5e-4])
CAMERAS = {
    'none': CameraModel(458.6, 457.3, 367.2, 248.4, width=752, height=480),
    'plumb_bob': CameraModel(458.6, 457.3, 367.2, 248.4, 'plumb_bob',
                             [-0.283, 0.074, 1.9e-4, 1.8e-5, 0.0], 752, 480),
    'equidistant': CameraModel(380.8, 380.3, 510.3, 514.3, 'equidistant',
                               [0.0107, -0.0064, 0.0021, -0.0005], 1024, 1024),
}


def builders() -> dict[str, Callable[[Any], Any]]:
    """Every builder, called with valid arguments; takes the backend."""
    frame = TrackFrame(T_NS, 'world', [1, 2], [0, 0], [[10.0, 20.0], [30.0, 40.0]],
                       [[0.1, 0.2], [0.3, 0.4]])
    return {
        'path': lambda b: outputs.make_path(T_NS, 'map', POSITIONS, QUATS,
                                            T_NS + np.arange(3), b),
        'pose_array': lambda b: outputs.make_pose_array(T_NS, 'map', POSITIONS, QUATS, b),
        'pose_stamped': lambda b: outputs.make_pose_stamped(T_NS, 'odom', [1, 2, 3],
                                                            QUATS[1], b),
        'cloud2_xyz': lambda b: outputs.make_point_cloud2_xyz(T_NS, 'map', POSITIONS, b),
        'odometry': lambda b: outputs.make_odometry(T_NS, 'map', 'base_link', [1, 2, 3],
                                                    QUATS[1], COV, b),
        'tf': lambda b: outputs.make_tf(T_NS, 'map', 'odom', [1, 2, 3], QUATS[2], b),
        'diagnostics': lambda b: outputs.make_diagnostics(
            T_NS, 'pmba_ros: solver', 'warn', 'slow', {'solve_ms': 12.5, 'n_kf': 7,
                                                       'mode': 'refine'}, b),
        'point_cloud': lambda b: make_point_cloud(
            T_NS, 'world', POSITIONS, [('a', [1, 2, 3]), ('b', [4.5])], b),
        'cloud2_named': lambda b: outputs.make_point_cloud2_named(
            T_NS, 'cam0', {'id': np.arange(3, dtype=np.uint32),
                           'u': np.ones(3, np.float32), 'w': np.ones(3, np.int16)}, b),
        'camera_info': lambda b: make_camera_info(T_NS, 'cam0',
                                                  CAMERAS['plumb_bob'], b),
        **{f'tracks_{lay}': (lambda b, lay=lay: make_tracks(frame, lay, b))
           for lay in ('vins_mono', 'vins_fusion', 'per_point', 'named')},
    }


@pytest.mark.parametrize('name', sorted(builders()))
def test_builder_output_serializes_with_jazzy(ts: Any, backend: Any, name: str) -> None:
    """Each builder's message survives a Jazzy CDR round trip byte for byte."""
    msg = builders()[name](backend)
    raw = ts.serialize_cdr(msg, msg.__msgtype__)
    back = ts.deserialize_cdr(raw, msg.__msgtype__)
    assert bytes(ts.serialize_cdr(back, msg.__msgtype__)) == bytes(raw)


def test_all_builders_read_back_with_mcap_ros2(ts: Any, backend: Any, tmp_path: Path) -> None:
    """An MCAP of every builder's message decodes with mcap_ros2 to the values written."""
    msgs = {name: build(backend) for name, build in builders().items()}
    out = tmp_path / 'outputs'
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for i, (name, msg) in enumerate(msgs.items()):
            conn = writer.add_connection(f'/{name}', msg.__msgtype__, typestore=ts)
            writer.write(conn, T_NS + i, ts.serialize_cdr(msg, msg.__msgtype__))
    with (out / 'outputs.mcap').open('rb') as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        got = {ch.topic[1:]: m for _, ch, _, m in reader.iter_decoded_messages()}
    assert set(got) == set(msgs)
    xyz = np.frombuffer(got['cloud2_xyz'].data, np.float32).reshape(-1, 3)
    np.testing.assert_allclose(xyz, POSITIONS)
    assert [p.header.stamp.nanosec for p in got['path'].poses] == [7, 8, 9]
    assert got['odometry'].pose.covariance[0] == pytest.approx(1e-3)
    assert got['diagnostics'].status[0].level == 1
    cam = parse_camera_info(got['camera_info'])
    np.testing.assert_allclose(cam.d, CAMERAS['plumb_bob'].d)


def test_path_and_pose_array_content(backend: Any) -> None:
    """Path and PoseArray carry the frames, per-pose stamps and normalized quaternions."""
    path = outputs.make_path(T_NS, 'map', POSITIONS, QUATS, [5, 6, 1_000_000_007], backend)
    assert path.header.frame_id == 'map'
    assert (path.header.stamp.sec, path.header.stamp.nanosec) == (42, 7)
    last = path.poses[2]
    assert (last.header.stamp.sec, last.header.stamp.nanosec) == (1, 7)
    assert last.header.frame_id == 'map'
    assert last.pose.position.z == 9.0
    first = path.poses[0].pose.orientation
    assert (first.x, first.y, first.z, first.w) == (0.0, 0.0, 0.0, 1.0)  # normalized
    poses = outputs.make_pose_array(T_NS, 'map', POSITIONS, QUATS, backend).poses
    assert len(poses) == 3
    assert poses[1].position.y == 2.0


@pytest.mark.parametrize(('positions', 'quats', 'stamps', 'match'), [
    (POSITIONS[:2], QUATS, [1, 2, 3], 'positions'),
    (POSITIONS, np.zeros((3, 4)), [1, 2, 3], 'zero-norm'),
    (POSITIONS, QUATS, [1, 2], 'stamps'),
    (POSITIONS[:, :2], QUATS, [1, 2, 3], r'\(N, 3\)'),
    (np.full((3, 3), np.nan), QUATS, [1, 2, 3], 'non-finite'),
])
def test_make_path_rejects_bad_input(backend: Any, positions: Any, quats: Any, stamps: Any,
                                     match: str) -> None:
    """Mismatched lengths, non-finite values and zero quaternions are a MessageError."""
    with pytest.raises(MessageError, match=match):
        outputs.make_path(T_NS, 'map', positions, quats, stamps, backend)


def test_point_cloud2_xyz_layout(backend: Any) -> None:
    """The landmark cloud has float32 x, y, z fields, little-endian, 12 bytes a point."""
    msg = outputs.make_point_cloud2_xyz(T_NS, 'map', POSITIONS, backend)
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ('x', 0, 7, 1), ('y', 4, 7, 1), ('z', 8, 7, 1)]
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, 3, 12, 36)
    assert not msg.is_bigendian and msg.is_dense
    np.testing.assert_allclose(np.frombuffer(msg.data, '<f4').reshape(-1, 3), POSITIONS)
    empty = outputs.make_point_cloud2_xyz(T_NS, 'map', np.zeros((0, 3)), backend)
    assert (empty.width, len(empty.data)) == (0, 0)


@pytest.mark.parametrize('n', [0, 1, 5])
def test_point_cloud2_xyz_equals_the_named_columns(backend: Any, n: int) -> None:
    """The xyz cloud is the named cloud of its float32 columns (non-finite, F-ordered too)."""
    rng = np.random.default_rng(n)
    points = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-3, 40, size=(n, 3))
    if n > 1:
        points[1, 2] = np.nan
    for pts in (points, np.asfortranarray(points), np.abs(points) + 1.0):
        f32 = np.asarray(pts, np.float64).astype(np.float32)
        named = outputs.make_point_cloud2_named(T_NS, 'map', {
            'x': f32[:, 0], 'y': f32[:, 1], 'z': f32[:, 2]}, backend)
        xyz = outputs.make_point_cloud2_xyz(T_NS, 'map', pts, backend)
        assert backend.serialize(xyz) == backend.serialize(named)


def test_point_cloud2_named_rejects_bad_columns(backend: Any) -> None:
    """Columns of unequal length or without a PointField type are a MessageError."""
    with pytest.raises(MessageError, match='different lengths'):
        outputs.make_point_cloud2_named(T_NS, 'c', {'a': np.zeros(2), 'b': np.zeros(3)},
                                        backend)
    with pytest.raises(MessageError, match='unsupported dtype'):
        outputs.make_point_cloud2_named(T_NS, 'c', {'a': np.zeros(2, np.int64)}, backend)


def test_odometry_covariance(backend: Any) -> None:
    """Odometry carries the pose covariance; invalid covariances are a MessageError.

    Also when asked again (valid covariances seen before are not checked again).
    """
    for _ in range(2):
        msg = outputs.make_odometry(T_NS, 'map', 'base_link', [1, 2, 3], QUATS[1], COV,
                                    backend)
        np.testing.assert_array_equal(np.asarray(msg.pose.covariance).reshape(6, 6), COV)
        assert msg.child_frame_id == 'base_link'
        assert not np.any(msg.twist.covariance)
        for bad in (np.zeros((6, 6)), np.eye(3), np.triu(np.ones((6, 6))), -np.eye(6),
                    np.full((6, 6), np.nan)):
            with pytest.raises(MessageError, match='covariance'):
                outputs.make_odometry(T_NS, 'map', 'b', [0, 0, 0], [0, 0, 0, 1], bad, backend)


def test_tf_message(backend: Any) -> None:
    """A TF message has the frames and the normalized rotation; NaN rotations are refused."""
    msg = outputs.make_tf(T_NS, 'map', 'odom', [1, 2, 3], [0, 0, 0, 3], backend)
    (tf,) = msg.transforms
    assert (tf.header.frame_id, tf.child_frame_id) == ('map', 'odom')
    assert (tf.transform.translation.x, tf.transform.rotation.w) == (1.0, 1.0)
    with pytest.raises(MessageError, match='quat_xyzw'):
        outputs.make_tf(T_NS, 'map', 'odom', [1, 2, 3], [0, 0, np.nan, 1], backend)


def test_one_pose_is_checked_and_normalized_as_the_rows_are(backend: Any) -> None:
    """One pose's scalar path gives the bits of the row path and refuses what it refuses."""
    rng = np.random.default_rng(7)
    quats = rng.normal(size=(20000, 4)) * 10.0 ** rng.integers(-6, 7, size=(20000, 1))
    rows = outputs._unit_quats(quats)
    for q, row in zip(quats, rows, strict=True):
        assert np.array(outputs._unit_quat(q, 'q')).tobytes() == row.tobytes()
    for bad, match in (([0, 0, 0, 0], 'zero-norm'), ([0, 0, np.inf, 1], 'finite'),
                       ([0, 0, 1], 'expected 4')):
        with pytest.raises(MessageError, match=match):
            outputs.pose_msg([1, 2, 3], bad, backend)
    for bad in ([1, 2], [1, 2, np.nan], [[1, 2, 3, 4]]):
        with pytest.raises(MessageError, match='position'):
            outputs.pose_msg(bad, [0, 0, 0, 1], backend)
        with pytest.raises(MessageError, match='translation'):
            outputs.make_tf(T_NS, 'map', 'odom', bad, [0, 0, 0, 1], backend)


def test_diagnostics(backend: Any) -> None:
    """Diagnostics map the level names to the constants and the values to strings."""
    msg = outputs.make_diagnostics(T_NS, 'pmba', 'error', 'diverged',
                                   {'cost': 0.1, 'iters': np.int64(3), 'ok': False,
                                    'mode': 'global_init'}, backend, hardware_id='cpu')
    (status,) = msg.status
    assert status.level == backend.constant('diagnostic_msgs/msg/DiagnosticStatus', 'ERROR')
    assert status.level == 2
    assert status.hardware_id == 'cpu'
    assert {kv.key: kv.value for kv in status.values} == {
        'cost': '0.1', 'iters': '3', 'ok': 'false', 'mode': 'global_init'}
    with pytest.raises(MessageError, match='unknown diagnostic level'):
        outputs.make_diagnostics(T_NS, 'pmba', 'fatal', '', {}, backend)


def test_negative_and_large_stamps(backend: Any) -> None:
    """Stamps before the epoch and far after it split into exact sec and nanosec."""
    stamp = outputs.time_msg(-1, backend)
    assert (stamp.sec, stamp.nanosec) == (-1, 999_999_999)
    stamp = outputs.time_msg(1_700_000_000_123_456_789, backend)
    assert (stamp.sec, stamp.nanosec) == (1_700_000_000, 123_456_789)


def test_make_tracks_rejects_what_layouts_cannot_carry(backend: Any) -> None:
    """Tracks a layout cannot carry (cameras, id range, coordinates) are refused."""
    stereo = TrackFrame(0, 'w', [1, 1], [0, 1], [[1.0, 2.0], [3.0, 4.0]], [[0, 0], [0, 0]])
    with pytest.raises(MessageError, match='camera'):
        make_tracks(stereo, 'per_point', backend)
    with pytest.raises(MessageError, match='num_cams'):
        make_tracks(stereo, 'vins_mono', backend, num_cams=1)
    big = TrackFrame(0, 'w', [2**24], [0], [[1.0, 2.0]], [[0.0, 0.0]])
    with pytest.raises(MessageError, match='2\\^24'):
        make_tracks(big, 'vins_fusion', backend)
    no_norm = TrackFrame(0, 'w', [1], [0], [[1.0, 2.0]], None)
    with pytest.raises(MessageError, match='normalized'):
        make_tracks(no_norm, 'vins_fusion', backend)
    with pytest.raises(MessageError, match='unknown feature layout'):
        make_tracks(no_norm, 'orb', backend)


@pytest.mark.parametrize('model', sorted(CAMERAS))
def test_camera_info_roundtrip(ts: Any, backend: Any, model: str) -> None:
    """A CameraInfo written for a camera model parses back to the same model."""
    cam = CAMERAS[model]
    msg = make_camera_info(T_NS, 'cam0', cam, backend)
    back = parse_camera_info(ts.deserialize_cdr(ts.serialize_cdr(msg, msg.__msgtype__),
                                                msg.__msgtype__))
    assert back.distortion_model == model
    assert (back.fx, back.fy, back.cx, back.cy) == (cam.fx, cam.fy, cam.cx, cam.cy)
    assert (back.width, back.height) == (cam.width, cam.height)
    np.testing.assert_array_equal(back.d, cam.d)
    np.testing.assert_array_equal(np.asarray(msg.p).reshape(3, 4)[:, :3], cam.k)


def test_camera_info_rejects_unsupported(ts: Any, backend: Any) -> None:
    """Unsupported distortion models and coefficients, and zero focal lengths, are refused."""
    msg = make_camera_info(T_NS, 'cam0', CAMERAS['plumb_bob'], backend)
    msg.distortion_model = 'rational_polynomial'
    msg.d = np.array([0.1, 0.01, 0, 0, 0, 0.2, 0, 0])
    with pytest.raises(MessageError, match='not supported'):
        parse_camera_info(msg)
    msg.d = np.array([0.1, 0.01, 0, 0, 0, 0, 0, 0])
    assert parse_camera_info(msg).distortion_model == 'plumb_bob'
    msg.distortion_model = 'equidistant'   # zeros beyond its 4 coefficients are dropped
    assert parse_camera_info(msg).d.tolist() == [0.1, 0.01, 0.0, 0.0]
    msg.d = np.array([0.1, 0.01, 0, 0, 0.3])
    with pytest.raises(MessageError, match='needs 4 coefficients'):
        parse_camera_info(msg)
    with pytest.raises(MessageError, match='fx, fy > 0'):
        parse_camera_info(SimpleNamespace(k=np.zeros(9), d=[], distortion_model='',
                                          width=0, height=0))


def test_plumb_bob_normalize_matches_cv2_projection() -> None:
    """Plumb-bob distortion and its inverse agree with cv2.projectPoints."""
    cam = CAMERAS['plumb_bob']
    xy = np.random.default_rng(7).uniform(-0.7, 0.7, size=(300, 2))
    rays = np.column_stack([xy, np.ones(len(xy))])
    px, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), cam.k, cam.d)
    px = px.reshape(-1, 2)
    np.testing.assert_allclose(cam.denormalize(xy), px, atol=1e-9)
    np.testing.assert_allclose(cam.normalize(px), xy, atol=1e-10)
    # cv2's own inverse (fixed-point, 5 iterations) agrees to its accuracy
    cv_xy = cv2.undistortPoints(px.reshape(-1, 1, 2), cam.k, cam.d).reshape(-1, 2)
    np.testing.assert_allclose(cam.normalize(px), cv_xy, atol=2e-3)


def test_equidistant_normalize_matches_cv2_fisheye_projection() -> None:
    """Equidistant distortion and its inverse agree with cv2.fisheye."""
    cam = CAMERAS['equidistant']
    xy = np.random.default_rng(8).uniform(-2.0, 2.0, size=(300, 2))
    rays = np.column_stack([xy, np.ones(len(xy))]).reshape(-1, 1, 3)
    px, _ = cv2.fisheye.projectPoints(rays, np.zeros(3), np.zeros(3), cam.k, cam.d)
    px = px.reshape(-1, 2)
    np.testing.assert_allclose(cam.denormalize(xy), px, atol=1e-9)
    np.testing.assert_allclose(cam.normalize(px), xy, atol=1e-9)
    cv_xy = cv2.fisheye.undistortPoints(px.reshape(-1, 1, 2), cam.k, cam.d).reshape(-1, 2)
    np.testing.assert_allclose(cam.normalize(px), cv_xy, atol=1e-5)


@pytest.mark.parametrize('model', ['none', 'plumb_bob', 'equidistant'])
def test_pixel_jacobian_is_the_derivative_of_the_projection(model: str) -> None:
    """d(raw pixel)/d(bearing) against central differences of :meth:`denormalize`.

    Out to 80 degrees from the axis for the fisheye, where its pixels are far from the
    pinhole's; a camera without distortion has none (its pinhole is the problem's).
    """
    cam = CAMERAS[model]
    rng = np.random.default_rng(9)
    theta = rng.uniform(0.0, 1.4 if model == 'equidistant' else 0.8, 200)
    phi = rng.uniform(0.0, 2 * np.pi, 200)
    v = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                         np.cos(theta)])
    v[0] = [0.0, 0.0, 1.0]
    J = cam.pixel_jacobian(v)
    if model == 'none':
        assert J is None
        return
    assert J is not None
    numeric = np.empty_like(J)
    for i, step in enumerate(np.eye(3) * 1e-6):
        numeric[:, :, i] = (cam.denormalize((v + step)[:, :2] / (v + step)[:, 2:])
                            - cam.denormalize((v - step)[:, :2] / (v - step)[:, 2:])) / 2e-6
    np.testing.assert_allclose(J, numeric, rtol=1e-6, atol=1e-4)
    behind = cam.pixel_jacobian(np.array([[1.0, 0.0, -0.1]]))
    assert behind is not None and np.all(np.isnan(behind))


def test_normalize_none_and_unreachable_pixels() -> None:
    """Undistorted cameras only scale; pixels beyond a fisheye's reach become NaN."""
    cam = CAMERAS['none']
    np.testing.assert_allclose(cam.normalize([[cam.cx + cam.fx, cam.cy]]), [[1.0, 0.0]])
    # theta_d = 2 rad is beyond 90 deg for this fisheye: no normalized coordinates exist
    fisheye = CAMERAS['equidistant']
    far = [[fisheye.cx + 2.2 * fisheye.fx, fisheye.cy]]
    assert np.all(np.isnan(fisheye.normalize(far)))
    with pytest.raises(MessageError, match=r'\(K, 2\)'):
        cam.normalize(np.zeros(3))


def fake_rclpy_modules(ts: Any) -> Callable[[str], Any]:
    """Serve rosbags classes as 'pkg.msg' modules (stand-in for rosidl modules)."""
    loaded: list[str] = []

    def load(name: str) -> Any:
        loaded.append(name)
        if name.split('.')[0] not in {t.split('/')[0] for t in ts.types}:
            raise ModuleNotFoundError(name)
        prefix = name.replace('.', '/') + '/'
        return SimpleNamespace(**{k[len(prefix):]: v for k, v in ts.types.items()
                                  if k.startswith(prefix)})
    load.loaded = loaded  # type: ignore[attr-defined]
    return load


def test_rclpy_backend_containers_and_lazy_loading(ts: Any) -> None:
    """The rclpy backend loads classes by name and fills arrays and Python scalars."""
    loader = fake_rclpy_modules(ts)
    backend = RclpyBackend(loader)
    assert backend.msg_class('nav_msgs/msg/Path') is ts.types['nav_msgs/msg/Path']
    assert backend.msg_class('nav_msgs/Path') is ts.types['nav_msgs/msg/Path']
    values = backend.seq_f32(np.array([1.5, 2.5]))
    assert isinstance(values, array.array) and values.typecode == 'f'
    assert list(values) == [1.5, 2.5]
    data = backend.seq_u8(b'\x01\x02')
    assert isinstance(data, array.array) and data.typecode == 'B'
    assert backend.seq_f64([1.0]).typecode == 'd'
    cloud = outputs.make_point_cloud2_xyz(T_NS, 'map', POSITIONS, backend)
    assert isinstance(cloud.data, array.array)
    info = make_camera_info(T_NS, 'cam0', CAMERAS['plumb_bob'], backend)
    assert isinstance(info.d, array.array) and isinstance(info.k, np.ndarray)
    path = outputs.make_path(T_NS, 'map', POSITIONS, QUATS, [1, 2, 3], backend)
    assert type(path.poses[0].pose.position.x) is float  # rclpy asserts Python floats
    assert type(path.header.stamp.sec) is int
    with pytest.raises(MessageError, match='cannot load'):
        backend.msg_class('no_such_msgs/msg/X')
    with pytest.raises(MessageError, match='bad message type name'):
        backend.msg_class('Path')


def test_rclpy_backend_builds_real_messages_without_importing_rclpy() -> None:
    """The real rosidl classes (the ``ros`` extra) serve the node's messages; no rclpy import."""
    run_python(
        'import sys\n'
        'from pmba_ros.backend import outputs\n'
        'from pmba_ros.backend.msg_backend import RclpyBackend\n'
        'path = outputs.make_path(5, "map", [[0.0, 0.0, 1.0]], [[0.0, 0.0, 0.0, 1.0]], [5],\n'
        '                         RclpyBackend())\n'
        'assert type(path).__module__ == "nav_msgs.msg._path", type(path)\n'
        'assert path.poses[0].pose.position.z == 1.0\n'
        'assert "rclpy" not in sys.modules\n', timeout_s=120.0)


def test_rosbags_backend_errors(backend: Any) -> None:
    """The rosbags backend names unknown types and constants in its MessageError."""
    with pytest.raises(MessageError, match='not in the rosbags typestore'):
        backend.msg_class('pmba_msgs/msg/Nope')
    with pytest.raises(MessageError, match='no constant'):
        backend.constant('diagnostic_msgs/msg/DiagnosticStatus', 'FATAL')
    assert isinstance(backend.serialize(outputs.time_msg(5, backend)), bytes)
