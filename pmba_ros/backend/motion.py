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
"""The front-end's motion as information: the relative-pose prior and what it is weighed by.

A window solve must not make the local motion worse than the front-end's (issue #12): the
front-end's keyframe-to-keyframe motion enters the solve as a weak prior
(:func:`frontend_motion_prior`), weighed by the noise the solves measure
(:class:`PixelNoise`, :class:`FrontendNoise`); each applied solve is then checked against
it (:mod:`pmba_ros.backend.consistency`).
"""

from __future__ import annotations

from collections import deque
import math
import statistics

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.window import (
    estimate_similarity,
    KeyframeStatus,
    KeyframeStore,
    Similarity,
)
from pmba_ros.core import so3
from pmba_ros.core.pose_prior import RelativePosePrior, StepChanges, WindowScale


def row_norms(x: FloatArray) -> FloatArray:
    """Return the norms of the rows of ``x`` (N, 3): np.linalg.norm's sums, without its wrapper."""
    return np.sqrt(np.add.reduce(x * x, axis=1))


class PixelNoise:
    """The tracks' per-axis pixel noise: the median of the recent solves' estimates.

    Enough solves are pooled that one odd window does not move the prior's weight, few
    enough that the estimate follows a change of the tracks' quality; 1 px before any.
    """

    HISTORY = 25

    def __init__(self) -> None:
        """Start without an estimate."""
        self._recent: deque[float] = deque(maxlen=self.HISTORY)
        self._sigma = 1.0   # read at every keyframe (prior, diagnostics), changed by note()

    @property
    def sigma(self) -> float:
        """Return the pooled estimate, px."""
        return self._sigma

    def note(self, noise_px: float) -> None:
        """Add one solve's estimate (non-finite or non-positive ones are skipped)."""
        if math.isfinite(noise_px) and noise_px > 0:
            self._recent.append(noise_px)
            self._sigma = float(statistics.median(self._recent))   # np.median's, cheaper


class RunScale:
    """The map <- odom scale of the run so far: the map's path length over the front-end's.

    Over the steps between consecutive optimized keyframes (free or fixed, both with
    front-end poses). A fixed keyframe does not move again, so the steps between fixed ones
    are summed once; the window's are summed at each call, which keeps the cost per keyframe
    flat over a long run.
    """

    def __init__(self) -> None:
        """Start with nothing summed."""
        self._map = 0.0
        self._odom = 0.0
        self._fixed_steps = 0   # the steps in the sums
        self._done = 1  # the steps (i - 1, i) with i < _done are in the sums
        self.steps = 0
        """The number of steps the last :meth:`scale` summed."""
        self.path = 0.0
        """The map's length of those steps."""

    def scale(self, kf: KeyframeStore, fallback: float) -> float:
        """Return the map <- odom scale of the run (``fallback`` before any step moved)."""
        n = kf.n
        status = kf.status[:n]
        unsettled = (status == KeyframeStatus.ACTIVE) | (status == KeyframeStatus.COLLECTED)
        pending = np.flatnonzero(unsettled[self._done - 1:])
        stop = self._done - 1 + int(pending[0]) if pending.shape[0] else n
        if stop > self._done:
            fixed = status[self._done - 1:stop] == KeyframeStatus.FIXED
            m, o, count = self._lengths(kf, self._done, stop, fixed)
            self._map += m
            self._odom += o
            self._fixed_steps += count
            self._done = stop
        window = status[self._done - 1:]
        optimized = (window == KeyframeStatus.ACTIVE) | (window == KeyframeStatus.FIXED)
        m, o, count = self._lengths(kf, self._done, n, optimized)
        total_map, total_odom = self._map + m, self._odom + o
        self.steps, self.path = self._fixed_steps + count, total_map
        return total_map / total_odom if total_odom > 0 and total_map > 0 else fallback

    def rescale(self, factor: float) -> None:
        """Take a rescaling of the whole map by ``factor`` into the steps already summed."""
        self._map *= factor

    @staticmethod
    def _lengths(kf: KeyframeStore, first: int, stop: int,
                 usable: BoolArray) -> tuple[float, float, int]:
        """Sum the map and odom lengths of the steps (i - 1, i), first <= i < stop, and count them.

        ``usable`` flags the keyframes first - 1 .. stop - 1 whose steps may count.
        """
        if stop <= first:
            return 0.0, 0.0, 0
        i = np.arange(first, stop)
        ok = usable[1:] & usable[:-1] & kf.same_odom(i - 1, i)
        i = i[ok]
        step_map = row_norms(kf.C_map[i] - kf.C_map[i - 1])
        step_odom = row_norms(kf.C_odom[i] - kf.C_odom[i - 1])
        good = np.isfinite(step_map) & np.isfinite(step_odom)
        return (float(np.sum(step_map[good])), float(np.sum(step_odom[good])),
                int(np.count_nonzero(good)))


