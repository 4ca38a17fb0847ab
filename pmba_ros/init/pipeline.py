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
"""Global initialization: from feature tracks alone to a converged PMBA, in one BA (or two).

The stages of PMBA Sec. 3 / Fig. 5 (pmba.md §4), each timed and reported:

1. ``pairs``: epipolar-geometry pairs, 5-point RANSAC + cheirality (OpenCV); a plane's
   second pose where the triangles of pairs close with it.
2. ``view_graph``: largest connected component, maximum spanning tree, tree-inconsistent
   pairs rejected.
3. ``rotations``: chordal rotation averaging, iteratively reweighted (Cauchy kernel, pair
   weights from inlier counts), pruning of disagreeing pairs, re-averaging,
   translation directions re-estimated with the rotations known; observations off the
   epipolar lines of most pairs testing them dropped (:mod:`pmba_ros.init.wrong_observations`).
4. ``features``: anchors restricted to EG pairs, theta-bar and n-bar from rotations only
   (Remark 5), alpha-bar and Q_j from the EG directions (eq. 11).
5. ``cls``: positions from the convex problem (eq. 14) with cheirality and a scale constraint.
6. ``nls``: positions from the nonlinear problem (eq. 13) with a Cauchy loss.
7. ``tracks``: with positions known, tracks inconsistent with them (wrong matches) dropped
   (the NLS re-run without them if any was EG-anchored); cameras whose rays miss the
   triangulated points re-placed by resection; features without an EG anchor pair
   anchored on their widest pair of cameras with a baseline (instead of being dropped).
8. ``ba``: full PMBA with Dogleg (:func:`pmba_ros.core.solve.solve`); the tracks dropped in
   ``tracks`` that fit its poses are taken back, and the BA resumed with them (a second
   invocation, only then: :func:`pmba_ros.init.wrong_tracks.readmitted`).

Only the input problem's observations and intrinsics are used; its poses and points are
ignored. The result's problem holds only the cameras of the largest component of the view
graph that see an EG-anchored feature, and the features seen by two of them
(``camera_index``/``feature_index`` map back to the input), because cameras without an EG
pair have no rotation to start from.

Deviations from the paper (tagged ``DEVIATION`` in the code, pmba.md §8):

- eq. (11): n_z is normalised.
- eq. (14): cheirality is read as r_k . N-bar_k >= 0 and enforced by an active-set quadratic
  penalty (no QP solver); a scale equality sum_k r_k . N-bar_k = K is added.
- eq. (13): Cauchy loss (IRLS Levenberg-Marquardt), because frozen noisy theta-bar act as
  outliers.
- Remark 5: features whose rotation-only parallax is below ``theta_floor_px`` start the BA at
  infinity (theta = 0), and anchors are swapped when only the other order gives a valid
  triangle (pmba.md §3.3); otherwise near-collinear features can stall the BA.
- Fig. 5: a second BA where tracks dropped at the positions fit the first BA's poses (a
  camera the positions left off had made them look wrong).
- Fig. 5: observations off the epipolar lines of most EG pairs testing them are dropped
  after the rotations, and, where wrong matches were found, those the BA leaves grossly off
  after it (the BA resumed without them): wrong single observations in long tracks.
- Fig. 5: a pair whose homography gives a second pose as good as the RANSAC's (points on a
  plane) keeps the one that closes more of its triangles of pairs
  (:mod:`pmba_ros.init.planar_ambiguity`).

The CLS and NLS assemble their normal matrices in the non-zero 3x3 blocks of co-visible camera
pairs (:mod:`pmba_ros.init.normal_blocks`) and factor them sparse above about 200 cameras:
they take seconds at 6000 cameras; the final BA's reduced camera system then dominates.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
import logging
import time
from typing import Any

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import conversions
from pmba_ros.core.problem import (
    BAProblem,
    make_problem,
    ParallaxFeatures,
    subset_features,
)
from pmba_ros.core.solve import IterationRecord, solve
from pmba_ros.errors import InitError
from pmba_ros.init import (
    anchors,
    cls,
    nls,
    pair_selection,
    register,
    rotation_averaging,
    two_view,
    view_graph,
    wrong_observations,
    wrong_tracks,
)
from pmba_ros.init.options import InitOptions, InitResult

logger = logging.getLogger(__name__)

ProgressCallback = Callable[[str, Mapping[str, Any]], None]
"""Called after every stage with the stage name and its report entries; during the ``pairs``
stage also as its RANSACs go on, with ``{'running': True, 'pairs_taken': k, 'pairs_to_estimate':
n}`` (the RANSACs started so far, on every thread)."""


STAGES = ('pairs', 'view_graph', 'rotations', 'features', 'cls', 'nls', 'tracks', 'ba')


def _angle_stats(angles_deg: FloatArray) -> dict[str, float]:
    if angles_deg.size == 0:
        return {'mean': 0.0, 'median': 0.0, 'max': 0.0}
    return {'mean': float(np.mean(angles_deg)), 'median': float(np.median(angles_deg)),
            'max': float(np.max(angles_deg))}


class _Stages:
    """Stage timer and report builder (wall time per stage, progress callback)."""

    def __init__(self, progress: ProgressCallback | None) -> None:
        self.report: dict[str, Any] = {'time_s': {}}
        self.progress = progress
        self.t_start = time.perf_counter()
        self.t_last = self.t_start

    def done(self, stage: str, entries: Mapping[str, Any]) -> None:
        now = time.perf_counter()
        self.report['time_s'][stage] = now - self.t_last
        self.t_last = now
        self.report[stage] = dict(entries)
        logger.info('global_init: %s done in %.3f s: %s', stage,
                    self.report['time_s'][stage], dict(entries))
        if self.progress is not None:
            self.progress(stage, self.report[stage])

    def running(self, stage: str) -> Callable[[int, int], None] | None:
        """Return the tick that reports ``stage``'s progress (None without a callback)."""
        progress = self.progress
        if progress is None:
            return None

        def tick(taken: int, total: int) -> None:
            progress(stage, {'running': True, 'pairs_taken': taken, 'pairs_to_estimate': total})
        return tick

    def finish(self) -> None:
        self.report['time_s']['total'] = time.perf_counter() - self.t_start


