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
"""Plain containers for what the back end consumes from ROS messages (no ROS imports).

:class:`TrackFrame` holds one frame of feature observations, :class:`KeyframePose` one
front-end keyframe pose and :class:`CameraModel` the intrinsics of one camera, read from a
``sensor_msgs/CameraInfo``. The containers copy their arrays and make them read-only, so a
parser or the solver cannot alias a caller's buffer.

Camera conventions follow ROS ``CameraInfo`` and OpenCV: normalized undistorted coordinates
``(x, y) = (X/Z, Y/Z)`` (``xy``) in the optical frame (x right, y down, z forward), pixels
``u = fx * x_d + cx``, ``v = fy * y_d + cy`` of the distorted ``(x_d, y_d)`` (``xy_d``); the
distortion models and their notation are in :mod:`.distortion`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.backend.distortion import (
    distort_equidistant,
    distort_plumb_bob,
    equidistant_fold,
    equidistant_jacobian,
    pinhole_jacobian,
    plumb_bob_fold,
    plumb_bob_jacobian,
    plumb_bob_radial,
    theta_d,
    undistort_equidistant,
    undistort_plumb_bob,
)
from pmba_ros.errors import MessageError

DISTORTION_MODELS = ('none', 'plumb_bob', 'equidistant')
"""Distortion models :class:`CameraModel` implements (ROS ``CameraInfo`` names)."""

REFINED_PX = 1.0
"""Largest move of a pixel's ray between two intrinsics that is a refinement, not a change."""


def _frozen_array(value: Any, dtype: type, shape_tail: tuple[int, ...], what: str,
                  ) -> np.ndarray:
    """Return a read-only copy of ``value`` with trailing shape ``shape_tail``."""
    arr: np.ndarray = np.array(value, dtype=dtype, copy=True)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        want = '(K' + ''.join(f', {n}' for n in shape_tail) + ')'
        msg = f'{what}: expected shape {want}, got {arr.shape}'
        raise MessageError(msg)
    arr.flags.writeable = False
    return arr


def float_rows(value: Any, n_cols: int, what: str, rows: str = 'N') -> FloatArray:
    """Return ``value`` as a float64 array of shape (rows, n_cols); MessageError if not."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != n_cols:
        msg = f'{what}: expected shape ({rows}, {n_cols}), got {arr.shape}'
        raise MessageError(msg)
    return arr


@dataclass(frozen=True, eq=False)
class TrackFrame:
    """Feature observations of one front-end frame.

    Attributes:
        stamp_ns: Header stamp of the source message, ns.
        frame_id: Header frame id of the source message.
        feature_ids: Front-end feature ids, shape (K,), int64.
        camera_ids: Camera index of each observation, shape (K,), int64.
        pixels: Raw (distorted) pixels, shape (K, 2), px; None if the message had none.
        normalized: Normalized undistorted coordinates ``(x/z, y/z)``, shape (K, 2);
            None if the message had none (OpenVINS ``loop_feats``): then normalize
            ``pixels`` with :meth:`CameraModel.normalize`.
        dropped: Observations the parser discarded (non-finite values, duplicates).
        drop_reasons: Of ``dropped``, the counts of suspect inputs by reason (ids that
            cannot be exact, duplicate ids); the back-end counts them as warnings.
    """

    stamp_ns: int
    frame_id: str
    feature_ids: IntArray
    camera_ids: IntArray
    pixels: FloatArray | None
    normalized: FloatArray | None
    dropped: int = 0
    drop_reasons: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Copy, freeze and validate the arrays.

        Raises:
            MessageError: If the shapes disagree or neither coordinate kind is given.
        """
        ids = _frozen_array(self.feature_ids, np.int64, (), 'feature_ids')
        cams = _frozen_array(self.camera_ids, np.int64, (), 'camera_ids')
        if cams.shape != ids.shape:
            msg = f'camera_ids has {cams.shape[0]} entries, feature_ids {ids.shape[0]}'
            raise MessageError(msg)
        object.__setattr__(self, 'feature_ids', ids)
        object.__setattr__(self, 'camera_ids', cams)
        for name in ('pixels', 'normalized'):
            value = getattr(self, name)
            if value is None:
                continue
            arr = _frozen_array(value, np.float64, (2,), name)
            if arr.shape[0] != ids.shape[0]:
                msg = f'{name} has {arr.shape[0]} rows, feature_ids {ids.shape[0]}'
                raise MessageError(msg)
            object.__setattr__(self, name, arr)
        if self.pixels is None and self.normalized is None and ids.shape[0] > 0:
            msg = 'track frame needs pixels or normalized coordinates'
            raise MessageError(msg)
        object.__setattr__(self, 'stamp_ns', int(self.stamp_ns))
        object.__setattr__(self, 'dropped', int(self.dropped))

    def __len__(self) -> int:
        """Return the number of observations K."""
        return int(self.feature_ids.shape[0])

    @classmethod
    def empty(cls, stamp_ns: int, frame_id: str, dropped: int = 0) -> TrackFrame:
        """Return a frame without observations.

        Args:
            stamp_ns: Header stamp, ns.
            frame_id: Header frame id.
            dropped: Observations discarded while parsing.

        Returns:
            A TrackFrame with K = 0 and (0, 2) pixel and normalized arrays.
        """
        zeros_i = np.zeros(0, dtype=np.int64)
        zeros_f = np.zeros((0, 2))
        return cls(stamp_ns, frame_id, zeros_i, zeros_i, zeros_f, zeros_f, dropped)


