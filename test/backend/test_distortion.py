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
"""Distortion that folds over inside the image: no ray of the wrong branch, the fold named."""

from __future__ import annotations

import cv2
import numpy as np
from pmba_ros.backend.distortion import equidistant_fold, plumb_bob_fold
from pmba_ros.backend.logic import BackendLogic
from pmba_ros.backend.types import CameraModel
from pmba_ros.sim.inputs import make_camera_info

from .test_logic import BACKEND, config

# A calibration whose k3 turns the radial polynomial down 0.87 focal lengths out: on a
# 640 x 480 image with f = 300 px its corners are 1.33 focal lengths out.
FOLDING = CameraModel(300.0, 300.0, 320.0, 240.0, 'plumb_bob',
                      [-0.09, 0.016, 0.0, 0.0, -0.275], 640, 480)
FOLDING_FISHEYE = CameraModel(200.0, 200.0, 320.0, 240.0, 'equidistant',
                              [0.0, -0.12, 0.0, 0.0], 640, 480)


def _grid(camera: CameraModel, n: int = 60) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0, camera.width, n), np.linspace(0, camera.height, n))
    return np.column_stack([u.ravel(), v.ravel()])


def _first_fold(f: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """Return where a sampled function first stops growing, and its value there."""
    i = int(np.argmax(np.diff(f) <= 0))
    return float(x[i]), float(f[i])


def test_fold_radii_are_where_the_polynomials_stop_growing() -> None:
    """Against a dense scan of each polynomial; inf / 90 degrees where it always grows."""
    r = np.linspace(0.0, 3.0, 300001)
    k1, k2, _, _, k3 = FOLDING.d
    fold, _ = _first_fold(r * (1 + k1 * r**2 + k2 * r**4 + k3 * r**6), r)
    assert abs(plumb_bob_fold(FOLDING.d) - fold) < 1e-4
    theta = np.linspace(0.0, np.pi / 2, 300001)
    k = FOLDING_FISHEYE.d
    t2 = theta**2
    fold, _ = _first_fold(theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))),
                          theta)
    assert abs(equidistant_fold(k) - fold) < 1e-4
    assert plumb_bob_fold(np.array([-0.283, 0.074, 0.0, 0.0, 0.0])) == np.inf
    assert equidistant_fold(np.array([0.0107, -0.0064, 0.0021, -0.0005])) == np.pi / 2


def test_folding_plumb_bob_gives_rays_of_the_first_branch_only() -> None:
    """Every ray is inside the fold and projects back to its pixel (cv2), for every pixel.

    Every pixel that has such a ray gets it. Newton from the distorted point had gone past
    the fold for 512 of these 3,600 pixels: rays up to 1.37 focal lengths out where the
    fold is at 0.87, each projecting back to its pixel.
    """
    px = _grid(FOLDING)
    with np.errstate(all='ignore'):
        xy = FOLDING.normalize(px)
    ok = np.all(np.isfinite(xy), axis=1)
    r = np.hypot(xy[ok, 0], xy[ok, 1])
    assert np.all(r < plumb_bob_fold(FOLDING.d))
    rays = np.column_stack([xy[ok], np.ones(int(ok.sum()))])
    back, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), FOLDING.k, FOLDING.d)
    np.testing.assert_allclose(back.reshape(-1, 2), px[ok], atol=1e-6)
    k1, k2, _, _, k3 = FOLDING.d
    s = np.linspace(0.0, 2.0, 200001)
    _, reach = _first_fold(s * (1 + k1 * s**2 + k2 * s**4 + k3 * s**6), s)
    rho = np.hypot(*((px - [FOLDING.cx, FOLDING.cy]) / FOLDING.fx).T)
    assert np.all(ok[rho < 0.999 * reach]) and not np.any(ok[rho > reach])
    assert 0.2 < np.mean(~ok) < 0.8


def test_folding_fisheye_gives_rays_of_the_first_branch_only() -> None:
    """The same for the equidistant model, with cv2.fisheye as the oracle.

    (Its Newton iteration stayed on the first branch before too: theta_d is concave here.)
    """
    px = _grid(FOLDING_FISHEYE)
    with np.errstate(all='ignore'):
        xy = FOLDING_FISHEYE.normalize(px)
    ok = np.all(np.isfinite(xy), axis=1)
    theta = np.arctan(np.hypot(xy[ok, 0], xy[ok, 1]))
    assert np.all(theta < equidistant_fold(FOLDING_FISHEYE.d))
    rays = np.column_stack([xy[ok], np.ones(int(ok.sum()))]).reshape(-1, 1, 3)
    back, _ = cv2.fisheye.projectPoints(rays, np.zeros(3), np.zeros(3), FOLDING_FISHEYE.k,
                                        FOLDING_FISHEYE.d)
    np.testing.assert_allclose(back.reshape(-1, 2), px[ok], atol=1e-6)
    assert 0.05 < np.mean(~ok) < 0.9


def test_fold_inside_the_image_is_named_once_per_camera_model() -> None:
    """A warning naming the fold and the image's share past it, counted, WARN-level error.

    Calibrations that grow over the whole image say nothing.
    """
    assert 'folds over inside the image' in FOLDING.fold_in_image()
    assert 'equidistant' in FOLDING_FISHEYE.fold_in_image()
    euroc = CameraModel(458.6, 457.3, 367.2, 248.4, 'plumb_bob',
                        [-0.283, 0.074, 1.9e-4, 1.8e-5, 0.0], 752, 480)
    assert euroc.fold_in_image() == '' and CameraModel(300, 300, 320, 240).fold_in_image() == ''
    logic = BackendLogic(config(), BACKEND)
    msg = make_camera_info(1, 'camera', FOLDING, BACKEND)
    for _ in range(3):   # the same model again and again: named once
        logic.on_camera_info(msg)
    assert logic.stats.counters['camera_info_folds'] == 1
    assert logic.last_error.startswith('camera_info_folds: camera 0: its plumb_bob distortion')
    logic.on_camera_info(make_camera_info(2, 'camera', euroc, BACKEND))
    assert logic.stats.counters['camera_info_folds'] == 1
