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
"""A front-end that tracks few features (low texture): initialized, and never worse.

Two new features per keyframe (20 at the first) give 15-45 observations per keyframe: no pair
of keyframes shares ``init_min_features`` (30) well-conditioned features, and on the street
half the keyframes have fewer than ``min_observations``. Before, such a run was never
initialized (the front-end's poses passed through for its whole length).
"""

from __future__ import annotations

from test.backend.test_logic import config, run

import numpy as np
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.logic import BackendLogic
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.eval.metrics import ate, rpe
from pmba_ros.sim.sequence import simulate_sequence
import pytest


@pytest.mark.parametrize('scenario', ['street', 'aerial'])
def test_front_end_tracking_few_features_is_initialized_and_not_made_worse(
        scenario: str) -> None:
    """Tried with half the features once the batch is full: below the front-end's errors.

    Every keyframe is out; on the street the keyframes with too few observations inside the
    batch are placed between their solved neighbours (left at the front-end's poses: RPE
    4.7x the front-end's).
    """
    seq = simulate_sequence(scenario, 200, seed=0, features_per_keyframe=2)
    n_obs = np.array([f.feature_ids.shape[0] for f in seq.frames])
    assert np.median(n_obs) < 2 * BackendConfig().init_min_features
    logic = BackendLogic(config(), RosbagsBackend())
    run(logic, seq)
    assert logic.state == 'tracking' and logic.estimator.init_attempts == 1
    gt, fe, opt = seq.gt_trajectory(), seq.odom_trajectory(), logic.optimized_trajectory()
    assert len(opt) == len(seq)
    assert ate(opt, gt, 'sim3').rmse < ate(fe, gt, 'sim3').rmse
    assert rpe(opt, gt, align='sim3').rmse < rpe(fe, gt, align='sim3').rmse


def test_full_batch_halves_the_features_needed() -> None:
    """The gate and the initialization's pair thresholds follow the batch's fill."""
    cfg = BackendConfig(init_min_features=30, init_max_batch=60)
    assert [cfg.init_features_needed(n) for n in (20, 59, 60)] == [30, 30, 15]
    full, sparse = cfg.init_options(30), cfg.init_options(15)
    assert (full.min_pair_matches, full.min_pair_inliers) == (30, 20)
    assert (sparse.min_pair_matches, sparse.min_pair_inliers) == (15, 10)