@dataclass(frozen=True, eq=False)
class KeyframePose:
    """One front-end keyframe pose (body or camera in ``frame_id``).

    Attributes:
        stamp_ns: Header stamp, ns.
        frame_id: Parent frame of the pose (front-end world/odom frame).
        child_frame_id: Frame the pose describes ('' for PoseStamped input).
        position: Translation, shape (3,), m.
        quat_xyzw: Unit rotation quaternion, shape (4,), order x, y, z, w.
        covariance: Pose covariance (x, y, z, rotation about x, y, z; in ``frame_id``),
            shape (6, 6), or None when the message has none (all zeros) or it is unusable.
    """

    stamp_ns: int
    frame_id: str
    child_frame_id: str
    position: FloatArray
    quat_xyzw: FloatArray
    covariance: FloatArray | None = None

    def __post_init__(self) -> None:
        """Copy, freeze and validate the arrays.

        Raises:
            MessageError: On wrong shapes, non-finite values or a zero-norm quaternion.
        """
        pos = np.array(self.position, dtype=np.float64, copy=True)
        quat = np.array(self.quat_xyzw, dtype=np.float64, copy=True)
        if pos.shape != (3,) or quat.shape != (4,):
            msg = f'keyframe pose: position {pos.shape} / quat_xyzw {quat.shape}, want (3,)/(4,)'
            raise MessageError(msg)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))):
            msg = f'keyframe pose at {self.stamp_ns} ns has non-finite values'
            raise MessageError(msg)
        with np.errstate(over='ignore'):
            norm = float(np.linalg.norm(quat))
        if not 1e-9 <= norm < np.inf:
            msg = (f'keyframe pose at {self.stamp_ns} ns has a zero-norm or overflowing '
                   f'quaternion (norm {norm:g})')
            raise MessageError(msg)
        quat /= norm
        pos.flags.writeable = False
        quat.flags.writeable = False
        if self.covariance is not None:
            cov = np.array(self.covariance, dtype=np.float64, copy=True)
            usable = cov.size == 36 and np.all(np.isfinite(cov)) and np.any(cov != 0.0)
            cov.flags.writeable = False
            object.__setattr__(self, 'covariance', cov.reshape(6, 6) if usable else None)
        object.__setattr__(self, 'position', pos)
        object.__setattr__(self, 'quat_xyzw', quat)
        object.__setattr__(self, 'stamp_ns', int(self.stamp_ns))


_CAMERA_INFOS: dict[tuple[Any, ...], CameraModel] = {}
"""CameraInfo fields -> the model :meth:`CameraModel.from_camera_info` made of them."""
_CAMERA_INFOS_KEPT = 16   # a rig's cameras and a few changes


