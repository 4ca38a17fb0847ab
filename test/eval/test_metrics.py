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
"""Tests of pmba_ros.eval.metrics: association, ATE and RPE, with evo as the oracle."""

from __future__ import annotations

import copy
from functools import cache
import json
from typing import Any

import numpy as np
from pmba_ros.core import so3
from pmba_ros.errors import EvaluationError
from pmba_ros.eval.align import apply_alignment, UmeyamaResult
from pmba_ros.eval.metrics import (
    associate,
    association_warning,
    ate,
    EvalResult,
    evaluate,
    match_stamps,
    rpe,
)
from pmba_ros.eval.trajectory import read_trajectory, Trajectory
import pytest

from ..conftest import SHARED_DATA as DATA

EVO_DIR = DATA / 'trajectories' / 'evo'
needs_data = pytest.mark.skipif(not EVO_DIR.is_dir(), reason=f'{EVO_DIR} is not available')

REL_TOL = 1e-6
"""Parity tolerance with evo (relative)."""


@pytest.fixture
def rng() -> np.random.Generator:
    """Seeded random generator."""
    return np.random.default_rng(2012)


def random_trajectory(rng: np.random.Generator, n: int, t0: float = 100.0,
                      dt: float = 0.1) -> Trajectory:
    """Return a smooth-ish random walk sampled every ``dt`` seconds."""
    positions = np.cumsum(rng.normal(scale=0.1, size=(n, 3)), axis=0)
    rotations = so3.exp(np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0))
    return Trajectory(t0 + dt * np.arange(n), positions, rotations)


def perturbed(traj: Trajectory, rng: np.random.Generator, sigma: float) -> Trajectory:
    """Return ``traj`` with Gaussian noise on positions and rotations."""
    return Trajectory(traj.stamps_s,
                      traj.positions_xyz + rng.normal(scale=sigma, size=traj.positions_xyz.shape),
                      traj.R_wc @ so3.exp(rng.normal(scale=sigma, size=(len(traj), 3))))


# --------------------------------------------------------------------------------------------
# Association
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize('sort_long', [True, False])
@pytest.mark.parametrize('offset', [0.0, 0.013])
def test_match_stamps_equals_evo_matching_time_indices(rng: np.random.Generator,
                                                       sort_long: bool, offset: float) -> None:
    """The vectorized matcher returns evo's indices (sorted and unsorted stamps)."""
    sync = pytest.importorskip('evo.core.sync')
    short = np.sort(rng.uniform(0.0, 10.0, 300))
    long_ = rng.uniform(-1.0, 11.0, 2000)
    if sort_long:
        long_ = np.sort(long_)
    ours = match_stamps(short, long_, 0.004, offset)
    theirs = sync.matching_time_indices(short, long_, 0.004, offset)
    np.testing.assert_array_equal(ours[0], theirs[0])
    np.testing.assert_array_equal(ours[1], theirs[1])
    assert ours[0].size > 50


def test_match_stamps_handles_empty_input() -> None:
    """Empty stamp arrays match nothing."""
    idx_a, idx_b = match_stamps(np.zeros(0), np.arange(3.0))
    assert idx_a.size == idx_b.size == 0


def test_associate_pairs_nearest_stamps_within_tolerance(rng: np.random.Generator) -> None:
    """Poses whose stamps differ by more than max_diff are dropped; order is kept."""
    ref = random_trajectory(rng, 50, dt=0.1)
    jitter = np.where(np.arange(20) % 4 == 0, 0.05, 0.003)
    est = Trajectory(ref.stamps_s[10:30] + jitter, ref.positions_xyz[10:30], ref.R_wc[10:30])
    est_a, ref_a = associate(est, ref, max_diff_s=0.01)
    assert len(est_a) == len(ref_a) == 15
    np.testing.assert_allclose(est_a.stamps_s - ref_a.stamps_s, 0.003, atol=1e-9)
    np.testing.assert_array_equal(est_a.positions_xyz, ref_a.positions_xyz)


