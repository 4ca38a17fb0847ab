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
"""Wrong tracks or misplaced cameras: judged at the positions, and again at the BA's poses.

At the positions (the NLS) a track far from its triangulated point is wrong, unless a
camera the positions left off explains it (:func:`wrong_tracks`). A camera left tens of
steps off whose residual stays under the resection's limit still makes good tracks look
wrong (a 1,000-camera street dropped 28 of its 500 tracks, none of them wrong): at the BA's
poses every dropped track is fitted again, its point the best for those poses, and those
that fit as the tracks the BA kept do are taken back (:func:`readmitted`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import conversions
from pmba_ros.core.loss import Loss
from pmba_ros.core.models import ParallaxModel
from pmba_ros.core.problem import (
    BAProblem,
    join_features,
    make_problem,
    ParallaxFeatures,
    Parameterization,
    restrict_features,
    subset_features,
    take_features,
)
from pmba_ros.core.refit import refit_features
from pmba_ros.core.solve import IterationRecord, solve, SolveOptions, SolveResult
from pmba_ros.init import tracks
from pmba_ros.init.options import InitOptions

READMIT_RELATIVE = 3.0
"""A dropped track is taken back if its RMS reprojection error at the BA's poses is within
this many times the median of the tracks the BA kept: as the kept ones fit, not as far off
as a wrong match."""

MIN_VIEWS = 3
"""Observations a dropped track needs to be taken back. Two rays leave a point one degree
of freedom to miss by: a wrong match whose pixel lies near its epipolar line fits them."""

READMIT_ITERATIONS = 20
"""Most iterations of the BA resumed with the dropped tracks under a Cauchy loss: its poses
judge them, the BA that follows converges."""

REFIT_ITERATIONS = 30
"""Damped Gauss-Newton iterations of a dropped track's point, from its rays' midpoint."""


def resect_outlying_cameras(problem: BAProblem, centers_w: FloatArray, options: InitOptions,
                            fit: BAProblem | None = None,
                            ) -> tuple[FloatArray, IntArray, FloatArray]:
    """Re-place the cameras whose rays miss the triangulated points, before the BA.

    A camera whose residual (px, :func:`~pmba_ros.init.tracks.camera_residuals_px`) exceeds
    max(camera_min_px, camera_relative x the median over cameras) is placed again by
    resection (rotation known) from the points triangulated without it and the other
    outlying cameras, those of ``fit`` (the same cameras, fewer tracks: the ones trusted;
    default ``problem``'s). Up to half the cameras are treated so; beyond that the positions
    are left to the BA.

    Returns:
        The centres, the resected cameras (indices of ``problem``) and every camera's residual
        before resection (px).
    """
    R_wc = problem.R_wc
    X = tracks.midpoints(problem, R_wc, centers_w)
    cam_px = tracks.camera_residuals_px(problem, R_wc, centers_w, X)
    limit = max(options.camera_min_px, options.camera_relative * float(np.median(cam_px)))
    bad = np.flatnonzero(cam_px > limit)
    if bad.size == 0 or 2 * bad.size > problem.n_cams:
        return centers_w, np.zeros(0, dtype=np.int64), cam_px
    fit = problem if fit is None else fit
    good_obs = ~np.isin(fit.obs.cam_idx, bad)
    X_good = tracks.midpoints(fit, R_wc, centers_w, obs_mask=good_obs)
    # A camera with fewer than three of those points (its tracks flagged, or seen only by
    # other outlying cameras) has no position to take from them: it is left to the BA.
    placed = fit.obs.cam_idx[np.all(np.isfinite(X_good[fit.obs.feat_idx]), axis=1)]
    bad = bad[np.bincount(placed, minlength=problem.n_cams)[bad] >= 3]
    centers = centers_w.copy()
    centers[bad] = tracks.resect_centers(fit, R_wc, X_good, bad)
    return centers, bad, cam_px


def wrong_tracks(problem: BAProblem, R_wc: FloatArray, centers_w: FloatArray,
                 options: InitOptions) -> tracks.TrackCheck:
    """Return the tracks inconsistent with the positions: wrong matches, not a misplaced camera.

    A camera the positions left far off makes every track through it look wrong (on a long
    street, a tenth of all tracks): the tracks flagged at the positions are judged again
    with the outlying cameras (found on every track) re-placed from the others' points on
    the tracks not flagged (:func:`resect_outlying_cameras`), and only those wrong both
    times are flagged.
    """
    check = tracks.check_tracks(problem, R_wc, centers_w, min_px=options.track_min_px,
                                relative=options.track_relative)
    if not np.any(check.inconsistent):
        return check
    clean = subset_features(problem, ~check.inconsistent, 'inconsistent_tracks')
    placed, resected, _ = resect_outlying_cameras(problem, centers_w, options, fit=clean)
    if resected.size == 0:
        return check
    again = tracks.check_tracks(problem, R_wc, placed, min_px=options.track_min_px,
                                relative=options.track_relative)
    return tracks.TrackCheck(check.rms_px, check.threshold_px,
                             check.inconsistent & again.inconsistent)


@dataclass(frozen=True, eq=False)
class Readmission:
    """Tracks taken back after the BA (:func:`readmitted`).

    Attributes:
        result: The last BA's result (problem: the first BA's tracks, then those taken back).
        features: The features that BA started from.
        taken: Feature ids of the tracks taken back.
        invocations: BA solves it took (1 or 2), whatever it took back.
        iterations: Their iterations, together.
    """

    result: SolveResult
    features: ParallaxFeatures
    taken: IntArray
    invocations: int
    iterations: int


def readmitted(solved: SolveResult, started: ParallaxFeatures, dropped: BAProblem,
               threshold_px: float, options: SolveOptions,
               callback: Callable[[IterationRecord], None] | None = None,
               ) -> Readmission | None:
    """Return the BA resumed with the dropped tracks that fit (None: no track to try).

    The BA without them can bend where they were the only near features (on a long street
    they hold its scale there): at its poses, good tracks can still miss by tens of pixels.
    So every dropped track is triangulated at the BA's poses, its point fitted to them
    (:func:`~pmba_ros.core.refit.refit_features`), and the BA resumed, for up to
    :data:`READMIT_ITERATIONS`, with those that pass at these poses the judgement they
    failed at the positions, under a Cauchy loss (the BA's own loss if it has one), which
    bounds what a wrong match pulls. Of those seen :data:`MIN_VIEWS` times
    or more, the tracks whose RMS reprojection error then is within
    :data:`READMIT_RELATIVE` times the median of the BA's own tracks are kept, and the BA is
    resumed once more, with its own options, without the others (not needed when all fit,
    the BA converged and the loss was the BA's own).

    Args:
        solved: The BA's result.
        started: The features that BA started from.
        dropped: The dropped tracks, on the BA's cameras (their poses are replaced).
        threshold_px: The RMS above which the tracks were judged wrong at the positions.
        options: The BA's options.
        callback: The BAs' iteration callback.

    Returns:
        The last BA, which is ``solved`` itself (and ``started``) where no track fits.
    """
    merged, feats = _appended(solved, dropped, threshold_px, options)
    if merged is None or feats is None:
        return None
    robust = replace(options, max_iterations=min(options.max_iterations, READMIT_ITERATIONS),
                     loss=Loss.CAUCHY if options.loss is Loss.NONE else options.loss)
    wide = solve(merged, robust, feats, callback=callback)
    final = wide.features
    assert isinstance(final, ParallaxFeatures)
    n_own = solved.problem.n_feats
    rms = _track_rms_px(merged, wide.R_wc, wide.centers_w, final, options)
    keep = np.arange(merged.n_feats) < n_own
    keep |= rms <= READMIT_RELATIVE * float(np.median(rms[:n_own]))
    if not np.any(keep[n_own:]):
        return Readmission(solved, started, np.zeros(0, np.int64), 1, wide.iterations)
    taken = np.asarray(merged.feature_ids[n_own:][keep[n_own:]])
    if np.all(keep) and robust.loss is options.loss and wide.converged:
        return Readmission(wide, feats, taken, 1, wide.iterations)
    start = take_features(final, np.flatnonzero(keep))
    assert isinstance(start, ParallaxFeatures)
    problem = restrict_features(merged.with_poses(wide.R_wc, wide.centers_w), keep)
    last = solve(problem, options, start, callback=callback)
    return Readmission(last, start, taken, 2, wide.iterations + last.iterations)


def _appended(solved: SolveResult, dropped: BAProblem, threshold_px: float,
              options: SolveOptions) -> tuple[BAProblem | None, ParallaxFeatures | None]:
    """Return the BA's problem and final features with the dropped tracks worth a try appended.

    Each dropped track's point is fitted to the BA's poses. Those seen :data:`MIN_VIEWS`
    times or more whose RMS is within ``threshold_px`` there are worth a try; those without
    a usable point (rays parallel, no pair of observers with a baseline) are not.
    """
    R, C, f = solved.R_wc, solved.centers_w, solved.features
    at_ba = replace(dropped, R_wc=R, centers_w=C)
    at_ba = replace(at_ba, points_w=tracks.midpoints(at_ba, R, C))
    back, found = conversions.initial_features(at_ba, Parameterization.PMBA)
    if back.n_feats == 0 or not isinstance(found, ParallaxFeatures) \
            or not isinstance(f, ParallaxFeatures):
        return None, None
    model = ParallaxModel(back, options.pixel_weighted)
    feats = refit_features(model, R, C, found, np.arange(back.n_feats), options.loss,
                           options.loss_scale(model), iterations=REFIT_ITERATIONS)
    worth = _track_rms_px(back, R, C, feats, options) <= threshold_px
    worth &= np.bincount(back.obs.feat_idx, minlength=back.n_feats) >= MIN_VIEWS
    if not np.any(worth):
        return None, None
    back = restrict_features(back, worth)
    tried = take_features(feats, np.flatnonzero(worth))
    assert isinstance(tried, ParallaxFeatures)
    own, obs, new = solved.problem, solved.problem.obs, back.obs
    merged = make_problem(
        R, C, own.intrinsics, np.concatenate([obs.cam_idx, new.cam_idx]),
        np.concatenate([obs.feat_idx, new.feat_idx + own.n_feats]),
        np.concatenate([obs.pixels, new.pixels]),
        bearings_c=np.concatenate([obs.bearings_c, new.bearings_c]), fixed=own.fixed,
        n_feats=own.n_feats + back.n_feats,
        feature_ids=np.concatenate([own.feature_ids, back.feature_ids]),
        pixel_jac=(None if obs.pixel_jac is None or new.pixel_jac is None
                   else np.concatenate([obs.pixel_jac, new.pixel_jac])))
    both = join_features(f, tried)
    assert isinstance(both, ParallaxFeatures)
    return merged, both


def _track_rms_px(problem: BAProblem, R_wc: FloatArray, centers_w: FloatArray,
                  feats: ParallaxFeatures, options: SolveOptions) -> FloatArray:
    """Return each feature's RMS reprojection error (px) at a state, shape (N,)."""
    model = ParallaxModel(problem, options.pixel_weighted)
    err = model.reprojection_errors_px(model.evaluate(R_wc, centers_w, feats))
    j = problem.obs.feat_idx
    counts = np.maximum(np.bincount(j, minlength=problem.n_feats), 1)
    out: FloatArray = np.sqrt(np.bincount(j, err * err, minlength=problem.n_feats) / counts)
    return out
