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
"""Front-end messages to numpy: feature tracks, keyframe poses and camera info.

The parsers are duck-typed: they read attributes only and convert every array field with
``np.asarray``/``np.frombuffer``, so they accept rclpy messages (``array.array`` sequences),
rosbags typestore messages (numpy arrays) and mcap_ros2 decoded objects (lists, ``bytes``)
alike. Nothing here imports ROS.

Feature layouts (``ros2_notes.md`` §3.1):

``vins_mono``
    ``sensor_msgs/PointCloud``; ``points[i]`` = normalized ``(x, y, 1)``; exactly five
    channels ``[0]=feature_id*num_cams+camera_id, [1]=u, [2]=v, [3]=vx, [4]=vy``.
``vins_fusion``
    ``sensor_msgs/PointCloud``; ``points[i]`` = normalized ``(x, y, 1)``; at least six
    channels ``[0]=feature_id, [1]=camera_id, [2]=u, [3]=v, [4]=vx, [5]=vy, ...``.
``per_point``
    ``sensor_msgs/PointCloud`` (VINS ``keyframe_point``, OpenVINS ``loop_feats``);
    ``points[i]`` = world landmark (ignored); channel ``i`` = ``[x_n, y_n, u, v, feature_id,
    ...]``; camera id 0. If every ``(x_n, y_n)`` is ``(0, 0)`` (OpenVINS) the frame has no
    normalized coordinates and the caller normalizes ``pixels`` with a camera model.
``named``
    ``sensor_msgs/PointCloud2`` with fields ``id``, optional ``cam`` (default 0), ``u, v``
    and/or ``x_n, y_n``; any PointField datatype, either byte order, padded rows.

Ids travel as float32 in PointCloud channels and are rounded with ``floor(v + 0.5)``.
Observations are dropped, and counted in :attr:`TrackFrame.dropped`, when their ids or
coordinates are not finite, or their ids cannot be exact in the message's number type
(>= 2^24 in float32, >= 2^53 in float64: neighbouring tracks would merge; counted as
``feature_ids_inexact``). A ``(feature_id, camera_id)`` pair repeated in one message is
resolved by consistency, not by order: with a :class:`TrackMemory` of the recent frames the
copy nearest to the track's previous observation is kept (``duplicate_observations`` counts
the others); a repeated pair without a previous observation is ambiguous and every copy is
dropped (``ambiguous_duplicate_observations``). A message that does not fit the layout raises
:class:`MessageError`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import logging
import math
from operator import attrgetter
from typing import Any

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray
from pmba_ros.backend.types import CameraModel, KeyframePose, TrackFrame
from pmba_ros.errors import MessageError

logger = logging.getLogger(__name__)

LAYOUTS = ('vins_mono', 'vins_fusion', 'per_point', 'named')
"""Feature-track layouts :func:`parse_tracks` understands."""

MAX_NORMALIZED_MEDIAN = 10.0
"""Largest median ``|x/z|``, ``|y/z|`` of a message's normalized coordinates (84 degrees).

