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
"""Pinhole cameras with polynomial radial distortion, batched over cameras.

Conventions: camera frame x right, y down, z forward (ROS optical frame). A camera-frame
direction h projects to ``x = h_x/h_z, y = h_y/h_z``, ``d = 1 + k1 r^2 + k2 r^4`` and pixel
``(fx d x + cx, fy d y + cy)``. BAL problems are converted to this convention on reading.
The engine works on unit bearings ``v = xi(K^-1 [u, v, 1]^T)`` (undistorted).
"""

from __future__ import annotations

from dataclasses import dataclass
import functools

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core import radial
from pmba_ros.errors import ProblemError


@dataclass(frozen=True, eq=False)
class Intrinsics:
    """Per-camera intrinsics as arrays of shape (M,): fx, fy, cx, cy (px), k1, k2."""

    fx: FloatArray
    fy: FloatArray
    cx: FloatArray
    cy: FloatArray
    k1: FloatArray
    k2: FloatArray

    @classmethod
    def uniform(cls, n_cams: int, fx: float, fy: float, cx: float, cy: float,
                k1: float = 0.0, k2: float = 0.0) -> Intrinsics:
        """Return the same intrinsics repeated for ``n_cams`` cameras.

        Intrinsics are immutable, so equal requests share one instance (a sliding window
        asks for the same ones at every keyframe).
        """
        return _uniform(int(n_cams), float(fx), float(fy), float(cx), float(cy),
                        float(k1), float(k2))

    @functools.cached_property
    def median_focal(self) -> float:
        """Return the median of all focal lengths, fx and fy (px)."""
        return float(np.median(np.concatenate([self.fx, self.fy])))

    def __post_init__(self) -> None:
        """Validate shapes and values."""
        arrays = [np.asarray(getattr(self, f), dtype=float)
                  for f in ('fx', 'fy', 'cx', 'cy', 'k1', 'k2')]
        shape = arrays[0].shape
        if len(shape) != 1 or any(a.shape != shape for a in arrays):
            msg = 'intrinsics: fx, fy, cx, cy, k1, k2 must be 1-D arrays of one length'
            raise ProblemError(msg)
        if not all(np.all(np.isfinite(a)) for a in arrays):
            msg = 'intrinsics: non-finite value'
            raise ProblemError(msg)
        if np.any(arrays[0] <= 0) or np.any(arrays[1] <= 0):
            msg = 'intrinsics: focal lengths must be positive'
            raise ProblemError(msg)
        for name, arr in zip(('fx', 'fy', 'cx', 'cy', 'k1', 'k2'), arrays, strict=True):
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        """Return the number of cameras."""
        return int(self.fx.shape[0])

    def take(self, index: np.ndarray) -> Intrinsics:
        """Return the intrinsics of the cameras in ``index``."""
        return Intrinsics(self.fx[index], self.fy[index], self.cx[index], self.cy[index],
                          self.k1[index], self.k2[index])


@functools.lru_cache(maxsize=16)
def _uniform(n_cams: int, *values: float) -> Intrinsics:
    return Intrinsics(*(np.full(n_cams, v) for v in values))


def project(h_c: FloatArray, intr: Intrinsics, cam_idx: np.ndarray) -> FloatArray:
    """Project camera-frame directions h_c (K, 3) of cameras cam_idx (K,) to pixels (K, 2).

    Directions with h_z <= 0 are projected through the same formula (as BAL does): the caller
    decides whether such points count.
    """
    z = h_c[:, 2]
    z = np.where(np.abs(z) < 1e-300, 1e-300, z)
    x = h_c[:, 0] / z
    y = h_c[:, 1] / z
    r2 = x * x + y * y
    d = 1.0 + intr.k1[cam_idx] * r2 + intr.k2[cam_idx] * r2 * r2
    return np.stack([intr.fx[cam_idx] * d * x + intr.cx[cam_idx],
                     intr.fy[cam_idx] * d * y + intr.cy[cam_idx]], axis=1)


