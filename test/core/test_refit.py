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
"""Features re-fitted to poses held (pmba_ros.core.refit)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pmba_ros.core import so3
from pmba_ros.core.baselines import project
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.conversions import initial_features
from pmba_ros.core.loss import Loss
from pmba_ros.core.models import make_model
from pmba_ros.core.problem import BAProblem, make_problem, ParallaxFeatures, Parameterization
from pmba_ros.core.refit import refit_features
from pmba_ros.core.solve import solve, SolveOptions
import pytest

from .helpers import forward_problem


def _feature_costs(model, problem, feats) -> np.ndarray:
    res = model.residuals(problem.R_wc, problem.centers_w, feats)
    return np.bincount(problem.obs.feat_idx, np.sum(res * res, axis=1), problem.n_feats)


@pytest.mark.parametrize('loss', [Loss.NONE, Loss.CAUCHY])
def test_a_refit_brings_features_turned_away_back_and_leaves_the_others(loss: Loss) -> None:
    """Rays turned 40 degrees off come back to their minimum; the rest stay bitwise.

    Residuals are pixels (pixel-weighted): the loss scale is 2 px.
    """
    problem, feats = initial_features(forward_problem(seed=3), Parameterization.PMBA)
    model = make_model(Parameterization.PMBA, problem, pixel_weighted=True)
    which = np.array([1, 7, 12, 30])
    turn = so3.exp(np.tile([0.0, 0.7, 0.0], (which.size, 1)))
    n = feats.n.copy()
    n[which] = np.einsum('kij,kj->ki', turn, n[which])
    bad = ParallaxFeatures(feats.theta, n, feats.main_idx, feats.assoc_idx)
    before = _feature_costs(model, problem, bad)
    fixed = refit_features(model, problem.R_wc, problem.centers_w, bad, which, loss, 2.0)
    after = _feature_costs(model, problem, fixed)
    assert np.all(after[which] < 1e-3 * before[which])
    # The same minimum as from the points that made the pixels.
    best = refit_features(model, problem.R_wc, problem.centers_w, feats, which, loss, 2.0)
    np.testing.assert_allclose(after[which], _feature_costs(model, problem, best)[which],
                               rtol=1e-4)
    if loss is Loss.NONE:
        assert np.all(after[which] <= _feature_costs(model, problem, feats)[which])
    rays = model.evaluate(problem.R_wc, problem.centers_w, fixed).rays_c
    assert np.all(np.einsum('ki,ki->k', rays, problem.obs.bearings_c) > 0.0)
    others = np.setdiff1d(np.arange(problem.n_feats), which)
    np.testing.assert_array_equal(fixed.n[others], bad.n[others])
    np.testing.assert_array_equal(fixed.theta[others], bad.theta[others])
    np.testing.assert_array_equal(bad.n, n)      # the caller's features are not written to


def _near_features_scene(seed: int, stretch: float) -> BAProblem:
    """Cameras moving forward, a few features just ahead of the last, the path's start short.

    The solve stretches the path back: its long steps carry the last cameras towards (and
    with a linearized feature step, past) the near features.
    """
    rng = np.random.default_rng(seed)
    n_cams, n_points, near = 12, 120, 6
    R = so3.exp(rng.normal(0.0, 0.01, (n_cams, 3)))
    P = np.column_stack([rng.normal(0, 0.01, (n_cams, 2)), np.arange(n_cams, dtype=float)])
    X = np.column_stack([rng.uniform(-4, 4, n_points), rng.uniform(-3, 3, n_points),
                         rng.uniform(12, 60, n_points)])
    X[:near] = np.column_stack([rng.uniform(-0.3, 0.3, near), rng.uniform(-0.2, 0.2, near),
                                n_cams - 1 + rng.uniform(0.125, 0.375, near)])
    intr = Intrinsics.uniform(n_cams, 500.0, 500.0, 320.0, 240.0)
    cam = np.repeat(np.arange(n_cams), n_points)
    feat = np.tile(np.arange(n_points), n_cams)
    h = np.einsum('kji,kj->ki', R[cam], X[feat] - P[cam])
    pix = project(h, intr, cam) + rng.normal(0.0, 0.5, (cam.shape[0], 2))
    seen = (h[:, 2] > 0) & np.all(np.abs(pix - [320, 240]) < [960, 720], axis=1)
    start = P * [1.0, 1.0, stretch] + rng.normal(0, 0.05, P.shape)
    return make_problem(R, start, intr, cam[seen], feat[seen], pix[seen], points_w=X)


@pytest.mark.parametrize(('seed', 'stretch'), [(0, 0.8), (2, 0.8), (5, 0.6)])
def test_a_poses_step_that_carries_a_camera_past_a_near_feature_is_judged_on_its_merit(
        seed: int, stretch: float) -> None:
    """The features whose rays the step turns away are re-fitted: no step is lost to them.

    Before, each such step was rejected (its ratio of actual to predicted decrease -7 to
    -16) and the trust region shrunk for a handful of features.
    """
    problem = _near_features_scene(seed, stretch)
    res = solve(problem, SolveOptions())
    assert res.converged
    assert all(h.accepted or h.rho > -1.0 or np.isnan(h.rho) for h in res.history[1:])
    from_truth = solve(replace(problem, centers_w=_near_features_scene(seed, 1.0).centers_w))
    assert res.final_cost <= from_truth.final_cost * (1.0 + 1e-6)
