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
"""Tests of the harder problem variants (pmba_ros.sim.variants)."""

from __future__ import annotations

import numpy as np
from pmba_ros.core.camera import pixels_to_bearings
from pmba_ros.core.problem import BAProblem
from pmba_ros.errors import ProblemError
from pmba_ros.sim import variants
from pmba_ros.sim.scenes import street_scene
import pytest


@pytest.fixture(scope='module')
def problem() -> BAProblem:
    """Return a small simulated street (ground truth with noisy observations)."""
    return street_scene(3, n_cams=12, n_points=200, max_track_length=6).gt


def _observations(p: BAProblem, cam_index: np.ndarray) -> set[tuple[int, int, float, float]]:
    """Return {(input camera, feature id, u, v)} of a problem."""
    o = p.obs
    return {(int(cam_index[c]), int(p.feature_ids[f]), float(u), float(v))
            for c, f, (u, v) in zip(o.cam_idx, o.feat_idx, o.pixels, strict=True)}


def test_shuffled_keeps_every_observation_under_new_camera_numbers(problem: BAProblem) -> None:
    """Each observation reappears under its camera's new number, with the same pose."""
    v = variants.shuffled(problem, seed=1)
    assert not np.array_equal(v.camera_index, np.arange(problem.n_cams))
    assert _observations(v.problem, v.camera_index) == _observations(
        problem, np.arange(problem.n_cams))
    np.testing.assert_array_equal(v.problem.R_wc, problem.R_wc[v.camera_index])
    np.testing.assert_array_equal(v.problem.centers_w, problem.centers_w[v.camera_index])


@pytest.mark.parametrize('make', [lambda p: variants.subset(p, 0.5, 2),
                                  lambda p: variants.stride(p, 3, 1)])
def test_camera_subsets_keep_only_their_cameras_and_tracks_of_two(problem: BAProblem,
                                                                  make: object) -> None:
    """Subsets keep the chosen cameras' observations; tracks left with one view are dropped."""
    v = make(problem)  # type: ignore[operator]
    all_obs = _observations(problem, np.arange(problem.n_cams))
    chosen = set(v.camera_index.tolist())
    expected = {o for o in all_obs if o[0] in chosen}
    counts: dict[int, int] = {}
    for o in expected:
        counts[o[1]] = counts.get(o[1], 0) + 1
    expected = {o for o in expected if counts[o[1]] >= 2}
    assert _observations(v.problem, v.camera_index) == expected
    assert v.problem.points_w is not None and problem.points_w is not None
    np.testing.assert_array_equal(v.problem.points_w, problem.points_w[v.problem.feature_ids])


def test_stride_takes_every_kth_camera_and_refuses_too_few(problem: BAProblem) -> None:
    """stride(3) keeps cameras 0, 3, 6, 9; a stride leaving two cameras is an error."""
    np.testing.assert_array_equal(variants.stride(problem, 3).camera_index, [0, 3, 6, 9])
    with pytest.raises(ProblemError, match='need 3'):
        variants.stride(problem, 6)


def test_mixed_focal_changes_pixels_not_bearings(problem: BAProblem) -> None:
    """Scaled images: focal lengths spread, bearings from the new pixels are the old ones."""
    v = variants.mixed_focal(problem, 3.0, seed=4)
    ratio = v.problem.intrinsics.fx / problem.intrinsics.fx
    assert np.all((ratio >= 1 / 3.0) & (ratio <= 3.0))
    assert ratio.max() / ratio.min() > 2.0
    o = v.problem.obs
    again = pixels_to_bearings(o.pixels, v.problem.intrinsics, o.cam_idx)
    np.testing.assert_allclose(again, problem.obs.bearings_c, atol=1e-12)
    assert not np.allclose(o.pixels, problem.obs.pixels)


def test_outlier_tracks_are_added_inside_the_images(problem: BAProblem) -> None:
    """5 % wrong tracks are appended with new ids; the real observations are unchanged."""
    v = variants.outlier_tracks(problem, 0.05, seed=5)
    n_bad = round(0.05 * problem.n_feats)
    assert v.outlier_ids.shape == (n_bad,)
    assert v.problem.n_feats == problem.n_feats + n_bad
    bad = np.isin(v.problem.feature_ids, v.outlier_ids)
    good_obs = ~bad[v.problem.obs.feat_idx]
    np.testing.assert_array_equal(v.problem.obs.pixels[good_obs], problem.obs.pixels)
    pix = v.problem.obs.pixels[~good_obs]
    cams = v.problem.obs.cam_idx[~good_obs]
    for c in np.unique(cams):
        real = problem.obs.pixels[problem.obs.cam_idx == c]
        assert np.all(pix[cams == c] >= real.min(axis=0))
        assert np.all(pix[cams == c] <= real.max(axis=0))


def test_make_variants_names_every_variant_and_rejects_unknown_names(problem: BAProblem) -> None:
    """The default list is the original plus every registered variant."""
    out = variants.make_variants(problem)
    assert [v.name for v in out] == ['original', *variants.VARIANTS]
    with pytest.raises(ProblemError, match='unknown variants'):
        variants.make_variants(problem, ['nope'])
