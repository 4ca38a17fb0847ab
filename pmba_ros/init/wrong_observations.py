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
"""Wrong single observations in long tracks: off the epipolar lines of the pairs testing them.

The positions judge whole tracks (:mod:`pmba_ros.init.wrong_tracks`). A few wrong matches
spread over long tracks put one in nearly every track, none far enough from its track's
fit to stand out, and the CLS, NLS and BA follow them (a 50-image street with a tenth of its
observations moved to random pixels ended with its cameras most of the scene's extent off).
Each EG pair tests the observations it shares with its epipolar geometry, once the rotations
are averaged: an observation that most pairs testing it put far off their epipolar lines is
dropped before the features are anchored (a wrong one fits a line by chance; a good one is
off where its partner is wrong, :func:`off_their_pairs`). A camera most of whose
observations are off is left whole: it is the camera that is off, which the later stages
judge. Where wrong matches were found, the few left (in short tracks, or on a line by
chance) are judged at the BA's result, where their error stands out from the noise, and the
BA resumed without them (:func:`without_gross_errors`, as COLMAP filters its observations
after a BA); a collection without them keeps its one BA.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
import math

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray
from pmba_ros.core import baselines, conversions, residuals, so3
from pmba_ros.core.problem import BAProblem, ParallaxFeatures, restrict_features
from pmba_ros.core.solve import IterationRecord, solve, SolveOptions, SolveResult
from pmba_ros.init import covisibility, two_view
from pmba_ros.init.two_view import EGPairs

MIN_TESTS = 2
"""Pairs that must test an observation before it can be dropped: one pair alone cannot tell
which of its two observations is wrong."""

NOISE_FACTOR = 5.0
"""An observation is off a pair when its Sampson distance exceeds this many times the median
distance of all the pairs' correspondences (which the noise sets, whatever its size)."""

MIN_THRESHOLD_FACTOR = 3.0
"""The distance that is off is at least this many times the RANSAC threshold."""

GROSS_NOISE_FACTOR = 20.0
"""An observation the BA leaves farther than this many times its noise estimate (per axis)
from its prediction is a wrong one (a good one is within 4 or 5 of it)."""

MIN_CAMERA_OBSERVATIONS = 6
"""Observations a camera keeps after the BA's wrong ones go; one that would keep fewer is
off itself, and keeps them all."""


@dataclass(frozen=True)
class OffTheirPairs:
    """The observations that most EG pairs testing them put off their epipolar lines.

    Attributes:
        wrong: Per observation of the problem, shape (K,).
        threshold_px: The Sampson distance beyond which an observation is off a pair (px).
        cameras_kept_whole: Cameras most of whose tested observations were off, kept.
    """

    wrong: BoolArray
    threshold_px: float
    cameras_kept_whole: list[int]


def off_their_pairs(problem: BAProblem, pairs: EGPairs, corr: covisibility.PairCorrespondences,
                    ransac_threshold_px: float) -> OffTheirPairs:
    """Return the observations off the epipolar lines of most EG pairs that test them.

    Args:
        problem: The problem whose observations the pairs index.
        pairs: The EG pairs, with their rotations averaged (``R_rel``) and translation
            directions refined (:func:`~pmba_ros.init.two_view.refine_translations`).
        corr: The correspondences of the pairs tried (those of ``pairs`` among them).
        ransac_threshold_px: The pairs' RANSAC threshold (px).
    """
    obs, M = problem.obs, problem.n_cams
    K = len(obs)
    none = OffTheirPairs(np.zeros(K, dtype=bool), np.inf, [])
    if pairs.n_pairs == 0 or corr.n_pairs == 0:
        return none
    eg_keys, corr_keys = pairs.cam_a * M + pairs.cam_b, corr.cam_a * M + corr.cam_b
    order = np.argsort(eg_keys)
    which = order[np.minimum(np.searchsorted(eg_keys[order], corr_keys), order.shape[0] - 1)]
    tried = np.repeat(eg_keys[which] == corr_keys, corr.counts())
    seg = np.repeat(which, corr.counts())[tried]
    a, b = corr.obs_a[tried], corr.obs_b[tried]
    front = (obs.bearings_c[a, 2] > 1e-3) & (obs.bearings_c[b, 2] > 1e-3)
    if not np.all(front):
        seg, a, b = seg[front], a[front], b[front]
    if seg.shape[0] == 0:
        return none
    E = so3.hat(pairs.t_rel) @ pairs.R_rel
    focal = np.sqrt(problem.intrinsics.fx * problem.intrinsics.fy)[obs.cam_idx]
    error_px = (two_view.sampson_errors(E[seg], obs.bearings_c[a], obs.bearings_c[b])
                * np.sqrt(focal[a] * focal[b]))
    threshold = max(NOISE_FACTOR * float(np.median(error_px)),
                    MIN_THRESHOLD_FACTOR * ransac_threshold_px)
    fit = error_px <= threshold
    tests = np.bincount(a, minlength=K) + np.bincount(b, minlength=K)
    fits = np.bincount(a[fit], minlength=K) + np.bincount(b[fit], minlength=K)
    wrong = (tests >= MIN_TESTS) & (2 * fits < tests)
    tested_per_cam = np.bincount(obs.cam_idx[tests > 0], minlength=M)
    wrong_per_cam = np.bincount(obs.cam_idx[wrong], minlength=M)
    whole = np.flatnonzero(2 * wrong_per_cam > tested_per_cam)
    wrong &= ~np.isin(obs.cam_idx, whole)
    return OffTheirPairs(wrong, threshold, whole.tolist())


