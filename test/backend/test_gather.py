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
"""The window's track order: the compiled loop gives the numpy reference's indices."""

from __future__ import annotations

import numpy as np
from pmba_ros.backend import window
from pmba_ros.core.compiled import gather as compiled_gather
import pytest


def _keyframes(rng: np.random.Generator, n_kf: int) -> tuple[np.ndarray, np.ndarray]:
    """Return the concatenated feature ids of n_kf keyframes (unique per keyframe), offsets."""
    parts = [np.sort(rng.choice(120, size=int(rng.integers(0, 60)), replace=False))
             for _ in range(n_kf)]
    parts = [rng.permutation(p) for p in parts]   # a keyframe's ids come in any order
    sizes = np.array([p.shape[0] for p in parts], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    return np.concatenate(parts).astype(np.int64), offsets


@pytest.mark.parametrize('seed', range(6))
@pytest.mark.parametrize('cap', [0, 3, 5, 14])
@pytest.mark.parametrize('by_length', [False, True])
def test_compiled_track_order_equals_numpy(seed: int, cap: int, by_length: bool) -> None:
    """Filtered (sorted or not) or not, thinned or not: the same observations in one order."""
    rng = np.random.default_rng(seed)
    ids, offsets = _keyframes(rng, int(rng.integers(1, 40)))
    wanted = np.unique(rng.choice(150, 80))
    filters = [None, wanted, rng.permutation(wanted), np.zeros(0, np.int64)]
    for feature_filter in filters:
        want = window.ordered_tracks(ids, offsets, feature_filter, cap, by_length)
        got = compiled_gather.ordered_tracks(ids, offsets, feature_filter, cap, by_length)
        for w, g in zip(want, got, strict=True):
            assert g.dtype == np.int64
            np.testing.assert_array_equal(g, w)


def test_track_order_of_no_observations() -> None:
    """No keyframes or no observations: empty indices from both."""
    for offsets in (np.zeros(1, np.int64), np.zeros(3, np.int64)):
        ids = np.zeros(0, np.int64)
        for order in (window.ordered_tracks, compiled_gather.ordered_tracks):
            out = order(ids, offsets, None, 14, True)
            assert all(a.shape == (0,) for a in out)


@pytest.mark.parametrize('seed', range(4))
def test_unique_ids_and_membership_are_numpys(seed: int) -> None:
    """unique_ids is np.unique, is_in np.isin (keys sorted or not, empty or not)."""
    rng = np.random.default_rng(seed)
    ids = rng.integers(-5, 200, int(rng.integers(0, 300)))
    np.testing.assert_array_equal(window.unique_ids(ids), np.unique(ids))
    assert window.unique_ids(ids).dtype == np.unique(ids).dtype
    for keys in (np.unique(rng.integers(0, 200, 50)), rng.integers(0, 200, 50),
                 np.zeros(0, np.int64), np.array([7, 7, 9])):
        for values in (ids, np.sort(ids)):
            np.testing.assert_array_equal(window.is_in(values, keys), np.isin(values, keys))


def test_feature_map_keeps_the_last_update_of_each_id() -> None:
    """upsert: ids sorted and distinct, an id given twice takes its last point."""
    fmap = window.FeatureMap()
    fmap.upsert(np.array([5, 2, 9]), np.arange(9.0).reshape(3, 3))
    fmap.upsert(np.array([9, 4, 9, 2]), 10.0 + np.arange(12.0).reshape(4, 3))
    np.testing.assert_array_equal(fmap.ids, [2, 4, 5, 9])
    np.testing.assert_array_equal(fmap.points[:, 0], [19.0, 13.0, 0.0, 16.0])
    removed, _ = fmap.pop_except(np.array([4, 9]))
    np.testing.assert_array_equal(removed, [2, 5])
    np.testing.assert_array_equal(fmap.ids, [4, 9])