def _check_input(problem: BAProblem) -> dict[str, Any]:
    info = {'n_cams': problem.n_cams, 'n_feats': problem.n_feats, 'n_obs': problem.n_obs,
            'dropped': dict(problem.dropped)}
    if problem.n_cams < 2:
        msg = f'global init needs at least 2 cameras, got {problem.n_cams}'
        raise InitError(msg)
    if problem.n_feats == 0:
        single = problem.dropped.get('single_observation_features', 0)
        msg = ('global init: no feature is observed by two cameras'
               + (f' ({single} tracks of length 1 were dropped)' if single else ''))
        raise InitError(msg)
    return info


def _compact(mask: BoolArray) -> IntArray:
    """Return the new index of every True entry (-1 elsewhere)."""
    new = np.full(mask.shape[0], -1, dtype=np.int64)
    new[mask] = np.arange(int(mask.sum()))
    return new


def _component_pairs(n_cams: int, pairs: two_view.EGPairs,
                     ) -> tuple[two_view.EGPairs, BoolArray]:
    comp = view_graph.largest_component(n_cams, pairs.cam_a, pairs.cam_b)
    return pairs.subset(comp[pairs.cam_a] & comp[pairs.cam_b]), comp


def _view_graph(n_cams: int, pairs: two_view.EGPairs, options: InitOptions,
                ) -> tuple[two_view.EGPairs, BoolArray, dict[str, Any]]:
    pairs_comp, comp = _component_pairs(n_cams, pairs)   # a pair at least: estimate_pairs
    n_comp = int(comp.sum())
    w = pairs_comp.n_inliers.astype(float)
    tree = view_graph.maximum_spanning_tree(n_cams, pairs_comp.cam_a, pairs_comp.cam_b, w)
    root = view_graph.choose_root(n_cams, pairs_comp.cam_a, pairs_comp.cam_b, w, comp)
    R_tree, _ = view_graph.chain_tree_rotations(n_cams, root, pairs_comp.cam_a[tree],
                                                pairs_comp.cam_b[tree], pairs_comp.R_rel[tree])
    dis = view_graph.pair_rotation_disagreement_deg(R_tree, pairs_comp.cam_a,
                                                    pairs_comp.cam_b, pairs_comp.R_rel)
    keep = tree | (dis <= options.max_tree_disagreement_deg)
    entries = {'cameras_in_component': n_comp,
               'cameras_left_out': np.flatnonzero(~comp).tolist(),
               'pairs_outside_component': pairs.n_pairs - pairs_comp.n_pairs,
               'tree_edges': int(tree.sum()),
               'pairs_tree_inconsistent': int(np.sum(~keep)), 'root': root,
               'tree_disagreement_deg': _angle_stats(dis[~tree])}
    return pairs_comp.subset(keep), comp, entries


