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
"""The online estimator: collect -> global init -> refine each new keyframe (no ROS, no messages).

State machine:

``collecting``
    Keyframes are stored until ``init_batch_size`` have arrived and the batch has enough
    well-conditioned features: ``init_min_features`` (half in a full batch) whose parallax,
    rotation compensated, between two of its keyframes is ``init_min_parallax_px`` or more
    (:func:`~pmba_ros.backend.window.well_conditioned_features`; PMBA needs some near
    features, not a high median). Then :func:`pmba_ros.init.pipeline.global_init` solves the
    batch. A failure (pure rotation, too few pairs, steps that disagree with the front-end's)
    moves to ``waiting_for_parallax`` and is retried every ``init_retry_every`` keyframes;
    the batch keeps at most ``init_max_batch`` keyframes (older ones keep their front-end
    pose). Until then every keyframe with a front-end pose is published at that pose (map =
    odom), flagged as not optimized (:meth:`Estimator.optimized`). An initialization with
    only some steps that far off starts its window from the front-end's motion.
``tracking``
    The map is expressed in the front-end's odom frame at initialization (similarity fit of
    the batch, so map -> odom starts at identity). Each new keyframe starts from the previous
    keyframe's optimized pose composed with the front-end's relative motion, its translation
    scaled by the current map <- odom similarity (constant velocity without front-end poses);
    then a budgeted, robust Dogleg PMBA refines the window. ``sliding``: the last
    ``window_size`` keyframes are free, plus up to ``max_fixed_keyframes`` fixed older
    co-observers (two or more fix the gauge); features no free keyframe observes retire to the
    landmark map. ``global``: every keyframe is free except the first (gauge root).

Feature states between refines are world points; each problem re-derives parallax features
from them (:func:`~pmba_ros.core.conversions.xyz_to_parallax`), and new features or points at
infinity start from rotations only (PMBA Remark 5), so no triangulation is needed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
import logging
import math
import time

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.consistency import in_odom_frame, inconsistency, motion_error
from pmba_ros.backend.gaps import place_unsolved, untied_chains
from pmba_ros.backend.motion import (
    ANCHOR_BASELINE_REL,
    fit_map_from_odom,
    frontend_motion_prior,
    FrontendNoise,
    JUMP_SIGMAS,
    PixelNoise,
    pose_from_odom_or_nearest,
    predict_pose,
    RunScale,
    step_sigmas,
    typical_step,
)
from pmba_ros.backend.rig_scale import rescale_map, RigScale
from pmba_ros.backend.sanity import CostMonitor
from pmba_ros.backend.status import UpdateInfo, waiting_for_parallax
from pmba_ros.backend.window import (
    FeatureMap,
    gather_observations,
    KeyframeObs,
    KeyframeStatus,
    KeyframeStore,
    LandmarkStore,
    select_fixed,
    Similarity,
    well_conditioned_features,
)
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.conversions import xyz_to_parallax
from pmba_ros.core.loss import Loss
from pmba_ros.core.pose_prior import RelativePosePrior
from pmba_ros.core.problem import (
    BAProblem,
    finite_rows,
    make_problem,
    ParallaxFeatures,
    Parameterization,
    Rig,
    subset_features,
)
from pmba_ros.core.solve import solve, SolveOptions, SolverKind
from pmba_ros.errors import InitError, PmbaError

logger = logging.getLogger(__name__)


INIT_CONTRADICTIONS = 3
"""Initializations whose steps contradict the front-end's (median) after which the batch is
seeded from the front-end instead (vision alone fitted wrong tracks that often)."""


class Estimator:
    """Keyframe-by-keyframe PMBA estimator (see the module docstring)."""

    def __init__(self, config: BackendConfig) -> None:
        """Create an estimator in state ``collecting``."""
        self.config = config
        self.fx = self.fy = config.fallback_focal_px
        self.cx = self.cy = 0.0
        self.checkpoint: Callable[[], None] = lambda: None   # between solver steps (worker)
        self.reset()

    def reset(self) -> None:
        """Forget every keyframe, feature and landmark."""
        self.kf = KeyframeStore()
        self.features = FeatureMap()
        self.landmarks = LandmarkStore(self.config.max_landmarks)
        self.state = 'collecting'
        self.map_from_odom = Similarity.identity()
        self.last_message = 'collecting keyframes for the global initialization'
        self._next_init_attempt = self.config.init_batch_size
        self.init_attempts = 0
        self._failures = 0
        self._contradicted = 0
        self._metric_scale = 1.0
        self._rig_scale = RigScale(self.config)
        self.map_version = 0
        """Counts the rescalings of the whole map (:mod:`~pmba_ros.backend.rig_scale`)."""
        self._run_scale = RunScale()
        self._segment = 0   # odom segment of the keyframe being added (as _odom_cov)
        self.pixel_noise = PixelNoise()
        self.frontend_noise = FrontendNoise()
        self._rig_offsets: dict[int, tuple[FloatArray, FloatArray]] = {}
        self._odom_cov: FloatArray | None = None
        self._cost = CostMonitor()
        self.deferred = 0
        """Keyframes added since the last solve (``add_keyframe(..., solve=False)``)."""

    def set_rig_camera(self, camera: int, rotation: FloatArray, translation: FloatArray) -> None:
        """Use observations of front-end camera ``camera`` (other than ``camera_id``).

        Args:
            camera: Front-end camera id, in [0, num_cams).
            rotation: Its rotation in the reference camera's frame, R_ref,cam (3, 3).
            translation: Its centre in the reference camera's frame (3,), m.
        """
        self._rig_offsets[int(camera)] = (np.asarray(rotation, dtype=float),
                                          np.asarray(translation, dtype=float))

    def _rig(self) -> Rig | None:
        """Return the rig of the reference and the configured cameras, or None (monocular)."""
        ref = self.config.camera_id
        if not any(c != ref for c in self._rig_offsets):
            return None
        R = np.tile(np.eye(3), (self.config.num_cams, 1, 1))
        t = np.zeros((self.config.num_cams, 3))
        for cam, (R_c, t_c) in self._rig_offsets.items():
            if cam != ref:
                R[cam], t[cam] = R_c, t_c
        return Rig(R, t)

    def set_pinhole(self, fx: float, fy: float, cx: float, cy: float) -> None:
        """Set the pinhole used to express observations in pixels (loss scale, rms)."""
        self.fx, self.fy, self.cx, self.cy = float(fx), float(fy), float(cx), float(cy)

    # --- public update -------------------------------------------------------------------

    def add_keyframe(self, stamp_ns: int, odom: tuple[FloatArray, FloatArray] | None,
                     obs: KeyframeObs | None, odom_covariance: FloatArray | None = None, *,
                     odom_jumped: bool = False, solve: bool = True) -> UpdateInfo:
        """Add a keyframe and update the estimate.

        Every keyframe with a front-end pose gets a map pose: before the first initialization
        and for keyframes without enough observations it is the front-end pose through the
        current map <- odom similarity (flagged as not optimized, see :meth:`optimized`).

        Args:
            stamp_ns: Keyframe stamp, ns (strictly increasing; the caller checks).
            odom: Front-end pose (R_wc (3, 3), centre (3,)) in the odom frame, or None.
            obs: Its observations, or None / too few for a keyframe without tracks.
            odom_covariance: The front-end pose's covariance (6, 6: position, rotation; in
                the odom frame), or None; weighs the motion prior (:meth:`_motion_prior`).
            odom_jumped: The front-end's frame jumped since the previous keyframe (a
                relocalization or a reset): this pose starts a new odom segment, the step to
                it is no motion, and map <- odom is estimated anew.
            solve: False (the node behind its input): once tracking, the keyframe's solve
                (its iterations) is left to a later one's or :meth:`solve_deferred`; in sliding
                mode at most ``window_size // 2`` in a row (each solved in the window).

        Returns:
            What the update did.
        """
        self._odom_cov = odom_covariance
        n = self.kf.n
        self._segment = (int(self.kf.segment[n - 1]) + int(odom_jumped)) if n else 0
        n_obs = 0 if obs is None else int(obs.ids.shape[0])
        usable = n_obs >= self.config.min_observations
        if self.state != 'tracking':
            if not usable:
                return self._pass_through(stamp_ns, odom)
            i = self.kf.add(stamp_ns, odom, obs, KeyframeStatus.COLLECTED, self._odom_cov,
                            self._segment)
            if odom is not None:
                self.kf.R_map[i], self.kf.C_map[i] = self._through_map_from_odom(i)
            return self._maybe_initialize(i)
        if not usable:
            return self._dead_reckon(stamp_ns, odom)
        R0, C0 = predict_pose(self.kf, self.map_from_odom, self._segment, odom)
        i = self.kf.add(stamp_ns, odom, obs, KeyframeStatus.ACTIVE, self._odom_cov, self._segment)
        self.kf.R_map[i], self.kf.C_map[i] = R0, C0
        if not solve and (self.config.mode == 'global'
                          or self.deferred < self.config.window_size // 2):
            self.deferred += 1
            return UpdateInfo('deferred', keyframe=i, message='solve deferred: input waiting')
        info = self._refine()
        info.keyframe = i
        return info

    def solve_deferred(self) -> UpdateInfo | None:
        """Run the solve keyframes added with ``solve=False`` left (None: none is left)."""
        return self._refine() if self.deferred and self.state == 'tracking' else None

    # --- initialization ------------------------------------------------------------------

    def _through_map_from_odom(self, i: int) -> tuple[FloatArray, FloatArray]:
        """Return keyframe i's front-end pose mapped through the current map <- odom."""
        R, C = self.map_from_odom.apply_poses(self.kf.R_odom[i][None], self.kf.C_odom[i][None])
        return R[0], C[0]

    def _pass_through(self, stamp_ns: int, odom: tuple[FloatArray, FloatArray] | None,
                      ) -> UpdateInfo:
        """Keep a keyframe that cannot join the initialization batch at its front-end pose."""
        if odom is None:
            return UpdateInfo('dropped', message='keyframe without enough observations or '
                              'front-end pose before initialization')
        i = self.kf.add(stamp_ns, odom, None, KeyframeStatus.PASSED_THROUGH, self._odom_cov,
                        self._segment)
        self.kf.R_map[i], self.kf.C_map[i] = self._through_map_from_odom(i)
        return UpdateInfo('passed_through', keyframe=i,
                          message='keyframe with too few observations: front-end pose')

    def _maybe_initialize(self, i: int) -> UpdateInfo:
        cfg = self.config
        batch = self.kf.indices(KeyframeStatus.COLLECTED)
        info_drop: dict[str, int] = {}
        if batch.shape[0] > cfg.init_max_batch:
            dropped = batch[:batch.shape[0] - cfg.init_max_batch]
            keep_pose = self.kf.has_odom[dropped]
            self.kf.status[dropped[keep_pose]] = KeyframeStatus.PASSED_THROUGH
            self.kf.status[dropped[~keep_pose]] = KeyframeStatus.DISCARDED
            for j in dropped:
                self.kf.obs.pop(int(j), None)
            batch = self.kf.indices(KeyframeStatus.COLLECTED)
            if np.any(~keep_pose):
                info_drop['keyframes_dropped_before_init'] = int(np.count_nonzero(~keep_pose))
        if batch.shape[0] < cfg.init_batch_size or self.kf.n < self._next_init_attempt:
            return UpdateInfo('collect', keyframe=i, message=self.last_message, dropped=info_drop)
        focal = math.sqrt(self.fx) * math.sqrt(self.fy)   # fx * fy can underflow
        min_angle = cfg.init_min_parallax_px / focal
        need = cfg.init_features_needed(batch.shape[0])
        count = well_conditioned_features(self.kf, batch, min_angle, cfg.camera_id, need)
        if count < need:
            self.state = 'waiting_for_parallax'
            self.last_message = waiting_for_parallax(count, need, batch.shape[0],
                                                     cfg.init_min_parallax_px, focal)
            self._next_init_attempt = self.kf.n + cfg.init_retry_every
            return UpdateInfo('collect', keyframe=i, message=self.last_message, dropped=info_drop)
        info = self._initialize(batch, need)
        info.keyframe = i
        info.dropped.update(info_drop)
        return info

    def _build_problem(self, cams: IntArray, fixed: np.ndarray, feature_filter: IntArray | None,
                       R: FloatArray, C: FloatArray, refine: bool = True) -> BAProblem:
        """Build a problem over keyframes ``cams`` (its ``feature_ids`` are the feature ids).

        A refine's problem uses every camera's observations, with configured cameras besides
        the reference one through a :class:`~pmba_ros.core.problem.Rig` (one pose per
        keyframe, the reference camera's), and comes in the solver's feature order; a
        sliding window's tracks are thinned. The pixels are nominal (the reference camera's
        pinhole on each camera's normalized coordinates).
        """
        rig = self._rig() if refine else None
        cap = self.config.max_observations_per_feature if feature_filter is not None else 0
        g = gather_observations(self.kf, cams, feature_filter, self.config.camera_id,
                                rig is not None, max_per_feature=cap, by_track_length=refine)
        xy = g.normalized
        pixels = np.column_stack([self.fx * xy[:, 0] + self.cx, self.fy * xy[:, 1] + self.cy])
        intr = Intrinsics.uniform(cams.shape[0], self.fx, self.fy, self.cx, self.cy)
        return make_problem(R, C, intr, g.local, g.feat_idx, pixels, bearings_c=g.bearings,
                            fixed=fixed, n_feats=g.feature_ids.shape[0],
                            feature_ids=g.feature_ids, camera=g.camera, rig=rig,
                            pixel_jac=g.pixel_jacobians(self.fx, self.fy))

    def _initialize(self, batch: IntArray, need: int) -> UpdateInfo:
        from pmba_ros.init.pipeline import global_init

        cfg = self.config
        M = batch.shape[0]
        problem = self._build_problem(batch, np.zeros(M, bool), None,
                                      np.tile(np.eye(3), (M, 1, 1)), np.zeros((M, 3)), False)
        opts = cfg.init_options(need)
        t0 = time.perf_counter()
        self.init_attempts += 1
        try:
            import cv2

            cv2.setRNGSeed(cfg.seed)
            result = global_init(problem, opts, progress=lambda *_: self.checkpoint(),
                                 callback=lambda _: self.checkpoint())
            used = batch[result.camera_index]
            try:
                R, C, sim, worst = in_odom_frame(self.kf, used, result.solve.R_wc,
                                                 result.solve.centers_w,
                                                 cfg.fallback_max_motion_error)
            except InitError:
                self._contradicted += 1
                if self._contradicted < INIT_CONTRADICTIONS:
                    raise
                worst = math.inf   # vision alone keeps fitting something else (wrong tracks)
            if worst > cfg.fallback_max_motion_error:
                # Steps far off the front-end's: the batch starts from its poses, re-seeded
                # below, at its scale (the fit of which the wrong tracks spoil too).
                has = used[self.kf.has_odom[used]]
                near = has[np.abs(has[None, :] - used[:, None]).argmin(axis=1)]
                R, C, sim = self.kf.R_odom[near], self.kf.C_odom[near], Similarity.identity()
        except (InitError, PmbaError, np.linalg.LinAlgError, ValueError) as err:
            self.state = 'waiting_for_parallax'
            self.last_message = f'waiting for parallax: initialization failed: {err}'
            self._next_init_attempt = self.kf.n + cfg.init_retry_every
            logger.info('%s', self.last_message)
            return UpdateInfo('init_failed', message=self.last_message)
        res = result.solve
        self.kf.R_map[used], self.kf.C_map[used] = R, C
        fids = problem.feature_ids[result.feature_index]
        with np.errstate(invalid='ignore'):   # points at infinity: unknown (NaN) below
            points = sim.scale * res.points_w @ sim.rotation.T + sim.translation
        self.features.upsert(fids, np.where(finite_rows(points)[:, None], points, np.nan))
        self.kf.status[batch] = KeyframeStatus.ACTIVE
        self.state = 'tracking'
        self._update_similarity()
        self._metric_scale = self.map_from_odom.scale
        self.pixel_noise.note(res.noise_px)
        passed = self.kf.indices(KeyframeStatus.PASSED_THROUGH)
        if passed.shape[0]:  # waited in the odom frame: from now on placed as later ones are
            self.kf.R_map[passed], self.kf.C_map[passed] = self.map_from_odom.apply_poses(
                self.kf.R_odom[passed], self.kf.C_odom[passed])
            self.kf.status[passed] = KeyframeStatus.DEAD_RECKONED
        left_out = np.setdiff1d(batch, used)
        for j in left_out:  # no EG pair: start from the front-end (or the nearest keyframe)
            self.kf.R_map[j], self.kf.C_map[j] = pose_from_odom_or_nearest(
                self.kf, self.map_from_odom, int(j), used)
        info = UpdateInfo('init', solve_ms=1e3 * (time.perf_counter() - t0),
                          iterations=res.iterations, cost_before=res.initial_cost,
                          cost_after=res.final_cost, n_cams=res.problem.n_cams,
                          n_free=res.problem.n_cams, n_feats=res.problem.n_feats,
                          n_obs=res.problem.n_obs,
                          message=f'initialized {used.shape[0]} of {M} keyframes')
        if worst > cfg.fallback_max_motion_error:   # the solves bring the vision in
            self._reseed_window()
            info.dropped['reinitializations'] = 1
            info.message += "; steps off the front-end's: re-seeded from it"
        if cfg.motion_prior_translation_rel > 0 or cfg.motion_prior_rotation_rad > 0:
            # The initialization used vision alone; where near features are few its local
            # motion is noisier than the front-end's. One refine of the whole batch with the
            # front-end's motion as prior, before older keyframes leave the window.
            refine = self._refine(slide=False)
            info.solve_ms += refine.solve_ms
            for reason, n in refine.dropped.items():   # a rollback counted, as any solve's
                info.dropped[reason] = info.dropped.get(reason, 0) + n
            if refine.dropped.get('solve_rollbacks') and not info.dropped.get('reinitializations'):
                self._reseed_window()   # its poses, vision alone, disagree with that
                info.dropped['reinitializations'] = 1
                info.message += "; its refine with the front-end's motion rejected: re-seeded"
        self._slide()
        if left_out.shape[0]:
            refine = self._refine()
            info.message += f'; {left_out.shape[0]} refined afterwards'
            info.solve_ms += refine.solve_ms
        self.last_message = 'tracking'
        place_unsolved(self.kf, self.optimized(np.arange(self.kf.n)), self.map_from_odom.scale, 0)
        logger.info('%s (%.0f ms)', info.message, info.solve_ms)
        return info

    # --- tracking -------------------------------------------------------------------------

    def _dead_reckon(self, stamp_ns: int, odom: tuple[FloatArray, FloatArray] | None,
                     ) -> UpdateInfo:
        if odom is None:
            return UpdateInfo('dropped', message='keyframe without tracks or front-end pose')
        R, C = predict_pose(self.kf, self.map_from_odom, self._segment, odom)
        i = self.kf.add(stamp_ns, odom, None, KeyframeStatus.DEAD_RECKONED, self._odom_cov,
                        self._segment)
        self.kf.R_map[i], self.kf.C_map[i] = R, C
        return UpdateInfo('dead_reckoned', keyframe=i,
                          message='keyframe with too few observations: front-end pose')

    def _slide(self) -> IntArray | None:
        """Fix keyframes that left the window; retire features and old observations.

        Returns:
            The ids of the features the window's keyframes observe (sliding mode), or None.
        """
        if self.config.mode != 'sliding':
            return None
        active = self.kf.indices(KeyframeStatus.ACTIVE)
        K = self.config.window_size
        if active.shape[0] > K:
            self.kf.status[active[:-K]] = KeyframeStatus.FIXED
            active = active[-K:]
        window_ids = self.kf.observed_ids(active)
        _, points = self.features.pop_except(window_ids)
        self.landmarks.add(points)
        self.kf.forget_observations_before(int(active[0]) - self.config.fixed_lookback)
        return window_ids

    def _refine(self, *, slide: bool = True) -> UpdateInfo:
        cfg = self.config
        iterations, self.deferred = cfg.max_iterations * (1 + self.deferred), 0
        rig = self._rig() is not None
        window_ids = self._slide() if slide else None
        active = self.kf.indices(KeyframeStatus.ACTIVE)
        if window_ids is not None:
            older = np.array(sorted(i for i in self.kf.obs if i < active[0]), dtype=np.int64)
            fixed_kf = select_fixed(self.kf, older, window_ids, cfg.max_fixed_keyframes)
            cams = np.concatenate([fixed_kf, active])
            fixed = np.arange(cams.shape[0]) < fixed_kf.shape[0]   # the fixed ones come first
            feature_filter: IntArray | None = window_ids
            sampled = self.frontend_noise.wants_sample()
        else:
            cams = np.array(sorted(i for i in self.kf.obs), dtype=np.int64)
            fixed = np.arange(cams.shape[0]) == 0   # the oldest holds the map
            feature_filter, sampled = None, False
        info = UpdateInfo('refine')
        try:
            problem = self._build_problem(cams, fixed, feature_filter, self.kf.R_map[cams],
                                          self.kf.C_map[cams])
            pts = self.features.lookup(problem.feature_ids)
            step = typical_step(self._run_scale, problem.centers_w)
            feats, ok = xyz_to_parallax(problem, problem.R_wc, problem.centers_w, pts,
                                        min_baseline=ANCHOR_BASELINE_REL * step)
            if not np.all(ok):
                problem = subset_features(problem, ok, 'features_without_anchor_baseline')
                feats = ParallaxFeatures(feats.theta[ok], feats.n[ok], feats.main_idx[ok],
                                         feats.assoc_idx[ok])
            options = SolveOptions(param=Parameterization.PMBA, solver=SolverKind.DOGLEG,
                                   loss=Loss(cfg.loss), loss_scale_px=cfg.loss_scale_px,
                                   max_iterations=iterations,
                                   max_time_s=math.inf if cfg.deterministic else cfg.max_time_s,
                                   prior_leverage=sampled,
                                   scale_tension=window_ids is not None and rig)
            prior = self._motion_prior(cams, fixed, step)
            fixed = fixed | untied_chains(problem, prior, finite_rows(pts)[ok],
                                          cfg.min_observations)
            res = solve(replace(problem, fixed=fixed), options, feats, pose_prior=prior,
                        callback=lambda _: self.checkpoint())
        except (PmbaError, np.linalg.LinAlgError, ValueError) as err:
            info.message = f'refine failed, keeping the prediction: {err}'
            logger.warning('%s', info.message)
            return info
        # The front-end's frame jumped where a solved step (not a rig's held one) stays far off
        # its step (jumps too small for the pose check): a new odom segment starts there,
        # before map <- odom is re-estimated. A rolled-back solve is no evidence: segments stay.
        segments = self.kf.segment[:self.kf.n].copy()
        jumped = np.zeros(0, dtype=np.int64) if prior is None else cams[prior.b[
            (step_sigmas(prior, res.prior_residuals) > JUMP_SIGMAS) & ~fixed[prior.b]]]
        for k in np.sort(jumped).tolist():
            self.kf.segment[k:self.kf.n] += 1
        free = ~res.problem.fixed
        moved = cams[free]
        before = (self.kf.R_map[moved].copy(), self.kf.C_map[moved].copy(), self.map_from_odom)
        error_before = motion_error(self.kf, moved, self.map_from_odom.scale)
        self.kf.R_map[moved] = res.R_wc[free]
        self.kf.C_map[moved] = res.centers_w[free]
        self._update_similarity()
        failure = inconsistency(self.kf, self.config, (res.initial_cost, res.final_cost),
                                (before[2].scale, self.map_from_odom.scale), moved, error_before)
        if not failure and (failure := self._cost.check(res.bounded_cost,
                                                        res.problem.n_obs) or ''):
            info.dropped['cost_explosions'] = 1   # garbage tracks: a fit to them is not kept
        info.solve_ms, info.iterations = 1e3 * res.time_s, res.iterations
        info.cost_before, info.cost_after = res.initial_cost, res.final_cost
        if failure:
            self.kf.R_map[moved], self.kf.C_map[moved], self.map_from_odom = before
            self.kf.segment[:segments.shape[0]] = segments
            return self._fall_back(info, failure)
        self._failures = 0
        for k in jumped.tolist():
            logger.warning('front-end step into keyframe %d is over %g sigmas off the map: '
                           'its frame jumped; a new odom segment starts there', k, JUMP_SIGMAS)
        info.dropped['odom_frame_jumps'] = jumped.shape[0]
        self.pixel_noise.note(res.noise_px)
        if prior is not None:
            self.frontend_noise.note(prior, res.prior_residuals, res.prior_leverage, step)
        pts = np.where(finite_rows(res.points_w)[:, None], res.points_w, np.nan)
        self.features.upsert(res.problem.feature_ids, pts)
        factor, info.dropped['scale_steps_left_out'] = self._rig_scale.take(*res.scale_tension)
        if factor is not None:   # after the solve's points are in: they scale with the rest
            rescale_map(self.kf, self.features, self.landmarks, self._run_scale, factor)
            self.map_version += 1
            self._update_similarity()
        info.n_cams, info.n_free = res.problem.n_cams, int(np.count_nonzero(free))
        info.n_feats, info.n_obs = res.problem.n_feats, res.problem.n_obs
        if jumped.size:   # this solve was pulled by the factors across the jump: again without
            info.solve_ms += self._refine(slide=slide).solve_ms
        place_unsolved(self.kf, self.optimized(np.arange(self.kf.n)), self.map_from_odom.scale,
                       int(moved.min()) if moved.size else self.kf.n)
        return info

    def _motion_prior(self, cams: IntArray, fixed: BoolArray,
                      step: float) -> RelativePosePrior | None:
        """Return the front-end's motion between the problem's keyframes as a prior.

        ``step``: the map's typical step (:func:`~pmba_ros.backend.motion.typical_step`).
        """
        monocular = self._rig() is None
        # A monocular window's scale wanders; the run's own scale so far is a steadier reference
        # for it than the initialization's (a rig's map is metric; a global solve holds the run).
        sliding = monocular and self.config.mode == 'sliding'
        run = self._run_scale.scale(self.kf, self._metric_scale)   # its path serves every mode
        ref = run if sliding else self._metric_scale
        return frontend_motion_prior(self.kf, cams, fixed, ref, self.config,
                                     follow_map_scale=monocular,
                                     pixel_sigma=self.pixel_noise.sigma,
                                     noise_factors=self.frontend_noise.factors,
                                     white_noise=self.frontend_noise.white,
                                     run_steps=self._run_scale.steps if sliding else self.kf.n,
                                     typical=step)

    def _fall_back(self, info: UpdateInfo, reason: str) -> UpdateInfo:
        """Keep the window's poses from before a rejected solve; re-seed it after repeats.

        After ``fallback_reinit_after`` rejected solves in a row the window is re-initialized
        from the front-end: each free keyframe is re-predicted from its predecessor with the
        front-end's relative motion, and its features restart from rotations (PMBA Remark 5).
        """
        self._failures += 1
        info.dropped['solve_rollbacks'] = 1
        info.message = f'solve rejected ({reason}): kept the previous poses'
        if self._failures >= self.config.fallback_reinit_after:
            self._reseed_window()
            info.dropped['reinitializations'] = 1
            info.message += '; window re-initialized from the front-end'
        logger.warning('%s', info.message)
        return info

    def _reseed_window(self) -> None:
        """Re-predict each free keyframe from its predecessor with the front-end's motion.

        The window's features restart from rotations (PMBA Remark 5); rejected solves are
        counted anew.
        """
        self._failures = 0
        active = self.kf.indices(KeyframeStatus.ACTIVE)
        for i in active[active > 0]:
            odom = (self.kf.R_odom[i], self.kf.C_odom[i]) if self.kf.has_odom[i] else None
            self.kf.R_map[i], self.kf.C_map[i] = predict_pose(self.kf, self.map_from_odom,
                                                              self._segment, odom, int(i))
        ids = np.unique(np.concatenate([self.kf.obs[int(i)].ids for i in active
                                        if int(i) in self.kf.obs]))
        self.features.upsert(ids, np.full((ids.shape[0], 3), np.nan))
        self._update_similarity()

    def _update_similarity(self) -> None:
        """Re-estimate map <- odom from the free keyframes with front-end poses."""
        self.map_from_odom = fit_map_from_odom(self.kf, self._run_scale, self.map_from_odom,
                                               self.config.window_size,
                                               self.config.mode == 'global')

    # --- accessors ------------------------------------------------------------------------

    def estimated(self) -> IntArray:
        """Return the keyframes that have a map pose, ascending.

        That is every keyframe with a front-end pose, and the initialized ones without;
        :meth:`optimized` tells which of them the solver estimated.
        """
        n = self.kf.n
        status = self.kf.status[:n]
        has_pose = (status != KeyframeStatus.DISCARDED) & (
            (status != KeyframeStatus.COLLECTED) | self.kf.has_odom[:n])
        return np.flatnonzero(has_pose).astype(np.int64)

    def optimized(self, idx: IntArray) -> BoolArray:
        """Return which of keyframes ``idx`` the solver estimated (others: front-end poses)."""
        status = self.kf.status[idx]
        return (status == KeyframeStatus.ACTIVE) | (status == KeyframeStatus.FIXED)

    def landmark_points(self) -> FloatArray:
        """Return retired landmarks and the current features' finite points, shape (L, 3)."""
        active = self.features.points[finite_rows(self.features.points)]
        return np.concatenate([self.landmarks.points(), active])
