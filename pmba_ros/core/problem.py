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
"""Struct-of-arrays bundle-adjustment problems and the feature states of each parameterization.

Notation (pmba.md §1.1):

==========  ============  ========  =============================================
paper       code          shape     meaning
==========  ============  ========  =============================================
R_i         R_wc[i]       (M,3,3)   camera -> world rotation of pose i
P_i         centers_w[i]  (M,3)     camera centre in the world frame
v_ji        bearings_c    (K,3)     measured unit bearing, camera frame
theta_j     theta         (N,)      parallax angle at the feature (PMBA)
n_j         n             (N,3)     unit ray in the main anchor's frame (PMBA)
m_j, a_j    main_idx,     (N,)      main and associate anchor poses (PMBA)
            assoc_idx
==========  ============  ========  =============================================

A :class:`BAProblem` is immutable: arrays are read-only, and solvers return new arrays.
:func:`make_problem` is the validating constructor: it rejects structural errors (unknown
indices, shapes) with :class:`~pmba_ros.errors.ProblemError` and drops unusable observations
(non-finite values, features seen fewer than twice) with a logged count.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from enum import Enum
import logging

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import sphere
from pmba_ros.core.camera import Intrinsics, pixels_to_bearings
from pmba_ros.errors import ProblemError

logger = logging.getLogger(__name__)


class Parameterization(str, Enum):
    """Feature parameterizations the engine solves (the paper's Table 4 columns)."""

    PMBA = 'pmba'
    XYZ = 'xyz'
    IDP = 'idp'


def finite_rows(x: FloatArray) -> BoolArray:
    """Return the rows of ``x`` (K, C) whose every value is finite, shape (K,).

    ``np.all(np.isfinite(x), axis=1)``, without numpy's slow reduction of a short axis.
    """
    out: BoolArray = np.isfinite(x[:, 0]) if x.shape[1] else np.ones(x.shape[0], dtype=bool)
    for c in range(1, x.shape[1]):
        out &= np.isfinite(x[:, c])
    return out


def _readonly(arr: np.ndarray) -> np.ndarray:
    arr = np.ascontiguousarray(arr)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class Observations:
    """Observations in struct-of-arrays form; K = number of observations.

    Attributes:
        cam_idx: Observing pose index, shape (K,).
        feat_idx: Feature index, shape (K,).
        bearings_c: Measured unit bearings in the camera frame, shape (K, 3).
        pixels: Measured pixels (distorted, as recorded), shape (K, 2).
        camera: Rig camera of each observation, shape (K,), or None: every bearing is in
            its pose's own frame (see :class:`Rig`).
        pixel_jac: d(pixel) / d(bearing) of the camera that measured each observation, at
            its bearing, shape (K, 2, 3), or None: the pinhole of the problem's intrinsics.
            A camera whose pixels relate to rays otherwise (a fisheye lens) weighs its
            errors by its own.
    """

    cam_idx: IntArray
    feat_idx: IntArray
    bearings_c: FloatArray
    pixels: FloatArray
    camera: IntArray | None = None
    pixel_jac: FloatArray | None = None

    def __len__(self) -> int:
        """Return the number of observations."""
        return int(self.cam_idx.shape[0])

    def take(self, index: np.ndarray) -> Observations:
        """Return the subset of observations selected by ``index``."""
        return Observations(self.cam_idx[index], self.feat_idx[index],
                            self.bearings_c[index], self.pixels[index],
                            None if self.camera is None else self.camera[index],
                            None if self.pixel_jac is None else self.pixel_jac[index])

    def reindexed(self, feat_idx: IntArray) -> Observations:
        """Return the observations with other feature indices (read-only arrays)."""
        return Observations(_readonly(self.cam_idx), _readonly(feat_idx),
                            _readonly(self.bearings_c), _readonly(self.pixels),
                            None if self.camera is None else _readonly(self.camera),
                            None if self.pixel_jac is None else _readonly(self.pixel_jac))


@dataclass(frozen=True, eq=False)
class Rig:
    """Cameras rigidly mounted on each pose (a stereo pair, a multi-camera rig).

    A pose (R_wc, centers_w) is the pose of the rig frame; rig camera c sits at
    ``x_rig = R_rc[c] x_c + t_rc[c]``, so its world pose is ``R_wc R_rc[c]`` with centre
    ``centers_w + R_wc t_rc[c]``. Observations name their camera in
    :attr:`Observations.camera`; the poses stay the only pose variables, so the baseline
    between the cameras fixes the scale.

    Attributes:
        R_rc: Camera -> rig rotations, shape (C, 3, 3).
        t_rc: Camera centres in the rig frame, shape (C, 3), m.
    """

    R_rc: FloatArray
    t_rc: FloatArray

    def __post_init__(self) -> None:
        """Validate shapes and values (read-only copies)."""
        R = np.array(self.R_rc, dtype=float)
        t = np.array(self.t_rc, dtype=float)
        C = R.shape[0] if R.ndim == 3 else -1
        if C < 1 or R.shape != (C, 3, 3) or t.shape != (C, 3):
            msg = f'rig: expected R_rc (C,3,3) and t_rc (C,3), got {R.shape}, {t.shape}'
            raise ProblemError(msg)
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            msg = 'rig: non-finite camera offsets'
            raise ProblemError(msg)
        if not np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-6):
            msg = 'rig: R_rc are not rotations'
            raise ProblemError(msg)
        object.__setattr__(self, 'R_rc', _readonly(R))
        object.__setattr__(self, 't_rc', _readonly(t))

    def __len__(self) -> int:
        """Return the number of cameras C."""
        return int(self.R_rc.shape[0])

    def in_rig_frame(self) -> BoolArray:
        """Return which cameras are the rig frame itself (identity offset), shape (C,)."""
        same: BoolArray = (np.all(np.abs(self.R_rc - np.eye(3)) <= 1e-12, axis=(1, 2))
                           & np.all(np.abs(self.t_rc) <= 1e-12, axis=1))
        return same


