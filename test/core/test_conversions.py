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
from pmba_ros.core.camera import Intrinsics
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
    """Admissible observer pair of smallest |cos| per feature by enumeration (first in order)."""
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
            cos = abs(float(rays[k1] @ rays[k2]))
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


def test_select_anchors_prefers_a_right_angle_to_a_near_opposite_pair(engine: Engine) -> None:
    """Anchors of a point between cameras: the pair of largest sin(parallax), not angle.

    Camera 0 and 2 face each other across the point (170 degrees of parallax: the point lies
    between them and w = sin(theta) ~ 0, which stalled the BA); camera 1 sees it at about 90
    degrees to both. The widest angle was (2, 0); the well-conditioned pair involves camera 1.
    """
    R_wc, centers = [], []
    for azimuth in np.deg2rad([0.0, 95.0, 170.0]):
        c = 10.0 * np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
        z = -c / np.linalg.norm(c)                         # looking at the origin
        x = np.cross([0.0, 0.0, 1.0], z)
        R_wc.append(np.column_stack([x, np.cross(z, x), z]))
        centers.append(c)
    R, C = np.array(R_wc), np.array(centers)
    point = np.array([0.1, 0.2, 0.3])
    bearings = np.einsum('mji,mj->mi', R, point - C)
    intr = Intrinsics(*(np.full(3, v) for v in (800.0, 800.0, 0.0, 0.0, 0.0, 0.0)))
    problem = make_problem(R, C, intr, np.arange(3), np.zeros(3, dtype=np.int64), np.zeros((3, 2)),
                           bearings_c=bearings)
    main, assoc, ok = conversions.select_anchors(problem, R, engine=engine)
    assert ok[0]
    assert 1 in (int(main[0]), int(assoc[0]))
    rays = conversions.world_rays(problem, R)
    assert abs(float(rays[main[0]] @ rays[assoc[0]])) < 0.2


def test_min_baseline_keeps_close_cameras_from_anchoring(engine: Engine) -> None:
    """Pairs closer than ``min_baseline`` anchor nothing, in both passes; the rest as before.

    Cameras 2 and 4 sit 1 mm apart (a standstill's solved poses): above the scene tolerance,
    so they anchor features without ``min_baseline``; with 1 cm they do not, and the features
    seen from those two only have no pair.
    """
    base = forward_problem(3, n_cams=7, n_points=30)
    centers = np.array(base.centers_w)
    centers[4] = centers[2] + np.array([1e-3, 0.0, 0.0])
    problem = _uneven(make_problem(base.R_wc, centers, base.intrinsics, base.obs.cam_idx,
                                   base.obs.feat_idx, base.obs.pixels), 3)
    _, _, ok_any = conversions.select_anchors(problem, problem.R_wc,
                                              centers_w=problem.centers_w, engine=engine)
    assert np.all(ok_any[:4])
    main, assoc, ok = conversions.select_anchors(problem, problem.R_wc,
                                                 centers_w=problem.centers_w, engine=engine,
                                                 min_baseline=0.01)
    expected = _brute_force(problem, problem.R_wc, problem.centers_w, 0.01)
    for f, pair in expected.items():
        assert bool(ok[f]) == (pair is not None)
        if pair is not None:
            assert (int(main[f]), int(assoc[f])) == pair
    assert not np.any(ok[:4]) and np.count_nonzero(ok) > 20
    feats, ok_x = conversions.xyz_to_parallax(problem, problem.R_wc, problem.centers_w,
                                              np.asarray(base.points_w)[problem.feature_ids],
                                              engine=engine, min_baseline=0.01)
    np.testing.assert_array_equal(ok_x, ok)
    np.testing.assert_array_equal(feats.main_idx[ok], main[ok])
    np.testing.assert_array_equal(feats.assoc_idx[ok], assoc[ok])


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


def _awkward_points(problem, points: np.ndarray, assoc: np.ndarray) -> np.ndarray:
    """Points with some unusable and some near their associate anchor (depth-ratio swap).

    Rows 0-1 are not finite, 2-3 lie behind every camera, 4 sits on its associate anchor's
    centre and 5-6 just in front of it.
    """
    X = np.array(points)
    X[0] = np.nan
    X[1] = [np.inf, 0.0, 1.0]
    mean = problem.centers_w.mean(axis=0)
    X[2:4] = 2.0 * mean - X[2:4]
    for row, ahead in ((4, 0.0), (5, 1e-3), (6, 1e-2)):
        cam = assoc[row]
        X[row] = problem.centers_w[cam] + ahead * problem.R_wc[cam][:, 2]
    return X


