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
"""The back end's outputs (Path, PoseArray, xyz PointCloud2, Odometry, TF, diagnostics).

Numpy to ROS messages through a :class:`~pmba_ros.backend.msg_backend.MsgBackend` (no ROS
import at module level). The builders always pass every field as a keyword, convert scalars
with ``float``/``int``, and route sequences through the backend, so the same builder makes
publishable rclpy messages and Jazzy-CDR-serializable rosbags messages. The front-end inputs
(tracks, camera info) are built in :mod:`pmba_ros.sim.inputs`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from pmba_ros._typing import FloatArray
from pmba_ros.backend.extrinsics import Rigid
from pmba_ros.backend.msg_backend import MsgBackend
from pmba_ros.backend.tracks import POINTFIELD_DTYPES
from pmba_ros.backend.types import float_rows, KeyframePose
from pmba_ros.core import so3
from pmba_ros.errors import MessageError

DIAGNOSTIC_LEVELS = ('ok', 'warn', 'error', 'stale')
"""Levels accepted by :func:`make_diagnostics`."""

_NUMPY_TO_POINTFIELD = {np.dtype(code): dt for dt, code in POINTFIELD_DTYPES.items()}
_FLOAT32 = _NUMPY_TO_POINTFIELD[np.dtype('f4')]


# --- small pieces -------------------------------------------------------------------------


def _floats(value: ArrayLike, n: int, what: str) -> list[float]:
    """Return ``value`` as ``n`` finite floats (one pose's values: no numpy per value)."""
    values: list[float] = np.asarray(value, dtype=np.float64).reshape(-1).tolist()
    if len(values) != n or not all(map(math.isfinite, values)):
        msg = f'{what}: expected {n} finite values, got {values}'
        raise MessageError(msg)
    return values


def _unit_quat(quat_xyzw: ArrayLike, what: str) -> list[float]:
    """Return one quaternion over its norm: :func:`_normalized` of one row, the same bits.

    The sum of squares runs left to right, as numpy's reduction of a row of four does (the
    tests compare the two bitwise).
    """
    x, y, z, w = _floats(quat_xyzw, 4, what)
    norm = math.sqrt(((x * x + y * y) + z * z) + w * w)
    if norm < 1e-9:
        msg = f'{what}: zero-norm quaternion'
        raise MessageError(msg)
    return [x / norm, y / norm, z / norm, w / norm]


def finite_rows(value: ArrayLike, n_cols: int, what: str) -> FloatArray:
    """Return ``value`` as a finite (N, n_cols) float64 array."""
    arr = float_rows(value, n_cols, what)
    if not np.all(np.isfinite(arr)):
        msg = f'{what}: non-finite values'
        raise MessageError(msg)
    return arr


def _unit_quats(quats_xyzw: ArrayLike, what: str = 'quats_xyzw') -> FloatArray:
    """Return (N, 4) quaternions normalized to unit length."""
    return _normalized(finite_rows(quats_xyzw, 4, what), what)


def _normalized(q: FloatArray, what: str) -> FloatArray:
    """Return finite (N, 4) quaternions ``q`` over their norms (np.linalg.norm's sums)."""
    norm = np.sqrt(np.add.reduce(q * q, axis=1))
    if np.any(norm < 1e-9):
        msg = f'{what}: zero-norm quaternion'
        raise MessageError(msg)
    unit: FloatArray = q / norm[:, None]
    return unit


def time_msg(stamp_ns: int, backend: MsgBackend) -> Any:
    """Return a ``builtin_interfaces/msg/Time`` for integer nanoseconds.

    Args:
        stamp_ns: Time, ns (floor division keeps ``nanosec`` in [0, 1e9) for negatives).
        backend: Message backend.

    Returns:
        The Time message.

    Raises:
        MessageError: If the backend lacks the type.
    """
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return backend.new('builtin_interfaces/msg/Time', sec=sec, nanosec=nanosec)


def header_msg(stamp_ns: int, frame_id: str, backend: MsgBackend) -> Any:
    """Return a ``std_msgs/msg/Header``.

    Args:
        stamp_ns: Stamp, ns.
        frame_id: Frame id.
        backend: Message backend.

    Returns:
        The Header message.

    Raises:
        MessageError: If the backend lacks the type.
    """
    return backend.new('std_msgs/msg/Header', stamp=time_msg(stamp_ns, backend),
                       frame_id=str(frame_id))


def _pose_msgs(positions: FloatArray, quats: FloatArray, backend: MsgBackend) -> list[Any]:
    """Return Pose messages of checked (N, 3) positions and unit (N, 4) quaternions.

    Built from plain floats, without numpy per pose: a path is rebuilt at every keyframe.
    """
    pose_t = backend.msg_class('geometry_msgs/msg/Pose')
    point_t = backend.msg_class('geometry_msgs/msg/Point')
    quat_t = backend.msg_class('geometry_msgs/msg/Quaternion')
    rows = zip(positions.tolist(), quats.tolist(), strict=True)
    return [pose_t(position=point_t(x=x, y=y, z=z), orientation=quat_t(x=qx, y=qy, z=qz, w=qw))
            for (x, y, z), (qx, qy, qz, qw) in rows]


def pose_msg(position: ArrayLike, quat_xyzw: ArrayLike, backend: MsgBackend) -> Any:
    """Return a ``geometry_msgs/msg/Pose``.

    Args:
        position: Translation, shape (3,), m.
        quat_xyzw: Rotation quaternion (x, y, z, w), shape (4,); normalized here.
        backend: Message backend.

    Returns:
        The Pose message.

    Raises:
        MessageError: On wrong shapes, non-finite values or a zero quaternion.
    """
    x, y, z = _floats(position, 3, 'position')
    qx, qy, qz, qw = _unit_quat(quat_xyzw, 'quat_xyzw')
    return backend.msg_class('geometry_msgs/msg/Pose')(
        position=backend.msg_class('geometry_msgs/msg/Point')(x=x, y=y, z=z),
        orientation=backend.msg_class('geometry_msgs/msg/Quaternion')(x=qx, y=qy, z=qz, w=qw))


# --- back-end outputs ---------------------------------------------------------------------


def make_pose_stamped(stamp_ns: int, frame_id: str, position: ArrayLike, quat_xyzw: ArrayLike,
                      backend: MsgBackend) -> Any:
    """Return a ``geometry_msgs/msg/PoseStamped``.

    Args:
        stamp_ns: Header stamp, ns.
        frame_id: Header frame.
        position: Translation, shape (3,), m.
        quat_xyzw: Rotation quaternion (x, y, z, w), shape (4,).
        backend: Message backend.

    Returns:
        The PoseStamped message.

    Raises:
        MessageError: On wrong shapes, non-finite values or a zero quaternion.
    """
    return backend.new('geometry_msgs/msg/PoseStamped',
                       header=header_msg(stamp_ns, frame_id, backend),
                       pose=pose_msg(position, quat_xyzw, backend))


def make_path(stamp_ns: int, frame_id: str, positions: ArrayLike, quats_xyzw: ArrayLike,
              stamps_ns: ArrayLike, backend: MsgBackend) -> Any:
    """Return a ``nav_msgs/msg/Path`` of N poses, each stamped with its keyframe time.

    Args:
        stamp_ns: Path header stamp, ns.
        frame_id: Frame of the path and of every pose (e.g. 'map').
        positions: Translations, shape (N, 3), m.
        quats_xyzw: Rotation quaternions (x, y, z, w), shape (N, 4); normalized here.
        stamps_ns: Pose stamps, shape (N,), ns.
        backend: Message backend.

    Returns:
        The Path message.

    Raises:
        MessageError: On shape mismatches, non-finite values or zero quaternions.
    """
    poses = pose_stamped_msgs(stamps_ns, frame_id, positions, quats_xyzw, backend)
    return backend.new('nav_msgs/msg/Path', header=header_msg(stamp_ns, frame_id, backend),
                       poses=poses)


def pose_stamped_msgs(stamps_ns: ArrayLike, frame_id: str, positions: ArrayLike,
                      quats_xyzw: ArrayLike, backend: MsgBackend) -> list[Any]:
    """Return N ``geometry_msgs/msg/PoseStamped`` messages (a path's poses), checked at once.

    Args:
        stamps_ns: Pose stamps, shape (N,), ns.
        frame_id: Frame of every pose.
        positions: Translations, shape (N, 3), m.
        quats_xyzw: Rotation quaternions (x, y, z, w), shape (N, 4); normalized here.
        backend: Message backend.

    Returns:
        The messages.

    Raises:
        MessageError: On shape mismatches, non-finite values or zero quaternions.
    """
    pos = finite_rows(positions, 3, 'positions')
    quats = _unit_quats(quats_xyzw)
    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    if not pos.shape[0] == quats.shape[0] == stamps.shape[0]:
        msg = (f'poses: {pos.shape[0]} positions, {quats.shape[0]} quaternions, '
               f'{stamps.shape[0]} stamps')
        raise MessageError(msg)
    stamped_t = backend.msg_class('geometry_msgs/msg/PoseStamped')
    header_t = backend.msg_class('std_msgs/msg/Header')
    time_t = backend.msg_class('builtin_interfaces/msg/Time')
    frame = str(frame_id)
    out = []
    # header_msg's steps with the classes looked up once: a path is rebuilt at every keyframe.
    for t, pose in zip(stamps.tolist(), _pose_msgs(pos, quats, backend), strict=True):
        sec, nanosec = divmod(t, 1_000_000_000)
        out.append(stamped_t(header=header_t(stamp=time_t(sec=sec, nanosec=nanosec),
                                             frame_id=frame), pose=pose))
    return out


def make_pose_array(stamp_ns: int, frame_id: str, positions: ArrayLike, quats_xyzw: ArrayLike,
                    backend: MsgBackend) -> Any:
    """Return a ``geometry_msgs/msg/PoseArray``.

    Args:
        stamp_ns: Header stamp, ns.
        frame_id: Header frame.
        positions: Translations, shape (N, 3), m.
        quats_xyzw: Rotation quaternions (x, y, z, w), shape (N, 4); normalized here.
        backend: Message backend.

    Returns:
        The PoseArray message.

    Raises:
        MessageError: On shape mismatches, non-finite values or zero quaternions.
    """
    pos = finite_rows(positions, 3, 'positions')
    quats = _unit_quats(quats_xyzw)
    if pos.shape[0] != quats.shape[0]:
        msg = f'make_pose_array: {pos.shape[0]} positions, {quats.shape[0]} quaternions'
        raise MessageError(msg)
    poses = _pose_msgs(pos, quats, backend)
    return backend.new('geometry_msgs/msg/PoseArray',
                       header=header_msg(stamp_ns, frame_id, backend), poses=poses)


def make_odometry(stamp_ns: int, frame_id: str, child_frame_id: str, position: ArrayLike,
                  quat_xyzw: ArrayLike, covariance: ArrayLike, backend: MsgBackend) -> Any:
    """Return a ``nav_msgs/msg/Odometry`` with a pose covariance and zero twist.

    An all-zero covariance breaks EKF consumers (robot_localization), so it is rejected.
    The twist and its covariance are zero: the back end does not estimate velocity.

    Args:
        stamp_ns: Header stamp, ns.
        frame_id: Header frame (pose parent, e.g. 'map').
        child_frame_id: Frame the pose describes.
        position: Translation, shape (3,), m.
        quat_xyzw: Rotation quaternion (x, y, z, w), shape (4,).
        covariance: Pose covariance over (x, y, z, rot_x, rot_y, rot_z), shape (6, 6).
        backend: Message backend.

    Returns:
        The Odometry message.

    Raises:
        MessageError: On bad pose values, or a covariance that is not a finite,
            symmetric, non-zero (6, 6) matrix with a non-negative diagonal.
    """
    cov = np.asarray(covariance, dtype=np.float64)
    _check_covariance(cov)
    pose = backend.new('geometry_msgs/msg/PoseWithCovariance',
                       pose=pose_msg(position, quat_xyzw, backend),
                       covariance=backend.fixed_f64(cov))
    vector_t = backend.msg_class('geometry_msgs/msg/Vector3')
    twist = backend.new(
        'geometry_msgs/msg/TwistWithCovariance',
        twist=backend.new('geometry_msgs/msg/Twist', linear=vector_t(x=0.0, y=0.0, z=0.0),
                          angular=vector_t(x=0.0, y=0.0, z=0.0)),
        covariance=backend.fixed_f64(np.zeros(36)))
    return backend.new('nav_msgs/msg/Odometry', header=header_msg(stamp_ns, frame_id, backend),
                       child_frame_id=str(child_frame_id), pose=pose, twist=twist)


_CHECKED_COVARIANCES: dict[bytes, None] = {}
"""Covariances :func:`_check_covariance` passed (a publisher sends the same one or two)."""


def _check_covariance(cov: FloatArray) -> None:
    """Raise MessageError unless ``cov`` is a usable (6, 6) Odometry covariance.

    Finite, symmetric, non-zero, with a non-negative diagonal; one seen before is not
    checked again (the checks cost more than the rest of an Odometry).
    """
    key = cov.tobytes() if cov.shape == (6, 6) else b''
    if key in _CHECKED_COVARIANCES:
        return
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        msg = f'make_odometry: covariance must be a finite (6, 6) matrix, got {cov.shape}'
        raise MessageError(msg)
    if not np.any(cov) or np.any(np.diag(cov) < 0) or not np.allclose(cov, cov.T):
        msg = 'make_odometry: covariance must be symmetric, non-zero, with diagonal >= 0'
        raise MessageError(msg)
    if len(_CHECKED_COVARIANCES) >= 16:
        _CHECKED_COVARIANCES.clear()
    _CHECKED_COVARIANCES[key] = None


@dataclass(frozen=True)
class MapToOdom:
    """The newest map <- odom transform and its message (with the frames)."""

    link: Rigid
    transform: Any

    @classmethod
    def of(cls, transform: Any) -> MapToOdom:
        """Return the map <- odom of a ``geometry_msgs/TransformStamped``."""
        q, t = transform.transform.rotation, transform.transform.translation
        return cls(Rigid.from_xyz_quat([t.x, t.y, t.z], [q.x, q.y, q.z, q.w]), transform)


def provisional_odometry(pose: KeyframePose, map_from_odom: Rigid | None, map_frame: str,
                         base_frame: str, covariance: ArrayLike, backend: MsgBackend) -> Any:
    """Return the Odometry of a front-end keyframe pose mapped through ``map_from_odom``.

    A node publishes it as soon as the keyframe pose arrives, before its solve; identity
    stands for a missing ``map_from_odom`` (map = odom before the first solve). The child
    frame is ``base_frame``, else the pose's, else 'base_link'.
    """
    T = Rigid(so3.from_quat_xyzw(pose.quat_xyzw), np.asarray(pose.position))
    if map_from_odom is not None:
        T = map_from_odom @ T
    return make_odometry(pose.stamp_ns, map_frame,
                         base_frame or pose.child_frame_id or 'base_link', T.translation,
                         so3.to_quat_xyzw(T.rotation), covariance, backend)


def restamped(transform: Any, stamp_ns: int, backend: MsgBackend) -> Any:
    """Return a copy of a ``geometry_msgs/msg/TransformStamped`` with a new stamp."""
    return backend.new('geometry_msgs/msg/TransformStamped',
                       header=header_msg(stamp_ns, transform.header.frame_id, backend),
                       child_frame_id=transform.child_frame_id, transform=transform.transform)


def make_tf(stamp_ns: int, parent: str, child: str, translation: ArrayLike,
            quat_xyzw: ArrayLike, backend: MsgBackend) -> Any:
    """Return a ``tf2_msgs/msg/TFMessage`` holding one transform parent -> child.

    Args:
        stamp_ns: Transform stamp, ns (future-date it by the TF tolerance if needed).
        parent: Parent frame (header.frame_id, e.g. 'map').
        child: Child frame (e.g. 'odom').
        translation: Child origin in the parent frame, shape (3,), m.
        quat_xyzw: Rotation parent <- child (x, y, z, w), shape (4,).
        backend: Message backend.

    Returns:
        The TFMessage.

    Raises:
        MessageError: On wrong shapes, non-finite values or a zero quaternion.
    """
    qx, qy, qz, qw = _unit_quat(quat_xyzw, 'quat_xyzw')
    x, y, z = _floats(translation, 3, 'translation')
    transform = backend.new(
        'geometry_msgs/msg/Transform',
        translation=backend.new('geometry_msgs/msg/Vector3', x=x, y=y, z=z),
        rotation=backend.new('geometry_msgs/msg/Quaternion', x=qx, y=qy, z=qz, w=qw))
    stamped = backend.new('geometry_msgs/msg/TransformStamped',
                          header=header_msg(stamp_ns, parent, backend),
                          child_frame_id=str(child), transform=transform)
    return backend.new('tf2_msgs/msg/TFMessage', transforms=[stamped])


def _diag_value(value: str | float) -> str:
    """Format one diagnostics value (floats in shortest round-trip form)."""
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return 'true' if value else 'false'
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return repr(float(value))


def make_diagnostics(stamp_ns: int, name: str, level: str, message: str,
                     values: Mapping[str, str | float], backend: MsgBackend, *,
                     hardware_id: str = '') -> Any:
    """Return a ``diagnostic_msgs/msg/DiagnosticArray`` with one status.

    Args:
        stamp_ns: Header stamp, ns.
        name: Status name (e.g. 'pmba_ros: solver').
        level: One of :data:`DIAGNOSTIC_LEVELS`.
        message: Human-readable summary.
        values: Key/value pairs; numbers are formatted with ``repr`` (floats) or ``str``.
        backend: Message backend.
        hardware_id: DiagnosticStatus.hardware_id.

    Returns:
        The DiagnosticArray.

    Raises:
        MessageError: If ``level`` is unknown.
    """
    if level not in DIAGNOSTIC_LEVELS:
        msg = f'unknown diagnostic level {level!r} (expected {", ".join(DIAGNOSTIC_LEVELS)})'
        raise MessageError(msg)
    status_type = 'diagnostic_msgs/msg/DiagnosticStatus'
    key_value_t = backend.msg_class('diagnostic_msgs/msg/KeyValue')
    key_values = [key_value_t(key=str(k), value=_diag_value(v)) for k, v in values.items()]
    status = backend.new(status_type, level=backend.constant(status_type, level.upper()),
                         name=str(name), message=str(message), hardware_id=str(hardware_id),
                         values=key_values)
    return backend.new('diagnostic_msgs/msg/DiagnosticArray',
                       header=header_msg(stamp_ns, '', backend), status=[status])


# --- point clouds -------------------------------------------------------------------------


def make_point_cloud2_named(stamp_ns: int, frame_id: str, columns: Mapping[str, ArrayLike],
                            backend: MsgBackend, *, big_endian: bool = False) -> Any:
    """Return an unorganized (height 1) ``sensor_msgs/msg/PointCloud2`` from named columns.

    Each column's numpy dtype picks its PointField datatype (int8..uint32, float32,
    float64; pass e.g. ``np.asarray(ids, np.uint32)``). Fields are packed in the given
    order without padding.

    Args:
        stamp_ns: Header stamp, ns.
        frame_id: Header frame.
        columns: Field name -> values, shape (N,) each.
        backend: Message backend.
        big_endian: Write big-endian data (sets ``is_bigendian``).

    Returns:
        The PointCloud2 message; ``is_dense`` is True if all values are finite.

    Raises:
        MessageError: On unequal column lengths or dtypes PointField cannot express.
    """
    cols = {str(k): np.asarray(v).reshape(-1) for k, v in columns.items()}
    sizes = {k: v.shape[0] for k, v in cols.items()}
    if len(set(sizes.values())) > 1:
        msg = f'make_point_cloud2_named: columns of different lengths {sizes}'
        raise MessageError(msg)
    n_pts = next(iter(sizes.values()), 0)
    order = '>' if big_endian else '<'
    field_type = backend.msg_class('sensor_msgs/msg/PointField')
    fields, formats, offset = [], [], 0
    for name, col in cols.items():
        datatype = _NUMPY_TO_POINTFIELD.get(col.dtype.newbyteorder('='))
        if datatype is None:
            msg = f'make_point_cloud2_named: column {name!r} has unsupported dtype {col.dtype}'
            raise MessageError(msg)
        fields.append(field_type(name=name, offset=offset, datatype=datatype, count=1))
        formats.append((name, order + POINTFIELD_DTYPES[datatype]))
        offset += col.dtype.itemsize
    rec = np.empty(n_pts, dtype=np.dtype(formats))
    for name, col in cols.items():
        rec[name] = col
    is_dense = all(np.all(np.isfinite(c)) for c in cols.values() if c.dtype.kind == 'f')
    return _point_cloud2(stamp_ns, frame_id, fields, n_pts, offset, rec, is_dense, big_endian,
                         backend)


def _point_cloud2(stamp_ns: int, frame_id: str, fields: list[Any], n_pts: int,
                  point_step: int, records: np.ndarray, is_dense: bool, big_endian: bool,
                  backend: MsgBackend) -> Any:
    """Return an unorganized PointCloud2 of packed, C-contiguous ``records``."""
    return backend.new('sensor_msgs/msg/PointCloud2',
                       header=header_msg(stamp_ns, frame_id, backend), height=1,
                       width=int(n_pts), fields=fields, is_bigendian=bool(big_endian),
                       point_step=int(point_step), row_step=int(point_step * n_pts),
                       data=backend.seq_u8(records), is_dense=bool(is_dense))


def make_point_cloud2_xyz(stamp_ns: int, frame_id: str, points: ArrayLike,
                          backend: MsgBackend) -> Any:
    """Return a ``sensor_msgs/msg/PointCloud2`` with float32 fields x, y, z (landmarks).

    Args:
        stamp_ns: Header stamp, ns.
        frame_id: Header frame (e.g. 'map').
        points: Points, shape (N, 3), m.
        backend: Message backend.

    Returns:
        The PointCloud2 message (little-endian, point_step 12).

    Raises:
        MessageError: If ``points`` is not (N, 3).
    """
    # C-ordered rows of three little-endian float32 are the packed x, y, z records of
    # make_point_cloud2_named's three columns, without its record array.
    pts = float_rows(points, 3, 'make_point_cloud2_xyz: points').astype('<f4', order='C')
    field_type = backend.msg_class('sensor_msgs/msg/PointField')
    fields = [field_type(name=name, offset=4 * i, datatype=_FLOAT32, count=1)
              for i, name in enumerate('xyz')]
    return _point_cloud2(stamp_ns, frame_id, fields, pts.shape[0], 12, pts,
                         bool(np.isfinite(pts).all()), False, backend)


__all__ = [
    'DIAGNOSTIC_LEVELS', 'MapToOdom', 'finite_rows', 'header_msg', 'make_diagnostics',
    'make_odometry', 'make_path', 'make_point_cloud2_named', 'make_point_cloud2_xyz',
    'make_pose_array', 'make_pose_stamped', 'make_tf', 'pose_msg', 'pose_stamped_msgs',
    'time_msg',
]


@dataclass
class PoseMessageCache:
    """The keyframes of the last Path / PoseArray and their messages.

    Attributes:
        idx: Keyframe indices last published.
        final: Which of them were final (their poses no longer change).
        stamped: Their PoseStamped messages.
        plain: Their Pose messages.
    """

    idx: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    final: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    stamped: list[Any] = field(default_factory=list)
    plain: list[Any] = field(default_factory=list)

    def update(self, idx: np.ndarray, final: np.ndarray,
               build: Callable[[np.ndarray], list[Any]]) -> tuple[list[Any], list[Any]]:
        """Return PoseStamped and Pose messages of keyframes ``idx``, then remember them.

        Keyframes that were final when last published keep their messages; when ``idx``
        extends the last published keyframes, only the others and the new ones are built
        (``build(keyframes)`` returns their PoseStamped messages), so the cost follows the
        window, not the trajectory.
        """
        n_last, n = self.idx.shape[0], idx.shape[0]
        if n_last <= n and np.array_equal(idx[:n_last], self.idx):
            redo = np.concatenate([np.flatnonzero(~self.final), np.arange(n_last, n)])
            stamped = self.stamped + [None] * (n - n_last)
            plain = self.plain + [None] * (n - n_last)
        else:
            redo = np.arange(n)
            stamped, plain = [None] * n, [None] * n
        for k, ps in zip(redo.tolist(), build(idx[redo]), strict=True):
            stamped[k] = ps
            plain[k] = ps.pose
        self.idx, self.final, self.stamped, self.plain = idx.copy(), final, stamped, plain
        return list(stamped), list(plain)