@dataclass(frozen=True, eq=False)
class BAProblem:
    """A bundle-adjustment problem: poses, intrinsics, observations and optional points.

    Attributes:
        R_wc: Camera -> world rotations, shape (M, 3, 3).
        centers_w: Camera centres in the world frame, shape (M, 3).
        intrinsics: Per-camera intrinsics (M cameras).
        obs: Observations, sorted by feature then camera.
        n_feats: Number of features N (every feature has >= 2 observations).
        points_w: Initial 3-D points (N, 3) or None (e.g. before global initialization).
        fixed: Poses held constant, shape (M,) bool.
        feature_ids: Caller's id of each feature, shape (N,).
        dropped: Counts of inputs dropped while building the problem, by reason.
        rig: The cameras of each pose, or None (one camera: the pose is the camera).
    """

    R_wc: FloatArray
    centers_w: FloatArray
    intrinsics: Intrinsics
    obs: Observations
    n_feats: int
    points_w: FloatArray | None
    fixed: BoolArray
    feature_ids: IntArray
    dropped: dict[str, int] = field(default_factory=dict)
    rig: Rig | None = None

    @property
    def n_cams(self) -> int:
        """Return the number of poses M."""
        return int(self.R_wc.shape[0])

    @property
    def n_obs(self) -> int:
        """Return the number of observations K."""
        return len(self.obs)

    def with_poses(self, R_wc: FloatArray, centers_w: FloatArray) -> BAProblem:
        """Return a copy with other poses (validated shapes, read-only)."""
        if R_wc.shape != self.R_wc.shape or centers_w.shape != self.centers_w.shape:
            msg = 'with_poses: pose arrays must keep their shapes'
            raise ProblemError(msg)
        return replace(self, R_wc=_readonly(np.array(R_wc, dtype=float)),
                       centers_w=_readonly(np.array(centers_w, dtype=float)))

    def with_points(self, points_w: FloatArray | None) -> BAProblem:
        """Return a copy with other initial points (or none)."""
        if points_w is not None and points_w.shape != (self.n_feats, 3):
            msg = f'with_points: expected shape ({self.n_feats}, 3), got {points_w.shape}'
            raise ProblemError(msg)
        pts = None if points_w is None else _readonly(np.array(points_w, dtype=float))
        return replace(self, points_w=pts)

    def feature_offsets(self) -> IntArray:
        """Return CSR offsets (N+1,) of each feature's observations (obs are sorted by feature)."""
        counts = np.bincount(self.obs.feat_idx, minlength=self.n_feats)
        return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