@pytest.mark.parametrize('shuffled', ['est', 'ref', 'both'])
def test_associate_pairs_poses_in_time_order(rng: np.random.Generator, shuffled: str) -> None:
    """Files out of time order give the metrics of the sorted ones (RPE pairs neighbours)."""
    ref = random_trajectory(rng, 60)
    est = perturbed(ref.take(np.arange(5, 45)), rng, 0.01)
    order = np.random.default_rng(7).permutation
    est_s = est.take(order(len(est))) if shuffled in ('est', 'both') else est
    ref_s = ref.take(order(len(ref))) if shuffled in ('ref', 'both') else ref
    want, got = evaluate(est, ref), evaluate(est_s, ref_s)
    for metric in ('ate', 'rpe'):
        assert got[metric].rmse == pytest.approx(want[metric].rmse, rel=1e-9)
    est_a, ref_a = associate(est_s, ref_s)
    assert np.all(np.diff(est_a.stamps_s) > 0)
    np.testing.assert_array_equal(est_a.stamps_s, ref_a.stamps_s)


def test_no_matching_stamps_names_absurd_spans_in_a_short_message(
        rng: np.random.Generator) -> None:
    """Stamps of 1e300 s print in exponent form (fixed-point gave hundreds of digits)."""
    ref = random_trajectory(rng, 10)
    est = Trajectory(ref.stamps_s + 1e300, ref.positions_xyz, ref.R_wc)
    with pytest.raises(EvaluationError, match=r'stamps 1e\+300\.\.1e\+300 s') as err:
        associate(est, ref)
    assert len(str(err.value)) < 300
    with pytest.raises(EvaluationError, match=r'stamps \d+\.\d{6}\.\.'):
        associate(Trajectory(ref.stamps_s - 100.0, ref.positions_xyz, ref.R_wc), ref)


def test_associate_applies_offset_to_estimate(rng: np.random.Generator) -> None:
    """A constant clock offset is compensated; returned stamps stay unshifted."""
    ref = random_trajectory(rng, 40)
    est = Trajectory(ref.stamps_s - 5.0, ref.positions_xyz, ref.R_wc)
    with pytest.raises(EvaluationError, match='no matching timestamps'):
        associate(est, ref)
    est_a, ref_a = associate(est, ref, offset_s=5.0)
    assert len(est_a) == 40
    np.testing.assert_array_equal(est_a.stamps_s, est.stamps_s)
    np.testing.assert_array_equal(ref_a.stamps_s, ref.stamps_s)
    # the same with the estimate as the longer trajectory
    est_a, ref_a = associate(est, ref.take(np.arange(0, 40, 2)), offset_s=5.0)
    assert len(est_a) == len(ref_a) == 20


def test_associate_raises_on_negative_tolerance(rng: np.random.Generator) -> None:
    """max_diff_s must be non-negative."""
    traj = random_trajectory(rng, 5)
    with pytest.raises(EvaluationError, match='max_diff_s must be >= 0'):
        associate(traj, traj, max_diff_s=-1.0)


def test_metrics_raise_on_fewer_than_three_matches(rng: np.random.Generator) -> None:
    """Two associated poses are not enough for an evaluation."""
    ref = random_trajectory(rng, 10)
    est = ref.take([0, 5])
    with pytest.raises(EvaluationError, match='only 2 associated poses; at least 3'):
        ate(est, ref)
    with pytest.raises(EvaluationError, match='only 2 associated poses'):
        rpe(est, ref)


def _numbered(traj: Trajectory) -> Trajectory:
    """Return ``traj`` as a KITTI file without times reads it: stamps 0, 1, 2, ..."""
    return Trajectory(np.arange(len(traj), dtype=np.float64), traj.positions_xyz, traj.R_wc,
                      index_stamps=True)


