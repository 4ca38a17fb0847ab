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