def _average(n_cams: int, pairs: two_view.EGPairs, cameras: BoolArray, options: InitOptions,
             ) -> tuple[FloatArray, int]:
    """Robust chordal averaging on the cameras of ``cameras`` (renumbered); identity elsewhere.

    Pairs are weighted by their inlier counts; IRLS with a Cauchy kernel of
    ``options.rotation_cauchy_deg`` down-weights the pairs that disagree with the consensus.
    """
    new = _compact(cameras)
    w = pairs.n_inliers.astype(float)
    root = view_graph.choose_root(n_cams, pairs.cam_a, pairs.cam_b, w, cameras)
    R_sub, _, rounds = rotation_averaging.robust_rotation_averaging(
        int(cameras.sum()), int(new[root]), new[pairs.cam_a], new[pairs.cam_b], pairs.R_rel, w,
        cauchy_deg=options.rotation_cauchy_deg)
    R = np.broadcast_to(np.eye(3), (n_cams, 3, 3)).copy()
    R[cameras] = R_sub
    return R, rounds


def _per_camera_residual_deg(n_cams: int, cameras: BoolArray, pairs: two_view.EGPairs,
                             dis: FloatArray) -> list[float | None]:
    """Return the median disagreement (deg) of each camera's pairs (None if it has none)."""
    cam = np.concatenate([pairs.cam_a, pairs.cam_b])
    val = np.concatenate([dis, dis])
    order = np.lexsort((val, cam))
    cam, val = cam[order], val[order]
    starts = np.searchsorted(cam, np.arange(n_cams))
    ends = np.searchsorted(cam, np.arange(n_cams), side='right')
    return [float(np.median(val[a:b])) if cameras[k] and b > a else None
            for k, (a, b) in enumerate(zip(starts, ends, strict=True))]


def _rotations(problem: BAProblem, pairs: two_view.EGPairs, comp: BoolArray,
               options: InitOptions,
               ) -> tuple[FloatArray, two_view.EGPairs, FloatArray, BoolArray, int,
                          dict[str, Any]]:
    M = problem.n_cams
    R, rounds = _average(M, pairs, comp, options)
    dis = view_graph.pair_rotation_disagreement_deg(R, pairs.cam_a, pairs.cam_b, pairs.R_rel)
    first = _angle_stats(dis)
    prune = dis > options.max_pair_disagreement_deg
    n_pruned = int(prune.sum())
    comp_before = comp
    if n_pruned:
        pairs, comp = _component_pairs(M, pairs.subset(~prune))
        if int(comp.sum()) < 2:
            msg = ('global init: pruning pairs that disagree with the averaged rotations '
                   f'leaves {int(comp.sum())} connected cameras')
            raise InitError(msg)
        R, rounds = _average(M, pairs, comp, options)
        dis = view_graph.pair_rotation_disagreement_deg(R, pairs.cam_a, pairs.cam_b,
                                                        pairs.R_rel)
    per_camera = _per_camera_residual_deg(M, comp, pairs, dis)
    pairs, d_ab = two_view.refine_translations(pairs, problem.obs.bearings_c, R)
    root = view_graph.choose_root(M, pairs.cam_a, pairs.cam_b, pairs.n_inliers.astype(float),
                                  comp)
    entries = {'rotation_residual_deg': _angle_stats(dis),
               'rotation_residual_per_camera_deg': per_camera, 'irls_rounds': rounds,
               'rotation_residual_before_pruning_deg': first,
               'pairs_pruned': n_pruned, 'pairs_kept': pairs.n_pairs,
               'cameras_dropped_by_pruning': np.flatnonzero(comp_before & ~comp).tolist()}
    return R, pairs, d_ab, comp, root, entries


