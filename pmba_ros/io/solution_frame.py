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
mapped onto the model's by a similarity whose rotation best maps the solution's camera
orientations onto the model's, and whose scale and translation then best map its camera
centres (and points, where the centres coincide) onto the model's. So the model is refined in
place and the images and points that were not solved stay consistent with the refined ones.
The orientations fix the rotation whatever the centres' layout: centres on or near a line (a
street, a forward motion) leave the turn about it to their noise. Points that PMBA
leaves at infinity get finite stand-ins far along their rays (the model formats cannot hold
a point at infinity).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from pmba_ros.core import so3
from pmba_ros.core.conversions import far_points, parallax_to_xyz
from pmba_ros.core.problem import ParallaxFeatures
from pmba_ros.eval.align import spread_over_rounding, UmeyamaResult

if TYPE_CHECKING:
    from pmba_ros._typing import FloatArray
    from pmba_ros.core.solve import SolveResult

__all__ = ['FAR_POINT_SPREADS', 'finite_points', 'in_model_frame', 'model_similarity']

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


def model_similarity(R_wc: FloatArray, centers_w: FloatArray, model_R_wc: FloatArray,
                     model_centers_w: FloatArray, with_scale: bool = True,
                     points: tuple[FloatArray, FloatArray] | None = None) -> UmeyamaResult:
    """Return the similarity that takes a solution's poses (R_wc, centres) onto a model's.

    The rotation is the chordal mean of ``model_R_wc[i] R_wc[i]^T``; given it, the scale
    (``with_scale``) and translation are the least-squares fit of the centres, joined by
    ``points`` (solution, model; each (N, 3), finite) where the centres coincide (a panorama).
    """
    rotation = so3.project(np.einsum('nij,nkj->ik', model_R_wc, R_wc))
    x, y = np.asarray(centers_w, dtype=float), np.asarray(model_centers_w, dtype=float)
    xc, yc = x - x.mean(axis=0), y - y.mean(axis=0)
    if points is not None and not (spread_over_rounding(x, xc)
                                   and spread_over_rounding(y, yc)):
        x, y = np.concatenate([x, points[0]]), np.concatenate([y, points[1]])
        xc, yc = x - x.mean(axis=0), y - y.mean(axis=0)
    var = float(np.sum(xc * xc))
    scale = float(np.sum(yc * (xc @ rotation.T))) / var if with_scale and var > 0 else 1.0
    return UmeyamaResult(rotation, y.mean(axis=0) - scale * rotation @ x.mean(axis=0), scale)


def in_model_frame(result: SolveResult, R_wc: FloatArray, centers_w: FloatArray,
                   points_w: FloatArray, with_scale: bool = True, behind: bool = False,
                   ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return a solution's rotations, centres and points in a model's frame.

    Args:
        result: The solve.
        R_wc: The model's rotations (camera -> world) of the solved poses, shape (M, 3, 3).
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
    sim = model_similarity(result.R_wc, result.centers_w, R_wc, centers_w, with_scale,
                           (points[finite], points_w[finite]))
    R_wc = sim.rotation @ result.R_wc
    centers = sim.scale * result.centers_w @ sim.rotation.T + sim.translation
    return R_wc, centers, sim.scale * points @ sim.rotation.T + sim.translation