def test_kitti_pose_numbers_against_seconds_are_refused(rng: np.random.Generator) -> None:
    """A KITTI ground truth without times against a 10 Hz estimate from 0 s is an error.

    Before, stamps 0.0, 1.0, 2.0, 3.0 of 40 met pose numbers 0-3 and an ATE was printed.
    """
    est = random_trajectory(rng, 40, t0=0.0, dt=0.1)
    gt = _numbered(est)
    with pytest.raises(EvaluationError, match=r'ground truth is a KITTI file without stamps'
                       r'.*--gt-times FILE'):
        evaluate(est, gt)
    with pytest.raises(EvaluationError, match=r'the estimate is a KITTI file.*--times FILE'):
        ate(gt, est)


def test_kitti_pose_numbers_match_pose_numbers(rng: np.random.Generator) -> None:
    """Both numbered, or an estimate stamped with whole numbers: pose i against pose i."""
    traj = random_trajectory(rng, 12, t0=0.0, dt=1.0)
    gt = _numbered(traj)
    assert evaluate(_numbered(traj), gt)['ate'].n_matched == 12
    assert evaluate(traj, gt)['ate'].n_matched == 12  # a TUM file of pose numbers
    assert gt.take([1, 2]).index_stamps


def test_association_warning_below_half_of_the_poses(rng: np.random.Generator) -> None:
    """Few of the overlapping poses matched: a warning; all matched, or a short GT: none."""
    gt = random_trajectory(rng, 41, t0=0.0, dt=0.1)
    assert association_warning(gt, gt) == ''
    assert association_warning(gt.take(np.arange(10, 20)), gt) == ''  # GT covers more
    assert association_warning(gt, gt.take(np.arange(10, 20))) == ''  # GT covers part
    first = gt.take(np.arange(40))
    shifted = Trajectory(first.stamps_s + np.where(np.arange(40) % 4 == 0, 0.0, 0.05),
                         first.positions_xyz, first.R_wc)
    text = association_warning(shifted, gt)
    assert text.startswith('only 10 of the 40 estimated poses inside') and '(25 %' in text
    assert association_warning(shifted, gt, offset_s=-0.05) == ''  # 30 of 39 inside
    assert association_warning(shifted, gt, max_diff_s=0.05) == ''
    assert association_warning(gt, shifted).startswith('only 10 of the 40 reference poses')


# --------------------------------------------------------------------------------------------
# ATE / RPE properties
# --------------------------------------------------------------------------------------------

def test_ate_and_rpe_are_zero_for_identical_trajectories(rng: np.random.Generator) -> None:
    """Comparing a trajectory with itself gives zero error in every mode."""
    traj = random_trajectory(rng, 30)
    for align in ('none', 'se3', 'sim3'):
        assert ate(traj, traj, align=align).rmse == pytest.approx(0.0, abs=1e-9)
        assert rpe(traj, traj, align=align).max == pytest.approx(0.0, abs=1e-9)


def test_sim3_alignment_removes_a_similarity_but_se3_does_not(
        rng: np.random.Generator) -> None:
    """A scaled, rotated copy has zero Sim(3) ATE, non-zero SE(3) ATE."""
    ref = random_trajectory(rng, 60)
    est = apply_alignment(ref, UmeyamaResult(so3.exp(np.array([0.3, -0.2, 1.0])),
                                             np.array([5.0, -2.0, 1.0]), 2.5))
    sim3 = ate(est, ref, align='sim3')
    assert sim3.rmse == pytest.approx(0.0, abs=1e-9)
    assert sim3.scale == pytest.approx(1.0 / 2.5, rel=1e-12)
    assert ate(est, ref, align='se3').rmse > 0.1
    assert rpe(est, ref, align='sim3').rmse == pytest.approx(0.0, abs=1e-9)


