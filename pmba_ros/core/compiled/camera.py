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
"""Compiled pixel reprojection errors and projection Jacobians (mirrors camera.py)."""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import jit

_jit = jit.jit


@_jit
def _reprojection_errors(rays_c: Any, fx: Any, fy: Any, cx: Any, cy: Any, k1: Any, k2: Any,
                         cam_idx: Any, pixels: Any, out: Any) -> None:
    """|pi(h) - (u, v)| per observation, pi as camera.project (radial k1, k2)."""
    for k in range(rays_c.shape[0]):
        i = cam_idx[k]
        z = rays_c[k, 2]
        if abs(z) < 1e-300:
            z = 1e-300
        x, y = rays_c[k, 0] / z, rays_c[k, 1] / z
        r2 = x * x + y * y
        dist = 1.0 + k1[i] * r2 + k2[i] * r2 * r2
        du = fx[i] * dist * x + cx[i] - pixels[k, 0]
        dv = fy[i] * dist * y + cy[i] - pixels[k, 1]
        out[k] = np.sqrt(du * du + dv * dv)


def reprojection_errors(rays_c: FloatArray, intr: Any, cam_idx: IntArray,
                        pixels: FloatArray) -> FloatArray:
    """Return the pixel reprojection error of camera-frame rays, shape (K,)."""
    out = np.empty(rays_c.shape[0])
    _reprojection_errors(rays_c, intr.fx, intr.fy, intr.cx, intr.cy, intr.k1, intr.k2, cam_idx,
                         pixels, out)
    return out


@_jit
def _projection_jacobian(h_c: Any, fx: Any, fy: Any, k1: Any, k2: Any, cam_idx: Any,
                         out: Any) -> None:
    """Write d pi / d h of camera.project at each h_c (radial k1, k2) to out (K, 2, 3)."""
    for k in range(h_c.shape[0]):
        i = cam_idx[k]
        z = h_c[k, 2]
        if abs(z) < 1e-300:
            z = 1e-300
        inv_z = 1.0 / z
        x, y = h_c[k, 0] * inv_z, h_c[k, 1] * inv_z
        r2 = x * x + y * y
        dist = 1.0 + k1[i] * r2 + k2[i] * r2 * r2
        dd = 2.0 * (k1[i] + 2.0 * k2[i] * r2)
        a, b = fx[i] * (dist + dd * x * x), fx[i] * dd * x * y
        c, e = fy[i] * dd * x * y, fy[i] * (dist + dd * y * y)
        # [[a, b], [c, e]] times [[1/z, 0, -x/z], [0, 1/z, -y/z]].
        out[k, 0, 0], out[k, 0, 1], out[k, 0, 2] = a * inv_z, b * inv_z, -(a * x + b * y) * inv_z
        out[k, 1, 0], out[k, 1, 1], out[k, 1, 2] = c * inv_z, e * inv_z, -(c * x + e * y) * inv_z


def projection_jacobian(h_c: FloatArray, intr: Any, cam_idx: IntArray) -> FloatArray:
    """Return d(pixel)/d(h_c) (K, 2, 3) of camera.project (camera.projection_jacobian's)."""
    out = np.empty((h_c.shape[0], 2, 3))
    _projection_jacobian(np.ascontiguousarray(h_c), intr.fx, intr.fy, intr.k1, intr.k2,
                         cam_idx, out)
    return out