Half the features of a frame beyond it from the optical axis is no camera's: such
coordinates are pixels in the normalized fields (a front-end's layout misread)."""

NORMALIZED_FIELDS = {'vins_mono': 'the points', 'vins_fusion': 'the points',
                     'per_point': 'channels [0:2] (x_n, y_n)', 'named': 'fields x_n, y_n'}
"""Where each layout's normalized coordinates are (named in errors)."""

KEYFRAME_KINDS = ('odometry', 'pose_stamped', 'pose_with_covariance')
"""Keyframe message kinds :func:`parse_keyframe` understands."""

KEYFRAME_MSGTYPES = {'odometry': 'nav_msgs/msg/Odometry',
                     'pose_stamped': 'geometry_msgs/msg/PoseStamped',
                     'pose_with_covariance': 'geometry_msgs/msg/PoseWithCovarianceStamped'}
"""Message type of each keyframe kind."""


def tracks_msgtype(layout: str) -> str:
    """Return the message type of tracks in ``layout`` (PointCloud2 for 'named')."""
    return 'sensor_msgs/msg/PointCloud2' if layout == 'named' else 'sensor_msgs/msg/PointCloud'


POINTFIELD_DTYPES = {1: 'i1', 2: 'u1', 3: 'i2', 4: 'u2', 5: 'i4', 6: 'u4', 7: 'f4', 8: 'f8'}
"""``sensor_msgs/PointField`` datatype constant -> numpy type code (without byte order)."""

_ID_TOL = 1e-3
FLOAT32_EXACT_IDS = float(2 ** 24)
"""Integers from 2^24 on are not all representable in float32: ids there may merge."""
FLOAT64_EXACT_IDS = float(2 ** 53)
_Z_TOL = 1e-3
_XYZ = attrgetter('x', 'y', 'z')
_QUAT_NORM2_TOL = 1e-2
"""A keyframe quaternion whose squared norm is off 1 by more is no rotation but a damaged
message (tf2 ignores such transforms with the same tolerance); normalizing it would turn it
into some other, wrong rotation."""


def stamp_to_ns(stamp: Any) -> int:
    """Return a ``builtin_interfaces/Time`` as integer nanoseconds.

    Args:
        stamp: Object with ``sec`` and ``nanosec``.

    Returns:
        ``sec * 10**9 + nanosec``.

    Raises:
        MessageError: If ``stamp`` lacks ``sec``/``nanosec``, or is before 0 (no ROS time
            is: a front-end's clock gone wrong).
    """
    try:
        ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    except (AttributeError, TypeError, ValueError) as err:
        msg = f'expected a builtin_interfaces/msg/Time stamp, got {type(stamp).__name__}'
        raise MessageError(msg) from err
    if ns < 0:
        msg = f'header stamp {ns * 1e-9:.9f} s is negative (ROS times start at 0)'
        raise MessageError(msg)
    return ns


def _type_name(msg: Any) -> str:
    """Return a readable type name of a message from any backend."""
    return str(getattr(msg, '__msgtype__', type(msg).__name__))


def _header(msg: Any) -> tuple[int, str]:
    """Return ``(stamp_ns, frame_id)`` of a message with a std_msgs/Header."""
    try:
        header = msg.header
        return stamp_to_ns(header.stamp), str(header.frame_id)
    except AttributeError as err:
        msg_ = f'expected a message with a std_msgs/Header, got {_type_name(msg)}'
        raise MessageError(msg_) from err


def stamp_of(msg: Any) -> int | None:
    """Return the header stamp of a message in ns, or None if it has no usable one."""
    try:
        return stamp_to_ns(msg.header.stamp)
    except (AttributeError, MessageError, OverflowError):
        return None


def parse_tracks(msg: Any, layout: str, num_cams: int = 1,
                 memory: TrackMemory | None = None, *, check_rays: bool = True) -> TrackFrame:
    """Parse a front-end feature message into a :class:`TrackFrame`.

    Args:
        msg: ``sensor_msgs/PointCloud`` (layouts vins_mono, vins_fusion, per_point) or
            ``sensor_msgs/PointCloud2`` (layout named), from any backend.
        layout: One of :data:`LAYOUTS`.
        num_cams: Number of cameras of the front-end (VINS ``NUM_OF_CAM``); vins_mono
            decodes ids with it, every layout rejects camera ids outside ``[0, num_cams)``.
        memory: Recent observations (updated with this frame) to resolve repeated ids by;
            without it every copy of a repeated ``(feature_id, camera_id)`` is dropped.
        check_rays: Refuse normalized coordinates that look like pixels (off: whether the
            message fits the layout at all, as a recording's layout is found).

    Returns:
        The observations, in message order, without non-finite rows, inexact ids and
        duplicates. An empty cloud gives an empty frame.

    Raises:
        MessageError: If the layout is unknown, ``num_cams < 1``, the normalized
            coordinates look like pixels (:data:`MAX_NORMALIZED_MEDIAN`), or the message
            does not fit the layout (wrong type, channel count or length, missing fields,
            non-integral or negative ids, camera ids out of range).
    """
    if layout not in LAYOUTS:
        msg_ = f'unknown feature layout {layout!r} (expected one of {", ".join(LAYOUTS)})'
        raise MessageError(msg_)
    if int(num_cams) < 1:
        msg_ = f'num_cams must be >= 1, got {num_cams}'
        raise MessageError(msg_)
    try:
        frame = _parse(msg, layout, int(num_cams), memory)
    except MessageError as err:
        fits = [other for other in LAYOUTS if other != layout
                and _parses(msg, other, int(num_cams))]
        if len(fits) != 1:
            raise
        msg_ = f'{err}; it parses in layout {fits[0]!r}: set feature_layout'
        raise MessageError(msg_) from err
    if check_rays and frame.normalized is not None and len(frame) and (
            median := float(np.median(np.abs(frame.normalized)))) > MAX_NORMALIZED_MEDIAN:
        msg_ = (f'normalized coordinates that look like pixels: their median |x/z|, |y/z| is '
                f'{median:.4g} (a ray {np.rad2deg(np.arctan(median)):.1f} degrees off the '
                f'optical axis); layout {layout!r} reads them from '
                f'{NORMALIZED_FIELDS[layout]} (wrong layout, or pixels in those fields?)')
        raise MessageError(msg_)
    if memory is not None:
        memory.remember(frame, int(num_cams))
    return frame


def _parse(msg: Any, layout: str, num_cams: int, memory: TrackMemory | None) -> TrackFrame:
    stamp_ns, frame_id = _header(msg)
    cols = _read_named(msg) if layout == 'named' else _read_point_cloud(msg, layout, num_cams)
    if cols is None:
        return TrackFrame.empty(stamp_ns, frame_id)
    return _finish(stamp_ns, frame_id, layout, num_cams, cols, memory)


def _parses(msg: Any, layout: str, num_cams: int) -> bool:
    """Return whether ``msg`` reads in ``layout`` (for the hint of a message that does not)."""
    try:
        _parse(msg, layout, num_cams, None)
    except MessageError:
        return False
    return True


@dataclass(frozen=True)
class _Columns:
    """Observation columns read from a message (float64, before validation)."""

    ids: FloatArray
    cams: FloatArray
    pixels: FloatArray | None
    normalized: FloatArray | None
    inexact: BoolArray
    """Ids that cannot be exact in the message's number type."""


class TrackMemory:
    """The observations of the last few frames (to resolve repeated ids by).

    Each frame is kept as its sorted ``feature_id * num_cams + camera_id`` keys and their
    coordinates; remembering sorts only the new frame, and lookups (needed only for repeated
    ids) search the frames newest first.
    """

    max_age = 10

    def __init__(self) -> None:
        """Start empty."""
        self._frames: deque[tuple[np.ndarray, FloatArray]] = deque(maxlen=self.max_age)
        self._normalized = True

    def lookup(self, keys: np.ndarray, normalized: bool) -> tuple[BoolArray, FloatArray]:
        """Return ``(found, coords)`` of the latest earlier observations of ``keys``.

        Args:
            keys: Track keys, shape (K,).
            normalized: Whether the coordinates asked for are normalized (else pixels).
        """
        found = np.zeros(keys.shape[0], dtype=bool)
        coords = np.full((keys.shape[0], 2), np.nan)
        if normalized != self._normalized:
            return found, coords
        for frame_keys, frame_coords in reversed(self._frames):
            if found.all():
                break
            if not frame_keys.size:
                continue
            pos = np.minimum(np.searchsorted(frame_keys, keys), frame_keys.size - 1)
            hit = ~found & (frame_keys[pos] == keys)
            coords[hit] = frame_coords[pos[hit]]
            found |= hit
        return found, coords

    def remember(self, frame: TrackFrame, num_cams: int) -> None:
        """Store the observations of a parsed frame."""
        normalized = frame.normalized is not None
        coords = frame.normalized if frame.normalized is not None else frame.pixels
        if coords is None:
            return
        if normalized != self._normalized:
            self._frames.clear()
            self._normalized = normalized
        keys = frame.feature_ids * num_cams + frame.camera_ids
        order = np.argsort(keys)
        self._frames.append((keys[order], coords[order]))


def _read_point_cloud(msg: Any, layout: str, num_cams: int) -> _Columns | None:
    """Read ids, camera ids, pixels and normalized coordinates from a PointCloud."""
    try:
        points_raw = msg.points
        channels = msg.channels
    except AttributeError as err:
        msg_ = (f'layout {layout!r} expects sensor_msgs/msg/PointCloud (points, channels), '
                f'got {_type_name(msg)}; wrong layout?')
        raise MessageError(msg_) from err
    n_pts = len(points_raw)
    rows = [np.asarray(ch.values, dtype=np.float64).reshape(-1) for ch in channels]
    lengths = np.fromiter(map(len, rows), dtype=np.int64, count=len(rows))
    if n_pts == 0 and not np.any(lengths):
        return None
    if layout == 'per_point':
        return _per_point_columns(rows, lengths, n_pts)
    if np.any(lengths != n_pts):
        bad = np.flatnonzero(lengths != n_pts)
        msg_ = (f'layout {layout!r} expects one value per point in every channel; '
                f'{n_pts} points but channel(s) {bad[:5].tolist()} hold '
                f'{lengths[bad[:5]].tolist()} values; wrong layout? '
                '(per_point data has one channel per point)')
        raise MessageError(msg_)
    want_ok = len(rows) == 5 if layout == 'vins_mono' else len(rows) >= 6
    if not want_ok:
        want = 'exactly 5' if layout == 'vins_mono' else 'at least 6'
        msg_ = (f'layout {layout!r} expects {want} channels, found {len(rows)}; '
                'wrong layout? (vins_mono has 5, vins_fusion 6 or more)')
        raise MessageError(msg_)
    ch = np.stack(rows)
    if isinstance(points_raw, np.ndarray):   # decoded in one piece (io.cloud_decode)
        xyz = points_raw.astype(np.float64).reshape(-1, 3)
    else:
        xyz = np.array(list(map(_XYZ, points_raw)), dtype=np.float64).reshape(-1, 3)
    z = xyz[:, 2]
    bad_z = np.isfinite(z) & (np.abs(z - 1.0) > _Z_TOL)
    if np.any(bad_z):
        msg_ = (f'layout {layout!r} expects normalized points (x, y, 1); {int(bad_z.sum())} '
                f'of {n_pts} points have z != 1 (e.g. {z[bad_z][0]:g}); wrong layout?')
        raise MessageError(msg_)
    normalized = xyz[:, :2]
    inexact = np.abs(ch[0]) >= FLOAT32_EXACT_IDS
    if layout == 'vins_mono':
        code = np.where(inexact, 0.0, np.floor(ch[0] + 0.5))
        _check_ids(code, np.where(inexact, 0.0, ch[0]), layout, 'channel 0 (id*num_cams+cam)')
        return _Columns(np.floor_divide(code, num_cams), np.mod(code, num_cams), ch[1:3].T,
                        normalized, inexact)
    return _Columns(ch[0], ch[1], ch[2:4].T, normalized, inexact)


def _per_point_columns(rows: list[FloatArray], lengths: np.ndarray, n_pts: int) -> _Columns:
    """Read the per_point layout: channel i = [x_n, y_n, u, v, feature_id, ...] of point i."""
    if len(rows) != n_pts or np.any(lengths < 5):
        short = np.flatnonzero(lengths < 5)
        msg_ = ("layout 'per_point' expects one channel per point with >= 5 values "
                f'[x_n, y_n, u, v, id]; found {n_pts} points, {len(rows)} channels'
                + (f', channel(s) {short[:5].tolist()} with {lengths[short[:5]].tolist()} '
                   'values' if short.size else '')
                + '; wrong layout?')
        raise MessageError(msg_)
    if np.all(lengths == lengths[0]):
        mat = np.stack(rows)[:, :5]
    else:
        mat = np.stack([row[:5] for row in rows])
    normalized: FloatArray | None = mat[:, 0:2]
    finite = np.isfinite(mat).all(axis=1)
    if not np.any(mat[finite, 0:2]):
        normalized = None  # OpenVINS leaves x_n = y_n = 0: normalize from pixels
    return _Columns(mat[:, 4], np.zeros(n_pts), mat[:, 2:4], normalized,
                    np.abs(mat[:, 4]) >= FLOAT32_EXACT_IDS)


def _read_named(msg: Any) -> _Columns | None:
    """Read the named layout from a PointCloud2 through one structured dtype."""
    try:
        fields = {str(f.name): f for f in msg.fields}
        height, width = int(msg.height), int(msg.width)
        point_step, row_step = int(msg.point_step), int(msg.row_step)
        order = '>' if bool(msg.is_bigendian) else '<'
        data = msg.data
    except AttributeError as err:
        msg_ = ("layout 'named' expects sensor_msgs/msg/PointCloud2 (fields, data), "
                f'got {_type_name(msg)}; wrong layout?')
        raise MessageError(msg_) from err
    if height * width == 0:
        return None
    has_uv = 'u' in fields and 'v' in fields
    has_xy = 'x_n' in fields and 'y_n' in fields
    if 'id' not in fields or not (has_uv or has_xy):
        msg_ = ("layout 'named' needs PointCloud2 fields id, u, v (and optional cam, x_n, "
                f'y_n); found {sorted(fields)}')
        raise MessageError(msg_)
    names = ['id', *(['cam'] if 'cam' in fields else []), *(['u', 'v'] if has_uv else []),
             *(['x_n', 'y_n'] if has_xy else [])]
    formats, offsets = [], []
    for name in names:
        field = fields[name]
        code = POINTFIELD_DTYPES.get(int(field.datatype))
        size = np.dtype(code).itemsize if code else 0
        if code is None or int(field.offset) < 0 or int(field.offset) + size > point_step:
            msg_ = (f'PointCloud2 field {name!r}: datatype {int(field.datatype)} at offset '
                    f'{int(field.offset)} does not fit point_step {point_step}')
            raise MessageError(msg_)
        formats.append(order + code)
        offsets.append(int(field.offset))
    n_pts = height * width
    dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                      'itemsize': point_step})
    buf = np.frombuffer(data, dtype=np.uint8)
    need = (height - 1) * row_step + width * point_step
    if row_step < width * point_step or buf.size < need:
        msg_ = (f'PointCloud2 data holds {buf.size} bytes, {height}x{width} points with '
                f'point_step {point_step} and row_step {row_step} need {need}')
        raise MessageError(msg_)
    rec = np.ndarray((height, width), dtype=dtype, buffer=buf, strides=(row_step, point_step))
    rec = rec.reshape(-1)

    def col(name: str) -> FloatArray:
        return rec[name].astype(np.float64)

    cams = col('cam') if 'cam' in fields else np.zeros(n_pts)
    pixels = np.stack([col('u'), col('v')], axis=1) if has_uv else None
    normalized = np.stack([col('x_n'), col('y_n')], axis=1) if has_xy else None
    ids = col('id')
    id_code = POINTFIELD_DTYPES[int(fields['id'].datatype)]
    limit = {'f4': FLOAT32_EXACT_IDS, 'f8': FLOAT64_EXACT_IDS}.get(id_code, np.inf)
    return _Columns(ids, cams, pixels, normalized, np.abs(ids) >= limit)