def _subproblem(problem: BAProblem, cameras: BoolArray, R_wc: FloatArray,
                feature_keep: BoolArray | None = None) -> tuple[BAProblem, IntArray]:
    """Return the problem restricted to ``cameras`` (and features), and the camera index."""
    cam_index = np.flatnonzero(cameras)
    new_cam = _compact(cameras)
    obs = problem.obs
    keep = cameras[obs.cam_idx]
    if feature_keep is not None:
        keep &= feature_keep[obs.feat_idx]
    Mc = cam_index.shape[0]
    sub = make_problem(R_wc[cam_index], np.zeros((Mc, 3)), problem.intrinsics.take(cam_index),
                       new_cam[obs.cam_idx[keep]], obs.feat_idx[keep], obs.pixels[keep],
                       bearings_c=obs.bearings_c[keep], n_feats=problem.n_feats,
                       feature_ids=np.arange(problem.n_feats),
                       pixel_jac=None if obs.pixel_jac is None else obs.pixel_jac[keep])
    return sub, cam_index


def _features(problem: BAProblem, R_wc: FloatArray, pairs: two_view.EGPairs, d_ab: FloatArray,
              comp: BoolArray,
              ) -> tuple[BAProblem, BAProblem, IntArray, ParallaxFeatures,
                         anchors.LinearizationFrames, dict[str, Any]]:
    """Anchor features on EG pairs (eq. 11).

    Returns the problem of the EG-anchored features (for the CLS / NLS), the problem of every
    feature seen twice by the same cameras (for :func:`_complete_tracks`), the camera index,
    the features, their frames and the report entries.
    """
    cameras = comp.copy()
    sub, cam_index = _subproblem(problem, cameras, R_wc)
    new = _compact(cameras)
    allowed = anchors.allowed_pair_mask(sub.n_cams, new[pairs.cam_a], new[pairs.cam_b])
    main_idx, assoc_idx, ok = conversions.select_anchors(sub, sub.R_wc, allowed_pairs=allowed)
    n_no_anchor = int(np.sum(~ok))
    n_single = sub.dropped.get('single_observation_features', 0)
    feat_keep = np.zeros(problem.n_feats, dtype=bool)
    feat_keep[sub.feature_ids[ok]] = True
    sub, cam_index = _subproblem(problem, cameras, R_wc, feat_keep)
    seen = np.bincount(sub.obs.cam_idx, minlength=sub.n_cams) > 0
    if not np.all(seen):  # cameras whose every track lost its anchor pair
        cameras[cam_index[~seen]] = False
        sub, cam_index = _subproblem(problem, cameras, R_wc, feat_keep)
        new = _compact(cameras)
    if sub.n_feats == 0:
        msg = 'global init: no feature is observed by an EG pair of the component'
        raise InitError(msg)
    pair_in = cameras[pairs.cam_a] & cameras[pairs.cam_b]
    pa, pb, dd = new[pairs.cam_a[pair_in]], new[pairs.cam_b[pair_in]], d_ab[pair_in]
    allowed = anchors.allowed_pair_mask(sub.n_cams, pa, pb)
    main_idx, assoc_idx, ok = conversions.select_anchors(sub, sub.R_wc, allowed_pairs=allowed)
    if not np.all(ok):  # cannot happen: the features were filtered on the same pairs
        msg = 'global init: anchor selection lost features between two identical calls'
        raise InitError(msg)
    feats = conversions.features_from_rotations(sub, sub.R_wc, main_idx, assoc_idx)
    d_ma = anchors.anchor_directions(sub.n_cams, pa, pb, dd, main_idx, assoc_idx)
    feats, swapped = _orient(sub, feats, d_ma)
    d_ma = np.where(swapped[:, None], -d_ma, d_ma)
    frames = anchors.linearization_frames(sub.R_wc, feats, d_ma)
    full, _ = _subproblem(problem, cameras, R_wc)
    entries = {'features_anchored_on_eg_pairs': sub.n_feats, 'observations_used': sub.n_obs,
               'features_without_eg_anchor_pair': n_no_anchor,
               'features_single_observation_in_component': int(n_single),
               'features_anchors_swapped': int(np.sum(swapped)),
               'features_inconsistent_triangle': int(np.sum(~frames.consistent)),
               'cameras_without_features': np.flatnonzero(comp & ~cameras).tolist(),
               'theta_deg': _angle_stats(np.rad2deg(feats.theta))}
    return sub, full, cam_index, feats, frames, entries


