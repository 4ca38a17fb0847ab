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
"""Tests of problem validation: bad input gets a clear error or a counted drop."""

from __future__ import annotations

import numpy as np
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.problem import make_problem
from pmba_ros.errors import ProblemError
import pytest


def _inputs(n_cams: int = 3):
    R = np.broadcast_to(np.eye(3), (n_cams, 3, 3)).copy()
    P = np.column_stack([np.arange(n_cams, dtype=float), np.zeros(n_cams), np.zeros(n_cams)])
    intr = Intrinsics.uniform(n_cams, 500, 500, 320, 240)
    cam = np.array([0, 1, 2, 0, 1, 2, 0])
    feat = np.array([0, 0, 0, 1, 1, 1, 2])
    pix = np.full((7, 2), 300.0)
    return R, P, intr, cam, feat, pix


def test_valid_problem_drops_single_observation_features() -> None:
    """Feature 2 has one observation: it is dropped and counted, the rest is kept."""
    p = make_problem(*_inputs())
    assert (p.n_cams, p.n_feats, p.n_obs) == (3, 2, 6)
    assert p.dropped == {'single_observation_features': 1,
                         'observations_of_dropped_features': 1}
    assert not p.obs.cam_idx.flags.writeable


def test_non_finite_observations_are_dropped_and_counted() -> None:
    """Non-finite pixels (NaN, inf) are dropped with a count; nothing else is lost."""
    R, P, intr, cam, feat, pix = _inputs()
    pix[0, 0] = np.nan
    pix[4, 1] = np.inf
    p = make_problem(R, P, intr, cam, feat, pix)
    assert p.dropped['non_finite_observations'] == 2
    assert p.n_obs == 4 and np.all(np.isfinite(p.obs.bearings_c))


def test_pixel_jacobians_follow_their_observations_and_weigh_the_errors() -> None:
    """A camera's own d(pixel)/d(bearing) goes with its observation and replaces the pinhole's.

    Rows with a non-finite one are dropped like non-finite bearings; the pixel-weighted
    residuals and the reprojection errors scale with it (twice the pinhole's: twice them).
    """
    from pmba_ros.core.conversions import initial_features
    from pmba_ros.core.models import ParallaxModel
    from pmba_ros.core.problem import Parameterization
    from pmba_ros.sim.scenes import street_scene

    problem = street_scene(seed=1).start
    obs = problem.obs
    pinhole = problem.intrinsics
    v = obs.bearings_c
    jac = np.zeros((len(obs), 2, 3))
    fx = pinhole.fx[obs.cam_idx]
    jac[:, 0, 0] = jac[:, 1, 1] = fx / v[:, 2]
    jac[:, :, 2] = -fx[:, None] * v[:, :2] / v[:, 2:3] ** 2
    args = (problem.R_wc, problem.centers_w, pinhole, obs.cam_idx, obs.feat_idx, obs.pixels)
    kw = {'bearings_c': v, 'points_w': problem.points_w}
    twice = jac * 2.0
    twice[[0, 5]] = np.nan
    same = make_problem(*args, **kw, pixel_jac=jac)
    doubled = make_problem(*args, **kw, pixel_jac=twice)
    assert doubled.dropped['non_finite_observations'] == 2
    keep = np.ones(len(obs), bool)
    keep[[0, 5]] = False
    np.testing.assert_array_equal(doubled.obs.pixel_jac, twice[keep])
    np.testing.assert_array_equal(doubled.obs.take(np.arange(3)).pixel_jac, twice[keep][:3])
    plain = make_problem(*args, **kw)
    _, feats = initial_features(plain, Parameterization.PMBA)
    state = (plain.R_wc, plain.centers_w, feats)
    ev_plain = ParallaxModel(plain, pixel_weighted=True).evaluate(*state)
    ev_same = ParallaxModel(same, pixel_weighted=True).evaluate(*state)
    np.testing.assert_allclose(ev_same.residuals, ev_plain.residuals, rtol=1e-9, atol=1e-12)
    model = ParallaxModel(make_problem(*args, **kw, pixel_jac=jac * 2.0), pixel_weighted=True)
    ev = model.evaluate(*state)
    np.testing.assert_allclose(ev.residuals, 2.0 * ev_plain.residuals, rtol=1e-9, atol=1e-12)
    # Reprojection errors to first order in the error: the pinhole's where the errors are small.
    err = model.reprojection_errors_px(ev)
    exact = ParallaxModel(plain).reprojection_errors_px(ev_plain)
    small = exact < 1.0
    np.testing.assert_allclose(err[small], 2.0 * exact[small], rtol=1e-2, atol=1e-6)
    with pytest.raises(ProblemError, match='pixel_jac'):
        make_problem(*args, **kw, pixel_jac=jac[:, :, :2])


