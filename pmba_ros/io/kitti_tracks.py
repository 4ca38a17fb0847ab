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
"""KITTI-00 stereo feature tracks (GTSAM's ``VO_*00s.txt``) as a monocular front-end recording.

Input files (``/work/shared/data/SOURCES.md`` §3):

* ``VO_calibration00s.txt``: ``fx fy skew cx cy baseline``;
* ``VO_camera_poses00s.txt``: ``id`` + a row-major 4x4 camera -> world matrix (stereo VO
  estimates, not ground truth), one per keyframe;
* ``VO_stereo_factors00s.txt``: ``cam lmk uL uR v X Y Z`` per observation.

The left image is used as a monocular front-end: each keyframe's ``(uL, v)`` observations
become one tracks message (rectified images, so no distortion) and its VO pose the keyframe
pose. With ``stereo`` the right image's ``(uR, v)`` join them as camera 1, which sits
``baseline`` metres along the left camera's x axis (:func:`right_camera`). Which KITTI
frames the keyframes are is not stated in the files; :func:`find_frame_offset` finds it
by comparing relative motions with the ground truth (for these files: the 77 poses are
frames 0-76, stride 1), and refuses a location that other frames fit about as well (a short
or straight sequence). Stamps come from KITTI's ``times.txt`` for those frames.
"""

from __future__ import annotations

from dataclasses import dataclass
import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pmba_ros.backend.extrinsics import Rigid
from pmba_ros.backend.types import CameraModel, TrackFrame
from pmba_ros.core import so3
from pmba_ros.errors import FormatError
from pmba_ros.eval.trajectory import Trajectory
from pmba_ros.io.text import float_values, nonblank_lines

if TYPE_CHECKING:
    from pmba_ros._typing import FloatArray, IntArray

logger = logging.getLogger(__name__)

IMAGE_SIZE = (1241, 376)
"""KITTI 00's image width and height, px."""

_ROTATION_TOL = 1e-3
"""Largest accepted ``|R^T R - I|`` entry (and ``|det R - 1|``) of a VO pose's rotation."""

_LOCATION_P = 1e-3
"""Chance allowed that the runner-up location fits as well as the best
(:func:`_distinct_ratio`)."""

_MAX_SKEW_PX = 0.01
"""Largest shift a skew may make across the image height, px: the camera model has no skew."""

CALIBRATION_FILE = 'VO_calibration00s.txt'
POSES_FILE = 'VO_camera_poses00s.txt'
FACTORS_FILE = 'VO_stereo_factors00s.txt'


@dataclass(frozen=True, eq=False)
class KittiTracks:
    """KITTI stereo VO tracks as a monocular keyframe sequence (F keyframes).

    Attributes:
        keyframe_ids: VO pose ids, shape (F,).
        R_wc: VO camera -> world rotations, shape (F, 3, 3).
        centers: VO camera centres, shape (F, 3), m.
        frames: One TrackFrame per keyframe (left-image pixels and normalized coordinates).
        camera: Left camera model (rectified: no distortion).
        baseline_m: Stereo baseline, m.
    """

    keyframe_ids: IntArray
    R_wc: FloatArray
    centers: FloatArray
    frames: list[TrackFrame]
    camera: CameraModel
    baseline_m: float


def _load(path: Path, min_cols: int) -> tuple[FloatArray, list[int]]:
    """Load a whitespace-separated table of finite numbers and its rows' line numbers.

    Raises:
        FormatError: Naming the file and line of a row that is short, of another width than
            the first, not numeric or not finite, or the file when it has no row.
    """
    try:
        lines, numbers = nonblank_lines(path)
    except OSError as err:
        msg = f'{path}: cannot read: {err}'
        raise FormatError(msg) from err
    # '#' lines are comments, as numpy.loadtxt read these files before
    rows = [(s, n) for s, n in zip(lines, numbers, strict=True)
            if not s.lstrip().startswith('#')]
    if not rows:
        msg = f'{path}: no data (expected rows of at least {min_cols} numbers)'
        raise FormatError(msg)
    width = len(rows[0][0].split())
    for text, n in rows:
        count = len(text.split())
        if count < min_cols or count != width:
            need = (f'at least {min_cols}' if count < min_cols else
                    f'{width} (as line {rows[0][1]})')
            msg = f'{path}:{n}: expected {need} numbers, got {count}'
            raise FormatError(msg)
    line_no = [n for _, n in rows]
    table = float_values(path, [t for t, _ in rows], line_no).reshape(len(rows), width)
    bad = np.flatnonzero(~np.all(np.isfinite(table), axis=1))
    if bad.size:
        msg = f'{path}:{line_no[int(bad[0])]}: non-finite value'
        raise FormatError(msg)
    return table, line_no


