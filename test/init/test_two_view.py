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
"""Tests of pmba_ros.init.two_view: pair correspondences, 5-point pairs, translations."""

from __future__ import annotations

import itertools
from test.init.scenes import street_scene
from typing import Any

import numpy as np
from pmba_ros.core import so3
from pmba_ros.core.engine import Engine
from pmba_ros.core.problem import BAProblem
from pmba_ros.init import covisibility, parallax, two_view
from pmba_ros.init.options import InitOptions
import pytest


def _two_cameras(rng: np.random.Generator, n: int = 80, noise: float = 0.0,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Bearings of n points in two cameras; returns b1, b2, R_cv, t_cv (unit)."""
    R1 = so3.exp(rng.normal(scale=0.1, size=3))
    R2 = so3.exp(rng.normal(scale=0.1, size=3))
    P1, P2 = np.zeros(3), np.array([1.0, 0.2, 0.3])
    X = rng.uniform([-4, -3, 6], [4, 3, 20], size=(n, 3))
    b1 = (X - P1) @ R1
    b2 = (X - P2) @ R2
    b1 = b1 / np.linalg.norm(b1, axis=1, keepdims=True)
    b2 = b2 / np.linalg.norm(b2, axis=1, keepdims=True)
    if noise:
        b1 = b1 + rng.normal(scale=noise, size=b1.shape)
        b2 = b2 + rng.normal(scale=noise, size=b2.shape)
        b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
        b2 /= np.linalg.norm(b2, axis=1, keepdims=True)
    R_cv = R2.T @ R1
    t_cv = R2.T @ (P1 - P2)
    return b1, b2, R_cv, t_cv / np.linalg.norm(t_cv)


def test_pair_correspondences_equal_brute_force_join(rng: np.random.Generator) -> None:
    """Vectorized joins give every common feature of every pair with enough matches."""
    n_cams, n_feats = 7, 60
    seen = rng.random((n_feats, n_cams)) < 0.45
    feat, cam = np.nonzero(seen)
    perm = rng.permutation(feat.shape[0])
    feat, cam = feat[perm].astype(np.int64), cam[perm].astype(np.int64)
    corr = covisibility.pair_correspondences(cam, feat, n_cams, min_matches=10)
    expected = {}
    for a, b in itertools.combinations(range(n_cams), 2):
        common = set(np.flatnonzero(seen[:, a] & seen[:, b]).tolist())
        if len(common) >= 10:
            expected[(a, b)] = common
    got = {}
    for p in range(corr.n_pairs):
        sl = slice(corr.offsets[p], corr.offsets[p + 1])
        a, b = int(corr.cam_a[p]), int(corr.cam_b[p])
        assert np.all(cam[corr.obs_a[sl]] == a) and np.all(cam[corr.obs_b[sl]] == b)
        assert np.array_equal(feat[corr.obs_a[sl]], feat[corr.obs_b[sl]])
        got[(a, b)] = set(feat[corr.obs_a[sl]].tolist())
    assert got == expected
    counts = covisibility.covisibility_counts(cam, feat, n_cams)
    for (a, b), common in expected.items():
        assert counts[a, b] == len(common)


def _tracks(rng: np.random.Generator, n_cams: int, n_feats: int,
            longest: int) -> tuple[np.ndarray, np.ndarray]:
    """Return cam_idx, feat_idx of tracks of 1 to ``longest`` views, in random order."""
    lengths = rng.integers(1, longest + 1, n_feats)
    cam = np.concatenate([rng.choice(n_cams, k, replace=False) for k in lengths])
    feat = np.repeat(np.arange(n_feats), lengths)
    perm = rng.permutation(cam.shape[0])
    return cam[perm].astype(np.int64), feat[perm].astype(np.int64)


def test_pair_correspondence_engines_agree(engine: Engine) -> None:
    """The compiled join gives the numpy reference's arrays, capped and sampled ones too."""
    rng = np.random.default_rng(3)
    n_cams = 40
    cam, feat = _tracks(rng, n_cams, 3000, 30)
    counts = covisibility.covisibility_counts(cam, feat, n_cams, 'numpy')
    np.testing.assert_array_equal(
        covisibility.covisibility_counts(cam, feat, n_cams, engine.name), counts)
    mask = (counts >= 40) & (rng.random(counts.shape) < 0.5)
    cases: list[dict[str, Any]] = [
        {'min_matches': 5}, {'min_matches': 30, 'max_partners': 4},
        {'min_matches': 0, 'pairs': mask, 'max_per_pair': 17, 'counts': counts},
        {'min_matches': 0, 'pairs': mask, 'max_per_pair': 1}]
    for kwargs in cases:
        ref = covisibility.pair_correspondences(cam, feat, n_cams, engine='numpy', **kwargs)
        out = covisibility.pair_correspondences(cam, feat, n_cams, engine=engine.name,
                                                **kwargs)
        assert ref.obs_a.shape[0] > 100
        for field in ('cam_a', 'cam_b', 'offsets', 'obs_a', 'obs_b'):
            np.testing.assert_array_equal(getattr(out, field), getattr(ref, field))


def test_compiled_join_refuses_counts_of_other_tracks() -> None:
    """Counts that are not the tracks' are an error, not writes past the arrays' end."""
    pytest.importorskip('numba')
    from pmba_ros.core.compiled import track_pairs

    rng = np.random.default_rng(4)
    cam, feat = _tracks(rng, 10, 200, 8)
    order = np.lexsort((cam, feat))
    f, c = feat[order], cam[order]
    counts = track_pairs.count_pairs(f, c, 10)
    selected = counts > 0
    _, offsets, _, _ = track_pairs.join_pairs(f, c, 10, 8, selected, counts, None)
    assert offsets[-1] == counts.sum()
    for wrong in (counts // 2, counts + 1):
        with pytest.raises(ValueError, match='not the count'):
            track_pairs.join_pairs(f, c, 10, 8, selected, wrong, None)


def test_relative_pose_5pt_recovers_noise_free_pose(rng: np.random.Generator) -> None:
    """The 5-point RANSAC returns R_cv = R_2^T R_1 and t_cv ~ R_2^T (P_1 - P_2)."""
    b1, b2, R_cv, t_cv = _two_cameras(rng)
    out = two_view.relative_pose_5pt(b1, b2, 1e-4)
    assert out is not None
    R, t, inl, ransac_inl = out
    assert np.rad2deg(so3.angle(R, R_cv)) < 1e-3
    assert np.dot(t, t_cv) > 1 - 1e-9
    assert inl.all() and ransac_inl.all()


def test_cheirality_depths_are_positive_in_front_and_flip_with_t(
        rng: np.random.Generator) -> None:
    """lambda1 R b1 + t = lambda2 b2 has positive depths for the true t, negative for -t."""
    b1, b2, R_cv, t_cv = _two_cameras(rng)
    lam1, lam2 = two_view.cheirality_depths(R_cv, t_cv, b1, b2)
    assert np.all(lam1 > 0) and np.all(lam2 > 0)
    np.testing.assert_allclose(lam1[:, None] * (b1 @ R_cv.T) + t_cv, lam2[:, None] * b2,
                               atol=1e-9)
    lam1n, lam2n = two_view.cheirality_depths(R_cv, -t_cv, b1, b2)
    assert np.all(lam1n < 0) and np.all(lam2n < 0)


def _parallax(b1: np.ndarray, b2: np.ndarray) -> float:
    """Return the rotation-compensated parallax of one pair of bearing sets, rad."""
    one = np.zeros(b1.shape[0], dtype=np.int64)
    return float(parallax.rotation_only_parallaxes(b1, b2, one, 1)[0])


def test_rotation_only_parallax_is_noise_level_for_pure_rotation(
        rng: np.random.Generator) -> None:
    """Pure rotation leaves no parallax after the Procrustes rotation; a baseline does."""
    b1, b2, _, _ = _two_cameras(rng)
    R = so3.exp(np.array([0.1, -0.2, 0.05]))
    assert _parallax(b1, b1 @ R.T) < 1e-12
    assert _parallax(b1, b2) > 1e-3


def test_refine_translations_recovers_direction_and_sign() -> None:
    """With true rotations, the smallest eigenvector gives xi(P_a - P_b) with the right sign."""
    scene = street_scene(3, n_cams=6, n_points=200, noise_px=0.0, translation_jitter_m=0.3)
    p = scene.gt
    corr = covisibility.pair_correspondences(p.obs.cam_idx, p.obs.feat_idx, p.n_cams, 20)
    pairs, _ = two_view.estimate_eg_pairs(p.obs.bearings_c, p.intrinsics.fx[p.obs.cam_idx],
                                          corr, min_parallax_px=0.0)
    assert pairs.n_pairs == corr.n_pairs
    pairs, d_ab = two_view.refine_translations(pairs, p.obs.bearings_c, p.R_wc)
    d_true = p.centers_w[pairs.cam_a] - p.centers_w[pairs.cam_b]
    d_true /= np.linalg.norm(d_true, axis=1, keepdims=True)
    np.testing.assert_allclose(np.sum(d_ab * d_true, axis=1), 1.0, atol=1e-8)


def test_eg_pairs_reject_pure_rotation_as_low_parallax() -> None:
    """Pairs of a rotating camera without baseline are rejected with reason low_parallax."""
    p = street_scene(0, n_cams=5, n_points=200, step_m=0.0, jitter_deg=8.0).gt
    corr = covisibility.pair_correspondences(p.obs.cam_idx, p.obs.feat_idx, p.n_cams, 20)
    assert corr.n_pairs > 0
    pairs, rejected = two_view.estimate_eg_pairs(
        p.obs.bearings_c, p.intrinsics.fx[p.obs.cam_idx], corr, min_parallax_px=2.0)
    assert pairs.n_pairs == 0
    assert rejected['low_parallax'] == corr.n_pairs, rejected


def test_noise_sigma_reads_the_noise_past_wrong_matches(rng: np.random.Generator) -> None:
    """A fifth of the Sampson distances far off: sigma within 10 %, the plain median not."""
    sigma = 0.7
    distances = np.abs(rng.normal(scale=sigma, size=2000))
    distances[:400] = rng.uniform(5.0, 200.0, 400)
    assert parallax.noise_sigma(distances) == pytest.approx(sigma, rel=0.1)
    assert np.median(distances) / 0.6745 > 1.2 * sigma


def _pairs_old_and_new(p: BAProblem) -> tuple[two_view.EGPairs, two_view.EGPairs]:
    """Return the pairs of ``p`` under a fixed 2 px parallax gate, and under the defaults."""
    corr = covisibility.pair_correspondences(p.obs.cam_idx, p.obs.feat_idx, p.n_cams, 20)
    args = (p.obs.bearings_c, p.intrinsics.fx[p.obs.cam_idx], corr)
    fixed, _ = two_view.estimate_eg_pairs(*args, min_parallax_px=2.0)
    options = InitOptions()
    relative, _ = two_view.estimate_eg_pairs(
        *args, min_parallax_px=options.min_pair_parallax_px,
        min_parallax_noise=options.min_pair_parallax_noise)
    return fixed, relative


def test_noisy_matches_of_a_camera_turning_in_place_have_no_baseline() -> None:
    """2 px noise leaves more than 2 px of parallax without a baseline: all pairs rejected."""
    p = street_scene(0, n_cams=5, n_points=200, step_m=0.0, jitter_deg=8.0, noise_px=2.0).gt
    fixed, relative = _pairs_old_and_new(p)
    assert fixed.n_pairs >= 3   # a fixed gate took noise for a baseline
    assert relative.n_pairs == 0


def test_clean_matches_show_a_small_baseline() -> None:
    """0.1 px noise, 0.4 m steps: pairs with 1-2 px of parallax kept, translations right."""
    p = street_scene(0, n_cams=5, n_points=300, step_m=0.4, noise_px=0.1, jitter_deg=3.0).gt
    fixed, relative = _pairs_old_and_new(p)
    assert fixed.n_pairs <= 1
    assert relative.n_pairs >= 5
    assert np.all(relative.parallax_px > 1.5 * relative.noise_px)
    t_true = np.einsum('pji,pj->pi', p.R_wc[relative.cam_b],
                       p.centers_w[relative.cam_a] - p.centers_w[relative.cam_b])
    t_true /= np.linalg.norm(t_true, axis=1, keepdims=True)
    assert np.all(np.sum(t_true * relative.t_rel, axis=1) > np.cos(np.deg2rad(0.5)))


@pytest.mark.parametrize('seed', [0, 1])
def test_eg_pairs_relative_rotations_are_accurate_at_half_pixel(seed: int) -> None:
    """USAC_FAST relative rotations are within a few hundredths of a degree."""
    p = street_scene(seed, n_cams=8, n_points=300, noise_px=0.5).gt
    corr = covisibility.pair_correspondences(p.obs.cam_idx, p.obs.feat_idx, p.n_cams, 30)
    pairs, _ = two_view.estimate_eg_pairs(p.obs.bearings_c, p.intrinsics.fx[p.obs.cam_idx],
                                          corr)
    R_true = np.swapaxes(p.R_wc[pairs.cam_b], 1, 2) @ p.R_wc[pairs.cam_a]
    err = np.rad2deg(so3.angle(R_true, pairs.R_rel))
    assert pairs.n_pairs >= 20
    assert err.mean() < 0.1


def test_max_partners_keeps_each_cameras_most_covisible_pairs() -> None:
    """With max_partners=2 on a sequence, every kept pair is a top-2 pair of one camera."""
    p = street_scene(1, n_cams=10, n_points=300).gt
    full = covisibility.pair_correspondences(p.obs.cam_idx, p.obs.feat_idx, p.n_cams, 20)
    few = covisibility.pair_correspondences(p.obs.cam_idx, p.obs.feat_idx, p.n_cams, 20,
                                            max_partners=2)
    assert 0 < few.n_pairs < full.n_pairs
    counts = covisibility.covisibility_counts(p.obs.cam_idx, p.obs.feat_idx, p.n_cams)
    sym = counts + counts.T
    for a, b in zip(few.cam_a.tolist(), few.cam_b.tolist(), strict=True):
        top_a = np.argsort(-sym[a], kind='stable')[:2]
        top_b = np.argsort(-sym[b], kind='stable')[:2]
        assert b in top_a or a in top_b
    # Every camera keeps at least its best partner.
    assert set(few.cam_a.tolist()) | set(few.cam_b.tolist()) == set(range(p.n_cams))


def test_sampled_parallax_follows_the_full_estimate_and_sees_no_baseline() -> None:
    """100 evenly spread correspondences give the parallax within noise; none without baseline.

    The full estimate is the median over all correspondences of the pair (:func:`_parallax`).
    """
    p = street_scene(2, n_cams=8, n_points=400, noise_px=0.5).gt
    corr = covisibility.pair_correspondences(p.obs.cam_idx, p.obs.feat_idx, p.n_cams, 30)
    focal = p.intrinsics.fx[p.obs.cam_idx]
    quick = parallax.sampled_parallax_px(corr, p.obs.bearings_c, focal)
    full = np.array([_parallax(
        p.obs.bearings_c[corr.obs_a[a:b]], p.obs.bearings_c[corr.obs_b[a:b]])
        for a, b in zip(corr.offsets[:-1], corr.offsets[1:], strict=True)]) * focal[0]
    assert np.all(corr.counts() > 30) and full.max() > 5.0
    np.testing.assert_allclose(quick, full, rtol=0.35, atol=1.0)
    rot = street_scene(0, n_cams=5, n_points=200, step_m=0.0, jitter_deg=8.0).gt
    corr = covisibility.pair_correspondences(rot.obs.cam_idx, rot.obs.feat_idx, rot.n_cams, 20)
    quick = parallax.sampled_parallax_px(corr, rot.obs.bearings_c,
                                         rot.intrinsics.fx[rot.obs.cam_idx])
    assert corr.n_pairs > 0 and quick.max() < 1.0


def test_top_partners_by_score_keep_each_cameras_best() -> None:
    """Each camera keeps its k best-scored pairs; a pair stays if it is best for either end."""
    cam_a = np.array([0, 0, 0, 1, 1, 2])
    cam_b = np.array([1, 2, 3, 2, 3, 3])
    score = np.array([5.0, 1.0, 3.0, 4.0, 0.5, 2.0])
    keep = covisibility.top_partners(cam_a, cam_b, score, 4, 1)
    # Best of 0: (0,1); of 1: (0,1); of 2: (1,2); of 3: (0,3).
    assert keep.tolist() == [True, False, True, True, False, False]


def test_eg_pairs_split_between_threads_are_the_same(monkeypatch: pytest.MonkeyPatch) -> None:
    """The 5-point calls in three chunks of pairs give the pairs of one thread, bit for bit."""
    from pmba_ros.core.compiled import chunks

    p = street_scene(2, n_cams=12, n_points=400, noise_px=0.5).gt
    corr = covisibility.pair_correspondences(p.obs.cam_idx, p.obs.feat_idx, p.n_cams, 20)
    args = (p.obs.bearings_c, p.intrinsics.fx[p.obs.cam_idx], corr)
    one, rejected_one = two_view.estimate_eg_pairs(*args)
    monkeypatch.setattr(chunks, 'CHUNK_OBSERVATIONS', 1)
    monkeypatch.setattr(chunks, 'max_threads', lambda: 3)
    three, rejected_three = two_view.estimate_eg_pairs(*args)
    assert one.n_pairs > 10 and rejected_three == rejected_one
    for field in ('cam_a', 'cam_b', 'R_rel', 't_rel', 'n_inliers', 'obs_a', 'obs_b'):
        np.testing.assert_array_equal(getattr(three, field), getattr(one, field))


def test_capped_correspondences_are_a_sample_of_each_pair() -> None:
    """max_per_pair keeps min(shared tracks, cap) correspondences of every pair, evenly spread."""
    p = street_scene(1, n_cams=10, n_points=300).gt
    obs = p.obs
    full = covisibility.pair_correspondences(obs.cam_idx, obs.feat_idx, p.n_cams, 20)
    mask = np.zeros((p.n_cams, p.n_cams), dtype=bool)
    mask[full.cam_a, full.cam_b] = True
    capped = covisibility.pair_correspondences(obs.cam_idx, obs.feat_idx, p.n_cams, 0,
                                               pairs=mask, max_per_pair=25)
    np.testing.assert_array_equal(capped.cam_a, full.cam_a)
    np.testing.assert_array_equal(capped.cam_b, full.cam_b)
    np.testing.assert_array_equal(capped.counts(), np.minimum(full.counts(), 25))
    assert np.any(full.counts() > 25)
    assert np.all(obs.feat_idx[capped.obs_a] == obs.feat_idx[capped.obs_b])
    seg = np.repeat(np.arange(capped.n_pairs), capped.counts())
    assert np.all(obs.cam_idx[capped.obs_a] == capped.cam_a[seg])
    assert np.all(obs.cam_idx[capped.obs_b] == capped.cam_b[seg])
    # The sample is the one sampled_parallax_px takes from the full list: the same estimate.
    focal = p.intrinsics.fx[obs.cam_idx]
    np.testing.assert_array_equal(parallax.sampled_parallax_px(capped, obs.bearings_c, focal,
                                                               25),
                                  parallax.sampled_parallax_px(full, obs.bearings_c, focal, 25))
    n, m = full.counts(), capped.counts()
    seg = np.repeat(np.arange(full.n_pairs), m)
    i = np.arange(seg.shape[0]) - np.repeat(np.cumsum(m) - m, m)
    rows = full.offsets[seg] + (i * n[seg]) // m[seg]
    np.testing.assert_array_equal(capped.obs_a, full.obs_a[rows])
    np.testing.assert_array_equal(capped.obs_b, full.obs_b[rows])


def test_pair_selection_joins_only_the_pairs_it_tries() -> None:
    """Many co-visible pairs: each camera's best partners only, with all their tracks."""
    from pmba_ros.init import pair_selection
    from pmba_ros.init.options import InitOptions

    p = street_scene(0, n_cams=30, n_points=1500, noise_px=0.5).gt
    options = InitOptions(max_pair_partners=4)
    pairs, _, entries = pair_selection.estimate_pairs(p, options)
    assert entries['pairs_covisible'] > 4 * p.n_cams
    assert entries['pairs_candidate'] <= 4 * p.n_cams
    assert pairs.n_pairs >= p.n_cams - 1
    counts = covisibility.covisibility_counts(p.obs.cam_idx, p.obs.feat_idx, p.n_cams)
    assert np.all(pairs.n_inliers <= counts[pairs.cam_a, pairs.cam_b])
    # Inliers come from all shared tracks, not from the ranking's sample.
    assert np.any(pairs.n_inliers > pair_selection.PARTNER_SAMPLE)


def test_eg_pair_engines_agree(engine: Engine) -> None:
    """The compiled model checks give the numpy reference's pairs, inliers and parallaxes.

    Some correspondences are corrupted (epipolar outliers) and some pairs see no baseline.
    """
    p = street_scene(4, n_cams=10, n_points=400, noise_px=0.5).gt
    bearings = p.obs.bearings_c.copy()
    rng = np.random.default_rng(0)
    bad = rng.choice(bearings.shape[0], bearings.shape[0] // 20, replace=False)
    bearings[bad] = bearings[rng.permutation(bad)]
    corr = covisibility.pair_correspondences(p.obs.cam_idx, p.obs.feat_idx, p.n_cams, 20)
    args = (bearings, p.intrinsics.fx[p.obs.cam_idx], corr)
    ref, rejected_ref = two_view.estimate_eg_pairs(*args, min_parallax_px=6.0, engine='numpy')
    out, rejected = two_view.estimate_eg_pairs(*args, min_parallax_px=6.0, engine=engine.name)
    assert ref.n_pairs > 10 and rejected == rejected_ref and rejected['low_parallax'] > 0
    for field in ('cam_a', 'cam_b', 'n_inliers', 'offsets', 'obs_a', 'obs_b'):
        np.testing.assert_array_equal(getattr(out, field), getattr(ref, field))
    for field in ('R_rel', 't_rel', 'parallax_px'):
        np.testing.assert_allclose(getattr(out, field), getattr(ref, field), atol=1e-12)
    # Translations re-estimated with (slightly wrong) rotations known.
    R_wc = p.R_wc @ so3.exp(rng.normal(scale=1e-3, size=(p.n_cams, 3)))
    (ref_pairs, ref_d), (out_pairs, out_d) = (
        two_view.refine_translations(ref, bearings, R_wc, name)
        for name in ('numpy', engine.name))
    np.testing.assert_allclose(out_pairs.t_rel, ref_pairs.t_rel, atol=1e-12)
    np.testing.assert_allclose(out_d, ref_d, atol=1e-12)
    # The parallaxes on a masked subset are those of the subset, with either engine.
    b1, b2 = bearings[corr.obs_a], bearings[corr.obs_b]
    seg = np.repeat(np.arange(corr.n_pairs), corr.counts())
    mask = rng.random(seg.shape[0]) < 0.5
    np.testing.assert_allclose(
        parallax.rotation_only_parallaxes(b1, b2, seg, corr.n_pairs, mask, engine.name),
        parallax.rotation_only_parallaxes(b1[mask], b2[mask], seg[mask], corr.n_pairs,
                                          engine='numpy'), atol=1e-13)


def test_compiled_parallaxes_refuse_unsorted_segments() -> None:
    """The compiled medians walk the correspondences pair by pair: unsorted input is an error."""
    pytest.importorskip('numba')
    from pmba_ros.core.compiled import epipolar

    b = np.tile([[0.0, 0.0, 1.0]], (3, 1))
    with pytest.raises(ValueError, match='sorted'):
        epipolar.median_angles(np.eye(3)[None].repeat(2, 0), b, b, np.array([1, 0, 1]),
                               np.ones(3, dtype=bool), 2)


def test_compiled_median_angles_equal_numpy_medians_with_ties() -> None:
    """Per pair, the compiled selection gives np.median's angle, odd and even counts, ties."""
    pytest.importorskip('numba')
    from pmba_ros.core.compiled import epipolar

    rng = np.random.default_rng(3)
    counts = [1, 2, 3, 4, 7, 8, 50, 51]
    seg = np.repeat(np.arange(len(counts)), counts)
    # Bearings on a few directions only, so that angles tie.
    angles = rng.choice(np.linspace(0.0, 0.3, 6), size=seg.shape[0])
    b1 = np.tile([0.0, 0.0, 1.0], (seg.shape[0], 1))
    b2 = np.column_stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)])
    mask = np.ones(seg.shape[0], dtype=bool)
    got = epipolar.median_angles(np.eye(3)[None].repeat(len(counts), 0), b1, b2, seg, mask,
                                 len(counts))
    cos = np.clip(np.sum(b1 * b2, axis=1), -1.0, 1.0)
    for p in range(len(counts)):
        c = np.sort(-cos[seg == p])
        n = c.shape[0]
        lo, hi = c[(n - 1) // 2], c[n // 2]
        # Tolerance for arccos implementations only; a wrong element is 0.03 rad off.
        assert abs(got[p] - 0.5 * (np.arccos(-lo) + np.arccos(-hi))) < 1e-12
