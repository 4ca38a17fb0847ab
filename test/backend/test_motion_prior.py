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
"""The front-end's motion prior: step lengths against the map's local scale."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.consistency import in_odom_frame, motion_error
from pmba_ros.backend.logic import BackendLogic, DIAGNOSTICS_TOPIC
from pmba_ros.backend.motion import (
    frontend_motion_prior,
    FrontendNoise,
    JUMP_SIGMAS,
    local_scales,
    MIN_PIXEL_SIGMA,
    PixelNoise,
    PRIOR_HUBER_SIGMAS,
    RUN_SCALE_SPAN,
    RunScale,
    step_changes,
    STEP_FLOOR_REL,
    typical_step,
)
from pmba_ros.backend.window import estimate_similarity, KeyframeStatus, KeyframeStore
from pmba_ros.core import so3
from pmba_ros.core.conversions import xyz_to_parallax
from pmba_ros.core.pose_prior import RelativePosePrior
from pmba_ros.core.solve import solve, SolveOptions
from pmba_ros.eval.metrics import ate, rpe
from pmba_ros.sim.scenes import street_scene
from pmba_ros.sim.sequence import simulate_sequence
import pytest

from .test_logic import BACKEND, config, diag_values, last, run


def _store(map_steps: np.ndarray) -> KeyframeStore:
    """Keyframes 1 m apart along x in odom; the map's steps have the given lengths."""
    kf = KeyframeStore()
    n = map_steps.shape[0] + 1
    for i in range(n):
        kf.add(i, (np.eye(3), np.array([float(i), 0.0, 0.0])), None, KeyframeStatus.ACTIVE)
    kf.R_map[:n] = np.eye(3)
    kf.C_map[:n, 0] = np.concatenate([[0.0], np.cumsum(map_steps)])
    return kf


def _steps(kf: KeyframeStore) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    idx = np.arange(kf.n)
    a, b = idx[:-1], idx[1:]
    return a, b, kf.C_odom[b] - kf.C_odom[a]


def test_local_scales_are_nearby_medians_of_solved_steps() -> None:
    """Each step gets the median map / odom ratio of its neighbours; the newest step is out."""
    steps = np.concatenate([np.full(10, 1.1), np.full(10, 0.9), [5.0]])  # last: a prediction
    kf = _store(steps)
    a, b, t_odom = _steps(kf)
    scales = local_scales(kf, a, b, t_odom, fallback=1.0, span=3)
    np.testing.assert_allclose(scales[:7], 1.1)
    np.testing.assert_allclose(scales[13:], 0.9)
    assert 0.9 <= scales[9] <= 1.1
    # The newest step's 7.0 would make the median 1.4.
    few = _store(np.array([1.2, 1.4, 7.0]))
    a, b, t_odom = _steps(few)
    np.testing.assert_allclose(local_scales(few, a, b, t_odom, 1.0, 3), 1.3)
    # Fewer than two solved steps nearby: the fallback.
    short = _store(np.array([1.2, 7.0]))
    a, b, t_odom = _steps(short)
    np.testing.assert_array_equal(local_scales(short, a, b, t_odom, 0.8, 3), [0.8, 0.8])
    none = np.zeros(0, dtype=np.int64)
    assert local_scales(short, none, none, np.zeros((0, 3)), 0.8, 3).shape == (0,)


@pytest.mark.parametrize('span', [1, 3, 20])
def test_local_scales_equal_nanmedians_of_padded_windows(span: int) -> None:
    """The windows' medians are np.nanmedian's, to the bit, with gaps, ends and odd counts."""
    rng = np.random.default_rng(span)
    steps = rng.uniform(0.5, 1.5, 30)
    steps[rng.choice(30, 8, replace=False)] = 0.0   # steps that did not move: unusable
    kf = _store(steps)
    a, b, t_odom = _steps(kf)
    ratio = np.linalg.norm(kf.C_map[b] - kf.C_map[a], axis=1) / np.linalg.norm(t_odom, axis=1)
    ratio[steps == 0] = np.nan
    ratio[-1] = np.nan
    padded = np.concatenate([np.full(span, np.nan), ratio, np.full(span, np.nan)])
    expected = []
    for i in range(steps.shape[0]):
        window = padded[i:i + 2 * span + 1]
        n_valid = np.count_nonzero(~np.isnan(window))
        expected.append(np.nanmedian(window) if n_valid >= 2 else 0.7)
    np.testing.assert_array_equal(local_scales(kf, a, b, t_odom, 0.7, span), expected)


def test_motion_error_is_the_median_relative_error() -> None:
    """np.median's value for odd and even counts, NaN for non-finite poses."""
    rng = np.random.default_rng(3)
    for n in (2, 3, 8, 9):
        kf = _store(rng.uniform(0.5, 1.5, n))
        idx = np.arange(kf.n)
        t_map = np.diff(kf.C_map[:kf.n], axis=0) / 1.3
        err = np.linalg.norm(t_map - np.diff(kf.C_odom[:kf.n], axis=0), axis=1)
        assert motion_error(kf, idx, 1.3) == np.median(err)
        kf.C_map[1] = np.nan
        assert np.isnan(motion_error(kf, idx, 1.3))