def without(problem: BAProblem, wrong: BoolArray) -> BAProblem:
    """Return ``problem`` without the observations ``wrong`` (features and numbering kept).

    A feature left with fewer than two observations is dropped where the stages that follow
    build their problems from it (``make_problem``).
    """
    if not np.any(wrong):
        return problem
    return replace(problem, obs=problem.obs.take(np.flatnonzero(~wrong)))


def without_gross_errors(result: SolveResult, floor_px: float, options: SolveOptions,
                         callback: Callable[[IterationRecord], None] | None = None,
                         ) -> tuple[SolveResult, ParallaxFeatures, int] | None:
    """Return the BA resumed without the observations it leaves grossly off (None: none).

    Off: beyond max(:data:`GROSS_NOISE_FACTOR` x the BA's noise estimate, ``floor_px``)
    from the prediction, or the point behind the camera. A feature left with fewer than two
    observations goes; the others are anchored again on their remaining observations, at
    the result's points.

    Returns:
        The resumed BA's result, the features it started from, and the observations dropped.
    """
    problem = result.problem
    feats = result.features
    if (problem.rig is not None or not isinstance(feats, ParallaxFeatures)
            or not math.isfinite(result.noise_px)):
        return None
    gross = ~(_errors_px(result, feats) <= max(GROSS_NOISE_FACTOR * result.noise_px, floor_px))
    left = np.bincount(problem.obs.cam_idx[~gross], minlength=problem.n_cams)
    gross &= left[problem.obs.cam_idx] >= MIN_CAMERA_OBSERVATIONS   # else the camera is off
    if not np.any(gross):
        return None
    obs = problem.obs.take(np.flatnonzero(~gross))
    seen = np.bincount(obs.feat_idx, minlength=problem.n_feats) >= 2
    kept = restrict_features(replace(problem.with_poses(result.R_wc, result.centers_w),
                                     obs=obs), seen)
    feats, ok = conversions.xyz_to_parallax(kept, kept.R_wc, kept.centers_w,
                                            result.points_w[seen])
    if not np.all(ok):
        kept = restrict_features(kept, ok)
        feats = ParallaxFeatures(feats.theta[ok], feats.n[ok], feats.main_idx[ok],
                                 feats.assoc_idx[ok])
    if kept.n_feats == 0:
        return None
    return solve(kept, options, feats, callback=callback), feats, int(np.sum(gross))


def _errors_px(result: SolveResult, feats: ParallaxFeatures) -> FloatArray:
    """Return each observation's pixel error at the result (inf: its point behind the camera)."""
    problem, R, obs = result.problem, result.R_wc, result.problem.obs
    h_c = residuals.camera_rays_from(
        residuals.observation_rays(R, result.centers_w, feats, obs), R, obs)
    with np.errstate(all='ignore'):
        errors: FloatArray = np.linalg.norm(
            baselines.pixel_errors(h_c, obs, problem.intrinsics), axis=1)
    errors[np.einsum('ki,ki->k', h_c, obs.bearings_c) <= 0.0] = np.inf
    return errors