@pytest.mark.parametrize('case', ['plain', 'restricted', 'rig'])
def test_xyz_to_parallax_engines_agree(case: str) -> None:
    """The compiled pass gives the numpy path's anchors, ok and features.

    Unusable points (not finite, behind the camera) take the rotation-only values, points
    close to a camera swap their anchors, coincident cameras anchor nothing. The floats are
    the same bits where numpy's products are added in the compiled order (x86-64); the test
    allows for another order's rounding.
    """
    from .helpers import engine_named
    from .test_rig import rig_problem

    if case == 'rig':
        problem, X = rig_problem(n_poses=6)
    else:
        base = forward_problem(7, n_cams=8, n_points=40)
        centers = np.array(base.centers_w)
        centers[4] = centers[2] + 1e-12          # no baseline between cameras 2 and 4
        problem = _uneven(make_problem(base.R_wc, centers, base.intrinsics, base.obs.cam_idx,
                                       base.obs.feat_idx, base.obs.pixels), 8)
        X = np.asarray(base.points_w)[problem.feature_ids]
    allowed = None
    if case == 'restricted':
        allowed = np.random.default_rng(2).random((problem.n_cams,) * 2) < 0.7
        allowed |= allowed.T
    _, assoc, _ = conversions.select_anchors(problem, problem.R_wc, allowed_pairs=allowed,
                                             centers_w=problem.centers_w)
    points = _awkward_points(problem, X, assoc)
    out = {}
    for name in ('numpy', 'compiled'):
        out[name] = conversions.xyz_to_parallax(problem, problem.R_wc, problem.centers_w,
                                                points, allowed_pairs=allowed,
                                                engine=engine_named(name))
    (f_np, ok_np), (f_c, ok_c) = out['numpy'], out['compiled']
    np.testing.assert_array_equal(ok_c, ok_np)
    np.testing.assert_array_equal(f_c.main_idx, f_np.main_idx)
    np.testing.assert_array_equal(f_c.assoc_idx, f_np.assoc_idx)
    np.testing.assert_allclose(f_c.theta, f_np.theta, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(f_c.n, f_np.n, rtol=0.0, atol=1e-12)
    # The cases above were reached: rotation-only values, swapped anchors.
    from_rot = conversions.features_from_rotations(problem, problem.R_wc, f_np.main_idx,
                                                   f_np.assoc_idx)
    np.testing.assert_array_equal(f_c.theta[:4], from_rot.theta[:4])
    np.testing.assert_array_equal(f_c.main_idx[4:7], assoc[4:7])
    assert np.any(ok_np) and (case == 'rig' or not np.all(ok_np))


def test_xyz_to_parallax_needs_anchors_that_observe(engine: Engine) -> None:
    """A feature seen once (not by camera 0) has no anchor observation: ProblemError."""
    from dataclasses import replace

    from pmba_ros.core.problem import Observations
    from pmba_ros.errors import ProblemError

    problem = forward_problem(4, n_cams=5, n_points=10)
    obs = problem.obs
    keep = (obs.feat_idx != 0) | (obs.cam_idx == 3)
    one_seen = replace(problem, obs=Observations(obs.cam_idx[keep], obs.feat_idx[keep],
                                                 obs.bearings_c[keep], obs.pixels[keep]))
    with pytest.raises(ProblemError, match='does not observe'):
        conversions.xyz_to_parallax(one_seen, problem.R_wc, problem.centers_w,
                                    np.array(problem.points_w), engine=engine)
    with pytest.raises(ValueError, match='points of shape'):
        conversions.xyz_to_parallax(problem, problem.R_wc, problem.centers_w,
                                    np.array(problem.points_w)[1:], engine=engine)


def test_compiled_coincident_pairs_are_numpys() -> None:
    """The compiled pass finds the same camera pairs without baseline, at the boundary too."""
    pytest.importorskip('numba')
    from pmba_ros.core.compiled import anchor_search

    rng = np.random.default_rng(6)
    found = 0
    for _ in range(300):
        M = int(rng.integers(1, 20))
        C = rng.normal(size=(M, 3)) * rng.choice([1e-3, 1.0, 1e3])
        scale = max(float(np.ptp(C, axis=0).max()) if M > 1 else 0.0, 1.0)
        for i, j in rng.integers(0, M, (M // 3, 2)):   # near the 1e-9 * scale boundary
            step = rng.choice([0.0, 0.5, 0.99, 1.0, 1.01]) * 1e-9 * scale
            C[i] = C[j] + step * rng.normal(size=3) / np.sqrt(3.0)
        if rng.random() < 0.2:
            C[:, 0] = np.round(C[:, 0])                  # ties in the sweep's axis
        expected = np.sort(conversions._coincident_pairs(C))
        np.testing.assert_array_equal(anchor_search.coincident_keys(C), expected)
        found += expected.shape[0]
        baseline = float(rng.choice([0.0, 1e-6, 1e-2, 1.0])) * scale
        np.testing.assert_array_equal(anchor_search.coincident_keys(C, baseline),
                                      np.sort(conversions._coincident_pairs(C, baseline)))
    assert found > 0


def test_a_parallax_past_zero_is_at_infinity_along_its_rays_not_behind_the_cameras() -> None:
    """Theta < 0 by a little: every ray is the same, but F of eq. 2 lies behind the anchor.

    It comes out at infinity (inf along its rays), and ``far_points`` puts it far along them.
    """
    from pmba_ros.core.problem import ParallaxFeatures

    problem = forward_problem(0)
    R, C = problem.R_wc, problem.centers_w
    feats, ok = conversions.xyz_to_parallax(problem, R, C, problem.points_w)
    assert np.all(ok)
    flipped = ParallaxFeatures(np.where(np.arange(feats.theta.size) == 3, -1e-7, feats.theta),
                               feats.n, feats.main_idx, feats.assoc_idx)
    X = conversions.parallax_to_xyz(R, C, flipped)
    np.testing.assert_array_equal(np.delete(X, 3, axis=0),
                                  np.delete(conversions.parallax_to_xyz(R, C, feats), 3, axis=0))
    ray = problem.points_w[3] - C[feats.main_idx[3]]
    assert not np.all(np.isfinite(X[3]))
    assert np.all(np.sign(X[3][np.isinf(X[3])]) == np.sign(ray[np.isinf(X[3])]))
    far = conversions.far_points(R, C, flipped, 1e9)[3] - C[feats.main_idx[3]]
    assert far @ ray / (np.linalg.norm(far) * np.linalg.norm(ray)) > 1 - 1e-9


def test_a_parallax_well_past_zero_written_behind_projects_as_pmbas_rays() -> None:
    """With ``behind``, F of eq. 2 for theta < 0: a pinhole projection sees PMBA's rays.

    A pinhole (BAL, Bundler) projects a point and its opposite alike; far along its rays,
    a point whose rays converge behind the cameras would not project where they point.
    """
    from pmba_ros.core import residuals
    from pmba_ros.core.problem import ParallaxFeatures

    problem = forward_problem(0)
    R, C = problem.R_wc, problem.centers_w
    feats, ok = conversions.xyz_to_parallax(problem, R, C, problem.points_w)
    assert np.all(ok)
    theta = np.where(np.arange(feats.theta.size) % 4 == 1, -0.3, feats.theta)
    flipped = ParallaxFeatures(theta, feats.n, feats.main_idx, feats.assoc_idx)
    assert not np.any(np.all(np.isfinite(conversions.parallax_to_xyz(R, C, flipped)[1::4]),
                             axis=1))
    X = conversions.parallax_to_xyz(R, C, flipped, behind=True)
    assert np.all(np.isfinite(X))
    obs = problem.obs
    rays = residuals.camera_rays_from(residuals.observation_rays(R, C, flipped, obs), R, obs)
    p_c = np.einsum('kji,kj->ki', R[obs.cam_idx], X[obs.feat_idx] - C[obs.cam_idx])
    np.testing.assert_allclose(p_c[:, :2] / p_c[:, 2:], rays[:, :2] / rays[:, 2:], atol=1e-9)
    assert np.any(p_c[:, 2] < 0)   # behind the cameras: their projections are the same