def projection_jacobian(h_c: FloatArray, intr: Intrinsics, cam_idx: np.ndarray,
                        ) -> tuple[FloatArray, FloatArray]:
    """Return pixels (K, 2) and d(pixel)/d(h_c) (K, 2, 3) of :func:`project`."""
    z = h_c[:, 2]
    z = np.where(np.abs(z) < 1e-300, 1e-300, z)
    x = h_c[:, 0] / z
    y = h_c[:, 1] / z
    k1 = intr.k1[cam_idx]
    k2 = intr.k2[cam_idx]
    fx = intr.fx[cam_idx]
    fy = intr.fy[cam_idx]
    r2 = x * x + y * y
    d = 1.0 + k1 * r2 + k2 * r2 * r2
    dd = 2.0 * (k1 + 2.0 * k2 * r2)  # d(d)/d(x) = dd * x
    pix = np.stack([fx * d * x + intr.cx[cam_idx], fy * d * y + intr.cy[cam_idx]], axis=1)
    J_xy = np.empty((h_c.shape[0], 2, 2))
    J_xy[:, 0, 0] = fx * (d + dd * x * x)
    J_xy[:, 0, 1] = fx * dd * x * y
    J_xy[:, 1, 0] = fy * dd * x * y
    J_xy[:, 1, 1] = fy * (d + dd * y * y)
    inv_z = 1.0 / z
    J_h = np.zeros((h_c.shape[0], 2, 3))
    J_h[:, 0, 0] = inv_z
    J_h[:, 0, 2] = -x * inv_z
    J_h[:, 1, 1] = inv_z
    J_h[:, 1, 2] = -y * inv_z
    return pix, J_xy @ J_h


def pixels_to_bearings(pixels: FloatArray, intr: Intrinsics, cam_idx: np.ndarray,
                       iterations: int = 20) -> FloatArray:
    """Undistort pixels (K, 2) and return unit bearings (K, 3), v = xi(K^-1 [u, v, 1]^T).

    Radial distortion is inverted with Newton's method on r (vectorized); cameras without
    distortion take the closed form. A radius Newton's method leaves unsolved or past the
    camera's fold (where r (1 + k1 r^2 + k2 r^4) stops growing) is searched again below the
    fold (:func:`~pmba_ros.core.radial.increasing_inverse`): its ray is NaN if none fits.
    """
    # Absurd intrinsics (a damaged file's 1e-306 px focal length) overflow here: their rays
    # come out non-finite, which make_problem drops and counts.
    with np.errstate(over='ignore', invalid='ignore'):
        return _undistorted_rays(pixels, intr, cam_idx, iterations)


def _within_folds(r: FloatArray, rd: FloatArray, k1: FloatArray, k2: FloatArray,
                  intr: Intrinsics, cam_idx: np.ndarray) -> FloatArray:
    """Return the radii r, those Newton's method left unsolved or past the fold redone."""
    folds = np.array([radial.fold((a, b, 0.0, 0.0))
                      for a, b in zip(intr.k1.tolist(), intr.k2.tolist(), strict=True)])[cam_idx]
    zeros = np.zeros_like(k1)
    g = radial.theta_d(r, np.stack([k1, k2, zeros, zeros]))
    fits = np.abs(g - rd) <= 1e-9 * np.maximum(rd, 1.0)
    redo = ~(fits & (r >= 0.0) & (r < folds))
    if not np.any(redo):
        return r
    part = np.stack([k1[redo], k2[redo], zeros[redo], zeros[redo]])
    out = r.copy()
    out[redo] = radial.increasing_inverse(lambda t: radial.theta_d(t, part),
                                          lambda t: radial.theta_d_slope(t, part), rd[redo],
                                          np.minimum(folds[redo], 1e6))
    return out


def _undistorted_rays(pixels: FloatArray, intr: Intrinsics, cam_idx: np.ndarray,
                      iterations: int) -> FloatArray:
    """Return :func:`pixels_to_bearings`' unit bearings (K, 3)."""
    xd = (pixels[:, 0] - intr.cx[cam_idx]) / intr.fx[cam_idx]
    yd = (pixels[:, 1] - intr.cy[cam_idx]) / intr.fy[cam_idx]
    k1 = intr.k1[cam_idx]
    k2 = intr.k2[cam_idx]
    rd = np.hypot(xd, yd)
    r = rd.copy()
    if np.any(k1 != 0.0) or np.any(k2 != 0.0):
        for _ in range(iterations):
            r2 = r * r
            f = r * (1.0 + k1 * r2 + k2 * r2 * r2) - rd
            df = 1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2
            r = r - f / np.where(np.abs(df) < 1e-12, 1e-12, df)
        r = _within_folds(r, rd, k1, k2, intr, cam_idx)
    scale = np.where(rd > 0, r / np.where(rd > 0, rd, 1.0), 1.0)
    rays = np.stack([xd * scale, yd * scale, np.ones_like(xd)], axis=1)
    out: FloatArray = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    return out