def _check_ids(rounded: FloatArray, raw: FloatArray, layout: str, what: str) -> None:
    """Raise if finite ids are negative or not integral (a symptom of a wrong layout)."""
    finite = np.isfinite(raw)
    bad = finite & ((np.abs(raw - rounded) > _ID_TOL) | (rounded < 0))
    if np.any(bad):
        msg_ = (f'layout {layout!r}: {what} must hold non-negative integers, found '
                f'{raw[bad][:3].tolist()}; wrong layout?')
        raise MessageError(msg_)


def _finish(stamp_ns: int, frame_id: str, layout: str, num_cams: int, cols: _Columns,
            memory: TrackMemory | None) -> TrackFrame:
    """Validate ids, drop unusable rows, resolve duplicates, and build the frame."""
    ids_raw, pixels, normalized = cols.ids, cols.pixels, cols.normalized
    finite: BoolArray = np.isfinite(ids_raw) & np.isfinite(cols.cams)
    for coords in (pixels, normalized):
        if coords is not None:
            finite &= np.isfinite(coords).all(axis=1)
    inexact = finite & cols.inexact
    usable = finite & ~cols.inexact
    if usable.all():   # the usual message: the masks below would select every row
        ids, cams = np.floor(ids_raw + 0.5), np.floor(cols.cams + 0.5)
        _check_ids(ids, ids_raw, layout, 'feature ids')
        _check_ids(cams, cols.cams, layout, 'camera ids')
    else:
        ids = np.floor(np.where(usable, ids_raw, 0.0) + 0.5)
        cams = np.floor(np.where(usable, cols.cams, 0.0) + 0.5)
        _check_ids(ids[usable], ids_raw[usable], layout, 'feature ids')
        _check_ids(cams[usable], cols.cams[usable], layout, 'camera ids')
    out_of_range = usable & (cams >= num_cams)
    if np.any(out_of_range):
        msg_ = (f'layout {layout!r}: camera id {int(cams[out_of_range][0])} >= num_cams '
                f'{num_cams}; set num_cams or check the layout')
        raise MessageError(msg_)
    keep = np.flatnonzero(usable)
    keys = ids[keep].astype(np.int64) * num_cams + cams[keep].astype(np.int64)
    coords = normalized if normalized is not None else pixels
    assert coords is not None  # the readers give one kind at least
    keep, reasons = _resolve_duplicates(keep, keys, coords[keep], normalized is not None,
                                        memory)
    if np.any(inexact):
        reasons['feature_ids_inexact'] = int(np.count_nonzero(inexact))
    dropped = int(ids_raw.shape[0] - keep.shape[0])
    if dropped:
        logger.debug('tracks at %d ns: dropped %d of %d observations (%s)', stamp_ns, dropped,
                     ids_raw.shape[0], reasons or 'non-finite')
    return TrackFrame(
        stamp_ns=stamp_ns, frame_id=frame_id,
        feature_ids=ids[keep].astype(np.int64), camera_ids=cams[keep].astype(np.int64),
        pixels=None if pixels is None else pixels[keep],
        normalized=None if normalized is None else normalized[keep],
        dropped=dropped, drop_reasons=reasons)