class FrontendNoise:
    """How the front-end's motion noise compares with the prior's sigmas.

    Helmert's variance components: at a solve's result, a prior residual whose leverage is
    h (its share of the fit, ``SolveResult.prior_leverage``) keeps 1 - h of its variance,
    its redundancy. Over the recent solves, the squared residuals over their summed
    redundancy estimate the variance factor of each group, in units of the pixel noise the
    prior was weighed against: rotation, translation along the step (its length) and
    across it (its direction). A front-end noisier than the parameters say has its sigmas
    grown by the square roots (:attr:`factors`), whatever front-end it is; 1 until the
    solves hold enough redundancy. Steps far beyond the others (:attr:`TRIM`) are left out:
    with wrong tracks in its window a solve leaves a few steps far off, which are not the
    front-end's noise (summed in, they raised the factors to 3.2 with 5 % wrong observations
    and left the vision more weight than it deserved).
    """

    HISTORY = 25
    MIN_REDUNDANCY = 10.0
    LIMITS = (1.0, 50.0)
    TRIM = 20.0
    """Steps beyond this many times their group's median squared residual over redundancy
    are left out of the estimates."""
    MOVING = 0.5
    """Steps shorter than this share of the typical step do not count in :attr:`white`: near
    rest a step's sigma is the floor, against which its noise vanishes (a stop drove it to a
    fifth)."""
    EVERY = 3
    """Window solves per sample: consecutive windows share most of their steps, and a
    leverage costs an inversion of the reduced system (a global solve's too much: the
    back-end samples sliding windows only)."""

    def __init__(self) -> None:
        """Start at the parameters' sigmas."""
        self._recent: deque[FloatArray] = deque(maxlen=self.HISTORY)
        self._factors = (1.0, 1.0, 1.0)
        self._white: tuple[float, float, float] | None = None
        self._asked = 0

    def wants_sample(self) -> bool:
        """Return whether the next solve should return its prior's leverage (one in EVERY)."""
        self._asked += 1
        return self._asked % self.EVERY == 1 or self.EVERY == 1

    @property
    def factors(self) -> tuple[float, float, float]:
        """Return the factors applied to the rotation, step-length and step-direction sigmas.

        The estimates within ``LIMITS``: the parameters are the most a front-end is
        trusted, as its errors beyond white step noise (a heading bias, a drifting
        scale) do not show in its steps one by one; a noisier one is trusted less. (Below
        1 an estimate is not followed by the weights, which Helmert's estimate assumes:
        it is not reported.)
        """
        return self._factors

    @property
    def white(self) -> tuple[float, float, float] | None:
        """Return the estimates themselves, below 1 as well (None until there are some).

        The scatter of single steps: the front-end's white step noise, which the step-change
        factors weigh in (:func:`frontend_motion_prior`).
        """
        return self._white

    def note(self, prior: RelativePosePrior, residuals: FloatArray,
             leverage: FloatArray, typical: float = 0.0) -> None:
        """Add one accepted solve: its ``prior_residuals`` and ``prior_leverage``.

        The prior was built with the current :attr:`factors`. Factors more than
        :data:`JUMP_SIGMAS` off (a step that is no motion) and factors without a leverage do
        not count. Those beyond the Huber threshold do: a front-end far noisier than the
        sigmas has most of its steps there until the factors have grown. :attr:`white` counts
        only steps of at least :attr:`MOVING` times ``typical`` (the run's typical step).
        """
        keep = ((step_sigmas(prior, residuals) <= JUMP_SIGMAS)
                & np.all(np.isfinite(leverage), axis=(1, 2)))
        if not np.any(keep):
            return
        e, hat = residuals[keep], leverage[keep]
        t = prior.t_ab[keep]
        along = t / np.maximum(np.sqrt(np.add.reduce(t * t, axis=1)), 1e-12)[:, None]
        e_along = np.einsum('mi,mi->m', e[:, 3:], along)
        h_along = np.einsum('mi,mij,mj->m', along, hat[:, 3:, 3:], along)
        h_trans = hat[:, 3, 3] + hat[:, 4, 4] + hat[:, 5, 5]
        # Each step's squared residual per group (rotation, along, across) and redundancy,
        # in units of the pixel noise the prior was weighed against (its huber / sigmas).
        unit = np.array(self._factors) * PRIOR_HUBER_SIGMAS / prior.huber
        e_rot, e_trans = np.add.reduce(e[:, :3] ** 2, axis=1), np.add.reduce(e[:, 3:] ** 2, axis=1)
        squares = np.column_stack([e_rot, e_along ** 2, e_trans - e_along ** 2]) * unit ** 2
        redundancy = np.column_stack([3.0 - (hat[:, 0, 0] + hat[:, 1, 1] + hat[:, 2, 2]),
                                      1.0 - h_along, 2.0 - (h_trans - h_along)])
        moving = np.sqrt(np.add.reduce(t * t, axis=1)) >= self.MOVING * typical
        self._recent.append(np.stack([squares, redundancy,
                                      np.broadcast_to(moving[:, None], squares.shape)]))
        q, r, moved = np.concatenate(list(self._recent), axis=1)
        k = self._estimate(q, r)
        if k is not None:
            k = np.clip(k, *self.LIMITS)
            self._factors = (float(k[0]), float(k[1]), float(k[2]))
        moving = moved[:, 0] > 0
        white = self._estimate(q[moving], r[moving]) if np.any(moving) else None
        if white is not None:
            self._white = (float(white[0]), float(white[1]), float(white[2]))

    def _estimate(self, q: FloatArray, r: FloatArray) -> FloatArray | None:
        """Return Helmert's factors of squares q, redundancies r (n, 3) within TRIM; None: few."""
        ratio = q / np.maximum(r, 1e-12)
        kept = ratio <= self.TRIM * np.median(ratio, axis=0)
        q, r = np.add.reduce(q * kept, axis=0), np.add.reduce(r * kept, axis=0)
        return np.sqrt(q / r) if np.all(r >= self.MIN_REDUNDANCY) else None