def make_problem(R_wc: FloatArray, centers_w: FloatArray, intrinsics: Intrinsics,
                 cam_idx: np.ndarray, feat_idx: np.ndarray, pixels: FloatArray, *,
                 bearings_c: FloatArray | None = None, points_w: FloatArray | None = None,
                 fixed: np.ndarray | None = None, n_feats: int | None = None,
                 feature_ids: np.ndarray | None = None, camera: np.ndarray | None = None,
                 rig: Rig | None = None, pixel_jac: FloatArray | None = None) -> BAProblem:
    """Validate inputs and build a :class:`BAProblem`.

    Args:
        R_wc: Camera -> world rotations, shape (M, 3, 3).
        centers_w: Camera centres, shape (M, 3).
        intrinsics: Intrinsics of the M cameras.
        cam_idx: Observing camera of each observation, shape (K,), values in [0, M).
        feat_idx: Observed feature of each observation, shape (K,), values in [0, N).
        pixels: Measured pixels, shape (K, 2).
        bearings_c: Unit bearings (K, 3); computed from pixels and intrinsics if None.
        points_w: Optional initial 3-D points, shape (N, 3).
        fixed: Optional fixed-pose flags, shape (M,).
        n_feats: Number of features N (default: max(feat_idx) + 1).
        feature_ids: Caller's ids of the N features (default: 0..N-1).
        camera: Rig camera of each observation (K,), values in [0, len(rig)); with ``rig``.
        rig: The cameras mounted on each pose (``bearings_c`` are then in each
            observation's rig camera frame).
        pixel_jac: d(pixel) / d(bearing) of each observation's camera at its bearing
            (K, 2, 3) (see :class:`Observations`); None: the intrinsics' pinhole.

    Returns:
        The problem; observations with non-finite values, duplicate (pose, rig camera,
        feature) triples and features with fewer than two observing poses are dropped and
        counted in ``dropped``.

    Raises:
        ProblemError: On wrong shapes, non-finite poses or unknown camera / feature indices.
    """
    R_wc = np.asarray(R_wc, dtype=float)
    centers_w = np.asarray(centers_w, dtype=float)
    M = R_wc.shape[0] if R_wc.ndim == 3 else -1
    if R_wc.shape != (M, 3, 3) or centers_w.shape != (M, 3) or M < 1:
        msg = (f'poses: expected R_wc (M,3,3) and centers_w (M,3), got {R_wc.shape}, '
               f'{centers_w.shape}')
        raise ProblemError(msg)
    if not (np.isfinite(R_wc).all() and np.isfinite(centers_w).all()):
        finite = np.isfinite(R_wc).all(axis=(1, 2)) & np.isfinite(centers_w).all(axis=1)
        bad = np.flatnonzero(~finite)
        msg = f'poses: non-finite values in pose(s) {bad[:10].tolist()}'
        raise ProblemError(msg)
    if len(intrinsics) != M:
        msg = f'intrinsics: {len(intrinsics)} cameras for {M} poses'
        raise ProblemError(msg)
    cam_idx = np.asarray(cam_idx)
    feat_idx = np.asarray(feat_idx)
    pixels = np.asarray(pixels, dtype=float)
    K = cam_idx.shape[0]
    if cam_idx.shape != (K,) or feat_idx.shape != (K,) or pixels.shape != (K, 2):
        msg = (f'observations: expected cam_idx (K,), feat_idx (K,), pixels (K,2); got '
               f'{cam_idx.shape}, {feat_idx.shape}, {pixels.shape}')
        raise ProblemError(msg)
    integer = (np.issubdtype(cam_idx.dtype, np.integer)
               and np.issubdtype(feat_idx.dtype, np.integer))
    if K and not integer:
        msg = 'observations: cam_idx and feat_idx must be integer arrays'
        raise ProblemError(msg)
    cam_idx = cam_idx.astype(np.int64)
    feat_idx = feat_idx.astype(np.int64)
    N = int(feat_idx.max()) + 1 if n_feats is None and K else int(n_feats or 0)
    bad_cam = (cam_idx < 0) | (cam_idx >= M)
    if bad_cam.any():
        k = int(np.flatnonzero(bad_cam)[0])
        msg = f'observation {k}: unknown camera index {int(cam_idx[k])} (problem has {M} cameras)'
        raise ProblemError(msg)
    bad_feat = (feat_idx < 0) | (feat_idx >= N)
    if bad_feat.any():
        k = int(np.flatnonzero(bad_feat)[0])
        msg = (f'observation {k}: unknown feature index {int(feat_idx[k])} '
               f'(problem has {N} features)')
        raise ProblemError(msg)
    if points_w is not None:
        points_w = np.asarray(points_w, dtype=float)
        if points_w.shape != (N, 3):
            msg = f'points_w: expected shape ({N}, 3), got {points_w.shape}'
            raise ProblemError(msg)
    if bearings_c is None:
        finite_px = finite_rows(pixels)
        safe_px = np.where(finite_px[:, None], pixels, 0.0)
        bearings_c = pixels_to_bearings(safe_px, intrinsics, cam_idx)
        bearings_c[~finite_px] = np.nan
    else:
        bearings_c = np.asarray(bearings_c, dtype=float)
        if bearings_c.shape != (K, 3):
            msg = f'bearings_c: expected shape ({K}, 3), got {bearings_c.shape}'
            raise ProblemError(msg)
        norms = sphere.norms(bearings_c)[:, None]
        bearings_c = bearings_c / np.where(norms > 0, norms, np.nan)

    rig_cam = _rig_cameras(camera, rig, K)
    if pixel_jac is not None:
        pixel_jac = np.asarray(pixel_jac, dtype=float)
        if pixel_jac.shape != (K, 2, 3):
            msg = f'pixel_jac: expected shape ({K}, 2, 3), got {pixel_jac.shape}'
            raise ProblemError(msg)
    dropped: dict[str, int] = {}
    keep = finite_rows(bearings_c)
    if pixel_jac is not None:
        keep &= np.all(np.isfinite(pixel_jac), axis=(1, 2))
    n_finite = int(np.count_nonzero(keep))
    _count(dropped, 'non_finite_observations', K - n_finite)

    n_rig = len(rig) if rig else 1
    order = _feature_camera_order(feat_idx, cam_idx, rig_cam, N, M, n_rig)
    if order is None and n_finite == K:
        # In order, keys strictly increasing: no duplicates, and a pose observes a feature
        # twice only through two rig cameras. Features need two observing poses (an
        # associate anchor with a baseline), pmba.md §3.3.
        observer = feat_idx
        if n_rig > 1:
            observer = feat_idx[np.concatenate([[True], (feat_idx[1:] != feat_idx[:-1])
                                                | (cam_idx[1:] != cam_idx[:-1])])]
        counts = np.bincount(observer, minlength=N)
        order = np.arange(K)
    else:
        order = np.arange(K) if order is None else order
        # Duplicate (pose, rig camera, feature) observations are inconsistent tracks: keep
        # the first.
        order = order[keep[order]]
        f_sorted, c_sorted, r_sorted = feat_idx[order], cam_idx[order], rig_cam[order]
        same_pose = np.zeros(order.shape[0], dtype=bool)
        same_pose[1:] = (f_sorted[1:] == f_sorted[:-1]) & (c_sorted[1:] == c_sorted[:-1])
        dup = same_pose.copy()
        dup[1:] &= r_sorted[1:] == r_sorted[:-1]
        _count(dropped, 'duplicate_observations', int(np.count_nonzero(dup)))
        order, same_pose = order[~dup], same_pose[~dup]
        counts = np.bincount(feat_idx[order[~same_pose]], minlength=N)   # as above
    feat_ok = counts >= 2
    _count(dropped, 'single_observation_features', int(np.count_nonzero(counts == 1)))
    _count(dropped, 'unobserved_features', int(np.count_nonzero(counts == 0)))
    if points_w is not None:
        finite_pt = finite_rows(points_w)
        _count(dropped, 'non_finite_points', int(np.count_nonzero(feat_ok & ~finite_pt)))
        feat_ok &= finite_pt
    n_before = order.shape[0]
    order = order[feat_ok[feat_idx[order]]]
    _count(dropped, 'observations_of_dropped_features', n_before - order.shape[0])
    new_index = np.cumsum(feat_ok) - 1
    ids = np.arange(N) if feature_ids is None else np.asarray(feature_ids)
    if ids.shape != (N,):
        msg = f'feature_ids: expected shape ({N},), got {ids.shape}'
        raise ProblemError(msg)
    for reason, count in dropped.items():
        logger.info('make_problem: dropped %d (%s)', count, reason)
    if fixed is None:
        fixed_arr = np.zeros(M, dtype=bool)
    else:
        fixed_arr = np.asarray(fixed, dtype=bool)
        if fixed_arr.shape != (M,):
            msg = f'fixed: expected shape ({M},), got {fixed_arr.shape}'
            raise ProblemError(msg)
    # np.take: the rows fancy indexing would copy, for less.
    obs = Observations(_readonly(cam_idx[order]), _readonly(new_index[feat_idx[order]]),
                       _readonly(np.take(bearings_c, order, axis=0)),
                       _readonly(np.take(pixels, order, axis=0)),
                       None if rig is None else _readonly(rig_cam[order]),
                       None if pixel_jac is None else _readonly(np.take(pixel_jac, order, axis=0)))
    pts = None if points_w is None else _readonly(points_w[feat_ok])
    return BAProblem(_readonly(R_wc.copy()), _readonly(centers_w.copy()), intrinsics, obs,
                     int(np.count_nonzero(feat_ok)), pts, _readonly(fixed_arr.copy()),
                     _readonly(ids[feat_ok].astype(np.int64)),
                     {k: v for k, v in dropped.items() if v}, rig)