def _resolve_duplicates(rows: np.ndarray, keys: np.ndarray, coords: FloatArray,
                        normalized: bool, memory: TrackMemory | None,
                        ) -> tuple[np.ndarray, dict[str, int]]:
    """Keep one observation per key: the one nearest to the track's previous observation.

    Args:
        rows: Message rows of the candidates, shape (K,).
        keys: Their track keys, shape (K,).
        coords: Their coordinates, shape (K, 2).
        normalized: Whether ``coords`` are normalized (else pixels).
        memory: Previous observations; None: every repeated key is ambiguous.

    Returns:
        The rows kept (in message order) and the counts of dropped copies by reason.
    """
    order = np.argsort(keys, kind='stable')
    sorted_keys = keys[order]
    differs = sorted_keys[1:] != sorted_keys[:-1]
    if differs.all():
        return rows, {}
    starts = np.r_[True, differs]
    group = np.cumsum(starts) - 1
    repeated = np.bincount(group)[group] > 1
    found, previous = (memory.lookup(sorted_keys, normalized) if memory is not None
                       else (np.zeros(keys.shape[0], dtype=bool), None))
    dist = np.full(keys.shape[0], np.inf)
    if previous is not None:
        dist[found] = np.linalg.norm(coords[order][found] - previous[found], axis=1)
    by_distance = np.lexsort((dist, group))
    best = by_distance[np.r_[True, group[by_distance][1:] != group[by_distance][:-1]]]
    keep_sorted = np.zeros(keys.shape[0], dtype=bool)
    keep_sorted[best] = True
    ambiguous = repeated & ~found
    keep_sorted &= ~ambiguous
    reasons = {}
    resolved = int(np.count_nonzero(repeated & found & ~keep_sorted))
    if resolved:
        reasons['duplicate_observations'] = resolved
    if np.any(ambiguous):
        reasons['ambiguous_duplicate_observations'] = int(np.count_nonzero(ambiguous))
    return rows[np.sort(order[keep_sorted])], reasons