def test_pixel_noise_is_np_median_of_the_recent_estimates() -> None:
    """The pooled estimate equals np.median of the last HISTORY usable ones, odd or even."""
    noise = PixelNoise()
    assert noise.sigma == 1.0
    values = np.random.default_rng(5).uniform(0.2, 3.0, 40)
    for k, v in enumerate(values):
        noise.note(float(v))
        noise.note(-1.0)   # skipped
        assert noise.sigma == np.median(values[max(0, k + 1 - PixelNoise.HISTORY):k + 1])


def test_run_scale_sums_optimized_steps_once_as_keyframes_settle() -> None:
    """Path-length ratio over free and fixed steps; fixed ones summed once, others skipped."""
    steps = np.concatenate([np.full(10, 1.2), np.full(10, 0.8), np.full(5, 1.0)])
    kf = _store(steps)
    S = KeyframeStatus
    kf.status[:3] = S.PASSED_THROUGH   # never optimized: steps 1-3 do not count
    kf.status[12] = S.DEAD_RECKONED    # nor do its two steps
    run_scale = RunScale()
    ok = np.array([i for i in range(4, kf.n) if i not in (12, 13)])
    for fixed_up_to in (3, 8, 12, 20):
        kf.status[3:fixed_up_to] = np.where(
            np.arange(3, fixed_up_to) == 12, S.DEAD_RECKONED, S.FIXED)
        expected = steps[ok - 1].sum() / ok.shape[0]
        assert RunScale().scale(kf, fallback=-1.0) == pytest.approx(expected)
        assert run_scale.scale(kf, fallback=-1.0) == pytest.approx(expected)
        assert run_scale.steps == ok.shape[0]
    # The window (keyframes 20-25, still free) moves: its steps are summed anew.
    kf.C_map[20:kf.n, 0] += np.arange(kf.n - 20) * 0.5
    moved = np.linalg.norm(np.diff(kf.C_map[:kf.n], axis=0), axis=1)[ok - 1].sum() / ok.size
    assert moved != pytest.approx(expected)
    assert run_scale.scale(kf, -1.0) == pytest.approx(moved)
    kf.status[20:kf.n] = S.FIXED
    assert run_scale.scale(kf, -1.0) == pytest.approx(moved)
    assert RunScale().scale(KeyframeStore(), fallback=0.7) == 0.7


def test_step_length_follows_the_map_scale_with_a_pull_to_the_front_ends() -> None:
    """Two Gaussian factors on each step's length, merged: their information-weighted mean."""
    kf = _store(np.full(12, 1.3))
    cams, fixed = np.arange(kf.n), np.zeros(kf.n, dtype=bool)
    cfg = BackendConfig()
    prior = frontend_motion_prior(kf, cams, fixed, 1.0, cfg)
    assert prior is not None
    info_abs = 1.0 / (cfg.motion_prior_translation_rel * 1.0 + 1e-3) ** 2
    info_map = 1.0 / (cfg.motion_prior_shape_rel * 1.3 + 1e-3) ** 2
    expected = (info_abs * 1.0 + info_map * 1.3) / (info_abs + info_map)
    np.testing.assert_allclose(prior.t_ab[:, 0], expected)
    np.testing.assert_allclose(prior.W_trans[:, 0, 0], np.sqrt(info_abs + info_map))
    # Switched off: the initialization's scale alone.
    for follow in (True, False):
        plain = frontend_motion_prior(kf, cams, fixed, 1.0,
                                      BackendConfig(motion_prior_shape_rel=0.0),
                                      follow_map_scale=follow)
        assert plain is not None and plain.window_scale is None
        np.testing.assert_allclose(plain.t_ab[:, 0], 1.0)
        np.testing.assert_allclose(plain.W_trans[:, 0, 0], np.sqrt(info_abs))


