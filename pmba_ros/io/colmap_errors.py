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
"""The reprojection errors COLMAP stores with its 3-D points, computed for a model."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from pmba_ros.core.camera import Intrinsics, project
from pmba_ros.io.colmap_cameras import camera_model
from pmba_ros.io.colmap_poses import quat_to_R

if TYPE_CHECKING:
    from pmba_ros._typing import FloatArray
    from pmba_ros.io.colmap import ColmapModel

__all__ = ['track_errors']


def track_errors(model: ColmapModel) -> FloatArray:
    """Return each 3-D point's mean reprojection error (px) over its track, shape (N,).

    As COLMAP computes its points3D ERROR: each observation's distance to the projection of
    the point through its image's pose and camera (distortion included), in the image's raw
    pixels, averaged over the point's observations. A point no image sees keeps its stored
    error. Images are looped over, not observations.
    """
    order = np.argsort(model.point_ids, kind='stable')
    sorted_ids = model.point_ids[order]
    total = np.zeros(model.point_ids.shape[0])
    count = np.zeros(model.point_ids.shape[0])
    for img in model.images.values():
        seen = img.point3d_ids != -1
        if not np.any(seen):
            continue
        at = np.minimum(np.searchsorted(sorted_ids, img.point3d_ids[seen]),
                        sorted_ids.shape[0] - 1)
        known = sorted_ids[at] == img.point3d_ids[seen]   # to_problem names the unknown ones
        rows = order[at[known]]
        h_c = model.xyz[rows] @ quat_to_R(np.asarray(img.qvec)[None])[0].T + np.asarray(img.tvec)
        row, opencv = camera_model(model.cameras[img.camera_id], img.camera_id)
        if opencv is None:
            intr = Intrinsics(*(np.array([v]) for v in row))
            pixels = project(h_c, intr, np.zeros(rows.shape[0], dtype=np.int64))
        else:
            pixels = opencv.denormalize(h_c[:, :2] / h_c[:, 2:3])
        error = np.linalg.norm(pixels - img.xys[seen][known], axis=1)
        np.add.at(total, rows, error)
        np.add.at(count, rows, 1.0)
    return np.where(count > 0, total / np.maximum(count, 1.0), model.error)