def test_rpe_is_invariant_to_rigid_alignment(rng: np.random.Generator) -> None:
    """RPE with se3 alignment equals RPE without alignment."""
    ref = random_trajectory(rng, 80)
    est = perturbed(ref, rng, 0.01)
    for delta in (1, 7):
        a = rpe(est, ref, delta=delta, align='se3')
        b = rpe(est, ref, delta=delta, align='none')
        assert a.rmse == pytest.approx(b.rmse, rel=1e-10)
        assert a.n_pairs == b.n_pairs == 80 - delta


def test_rpe_consecutive_pairs_use_every_delta_th_pose(rng: np.random.Generator) -> None:
    """all_pairs=False uses pairs (0, d), (d, 2d), ... like evo's default."""
    ref = random_trajectory(rng, 31)
    est = perturbed(ref, rng, 0.01)
    assert rpe(est, ref, delta=5, all_pairs=False).n_pairs == 6
    assert rpe(est, ref, delta=1, all_pairs=False).rmse == pytest.approx(
        rpe(est, ref, delta=1).rmse, rel=1e-12)


def test_ate_statistics_follow_definitions(rng: np.random.Generator) -> None:
    """rmse, mean, median, std, min, max and sse agree with the per-pose errors."""
    ref = random_trajectory(rng, 25)
    res = ate(perturbed(ref, rng, 0.02), ref, align='none')
    e = res.errors
    assert res.rmse == pytest.approx(np.sqrt(np.mean(e ** 2)))
    assert (res.mean, res.median, res.std) == pytest.approx((e.mean(), np.median(e), e.std()))
    assert (res.min, res.max, res.sse) == pytest.approx((e.min(), e.max(), np.sum(e ** 2)))
    assert res.n_pairs == res.n_matched == 25
    assert not res.errors.flags.writeable


@pytest.mark.parametrize(('kwargs', 'match'), [
    ({'align': 'affine'}, "unknown alignment 'affine'"),
    ({'delta': 0}, 'positive whole number of frames, got 0'),
    ({'delta': 1.5}, 'positive whole number of frames'),
    ({'delta_unit': 'm'}, "unsupported RPE delta unit 'm'"),
    ({'delta': 40}, 'no pose pairs 40 frames apart among 20'),
])
def test_rpe_raises_on_invalid_options(rng: np.random.Generator, kwargs: dict[str, Any],
                                       match: str) -> None:
    """Invalid options raise EvaluationError with the reason."""
    traj = random_trajectory(rng, 20)
    with pytest.raises(EvaluationError, match=match):
        rpe(traj, traj, **kwargs)


def test_degenerate_positions_fall_back_with_a_note() -> None:
    """Collinear or coincident positions: aligned by the first pose, with a note, no error."""
    n = 10
    line = Trajectory(np.arange(n, dtype=float), np.outer(np.arange(n, dtype=float), [1, 0, 0]),
                      np.broadcast_to(np.eye(3), (n, 3, 3)))
    result = ate(line, line, align='se3')
    assert result.align == 'first_pose' and result.rmse == pytest.approx(0.0, abs=1e-12)
    assert 'cannot align with se3' in result.note and 'covariance rank' in result.note
    assert result.to_dict()['note'] == result.note
    # Pure rotation about a point, with a moved and rotated copy as the estimate.
    R = np.stack([_rot_z(0.1 * k) for k in range(n)])
    ref = Trajectory(np.arange(n, dtype=float), np.zeros((n, 3)), R)
    T = _rot_z(0.7)
    est = Trajectory(ref.stamps_s, ref.positions_xyz + np.array([1.0, 2.0, 3.0]),
                     np.einsum('ij,njk->nik', T, R))
    results = evaluate(est, ref, align='sim3')
    for res in results.values():
        assert res.align == 'first_pose' and 'cannot align with sim3' in res.note
        assert res.rmse == pytest.approx(0.0, abs=1e-9)
    assert ate(line, line, align='none').note == ''


