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
"""Wrong single observations in long tracks, found by the EG pairs (init.wrong_observations)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pmba_ros.backend.window import estimate_similarity
from pmba_ros.core import so3
from pmba_ros.core.problem import BAProblem
from pmba_ros.core.solve import SolveOptions
from pmba_ros.errors import ProblemError
from pmba_ros.init import pair_selection, pipeline, wrong_observations
from pmba_ros.init.options import InitOptions
from pmba_ros.sim import variants
from pmba_ros.sim.scenes import street_scene
import pytest


def _with_wrong_observations(problem: BAProblem, fraction: float,
                             seed: int) -> tuple[BAProblem, np.ndarray]:
    """Return the problem with ``fraction`` of its observations wrong, and which."""
    v = variants.wrong_observations(problem, fraction, seed)
    return v.problem, v.wrong_observations


def _off(problem: BAProblem, turn_camera: int | None = None) -> wrong_observations.OffTheirPairs:
    """Return the wrong observations found as the pipeline finds them.

    With ``turn_camera``, that camera's averaged rotation turned by 3 degrees first.
    """
    options = InitOptions()
    pairs, corr, _ = pair_selection.estimate_pairs(problem, options)
    pairs, comp, _ = pipeline._view_graph(problem.n_cams, pairs, options)
    pairs = pipeline._rotations(problem, pairs, comp, options)[1]
    if turn_camera is not None:
        turn = so3.exp(np.array([0.0, np.deg2rad(3.0), 0.0]))
        R = pairs.R_rel.copy()   # R_b^T R_a: the camera turned in its own frame
        R[pairs.cam_a == turn_camera] = R[pairs.cam_a == turn_camera] @ turn.T
        R[pairs.cam_b == turn_camera] = turn @ R[pairs.cam_b == turn_camera]
        pairs = replace(pairs, R_rel=R)
    return wrong_observations.off_their_pairs(problem, pairs, corr, 1.0)


@pytest.fixture(scope='module')
def street() -> BAProblem:
    """Return a 30-camera street whose tracks are long (up to 20 views)."""
    return street_scene(seed=3, n_cams=30, n_points=600).gt


def test_clean_tracks_lose_almost_nothing(street: BAProblem) -> None:
    """0.5 px noise: at most 0.2 % of the observations are taken for wrong ones."""
    off = _off(street)
    assert np.count_nonzero(off.wrong) <= 0.002 * len(street.obs)
    assert off.cameras_kept_whole == []
    assert 1.0 < off.threshold_px < 20.0


@pytest.mark.parametrize('noise_px', [0.5, 2.0])
def test_wrong_observations_are_found(noise_px: float) -> None:
    """A tenth of the observations at random pixels: 85 % of them found, 0.5 % of the rest taken.

    The threshold follows the noise: at 2 px most of the good observations are beyond the
    RANSAC threshold of 1 px, and they stay.
    """
    problem = street_scene(seed=3, n_cams=30, n_points=600, noise_px=noise_px).gt
    corrupted, wrong = _with_wrong_observations(problem, 0.1, seed=1)
    off = _off(corrupted)
    tested = _tested_twice(corrupted)
    assert np.count_nonzero(off.wrong & wrong) >= 0.85 * np.count_nonzero(wrong & tested)
    assert np.count_nonzero(off.wrong & ~wrong) <= 0.005 * np.count_nonzero(~wrong)
    kept = wrong_observations.without(corrupted, off.wrong)
    assert len(kept.obs) == len(corrupted.obs) - np.count_nonzero(off.wrong)
    assert kept.n_feats == corrupted.n_feats   # the numbering the pairs and results use


def _tested_twice(problem: BAProblem) -> np.ndarray:
    """Return the observations whose track has three views at least (two pairs can test it)."""
    length = np.bincount(problem.obs.feat_idx, minlength=problem.n_feats)
    return length[problem.obs.feat_idx] >= 3


def test_global_init_with_wrong_observations_places_the_cameras() -> None:
    """A tenth of the observations wrong: the cameras within 0.5 % of the street's length.

    Before, the positions followed the wrong observations (every long track held one, none
    stood out) and the cameras ended 4 % of the street's length off; the wrong observations
    the pairs do not find go after the BA, whose RMS is then the noise's (it was 10^5 px).
    """
    scene = street_scene(seed=3, n_cams=30, n_points=600)
    corrupted, _ = _with_wrong_observations(scene.gt, 0.1, seed=1)
    options = InitOptions(solve_options=SolveOptions(loss='cauchy'))
    res = pipeline.global_init(corrupted, options)
    assert res.report['summary']['observations_off_their_pairs'] > 0
    assert res.report['ba']['observations_off_after_ba'] > 0
    assert res.solve.final_rms_px < 1.0   # 0.5 px per axis
    ci = res.camera_index
    assert ci.shape[0] == scene.gt.n_cams
    true_centers = scene.gt.centers_w[ci]
    sim = estimate_similarity(scene.gt.R_wc[ci], true_centers, res.solve.R_wc,
                              res.solve.centers_w)
    _, centers = sim.apply_poses(res.solve.R_wc, res.solve.centers_w)
    error = np.linalg.norm(centers - true_centers, axis=1)
    extent = np.ptp(true_centers, axis=0).max()
    assert error.max() < 0.005 * extent, error.max() / extent


def test_a_camera_off_its_pairs_is_left_whole(street: BAProblem) -> None:
    """A camera whose rotation is 3 degrees off: its observations are not dropped, it is named.

    Every pair of it puts its observations off their epipolar lines; it is the camera that
    is wrong, and the stages that place cameras judge it.
    """
    off = _off(street, turn_camera=5)
    assert off.cameras_kept_whole == [5]
    assert not np.any(off.wrong)


@pytest.mark.parametrize('fraction', [-0.1, 1.0, float('nan')])
def test_the_variant_refuses_a_fraction_outside_zero_one(street: BAProblem,
                                                         fraction: float) -> None:
    """A fraction that is no fraction of the observations is named, not drawn from."""
    with pytest.raises(ProblemError, match='fraction must be in'):
        variants.wrong_observations(street, fraction, seed=0)