def _complete_tracks(full: BAProblem, eg: BAProblem, eg_feats: ParallaxFeatures,
                     centers_w: FloatArray) -> tuple[BAProblem, ParallaxFeatures, dict[str, Any]]:
    """Anchor the features without an EG anchor pair, now that positions are known.

    The EG-anchored features (those of ``eg`` that are still in ``full``) keep their anchors.
    Every other feature of ``full`` (seen by at least two of its cameras) gets the
    widest-parallax pair of its observers among the pairs with a baseline, and theta-bar,
    n-bar from the rotations (Remark 5), as the EG-anchored ones; the BA recomputes alpha from
    the positions.

    Returns:
        The problem with every anchored feature (poses from the NLS), its features and the
        report entries.
    """
    R_wc = full.R_wc
    is_eg = np.isin(full.feature_ids, eg.feature_ids)
    in_full = np.isin(eg.feature_ids, full.feature_ids)
    main_idx = np.zeros(full.n_feats, dtype=np.int64)
    assoc_idx = np.zeros(full.n_feats, dtype=np.int64)
    # Both problems are sorted by feature id (subset_features keeps the order).
    main_idx[is_eg] = eg_feats.main_idx[in_full]
    assoc_idx[is_eg] = eg_feats.assoc_idx[in_full]
    rest = subset_features(full, ~is_eg, 'features_with_eg_anchor_pair')
    m, a, ok = conversions.select_anchors(rest, R_wc, centers_w=centers_w)
    main_idx[~is_eg] = m
    assoc_idx[~is_eg] = a
    keep = is_eg.copy()
    keep[~is_eg] = ok
    done = subset_features(full.with_poses(R_wc, centers_w), keep,
                           'features_without_anchor_baseline')
    feats = conversions.features_from_rotations(done, R_wc, main_idx[keep], assoc_idx[keep])
    entries = {'features_recovered': int(np.sum(ok)),
               'features_without_anchor_baseline': int(np.sum(~ok)),
               'features_used': done.n_feats, 'observations_used': done.n_obs}
    return done, feats, entries


def _register(problem: BAProblem, cameras: BoolArray, R_wc: FloatArray,
              component_centers: FloatArray, bad_ids: IntArray, options: InitOptions,
              max_px: float) -> register.Registration:
    """Place the cameras outside the component by PnP on its consistent tracks."""
    C = np.zeros((problem.n_cams, 3))
    C[cameras] = component_centers
    if options.register_min_points == 0 or np.all(cameras):
        return register.Registration(cameras, R_wc, C, np.zeros(0, dtype=np.int64))
    every, _ = _subproblem(problem, np.ones(problem.n_cams, dtype=bool), R_wc)
    every = subset_features(every, ~np.isin(every.feature_ids, bad_ids), 'inconsistent_tracks')
    return register.register_cameras(every, cameras, R_wc, C,
                                     min_points=options.register_min_points, max_px=max_px)


