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
"""Small deterministic problems and a finite-difference Jacobian checker for core tests."""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros.core import conversions, so3, sphere
from pmba_ros.core.camera import Intrinsics, project
from pmba_ros.core.engine import compiled_available, Engine, resolve
from pmba_ros.core.models import Model
from pmba_ros.core.problem import BAProblem, make_problem, ParallaxFeatures
import pytest


def forward_problem(seed: int = 0, n_cams: int = 6, n_points: int = 40, noise_px: float = 0.5,
                    k1: float = 0.0, k2: float = 0.0) -> BAProblem:
    """Cameras moving forward along +z (collinear), near, far and near-collinear points.

    Every point is seen by every camera (a few points lie almost on the line of motion and a
    few are 1e4 baselines away).
    """
    rng = np.random.default_rng(seed)
    R = so3.exp(rng.normal(0.0, 0.02, (n_cams, 3)))
    P = np.column_stack([rng.normal(0, 0.02, n_cams), rng.normal(0, 0.02, n_cams),
                         np.arange(n_cams, dtype=float)])
    X = np.column_stack([rng.uniform(-4, 4, n_points), rng.uniform(-3, 3, n_points),
                         rng.uniform(12, 40, n_points)])
    X[:3] = [[0.05, 0.03, 60.0], [-0.04, 0.02, 45.0], [0.02, -0.05, 80.0]]  # near-collinear
    X[3:6] *= 1e4 / X[3:6, 2:3]                                          # 1e4 baselines
    intr = Intrinsics.uniform(n_cams, 500.0, 500.0, 320.0, 240.0, k1, k2)
    cam = np.repeat(np.arange(n_cams), n_points)
    feat = np.tile(np.arange(n_points), n_cams)
    h = np.einsum('kji,kj->ki', R[cam], X[feat] - P[cam])
    pix = project(h, intr, cam) + rng.normal(0.0, noise_px, (cam.shape[0], 2))
    return make_problem(R, P, intr, cam, feat, pix, points_w=X)


def check_jacobians(model: Model[Any], R_wc: np.ndarray, centers_w: np.ndarray, feats: Any,
                    eps: float = 1e-6) -> tuple[float, float]:
    """Return the max abs error of pose and feature Jacobians against central differences."""
    lin = model.linearize(R_wc, centers_w, feats)
    J_pose, J_feat = lin.J_pose(), lin.J_feat
    slots = model.slots(feats)
    M = R_wc.shape[0]
    pose_err = 0.0
    for cam in range(M):
        on_cam = (slots == cam).astype(float)
        for c in range(6):
            d = np.zeros(6)
            d[c] = eps
            Rp, Pp, Rm, Pm = R_wc.copy(), centers_w.copy(), R_wc.copy(), centers_w.copy()
            Rp[cam] = R_wc[cam] @ so3.exp(d[:3])
            Rm[cam] = R_wc[cam] @ so3.exp(-d[:3])
            Pp[cam] = centers_w[cam] + d[3:]
            Pm[cam] = centers_w[cam] - d[3:]
            num = (model.residuals(Rp, Pp, feats) - model.residuals(Rm, Pm, feats)) / (2 * eps)
            ana = np.einsum('ksd,ks->kd', J_pose[:, :, :, c], on_cam)
            pose_err = max(pose_err, float(np.max(np.abs(num - ana))))
    feat_err = 0.0
    n_feats = J_feat.shape[0] and int(model.obs.feat_idx.max()) + 1
    for c in range(3):
        d = np.zeros((n_feats, 3))
        d[:, c] = eps
        num = (model.residuals(R_wc, centers_w, model.retract(feats, d))
               - model.residuals(R_wc, centers_w, model.retract(feats, -d))) / (2 * eps)
        feat_err = max(feat_err, float(np.max(np.abs(num - J_feat[:, :, c]))))
    return pose_err, feat_err


def engine_named(name: str) -> Engine:
    """Return the engine of a name, skipping the test where it cannot run (no numba)."""
    if name == 'compiled' and not compiled_available():
        pytest.skip('the compiled engine needs numba')
    return resolve(name)


def perturbed_state(problem: BAProblem, seed: int,
                    ) -> tuple[np.ndarray, np.ndarray, ParallaxFeatures]:
    """Return poses and PMBA features of ``problem``'s true state, each slightly perturbed."""
    feats, ok = conversions.xyz_to_parallax(problem, problem.R_wc, problem.centers_w,
                                            problem.points_w)
    assert ok.all()
    rng = np.random.default_rng(seed)
    R = problem.R_wc @ so3.exp(rng.normal(0, 0.01, (problem.n_cams, 3)))
    P = problem.centers_w + rng.normal(0, 0.05, problem.centers_w.shape)
    theta = feats.theta + rng.normal(0, 1e-3, feats.theta.shape)
    n = sphere.retract(feats.n, rng.normal(0, 1e-2, (feats.n.shape[0], 2)))
    return R, P, ParallaxFeatures(theta, n, feats.main_idx, feats.assoc_idx)