def test_an_estimate_still_but_for_its_noise_falls_back_to_se3(
        rng: np.random.Generator) -> None:
    """Micrometre jitter about one point: SE(3) with a note (was Sim(3) scale 1e6, no note)."""
    ref = random_trajectory(rng, 40)
    est = Trajectory(ref.stamps_s, [5.0, 2.0, 1.0] + 1e-6 * rng.normal(size=(40, 3)),
                     ref.R_wc)
    for res in evaluate(est, ref, align='sim3').values():
        assert res.align == 'se3' and res.scale == 1.0
        assert res.note.startswith('cannot align with sim3 (the scale ')
        assert res.note.endswith('; aligned with se3')


def test_a_fallback_is_logged_once(caplog: pytest.LogCaptureFixture) -> None:
    """The first-pose fallback is one warning for both metrics (was one per metric)."""
    n = 10
    ref = Trajectory(np.arange(n, dtype=float), np.zeros((n, 3)),
                     np.stack([_rot_z(0.1 * k) for k in range(n)]))
    with caplog.at_level('WARNING', logger='pmba_ros.eval.metrics'):
        evaluate(ref, ref)
    assert [r.getMessage().endswith('aligned by the first pose') for r in caplog.records] == [True]


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_evaluate_returns_ate_and_rpe_with_json_ready_dicts(rng: np.random.Generator) -> None:
    """evaluate() bundles both metrics; to_dict() is JSON-serializable."""
    ref = random_trajectory(rng, 40)
    results = evaluate(perturbed(ref, rng, 0.01), ref, align='sim3', delta=2)
    assert set(results) == {'ate', 'rpe'}
    assert isinstance(results['ate'], EvalResult)
    assert results['rpe'].delta_frames == 2
    as_dict = results['ate'].to_dict()
    assert json.loads(json.dumps(as_dict)) == as_dict
    assert set(as_dict['alignment']) == {'rotation', 'translation', 'scale'}
    assert 'errors' not in as_dict
    assert len(results['rpe'].to_dict(include_errors=True)['errors']) == 38


# --------------------------------------------------------------------------------------------
# Parity with evo on real trajectory pairs
# --------------------------------------------------------------------------------------------

PAIRS = {
    'fr1_xyz_rgbdslam': ('freiburg1_xyz-rgbdslam.txt', 'freiburg1_xyz-groundtruth.txt', 'tum'),
    'fr2_desk_orb': ('fr2_desk_ORB.txt', 'fr2_desk_groundtruth.txt', 'tum'),
    'v102': ('V102.txt', 'V102_groundtruth.csv', 'euroc'),
    'kitti_00_orb': ('KITTI_00_ORB.txt', 'KITTI_00_gt.txt', 'kitti'),
}


@cache
def evo_pair(name: str) -> tuple[Any, Any]:
    """Read and associate a pair with evo (reference, estimate), cached per session."""
    sync = pytest.importorskip('evo.core.sync')
    file_interface = pytest.importorskip('evo.tools.file_interface')
    est_name, gt_name, fmt = PAIRS[name]
    if fmt == 'kitti':
        # KITTI files have no stamps: evo compares pose i with pose i.
        return (file_interface.read_kitti_poses_file(str(EVO_DIR / gt_name)),
                file_interface.read_kitti_poses_file(str(EVO_DIR / est_name)))
    est = file_interface.read_tum_trajectory_file(str(EVO_DIR / est_name))
    gt_reader = (file_interface.read_euroc_csv_trajectory if fmt == 'euroc'
                 else file_interface.read_tum_trajectory_file)
    gt = gt_reader(str(EVO_DIR / gt_name))
    return sync.associate_trajectories(gt, est, max_diff=0.01)


@cache
def our_pair(name: str) -> tuple[Trajectory, Trajectory]:
    """Read a pair with pmba_ros (estimate, ground truth), cached per session."""
    est_name, gt_name, _ = PAIRS[name]
    return read_trajectory(EVO_DIR / est_name), read_trajectory(EVO_DIR / gt_name)


