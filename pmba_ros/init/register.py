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
"""Registering the cameras the view graph left out: PnP on the triangulated tracks.

A camera that shares too few tracks with any other for an essential matrix stays out of the
view graph's largest component and gets no rotation from the averaging. Once the component's
positions are known, its tracks can be triangulated; a left-out camera that sees enough of
those points is placed by PnP with RANSAC, as incremental SfM registers an image, and every
camera placed adds points for the next round. The BA then refines all cameras together.
"""

from __future__ import annotations

from dataclasses import dataclass
import logging

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.problem import BAProblem
from pmba_ros.init import tracks, two_view

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Registration:
    """Cameras with a pose after registering the left-out ones.

    Attributes:
        cameras: Cameras with a pose (the component's and the registered ones), shape (M,).
        R_wc: Camera -> world rotations, valid where ``cameras``, shape (M, 3, 3).
        centers_w: Camera centres, valid where ``cameras``, shape (M, 3).
        registered: The registered cameras, in the order they were placed.
    """

    cameras: BoolArray
    R_wc: FloatArray
    centers_w: FloatArray
    registered: IntArray


def register_cameras(problem: BAProblem, cameras: BoolArray, R_wc: FloatArray,
                     centers_w: FloatArray, *, min_points: int, max_px: float,
                     ) -> Registration:
    """Place the cameras outside ``cameras`` by PnP on the points of the placed ones.

    Args:
        problem: Observations of every camera (M cameras).
        cameras: The placed cameras, shape (M,).
        R_wc: Their rotations (rows of other cameras are ignored), shape (M, 3, 3).
        centers_w: Their centres, shape (M, 3).
        min_points: Inliers a camera needs (at least 6, the points a pose needs with room
            for a wrong match or two).
        max_px: Largest reprojection error of an inlier (px, divided by the camera's focal
            length for the normalized image plane).

    Returns:
        The cameras placed, and the poses.
    """
    placed = cameras.copy()
    R = np.array(R_wc, dtype=np.float64)
    C = np.array(centers_w, dtype=np.float64)
    obs = problem.obs
    focal = np.sqrt(problem.intrinsics.fx * problem.intrinsics.fy)
    registered: list[int] = []
    need = max(int(min_points), 6)
    while True:
        X = tracks.midpoints(problem, R, C, obs_mask=placed[obs.cam_idx])
        seen = np.all(np.isfinite(X[obs.feat_idx]), axis=1) & (obs.bearings_c[:, 2] > 1e-6)
        counts = np.bincount(obs.cam_idx[seen & ~placed[obs.cam_idx]],
                             minlength=problem.n_cams)
        new = []
        for c in np.flatnonzero(~placed & (counts >= need)):  # one PnP per camera
            sel = seen & (obs.cam_idx == c)
            pose = _pnp(X[obs.feat_idx[sel]], obs.bearings_c[sel], max_px / focal[c], need)
            if pose is not None:
                R[c], C[c] = pose
                new.append(int(c))
        if not new:
            break
        placed[new] = True
        registered.extend(new)
    if registered:
        logger.info('global_init: registered left-out cameras %s by PnP', registered)
    return Registration(placed, R, C, np.asarray(registered, dtype=np.int64))


def _pnp(points_w: FloatArray, bearings_c: FloatArray, max_err: float, need: int,
         ) -> tuple[FloatArray, FloatArray] | None:
    """Return (R_wc, C) from 3-D points and their bearings, or None without enough inliers."""
    cv2 = two_view.cv2  # type: ignore[attr-defined]
    image = np.ascontiguousarray(bearings_c[:, :2] / bearings_c[:, 2:3])
    world = np.ascontiguousarray(points_w)
    try:
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            world, image, np.eye(3), None, reprojectionError=float(max_err),
            confidence=0.999, iterationsCount=1000, flags=cv2.SOLVEPNP_SQPNP)
    except cv2.error:
        return None
    # Half the points at least: a pose that explains few of its points is a wrong one.
    if not ok or inliers is None or inliers.shape[0] < max(need, 0.5 * image.shape[0]):
        return None
    idx = inliers[:, 0]
    rvec, tvec = cv2.solvePnPRefineLM(world[idx], image[idx], np.eye(3), None, rvec, tvec)
    R_cw = cv2.Rodrigues(rvec)[0]
    R_wc = R_cw.T
    center = -R_wc @ tvec[:, 0]
    depth = (world[idx] - center) @ R_wc[:, 2]
    if np.count_nonzero(depth > 0) < 0.9 * idx.shape[0]:  # cheirality
        return None
    return np.asarray(R_wc, dtype=np.float64), np.asarray(center, dtype=np.float64)