def _integers(path: Path, values: FloatArray, line_no: list[int], what: str) -> IntArray:
    """Return ``values`` as int64, naming the line of the first that is no integer."""
    bad = np.flatnonzero((values != np.round(values)) | (np.abs(values) > 2.0 ** 62))
    if bad.size:
        k = int(bad[0])
        msg = f'{path}:{line_no[k]}: {what} {values[k]:g} is not an integer'
        raise FormatError(msg)
    return values.astype(np.int64)


def _read_poses(path: Path) -> tuple[IntArray, FloatArray, FloatArray]:
    """Return the pose ids, rotations and centres of the poses file, in id order.

    Raises:
        FormatError: Naming the line of a repeated id or of a matrix that is no rigid
            motion (its rotation block not a rotation, its last row not ``0 0 0 1``).
    """
    poses, line_no = _load(path, 17)
    ids = _integers(path, poses[:, 0], line_no, 'pose id')
    mats = poses[:, 1:17].reshape(-1, 4, 4)
    R = mats[:, :3, :3]
    ortho_err = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    last_err = np.abs(mats[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1)
    bad = np.flatnonzero((ortho_err > _ROTATION_TOL) | (np.abs(det - 1.0) > _ROTATION_TOL) |
                         (last_err > _ROTATION_TOL))
    if bad.size:
        k = int(bad[0])
        msg = (f'{path}:{line_no[k]}: pose {ids[k]} is not a rigid motion (|R^T R - I| = '
               f'{ortho_err[k]:.3g}, det R = {det[k]:.3g}, last row '
               f'{" ".join(f"{v:g}" for v in mats[k, 3])})')
        raise FormatError(msg)
    order = np.argsort(ids, kind='stable')
    repeated = np.flatnonzero(np.diff(ids[order]) == 0)
    if repeated.size:
        a, b = (int(order[repeated[0] + i]) for i in (0, 1))
        msg = f'{path}:{line_no[b]}: pose id {ids[b]} repeats line {line_no[a]}'
        raise FormatError(msg)
    if np.any(np.diff(ids) < 0):
        # ids number the keyframes in time (GTSAM's x0, x1, ...): their order is the file's
        k = int(np.flatnonzero(np.diff(ids) < 0)[0]) + 1
        logger.warning('%s:%d: pose id %d after %d; the poses are taken in id order', path,
                       line_no[k], ids[k], ids[k - 1])
    return ids[order], so3.project(R[order]), mats[order, :3, 3].copy()


def _read_camera(path: Path, stereo: bool) -> tuple[CameraModel, float]:
    """Return the left camera model and the baseline of the calibration file.

    Raises:
        FormatError: If fx or fy is not positive, the skew is not 0 (the model has none)
            or, with ``stereo``, the baseline is not positive.
    """
    calib, line_no = _load(path, 6)
    fx, fy, skew, cx, cy, baseline = (float(v) for v in calib[0, :6])
    problem = ('fx and fy must be > 0' if fx <= 0 or fy <= 0 else
               # what a skew moves a pixel by across the image: no camera model here has one
               f'skew {skew:g} is not supported (rectified images have 0)'
               if abs(skew) * IMAGE_SIZE[1] / fy > _MAX_SKEW_PX else
               f'a stereo baseline must be > 0 m, got {baseline:g}'
               if stereo and baseline <= 0 else None)
    if problem is not None:
        msg = f'{path}:{line_no[0]}: {problem}'
        raise FormatError(msg)
    camera = CameraModel(fx=fx, fy=fy, cx=cx, cy=cy, width=IMAGE_SIZE[0], height=IMAGE_SIZE[1])
    return camera, baseline


def read_kitti_tracks(directory: Path | str, stereo: bool = False) -> KittiTracks:
    """Read the three ``VO_*00s.txt`` files of a directory.

    Args:
        directory: Folder with :data:`CALIBRATION_FILE`, :data:`POSES_FILE` and
            :data:`FACTORS_FILE`.
        stereo: Also the right image's observations ``(uR, v)``, as camera 1.

    Returns:
        The keyframe sequence (stamps are assigned by the caller).

    Raises:
        FormatError: If a file is missing or malformed (naming the line): a value not
            finite, a pose no rigid motion or its id repeated, an observation of a keyframe
            without a pose, repeated at other pixels or, with ``stereo``, with ``uR > uL``,
            or a baseline not > 0.
    """
    directory = Path(directory)
    camera, baseline = _read_camera(directory / CALIBRATION_FILE, stereo)
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    ids, R_wc, centers = _read_poses(directory / POSES_FILE)
    path = directory / FACTORS_FILE
    factors, line_no = _load(path, 5)
    keep = _unique_observations(path, factors, line_no)
    factors, line_no = factors[keep], [line_no[i] for i in keep]
    cam = _integers(path, factors[:, 0], line_no, 'keyframe id')
    lmk = _integers(path, factors[:, 1], line_no, 'landmark id')
    unknown = np.flatnonzero(~np.isin(cam, ids))
    if unknown.size:
        k = int(unknown[0])
        msg = f'{path}:{line_no[k]}: observation of keyframe {cam[k]}, which has no pose'
        raise FormatError(msg)
    _check_disparity(path, factors[:, 2] - factors[:, 3], line_no, stereo)
    uv = factors[:, [2, 4]]
    side = np.zeros(cam.shape[0], dtype=np.int64)
    if stereo:
        cam, lmk, side = np.tile(cam, 2), np.tile(lmk, 2), np.repeat([0, 1], cam.shape[0])
        uv = np.concatenate([uv, factors[:, [3, 4]]])
    order = np.lexsort((side, lmk, cam))
    cam, lmk, uv, side = cam[order], lmk[order], uv[order], side[order]
    normalized = np.column_stack([(uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy])
    bounds = np.searchsorted(cam, ids, side='left'), np.searchsorted(cam, ids, side='right')
    frames = []
    for k, (lo, hi) in enumerate(zip(*bounds, strict=True)):
        frames.append(TrackFrame(stamp_ns=0, frame_id='camera', feature_ids=lmk[lo:hi],
                                 camera_ids=side[lo:hi],
                                 pixels=uv[lo:hi], normalized=normalized[lo:hi]))
        logger.debug('keyframe %d: %d observations', ids[k], hi - lo)
    return KittiTracks(ids, R_wc, centers, frames, camera, baseline)


def _check_disparity(path: Path, disparity: FloatArray, line_no: list[int],
                     stereo: bool) -> None:
    """Refuse (stereo) or warn of (monocular) observations with ``uR > uL``.

    A negative disparity puts the point behind the cameras: the row is wrong (its columns
    swapped or its match false). Monocular tracks use no ``uR``, so they only warn.
    """
    bad = np.flatnonzero(disparity < 0.0)
    if not bad.size:
        return
    k = int(bad[0])
    what = (f'uR > uL by {-disparity[k]:g} px (negative disparity; {bad.size} such '
            f'observation(s))')
    if stereo:
        msg = f'{path}:{line_no[k]}: {what}: no point lies behind both cameras'
        raise FormatError(msg)
    logger.warning('%s:%d: %s; only (uL, v) is used', path, line_no[k], what)


def _unique_observations(path: Path, factors: FloatArray, line_no: list[int]) -> IntArray:
    """Return the rows to keep: a repeated ``(keyframe, landmark)`` row is dropped.

    Raises:
        FormatError: If a keyframe observes a landmark twice at different pixels.
    """
    _, first, inverse = np.unique(factors[:, :2], axis=0, return_index=True,
                                  return_inverse=True)
    firsts = first[inverse.reshape(-1)]
    repeat = np.flatnonzero(firsts != np.arange(factors.shape[0]))
    if not repeat.size:
        return np.arange(factors.shape[0])
    differ = repeat[np.any(factors[repeat, 2:5] != factors[firsts[repeat], 2:5], axis=1)]
    k = int(differ[0] if differ.size else repeat[0])
    j = int(firsts[k])
    if differ.size:
        msg = (f'{path}:{line_no[k]}: keyframe {factors[k, 0]:g} observes landmark '
               f'{factors[k, 1]:g} again (line {line_no[j]}), at other pixels')
        raise FormatError(msg)
    logger.warning('%s:%d: %d observation(s) repeat an earlier line (the first repeats line '
                   '%d); dropped', path, line_no[k], repeat.size, line_no[j])
    return np.sort(first)


def right_camera(baseline_m: float) -> Rigid:
    """Return the right camera's pose in the left camera's frame (rectified: no rotation)."""
    return Rigid(np.eye(3), np.array([float(baseline_m), 0.0, 0.0]))


def _relative(R_wc: FloatArray, centers: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return consecutive relative rotations and translations (in the earlier camera)."""
    R_rel = np.einsum('kji,kjl->kil', R_wc[:-1], R_wc[1:])
    t_rel = np.einsum('kji,kj->ki', R_wc[:-1], centers[1:] - centers[:-1])
    return R_rel, t_rel


def _relative_strided(R_wc: FloatArray, centers: FloatArray,
                      stride: int) -> tuple[FloatArray, FloatArray]:
    """Return the relative motions from frame k to frame k + stride, for every k."""
    R_rel = np.einsum('kji,kjl->kil', R_wc[:-stride], R_wc[stride:])
    t_rel = np.einsum('kji,kj->ki', R_wc[:-stride], centers[stride:] - centers[:-stride])
    return R_rel, t_rel


def _scores(R_wc: FloatArray, centers: FloatArray, gt: Trajectory, strides: range,
            first_frame: int | None) -> FloatArray:
    """Score every candidate ``gt[offset + stride * k]`` of ``strides`` (and ``first_frame``).

    One row ``(rot_sq, trans_sq, offset, stride)`` per candidate: ``rot_sq`` sums the
    squared angles (deg^2) between the VO and GT consecutive relative rotations,
    ``trans_sq`` the squared relative translation differences (m^2).
    """
    n = R_wc.shape[0]
    R_vo, t_vo = _relative(np.asarray(R_wc), np.asarray(centers))
    rows = []
    for stride in strides:
        n_off = len(gt) - stride * (n - 1)
        offsets = (np.arange(max(n_off, 0)) if first_frame is None else
                   np.array([first_frame] if first_frame < n_off else [], dtype=np.int64))
        if not offsets.size:
            continue
        # relative motions of every GT frame pair (k, k + stride), then gathered per offset
        R_gt, t_gt = _relative_strided(gt.R_wc, gt.positions_xyz, stride)
        rot_sq = np.zeros(offsets.size)
        trans_sq = np.zeros(offsets.size)
        for j in range(n - 1):
            at = offsets + stride * j
            cos = (np.einsum('kab,ab->k', R_gt[at], R_vo[j]) - 1.0) / 2.0
            rot_sq += np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) ** 2
            trans_sq += np.sum((t_gt[at] - t_vo[j]) ** 2, axis=1)
        rows.append(np.column_stack([rot_sq, trans_sq, offsets, np.full(offsets.size, stride)]))
    return np.concatenate(rows) if rows else np.zeros((0, 4))


def _distinct_ratio(m: int) -> float:
    """Return the factor by which the runner-up's ``rot_sq`` must exceed the best's.

    The best candidate's residual is the VO's and the GT's noise; another candidate is as
    plausible unless its residual is larger than two samples of that noise would differ by
    chance: an F(m, m) test at p = :data:`_LOCATION_P`, one degree of freedom per relative
    motion (not three per rotation: the axes' and consecutive motions' errors correlate).
    """
    from scipy.special import betaincinv

    # F(m, m) exceeds f with probability p where x = f / (1 + f) is Beta(m/2, m/2)'s quantile
    x = float(betaincinv(m / 2, m / 2, 1.0 - _LOCATION_P))
    return x / (1.0 - x)


def find_frame_offset(R_wc: FloatArray, centers: FloatArray, gt: Trajectory,
                      max_stride: int = 3, first_frame: int | None = None,
                      stride: int | None = None) -> tuple[int, int, float, float]:
    """Find which ground-truth frames a VO keyframe sequence is, by relative motions.

    Every candidate ``gt[offset + stride * k]`` is scored by the RMS rotation angle between
    the VO and GT consecutive relative rotations (independent of scale and of the world
    frame), ties broken by the RMS relative translation difference. The best must fit
    clearly better than every other candidate (:func:`_distinct_ratio`): a short or
    straight sequence fits many places about equally well, and the best of those was taken.

    Args:
        R_wc: VO camera -> world rotations, shape (F, 3, 3).
        centers: VO camera centres, shape (F, 3).
        gt: Ground-truth trajectory with at least F poses.
        max_stride: Largest frame stride tried.
        first_frame: Only this offset is tried (None: all).
        stride: Only this stride is tried (None: 1 to ``max_stride``).

    Returns:
        ``(offset, stride, rms_rotation_deg, rms_translation_m)`` of the best candidate.

    Raises:
        FormatError: If there is one VO pose, the ground truth is shorter than the VO
            sequence or has no candidate, or the best candidate is not clearly the best.
    """
    n = R_wc.shape[0]
    if n < 2:
        msg = ('one VO pose cannot be located among the ground-truth frames (that takes '
               'relative motions): give its frame (pmba import-tracks --first-frame N)')
        raise FormatError(msg)
    if len(gt) < n:
        msg = f'ground truth has {len(gt)} poses, fewer than the {n} VO keyframes'
        raise FormatError(msg)
    strides = range(1, max_stride + 1) if stride is None else range(stride, stride + 1)
    scores = _scores(R_wc, centers, gt, strides, first_frame)
    if not scores.shape[0]:
        msg = (f'ground truth has {len(gt)} poses: none holds the {n} VO keyframes from frame '
               f'{first_frame} with stride {list(strides)}')
        raise FormatError(msg)
    ranked = scores[np.lexsort((scores[:, 1], scores[:, 0]))]
    rms = np.sqrt(ranked[:, :2] / (n - 1))
    ratio = _distinct_ratio(n - 1)
    if ranked.shape[0] > 1 and ranked[1, 0] <= ratio * ranked[0, 0]:
        best = ', '.join(f'frames {int(o)}.. stride {int(s)}: {r:.3g} deg'
                         for r, o, s in zip(rms[:3, 0], ranked[:3, 2], ranked[:3, 3],
                                            strict=True))
        give = ('the stride: pmba import-tracks --stride S' if first_frame is not None else
                'the first frame: pmba import-tracks --first-frame N [--stride S]')
        msg = (f'the {n} VO poses cannot be located among the {len(gt)} ground-truth frames: '
               f'several fit about as well (RMS relative-rotation difference {best}; the '
               f"runner-up's squared difference must be {ratio:.3g}x the best's, F test "
               f'p = {_LOCATION_P:g}). Give {give}')
        raise FormatError(msg)
    offset, found_stride = int(ranked[0, 2]), int(ranked[0, 3])
    rot, trans = float(rms[0, 0]), float(rms[0, 1])
    logger.info('VO keyframes = GT frames %d + %d k (rms %.3f deg, %.3f m; runner-up %s deg)',
                offset, found_stride, rot, trans,
                f'{rms[1, 0]:.3f}' if ranked.shape[0] > 1 else 'none')
    return offset, found_stride, rot, trans


@dataclass(frozen=True, eq=False)
class KittiSequence:
    """KITTI tracks with stamps and optional ground truth, in the shape of a ``SimSequence``.

    Attributes:
        stamps_ns: Keyframe stamps, shape (F,), ns.
        R_wc_odom: VO rotations (the front-end poses), shape (F, 3, 3).
        centers_odom: VO centres, shape (F, 3).
        R_wc_gt: Ground-truth rotations, shape (F, 3, 3), or None.
        centers_gt: Ground-truth centres, shape (F, 3), or None.
        frames: Track frames, stamped.
        camera: Camera model.
        points_w: Unused (no world points); shape (0, 3).
        first_frame: KITTI frame of keyframe 0.
        stride: KITTI frames between keyframes.
    """

    stamps_ns: IntArray
    R_wc_odom: FloatArray
    centers_odom: FloatArray
    R_wc_gt: FloatArray | None
    centers_gt: FloatArray | None
    frames: list[TrackFrame]
    camera: CameraModel
    points_w: FloatArray
    first_frame: int
    stride: int


def kitti_sequence(tracks: KittiTracks, times_s: FloatArray | None = None,
                   gt: Trajectory | None = None, first_frame: int | None = None,
                   stride: int | None = None) -> KittiSequence:
    """Stamp KITTI tracks with their frames' times and attach the ground truth.

    Args:
        tracks: Result of :func:`read_kitti_tracks`.
        times_s: KITTI ``times.txt`` values (s), one per KITTI frame; None gives 10 Hz stamps.
        gt: KITTI ground truth (one pose per KITTI frame, e.g. ``read_kitti``), or None.
        first_frame: KITTI frame of keyframe 0; None finds it with :func:`find_frame_offset`
            (needs ``gt``; 0 without it).
        stride: KITTI frames between keyframes; None: found with the offset (1 without gt).

    Returns:
        The stamped sequence; stamps are the KITTI times in ns.

    Raises:
        FormatError: If the times or ground truth do not cover the keyframes, the frames
            cannot be located (:func:`find_frame_offset`), or ``first_frame < 0`` or
            ``stride < 1``.
    """
    n = len(tracks.frames)
    if (first_frame is not None and first_frame < 0) or (stride is not None and stride < 1):
        msg = (f'first_frame must be >= 0 and stride >= 1, got first_frame={first_frame}, '
               f'stride={stride}')
        raise FormatError(msg)
    if first_frame is None or stride is None:
        # one keyframe given its frame has no stride to find
        if gt is not None and (n > 1 or first_frame is None):
            found_first, found_stride, _, _ = find_frame_offset(
                tracks.R_wc, tracks.centers, gt, first_frame=first_frame, stride=stride)
        else:
            found_first, found_stride = 0, 1
        first_frame = found_first if first_frame is None else first_frame
        stride = found_stride if stride is None else stride
    frame_idx = first_frame + stride * np.arange(n)
    if times_s is None:
        stamps_s = frame_idx * 0.1
    else:
        times = np.asarray(times_s, dtype=np.float64).reshape(-1)
        if frame_idx[-1] >= times.shape[0]:
            msg = f'times cover {times.shape[0]} frames, keyframes need {frame_idx[-1] + 1}'
            raise FormatError(msg)
        stamps_s = times[frame_idx]
    stamps_ns = np.round(stamps_s * 1e9).astype(np.int64)
    R_gt = c_gt = None
    if gt is not None:
        if frame_idx[-1] >= len(gt):
            msg = f'ground truth has {len(gt)} poses, keyframes need {frame_idx[-1] + 1}'
            raise FormatError(msg)
        R_gt, c_gt = gt.R_wc[frame_idx], gt.positions_xyz[frame_idx]
    frames = [TrackFrame(int(t), f.frame_id, f.feature_ids, f.camera_ids, f.pixels,
                         f.normalized) for t, f in zip(stamps_ns, tracks.frames, strict=True)]
    return KittiSequence(stamps_ns, tracks.R_wc, tracks.centers, R_gt, c_gt, frames,
                         tracks.camera, np.zeros((0, 3)), int(first_frame), int(stride))


__all__ = [
    'CALIBRATION_FILE',
    'FACTORS_FILE',
    'POSES_FILE',
    'KittiSequence',
    'KittiTracks',
    'find_frame_offset',
    'kitti_sequence',
    'read_kitti_tracks',
    'right_camera',
]
