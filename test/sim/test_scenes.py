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
"""Tests of pmba_ros.sim.scenes: determinism, noise level, visibility, problematic features."""

from __future__ import annotations

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core import so3
from pmba_ros.core.camera import project
from pmba_ros.core.problem import BAProblem
from pmba_ros.sim.scenes import (
    shuffle_cameras,
    SimScene,
    street_scene,
    synthetic_large,
    table3_scene,
)
import pytest


def reprojection_residuals_px(problem: BAProblem) -> FloatArray:
    """Return project(R_wc^T (X - C)) - pixel per observation, shape (K, 2) (px)."""
    assert problem.points_w is not None
    obs = problem.obs
    h_c = np.einsum('kji,kj->ki', problem.R_wc[obs.cam_idx],
                    problem.points_w[obs.feat_idx] - problem.centers_w[obs.cam_idx])
    return project(h_c, problem.intrinsics, obs.cam_idx) - obs.pixels


def assert_well_formed(scene: SimScene, *, pose0_fixed: bool = True) -> None:
    """Shared structural checks: >= 2 cameras per feature, sorted obs, consistent start."""
    gt, start = scene.gt, scene.start
    counts = np.bincount(gt.obs.feat_idx, minlength=gt.n_feats)
    assert counts.min() >= 2
    key = gt.obs.feat_idx * gt.n_cams + gt.obs.cam_idx
    assert np.all(np.diff(key) > 0)  # sorted by feature then camera, no duplicates
    assert start.obs is gt.obs
    assert gt.points_w is not None and start.points_w is not None
    assert gt.points_w.shape == start.points_w.shape == (gt.n_feats, 3)
    assert scene.far_mask is not None and scene.collinear_mask is not None
    assert scene.far_mask.shape == scene.collinear_mask.shape == (gt.n_feats,)
    h_c = np.einsum('kji,kj->ki', gt.R_wc[gt.obs.cam_idx],
                    gt.points_w[gt.obs.feat_idx] - gt.centers_w[gt.obs.cam_idx])
    assert np.all(h_c[:, 2] > 0)
    if pose0_fixed:  # the start keeps pose 0 at its true value
        np.testing.assert_array_equal(start.R_wc[0], gt.R_wc[0])
        np.testing.assert_array_equal(start.centers_w[0], gt.centers_w[0])


def assert_same_scene(a: SimScene, b: SimScene) -> None:
    """Assert two scenes are identical array by array."""
    for pa, pb in ((a.gt, b.gt), (a.start, b.start)):
        np.testing.assert_array_equal(pa.R_wc, pb.R_wc)
        np.testing.assert_array_equal(pa.centers_w, pb.centers_w)
        np.testing.assert_array_equal(pa.points_w, pb.points_w)
        np.testing.assert_array_equal(pa.obs.cam_idx, pb.obs.cam_idx)
        np.testing.assert_array_equal(pa.obs.feat_idx, pb.obs.feat_idx)
        np.testing.assert_array_equal(pa.obs.pixels, pb.obs.pixels)


@pytest.mark.parametrize('make', [
    lambda seed: street_scene(seed=seed),
    lambda seed: street_scene(seed=seed, n_cams=60, n_points=400, max_track_length=8,
                              jitter_m=0.05, jitter_deg=0.5),
    lambda seed: table3_scene(seed=seed),
    lambda seed: synthetic_large(seed=seed, n_cams=24, n_points=600),
])
def test_scenes_are_deterministic_per_seed(make: object) -> None:
    """The same seed gives identical scenes; another seed gives another scene."""
    assert callable(make)
    first, again, other = make(1), make(1), make(2)
    assert_same_scene(first, again)
    assert not np.array_equal(first.gt.obs.pixels[:5], other.gt.obs.pixels[:5])
    assert_well_formed(first)


def test_street_scene_default_reprojects_within_noise() -> None:
    """Street default: 20 cameras, 500 features; residuals are the injected 0.5 px noise."""
    scene = street_scene(seed=0)
    assert_well_formed(scene)
    gt = scene.gt
    assert (gt.n_cams, gt.n_feats) == (20, 500)
    assert gt.dropped == {}
    res = reprojection_residuals_px(gt)
    assert np.sqrt(np.mean(res**2)) == pytest.approx(0.5, rel=0.05)
    assert np.abs(np.mean(res)) < 0.05
    assert scene.noise_px == 0.5
    pixels = gt.obs.pixels
    assert np.all((pixels > -5) & (pixels < np.array([645.0, 485.0])))