def _rig_cameras(camera: np.ndarray | None, rig: Rig | None, K: int) -> IntArray:
    """Return the validated rig camera of each observation (zeros without a rig)."""
    if rig is None:
        if camera is not None:
            msg = 'observations name rig cameras but the problem has no rig'
            raise ProblemError(msg)
        return np.zeros(K, dtype=np.int64)
    if camera is None:
        return np.zeros(K, dtype=np.int64)
    cam = np.asarray(camera)
    if cam.shape != (K,) or (K and not np.issubdtype(cam.dtype, np.integer)):
        msg = f'camera: expected an integer array of shape ({K},), got {cam.shape} {cam.dtype}'
        raise ProblemError(msg)
    bad = (cam < 0) | (cam >= len(rig))
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        msg = f'observation {k}: unknown rig camera {int(cam[k])} (rig has {len(rig)} cameras)'
        raise ProblemError(msg)
    return cam.astype(np.int64)


def _feature_camera_order(feat_idx: IntArray, cam_idx: IntArray, rig_cam: IntArray,
                          n_feats: int, n_cams: int, n_rig: int) -> IntArray | None:
    """Return the stable order of observations by feature, pose, then rig camera.

    The three (validated) indices make one integer key where it cannot overflow; input
    already in that order (as the back-end builds it) then needs no sort at all: None, for
    keys strictly increasing (no two observations share all three).
    """
    K = feat_idx.shape[0]
    if n_feats * n_cams * n_rig >= 2 ** 62:
        return np.lexsort((np.arange(K), rig_cam, cam_idx, feat_idx))
    key = (feat_idx * n_cams + cam_idx) * n_rig + rig_cam
    if (key[1:] > key[:-1]).all():
        return None
    return np.argsort(key, kind='stable')


