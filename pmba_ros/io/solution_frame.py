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
"""A solution brought onto the frame of the model it refines, ready to be written back.

The solution's frame is a free gauge (and arbitrary after a global initialization): it is
mapped onto the model's by the similarity that best maps its camera centres (and points, if
the centres are collinear) onto the model's, so the model is refined in place and the images
and points that were not solved stay consistent with the refined ones. Points that PMBA
leaves at infinity get finite stand-ins far along their rays (the model formats cannot hold
a point at infinity).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from pmba_ros.core.conversions import far_points, parallax_to_xyz
from pmba_ros.core.problem import ParallaxFeatures
from pmba_ros.errors import DegenerateGeometryError
from pmba_ros.eval.align import umeyama_alignment

if TYPE_CHECKING:
    from pmba_ros._typing import FloatArray
    from pmba_ros.core.solve import SolveResult

__all__ = ['FAR_POINT_SPREADS', 'finite_points', 'in_model_frame']

FAR_POINT_SPREADS = 1e4
"""Distance of a point at infinity's stand-in, in spreads of the camera centres: its rays
then differ from parallel by 1e-4 rad at most."""


def finite_points(result: SolveResult, behind: bool = False) -> FloatArray:
    """Return a solution's points, those at infinity far along their rays, shape (N, 3).

    Where COLMAP and Bundler see them too: :data:`FAR_POINT_SPREADS` spreads of the camera
    centres from their main anchor. With ``behind``, a point whose parallax angle crossed
    zero is at its Euclidean place behind the cameras instead, where a pinhole projection
    (Bundler, BAL) sees it as PMBA's rays do (far along its rays it would not be).
    """
    points = np.array(result.points_w)
    finite = np.all(np.isfinite(points), axis=1)
    if not np.all(finite) and isinstance(result.features, ParallaxFeatures):
        if behind:
            with np.errstate(divide='ignore', invalid='ignore'):
                points[~finite] = parallax_to_xyz(result.R_wc, result.centers_w,
                                                  result.features, behind=True)[~finite]
            finite = np.all(np.isfinite(points), axis=1)
        spread = float(np.sqrt(np.mean(np.sum(
            (result.centers_w - result.centers_w.mean(axis=0)) ** 2, axis=1)))) or 1.0
        points[~finite] = far_points(result.R_wc, result.centers_w, result.features,
                                     FAR_POINT_SPREADS * spread)[~finite]
    return points


def in_model_frame(result: SolveResult, centers_w: FloatArray, points_w: FloatArray,
                   with_scale: bool = True, behind: bool = False,
                   ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return a solution's rotations, centres and points in a model's frame.

    Args:
        result: The solve.
        centers_w: The model's centres of the solved poses, shape (M, 3).
        points_w: The model's points of the solved features, shape (N, 3).
        with_scale: Map by a similarity; False: by a rigid motion (a solution whose scale
            is observed, by a rig's baselines, keeps it).
        behind: Points whose parallax angle crossed zero behind the cameras
            (:func:`finite_points`; a pinhole format), else far along their rays.

    Returns:
        Rotations (M, 3, 3), centres (M, 3) and points (N, 3), every point finite.
    """
    points = finite_points(result, behind)
    finite = np.all(np.isfinite(result.points_w), axis=1)
    try:
        sim = umeyama_alignment(result.centers_w, centers_w, with_scale=with_scale)
    except DegenerateGeometryError:  # cameras on a line (a street) fix no rotation: add points
        sim = umeyama_alignment(np.concatenate([result.centers_w, points[finite]]),
                                np.concatenate([centers_w, points_w[finite]]),
                                with_scale=with_scale)
    R_wc = sim.rotation @ result.R_wc
    centers = sim.scale * result.centers_w @ sim.rotation.T + sim.translation
    return R_wc, centers, sim.scale * points @ sim.rotation.T + sim.translation