PRIOR_HUBER_SIGMAS = 5.0
"""Where a motion-prior factor's cost turns linear, in sigmas of its (6) residuals: beyond the
noise of any step (chi with 6 degrees of freedom passes 5 once in about 5,000 steps)."""

JUMP_SIGMAS = 30.0
"""A solved step this many sigmas off the front-end's is no motion of it: its frame jumped."""

STEP_FLOOR_REL = 1e-3
"""Each translation sigma of the prior holds this share of the run's typical step
(:func:`typical_step`): a standstill step keeps a finite weight, and the floor scales with the
scene, as a map's units are the scene's (a fixed length would weigh a handheld camera's
centimetre steps far below a car's metre steps). The run's, not the window's: slowing to a
stop, a window's steps shrink to nothing, and a floor that shrank with them would take the
solve's millimetres for a jump of the front-end's frame."""

RUN_SCALE_SPAN = 200
"""Steps over which a front-end's scale error stays correlated. Its scale over n steps of a
run is an average of n / span independent samples of that error, so a step's length is held to
the reference scale with the variance ``motion_prior_translation_rel**2 * (1 + span / n)``:
loosely early in a run, where that scale is itself uncertain, and more tightly on a long one,
where a window's vision lets the map's scale wander further than the front-end's strays."""

ANCHOR_BASELINE_REL = 0.01
"""Camera pairs closer than this share of the run's typical step anchor no feature. Standing
still, keyframes sit within the solve's noise of each other: a feature seen only from there
has no parallax, and anchored on such a pair its angle fits that noise and puts its point
at the camera, where every later observer sees it wrong. Such features wait, out of the
solve, for a keyframe with a baseline."""

MIN_PIXEL_SIGMA = 0.1
"""Pixel noise below which tracks are not trusted more: a feature tracker's sub-pixel
accuracy ends about there, whatever a noise-free simulation's residuals say."""