@dataclass(frozen=True, eq=False)
class CameraModel:
    """Pinhole intrinsics with ROS ``CameraInfo`` distortion.

    Supported ``distortion_model`` values: ``'none'``; ``'plumb_bob'`` (OpenCV
    k1, k2, p1, p2[, k3]; 4 or 5 coefficients, stored as 5) and ``'equidistant'``
    (OpenCV fisheye k1..k4). Skew (``CameraInfo.k[1]``) is ignored.

    The intrinsics are the sensor's at full resolution; a camera that publishes a binned or
    cropped image (``CameraInfo.binning_x/y``, ``roi``, REP 104) has its pixels at
    ``(full - offset) / binning``, which :meth:`normalize` and :meth:`denormalize` take.

    Attributes:
        fx: Focal length x, px (full resolution).
        fy: Focal length y, px.
        cx: Principal point x, px.
        cy: Principal point y, px.
        distortion_model: One of :data:`DISTORTION_MODELS`.
        d: Distortion coefficients, shape (n,): 0 ('none'), 5 ('plumb_bob'), 4 ('equidistant').
        width: Image width, px (0 if unknown; full resolution).
        height: Image height, px (0 if unknown).
        binning: Full-resolution pixels per image pixel, x and y (>= 1).
        offset: The image's top-left corner at full resolution (the ROI's offset), px.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    distortion_model: str = 'none'
    d: FloatArray = field(default_factory=lambda: np.zeros(0))
    width: int = 0
    height: int = 0
    binning: tuple[int, int] = (1, 1)
    offset: tuple[int, int] = (0, 0)

    def __post_init__(self) -> None:
        """Validate and canonicalize the model.

        Raises:
            MessageError: On non-positive or non-finite intrinsics, an unknown model or a
                wrong number of coefficients.
        """
        vals = np.array([self.fx, self.fy, self.cx, self.cy], dtype=np.float64)
        if not np.all(np.isfinite(vals)) or vals[0] <= 0 or vals[1] <= 0:
            msg = f'camera: need finite intrinsics and fx, fy > 0, got {vals.tolist()}'
            raise MessageError(msg)
        d = np.array(self.d, dtype=np.float64, copy=True).reshape(-1)
        model = self.distortion_model
        if not np.all(np.isfinite(d)):
            msg = f'camera: non-finite distortion coefficients {d.tolist()}'
            raise MessageError(msg)
        if model == 'plumb_bob' and d.size == 4:
            d = np.append(d, 0.0)
        want = {'none': 0, 'plumb_bob': 5, 'equidistant': 4}
        if model not in want:
            msg = (f'camera: distortion model {model!r} not supported '
                   f'(supported: {", ".join(DISTORTION_MODELS)})')
            raise MessageError(msg)
        if d.size != want[model]:
            msg = f'camera: {model!r} needs {want[model]} coefficients, got {d.size}'
            raise MessageError(msg)
        if min(self.binning) < 1 or min(self.offset) < 0:
            msg = (f'camera: binning must be >= 1 and the ROI offset >= 0, got binning '
                   f'{self.binning}, offset {self.offset}')
            raise MessageError(msg)
        object.__setattr__(self, 'binning', tuple(int(b) for b in self.binning))
        object.__setattr__(self, 'offset', tuple(int(o) for o in self.offset))
        d.flags.writeable = False
        for name, value in zip(('fx', 'fy', 'cx', 'cy'), vals, strict=True):
            object.__setattr__(self, name, float(value))
        object.__setattr__(self, 'd', d)
        object.__setattr__(self, 'width', int(self.width))
        object.__setattr__(self, 'height', int(self.height))

    def describe(self) -> str:
        """Return the model in one line: size, distortion model, intrinsics, coefficients."""
        coefficients = ' '.join(f'{v:.6g}' for v in self.d)
        return (f'{self.width}x{self.height} {self.distortion_model} fx={self.fx:.6g} '
                f'fy={self.fy:.6g} cx={self.cx:.6g} cy={self.cy:.6g}'
                + (f' d=[{coefficients}]' if coefficients else '')
                + (f' binning={self.binning[0]}x{self.binning[1]}'
                   if self.binning != (1, 1) else '')
                + (f' roi_offset={self.offset[0]},{self.offset[1]}' if any(self.offset) else ''))

    def fold_in_image(self) -> str:
        """Say where the distortion folds over inside the image ('' if not, or size unknown).

        Past its fold a distortion polynomial stops growing: a pixel there has no ray or two
        (:mod:`.distortion`), :meth:`normalize` gives NaN, and its observations are dropped
        as not finite. The tangential terms are left out of the estimate.
        """
        if self.width <= 0 or self.height <= 0 or not np.any(self.d):
            return ''
        if self.distortion_model == 'plumb_bob':
            fold, radial = plumb_bob_fold(self.d), plumb_bob_radial(self.d)
        else:
            fold, radial = equidistant_fold(self.d), self.d
            if fold >= np.pi / 2:   # 90 degrees: no pinhole ray, the fisheye's own limit
                return ''
        if not np.isfinite(fold):
            return ''
        reach = float(theta_d(np.array([fold]), radial)[0])
        u, v = np.meshgrid(np.linspace(0.0, self.width, 81), np.linspace(0.0, self.height, 61))
        share = float(np.mean(np.hypot((u - self.cx) / self.fx, (v - self.cy) / self.fy) > reach))
        if share == 0.0:
            return ''
        return (f'its {self.distortion_model} distortion folds over inside the image: pixels '
                f'more than {reach:.3g} focal lengths from the principal point ({100 * share:.2g} '
                '% of the image) have no ray or two, and their observations are dropped (a '
                'calibration fitted to a smaller part of the image?)')

    @property
    def image_pinhole(self) -> tuple[float, float, float, float]:
        """Return fx, fy, cx, cy in the published image's pixels (binned and cropped)."""
        (bx, by), (ox, oy) = self.binning, self.offset
        return self.fx / bx, self.fy / by, (self.cx - ox) / bx, (self.cy - oy) / by

    def change_from(self, old: CameraModel) -> str:
        """Return ``'OLD -> NEW'`` (:meth:`describe`) if ``old`` differs, else ''.

        A refinement is no change: the same image and model, no pixel's ray moved by more
        than :data:`REFINED_PX` (an online calibration, OpenVINS' ``calib_cam_intrinsics``,
        publishes one with every frame: counted as changes, they had looked like two cameras
        alternating on the topic).
        """
        if old is self:   # the same CameraInfo again (from_camera_info keeps its models)
            return ''
        before, after = old.describe(), self.describe()
        if before == after or self.moves_pixels_from(old) <= REFINED_PX:
            return ''
        return f'{before} -> {after}'

    def moves_pixels_from(self, old: CameraModel) -> float:
        """Return how far a pixel of the image moves from ``old``'s ray to this model's, px.

        Over a grid of the image, as a ray of ``old`` projected by this model; inf for
        another image size, binning, ROI or distortion model. An image of unknown size
        (OpenVINS' intrinsics give none) is taken to span twice the principal point.
        """
        same = (self.width, self.height, self.binning, self.offset, self.distortion_model) == (
            old.width, old.height, old.binning, old.offset, old.distortion_model)
        if not same:
            return float('inf')
        _, _, cx, cy = self.image_pinhole
        (bx, by), (ox, oy) = self.binning, self.offset
        width = (self.width - ox) / bx if self.width > 0 else 2.0 * cx
        height = (self.height - oy) / by if self.height > 0 else 2.0 * cy
        u, v = np.meshgrid(np.linspace(0, width, 9), np.linspace(0, height, 7))
        pixels = np.column_stack([u.ravel(), v.ravel()])
        with np.errstate(all='ignore'):
            moved = np.hypot(*(self.denormalize(old.normalize(pixels)) - pixels).T)
        moved = moved[np.isfinite(moved)]   # past a fold: no ray to compare
        return float(moved.max()) if moved.size else float('inf')

    @property
    def k(self) -> FloatArray:
        """Return the 3x3 calibration matrix K (row-major, no skew)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_camera_info(cls, msg: Any) -> CameraModel:
        """Build a camera model from a ``sensor_msgs/msg/CameraInfo`` (any backend).

        All-zero (or no) coefficients with model '', 'none', 'plumb_bob' or
        'rational_polynomial' give 'none' (a rectified camera). Zero coefficients beyond the
        ones a model uses are dropped, so a 'rational_polynomial' model whose k4..k6 (and
        s1..s4, tx, ty: 14 coefficients) are zero is read as 'plumb_bob'.

        Args:
            msg: CameraInfo from rclpy, rosbags or mcap_ros2 (fields ``k``, ``d``,
                ``distortion_model``, ``width``, ``height``; ROS 1's ``K``, ``D`` too).

        Returns:
            The camera model.

        Raises:
            MessageError: If ``k`` does not have 9 values, or the model is unsupported.
        """
        try:
            k = np.asarray(_camera_info_field(msg, 'k'), dtype=np.float64).reshape(-1)
            d = np.asarray(_camera_info_field(msg, 'd'), dtype=np.float64).reshape(-1)
            model = str(msg.distortion_model)
            width, height = int(msg.width), int(msg.height)
            binning, offset = _binning_and_offset(msg)
        except (AttributeError, TypeError, ValueError) as err:
            msg_ = f'expected sensor_msgs/msg/CameraInfo, got {type(msg).__name__}: {err}'
            raise MessageError(msg_) from err
        # A camera sends the same CameraInfo with every frame: the same fields gave this
        # (immutable) model before, through the same checks.
        key = (cls, k.tobytes(), d.tobytes(), model, width, height, binning, offset)
        known = _CAMERA_INFOS.get(key)
        if known is not None:
            return known
        if k.size != 9:
            msg_ = f'CameraInfo.k must have 9 values, got {k.size}'
            raise MessageError(msg_)
        used = {'plumb_bob': 5, 'rational_polynomial': 5, 'equidistant': 4}.get(model, d.size)
        if model in ('', 'none', 'plumb_bob', 'rational_polynomial') and not np.any(d):
            model, d = 'none', np.zeros(0)
        elif d.size > used and not np.any(d[used:]):   # zeros beyond what the model uses
            model, d = 'plumb_bob' if model == 'rational_polynomial' else model, d[:used]
        camera = cls(fx=k[0], fy=k[4], cx=k[2], cy=k[5], distortion_model=model, d=d,
                     width=width, height=height, binning=binning, offset=offset)
        if len(_CAMERA_INFOS) >= _CAMERA_INFOS_KEPT:
            _CAMERA_INFOS.clear()
        _CAMERA_INFOS[key] = camera
        return camera

    def normalize(self, pixels: FloatArray) -> FloatArray:
        """Undistort raw pixels to normalized coordinates ``(x/z, y/z)``.

        Distortion is inverted with a vectorized Newton iteration (more accurate than
        ``cv2.undistortPoints``' fixed-point default). Rows whose inversion does not converge,
        and equidistant rays at or beyond 90 degrees from the optical axis, are NaN.

        Args:
            pixels: Raw pixels, shape (K, 2), px.

        Returns:
            Normalized undistorted coordinates, shape (K, 2).

        Raises:
            MessageError: If ``pixels`` is not (K, 2).
        """
        px = float_rows(pixels, 2, 'normalize: pixels', 'K')
        fx, fy, cx, cy = self.image_pinhole
        xy_d = np.stack([(px[:, 0] - cx) / fx, (px[:, 1] - cy) / fy], 1)
        if self.distortion_model == 'plumb_bob' and np.any(self.d):
            return undistort_plumb_bob(xy_d, self.d)
        if self.distortion_model == 'equidistant':
            return undistort_equidistant(xy_d, self.d)
        return xy_d

    def denormalize(self, normalized: FloatArray) -> FloatArray:
        """Distort normalized coordinates and return raw pixels (inverse of :meth:`normalize`).

        Args:
            normalized: Normalized undistorted coordinates, shape (K, 2).

        Returns:
            Raw pixels, shape (K, 2), px (same as ``cv2.projectPoints`` /
            ``cv2.fisheye.projectPoints`` of the rays ``(x, y, 1)``).

        Raises:
            MessageError: If ``normalized`` is not (K, 2).
        """
        xy = float_rows(normalized, 2, 'denormalize: normalized', 'K')
        if self.distortion_model == 'plumb_bob':
            xy_d = distort_plumb_bob(xy, self.d)
        elif self.distortion_model == 'equidistant':
            xy_d = distort_equidistant(xy, self.d)
        else:
            xy_d = xy
        fx, fy, cx, cy = self.image_pinhole
        return np.stack([fx * xy_d[:, 0] + cx, fy * xy_d[:, 1] + cy], 1)

    def pixel_jacobian(self, bearings: FloatArray) -> FloatArray | None:
        """Return d(raw pixel) / d(bearing) at unit ``bearings`` (K, 3), shape (K, 2, 3).

        What one pixel of this camera is as a ray error, where that is not the pinhole of
        its intrinsics (None for a model without distortion): the errors of the observations
        are weighed by it. Rays at or beyond 90 degrees from the optical axis are NaN.
        """
        v = float_rows(bearings, 3, 'pixel_jacobian: bearings', 'K')
        if self.distortion_model == 'none' or not np.any(self.d):
            return None
        if self.distortion_model == 'equidistant':
            J = equidistant_jacobian(v, self.d)
            J[v[:, 2] <= 0] = np.nan
        else:
            xy = v[:, :2] / np.where(v[:, 2] > 0, v[:, 2], np.nan)[:, None]
            J = plumb_bob_jacobian(xy, self.d) @ pinhole_jacobian(v, 1.0, 1.0)
        fx, fy, _, _ = self.image_pinhole
        J[:, 0] *= fx
        J[:, 1] *= fy
        return J


def _binning_and_offset(msg: Any) -> tuple[tuple[int, int], tuple[int, int]]:
    """Return a CameraInfo's binning (0: none, i.e. 1) and ROI offset (REP 104)."""
    bx = int(getattr(msg, 'binning_x', 0) or 1)
    by = int(getattr(msg, 'binning_y', 0) or 1)
    roi = getattr(msg, 'roi', None)
    offset = (0, 0) if roi is None else (int(roi.x_offset), int(roi.y_offset))
    return (bx, by), offset


def _camera_info_field(msg: Any, name: str) -> Any:
    """Return CameraInfo field ``name`` in ROS 2 spelling, else ROS 1's (``K``, ``D``, ...)."""
    try:
        return getattr(msg, name)
    except AttributeError:
        return getattr(msg, name.upper())