def _behind_an_observer(problem: BAProblem, feats: ParallaxFeatures) -> BoolArray:
    """Return the features (N,) whose predicted ray points away from a measured bearing."""
    X, w = conversions.parallax_homogeneous(problem.R_wc, problem.centers_w, feats)
    obs = problem.obs
    N = X[obs.feat_idx] - w[obs.feat_idx, None] * problem.centers_w[obs.cam_idx]
    bearing_w = np.einsum('kij,kj->ki', problem.R_wc[obs.cam_idx], obs.bearings_c)
    behind = np.einsum('ki,ki->k', N, bearing_w) < 0.0
    return np.bincount(obs.feat_idx[behind], minlength=problem.n_feats) > 0


def _orient(problem: BAProblem, feats: ParallaxFeatures, d_ma: FloatArray,
            ) -> tuple[ParallaxFeatures, BoolArray]:
    """Swap anchors of features whose triangle is only valid the other way round."""
    v_a = problem.obs.bearings_c[conversions.anchor_observations(problem, feats.assoc_idx)]
    return anchors.orient_anchors(problem.R_wc, feats, d_ma, v_a)


def global_init(problem: BAProblem, options: InitOptions = InitOptions(), *,
                progress: ProgressCallback | None = None,
                callback: Callable[[IterationRecord], None] | None = None) -> InitResult:
    """Initialize and solve a PMBA problem from its feature tracks alone, with one BA (or two).

    Args:
        problem: Observations (tracks) and intrinsics; its poses and points are ignored.
        options: Stage options.
        progress: Optional callback ``progress(stage, entries)`` after every stage.
        callback: Optional callback of the BA's iterations (see :func:`~pmba_ros.core.
            solve.solve`).

    Returns:
        The solved sub-problem of the largest view-graph component, with the per-stage report.

    Raises:
        InitError: On degenerate input with the reason: fewer than 2 cameras, no track of
            length >= 2, no image pair with enough common tracks, no EG pair with a baseline
            (pure rotation), every pair pruned by the rotation averaging. Cameras outside
            the largest component are reported (``cameras_left_out``), not an error.

    References:
        PMBA Sec. 3, Fig. 5; eqs. (11)-(14); pmba.md §4.
    """
    st = _Stages(progress)
    st.report['input'] = _check_input(problem)
    M = problem.n_cams

    pairs, corr, entries = pair_selection.estimate_pairs(problem, options, st.running('pairs'))
    st.done('pairs', entries)

    pairs, comp, entries = _view_graph(M, pairs, options)
    st.done('view_graph', entries)

    R_wc, pairs, d_ab, comp, _, entries = _rotations(problem, pairs, comp, options)
    # DEVIATION(Fig. 5): wrong single observations dropped (wrong_observations).
    off = wrong_observations.off_their_pairs(problem, pairs, corr, options.ransac_threshold_px)
    del corr
    st.done('rotations', {**entries, 'observations_off_their_pairs': int(off.wrong.sum()),
                          'pair_error_threshold_px': off.threshold_px,
                          'cameras_off_their_pairs': off.cameras_kept_whole})
    # From here on the pairs' correspondences (observation indices) are not read again.
    problem = wrong_observations.without(problem, off.wrong)

    sub, full, cam_index, feats, frames, entries = _features(problem, R_wc, pairs, d_ab, comp)
    st.done('features', entries)
    cameras_used = np.zeros(M, dtype=bool)
    cameras_used[cam_index] = True
    new = _compact(cameras_used)
    pair_in = cameras_used[pairs.cam_a] & cameras_used[pairs.cam_b]
    root = view_graph.choose_root(sub.n_cams, new[pairs.cam_a[pair_in]],
                                  new[pairs.cam_b[pair_in]],
                                  pairs.n_inliers[pair_in].astype(float),
                                  np.ones(sub.n_cams, dtype=bool))

    lin = cls.linear_rays(sub.R_wc, feats, frames, sub.obs.cam_idx, sub.obs.feat_idx,
                          sub.obs.bearings_c)
    weights = frames.consistent[sub.obs.feat_idx].astype(float)
    res_cls = cls.solve_cls(lin, sub.n_cams, root, weights=weights,
                            max_penalty_iterations=options.cls_max_penalty_iterations)
    st.done('cls', {'cls_residual': res_cls.residual,
                    'cheirality_violations': res_cls.cheirality_violations,
                    'penalty_iterations': res_cls.penalty_iterations})

    focal = float(np.median(np.sqrt(sub.intrinsics.fx * sub.intrinsics.fy)))
    focal_obs = np.sqrt(sub.intrinsics.fx * sub.intrinsics.fy)[sub.obs.cam_idx]
    res_nls = nls.solve_nls(lin, res_cls.centers_w, root,
                            f_scale=options.nls_cauchy_px / focal_obs, weights=weights,
                            max_iterations=options.nls_max_iterations)
    # Wrong tracks pull the positions; with positions known they stand out: drop them and
    # refine the positions again without them.
    check = wrong_tracks.wrong_tracks(full, sub.R_wc, res_nls.centers_w, options)
    bad_ids = full.feature_ids[check.inconsistent]
    bad_eg = np.isin(sub.feature_ids, bad_ids)
    first_nls = res_nls
    if np.any(bad_eg):
        weights = weights * ~bad_eg[sub.obs.feat_idx]
        res_nls = nls.solve_nls(lin, res_nls.centers_w, root,
                                f_scale=options.nls_cauchy_px / focal_obs, weights=weights,
                                max_iterations=options.nls_max_iterations)
    st.done('nls', {'nls_residual': res_nls.residual,
                    'nls_residual_px': res_nls.residual * focal,
                    'initial_cost': first_nls.initial_cost, 'final_cost': res_nls.final_cost,
                    'iterations': first_nls.iterations + (res_nls.iterations
                                                          if np.any(bad_eg) else 0),
                    'converged': first_nls.converged and res_nls.converged,
                    'rerun_without_inconsistent_tracks': bool(np.any(bad_eg))})

    full = subset_features(full, ~check.inconsistent, 'inconsistent_tracks')
    centers, resected, cam_px = wrong_tracks.resect_outlying_cameras(full, res_nls.centers_w,
                                                                     options)
    if resected.size:
        logger.info('global_init: resected cameras %s (residuals %s px)', resected.tolist(),
                    np.round(cam_px[resected], 1).tolist())
    resected_ids, in_component = cam_index[resected], int(np.count_nonzero(cameras_used))
    reg = _register(problem, cameras_used, R_wc, centers, bad_ids, options, check.threshold_px)
    P = reg.centers_w.copy()
    P[cam_index] = res_nls.centers_w
    if reg.registered.shape[0]:
        moved = _compact(reg.cameras)[cam_index]  # the component's cameras, renumbered
        feats = ParallaxFeatures(feats.theta, feats.n, moved[feats.main_idx],
                                 moved[feats.assoc_idx])
        cameras_used = reg.cameras
        full, cam_index = _subproblem(problem, cameras_used, reg.R_wc)
        full = subset_features(full, ~np.isin(full.feature_ids, bad_ids), 'inconsistent_tracks')
    P = P[cam_index]
    init_problem, feats, entries = _complete_tracks(full, sub, feats,
                                                    reg.centers_w[cam_index])
    st.done('tracks', {'inconsistent_tracks': int(np.sum(check.inconsistent)),
                       'track_threshold_px': check.threshold_px,
                       'track_residual_median_px': float(np.median(check.rms_px)),
                       'camera_residual_px': _angle_stats(cam_px),
                       'cameras_resected': resected_ids.tolist(),
                       'cameras_registered': reg.registered.tolist(), **entries})
    # With positions known, alpha is recomputed by the BA: re-check the anchor order.
    d_ma = P[feats.main_idx] - P[feats.assoc_idx]
    d_ma /= np.maximum(np.linalg.norm(d_ma, axis=1, keepdims=True), 1e-300)
    feats, swapped = _orient(init_problem, feats, d_ma)
    report_swaps = int(np.sum(swapped))
    # DEVIATION(Remark 5): theta-bar below theta_floor_px / f is noise (the maximum over the
    # EG pairs of noise-level parallaxes); such features start at infinity, theta = 0, a
    # valid PMBA state (pmba.md §1.3, §3.3). Near-collinear features otherwise start at a
    # wrong finite depth, between the cameras, and the BA can stall there.
    f_main = np.sqrt(init_problem.intrinsics.fx * init_problem.intrinsics.fy)[feats.main_idx]
    low = feats.theta < options.theta_floor_px / f_main
    # A start that puts a feature behind one of its observers is a saddle of the ray error
    # (the error is at its largest, its gradient vanishes, and the first step cannot predict
    # the cost it removes): the BA spends its iterations there. Near-collinear features (the
    # ray along the anchor baseline) get there from a noise-level theta-bar that passes the
    # floor: sin(alpha - theta) ~ 0 puts the point a few baselines away. At infinity every
    # observer sees it along n-bar, in front.
    low |= _behind_an_observer(init_problem, feats)
    feats = ParallaxFeatures(np.where(low, 0.0, feats.theta), feats.n, feats.main_idx,
                             feats.assoc_idx)
    result = solve(init_problem, options.solve_options, feats, callback=callback)
    iterations, back = result.iterations, None
    if bad_ids.size:
        dropped, _ = _subproblem(problem, cameras_used, reg.R_wc,
                                 np.isin(np.arange(problem.n_feats), bad_ids))
        # DEVIATION(Fig. 5): the BA resumed with the dropped tracks that fit its poses.
        back = wrong_tracks.readmitted(result, feats, dropped, check.threshold_px,
                                       options.solve_options, callback)
    if back is not None:
        init_problem, feats, result = back.result.problem, back.features, back.result
        iterations += back.iterations
    invocations = 1 + (0 if back is None else back.invocations)
    cleaned = None
    if np.any(off.wrong) or bad_ids.size:   # wrong matches: some may be left, in short tracks
        cleaned = wrong_observations.without_gross_errors(result, options.track_min_px,
                                                          options.solve_options, callback)
    if cleaned is not None:
        result, feats, _ = cleaned
        init_problem, iterations, invocations = (result.problem, iterations + result.iterations,
                                                 invocations + 1)
    st.done('ba', {'anchors_swapped_before_ba': report_swaps,
                   'features_started_at_infinity': int(np.sum(low)),
                   'tracks_readmitted': 0 if back is None else int(back.taken.size),
                   'observations_off_after_ba': 0 if cleaned is None else cleaned[2],
                   'initial_cost': result.initial_cost, 'final_cost': result.final_cost,
                   'initial_rms_px': result.initial_rms_px,
                   'final_rms_px': result.final_rms_px, 'iterations': iterations,
                   'linear_solves': result.linear_solves, 'converged': result.converged,
                   'termination': result.termination.value})
    st.finish()
    report = st.report
    report['summary'] = {
        'pairs_found': report['pairs']['pairs_found'],
        'pairs_kept': report['rotations']['pairs_kept'],
        'cameras_in_component': in_component,
        'cameras_left_out': np.flatnonzero(~cameras_used).tolist(),
        'rotation_residual_deg': report['rotations']['rotation_residual_deg']['mean'],
        'cls_residual': res_cls.residual, 'nls_residual': res_nls.residual,
        'observations_off_their_pairs': report['rotations']['observations_off_their_pairs'],
        'features_used': init_problem.n_feats,
        'features_recovered': report['tracks']['features_recovered'],
        'inconsistent_tracks': report['tracks']['inconsistent_tracks'],
        'tracks_readmitted': report['ba']['tracks_readmitted'],
        'cameras_resected': report['tracks']['cameras_resected'],
        'cameras_registered': report['tracks']['cameras_registered'],
        'final_rms_px': result.final_rms_px, 'ba_converged': result.converged,
        'ba_termination': result.termination.value, 'ba_invocations': invocations}
    return InitResult(init_problem, feats, result, cam_index,
                      np.asarray(init_problem.feature_ids, dtype=np.int64), cameras_used, report,
                      invocations)


__all__ = ['STAGES', 'InitOptions', 'InitResult', 'ProgressCallback', 'global_init']