def _count(dropped: dict[str, int], reason: str, count: int) -> None:
    if count:
        dropped[reason] = dropped.get(reason, 0) + count


@dataclass(frozen=True, eq=False)
class ParallaxFeatures:
    """PMBA features F_j = (theta_j, n_j) with their anchors (pmba.md §1.1).

    Attributes:
        theta: Parallax angle at the feature, radians, shape (N,).
        n: Unit ray from the main anchor to the feature, in its camera frame, shape (N, 3).
        main_idx: Main anchor pose m_j, shape (N,).
        assoc_idx: Associate anchor pose a_j, shape (N,).
    """

    theta: FloatArray
    n: FloatArray
    main_idx: IntArray
    assoc_idx: IntArray


@dataclass(frozen=True, eq=False)
class XyzFeatures:
    """Euclidean points in the world frame, shape (N, 3)."""

    points_w: FloatArray


@dataclass(frozen=True, eq=False)
class IdpFeatures:
    """Inverse-depth points X = P_h + R_h [a, b, 1]^T / rho anchored at pose h.

    Attributes:
        anchor_idx: Anchor pose h (the first observing camera), shape (N,).
        ab: Normalized image coordinates of the ray in the anchor frame, shape (N, 2).
        rho: Inverse depth along [a, b, 1], shape (N,) (0 is a point at infinity).
    """

    anchor_idx: IntArray
    ab: FloatArray
    rho: FloatArray


