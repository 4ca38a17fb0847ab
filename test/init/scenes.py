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
"""Small seeded street scenes for the global-initialization tests (no dependency on sim/)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pmba_ros.core import so3
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.problem import BAProblem, make_problem


@dataclass(frozen=True, eq=False)
class StreetScene:
    """A ground-truth problem (poses and points) with noisy pixel observations."""

    gt: BAProblem
    noise_px: float


def street_scene(seed: int, n_cams: int = 12, n_points: int = 300, noise_px: float = 0.5, *,
                 step_m: float = 1.0, width_m: float = 8.0, height_m: float = 4.0,
                 depth_m: float = 60.0, jitter_deg: float = 3.0, focal_px: float = 500.0,
                 translation_jitter_m: float = 0.0,
                 order: np.ndarray | None = None) -> StreetScene:
    """Return a street with cameras moving forward along +z (collinear motion).

    Points lie on two facades (x = +-width/2) and on the ground, between the first camera and
    ``depth_m`` beyond the last one. Cameras look forward with a few degrees of jitter. An
    optional permutation ``order`` renumbers the cameras (shuffled images).
    """
    rng = np.random.default_rng(seed)
    width, height = 640.0, 480.0
    centers = np.zeros((n_cams, 3))
    centers[:, 2] = np.arange(n_cams) * step_m
    centers[:, :2] += rng.normal(scale=translation_jitter_m, size=(n_cams, 2))
    R_wc = so3.exp(np.deg2rad(jitter_deg) * rng.normal(size=(n_cams, 3)) / np.sqrt(3.0))
    z_far = centers[-1, 2] + depth_m
    side = rng.integers(0, 3, size=n_points)
    pts = np.empty((n_points, 3))
    pts[:, 2] = rng.uniform(2.0, z_far, size=n_points)
    pts[:, 0] = np.where(side == 0, -width_m / 2, width_m / 2) + rng.normal(0, 0.3, n_points)
    pts[:, 1] = rng.uniform(-height_m, height_m / 2, size=n_points)
    ground = side == 2
    pts[ground, 0] = rng.uniform(-width_m / 2, width_m / 2, size=int(ground.sum()))
    pts[ground, 1] = 1.5
    cam = np.repeat(np.arange(n_cams), n_points)
    feat = np.tile(np.arange(n_points), n_cams)
    h_c = np.einsum('kji,kj->ki', R_wc[cam], pts[feat] - centers[cam])
    z = h_c[:, 2]
    with np.errstate(divide='ignore', invalid='ignore'):
        u = focal_px * h_c[:, 0] / z + width / 2
        v = focal_px * h_c[:, 1] / z + height / 2
    vis = (z > 0.5) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    pix = np.stack([u, v], axis=1)[vis] + rng.normal(scale=noise_px, size=(int(vis.sum()), 2))
    cam, feat = cam[vis], feat[vis]
    if order is not None:
        inv = np.empty(n_cams, dtype=np.int64)
        inv[order] = np.arange(n_cams)
        cam = inv[cam]
        R_wc, centers = R_wc[order], centers[order]
    sort = np.lexsort((cam, feat))
    intr = Intrinsics.uniform(n_cams, focal_px, focal_px, width / 2, height / 2)
    gt = make_problem(R_wc, centers, intr, cam[sort], feat[sort], pix[sort], points_w=pts,
                      n_feats=n_points)
    return StreetScene(gt=gt, noise_px=noise_px)
