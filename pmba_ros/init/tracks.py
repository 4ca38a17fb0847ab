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
"""Track consistency once rotations and positions are known: wrong tracks found before the BA.

A track is checked by triangulating it from its observers (midpoint of the rays, one batched
3x3 solve per feature) and measuring each observation's angle to the triangulated point,
in pixels of its camera's focal length. A track whose rays are nearly parallel is also
measured against the point at infinity in the mean ray's direction, and keeps the smaller of
the two (a far feature is not an outlier because its midpoint falls behind a camera).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.problem import BAProblem


@dataclass(frozen=True, eq=False)
class TrackCheck:
    """Per-feature consistency of the tracks of a problem.

    Attributes:
        rms_px: RMS over the track's observations of the angle to the triangulated point (or
            to the point at infinity), in pixels, shape (N,).
        threshold_px: The rejection threshold that was applied.
        inconsistent: Tracks above the threshold, shape (N,).
    """

    rms_px: FloatArray
    threshold_px: float
    inconsistent: BoolArray


def midpoints(problem: BAProblem, R_wc: FloatArray, centers_w: FloatArray,
              obs_mask: BoolArray | None = None) -> FloatArray:
    """Return each feature's point closest to all its rays (least squares), shape (N, 3).

    Solves sum_k (I - r_k r_k^T)(X - C_k) = 0 per feature; nearly parallel rays give a far
    (possibly behind-the-camera) point, not a failure. With ``obs_mask`` only those
    observations are used, and features left with fewer than two get NaN.
    """
    obs = problem.obs
    use = np.ones(problem.n_obs, dtype=bool) if obs_mask is None else obs_mask
    j = obs.feat_idx[use]
    cam = obs.cam_idx[use]
    N = problem.n_feats
    rays = np.einsum('kij,kj->ki', R_wc[cam], obs.bearings_c[use])
    proj = np.eye(3)[None] - rays[:, :, None] * rays[:, None, :]
    A = np.zeros((N, 3, 3))
    b = np.zeros((N, 3))
    np.add.at(A, j, proj)
    np.add.at(b, j, np.einsum('kij,kj->ki', proj, centers_w[cam]))
    scale = np.trace(A, axis1=1, axis2=2)
    A += (1e-12 * np.maximum(scale, 1e-300))[:, None, None] * np.eye(3)[None]
    X = np.asarray(np.linalg.solve(A, b[..., None])[..., 0], dtype=np.float64)
    X[np.bincount(j, minlength=N) < 2] = np.nan
    return X


def track_residuals_px(problem: BAProblem, R_wc: FloatArray, centers_w: FloatArray,
                       ) -> FloatArray:
    """Return each feature's RMS angular residual (px) to its best point, shape (N,).

    Args:
        problem: Observations (sorted by feature) and intrinsics.
        R_wc: Rotations (M, 3, 3).
        centers_w: Camera centres (M, 3).
    """
    obs = problem.obs
    j = obs.feat_idx
    N = problem.n_feats
    rays = np.einsum('kij,kj->ki', R_wc[obs.cam_idx], obs.bearings_c)
    C = centers_w[obs.cam_idx]
    X = midpoints(problem, R_wc, centers_w)
    d = X[j] - C
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    ang_point = np.arccos(np.clip(np.sum(d * rays, axis=1), -1.0, 1.0))
    mean_ray = np.zeros((N, 3))
    np.add.at(mean_ray, j, rays)
    mean_ray /= np.maximum(np.linalg.norm(mean_ray, axis=1, keepdims=True), 1e-300)
    ang_inf = np.arccos(np.clip(np.sum(mean_ray[j] * rays, axis=1), -1.0, 1.0))
    focal = np.sqrt(problem.intrinsics.fx * problem.intrinsics.fy)[obs.cam_idx]
    sq_point = np.bincount(j, (focal * ang_point) ** 2, minlength=N)
    sq_inf = np.bincount(j, (focal * ang_inf) ** 2, minlength=N)
    counts = np.maximum(np.bincount(j, minlength=N), 1)
    return np.sqrt(np.minimum(sq_point, sq_inf) / counts)


def check_tracks(problem: BAProblem, R_wc: FloatArray, centers_w: FloatArray, *,
                 min_px: float, relative: float) -> TrackCheck:
    """Flag tracks whose residual exceeds max(min_px, relative * median residual).

    The median adapts the threshold to how good the rotations and positions are (a few px on
    sequential sets, tens of px on narrow-field photo collections), while random wrong
    matches sit at a sizeable fraction of the field of view.
    """
    rms = track_residuals_px(problem, R_wc, centers_w)
    threshold = max(min_px, relative * float(np.median(rms))) if rms.size else min_px
    return TrackCheck(rms, threshold, rms > threshold)


def camera_residuals_px(problem: BAProblem, R_wc: FloatArray, centers_w: FloatArray,
                        points_w: FloatArray) -> FloatArray:
    """Return each camera's upper-quartile angle (px) between its rays and the points, (M,).

    The upper quartile, not the median: a camera misplaced along its optical axis (forward
    motion, a street) turns the rays of its near and off-centre points only, fewer than half
    of them when most of what it sees is far. Also counts observations behind the camera
    (negative depth) as half a turn, so that a camera placed on the wrong side of its
    points stands out.
    """
    obs = problem.obs
    rays = np.einsum('kij,kj->ki', R_wc[obs.cam_idx], obs.bearings_c)
    d = points_w[obs.feat_idx] - centers_w[obs.cam_idx]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    ang = np.arccos(np.clip(np.sum(d * rays, axis=1), -1.0, 1.0))
    px = ang * np.sqrt(problem.intrinsics.fx * problem.intrinsics.fy)[obs.cam_idx]
    out = np.zeros(problem.n_cams)
    order = np.argsort(obs.cam_idx, kind='stable')
    bounds = np.searchsorted(obs.cam_idx[order], np.arange(problem.n_cams + 1))
    for k in range(problem.n_cams):  # one quartile per camera, not per observation
        sel = px[order[bounds[k]:bounds[k + 1]]]
        out[k] = float(np.percentile(sel, 75.0)) if sel.size else 0.0
    return out


def resect_centers(problem: BAProblem, R_wc: FloatArray, points_w: FloatArray,
                   cameras: IntArray) -> FloatArray:
    """Return the centres (len(cameras), 3) that best fit the points with rotations known.

    Each observation asks the centre to lie on the line through its point along its ray:
    sum_k (I - r_k r_k^T)(C - X_k) = 0 is linear in C (one 3x3 solve per camera). Points
    that are not finite are skipped.
    """
    obs = problem.obs
    ok = np.isin(obs.cam_idx, cameras) & np.all(np.isfinite(points_w[obs.feat_idx]), axis=1)
    cam = np.searchsorted(cameras, obs.cam_idx[ok])
    rays = np.einsum('kij,kj->ki', R_wc[obs.cam_idx[ok]], obs.bearings_c[ok])
    proj = np.eye(3)[None] - rays[:, :, None] * rays[:, None, :]
    A = np.zeros((cameras.shape[0], 3, 3))
    b = np.zeros((cameras.shape[0], 3))
    np.add.at(A, cam, proj)
    np.add.at(b, cam, np.einsum('kij,kj->ki', proj, points_w[obs.feat_idx[ok]]))
    return np.asarray(np.linalg.solve(A, b[..., None])[..., 0], dtype=np.float64)
