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
from pmba_ros.backend.rig_scale import GATE_SIGMAS, rescale_map, RESCALE_MIN, RigScale
from pmba_ros.backend.window import FeatureMap, KeyframeStatus, KeyframeStore, LandmarkStore


def test_steps_are_weighed_as_measurements_of_one_scale_error() -> None:
    """Gains min(P / (P + window / curvature), 1 / window), P from the front-end's sigma.

    Steps wait until they reach RESCALE_MIN; none moves the scale by more than its share of
    the largest jump a solve may make; what cannot be weighed adds nothing.
    """
    config = BackendConfig(window_size=20, fallback_max_scale_jump=0.1,
                           motion_prior_translation_rel=0.05)
    scale = RigScale(config)
    for slope, curvature in ((np.nan, 1.0), (1.0, 0.0), (1.0, -5.0), (np.inf, 1.0)):
        assert scale.take(slope, curvature) == (None, 0)
    assert scale.pending == 0.0 and scale.variance == 0.05 ** 2
    # Curvature 8,000: a step's variance 20 / 8000, the scale's as large: the Kalman gain
    # 1/2 is capped at 1/20. A step of -1 %: -0.05 % pending, then -0.1 %: applied.
    assert 0.0005 < RESCALE_MIN <= 0.001
    assert scale.take(80.0, 8000.0) == (None, 0) and abs(scale.pending + 0.0005) < 1e-15
    assert abs(scale.variance - (0.95 ** 2 * 0.0025 + 0.05 ** 2 * 0.0025)) < 1e-15
    factor, left_out = scale.take(80.0, 8000.0)
    assert factor is not None and left_out == 0
    assert abs(factor - 0.999) < 1e-12 and scale.pending == 0.0
    # The cap holds while the scale is uncertain; then each solve counts less, so the
    # window's local scale does not walk the older map away.
    gains = []
    for _ in range(100):
        before = scale.variance
        scale.take(0.0, 8000.0)
        gains.append(min(before / (before + 20 / 8000.0), 1 / 20))
    assert gains[0] == 1 / 20 and np.all(np.diff(gains) <= 0) and gains[-1] < 0.02
    bounded = RigScale(config)   # a 15 % step, its 1/20 beyond the bound of 0.1 / 20
    assert bounded.take(-1200.0, 8000.0) == (1.0 + 0.1 / 20, 0)


def test_a_step_far_beyond_what_the_filter_expects_is_left_out() -> None:
    """A step beyond GATE_SIGMAS of sqrt(P + window / curvature) is counted, not weighed.

    A window at rest turning on the spot asked for 30-40 % (its new features placed by the
    rig's baseline alone); weighed, the bound per solve let each through as 0.5 %.
    """
    config = BackendConfig(window_size=20, fallback_max_scale_jump=0.1,
                           motion_prior_translation_rel=0.05)
    scale = RigScale(config)
    sigma = np.sqrt(0.05 ** 2 + 20 / 8000.0)
    assert scale.take(-2400.0, 8000.0) == (None, 1)   # 30 %
    assert scale.pending == 0.0 and scale.variance == 0.05 ** 2
    inside = 0.99 * GATE_SIGMAS * sigma * 8000.0
    assert scale.take(-inside, 8000.0) == (1.0 + 0.1 / 20, 0)   # weighed (and bounded)


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
