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
"""Tests of anchor selection and the XYZ <-> PMBA conversions (pmba.md §3)."""

from __future__ import annotations

import itertools

import numpy as np
from pmba_ros.core import conversions
from pmba_ros.core.engine import Engine
from pmba_ros.core.problem import make_problem
import pytest

from .helpers import forward_problem


def _uneven(problem, seed: int):
    """Keep a random subset of each feature's observers (several track lengths).

    Features 0-3 keep only cameras 2 and 4.
    """
    rng = np.random.default_rng(seed)
    obs = problem.obs
    keep = rng.random(obs.cam_idx.shape[0]) < 0.6
    only_2_4 = obs.feat_idx < 4
    keep[only_2_4] = np.isin(obs.cam_idx[only_2_4], [2, 4])
    return make_problem(problem.R_wc, problem.centers_w, problem.intrinsics,
                        obs.cam_idx[keep], obs.feat_idx[keep], obs.pixels[keep])


def _brute_force(problem, R_wc, centers_w, tol, allowed=None):
    """Widest admissible observer pair per feature by enumeration (first in pair order)."""
    rays = conversions.world_rays(problem, R_wc)
    out = {}
    for f in range(problem.n_feats):
        ks = np.flatnonzero(problem.obs.feat_idx == f)
        best, best_cos = None, 2.0
        for k1, k2 in itertools.combinations(ks, 2):
            c1, c2 = problem.obs.cam_idx[k1], problem.obs.cam_idx[k2]
            if np.linalg.norm(centers_w[c1] - centers_w[c2]) <= tol:
                continue
            if allowed is not None and not allowed[c1, c2]:
                continue
            cos = float(rays[k1] @ rays[k2])
            if cos < best_cos:
                best, best_cos = (int(c2), int(c1)), cos
        out[f] = best
    return out


@pytest.mark.parametrize('restricted', [False, True])
def test_select_anchors_takes_the_widest_admissible_pair(restricted: bool,
                                                         engine: Engine) -> None:
    """Anchors equal an enumeration of all observer pairs, with coincident cameras excluded.

    ``restricted``: only some camera pairs may anchor (the epipolar-geometry pairs of init).
    """
    base = forward_problem(3, n_cams=7, n_points=30)
    centers = np.array(base.centers_w)
    centers[4] = centers[2] + 1e-12            # no baseline between cameras 2 and 4
    problem = make_problem(base.R_wc, centers, base.intrinsics, base.obs.cam_idx,
                           base.obs.feat_idx, base.obs.pixels)
    problem = _uneven(problem, 3)
    assert len(set(np.bincount(problem.obs.feat_idx).tolist())) >= 3
    allowed = None
    if restricted:
        allowed = np.random.default_rng(5).random((7, 7)) < 0.6
        allowed |= allowed.T
    main, assoc, ok = conversions.select_anchors(problem, problem.R_wc, allowed_pairs=allowed,
                                                 centers_w=problem.centers_w, engine=engine)
    scale = float(np.ptp(centers, axis=0).max())
    expected = _brute_force(problem, problem.R_wc, problem.centers_w, scale * 1e-9, allowed)
    for f, pair in expected.items():
        assert bool(ok[f]) == (pair is not None)
        if pair is not None:
            assert (int(main[f]), int(assoc[f])) == pair
    assert not np.any(ok[:4])                 # seen from one place only: no anchor pair
    assert not np.any((np.minimum(main, assoc) == 2) & (np.maximum(main, assoc) == 4) & ok)


def test_check_features_names_what_does_not_fit() -> None:
    """Features of another size, anchors outside the problem or not observing: ProblemError."""
    from dataclasses import replace

    from pmba_ros.core.problem import Parameterization
    from pmba_ros.errors import ProblemError

    problem = _uneven(forward_problem(3, n_cams=5, n_points=20), 4)
    feats = conversions.features_from_rotations(problem, problem.R_wc, *_anchors_of(problem))
    conversions.check_features(problem, feats, Parameterization.PMBA)
    both = conversions.anchor_observations(problem, np.stack([feats.main_idx,
                                                             feats.assoc_idx], axis=1))
    np.testing.assert_array_equal(both[:, 1],
                                  conversions.anchor_observations(problem, feats.assoc_idx))
    n = problem.n_feats
    unseen = np.where(np.arange(n) == 0, 0, feats.assoc_idx)   # feature 0: cameras 2, 4 only
    bad = {
        'do not fit param': (feats, Parameterization.XYZ),
        'rows for': (replace(feats, theta=feats.theta[1:]), Parameterization.PMBA),
        'non-finite': (replace(feats, theta=np.where(np.arange(n) == 3, np.nan, feats.theta)),
                       Parameterization.PMBA),
        'assoc_idx: unknown camera': (replace(feats, assoc_idx=feats.assoc_idx + 5),
                                      Parameterization.PMBA),
        'main anchor == associate': (replace(feats, assoc_idx=feats.main_idx),
                                     Parameterization.PMBA),
        'does not observe': (replace(feats, assoc_idx=unseen), Parameterization.PMBA),
    }
    for match, (f, param) in bad.items():
        with pytest.raises(ProblemError, match=match):
            conversions.check_features(problem, f, param)


def _anchors_of(problem):
    main, assoc, ok = conversions.select_anchors(problem, problem.R_wc,
                                                 centers_w=problem.centers_w)
    assert ok.all()
    return main, assoc
