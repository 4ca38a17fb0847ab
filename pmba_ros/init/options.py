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
"""Options and result of the global initialization (:func:`pmba_ros.init.pipeline.global_init`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pmba_ros._json import to_jsonable
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.loss import Loss
from pmba_ros.core.problem import BAProblem, ParallaxFeatures, Parameterization
from pmba_ros.core.solve import SolveOptions, SolveResult, SolverKind
from pmba_ros.init import two_view


def _default_solve_options() -> SolveOptions:
    # The engine's (Ceres') defaults; tighten function_tolerance to compare optima closely.
    return SolveOptions(param=Parameterization.PMBA, solver=SolverKind.DOGLEG, loss=Loss.NONE)


@dataclass(frozen=True, slots=True)
class InitOptions:
    """Options of :func:`global_init`.

    Attributes:
        min_pair_matches: Minimum common tracks of an image pair to try a 5-point RANSAC.
        min_pair_inliers: Minimum cheirality inliers of an EG pair.
        max_pair_partners: If set, try only the pairs that are among the best partners of one
            of their cameras: half by shared tracks, half by a quick parallax estimate times
            the square root of the shared tracks. Only where there are more than
            ``max_pair_partners`` pairs per camera (small collections keep every pair; None:
            always every pair with enough common tracks).
        ransac_max_points: Largest number of a pair's correspondences given to the RANSAC
            (evenly spread over its tracks; None: all). The inliers, the choice of (R, t)
            and the parallax test use all of them.
        ransac_threshold_px: RANSAC threshold in pixels (divided by the pair's focal length).
        ransac_confidence: RANSAC confidence.
        ransac_method: 'usac_fast' (default) or 'usac_accurate' (both with local optimization
            refining the essential matrix on its inliers; the fast one with fewer inner
            iterations), 'usac_magsac', 'usac_default' or 'ransac' (OpenCV's classic RANSAC,
            whose minimal-sample model is several times less accurate).
        min_pair_parallax_px: Minimum median parallax (px) that the best pure rotation leaves
            on a pair's inliers; pairs below it have no usable baseline (pure rotation).
        min_pair_parallax_noise: That parallax must also be this many times the median a
            pure rotation would leave with the pair's own noise (measured from its
            epipolar distances): noisy matches leave parallax without a baseline, and
            clean ones show a small baseline.
        max_tree_disagreement_deg: Discard EG pairs whose rotation disagrees with the rotations
            chained along the maximum spanning tree by more than this.
        max_pair_disagreement_deg: After averaging, prune EG pairs that disagree with the
            averaged rotations by more than this, then average again.
        rotation_cauchy_deg: Cauchy scale (deg) of the iteratively reweighted rotation
            averaging: pairs disagreeing with the consensus by several times this lose
            their weight.
        cls_max_penalty_iterations: Active-set iterations for the CLS cheirality penalty.
        nls_cauchy_px: Cauchy scale of the NLS (eq. 13) in pixels (divided by the focal length
            of each observation's camera).
        nls_max_iterations: LM iteration limit of the NLS (a safeguard: the NLS stops on its
            tolerances well before it; the report says whether it converged).
        track_min_px: Tracks whose RMS angle to their triangulated point (px) exceeds
            max(track_min_px, track_relative x the median over all tracks) once positions
            are known are dropped as wrong matches before the BA.
        track_relative: See ``track_min_px``.
        camera_min_px: Cameras whose upper-quartile residual to the triangulated points (px)
            exceeds max(camera_min_px, camera_relative x the median over cameras) after the
            NLS are placed again by resection from the other cameras' points before the BA
            (and before the tracks flagged as wrong are judged a second time).
        camera_relative: See ``camera_min_px``.
        register_min_points: Cameras left out of the view graph's largest component are
            placed by PnP on the component's triangulated tracks when at least this many of
            their points agree (inliers within the track threshold of ``track_min_px``);
            0: never.
        theta_floor_px: Features whose rotation-only parallax theta-bar is below this (px,
            divided by the main anchor's focal length) start the BA at infinity (theta = 0).
        solve_options: Options of the final (and only) BA: PMBA with Dogleg, no loss, the
            engine's defaults otherwise (function_tolerance 1e-6, as Ceres).
    """

    min_pair_matches: int = 30
    min_pair_inliers: int = 20
    max_pair_partners: int | None = 10
    ransac_max_points: int | None = 200
    ransac_threshold_px: float = 1.0
    ransac_confidence: float = 0.999
    ransac_method: str = 'usac_fast'
    min_pair_parallax_px: float = 1.0
    min_pair_parallax_noise: float = 1.5
    max_tree_disagreement_deg: float = 5.0
    max_pair_disagreement_deg: float = 2.0
    rotation_cauchy_deg: float = 1.0
    cls_max_penalty_iterations: int = 10
    nls_cauchy_px: float = 3.0
    nls_max_iterations: int = 500
    track_min_px: float = 10.0
    track_relative: float = 30.0
    camera_min_px: float = 10.0
    camera_relative: float = 5.0
    register_min_points: int = 12
    theta_floor_px: float = 3.0
    solve_options: SolveOptions = field(default_factory=_default_solve_options)

    def __post_init__(self) -> None:
        """Validate ranges."""
        if self.min_pair_matches < 5 or self.min_pair_inliers < 5:
            msg = '`min_pair_matches` and `min_pair_inliers` must be >= 5 (5-point solver)'
            raise ValueError(msg)
        if self.max_pair_partners is not None and self.max_pair_partners < 1:
            msg = '`max_pair_partners` must be None or >= 1'
            raise ValueError(msg)
        if self.ransac_max_points is not None and self.ransac_max_points < 5:
            msg = '`ransac_max_points` must be None or >= 5 (5-point solver)'
            raise ValueError(msg)
        if self.ransac_method not in two_view.RANSAC_METHODS:
            msg = f'`ransac_method` must be one of {sorted(two_view.RANSAC_METHODS)}'
            raise ValueError(msg)
        if not 0.0 < self.ransac_confidence < 1.0:
            msg = '`ransac_confidence` must be in (0, 1)'
            raise ValueError(msg)
        for name in ('ransac_threshold_px', 'max_tree_disagreement_deg',
                     'max_pair_disagreement_deg', 'nls_cauchy_px', 'track_min_px',
                     'rotation_cauchy_deg', 'camera_min_px', 'camera_relative',
                     'track_relative'):
            if not getattr(self, name) > 0.0:
                msg = f'`{name}` must be positive'
                raise ValueError(msg)
        if self.register_min_points != 0 and self.register_min_points < 6:
            msg = '`register_min_points` must be 0 (off) or >= 6 (a pose and some to spare)'
            raise ValueError(msg)
        if min(self.min_pair_parallax_px, self.min_pair_parallax_noise,
               self.theta_floor_px) < 0.0:
            msg = ('`min_pair_parallax_px`, `min_pair_parallax_noise` and `theta_floor_px` '
                   'must be >= 0')
            raise ValueError(msg)
        if self.solve_options.param.value != 'pmba':
            msg = '`solve_options.param` must be pmba (the features are parallax features)'
            raise ValueError(msg)


@dataclass(frozen=True, eq=False)
class InitResult:
    """Result of :func:`global_init`.

    Attributes:
        problem: The problem handed to the final BA: cameras of the largest component of the
            view graph (renumbered), every feature they see twice, poses from the NLS.
        features: The PMBA features the BA started from: theta-bar and n-bar from the
            averaged rotations (Remark 5), anchors on EG pairs (on the widest pair with a
            baseline for the features recovered in the ``tracks`` stage) oriented so that
            the triangle is valid, theta = 0 (infinity) below ``InitOptions.theta_floor_px``.
        solve: The final PMBA result (its R_wc, centers_w, features and points are the output).
        camera_index: Input camera index of each camera of ``problem``, shape (M',).
        feature_index: Input feature index of each feature of ``problem``, shape (N',).
        cameras_used: Mask (M,) of input cameras that are in ``problem``.
        report: Per-stage report (see :meth:`to_report`).
        ba_invocations: Number of BA solves: 1, or 2 where tracks dropped before the first
            fit its poses and were taken back (:func:`~pmba_ros.init.wrong_tracks.readmitted`).
    """

    problem: BAProblem
    features: ParallaxFeatures
    solve: SolveResult
    camera_index: IntArray
    feature_index: IntArray
    cameras_used: BoolArray
    report: dict[str, Any]
    ba_invocations: int = 1

    @property
    def R_wc(self) -> FloatArray:
        """Final camera -> world rotations of ``problem``'s cameras, shape (M', 3, 3)."""
        return self.solve.R_wc

    @property
    def centers_w(self) -> FloatArray:
        """Final camera centres of ``problem``'s cameras, shape (M', 3)."""
        return self.solve.centers_w

    def to_report(self) -> dict[str, Any]:
        """Return the JSON-able report: one entry per stage and ``time_s`` per stage."""
        report: dict[str, Any] = to_jsonable(self.report)
        return report