def evo_stats(name: str, metric: str, align: str, delta: int = 1,
              all_pairs: bool = True) -> dict[str, Any]:
    """Run evo's APE/RPE (translation part) on a pair; return its statistics and errors."""
    metrics = pytest.importorskip('evo.core.metrics')
    ref, est = evo_pair(name)
    est = copy.deepcopy(est)
    if align != 'none':
        est.align(ref, correct_scale=align == 'sim3')
    if metric == 'ate':
        evo_metric = metrics.APE(metrics.PoseRelation.translation_part)
    else:
        evo_metric = metrics.RPE(metrics.PoseRelation.translation_part, delta=delta,
                                 delta_unit=metrics.Unit.frames, all_pairs=all_pairs)
    evo_metric.process_data((ref, est))
    stats: dict[str, Any] = evo_metric.get_all_statistics()
    stats['errors'] = np.asarray(evo_metric.error)
    return stats


def assert_parity(ours: EvalResult, theirs: dict[str, Any]) -> None:
    """Every statistic and every per-pose error agrees to REL_TOL, the counts exactly."""
    assert ours.n_pairs == theirs['errors'].size
    np.testing.assert_allclose(ours.errors, theirs['errors'], rtol=REL_TOL, atol=0.0)
    for key in ('rmse', 'mean', 'median', 'std', 'min', 'max', 'sse'):
        assert getattr(ours, key) == pytest.approx(theirs[key], rel=REL_TOL), key


@needs_data
@pytest.mark.parametrize('align', ['se3', 'sim3', 'none'])
@pytest.mark.parametrize('name', list(PAIRS))
def test_ate_matches_evo_ape(name: str, align: str) -> None:
    """ATE statistics equal evo_ape (translation part) with -a / -as / no alignment."""
    est, gt = our_pair(name)
    assert_parity(ate(est, gt, align=align), evo_stats(name, 'ate', align))


@needs_data
@pytest.mark.parametrize('align', ['se3', 'sim3'])
@pytest.mark.parametrize('name', list(PAIRS))
def test_rpe_matches_evo_rpe(name: str, align: str) -> None:
    """RPE statistics (delta 1 frame) equal evo_rpe (translation part)."""
    est, gt = our_pair(name)
    assert_parity(rpe(est, gt, delta=1, align=align), evo_stats(name, 'rpe', align))


@needs_data
@pytest.mark.parametrize('all_pairs', [True, False])
@pytest.mark.parametrize('name', ['fr2_desk_orb', 'kitti_00_orb'])
def test_rpe_with_larger_delta_matches_evo_rpe(name: str, all_pairs: bool) -> None:
    """RPE over 10 frames, all pairs and consecutive pairs, equals evo_rpe."""
    est, gt = our_pair(name)
    ours = rpe(est, gt, delta=10, align='sim3', all_pairs=all_pairs)
    assert_parity(ours, evo_stats(name, 'rpe', 'sim3', delta=10, all_pairs=all_pairs))


@needs_data
@pytest.mark.parametrize('name', list(PAIRS))
def test_evaluate_alignment_matches_evo(name: str) -> None:
    """The Sim(3) alignment reported by evaluate() equals evo's Umeyama result."""
    ref, est = evo_pair(name)
    r, t, s = copy.deepcopy(est).align(ref, correct_scale=True)
    results = evaluate(*our_pair(name), align='sim3')
    assert results['ate'].scale == pytest.approx(s, rel=REL_TOL)
    np.testing.assert_allclose(results['ate'].rotation, r, atol=1e-6)
    np.testing.assert_allclose(results['ate'].translation, t,
                               atol=1e-6 * max(1.0, float(np.abs(t).max())))
    assert_parity(results['rpe'], evo_stats(name, 'rpe', 'sim3'))