def frontend_motion_prior(kf: KeyframeStore, cams: IntArray, fixed: BoolArray,
                          metric_scale: float, config: BackendConfig, *,
                          follow_map_scale: bool = True, pixel_sigma: float = 1.0,
                          noise_factors: tuple[float, float, float] = (1.0, 1.0, 1.0),
                          white_noise: tuple[float, float, float] | None = None,
                          run_steps: int = 0, typical: float = 0.0) -> RelativePosePrior | None:
    """Return the front-end's motion between consecutive problem keyframes as a prior.

    Factors join each keyframe of the (ascending) problem ``cams`` with the next one when
    both have front-end poses and one is free (for a rig, held pairs too: below). A step's
    length enters as two Gaussian factors merged into one:

    * against ``metric_scale``, the reference map <- odom scale (the run's, :class:`RunScale`,
      or the initialization's; sigma ``motion_prior_translation_rel``, grown as
      :data:`RUN_SCALE_SPAN` says for a run of ``run_steps`` steps, not at all for 0);
    * against the map's own scale around the step (sigma ``motion_prior_shape_rel``): a
      front-end's step lengths agree with each other far better than its scale holds.

    The second keeps the front-end's local motion and leaves the map's scale to the
    vision, the first slowly pulls that scale back to the run's. With
    ``follow_map_scale`` (monocular solves, sliding or global, whose vision sees the scale
    weakly and step by step) the map's scale is taken before the solve
    (:func:`local_scales` over ``window_size`` steps), which also holds back changes of it.
    A stereo rig's map is metric: there the scale is a level and a trend fitted to the
    solved steps of each run of ``window_size`` steps at every evaluation
    (:class:`~pmba_ros.core.pose_prior.WindowScale`), which leaves it to the rig's baseline
    and a front-end's slow scale drift out; the steps between held keyframes of the
    problem join the fit, so a window's scale continues the held map's.
    Weights: one sigma (of the length, of the direction across it
    ``motion_prior_direction_rel``, each of the step plus :data:`STEP_FLOOR_REL` of a typical one,
    ``typical`` (:func:`typical_step`; 0: the median moving front-end step of ``cams`` in map
    units);
    ``motion_prior_rotation_rad``) counts as much as one sigma of the tracks' pixel noise,
    ``pixel_sigma`` (measured by the solves), so that noisy tracks lean more on the
    front-end and clean ones less; where the front-end gives pose covariances they take
    over (:func:`covariance_weights`). ``noise_factors`` multiply the rotation, step
    length and step direction sigmas (:class:`FrontendNoise`). Where ``white_noise`` (the
    measured scatter of single steps, :attr:`FrontendNoise.white`) is below them, consecutive
    steps are also joined by step-change factors (:func:`step_changes`).
    """
    cfg = config
    if cfg.motion_prior_translation_rel <= 0 and cfg.motion_prior_rotation_rad <= 0:
        return None
    a_loc = np.arange(cams.shape[0] - 1)
    a, b = cams[:-1], cams[1:]
    ok = kf.same_odom(a, b) & (~(fixed[:-1] & fixed[1:]) | (not follow_map_scale))
    a_loc, a, b = a_loc[ok], a[ok], b[ok]
    R_ab = np.einsum('mji,mjk->mik', kf.R_odom[a], kf.R_odom[b])
    t_odom = np.einsum('mji,mj->mi', kf.R_odom[a], kf.C_odom[b] - kf.C_odom[a])
    step = row_norms(t_odom)
    along = t_odom / np.maximum(step, 1e-12)[:, None]
    P_along = np.einsum('mi,mj->mij', along, along)
    scale = np.full(a.shape[0], metric_scale)
    W_trans = np.zeros((a.shape[0], 3, 3))
    window_scale = None
    if typical <= 0:
        moving = np.sort(step[step > 0])   # its middle element: np.median without its cost
        typical = metric_scale * (float(moving[moving.size // 2]) if moving.size else 1.0)
    floor = STEP_FLOOR_REL * typical
    if cfg.motion_prior_translation_rel > 0:
        rel = cfg.motion_prior_translation_rel
        if run_steps > 0:
            rel *= math.sqrt(1.0 + RUN_SCALE_SPAN / run_steps)
        info = 1.0 / (rel * metric_scale * step + floor) ** 2
        if cfg.motion_prior_shape_rel > 0 and follow_map_scale:
            local = local_scales(kf, a, b, t_odom, metric_scale, cfg.window_size, step)
            info_local = 1.0 / (cfg.motion_prior_shape_rel * local * step + floor) ** 2
            scale = (info * metric_scale + info_local * local) / (info + info_local)
            info = info + info_local
        elif cfg.motion_prior_shape_rel > 0 and a.shape[0]:
            info_local = 1.0 / (cfg.motion_prior_shape_rel * metric_scale * step + floor) ** 2
            groups = max(1, round(a.shape[0] / cfg.window_size))
            window_scale = WindowScale(info_local / (info + info_local),
                                       np.arange(a.shape[0]) * groups // a.shape[0])
            info = info + info_local
        # Square-root information: along the step (its length: the scale) and across it
        # (its direction, which a front-end measures much better).
        w_dir = 1.0 / (cfg.motion_prior_direction_rel * scale * step + floor)
        W_trans = (np.sqrt(info)[:, None, None] * P_along
                   + w_dir[:, None, None] * (np.eye(3) - P_along))
    w_rot = np.full(a.shape[0], 1.0 / cfg.motion_prior_rotation_rad
                    if cfg.motion_prior_rotation_rad > 0 else 0.0)
    covariance_weights(kf, a, b, metric_scale, config, W_trans, w_rot)
    weight = max(pixel_sigma, MIN_PIXEL_SIGMA)
    k_rot, k_along, k_across = noise_factors
    if k_along != 1.0 or k_across != 1.0:
        W_trans = (P_along / k_along + (np.eye(3) - P_along) / k_across) @ W_trans
    w_rot, W_trans = (weight / k_rot) * w_rot, weight * W_trans
    t_ab = scale[:, None] * t_odom
    changes = step_changes(a_loc, t_ab, P_along, w_rot, W_trans, noise_factors, white_noise,
                           cfg.motion_prior_translation_rel)
    return RelativePosePrior(a_loc, a_loc + 1, R_ab, t_ab, w_rot, W_trans,
                             huber=PRIOR_HUBER_SIGMAS * weight, changes=changes,
                             window_scale=window_scale)


def step_changes(a: IntArray, t_ab: FloatArray, P_along: FloatArray, w_rot: FloatArray,
                 W_trans: FloatArray, factors: tuple[float, float, float],
                 white: tuple[float, float, float] | None,
                 scale_rel: float) -> StepChanges | None:
    """Return the step-change factors of consecutive prior factors (steps a -> a + 1).

    The step factors hold each step to ``factors`` (k) times the parameters' sigmas; single
    steps scatter ``white`` (w) times them. The step factors leave, per step and part
    (rotation, length, direction), ``k^2 / w^2 - 1`` times their information (none where
    w >= k or w is not measured): covariance S. A change of
    the error from step ab to bc has S_ab + S_bc, and independent factors on consecutive
    changes count its fastest component twice: 2 (S_ab + S_bc). A drift that stays over a
    step cancels in the change; near a stop the larger step's S sets it. The steps are
    brought to the map by a scale known to ``scale_rel``: where the step changes (speeding
    up, turning), ``scale_rel (t_bc - t_ab)`` adds to the covariance (stiff factors had
    held the map to a scale taken at a stop).

    Args:
        a: First pose of each step factor (consecutive steps: a[i + 1] == a[i] + 1).
        t_ab: The measured steps in map units, (M, 3).
        P_along: Projections onto each step's direction, (M, 3, 3).
        w_rot: The step factors' rotation weights, (M,).
        W_trans: Their translation weights, (M, 3, 3).
        factors: :attr:`FrontendNoise.factors`.
        white: :attr:`FrontendNoise.white`.
        scale_rel: Relative sigma of the scale the steps were brought to the map with.
    """
    k = np.asarray(factors)
    gain = np.zeros(3) if white is None else np.sqrt(
        np.maximum(k * k / np.maximum(np.asarray(white) ** 2, 1e-12) - 1.0, 0.0))
    # Not the newest step yet: a jump of the front-end's frame arrives there, and the solve
    # that finds it should not be pulled by more than the step's own factor.
    first = np.flatnonzero(a[1:-1] == a[:-2] + 1)
    if not np.any(gain) or first.size == 0:
        return None
    # Per step, the square-root information the white noise adds, and its covariance.
    E = (gain[1] * P_along + gain[2] * (np.eye(3) - P_along)) @ W_trans
    info = np.swapaxes(E, 1, 2) @ E
    ridge = 1e-12 * np.max(np.trace(info, axis1=1, axis2=2), initial=1.0)
    S = np.linalg.inv(info + ridge * np.eye(3))
    d = t_ab[first + 1] - t_ab[first]
    L = np.linalg.cholesky(2.0 * (S[first] + S[first + 1])
                           + scale_rel ** 2 * np.einsum('mi,mj->mij', d, d))
    W = np.linalg.inv(L)   # W (2 (S_ab + S_bc)) W^T = I
    var_rot = 1.0 / np.maximum((gain[0] * w_rot) ** 2, 1e-300)
    w_change = np.where(gain[0] > 0, 1.0 / np.sqrt(2.0 * (var_rot[first] + var_rot[first + 1])),
                        0.0)
    return StepChanges(first, w_change, W)


def typical_step(run: RunScale, centers: FloatArray) -> float:
    """Return the map's typical keyframe step for a problem whose camera centres are ``centers``.

    The run's mean map step (:class:`RunScale`); before the run has one, the problem's
    median moving step (0 without one). The run's holds through a standstill of any length,
    where the window's steps are all noise.
    """
    if run.steps and run.path > 0:
        return run.path / run.steps
    steps = row_norms(np.diff(centers, axis=0))
    moving = steps[steps > 0]
    return float(np.median(moving)) if moving.size else 0.0


def step_sigmas(prior: RelativePosePrior, residuals: FloatArray) -> FloatArray:
    """Return how many sigmas each factor's step is off the front-end's.

    ``residuals``: the factors' at the poses in question, ``prior.residuals(R, P)``, or a
    solve's ``prior_residuals`` at its result.
    """
    norm = np.sqrt(np.add.reduce(residuals * residuals, axis=1))
    return PRIOR_HUBER_SIGMAS * norm / prior.huber


def local_scales(kf: KeyframeStore, a: IntArray, b: IntArray, t_odom: FloatArray,
                 fallback: float, span: int, step_odom: FloatArray | None = None) -> FloatArray:
    """Return the map <- odom scale around each step a -> b, shape (M,).

    The median of the map / odom length ratios of the solved steps within ``span`` steps
    on either side. The last step, to the newest keyframe, holds only its prediction and
    does not count; ``fallback`` serves where fewer than two solved steps move nearby.
    ``step_odom``: the lengths of ``t_odom`` if the caller has them.
    """
    m = a.shape[0]
    if m == 0:
        return np.zeros(0)
    if step_odom is None:
        step_odom = row_norms(t_odom)
    step_map = row_norms(kf.C_map[b] - kf.C_map[a])
    with np.errstate(divide='ignore', invalid='ignore'):
        ratio = step_map / step_odom
    usable = (step_odom > 1e-6) & np.isfinite(ratio) & (ratio > 0)
    usable[-1:] = False
    # Row i: the ratios of steps i - span .. i + span, NaN where unusable or beyond the ends.
    width = 2 * span + 1
    padded = np.full(m + 2 * span, np.nan)
    padded[span:span + m] = np.where(usable, ratio, np.nan)
    windows = padded[np.arange(m)[:, None] + np.arange(width)]
    # The median of each window's valid ratios: sorting puts the NaNs last (np.nanmedian
    # is several times slower on these small rows).
    ordered = np.sort(windows, axis=1)
    valid = np.zeros(m + 2 * span + 1, dtype=np.intp)
    np.cumsum(usable, out=valid[span + 1:span + 1 + m])
    valid[span + 1 + m:] = valid[span + m]
    count = valid[width:] - valid[:m]
    rows = np.flatnonzero(count >= 2)
    scales = np.full(m, fallback)
    scales[rows] = 0.5 * (ordered[rows, (count[rows] - 1) // 2] + ordered[rows, count[rows] // 2])
    return scales


def covariance_weights(kf: KeyframeStore, a: IntArray, b: IntArray, metric_scale: float,
                       config: BackendConfig, W_trans: FloatArray, w_rot: FloatArray) -> None:
    """Weigh the factors a -> b by the front-end's pose covariances where they are usable.

    The covariance a step adds is taken as ``Sigma_b - Sigma_a`` (a front-end's covariance
    grows by what each step adds); where both keyframes have a covariance and that
    difference is positive definite, it replaces the parameter sigmas: translation
    ``W = Sigma_t^(-1/2)`` in the frame of a (times the map scale), rotation
    ``1 / sqrt(trace(Sigma_r) / 3)``. Parts switched off by their parameter stay off; other
    factors keep the parameter weights. In place.
    """
    both = np.flatnonzero(kf.has_cov[a] & kf.has_cov[b])
    if both.shape[0] == 0:
        return
    Q = kf.cov_odom[b[both]] - kf.cov_odom[a[both]]
    R_a = kf.R_odom[a[both]]
    Q_t = np.einsum('nji,njk,nkl->nil', R_a, Q[:, :3, :3], R_a) * metric_scale ** 2
    lam, V = np.linalg.eigh(0.5 * (Q_t + np.swapaxes(Q_t, 1, 2)))
    q_rot = (Q[:, 3, 3] + Q[:, 4, 4] + Q[:, 5, 5]) / 3.0   # the trace, without np.trace's wrapper
    scale = np.abs(Q).reshape(-1, 36).max(axis=1)
    pd = (lam[:, 0] > 1e-12 * scale) & (q_rot > 0)
    if config.motion_prior_translation_rel > 0:
        W = np.einsum('nij,nj,nkj->nik', V, 1.0 / np.sqrt(np.maximum(lam, 1e-300)), V)
        W_trans[both[pd]] = W[pd]
    if config.motion_prior_rotation_rad > 0:
        w_rot[both[pd]] = 1.0 / np.sqrt(q_rot[pd])


def predict_pose(kf: KeyframeStore, map_from_odom: Similarity, segment: int,
                 odom: tuple[FloatArray, FloatArray] | None,
                 n: int | None = None) -> tuple[FloatArray, FloatArray]:
    """Return the map pose of keyframe n (default: a new one) from its predecessor's.

    The front-end's relative motion, its translation scaled by ``map_from_odom``; constant
    velocity without front-end poses. ``segment``: the odom segment of a new keyframe.
    """
    n = kf.n if n is None else n
    prev = n - 1
    segment = segment if n == kf.n else int(kf.segment[n])
    # Across a jump of the front-end's frame neither its motion nor map <- odom holds.
    same_frame = int(kf.segment[prev]) == segment
    if odom is not None and kf.has_odom[prev] and same_frame:
        R_po, C_po = kf.R_odom[prev], kf.C_odom[prev]
        R_rel = R_po.T @ odom[0]
        t_rel = R_po.T @ (odom[1] - C_po)
        R_p, C_p = kf.R_map[prev], kf.C_map[prev]
        return so3.project(R_p @ R_rel), C_p + map_from_odom.scale * R_p @ t_rel
    if odom is not None and same_frame:
        R, C = map_from_odom.apply_poses(odom[0][None], odom[1][None])
        return R[0], C[0]
    if n >= 2:  # constant velocity
        R_a, C_a = kf.R_map[n - 2], kf.C_map[n - 2]
        R_b, C_b = kf.R_map[prev], kf.C_map[prev]
        R_rel = R_a.T @ R_b
        return so3.project(R_b @ R_rel), C_b + R_b @ (R_a.T @ (C_b - C_a))
    return kf.R_map[prev].copy(), kf.C_map[prev].copy()


def pose_from_odom_or_nearest(kf: KeyframeStore, map_from_odom: Similarity, j: int,
                              used: IntArray) -> tuple[FloatArray, FloatArray]:
    """Return keyframe j's front-end pose through map <- odom, else its nearest in used."""
    if kf.has_odom[j]:
        R, C = map_from_odom.apply_poses(kf.R_odom[j][None], kf.C_odom[j][None])
        return R[0], C[0]
    k = int(used[np.argmin(np.abs(used - j))])
    return kf.R_map[k].copy(), kf.C_map[k].copy()


def fit_map_from_odom(kf: KeyframeStore, run: RunScale, current: Similarity, window: int,
                      global_mode: bool) -> Similarity:
    """Return map <- odom fitted to the free keyframes with front-end poses (or ``current``).

    In global mode to the newest ``window`` of them; in the newest odom frame only (right
    after a jump, one pose fixes the new frame's rotation and offset, and the scale stays).
    Keyframes within a step of each other (a stop) do not measure the scale.
    """
    active = kf.indices(KeyframeStatus.ACTIVE)
    if global_mode:
        active = active[-window:]
    sel = active[kf.has_odom[active]]
    if sel.shape[0] == 0:
        return current
    newest = sel[kf.segment[sel] == kf.segment[sel[-1]]]
    if newest.shape[0] < 2 and newest.shape[0] == sel.shape[0]:
        return current
    step = typical_step(run, kf.C_map[newest])
    return estimate_similarity(kf.R_map[newest], kf.C_map[newest], kf.R_odom[newest],
                               kf.C_odom[newest], current.scale,
                               min_spread=step / current.scale)
