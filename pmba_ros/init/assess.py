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
"""Judge a global initialization against PMBA started from the input's own poses and points.

The reference solves the same sub-problem (the cameras and features the initialization kept)
with the same solver options, started from the input's poses and points instead of the
pipeline's. :func:`assess` returns one flat row per run: what the sweep benchmark prints and
what the variant tests assert on.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import time
from typing import Any

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.problem import BAProblem
from pmba_ros.core.solve import solve, SolveResult
from pmba_ros.init import covisibility, view_graph
from pmba_ros.init.pipeline import global_init, InitOptions, InitResult


@dataclass(frozen=True, slots=True)
class InitAssessment:
    """One run of the global initialization and its reference.

    Attributes:
        n_cams: Cameras of the input.
        cams_used: Cameras in the solved sub-problem.
        n_feats: Features of the input.
        features_used_pct: Percentage of the input's features (outlier tracks excluded) in
            the solved sub-problem.
        outliers_kept: Known outlier tracks that are still in the solved sub-problem.
        reachable_cams: Cameras of the largest component of the co-visibility graph whose
            edges are the pairs sharing at least ``min_pair_matches`` tracks: the most that
            a pairwise (EG-pair) initialization can register in one frame.
        reachable_feats_pct: Percentage of the features (outlier tracks excluded) seen by two
            of those cameras: what ``features_used_pct`` can reach.
        features_recovered: Features anchored after the positions were known.
        rot_median_deg: Median residual of the kept EG pairs after rotation averaging.
        rot_max_deg: Largest such residual.
        nls_iterations: Iterations of the position NLS (eq. 13).
        nls_converged: Whether the NLS met a tolerance.
        nls_px: RMS residual of the NLS in pixels (median focal length).
        ba_rms0_px: RMS at the start of the BA.
        ba_iterations: Iterations of the one BA.
        ba_termination: Why the BA stopped.
        ba_converged: Whether the BA met a convergence criterion.
        rms_px: Final RMS of the BA.
        ref_rms_px: Final RMS of PMBA from the input's start on the same sub-problem.
        ref_converged: Whether the reference converged.
        rms_ratio: rms_px / ref_rms_px.
        init_s: Wall time of the initialization including its BA.
    """

    n_cams: int
    cams_used: int
    n_feats: int
    features_used_pct: float
    outliers_kept: int
    reachable_cams: int
    reachable_feats_pct: float
    features_recovered: int
    rot_median_deg: float
    rot_max_deg: float
    nls_iterations: int
    nls_converged: bool
    nls_px: float
    ba_rms0_px: float
    ba_iterations: int
    ba_termination: str
    ba_converged: bool
    rms_px: float
    ref_rms_px: float
    ref_converged: bool
    rms_ratio: float
    init_s: float

    def passed(self, min_features_pct: float = 95.0, rms_tolerance: float = 0.01) -> bool:
        """Return the issue's criterion: BA converged, RMS within tolerance, features used.

        The feature share is judged against the reachable features (a co-visibility graph in
        pieces cannot be registered in one frame by any pairwise method).
        """
        return bool(self.ba_converged and self.rms_ratio <= 1.0 + rms_tolerance
                    and self.features_used_pct >= min_features_pct / 100.0
                    * self.reachable_feats_pct)

    def to_dict(self) -> dict[str, Any]:
        """Return the row as a plain dict."""
        return asdict(self)


def _reachable(problem: BAProblem, min_matches: int) -> tuple[BoolArray, BoolArray]:
    """Return the cameras (M,) and features (N,) a pairwise initialization can reach."""
    obs = problem.obs
    counts = covisibility.covisibility_counts(obs.cam_idx, obs.feat_idx, problem.n_cams)
    cam_a, cam_b = np.nonzero(counts >= min_matches)
    cams = view_graph.largest_component(problem.n_cams, cam_a, cam_b)
    seen = np.bincount(obs.feat_idx[cams[obs.cam_idx]], minlength=problem.n_feats)
    return cams, seen >= 2


def solve_from_start(problem: BAProblem, result: InitResult, points_w: FloatArray,
                     ) -> SolveResult:
    """Solve ``result``'s sub-problem from the input's poses and points (same options).

    Args:
        problem: The input problem given to :func:`global_init`.
        result: Its result.
        points_w: Starting points of the input's features, shape (problem.n_feats, 3).
    """
    ci = result.camera_index
    fi = result.feature_index
    start = result.problem.with_poses(problem.R_wc[ci], problem.centers_w[ci])
    return solve(start.with_points(np.asarray(points_w)[fi]), result.solve.options)


def assess(problem: BAProblem, points_w: FloatArray, options: InitOptions | None = None,
           outlier_ids: IntArray | None = None) -> tuple[InitAssessment, InitResult]:
    """Run :func:`global_init` on ``problem`` and compare it with PMBA from its own start.

    Args:
        problem: Tracks, intrinsics and the reference start (poses).
        points_w: Reference starting points, shape (problem.n_feats, 3).
        options: Initialization options (default: :class:`InitOptions`()).
        outlier_ids: Feature ids of tracks known to be wrong (not counted as features to use).

    Returns:
        The assessment row and the initialization result.
    """
    options = InitOptions() if options is None else options
    t0 = time.perf_counter()
    res = global_init(problem, options)
    init_s = time.perf_counter() - t0
    ref = solve_from_start(problem, res, points_w)
    rep = res.report
    rot = rep['rotations']['rotation_residual_deg']
    outlier = np.isin(problem.feature_ids, np.zeros(0) if outlier_ids is None else outlier_ids)
    kept = np.zeros(problem.n_feats, dtype=bool)
    kept[res.feature_index] = True
    reach_cams, reach_feats = _reachable(problem, options.min_pair_matches)
    row = InitAssessment(
        n_cams=problem.n_cams, cams_used=res.problem.n_cams, n_feats=problem.n_feats,
        features_used_pct=100.0 * int(np.sum(kept & ~outlier)) / max(int(np.sum(~outlier)), 1),
        outliers_kept=int(np.sum(kept & outlier)), reachable_cams=int(reach_cams.sum()),
        reachable_feats_pct=100.0 * int(np.sum(reach_feats & ~outlier))
        / max(int(np.sum(~outlier)), 1),
        features_recovered=int(rep['tracks']['features_recovered']),
        rot_median_deg=float(rot['median']), rot_max_deg=float(rot['max']),
        nls_iterations=int(rep['nls']['iterations']),
        nls_converged=bool(rep['nls']['converged']),
        nls_px=float(rep['nls']['nls_residual_px']),
        ba_rms0_px=res.solve.initial_rms_px, ba_iterations=res.solve.iterations,
        ba_termination=res.solve.termination.value, ba_converged=res.solve.converged,
        rms_px=res.solve.final_rms_px, ref_rms_px=ref.final_rms_px,
        ref_converged=ref.converged,
        rms_ratio=float(res.solve.final_rms_px / max(ref.final_rms_px, 1e-300)), init_s=init_s)
    return row, res
