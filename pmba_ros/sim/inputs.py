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
"""Front-end input messages (tracks, camera info), for the simulator, the replay and tests.

:func:`make_tracks` and :func:`make_camera_info` are the inverses of
:func:`pmba_ros.backend.tracks.parse_tracks` and
:meth:`~pmba_ros.backend.types.CameraModel.from_camera_info`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from pmba_ros.backend.msg_backend import MsgBackend
from pmba_ros.backend.outputs import finite_rows, header_msg, make_point_cloud2_named
from pmba_ros.backend.tracks import LAYOUTS
from pmba_ros.backend.types import CameraModel, float_rows, TrackFrame
from pmba_ros.errors import MessageError

_F32_EXACT_INT = 2**24


def make_point_cloud(stamp_ns: int, frame_id: str, points: ArrayLike,
                     channels: Sequence[tuple[str, ArrayLike]], backend: MsgBackend) -> Any:
    """Return a ``sensor_msgs/msg/PointCloud`` with arbitrary channels.

    Channel lengths are not checked against the point count, so per-point layouts can be
    written too.

    Args:
        stamp_ns: Header stamp, ns.
        frame_id: Header frame.
        points: Point coordinates, shape (N, 3) (stored as float32 Point32).
        channels: ``(name, values)`` pairs; values are stored as float32.
        backend: Message backend.

    Returns:
        The PointCloud message.

    Raises:
        MessageError: If ``points`` is not (N, 3).
    """
    pts = float_rows(points, 3, 'make_point_cloud: points')
    point_type = backend.msg_class('geometry_msgs/msg/Point32')
    point_msgs = [point_type(x=x, y=y, z=z) for x, y, z in pts.tolist()]
    channel_msgs = [backend.new('sensor_msgs/msg/ChannelFloat32', name=str(name),
                                values=backend.seq_f32(values))
                    for name, values in channels]
    return backend.new('sensor_msgs/msg/PointCloud',
                       header=header_msg(stamp_ns, frame_id, backend),
                       points=point_msgs, channels=channel_msgs)


def make_tracks(frame: TrackFrame, layout: str, backend: MsgBackend, num_cams: int = 1, *,
                landmarks_xyz: ArrayLike | None = None) -> Any:
    """Write a :class:`TrackFrame` in a front-end layout (inverse of ``parse_tracks``).

    Velocity channels are written as zeros. Coordinates and ids travel as float32.

    Args:
        frame: Observations to write.
        layout: One of :data:`~pmba_ros.backend.tracks.LAYOUTS`.
        backend: Message backend.
        num_cams: Front-end camera count (vins_mono id encoding, ``id*num_cams+cam``).
        landmarks_xyz: World points, shape (K, 3), for ``per_point`` ``points`` and for
            ``named`` fields x, y, z; default zeros (per_point) or omitted (named).

    Returns:
        A PointCloud (vins_mono, vins_fusion, per_point) or PointCloud2 (named).

    Raises:
        MessageError: If the layout is unknown or cannot carry the frame (vins layouts
            need pixels and normalized coordinates, per_point needs pixels and camera 0,
            ids must be exact in float32, i.e. < 2^24).
    """
    if layout not in LAYOUTS:
        msg = f'unknown feature layout {layout!r} (expected one of {", ".join(LAYOUTS)})'
        raise MessageError(msg)
    n_obs = len(frame)
    ids, cams = frame.feature_ids, frame.camera_ids
    landmarks = None if landmarks_xyz is None else finite_rows(landmarks_xyz, 3, 'landmarks_xyz')
    if landmarks is not None and landmarks.shape[0] != n_obs:
        msg = f'make_tracks: {landmarks.shape[0]} landmarks for {n_obs} observations'
        raise MessageError(msg)
    if layout == 'named':
        columns: dict[str, ArrayLike] = {'id': ids.astype(np.uint32),
                                         'cam': cams.astype(np.uint8)}
        if frame.pixels is not None:
            columns |= {'u': frame.pixels[:, 0].astype(np.float32),
                        'v': frame.pixels[:, 1].astype(np.float32)}
        if frame.normalized is not None:
            columns |= {'x_n': frame.normalized[:, 0].astype(np.float32),
                        'y_n': frame.normalized[:, 1].astype(np.float32)}
        if landmarks is not None:
            columns |= {k: landmarks[:, i].astype(np.float32) for i, k in enumerate('xyz')}
        if np.any(ids < 0) or np.any(ids >= 2**32) or np.any(cams < 0) or np.any(cams > 255):
            msg = 'make_tracks: named layout stores id as uint32 and cam as uint8'
            raise MessageError(msg)
        return make_point_cloud2_named(frame.stamp_ns, frame.frame_id, columns, backend)
    if frame.pixels is None and n_obs:
        msg = f'make_tracks: layout {layout!r} needs pixels'
        raise MessageError(msg)
    pixels = frame.pixels if frame.pixels is not None else np.zeros((0, 2))
    zeros = np.zeros(n_obs)
    if layout == 'per_point':
        if np.any(cams != 0):
            msg = "make_tracks: layout 'per_point' has no camera id; all cameras must be 0"
            raise MessageError(msg)
        _check_f32_ids(ids)
        norm = frame.normalized if frame.normalized is not None else np.zeros((n_obs, 2))
        table = np.column_stack([norm, pixels, ids.astype(np.float64)])
        points = landmarks if landmarks is not None else np.zeros((n_obs, 3))
        return make_point_cloud(frame.stamp_ns, frame.frame_id, points,
                                [('', row) for row in table], backend)
    if frame.normalized is None and n_obs:
        msg = f'make_tracks: layout {layout!r} needs normalized coordinates'
        raise MessageError(msg)
    norm = frame.normalized if frame.normalized is not None else np.zeros((0, 2))
    points = np.column_stack([norm, np.ones(n_obs)])
    if layout == 'vins_mono':
        if np.any(cams >= num_cams):
            msg = f'make_tracks: camera id >= num_cams {num_cams}'
            raise MessageError(msg)
        code = ids * int(num_cams) + cams
        _check_f32_ids(code)
        values = [code, pixels[:, 0], pixels[:, 1], zeros, zeros]
    else:
        _check_f32_ids(ids)
        values = [ids, cams, pixels[:, 0], pixels[:, 1], zeros, zeros]
    return make_point_cloud(frame.stamp_ns, frame.frame_id, points,
                            [('', v) for v in values], backend)


def _check_f32_ids(ids: np.ndarray) -> None:
    """Raise if ids cannot travel exactly as float32 (VINS channels)."""
    if np.any(ids < 0) or np.any(ids >= _F32_EXACT_INT):
        msg = 'make_tracks: ids must be in [0, 2^24) to be exact in float32 channels'
        raise MessageError(msg)


def make_camera_info(stamp_ns: int, frame_id: str, camera: CameraModel,
                     backend: MsgBackend) -> Any:
    """Return a ``sensor_msgs/msg/CameraInfo`` for a camera model (its binning and ROI offset).

    Model 'none' is written as 'plumb_bob' with five zero coefficients (the ROS convention
    for a rectified camera), which :meth:`CameraModel.from_camera_info` reads back as 'none'.

    Args:
        stamp_ns: Header stamp, ns.
        frame_id: Camera optical frame.
        camera: The camera model.
        backend: Message backend.

    Returns:
        The CameraInfo message (r = identity, p = [K | 0]).

    Raises:
        MessageError: If the backend lacks the types.
    """
    if camera.distortion_model == 'none':
        model, d = 'plumb_bob', np.zeros(5)
    else:
        model, d = camera.distortion_model, camera.d
    k = camera.k
    p = np.column_stack([k, np.zeros(3)])
    (ox, oy), (bx, by) = camera.offset, camera.binning
    cropped = ox > 0 or oy > 0   # an ROI of zero size is the whole image (REP 104)
    roi = backend.new('sensor_msgs/msg/RegionOfInterest', x_offset=ox, y_offset=oy,
                      height=camera.height - oy if cropped else 0,
                      width=camera.width - ox if cropped else 0, do_rectify=False)
    return backend.new('sensor_msgs/msg/CameraInfo',
                       header=header_msg(stamp_ns, frame_id, backend),
                       height=int(camera.height), width=int(camera.width),
                       distortion_model=model, d=backend.seq_f64(d),
                       k=backend.fixed_f64(k), r=backend.fixed_f64(np.eye(3)),
                       p=backend.fixed_f64(p), binning_x=bx if bx > 1 else 0,
                       binning_y=by if by > 1 else 0, roi=roi)


__all__ = ['make_camera_info', 'make_point_cloud', 'make_tracks']
