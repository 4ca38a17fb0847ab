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
"""COLMAP camera models as this package's intrinsics, or through an OpenCV camera model.

The pinhole and radial models are rows of :class:`~pmba_ros.core.camera.Intrinsics` (see
:mod:`pmba_ros.io.colmap`). The models beyond radial distortion are read through the OpenCV
camera models of :class:`~pmba_ros.backend.types.CameraModel`: OPENCV with tangential terms
and FULL_OPENCV without its rational terms (k4 = k5 = k6 = 0) as ``plumb_bob``,
OPENCV_FISHEYE, SIMPLE_RADIAL_FISHEYE and RADIAL_FISHEYE as ``equidistant`` (COLMAP's fisheye
models distort the angle from the axis as OpenCV's do). Their observations are undistorted to
the pinhole of their intrinsics (the cameras are not refined), and each error is weighed by
its camera's own pixels (``pixel_jac``), so the solve minimizes the reprojection error
COLMAP reports; an observation that does not undistort (a fisheye ray beyond 90 degrees) is
dropped. The XYZ and IDP peers of ``pmba solve --compare`` measure their errors in the
undistorted pixels.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np
from pmba_ros.backend.types import CameraModel
from pmba_ros.core.camera import Intrinsics, pixels_to_bearings, projection_jacobian
from pmba_ros.errors import FormatError, MessageError

if TYPE_CHECKING:
    from pmba_ros._typing import FloatArray, IntArray
    from pmba_ros.io.colmap import ColmapCamera

__all__ = ['SUPPORTED', 'camera_model', 'through_pinhole']

SUPPORTED = ('SIMPLE_PINHOLE', 'PINHOLE', 'SIMPLE_RADIAL', 'RADIAL', 'OPENCV', 'FULL_OPENCV',
             'OPENCV_FISHEYE', 'SIMPLE_RADIAL_FISHEYE', 'RADIAL_FISHEYE')
"""The COLMAP camera models that can be read."""


def camera_model(cam: ColmapCamera, camera_id: int,
                 ) -> tuple[tuple[float, ...], CameraModel | None]:
    """Return a camera's intrinsics row (fx, fy, cx, cy, k1, k2) and its OpenCV model, if any.

    The OpenCV model (see the module docstring) is None where the row holds the camera.

    Raises:
        FormatError: For a model neither represents.
    """
    p = [float(v) for v in cam.params]
    opencv: tuple[str, list[float]] | None = None
    if cam.model == 'SIMPLE_PINHOLE':
        return (p[0], p[0], p[1], p[2], 0.0, 0.0), None
    if cam.model == 'PINHOLE':
        return (p[0], p[1], p[2], p[3], 0.0, 0.0), None
    if cam.model == 'SIMPLE_RADIAL':
        return (p[0], p[0], p[1], p[2], p[3], 0.0), None
    if cam.model == 'RADIAL':
        return (p[0], p[0], p[1], p[2], p[3], p[4]), None
    if cam.model == 'OPENCV' and p[6] == 0.0 and p[7] == 0.0:
        return (p[0], p[1], p[2], p[3], p[4], p[5]), None
    if cam.model == 'OPENCV':
        opencv = 'plumb_bob', p[4:8]
    elif cam.model == 'FULL_OPENCV' and not any(p[9:12]):
        opencv = 'plumb_bob', p[4:9]
    elif cam.model == 'OPENCV_FISHEYE':
        opencv = 'equidistant', p[4:8]
    elif cam.model in ('SIMPLE_RADIAL_FISHEYE', 'RADIAL_FISHEYE'):
        p = [p[0], *p]   # f -> fx, fy
        opencv = 'equidistant', [*p[4:], 0.0, 0.0, 0.0][:4]
    if opencv is None:
        why = ('rational distortion k4, k5, k6 != 0' if cam.model == 'FULL_OPENCV'
               else f'model {cam.model}')
        msg = (f'COLMAP camera {camera_id}: {why} is not supported; supported models: '
               f'{", ".join(SUPPORTED)} (FULL_OPENCV without rational terms). Undistort the '
               'images (colmap image_undistorter) first')
        raise FormatError(msg)
    try:
        model = CameraModel(p[0], p[1], p[2], p[3], opencv[0], np.array(opencv[1]),
                            cam.width, cam.height)
    except MessageError as err:
        msg = f'COLMAP camera {camera_id} ({cam.model}): {err}'
        raise FormatError(msg) from err
    return (p[0], p[1], p[2], p[3], 0.0, 0.0), model


def through_pinhole(pixels: FloatArray, cam_idx: IntArray, intr: Intrinsics,
                    models: list[CameraModel | None]) -> tuple[FloatArray, FloatArray]:
    """Return the observations undistorted to their pinhole, and d(pixel) / d(bearing).

    Args:
        pixels: Raw pixels (K, 2).
        cam_idx: Camera of each observation (K,).
        intr: The cameras' intrinsics rows (a pinhole for those with an OpenCV model).
        models: Each camera's OpenCV model, or None.

    Returns:
        Pixels (K, 2): the OpenCV models' undistorted (NaN where that fails), the others'
        as they are; and each observation's pixel Jacobian at its bearing (K, 2, 3).
    """
    out = np.array(pixels, dtype=float)
    # The observations of each distinct OpenCV model (COLMAP images share cameras), found in
    # one sort: a collection with a camera per image has as many models as images.
    distinct: dict[int, int] = {}
    firsts: list[CameraModel] = []
    codes = np.full(len(models), -1, dtype=np.int64)
    for k, m in enumerate(models):
        if m is not None:
            if id(m) not in distinct:
                distinct[id(m)] = len(firsts)
                firsts.append(m)
            codes[k] = distinct[id(m)]
    group = codes[cam_idx]
    order = np.argsort(group, kind='stable')
    bounds = np.searchsorted(group[order], np.arange(len(firsts) + 1))
    groups = [(firsts[g], order[a:b]) for g, (a, b) in enumerate(itertools.pairwise(bounds))]
    for model, rows in groups:
        xy = model.normalize(out[rows])
        out[rows] = np.column_stack([model.fx * xy[:, 0] + model.cx,
                                     model.fy * xy[:, 1] + model.cy])
    finite = np.isfinite(out).all(axis=1)
    bearings = pixels_to_bearings(np.where(finite[:, None], out, 0.0), intr, cam_idx)
    _, jac = projection_jacobian(bearings, intr, cam_idx)
    for model, rows in groups:
        own = model.pixel_jacobian(bearings[rows])
        if own is not None:
            jac[rows] = own
    out[~finite] = np.nan
    return out, jac
