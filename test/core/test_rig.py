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
"""Tests of multi-camera rigs: one pose per keyframe, observations through camera offsets."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pmba_ros.core import conversions, so3
from pmba_ros.core.camera import Intrinsics, project
from pmba_ros.core.engine import Engine
from pmba_ros.core.models import make_model, ParallaxModel
from pmba_ros.core.problem import (
    BAProblem,
    make_problem,
    Parameterization,
    Rig,
)
from pmba_ros.core.solve import solve, SolveOptions
from pmba_ros.errors import ProblemError
import pytest

from .helpers import check_jacobians, perturbed_state


def _rig(offset_first: bool) -> Rig:
    """Two cameras 0.5 m apart; the first is the rig frame unless ``offset_first``."""
    R = np.stack([so3.exp(np.array([0.02, -0.03, 0.01])) if offset_first else np.eye(3),
                  so3.exp(np.array([0.01, 0.02, -0.02]))])
    t = np.array([[0.05, -0.02, 0.03] if offset_first else [0.0, 0.0, 0.0],
                  [0.5, 0.01, -0.02]])
    return Rig(R, t)


def rig_problem(seed: int = 0, offset_first: bool = False, n_poses: int = 5,
                n_points: int = 40, noise_px: float = 0.0) -> tuple[BAProblem, np.ndarray]:
    """Poses moving forward, every point seen by both cameras of every pose; returns points."""
    rng = np.random.default_rng(seed)
    rig = _rig(offset_first)
    R = so3.exp(rng.normal(0.0, 0.05, (n_poses, 3)))
    P = np.column_stack([rng.normal(0, 0.1, n_poses), rng.normal(0, 0.1, n_poses),
                         0.4 * np.arange(n_poses, dtype=float)])
    X = np.column_stack([rng.uniform(-4, 4, n_points), rng.uniform(-3, 3, n_points),
                         rng.uniform(8, 30, n_points)])
    X[:3] *= 300.0 / X[:3, 2:3]                                          # far points
    pose = np.repeat(np.arange(n_poses), 2 * n_points)
    camera = np.tile(np.repeat([0, 1], n_points), n_poses)
    feat = np.tile(np.arange(n_points), 2 * n_poses)
    R_cam = R[pose] @ rig.R_rc[camera]
    P_cam = P[pose] + np.einsum('kij,kj->ki', R[pose], rig.t_rc[camera])
    h = np.einsum('kji,kj->ki', R_cam, X[feat] - P_cam)
    intr = Intrinsics.uniform(n_poses, 450.0, 450.0, 320.0, 240.0)
    pix = project(h, intr, pose) + rng.normal(0.0, noise_px, (pose.shape[0], 2))
    problem = make_problem(R, P, intr, pose, feat, pix, points_w=X, camera=camera, rig=rig)
    return problem, X


@pytest.mark.parametrize('offset_first', [False, True])
@pytest.mark.parametrize('pixel_weighted', [False, True])
def test_rig_jacobians_match_central_differences(offset_first: bool, pixel_weighted: bool,
                                                 engine: Engine) -> None:
    """Observer blocks through the camera offsets, anchors on the rig poses: all exact."""
    problem, _ = rig_problem(offset_first=offset_first)
    R, P, feats = perturbed_state(problem, 1)
    model = ParallaxModel(problem, pixel_weighted, engine)
    slots = model.slots(feats)
    # Second-camera observations of a main anchor name its pose in two slots.
    assert np.any((slots[:, 0] == slots[:, 1]) & (problem.obs.camera == 1))
    pose_err, feat_err = check_jacobians(model, R, P, feats)
    scale = 500.0 if pixel_weighted else 1.0
    assert pose_err < 1e-6 * scale
    assert feat_err < 1e-6 * scale


def test_rig_rays_point_from_each_camera_to_the_point() -> None:
    """At the true state every residual is zero (noise-free pixels): rays go through offsets."""
    problem, _ = rig_problem()
    feats, _ = conversions.xyz_to_parallax(problem, problem.R_wc, problem.centers_w,
                                           problem.points_w)
    res = ParallaxModel(problem).residuals(problem.R_wc, problem.centers_w, feats)
    assert np.max(np.abs(res)) < 1e-9


@pytest.mark.parametrize('offset_first', [False, True])
def test_rig_solve_recovers_metric_scale(offset_first: bool, engine: Engine) -> None:
    """From poses 15 % too far apart, the stereo baseline brings back the true positions."""
    problem, X = rig_problem(offset_first=offset_first, noise_px=0.3, n_poses=6)
    true_P = problem.centers_w.copy()
    start_P = true_P[0] + 1.15 * (true_P - true_P[0])
    fixed = np.zeros(problem.n_cams, dtype=bool)
    fixed[0] = True
    start = problem.with_poses(problem.R_wc, start_P).with_points(
        true_P[0] + 1.15 * (X - true_P[0]))
    start = make_problem(start.R_wc, start.centers_w, start.intrinsics, start.obs.cam_idx,
                         start.obs.feat_idx, start.obs.pixels, points_w=start.points_w,
                         camera=start.obs.camera, rig=start.rig, fixed=fixed)
    res = solve(start, SolveOptions(max_iterations=50, engine=engine.name))
    err = np.linalg.norm(res.centers_w - true_P, axis=1)
    assert np.max(err) < 0.1 * np.max(np.linalg.norm(start_P - true_P, axis=1)), err
    # Without the second camera the scale stays where it started.
    mono = problem.obs.camera == 0
    mono_problem = make_problem(start.R_wc, start.centers_w, start.intrinsics,
                                start.obs.cam_idx[mono], start.obs.feat_idx[mono],
                                start.obs.pixels[mono], points_w=start.points_w, fixed=fixed,
                                bearings_c=np.einsum('kij,kj->ki',
                                                     start.rig.R_rc[start.obs.camera[mono]],
                                                     start.obs.bearings_c[mono]),
                                ) if not offset_first else None
    if mono_problem is not None:
        res_mono = solve(mono_problem, SolveOptions(max_iterations=50, engine=engine.name))
        spread = np.linalg.norm(res_mono.centers_w[-1] - res_mono.centers_w[0])
        assert spread > 1.1 * np.linalg.norm(true_P[-1] - true_P[0])


def test_make_problem_with_a_rig_validates_and_deduplicates() -> None:
    """Rig cameras are checked; (pose, camera, feature) repeats and one-pose features drop."""
    rig = _rig(False)
    intr = Intrinsics.uniform(2, 400.0, 400.0, 0.0, 0.0)
    R, P = np.tile(np.eye(3), (2, 1, 1)), np.array([[0.0, 0, 0], [1.0, 0, 0]])
    pose = np.array([0, 0, 1, 0, 0, 0])
    feat = np.array([0, 0, 0, 1, 1, 0])
    camera = np.array([0, 1, 0, 0, 1, 1])
    pix = np.zeros((6, 2))
    p = make_problem(R, P, intr, pose, feat, pix, camera=camera, rig=rig)
    assert p.n_feats == 1          # feature 1: two cameras of one pose, no anchor baseline
    assert p.dropped['duplicate_observations'] == 1
    assert p.dropped['single_observation_features'] == 1
    pairs = zip(p.obs.cam_idx.tolist(), p.obs.camera.tolist(), strict=True)
    assert sorted(pairs) == [(0, 0), (0, 1), (1, 0)]
    with pytest.raises(ProblemError, match='unknown rig camera 2'):
        make_problem(R, P, intr, pose, feat, pix, camera=camera + 1, rig=rig)
    with pytest.raises(ProblemError, match='no rig'):
        make_problem(R, P, intr, pose, feat, pix, camera=camera)
    with pytest.raises(ProblemError, match='pmba parameterization'):
        make_model(Parameterization.XYZ, p)
    with pytest.raises(ProblemError, match='not rotations'):
        Rig(2.0 * np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 3)))


def test_scale_tension_is_the_rigs_pull_towards_its_metric_scale(engine: Engine) -> None:
    """A noise-free rig map 0.5 % too large: the Newton step along a scaling of every pose.

    It brings the map back to its metric scale (to second order); one camera's observations
    do not see a scaling at all, and other parameterizations do not compute it.
    """
    problem, X = rig_problem()
    fixed = np.zeros(problem.n_cams, dtype=bool)
    fixed[0] = True
    large = make_problem(problem.R_wc, 1.005 * problem.centers_w, problem.intrinsics,
                         problem.obs.cam_idx, problem.obs.feat_idx, problem.obs.pixels,
                         points_w=1.005 * X, camera=problem.obs.camera, rig=problem.rig,
                         fixed=fixed)
    options = SolveOptions(max_iterations=0, scale_tension=True, engine=engine.name)
    slope, curvature = solve(large, options).scale_tension
    assert curvature > 0
    np.testing.assert_allclose(-slope / curvature, 1.0 / 1.005 - 1.0, rtol=0.02)
    mono = large.obs.camera == 0
    one_camera = make_problem(large.R_wc, large.centers_w, large.intrinsics,
                              large.obs.cam_idx[mono], large.obs.feat_idx[mono],
                              large.obs.pixels[mono], points_w=large.points_w, fixed=fixed)
    slope, curvature = solve(one_camera, options).scale_tension
    assert abs(slope) < 1e-9 and abs(curvature) < 1e-6
    xyz = replace(options, param=Parameterization.XYZ)
    assert np.all(np.isnan(solve(one_camera, xyz).scale_tension))
