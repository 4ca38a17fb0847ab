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
"""The distortion models of ROS ``CameraInfo``: OpenCV's ``plumb_bob`` and fisheye.

Distortion maps normalized undistorted coordinates ``(x, y) = (X/Z, Y/Z)`` to distorted ones
``(x_d, y_d)``, with pixels ``u = fx * x_d + cx``, ``v = fy * y_d + cy``. Both models are
polynomials in the radius (or the ray's angle) that a calibration fits to the image it saw;
past the radius where one stops growing (its fold) a pixel has no ray or two, and the
inversions return NaN there rather than a ray of the wrong branch.

Notation:
    ========  =========  ======  ================================================
    symbol    code       shape   meaning
    ========  =========  ======  ================================================
    (x, y)    ``xy``     (K, 2)  normalized undistorted coordinates
    (x_d,y_d) ``xy_d``   (K, 2)  normalized distorted coordinates
    r         ``r``      (K,)    ``|(x, y)|``
    theta     ``theta``  (K,)    ``atan(r)``, angle of the ray to the optical axis
    ========  =========  ======  ================================================
"""

from __future__ import annotations

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core.radial import (
    fold,
    increasing_inverse,
    NEWTON_ITERATIONS,
    NEWTON_TOL,
    theta_d,
    theta_d_slope,
)

__all__ = ['distort_equidistant', 'distort_plumb_bob', 'equidistant_fold',
           'equidistant_jacobian', 'pinhole_jacobian', 'plumb_bob_fold', 'plumb_bob_jacobian',
           'plumb_bob_radial', 'theta_d', 'theta_d_slope', 'undistort_equidistant',
           'undistort_plumb_bob']


def pinhole_jacobian(bearings: FloatArray, fx: float, fy: float) -> FloatArray:
    """Return d(fx x / z, fy y / z) / d(bearing) at ``bearings``, (K, 2, 3); NaN where z <= 0."""
    v = bearings
    inv_z = 1.0 / np.where(v[:, 2] > 0, v[:, 2], np.nan)
    J = np.zeros((v.shape[0], 2, 3))
    J[:, 0, 0], J[:, 1, 1] = fx * inv_z, fy * inv_z
    J[:, 0, 2] = -fx * v[:, 0] * inv_z * inv_z
    J[:, 1, 2] = -fy * v[:, 1] * inv_z * inv_z
    return J


def _radial(xy: FloatArray, d: FloatArray,
            ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Return x, y, r^2 and plumb_bob's radial factor 1 + k1 r^2 + k2 r^4 + k3 r^6."""
    k1, k2, _, _, k3 = d
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    return x, y, r2, 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))


def plumb_bob_jacobian(xy: FloatArray, d: FloatArray) -> FloatArray:
    """Return d(distorted) / d(normalized) of :func:`distort_plumb_bob` at xy, (K, 2, 2)."""
    k1, k2, p1, p2, k3 = d
    x, y, r2, radial = _radial(xy, d)
    g = 2.0 * k1 + r2 * (4.0 * k2 + 6.0 * k3 * r2)  # d(radial)/dx = g * x
    off = g * x * y + 2.0 * p1 * x + 2.0 * p2 * y
    return np.stack([np.stack([radial + g * x * x + 2.0 * p1 * y + 6.0 * p2 * x, off], -1),
                     np.stack([off, radial + g * y * y + 6.0 * p1 * y + 2.0 * p2 * x], -1)],
                    axis=1)


def equidistant_jacobian(v: FloatArray, d: FloatArray) -> FloatArray:
    """Return d(distorted normalized) / d(bearing) of the fisheye model at unit v, (K, 2, 3).

    From the bearing, not from x/z: the pinhole's 1 / z^2 and the fisheye's cos^2 cancel
    at the border, where they are each far from 1.
    """
    rho = np.hypot(v[:, 0], v[:, 1])
    theta = np.arctan2(rho, v[:, 2])
    slope = theta_d_slope(theta, d)
    centre = rho < 1e-9
    safe = np.where(centre, 1.0, rho)
    s = v[:, :2] / safe[:, None]                       # direction in the image
    d_theta = np.column_stack([v[:, 2:3] * s, -rho])   # d theta / d v, (K, 3)
    stretch = theta_d(theta, d) / safe
    across = (np.eye(2) - np.einsum('ki,kj->kij', s, s)) * stretch[:, None, None]
    J = np.einsum('ki,kj->kij', slope[:, None] * s, d_theta)
    J[:, :, :2] += across
    J[centre] = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return J