def test_step_length_is_held_to_the_run_scale_more_tightly_as_the_run_grows() -> None:
    """Sigma rel * sqrt(1 + span / n) over n summed steps; the plain rel without a run."""
    kf = _store(np.full(12, 1.0))
    cams, fixed = np.arange(kf.n), np.zeros(kf.n, dtype=bool)
    cfg = BackendConfig(motion_prior_shape_rel=0.0)
    rel = cfg.motion_prior_translation_rel
    along = []
    for steps in (0, RUN_SCALE_SPAN // 4, RUN_SCALE_SPAN, 100 * RUN_SCALE_SPAN):
        prior = frontend_motion_prior(kf, cams, fixed, 1.0, cfg, run_steps=steps)
        assert prior is not None
        grown = rel * np.sqrt(1.0 + RUN_SCALE_SPAN / steps) if steps else rel
        np.testing.assert_allclose(prior.W_trans[:, 0, 0], 1.0 / (grown + 1e-3))
        along.append(float(prior.W_trans[0, 0, 0]))
    assert along[1] < along[2] < along[3] < along[0] * 1.01
    # The step's direction is not the run scale's business.
    direction = 1.0 / (cfg.motion_prior_direction_rel + 1e-3)
    np.testing.assert_allclose(prior.W_trans[:, 1, 1], direction)


def test_a_rigs_step_lengths_follow_its_windows_own_scale() -> None:
    """A rig's steps are held to each other (shape sigma), their scale and its trend left free.

    The second length factor is against the window's fitted scale (a level and a trend,
    :class:`~pmba_ros.core.pose_prior.WindowScale`) instead of the map's scale before the
    solve: a map stretched as a whole, or along a linear trend, costs only what the
    run-scale factor charges; one step 3 % longer costs far more. Steps between held
    keyframes join the fit, and do not count as the front-end's noise.
    """
    kf = _store(np.full(12, 1.0))
    cams, fixed = np.arange(kf.n), np.zeros(kf.n, dtype=bool)
    cfg = BackendConfig(motion_prior_rotation_rad=0.0, motion_prior_direction_rel=1e6)
    rig = frontend_motion_prior(kf, cams, fixed, 1.0, cfg, follow_map_scale=False)
    assert rig is not None and rig.window_scale is not None and rig.changes is None
    info_abs = 1.0 / (cfg.motion_prior_translation_rel + 1e-3) ** 2
    info_map = 1.0 / (cfg.motion_prior_shape_rel + 1e-3) ** 2
    np.testing.assert_allclose(rig.window_scale.share, info_map / (info_abs + info_map))
    np.testing.assert_array_equal(rig.window_scale.group, 0)
    np.testing.assert_allclose(rig.W_trans[:, 0, 0], np.sqrt(info_abs + info_map))
    R = np.tile(np.eye(3), (kf.n, 1, 1))
    C = kf.C_map[:kf.n]
    tau = rig.window_scale.basis()[:, 1]
    for lengths in (np.full(12, 1.03), 1.0 + 0.04 * tau):
        bent = np.zeros_like(C)
        bent[1:, 0] = np.cumsum(lengths)
        excess = lengths - 1.0
        assert rig.cost(R, bent) == pytest.approx(0.5 * info_abs * np.sum(excess ** 2), rel=1e-6)
    one_longer = C.copy()
    one_longer[6:, 0] += 0.03
    assert rig.cost(R, one_longer) > 10 * 0.5 * info_abs * 0.03 ** 2
    # Held keyframes' steps are in the fit (they hold the window's scale to the held map's).
    fixed[:4] = True
    held = frontend_motion_prior(kf, cams, fixed, 1.0, cfg, follow_map_scale=False)
    assert held is not None and len(held) == kf.n - 1
    # Monocular solves hold the lengths to the map's scale before the solve instead.
    mono = frontend_motion_prior(kf, cams, np.zeros(kf.n, dtype=bool), 1.0, cfg)
    assert mono is not None and mono.window_scale is None and len(mono) == kf.n - 1


def test_weights_count_one_sigma_as_one_sigma_of_the_pixel_noise() -> None:
    """The factors' square-root weights scale with the tracks' noise, down to a floor."""
    kf = _store(np.full(6, 1.0))
    cams, fixed = np.arange(kf.n), np.zeros(kf.n, dtype=bool)
    base = frontend_motion_prior(kf, cams, fixed, 1.0, BackendConfig())
    noisy = frontend_motion_prior(kf, cams, fixed, 1.0, BackendConfig(), pixel_sigma=2.5)
    clean = frontend_motion_prior(kf, cams, fixed, 1.0, BackendConfig(), pixel_sigma=1e-6)
    assert base is not None and noisy is not None and clean is not None
    np.testing.assert_allclose(noisy.W_trans, 2.5 * base.W_trans)
    np.testing.assert_allclose(noisy.w_rot, 2.5 * base.w_rot)
    np.testing.assert_allclose(clean.W_trans, MIN_PIXEL_SIGMA * base.W_trans)
    np.testing.assert_array_equal(noisy.t_ab, base.t_ab)


@pytest.mark.parametrize(('seed', 'n', 'noise_px'), [(0, 150, 2.0), (3, 300, 1.0)])
def test_noisy_tracks_lean_on_the_front_end(seed: int, n: int, noise_px: float) -> None:
    """Tracks noisier than the default simulation: measured, ATE and RPE below the front-end's.

    With the prior weighed against one pixel whatever the tracks' noise, both ended with
    an RPE 1.2x the front-end's.
    """
    seq = simulate_sequence('street', n_keyframes=n, seed=seed, noise_px=noise_px)
    logic = BackendLogic(config(), BACKEND)
    outputs = run(logic, seq)
    assert logic.estimator.pixel_noise.sigma == pytest.approx(noise_px, rel=0.1)
    diagnostics = diag_values(last(outputs, DIAGNOSTICS_TOPIC))
    assert float(diagnostics['tracks_noise_px']) == pytest.approx(noise_px, rel=0.1)
    gt, fe, opt = seq.gt_trajectory(), seq.odom_trajectory(), logic.optimized_trajectory()
    assert ate(opt, gt, 'sim3').rmse <= ate(fe, gt, 'sim3').rmse
    assert rpe(opt, gt, align='sim3').rmse <= rpe(fe, gt, align='sim3').rmse


def test_a_wide_fisheye_weighs_its_errors_by_its_own_pixels() -> None:
    """An equidistant camera seeing 80 degrees off its axis (focal 250 px, 640 x 480).

    Weighed as pinhole pixels, its border observations counted many times their noise: the
    tracks' noise was measured at 1.6x the simulated 0.5 px and the RPE was 1.3x the
    front-end's (loop, 120 keyframes).
    """
    seq = simulate_sequence('loop', n_keyframes=60, seed=0, distortion='equidistant',
                            focal_px=250.0)
    logic = BackendLogic(config(), BACKEND)
    outputs = run(logic, seq)
    diagnostics = diag_values(last(outputs, DIAGNOSTICS_TOPIC))
    assert float(diagnostics['tracks_noise_px']) == pytest.approx(0.5, rel=0.1)
    gt, fe, opt = seq.gt_trajectory(), seq.odom_trajectory(), logic.optimized_trajectory()
    assert rpe(opt, gt, align='sim3').rmse < rpe(fe, gt, align='sim3').rmse
    assert ate(opt, gt, 'sim3').rmse < ate(fe, gt, 'sim3').rmse


def test_keyframes_without_front_end_poses_give_no_factor() -> None:
    """Tracks without keyframe poses: an empty prior, not an error."""
    kf = KeyframeStore()
    for i in range(5):
        kf.add(i, None, None, KeyframeStatus.ACTIVE)
    prior = frontend_motion_prior(kf, np.arange(5), np.zeros(5, dtype=bool), 1.0,
                                  BackendConfig())
    assert prior is not None and len(prior) == 0


def test_global_mode_keeps_the_local_motion_where_vision_sees_it_weakly() -> None:
    """Aerial, 40 m up, 0.5 m steps: global mode's RPE stays below the front-end's.

    Without the step lengths held to the map's local scale it was well above it.
    """
    seq = simulate_sequence('aerial', n_keyframes=60, seed=0)
    logic = BackendLogic(config(mode='global'), BACKEND)
    run(logic, seq)
    gt, fe, opt = seq.gt_trajectory(), seq.odom_trajectory(), logic.optimized_trajectory()
    assert len(opt) == len(seq)
    assert rpe(opt, gt, align='sim3').rmse <= rpe(fe, gt, align='sim3').rmse
    assert ate(opt, gt, 'sim3').rmse <= ate(fe, gt, 'sim3').rmse


@pytest.mark.parametrize('true_over_parameters', [0.3, 2.5])
def test_frontend_noise_measures_the_steps_noise_against_the_parameters(
        true_over_parameters: float) -> None:
    """A front-end's noise over the prior's sigmas is found; a better one is not followed.

    Windows whose prior is measured with noise ``true_over_parameters`` times the sigmas its
    weights assume: a noisier front-end's ratio is recovered, rotation and translation
    apart; a better one is not trusted more than the parameters say (factors 1).

    The prior is rebuilt with the factors after each solve, as the back-end does.
    """
    sigma_rot, sigma_t, noise_px = 2e-3, 5e-3, 0.5
    noise = FrontendNoise()
    options = SolveOptions(max_iterations=20, prior_leverage=True)
    for seed in range(12):
        scene = street_scene(seed=seed, n_cams=10, n_points=150, noise_px=noise_px,
                             pos_noise_m=0.02, rot_noise_deg=0.1)
        gt, start = scene.gt, scene.start
        fixed = np.arange(start.n_cams) < 2
        start = start.with_poses(np.where(fixed[:, None, None], gt.R_wc, start.R_wc),
                                 np.where(fixed[:, None], gt.centers_w, start.centers_w))
        start = replace(start, fixed=fixed)
        rng = np.random.default_rng(100 + seed)
        a, b = np.arange(start.n_cams - 1), np.arange(1, start.n_cams)
        R_ab = np.einsum('mji,mjk->mik', gt.R_wc[a], gt.R_wc[b]) @ so3.exp(
            rng.normal(0, true_over_parameters * sigma_rot, (a.size, 3)))
        t_ab = (np.einsum('mji,mj->mi', gt.R_wc[a], gt.centers_w[b] - gt.centers_w[a])
                + rng.normal(0, true_over_parameters * sigma_t, (a.size, 3)))
        for _ in range(3):
            used = noise.factors
            # One sigma counts as one sigma of the pixel noise; the translation sigma is
            # isotropic, so the step-length and direction factors apply alike.
            W = np.tile(np.eye(3) * noise_px / sigma_t, (a.size, 1, 1))
            along = t_ab / np.linalg.norm(t_ab, axis=1, keepdims=True)
            P = np.einsum('mi,mj->mij', along, along)
            W = (P / used[1] + (np.eye(3) - P) / used[2]) @ W
            prior = RelativePosePrior(a, b, R_ab, t_ab,
                                      np.full(a.size, noise_px / sigma_rot / used[0]), W,
                                      huber=PRIOR_HUBER_SIGMAS * noise_px)
            feats, _ = xyz_to_parallax(start, start.R_wc, start.centers_w,
                                       np.asarray(start.points_w))
            res = solve(start, options, feats, pose_prior=prior)
            noise.note(prior, res.prior_residuals, res.prior_leverage)
    np.testing.assert_allclose(noise.factors, max(true_over_parameters, 1.0), rtol=0.2)
    if true_over_parameters < 1:
        assert noise.factors == (1.0, 1.0, 1.0)
    # The measured scatter itself, below 1 as well (there the solves' own error adds to it).
    assert noise.white is not None
    if true_over_parameters >= 1:
        np.testing.assert_allclose(noise.white, noise.factors)
    else:
        assert max(noise.white) < 0.7, noise.white


@pytest.mark.parametrize(('scenario', 'n'), [('street', 60), ('loop', 60)])
def test_a_noisier_front_end_is_measured_and_trusted_less(
        scenario: str, n: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """A front-end 5x noisier than the default simulation (``drift=0.1``).

    The solves find it noisier than the parameters (factors > 1, in the diagnostics), and
    the local motion gets better than with the parameters' sigmas kept.
    """
    seq = simulate_sequence(scenario, n_keyframes=n, seed=0, drift=0.1)
    gt = seq.gt_trajectory()

    def optimized_rpe() -> tuple[float, list[tuple[str, Any]], BackendLogic]:
        logic = BackendLogic(config(), BACKEND)
        outputs = run(logic, seq)
        return rpe(logic.optimized_trajectory(), gt, align='sim3').rmse, outputs, logic

    adaptive, outputs, logic = optimized_rpe()
    factors = [float(k) for k in
               diag_values(last(outputs, DIAGNOSTICS_TOPIC))['frontend_noise_factors'].split()]
    assert factors == pytest.approx(list(logic.estimator.frontend_noise.factors), rel=1e-2)
    assert min(factors) > 1.5, factors
    monkeypatch.setattr(FrontendNoise, 'LIMITS', (1.0, 1.0))
    kept, _, _ = optimized_rpe()
    assert adaptive < 0.8 * kept, (adaptive, kept)
    assert adaptive < rpe(seq.odom_trajectory(), gt, align='sim3').rmse


def test_the_scene_scale_does_not_change_the_result() -> None:
    """The same images with every length 10x smaller (a handheld camera's centimetre steps).

    Pixels do not change, so neither may the optimized trajectory, up to that scale; with a
    fixed floor (a millimetre) in the prior's sigmas, the small scene leaned far less on
    the front-end (aerial-60: ATE 0.58 -> 1.05x the front-end's, RPE 0.99 -> 2.27x).
    """
    seq = simulate_sequence('aerial', n_keyframes=60, seed=0)
    small = replace(seq, centers_gt=0.1 * seq.centers_gt, centers_odom=0.1 * seq.centers_odom,
                    points_w=0.1 * seq.points_w)
    ratios = []
    for s in (seq, small):
        logic = BackendLogic(config(), BACKEND)
        run(logic, s)
        gt, fe, opt = s.gt_trajectory(), s.odom_trajectory(), logic.optimized_trajectory()
        ratios.append((ate(opt, gt, 'sim3').rmse / ate(fe, gt, 'sim3').rmse,
                       rpe(opt, gt, align='sim3').rmse / rpe(fe, gt, align='sim3').rmse))
    np.testing.assert_allclose(ratios[1], ratios[0], rtol=0.02)


def test_typical_step_is_the_runs_mean_step_or_the_problems_median() -> None:
    """The run's mean map step once it has one; before, the problem's median moving step."""
    kf = _store(np.array([1.0, 1.0, 1.0, 5.0]))
    centers = kf.C_map[:kf.n]
    run_scale = RunScale()
    assert typical_step(run_scale, centers) == 1.0
    assert typical_step(run_scale, np.zeros((4, 3))) == 0.0
    run_scale.scale(kf, fallback=1.0)
    assert typical_step(run_scale, np.zeros((4, 3))) == pytest.approx(2.0)


def test_a_standstill_step_weighs_by_the_typical_step() -> None:
    """A step of zero length: sigma = STEP_FLOOR_REL of the typical step.

    The run's when given, else the window's median moving step.
    """
    kf = KeyframeStore()
    xs = [0.0, 0.0, 0.05, 0.10, 0.15, 0.20]   # a standstill, then 5 cm steps
    for i, x in enumerate(xs):
        kf.add(i, (np.eye(3), np.array([x, 0.0, 0.0])), None, KeyframeStatus.ACTIVE)
    kf.R_map[:kf.n] = np.eye(3)
    kf.C_map[:kf.n, 0] = xs
    cams, fixed = np.arange(kf.n), np.zeros(kf.n, dtype=bool)
    prior = frontend_motion_prior(kf, cams, fixed, 1.0, BackendConfig(), follow_map_scale=False)
    assert prior is not None and np.all(np.isfinite(prior.W_trans))
    np.testing.assert_allclose(prior.W_trans[0], np.eye(3) / (STEP_FLOOR_REL * 0.05))
    run_prior = frontend_motion_prior(kf, cams, fixed, 1.0, BackendConfig(),
                                      follow_map_scale=False, typical=2.0)
    assert run_prior is not None
    np.testing.assert_allclose(run_prior.W_trans[0], np.eye(3) / (STEP_FLOOR_REL * 2.0))
    # The same in metres x 100: the same weights / 100, the same factors in sigmas.
    big = KeyframeStore()
    for i, x in enumerate(xs):
        big.add(i, (np.eye(3), np.array([100.0 * x, 0.0, 0.0])), None, KeyframeStatus.ACTIVE)
    big_prior = frontend_motion_prior(big, cams, fixed, 1.0, BackendConfig(),
                                      follow_map_scale=False)
    assert big_prior is not None
    np.testing.assert_allclose(big_prior.W_trans, prior.W_trans / 100.0)


@pytest.mark.parametrize(('scenario', 'seed', 'turn_deg'),
                         [('street', 3, 0.0), ('loop', 0, 0.0), ('street', 2, 60.0)])
def test_a_stop_neither_breaks_the_map_nor_is_taken_for_frame_jumps(scenario: str, seed: int,
                                                                    turn_deg: float) -> None:
    """Slowing down, 30 keyframes at rest, speeding up: still better than the front-end.

    At rest the window's keyframes sit within the solve's noise of each other. Anchored on
    such a pair, a feature's parallax fitted that noise (ATE 1.04x / 3.3x the front-end's
    here); and with the prior's floor taken from the window's shrinking steps, the solve's
    millimetres counted as jumps of the front-end's frame (with both: 0.84x / 2.1x, five
    odom-frame jumps on the loop). Turning on the spot at rest (60 degrees and back), the
    features seen from there only made the solves' cost explode (3 rollbacks and a
    re-initialization, ATE 1.12x).
    """
    seq = simulate_sequence(scenario, n_keyframes=160, seed=seed, stop=(60, 30),
                            turn_deg=turn_deg)
    logic = BackendLogic(config(), BACKEND)
    run(logic, seq)
    counters = logic.stats.counters
    for name in ('odom_frame_jumps', 'solve_rollbacks', 'cost_explosions'):
        assert not counters.get(name), counters
    gt, fe, opt = seq.gt_trajectory(), seq.odom_trajectory(), logic.optimized_trajectory()
    assert len(opt) == 160
    assert ate(opt, gt, 'sim3').rmse < 0.8 * ate(fe, gt, 'sim3').rmse
    assert rpe(opt, gt, align='sim3').rmse < 0.9 * rpe(fe, gt, align='sim3').rmse
    # Near rest the window's centres do not measure map <- odom's scale: it holds (it
    # jumped by 2-3 % per keyframe when fitted to them).
    scales = np.log(np.array(logic.stats.map_scale))
    assert np.max(np.abs(np.diff(scales))) < 0.015


def test_an_initialization_is_put_in_the_odom_frame_if_its_steps_agree() -> None:
    """Poses of a scaled, turned, shifted frame come out as the front-end's.

    Scrambled ones are an InitError naming the disagreement.
    """
    from pmba_ros.errors import InitError

    kf = _store(np.full(7, 1.0))
    kf.C_odom[:kf.n, 1] = 0.3 * np.sin(np.arange(kf.n))   # not collinear
    used = np.arange(kf.n)
    R_s = so3.exp(np.array([0.1, -0.2, 0.3]))
    R_init = np.einsum('ij,njk->nik', R_s, kf.R_odom[used])
    C_init = 2.5 * kf.C_odom[used] @ R_s.T + np.array([1.0, 2.0, 3.0])
    R, C, sim, worst = in_odom_frame(kf, used, R_init, C_init, 0.5)
    np.testing.assert_allclose(C, kf.C_odom[used], atol=1e-9)
    np.testing.assert_allclose(R, kf.R_odom[used], atol=1e-9)
    assert sim.scale == pytest.approx(1 / 2.5) and worst < 1e-9
    one_off = C_init.copy()
    one_off[4] += 2.5 * np.array([0.0, 3.0, 0.0])   # one pose 3 steps aside: two steps off
    _, _, _, worst = in_odom_frame(kf, used, R_init, one_off, 0.5)
    assert worst > 2.0
    scrambled = C_init[[0, 3, 1, 5, 2, 6, 4, 7]]
    with pytest.raises(InitError, match="disagree with the front-end's by"):
        in_odom_frame(kf, used, R_init, scrambled, 0.5)


def test_similarity_keeps_its_scale_where_the_centres_barely_spread() -> None:
    """Centres within ``min_spread`` (RMS, frame b) keep ``prior_scale``; others fit it."""
    rng = np.random.default_rng(3)
    R = so3.exp(rng.normal(0.0, 0.1, (6, 3)))
    C_b = rng.normal(size=(6, 3))
    C_a = 2.0 * C_b + 1.0
    spread = float(np.sqrt(np.mean(np.sum((C_b - C_b.mean(axis=0)) ** 2, axis=1))))
    assert estimate_similarity(R, C_a, R, C_b, 0.5).scale == pytest.approx(2.0)
    assert estimate_similarity(R, C_a, R, C_b, 0.5, min_spread=0.99 * spread).scale == \
        pytest.approx(2.0)
    assert estimate_similarity(R, C_a, R, C_b, 0.5, min_spread=1.01 * spread).scale == 0.5


def _unit_prior(M: int) -> RelativePosePrior:
    """Return M unit-weight factors of 1 m steps along x, without rotation."""
    return RelativePosePrior(np.arange(M), np.arange(1, M + 1), np.tile(np.eye(3), (M, 1, 1)),
                             np.tile([1.0, 0.0, 0.0], (M, 1)), np.ones(M),
                             np.tile(np.eye(3), (M, 1, 1)), huber=PRIOR_HUBER_SIGMAS)


def test_frontend_noise_is_not_raised_by_steps_a_solve_got_wrong() -> None:
    """A few steps 25 sigmas off (wrong tracks in their windows) among Gaussian ones.

    Summed in, 5 % of them took the factors to 2.5 for a front-end as the parameters say;
    beyond TRIM times the median ratio they are left out, and a front-end 2x noisier is still
    found.
    """
    M = 40
    rng = np.random.default_rng(3)
    prior = _unit_prior(M)
    for true_sigma in (1.0, 2.0):
        noise = FrontendNoise()
        for _ in range(10):
            e = rng.normal(0.0, true_sigma, (M, 6))
            e[:2] = 25.0 / np.sqrt(6.0)   # two steps in 40: 25 sigmas in norm, short of a jump
            # The back-end weighs the next prior with the factors: rotation, along the step
            # (x here), across it.
            k_rot, k_along, k_across = noise.factors
            noise.note(prior, e / np.array([k_rot] * 3 + [k_along] + [k_across] * 2),
                       np.zeros((M, 6, 6)))
        np.testing.assert_allclose(noise.factors, true_sigma, rtol=0.15)


def test_frontend_noise_skips_what_it_cannot_weigh() -> None:
    """No leverage (a singular window) or a step JUMP_SIGMAS off (a jump): not counted.

    Steps beyond the Huber threshold but short of a jump count: a front-end 3x noisier than
    the sigmas is found from one window, though most of its steps lie beyond 5 sigmas.
    """
    M = 30
    rng = np.random.default_rng(0)
    prior = _unit_prior(M)
    noise = FrontendNoise()
    wild = rng.normal(0.0, 3.0, (M, 6))   # 3 sigmas per residual: most beyond 5 in norm
    noise.note(prior, wild, np.full((M, 6, 6), np.nan))
    assert noise.factors == (1.0, 1.0, 1.0)
    jumps = np.zeros((M, 6))
    jumps[:, 3] = JUMP_SIGMAS + 1.0   # every step just over a jump (weights of 1: sigmas)
    noise.note(prior, jumps, np.zeros((M, 6, 6)))
    assert noise.factors == (1.0, 1.0, 1.0)
    noise.note(prior, wild, np.zeros((M, 6, 6)))   # now counted: no leverage, all redundancy
    assert np.mean(np.linalg.norm(wild, axis=1) > PRIOR_HUBER_SIGMAS) > 0.5
    np.testing.assert_allclose(noise.factors, 3.0, rtol=0.2)


def test_white_noise_counts_the_steps_of_a_moving_platform() -> None:
    """Steps shorter than MOVING typical steps (a stop: their sigma is the floor) do not count.

    Counted, their near-zero residuals pulled the white estimate to a fraction of the
    moving steps' scatter.
    """
    M = 40
    rng = np.random.default_rng(7)
    prior = _unit_prior(M)
    short = np.arange(M) % 2 == 0
    prior = replace(prior, t_ab=np.where(short[:, None], 0.1 * prior.t_ab, prior.t_ab))
    e = rng.normal(0.0, 0.5, (M, 6)) * np.where(short, 0.05, 1.0)[:, None]
    white = []
    for typical in (1.0, 0.0):   # 0: every step counts
        noise = FrontendNoise()
        for _ in range(4):
            noise.note(prior, e, np.zeros((M, 6, 6)), typical)
        assert noise.white is not None and noise.factors == (1.0, 1.0, 1.0)
        white.append(noise.white)
    np.testing.assert_allclose(white[0], 0.5, rtol=0.25)
    assert max(white[1]) < 0.35, white[1]


def _weighted_steps(lengths: list[float]) -> tuple[np.ndarray, ...]:
    """Return a, t_ab, P_along, w_rot, W_trans of steps along x (weights: 1 / (1 % of it))."""
    t = np.outer(lengths, [1.0, 0.0, 0.0])
    P = np.tile(np.diag([1.0, 0.0, 0.0]), (len(lengths), 1, 1))
    W = np.stack([np.eye(3) / (0.01 * n) for n in lengths])
    return np.arange(len(lengths)), t, P, np.full(len(lengths), 2000.0), W


def test_step_changes_add_what_the_step_factors_leave_of_the_white_noise() -> None:
    """Equal steps, a front-end half as noisy as the weights: 3 / 4 of a step's information.

    The white noise leaves (4 - 1) times the step factor's information per step, 2 (S + S)
    per change makes that 3 / 4; a front-end as noisy as its weights gets none.
    """
    a, t, P, w_rot, W = _weighted_steps([1.0, 1.0, 1.0, 1.0])
    changes = step_changes(a, t, P, w_rot, W, (1.0, 1.0, 1.0), (0.5, 0.5, 0.5), 0.0)
    # Not the newest step (3) yet: the solve that finds a jump there is not pulled by these.
    assert changes is not None and changes.first.tolist() == [0, 1]
    np.testing.assert_allclose(changes.w_rot, np.sqrt(0.75) * w_rot[:2])
    info = np.swapaxes(changes.W_trans, 1, 2) @ changes.W_trans
    np.testing.assert_allclose(info, 0.75 * np.swapaxes(W[:2], 1, 2) @ W[:2], rtol=1e-6)
    assert step_changes(a, t, P, w_rot, W, (1.0, 1.0, 1.0), (1.0, 1.2, 1.0), 0.0) is None


def test_step_changes_near_a_stop_and_while_speeding_up() -> None:
    """Next to a standstill step the moving step sets the change's covariance.

    A change of step (speeding up) adds the scale's uncertainty along it.
    """
    a, t, P, w_rot, W = _weighted_steps([1.0, 0.001, 2.0, 2.0])
    changes = step_changes(a, t, P, w_rot, W, (1.0, 1.0, 1.0), (0.5, 0.5, 0.5), 0.0)
    assert changes is not None
    sigma = 1.0 / np.linalg.norm(changes.W_trans, axis=2)   # per axis (diagonal here)
    # 2 (S_ab + S_bc), S = (1 %)^2 l^2 / 3: the longer step's sets it to within 1e-6.
    np.testing.assert_allclose(sigma[0], 0.01 * np.sqrt(2.0 / 3.0), rtol=1e-5)
    np.testing.assert_allclose(sigma[1], 0.02 * np.sqrt(2.0 / 3.0), rtol=1e-5)
    scaled = step_changes(a, t, P, w_rot, W, (1.0, 1.0, 1.0), (0.5, 0.5, 0.5), 0.045)
    assert scaled is not None
    along = 1.0 / np.linalg.norm(scaled.W_trans, axis=2)[:, 0]
    # The change of step (0.999 m, 1.999 m) times 4.5 % adds in quadrature along x only.
    np.testing.assert_allclose(along, np.hypot(sigma[:, 0], 0.045 * np.array([0.999, 1.999])),
                               rtol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(scaled.W_trans, axis=2)[:, 1:],
                               np.linalg.norm(changes.W_trans, axis=2)[:, 1:])


def test_a_front_end_better_than_the_parameters_is_followed() -> None:
    """A front-end 4x less noisy than the default simulation (``drift=0.005``), 200 keyframes.

    Its steps' scatter is measured below the parameters and the step-change factors weigh it
    in: the local motion beats the front-end's (before them, 1.6x it) without its drift.
    """
    seq = simulate_sequence('street', n_keyframes=200, seed=0, drift=0.005)
    gt = seq.gt_trajectory()
    logic = BackendLogic(config(), BACKEND)
    run(logic, seq)
    noise = logic.estimator.frontend_noise
    assert noise.white is not None and max(noise.white) < 0.5
    opt, fe = logic.optimized_trajectory(), seq.odom_trajectory()
    assert rpe(opt, gt, align='sim3').rmse < rpe(fe, gt, align='sim3').rmse
    assert ate(opt, gt, 'sim3').rmse < 0.5 * ate(fe, gt, 'sim3').rmse
