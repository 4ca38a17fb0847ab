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
"""Tests of the track consistency check (pmba_ros.init.tracks) and of the sweep's variants."""

from __future__ import annotations

import numpy as np
from pmba_ros.init.tracks import check_tracks, track_residuals_px
from pmba_ros.sim.scenes import street_scene
from pmba_ros.sim.variants import outlier_tracks


def test_true_poses_give_noise_level_residuals_and_flag_only_wrong_tracks() -> None:
    """With the true poses, real tracks sit at the noise level and added wrong ones above."""
    gt = street_scene(2, n_cams=10, n_points=300, noise_px=0.5, max_track_length=6).gt
    v = outlier_tracks(gt, 0.1, seed=3)
    p = v.problem
    rms = track_residuals_px(p, p.R_wc, p.centers_w)
    wrong = np.isin(p.feature_ids, v.outlier_ids)
    assert np.median(rms[~wrong]) < 1.0
    assert np.max(rms[~wrong]) < 3.0
    assert np.median(rms[wrong]) > 20.0
    check = check_tracks(p, p.R_wc, p.centers_w, min_px=5.0, relative=30.0)
    assert check.threshold_px == max(5.0, 30.0 * float(np.median(rms)))
    assert not np.any(check.inconsistent[~wrong])
    assert np.mean(check.inconsistent[wrong]) > 0.9


def test_far_tracks_are_measured_against_the_point_at_infinity() -> None:
    """Nearly parallel rays of a far feature are consistent even if their midpoint is not."""
    gt = street_scene(5, n_cams=8, n_points=200, noise_px=0.5, far_fraction=0.8,
                      max_depth_baselines=1e6).gt
    rms = track_residuals_px(gt, gt.R_wc, gt.centers_w)
    assert np.percentile(rms, 99) < 3.0


def test_global_init_drops_wrong_tracks_before_its_one_ba() -> None:
    """5 % added wrong tracks: dropped before the BA, which ends at the true-start optimum.

    Their observations are off the pairs' epipolar lines, or else the whole tracks off the
    positions.
    """
    from pmba_ros.core.solve import solve
    from pmba_ros.init.pipeline import global_init

    gt = street_scene(6, n_cams=12, n_points=300, noise_px=0.5).gt
    v = outlier_tracks(gt, 0.05, seed=1)
    res = global_init(v.problem)
    kept_ids = v.problem.feature_ids[res.feature_index]
    wrong = np.isin(kept_ids, v.outlier_ids)
    summary = res.report['summary']
    assert summary['inconsistent_tracks'] + summary['observations_off_their_pairs'] >= (
        v.outlier_ids.shape[0] - 1)
    assert wrong.sum() <= 1
    assert (~wrong).sum() >= 0.98 * gt.n_feats
    assert res.solve.converged
    start = res.problem.with_poses(gt.R_wc[res.camera_index], gt.centers_w[res.camera_index])
    assert v.problem.points_w is not None
    ref = solve(start.with_points(v.problem.points_w[res.feature_index]), res.solve.options)
    assert res.solve.final_rms_px <= 1.01 * ref.final_rms_px


def test_a_misplaced_camera_is_flagged_and_resected_back() -> None:
    """One camera moved by 2 m: its residual stands out and resection puts it back."""
    from pmba_ros.init import pipeline, wrong_tracks
    from pmba_ros.init.tracks import camera_residuals_px, midpoints, resect_centers

    gt = street_scene(3, n_cams=10, n_points=400, noise_px=0.0, far_fraction=0.0).gt
    assert gt.points_w is not None
    np.testing.assert_allclose(resect_centers(gt, gt.R_wc, gt.points_w, np.array([2, 7])),
                               gt.centers_w[[2, 7]], atol=1e-8)
    moved = gt.centers_w.copy()
    moved[4] += [0.5, 2.0, -1.0]
    px = camera_residuals_px(gt, gt.R_wc, moved, midpoints(gt, gt.R_wc, moved))
    assert np.argmax(px) == 4 and px[4] > 5 * np.median(px)
    centers, resected, _ = wrong_tracks.resect_outlying_cameras(gt, moved, pipeline.InitOptions())
    assert resected.tolist() == [4]
    np.testing.assert_allclose(centers[4], gt.centers_w[4], atol=0.05)
    np.testing.assert_array_equal(np.delete(centers, 4, 0), np.delete(moved, 4, 0))


def test_well_placed_cameras_are_left_alone() -> None:
    """Noisy but right positions: no camera is resected."""
    from pmba_ros.init import pipeline, wrong_tracks

    gt = street_scene(3, n_cams=10, n_points=400, noise_px=0.5).gt
    centers, resected, _ = wrong_tracks.resect_outlying_cameras(gt, gt.centers_w,
                                                                pipeline.InitOptions())
    assert resected.size == 0
    np.testing.assert_array_equal(centers, gt.centers_w)


def test_tracks_through_a_misplaced_camera_are_not_taken_for_wrong_matches() -> None:
    """One camera far off along its optical axis: only the wrong matches are flagged.

    Forward motion, as the positions of a long street can leave a camera (several steps
    along the street): the tracks of its near points miss it by tens of pixels, as wrong
    matches do. Judged once more with that camera re-placed, they are kept.
    """
    from pmba_ros.init import pipeline, wrong_tracks

    for seed in range(4):
        gt = street_scene(seed, n_cams=40, n_points=400, noise_px=0.5).gt
        variant = outlier_tracks(gt, 0.05, seed)
        problem = variant.problem
        wrong = np.isin(problem.feature_ids, variant.outlier_ids)
        moved = problem.centers_w.copy()
        step = np.median(np.linalg.norm(np.diff(moved, axis=0), axis=1))
        moved[20] += 6 * step * problem.R_wc[20][:, 2]
        options = pipeline.InitOptions()
        at_moved = check_tracks(problem, problem.R_wc, moved, min_px=options.track_min_px,
                                relative=options.track_relative)
        assert np.count_nonzero(at_moved.inconsistent & ~wrong) > 0, seed   # the case bites
        judged = wrong_tracks.wrong_tracks(problem, problem.R_wc, moved, options)
        np.testing.assert_array_equal(judged.inconsistent, wrong, err_msg=f'seed {seed}')


def test_a_misplaced_camera_without_trusted_points_is_left_to_the_ba() -> None:
    """Every track of the moved camera untrusted: no resection from nothing, no error."""
    from pmba_ros.core.problem import subset_features
    from pmba_ros.init import pipeline, wrong_tracks

    gt = street_scene(3, n_cams=10, n_points=400, noise_px=0.0, far_fraction=0.0).gt
    moved = gt.centers_w.copy()
    moved[4] += [0.5, 2.0, -1.0]
    seen_by_4 = np.isin(np.arange(gt.n_feats), gt.obs.feat_idx[gt.obs.cam_idx == 4])
    fit = subset_features(gt, ~seen_by_4, 'untrusted')
    centers, resected, _ = wrong_tracks.resect_outlying_cameras(gt, moved, pipeline.InitOptions(),
                                                                fit=fit)
    assert 4 not in resected.tolist()
    np.testing.assert_array_equal(centers[4], moved[4])