def test_street_scene_without_noise_reprojects_exactly() -> None:
    """noise_px = 0 gives exact pixels."""
    scene = street_scene(seed=4, noise_px=0.0)
    assert np.max(np.abs(reprojection_residuals_px(scene.gt))) < 1e-9


def test_street_scene_geometry_is_forward_collinear_motion() -> None:
    """Cameras move along world x, looking along the motion; start poses are perturbed."""
    scene = street_scene(seed=0, step_m=2.0)
    gt = scene.gt
    np.testing.assert_allclose(gt.centers_w[:, 0], 2.0 * np.arange(20))
    np.testing.assert_array_equal(gt.centers_w[:, 1:], 0.0)
    np.testing.assert_allclose(gt.R_wc[:, :, 2], np.tile([1.0, 0.0, 0.0], (20, 1)))  # z_c
    np.testing.assert_allclose(gt.R_wc[:, :, 1], np.tile([0.0, 0.0, -1.0], (20, 1)))  # y_c
    rot_err_deg = np.rad2deg(so3.angle(gt.R_wc, scene.start.R_wc))
    assert 0.3 < np.median(rot_err_deg[1:]) < 4.0
    pos_err = np.linalg.norm(gt.centers_w - scene.start.centers_w, axis=1)
    assert 0.05 < np.median(pos_err[1:]) < 0.4


def test_street_scene_scales_with_step() -> None:
    """The true scene is similarity-covariant in step_m (same draws, scaled)."""
    one, two = street_scene(seed=3), street_scene(seed=3, step_m=2.0)
    assert one.gt.points_w is not None and two.gt.points_w is not None
    np.testing.assert_allclose(two.gt.points_w, 2.0 * one.gt.points_w)
    np.testing.assert_array_equal(two.gt.obs.pixels, one.gt.obs.pixels)


def test_street_scene_has_far_and_collinear_features() -> None:
    """Far features reach ~1e4 baselines; collinear ones lie within 0.5 deg of the motion."""
    scene = street_scene(seed=0)
    gt = scene.gt
    assert gt.points_w is not None and scene.far_mask is not None
    assert scene.collinear_mask is not None
    assert scene.far_mask.sum() == 150
    assert scene.collinear_mask.sum() == 15
    assert not np.any(scene.collinear_mask & ~scene.far_mask)
    dist = np.linalg.norm(gt.points_w - gt.centers_w[-1], axis=1)
    assert dist[scene.far_mask].max() > 1e3
    assert dist[scene.far_mask].max() <= 1e4 * 1.01
    assert dist[scene.far_mask].min() >= 20.0 * 0.99
    assert dist[~scene.far_mask].max() < 60.0
    rays = gt.points_w - gt.centers_w[0]
    angle_deg = np.rad2deg(np.arccos(rays[:, 0] / np.linalg.norm(rays, axis=1)))
    assert np.all(angle_deg[scene.collinear_mask] < 0.5)
    assert np.all(angle_deg[~scene.collinear_mask] > 0.5)


def test_street_scene_long_sequence_has_local_tracks() -> None:
    """With max_track_length, tracks are short, contiguous and cover the whole sequence."""
    scene = street_scene(seed=5, n_cams=300, n_points=3000, max_track_length=6)
    assert_well_formed(scene)
    gt = scene.gt
    offsets = gt.feature_offsets()
    counts = np.diff(offsets)
    assert counts.max() <= 6
    first = gt.obs.cam_idx[offsets[:-1]]
    last = gt.obs.cam_idx[offsets[1:] - 1]
    np.testing.assert_array_equal(last - first + 1, counts)  # contiguous camera runs
    per_cam = np.bincount(gt.obs.cam_idx, minlength=gt.n_cams)
    assert per_cam.min() >= 20
    assert scene.far_mask is not None
    assert np.ptp(first[scene.far_mask]) > 200  # far tracks start all along the sequence


