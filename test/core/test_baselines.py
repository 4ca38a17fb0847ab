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


def test_undistortion_stays_below_the_fold(rng: np.random.Generator) -> None:
    """Strong barrel distortion: rays from below the fold, pixels past its reach NaN.

    r (1 - 0.4 r^2 + 0.02 r^4) stops growing at r = 0.949 (its fold, where it reaches 0.63)
    and grows again from r = 3.3: pixels past the reach (noise at the image's border) have
    no ray, and no pixel's ray lies past the fold.
    """
    k1, k2 = -0.4, 0.02
    intr = Intrinsics.uniform(1, 500.0, 500.0, 320.0, 240.0, k1=k1, k2=k2)
    fold = np.sqrt((-3.0 * k1 - np.sqrt(9.0 * k1 * k1 - 20.0 * k2)) / (10.0 * k2))
    reach = fold * (1.0 + k1 * fold ** 2 + k2 * fold ** 4)
    angle = rng.uniform(0.0, 2.0 * np.pi, 200)
    direction = np.column_stack([np.cos(angle), np.sin(angle)])
    cam = np.zeros(200, dtype=np.int64)
    r = rng.uniform(0.0, 0.99 * fold, 200)
    h = np.column_stack([r[:, None] * direction, np.ones(200)])
    v = pixels_to_bearings(project(h, intr, cam), intr, cam)
    np.testing.assert_allclose(v, h / np.linalg.norm(h, axis=1, keepdims=True), atol=1e-8)
    rd = rng.uniform(0.0, 1.5 * reach, 200)
    pixels = 500.0 * rd[:, None] * direction + np.array([320.0, 240.0])
    v = pixels_to_bearings(pixels, intr, cam)
    assert np.all(np.isnan(v[rd > 1.0001 * reach]))
    inside = rd < 0.9999 * reach
    assert np.all(np.hypot(v[inside, 0], v[inside, 1]) / v[inside, 2] < fold)
    assert np.all(np.isfinite(v[inside]))