def parse_keyframe(msg: Any, kind: str = 'odometry') -> KeyframePose:
    """Parse a keyframe pose message.

    Args:
        msg: ``nav_msgs/Odometry`` (kind 'odometry'), ``geometry_msgs/PoseStamped``
            (kind 'pose_stamped') or ``geometry_msgs/PoseWithCovarianceStamped`` (kind
            'pose_with_covariance': ROVIO's, AMCL's) from any backend.
        kind: One of :data:`KEYFRAME_KINDS`.

    Returns:
        The pose with a unit quaternion; ``child_frame_id`` is '' but for Odometry; the
        pose covariance when the message has one set (not all zeros) and finite.

    Raises:
        MessageError: If the kind is unknown, the message is of another type, or the pose
            has non-finite values or a quaternion that is not of unit norm.
    """
    if kind not in KEYFRAME_KINDS:
        msg_ = f'unknown keyframe kind {kind!r} (expected one of {", ".join(KEYFRAME_KINDS)})'
        raise MessageError(msg_)
    stamp_ns, frame_id = _header(msg)
    try:
        covariance = None
        if kind == 'pose_stamped':
            pose, child = msg.pose, ''
        else:
            pose = msg.pose.pose
            child = str(msg.child_frame_id) if kind == 'odometry' else ''
            covariance = np.asarray(getattr(msg.pose, 'covariance', ()), dtype=np.float64)
        position = _XYZ(pose.position)
        quat_xyzw = (*_XYZ(pose.orientation), pose.orientation.w)
    except AttributeError as err:
        msg_ = f'keyframe kind {kind!r} expects {KEYFRAME_MSGTYPES[kind]}, got {_type_name(msg)}'
        raise MessageError(msg_) from err
    with np.errstate(over='ignore', invalid='ignore'):
        norm2 = float(np.dot(quat_xyzw, quat_xyzw))
    if math.isfinite(norm2) and norm2 > 0 and abs(norm2 - 1.0) > _QUAT_NORM2_TOL:
        msg_ = (f'keyframe pose at {stamp_ns} ns has a quaternion of norm '
                f'{math.sqrt(norm2):.4g}, not a rotation (a unit quaternion is required)')
        raise MessageError(msg_)
    return KeyframePose(stamp_ns=stamp_ns, frame_id=frame_id, child_frame_id=child,
                        position=np.array(position, dtype=np.float64),
                        quat_xyzw=np.array(quat_xyzw, dtype=np.float64),
                        covariance=covariance)


def parse_camera_info(msg: Any) -> CameraModel:
    """Parse a ``sensor_msgs/CameraInfo`` (any backend); see :meth:`CameraModel.from_camera_info`.

    Args:
        msg: The CameraInfo message.

    Returns:
        The camera model.

    Raises:
        MessageError: If the message is not a usable CameraInfo.
    """
    return CameraModel.from_camera_info(msg)