@pytest.mark.parametrize('field,value,match', [
    ('cam', np.array([0, 1, 5, 0, 1, 2, 0]), 'unknown camera index 5'),
    ('feat', np.array([0, 0, 0, 1, 1, -1, 2]), 'unknown feature index -1'),
    ('pix', np.zeros((6, 2)), 'expected cam_idx'),
])
def test_structural_errors_raise(field: str, value: np.ndarray, match: str) -> None:
    """Unknown indices and wrong shapes raise ProblemError naming the problem."""
    R, P, intr, cam, feat, pix = _inputs()
    args = {'cam': cam, 'feat': feat, 'pix': pix}
    args[field] = value
    with pytest.raises(ProblemError, match=match):
        make_problem(R, P, intr, args['cam'], args['feat'], args['pix'])


def test_non_finite_pose_raises() -> None:
    """A NaN pose is an error naming the pose."""
    R, P, intr, cam, feat, pix = _inputs()
    P[1, 0] = np.nan
    with pytest.raises(ProblemError, match=r'pose\(s\) \[1\]'):
        make_problem(R, P, intr, cam, feat, pix)


def test_duplicate_observation_is_dropped() -> None:
    """The same (camera, feature) twice keeps the first and counts the second."""
    R, P, intr, cam, feat, pix = _inputs()
    cam = np.append(cam, 0)
    feat = np.append(feat, 0)
    pix = np.vstack([pix, [1.0, 1.0]])
    p = make_problem(R, P, intr, cam, feat, pix)
    assert p.dropped['duplicate_observations'] == 1


def test_permute_features_renumbers_and_keeps_camera_order() -> None:
    """Feature order[j] becomes j; observations stay sorted by feature, then camera."""
    from pmba_ros.core.problem import permute_features

    from .helpers import forward_problem

    base = forward_problem(5, n_cams=6, n_points=25)
    keep = np.random.default_rng(5).random(base.n_obs) < 0.7
    problem = make_problem(base.R_wc, base.centers_w, base.intrinsics, base.obs.cam_idx[keep],
                           base.obs.feat_idx[keep], base.obs.pixels[keep],
                           points_w=base.points_w)
    order = np.random.default_rng(6).permutation(problem.n_feats)
    out = permute_features(problem, order)
    obs = out.obs
    assert np.all(np.diff(obs.feat_idx) >= 0)
    same = np.diff(obs.feat_idx) == 0
    assert np.all(np.diff(obs.cam_idx)[same] > 0)
    np.testing.assert_array_equal(out.feature_ids, problem.feature_ids[order])
    np.testing.assert_array_equal(out.points_w, problem.points_w[order])

    def triples(p):
        return {(int(p.feature_ids[f]), int(c), tuple(px))
                for f, c, px in zip(p.obs.feat_idx, p.obs.cam_idx, p.obs.pixels, strict=True)}

    assert triples(out) == triples(problem)