Features = ParallaxFeatures | XyzFeatures | IdpFeatures


def subset_features(problem: BAProblem, keep: BoolArray, reason: str) -> BAProblem:
    """Return the problem without the features where ``keep`` is False (counted under reason).

    Args:
        problem: The problem.
        keep: Features to keep, shape (N,).
        reason: Key under which the dropped features are counted in ``dropped``.

    Returns:
        A new problem with features re-indexed densely (``feature_ids`` keeps the caller's ids).
    """
    keep = np.asarray(keep, dtype=bool)
    if keep.shape != (problem.n_feats,):
        msg = f'subset_features: expected mask of shape ({problem.n_feats},), got {keep.shape}'
        raise ProblemError(msg)
    if np.all(keep):
        return problem
    dropped = dict(problem.dropped)
    _count(dropped, reason, int(np.sum(~keep)))
    logger.info('dropped %d features (%s)', int(np.sum(~keep)), reason)
    return replace(restrict_features(problem, keep), dropped=dropped)


def restrict_features(problem: BAProblem, keep: BoolArray) -> BAProblem:
    """Return the problem of the features where ``keep`` (N,) is True, nothing counted."""
    new_index = np.cumsum(keep) - 1
    obs = problem.obs.take(keep[problem.obs.feat_idx])
    obs = obs.reindexed(new_index[obs.feat_idx])
    pts = None if problem.points_w is None else _readonly(problem.points_w[keep])
    return replace(problem, obs=obs, n_feats=int(np.sum(keep)), points_w=pts,
                   feature_ids=_readonly(problem.feature_ids[keep]))


def permute_features(problem: BAProblem, order: IntArray) -> BAProblem:
    """Return the problem with feature ``order[j]`` renumbered j (observations re-sorted).

    Args:
        problem: The problem.
        order: A permutation of the N features: new index -> old index.
    """
    # Observations are sorted by feature then camera, so each feature's run moves as a block.
    counts = np.bincount(problem.obs.feat_idx, minlength=problem.n_feats)
    by_feature, new_counts = run_order(counts, order)
    obs = problem.obs.take(by_feature).reindexed(
        np.repeat(np.arange(problem.n_feats), new_counts))
    pts = None if problem.points_w is None else _readonly(problem.points_w[order])
    return replace(problem, obs=obs, points_w=pts,
                   feature_ids=_readonly(problem.feature_ids[order]))


def run_order(counts: IntArray, order: IntArray) -> tuple[IntArray, IntArray]:
    """Return how to reorder consecutive runs of elements, run ``order[j]`` becoming run j.

    Args:
        counts: Length of each run, shape (R,) (the runs fill the array in turn).
        order: A permutation of the runs: new index -> old index.

    Returns:
        The old position of each element in the new order, shape (sum(counts),), and the
        new runs' lengths ``counts[order]``.
    """
    old_start = np.cumsum(counts) - counts
    new_counts = counts[order]
    new_start = np.cumsum(new_counts) - new_counts
    index = np.repeat(old_start[order] - new_start, new_counts) + np.arange(int(counts.sum()))
    return index, new_counts


def take_features(feats: Features, index: IntArray) -> Features:
    """Return the features selected (or permuted) by ``index`` (every field is per feature)."""
    columns = {f.name: np.asarray(getattr(feats, f.name))[index] for f in fields(feats)}
    return type(feats)(**columns)


def join_features(first: Features, then: Features) -> Features:
    """Return the features of ``first`` followed by those of ``then`` (of the same type)."""
    columns = {f.name: np.concatenate([getattr(first, f.name), getattr(then, f.name)])
               for f in fields(first)}
    return type(first)(**columns)