def distort_plumb_bob(xy: FloatArray, d: FloatArray) -> FloatArray:
    """Apply OpenCV's radial-tangential model (k1, k2, p1, p2, k3) to (K, 2) points."""
    _, _, p1, p2, _ = d
    x, y, r2, radial = _radial(xy, d)
    x_d = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    y_d = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([x_d, y_d], axis=1)


def undistort_plumb_bob(xy_d: FloatArray, d: FloatArray) -> FloatArray:
    """Invert :func:`distort_plumb_bob` on the branch the distortion grows on; NaN elsewhere.

    Where the radial part stops growing (:func:`plumb_bob_fold`), it is inverted first,
    within that radius, and Newton's method takes in the tangential part from there: from
    the distorted point, Newton went past the fold to a root there (a pixel of the
    calibrated image read as a ray far outside it).
    """
    fold = plumb_bob_fold(d)
    xy = xy_d.copy()
    if np.isfinite(fold):   # else the radial part grows everywhere: one root, found from xy_d
        rho = np.hypot(xy_d[:, 0], xy_d[:, 1])
        radial = plumb_bob_radial(d)
        r = increasing_inverse(lambda t: theta_d(t, radial),
                               lambda t: theta_d_slope(t, radial), rho, fold)
        xy *= np.where(rho > 1e-12, r / np.where(rho > 1e-12, rho, 1.0), 1.0)[:, None]
    for _ in range(NEWTON_ITERATIONS):
        f = distort_plumb_bob(xy, d) - xy_d
        J = plumb_bob_jacobian(xy, d)
        j00, j01, j11 = J[:, 0, 0], J[:, 0, 1], J[:, 1, 1]
        det = j00 * j11 - j01 * j01
        det = np.where(np.abs(det) < 1e-12, np.nan, det)
        step = np.stack([j11 * f[:, 0] - j01 * f[:, 1], j00 * f[:, 1] - j01 * f[:, 0]], 1)
        xy = xy - step / det[:, None]
        if np.all(~np.isfinite(step) | (np.abs(step) <= NEWTON_TOL * np.abs(det)[:, None])):
            break
    resid = np.abs(distort_plumb_bob(xy, d) - xy_d).max(axis=1)
    xy[~((resid < 1e-9) & (np.hypot(xy[:, 0], xy[:, 1]) < fold))] = np.nan
    return xy


def plumb_bob_radial(d: FloatArray) -> FloatArray:
    """Return plumb_bob's radial part as :func:`theta_d`'s coefficients (in r, k4 = 0)."""
    k1, k2, _, _, k3 = d
    return np.array([k1, k2, k3, 0.0])


def distort_equidistant(xy: FloatArray, d: FloatArray) -> FloatArray:
    """Apply OpenCV's fisheye (equidistant) model to (K, 2) normalized points."""
    r = np.hypot(xy[:, 0], xy[:, 1])
    theta = np.arctan(r)
    scale = np.where(r > 1e-12, theta_d(theta, d) / np.where(r > 1e-12, r, 1.0), 1.0)
    return xy * scale[:, None]


def undistort_equidistant(xy_d: FloatArray, d: FloatArray) -> FloatArray:
    """Invert :func:`distort_equidistant` below its fold and 90 degrees; NaN elsewhere."""
    theta_d_ = np.hypot(xy_d[:, 0], xy_d[:, 1])
    theta = increasing_inverse(lambda t: theta_d(t, d), lambda t: theta_d_slope(t, d),
                               theta_d_, equidistant_fold(d))
    ok = (np.abs(theta_d(theta, d) - theta_d_) < 1e-9) & (theta < np.pi / 2)
    scale = np.where(theta_d_ > 1e-12,
                     np.tan(theta) / np.where(theta_d_ > 1e-12, theta_d_, 1.0), 1.0)
    xy = xy_d * scale[:, None]
    xy[~ok] = np.nan
    return xy


def plumb_bob_fold(d: FloatArray) -> float:
    """Return the radius r of (x, y) where plumb_bob's radial distortion stops growing (or inf).

    Where d(r (1 + k1 r^2 + k2 r^4 + k3 r^6)) / dr = 0 (:func:`~pmba_ros.core.radial.fold`).
    Past it, pixels have no ray or two.
    """
    k1, k2, _, _, k3 = (float(v) for v in d)
    return fold((k1, k2, k3, 0.0))


def equidistant_fold(d: FloatArray) -> float:
    """Return the angle theta where the fisheye's theta_d stops growing (or pi/2 if beyond).

    (:func:`~pmba_ros.core.radial.fold`).
    """
    k1, k2, k3, k4 = (float(v) for v in d)
    return min(fold((k1, k2, k3, k4)), np.pi / 2)