def test_observation_order_is_the_same_sorted_or_not() -> None:
    """Input already sorted by feature, pose and rig camera gives the problem shuffled input does.

    The sort key falls back to a lexicographic sort where the combined index could overflow.
    """
    from pmba_ros.core.problem import _feature_camera_order, Rig

    rng = np.random.default_rng(7)
    K, M = 300, 6
    cam, feat, rig_cam = rng.integers(0, M, K), rng.integers(0, 40, K), rng.integers(0, 2, K)
    rig = Rig(np.tile(np.eye(3), (2, 1, 1)), np.array([[0.0, 0, 0], [0.2, 0, 0]]))
    R = np.tile(np.eye(3), (M, 1, 1))
    P = np.column_stack([np.arange(M, dtype=float), np.zeros(M), np.zeros(M)])
    intr = Intrinsics.uniform(M, 500, 500, 320, 240)
    pix = rng.uniform(0, 600, (K, 2))
    shuffled = make_problem(R, P, intr, cam, feat, pix, camera=rig_cam, rig=rig)
    assert shuffled.dropped['duplicate_observations'] > 0
    reference = np.lexsort((np.arange(K), rig_cam, cam, feat))
    np.testing.assert_array_equal(_feature_camera_order(feat, cam, rig_cam, 40, M, 2), reference)
    np.testing.assert_array_equal(_feature_camera_order(feat, cam, rig_cam, 2 ** 61, M, 2),
                                  reference)
    s = reference
    in_order = make_problem(R, P, intr, cam[s], feat[s], pix[s], camera=rig_cam[s], rig=rig)
    np.testing.assert_array_equal(_feature_camera_order(feat[s], cam[s], rig_cam[s], 40, M, 2),
                                  np.arange(K))   # duplicates: not strictly in order
    for name in ('cam_idx', 'feat_idx', 'bearings_c', 'pixels', 'camera'):
        np.testing.assert_array_equal(getattr(in_order.obs, name), getattr(shuffled.obs, name))
    assert in_order.dropped == shuffled.dropped


@pytest.mark.parametrize('n_rig', [1, 2])
def test_strictly_ordered_input_gives_the_problem_of_shuffled_input(n_rig: int) -> None:
    """Observations without duplicates, in order (the back-end's): the same problem.

    Single-observation features, and with a rig features seen by two cameras of one pose
    only, are dropped and counted as from shuffled input.
    """
    from pmba_ros.core.problem import _feature_camera_order, Rig

    rng = np.random.default_rng(3)
    K, M = 400, 6
    cam, feat, rig_cam = rng.integers(0, M, K), rng.integers(0, 90, K), rng.integers(0, n_rig, K)
    key = (feat * M + cam) * n_rig + rig_cam
    _, first = np.unique(key, return_index=True)   # one observation per key, in key order
    cam, feat, rig_cam = cam[first], feat[first], rig_cam[first]
    rig = Rig(np.tile(np.eye(3), (2, 1, 1)), np.array([[0.0, 0, 0], [0.2, 0, 0]]))
    camera, rig = (rig_cam, rig) if n_rig > 1 else (None, None)
    R = np.tile(np.eye(3), (M, 1, 1))
    P = np.column_stack([np.arange(M, dtype=float), np.zeros(M), np.zeros(M)])
    intr = Intrinsics.uniform(M, 500, 500, 320, 240)
    pix = rng.uniform(0, 600, (first.shape[0], 2))
    assert _feature_camera_order(feat, cam, rig_cam, 90, M, n_rig) is None
    in_order = make_problem(R, P, intr, cam, feat, pix, camera=camera, rig=rig)
    s = rng.permutation(first.shape[0])
    shuffled = make_problem(R, P, intr, cam[s], feat[s], pix[s],
                            camera=None if camera is None else camera[s], rig=rig)
    assert in_order.dropped == shuffled.dropped
    assert in_order.dropped['single_observation_features'] > 0
    assert in_order.n_feats == shuffled.n_feats
    for name in ('cam_idx', 'feat_idx', 'bearings_c', 'pixels', 'camera'):
        np.testing.assert_array_equal(getattr(in_order.obs, name), getattr(shuffled.obs, name))
    np.testing.assert_array_equal(in_order.feature_ids, shuffled.feature_ids)


def test_uniform_intrinsics_are_shared_and_know_their_median_focal() -> None:
    """Equal uniform intrinsics are one (read-only) instance; the median focal is numpy's."""
    a = Intrinsics.uniform(4, 500, 510, 320, 240)
    assert Intrinsics.uniform(4, 500.0, 510.0, 320.0, 240.0) is a
    assert Intrinsics.uniform(5, 500, 510, 320, 240) is not a
    assert not a.fx.flags.writeable
    intr = Intrinsics(np.array([400.0, 500, 700]), np.array([410.0, 505, 690]), np.zeros(3),
                      np.zeros(3), np.zeros(3), np.zeros(3))
    assert intr.median_focal == float(np.median(np.concatenate([intr.fx, intr.fy])))
