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
"""Tests of the XYZ-BA and IDP-BA baselines and the camera model."""

from __future__ import annotations

import numpy as np
from pmba_ros.core import conversions, so3
from pmba_ros.core.camera import Intrinsics, pixels_to_bearings, project
from pmba_ros.core.models import IdpModel, XyzModel
from pmba_ros.core.problem import XyzFeatures
import pytest

from .helpers import check_jacobians, forward_problem


def _start(problem, seed: int = 1):
    rng = np.random.default_rng(seed)
    R = problem.R_wc @ so3.exp(rng.normal(0, 0.01, (problem.n_cams, 3)))
    P = problem.centers_w + rng.normal(0, 0.05, problem.centers_w.shape)
    return R, P


@pytest.mark.parametrize('k1,k2', [(0.0, 0.0), (-0.1, 0.02)])
def test_xyz_jacobians_match_central_differences(k1: float, k2: float) -> None:
    """XYZ-BA blocks (pose, point) against central differences, with radial distortion."""
    problem = forward_problem(2, k1=k1, k2=k2)
    R, P = _start(problem)
    near = problem.points_w[:, 2] < 100  # far points make FD steps of 1e-6 m meaningless
    feats = XyzFeatures(np.where(near[:, None], problem.points_w, problem.points_w * 1e-2))
    pose_err, feat_err = check_jacobians(XyzModel(problem), R, P, feats)
    assert pose_err < 1e-4 and feat_err < 1e-4


def test_idp_jacobians_match_central_differences() -> None:
    """IDP-BA blocks (observer, anchor, (a, b, rho)) against central differences."""
    problem = forward_problem(4, k1=-0.05)
    R, P = _start(problem)
    feats = conversions.xyz_to_idp(problem, problem.R_wc, problem.centers_w, problem.points_w)
    pose_err, feat_err = check_jacobians(IdpModel(problem), R, P, feats)
    assert pose_err < 1e-4 and feat_err < 1e-3


def test_idp_round_trip_to_xyz() -> None:
    """Converting xyz -> idp -> xyz reproduces the points."""
    problem = forward_problem(5)
    feats = conversions.xyz_to_idp(problem, problem.R_wc, problem.centers_w, problem.points_w)
    back = conversions.idp_to_xyz(problem.R_wc, problem.centers_w, feats)
    np.testing.assert_allclose(back, problem.points_w, rtol=1e-9)


def test_undistortion_inverts_projection(rng: np.random.Generator) -> None:
    """pixels_to_bearings inverts project for radial distortion (Newton iterations)."""
    intr = Intrinsics.uniform(1, 400.0, 410.0, 320.0, 240.0, k1=-0.2, k2=0.05)
    h = np.column_stack([rng.uniform(-0.6, 0.6, (100, 2)), np.ones(100)])
    cam = np.zeros(100, dtype=np.int64)
    v = pixels_to_bearings(project(h, intr, cam), intr, cam)
    np.testing.assert_allclose(v, h / np.linalg.norm(h, axis=1, keepdims=True), atol=1e-10)