def test_table3_scene_layout() -> None:
    """4 poses, 10 features (all seen by all poses): 8 good, 1 very far, 1 nearly collinear."""
    scene = table3_scene(seed=0)
    assert_well_formed(scene)
    gt = scene.gt
    assert (gt.n_cams, gt.n_feats, gt.n_obs) == (4, 10, 40)
    assert gt.points_w is not None and scene.far_mask is not None
    assert scene.collinear_mask is not None
    np.testing.assert_array_equal(np.flatnonzero(scene.far_mask), [8])
    np.testing.assert_array_equal(np.flatnonzero(scene.collinear_mask), [9])
    baseline = np.linalg.norm(gt.centers_w[1] - gt.centers_w[0])
    rays = gt.points_w[None, :, :] - gt.centers_w[:, None, :]
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    parallax_deg = np.rad2deg(np.arccos(np.clip(np.sum(rays[0] * rays[3], axis=1), -1, 1)))
    assert np.all(parallax_deg[:8] > 3.0)
    far = np.linalg.norm(gt.points_w[8] - gt.centers_w[0]) / baseline
    assert far == pytest.approx(1e4, rel=0.01)
    motion = gt.centers_w[3] - gt.centers_w[0]
    motion /= np.linalg.norm(motion)
    assert np.rad2deg(np.arccos(rays[0, 9] @ motion)) < 0.5
    assert parallax_deg[8] < 0.01
    assert parallax_deg[9] < 0.5


def test_shuffle_cameras_permutes_consistently() -> None:
    """Shuffled scenes have the same cameras and tracks under a permutation of indices."""
    scene = street_scene(seed=0)
    shuffled = shuffle_cameras(scene, seed=3)
    perm = np.random.default_rng(3).permutation(scene.gt.n_cams)
    assert_well_formed(shuffled, pose0_fixed=False)
    unperturbed = np.flatnonzero(perm == 0)[0]
    np.testing.assert_array_equal(shuffled.start.R_wc[unperturbed], shuffled.gt.R_wc[unperturbed])
    assert not np.array_equal(perm, np.arange(scene.gt.n_cams))
    np.testing.assert_array_equal(shuffled.gt.R_wc, scene.gt.R_wc[perm])
    np.testing.assert_array_equal(shuffled.start.centers_w, scene.start.centers_w[perm])
    np.testing.assert_array_equal(shuffled.gt.points_w, scene.gt.points_w)
    np.testing.assert_array_equal(shuffled.gt.obs.feat_idx, scene.gt.obs.feat_idx)
    old = {(int(f), int(perm[c])): tuple(px) for f, c, px in
           zip(shuffled.gt.obs.feat_idx, shuffled.gt.obs.cam_idx, shuffled.gt.obs.pixels,
               strict=True)}
    new = {(int(f), int(c)): tuple(px) for f, c, px in
           zip(scene.gt.obs.feat_idx, scene.gt.obs.cam_idx, scene.gt.obs.pixels, strict=True)}
    assert old == new
    np.testing.assert_allclose(np.sort(np.abs(reprojection_residuals_px(shuffled.gt)), axis=None),
                               np.sort(np.abs(reprojection_residuals_px(scene.gt)), axis=None))


def test_synthetic_large_is_benchmark_size() -> None:
    """Default large scene: 100 cameras, ~20000 features each seen by several cameras."""
    scene = synthetic_large(seed=0)
    gt = scene.gt
    assert gt.n_cams == 100
    assert gt.n_feats >= 19_000
    counts = np.bincount(gt.obs.feat_idx)
    assert counts.min() >= 2
    assert np.median(counts) >= 8
    assert 150_000 < gt.n_obs < 400_000
    res = reprojection_residuals_px(gt)
    assert np.sqrt(np.mean(res**2)) == pytest.approx(0.5, rel=0.02)


@pytest.mark.parametrize(('call', 'match'), [
    (lambda: street_scene(n_cams=1), 'n_cams >= 2'),
    (lambda: street_scene(noise_px=-1.0), 'noise_px'),
    (lambda: street_scene(far_fraction=1.5), 'far_fraction'),
    (lambda: street_scene(max_track_length=1), 'max_track_length'),
    (lambda: street_scene(step_m=0.0), 'step_m'),
    (lambda: synthetic_large(max_incidence_deg=95.0), 'max_incidence_deg'),
])
def test_invalid_scene_arguments_raise(call: object, match: str) -> None:
    """Invalid arguments raise ValueError with a specific message."""
    assert callable(call)
    with pytest.raises(ValueError, match=match):
        call()
