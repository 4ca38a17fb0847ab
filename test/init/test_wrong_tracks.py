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
"""Tracks dropped at the positions, judged again at the BA's poses (init.wrong_tracks)."""

from __future__ import annotations

import numpy as np
from pmba_ros.core.conversions import initial_features
from pmba_ros.core.loss import Loss
from pmba_ros.core.problem import Parameterization, subset_features
from pmba_ros.core.solve import solve, SolveOptions
from pmba_ros.init.wrong_tracks import readmitted
from pmba_ros.sim.variants import outlier_tracks

from ..core.helpers import forward_problem


def _start(problem):
    """Return the problem's features from its points and the problem they belong to."""
    return initial_features(problem, Parameterization.PMBA)


def test_dropped_tracks_that_fit_the_bas_poses_are_taken_back_and_wrong_ones_not() -> None:
    """Ten good tracks and six wrong ones dropped: the good ten come back, the BA as if whole."""
    variant = outlier_tracks(forward_problem(seed=1, n_cams=8, n_points=60), 0.1, seed=2)
    problem, ids = variant.problem, variant.problem.feature_ids
    good_dropped = np.isin(ids, ids[40:50])
    wrong = np.isin(ids, variant.outlier_ids)
    assert np.count_nonzero(wrong) == 6
    options = SolveOptions()
    kept, started = _start(subset_features(problem, ~(good_dropped | wrong), 'dropped'))
    first = solve(kept, options, started)
    back = readmitted(first, started, subset_features(problem, good_dropped | wrong, 'kept'),
                      10.0, options)
    assert back is not None
    np.testing.assert_array_equal(np.sort(back.taken), np.sort(ids[good_dropped]))
    assert back.invocations == 2    # a robust BA with every dropped track, then the plain one
    solved = back.result.problem
    assert solved.n_feats == kept.n_feats + 10
    np.testing.assert_array_equal(solved.feature_ids[:kept.n_feats], kept.feature_ids)
    whole = solve(subset_features(problem, ~wrong, 'wrong'), options)
    assert back.result.converged and back.result.options.loss is Loss.NONE
    assert back.result.final_cost <= whole.final_cost * (1.0 + 1e-6)


def test_nothing_to_take_back_when_every_dropped_track_is_wrong() -> None:
    """Only wrong tracks dropped: none is worth a BA, the first BA's result stands."""
    variant = outlier_tracks(forward_problem(seed=4, n_cams=8, n_points=60), 0.1, seed=5)
    problem = variant.problem
    wrong = np.isin(problem.feature_ids, variant.outlier_ids)
    kept, started = _start(subset_features(problem, ~wrong, 'wrong'))
    first = solve(kept, SolveOptions(), started)
    back = readmitted(first, started, subset_features(problem, wrong, 'kept'), 10.0,
                      SolveOptions())
    assert back is None     # none passes the tracks' first judgement at the BA's poses
