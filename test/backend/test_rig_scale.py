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
"""A rig's map scale from the solves' scale tension."""

from __future__ import annotations

import numpy as np
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.motion import RunScale
from pmba_ros.backend.rig_scale import rescale_map, RESCALE_MIN, RigScale
from pmba_ros.backend.window import FeatureMap, KeyframeStatus, KeyframeStore, LandmarkStore


def test_each_solve_takes_its_share_of_the_step_bounded() -> None:
    """1 / window_size of -slope / curvature, applied once the shares reach RESCALE_MIN."""
    config = BackendConfig(window_size=20, fallback_max_scale_jump=0.1)
    scale = RigScale()
    for slope, curvature in ((np.nan, 1.0), (1.0, 0.0), (1.0, -5.0), (np.inf, 1.0)):
        assert scale.take(slope, curvature, config) is None
    assert scale.pending == 0.0
    # A step of -1 %: -0.05 % per solve, the map rescaled at the second.
    assert scale.take(10.0, 1000.0, config) is None
    factor = scale.take(10.0, 1000.0, config)
    assert factor is not None and abs(factor - (1.0 - 2 * 0.0005)) < 1e-12 <= RESCALE_MIN
    assert scale.pending == 0.0
    # No solve moves the scale by more than its share of the largest jump a solve may make.
    assert scale.take(-1e6, 1.0, config) == 1.0 + 0.1 / 20


def test_rescaling_keeps_the_newest_keyframe_and_scales_everything_else() -> None:
    """Keyframes, features, landmarks and the run's summed path, about the newest keyframe."""
    kf = KeyframeStore()
    for i in range(4):
        kf.add(i, (np.eye(3), np.array([float(i), 0.0, 0.0])), None, KeyframeStatus.FIXED)
    kf.C_map[:4] = np.column_stack([np.arange(4.0), np.zeros(4), np.zeros(4)])
    features, landmarks, run = FeatureMap(), LandmarkStore(10), RunScale()
    features.upsert(np.array([7, 9]), np.array([[3.0, 4.0, 0.0], [np.nan, np.nan, np.nan]]))
    landmarks.add(np.array([[0.0, 0.0, 3.0]]))
    run.scale(kf, 1.0)
    rescale_map(kf, features, landmarks, run, 0.5)
    np.testing.assert_allclose(kf.C_map[:4, 0], [1.5, 2.0, 2.5, 3.0])
    np.testing.assert_allclose(features.points[0], [3.0, 2.0, 0.0])
    assert np.all(np.isnan(features.points[1]))
    np.testing.assert_allclose(landmarks.points(), [[1.5, 0.0, 1.5]])
    assert abs(run.scale(kf, 1.0) - 0.5) < 1e-12
