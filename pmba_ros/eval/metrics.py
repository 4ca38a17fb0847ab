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
"""Trajectory error metrics: timestamp association, ATE and RPE (translation part).

The numbers match evo (``evo_ape`` / ``evo_rpe`` with the default ``translation_part``
pose relation); the test suite checks this on real trajectory pairs.

Notation (Sturm et al., "A Benchmark for the Evaluation of RGB-D SLAM Systems", IROS 2012;
evo's ``metrics.py`` follows the same paper):

=========  ===============  ========  ==============================================
paper      code             shape     meaning
=========  ===============  ========  ==============================================
Q_i        ref (R_wc, pos)  (N, ...)  reference poses, after association
P_i        est (R_wc, pos)  (N, ...)  estimated poses, after association and alignment
S          alignment        --        Umeyama transform applied to P (identity if none)
F_i        --               --        ATE error pose Q_i^-1 S P_i, eq. (3)
E_i        --               --        RPE error (Q_i^-1 Q_{i+d})^-1 (P_i^-1 P_{i+d}), eq. (1)
e_i        errors           (K,)      norm of the translation part of F_i or E_i
=========  ===============  ========  ==============================================

The translation part of F_i is ``R_q,i^T (p_i - q_i)``, whose norm is ``|p_i - q_i|``. The
translation part of E_i is ``R_rel^T (t_P - t_Q)`` with ``t_P = R_p,i^T (p_{i+d} - p_i)`` and
``R_rel = R_q,i^T R_q,{i+d}``; it is evaluated literally, as evo does, so that rotations that
are orthonormal only to the printed digits (KITTI, see
:func:`~pmba_ros.eval.trajectory.read_kitti`) give evo's numbers. Both metrics are computed
for all poses at once.
"""

from __future__ import annotations

from dataclasses import dataclass
import logging
from typing import Literal, NamedTuple, TYPE_CHECKING

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.errors import DegenerateGeometryError, EvaluationError
from pmba_ros.eval.align import align_se3, align_sim3, apply_alignment, UmeyamaResult
from pmba_ros.eval.trajectory import Trajectory

if TYPE_CHECKING:
    from collections.abc import Mapping

logger = logging.getLogger(__name__)

AlignMode = Literal['se3', 'sim3', 'none']
ALIGN_MODES: tuple[str, ...] = ('se3', 'sim3', 'none')
"""Accepted ``align`` values: rigid, similarity (with scale) or no alignment."""

MIN_MATCHES = 3
"""Fewest associated poses an evaluation accepts (Umeyama needs 3 non-collinear points)."""

MIN_MATCHED_FRACTION = 0.5
"""Share of the poses that should find a partner, below which :func:`association_warning` warns.

Of the sparser trajectory's poses inside the other's time span. A ground truth at the
estimate's rate or faster on the same clock matches every pose (the simulated bags, EuRoC's
200 Hz, TUM's 100 Hz), up to gaps of the motion capture. Stamps that do not belong together
(another clock, a rate that does not fit, KITTI pose numbers against seconds) match where
two happen to lie within ``max_diff_s``: about ``2 max_diff_s f`` of the poses against the
other trajectory's rate ``f``, under half for any rate below 25 Hz at the 0.01 s default (a
KITTI file's pose numbers matched 4 of 40 keyframes at 10 Hz). The result then holds a
chance selection of the poses, and says nothing of the others.
"""


def _readonly(arr: np.ndarray) -> np.ndarray:
    """Return a float64 copy of ``arr`` that cannot be written to."""
    out = np.array(arr, dtype=np.float64, copy=True)
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class EvalResult:
    """Statistics of one error metric, with the alignment that was applied.

    Attributes:
        metric: ``'ate'`` or ``'rpe'``.
        align: Alignment mode, one of :data:`ALIGN_MODES`.
        rmse: Root mean square error (m, in the reference frame and scale).
        mean: Mean error (m).
        median: Median error (m).
        std: Population standard deviation of the errors (m).
        min: Smallest error (m).
        max: Largest error (m).
        sse: Sum of squared errors (m^2).
        n_pairs: Number of errors: associated poses (ATE) or pose pairs (RPE).
        n_matched: Number of associated poses.
        rotation: Alignment rotation, shape (3, 3).
        translation: Alignment translation (m), shape (3,).
        scale: Alignment scale (1.0 unless ``align == 'sim3'``).
        errors: Per-pose (ATE) or per-pair (RPE) errors (m), shape (n_pairs,).
        delta_frames: RPE pose distance in frames; None for ATE.
        note: Why the alignment differs from the one asked for ('' if it does not).
    """

    metric: str
    align: str
    rmse: float
    mean: float
    median: float
    std: float
    min: float  # noqa: A003 (evo's statistic names)
    max: float  # noqa: A003
    sse: float
    n_pairs: int
    n_matched: int
    rotation: FloatArray
    translation: FloatArray
    scale: float
    errors: FloatArray
    delta_frames: int | None = None
    note: str = ''

    def __post_init__(self) -> None:
        """Freeze copies of the array fields."""
        for name in ('rotation', 'translation', 'errors'):
            object.__setattr__(self, name, _readonly(getattr(self, name)))

    def to_dict(self, include_errors: bool = False) -> dict[str, object]:
        """Return a JSON-serializable dictionary of the result.

        Args:
            include_errors: Also include the per-pose ``errors`` list.

        Returns:
            Plain Python scalars and nested lists, keyed by field name.
        """
        out: dict[str, object] = {
            'metric': self.metric, 'align': self.align,
            'rmse': self.rmse, 'mean': self.mean, 'median': self.median, 'std': self.std,
            'min': self.min, 'max': self.max, 'sse': self.sse,
            'n_pairs': self.n_pairs, 'n_matched': self.n_matched,
            'alignment': {'rotation': self.rotation.tolist(),
                          'translation': self.translation.tolist(),
                          'scale': self.scale},
        }
        if self.delta_frames is not None:
            out['delta_frames'] = self.delta_frames
        if self.note:
            out['note'] = self.note
        if include_errors:
            out['errors'] = self.errors.tolist()
        return out


# --------------------------------------------------------------------------------------------
# Association
# --------------------------------------------------------------------------------------------

def match_stamps(stamps_short: FloatArray, stamps_long: FloatArray, max_diff_s: float = 0.01,
                 offset_long_s: float = 0.0) -> tuple[IntArray, IntArray]:
    """Match each stamp of one sequence with the nearest stamp of another, within a tolerance.

    This is evo's ``sync.matching_time_indices``, vectorized: for every ``stamps_short[i]``
    the nearest ``stamps_long[j] + offset_long_s`` is taken if it lies within ``max_diff_s``;
    on a tie the earlier stamp wins. Each short index appears at most once.

    Args:
        stamps_short: Stamps to match (s), shape (A,).
        stamps_long: Stamps to search (s), shape (B,); sorted or not.
        max_diff_s: Largest accepted absolute difference (s).
        offset_long_s: Offset added to ``stamps_long`` before matching (s).

    Returns:
        Matched indices into ``stamps_short`` (increasing) and into ``stamps_long``, each of
        shape (K,).
    """
    short = np.asarray(stamps_short, dtype=np.float64)
    long_ = np.asarray(stamps_long, dtype=np.float64) + offset_long_s
    empty = np.zeros(0, dtype=np.int64)
    if short.size == 0 or long_.size == 0:
        return empty, empty.copy()
    order = None
    if np.any(np.diff(long_) < 0):
        order = np.argsort(long_, kind='stable')
        long_ = long_[order]
    in_range = (short >= long_[0] - max_diff_s) & (short <= long_[-1] + max_diff_s)
    upper = np.minimum(np.searchsorted(long_, short, side='right'), long_.size - 1)
    diff_ub = long_[upper] - short
    diff_lb = np.where(upper > 0, short - long_[np.maximum(upper - 1, 0)], np.inf)
    take_ub = (diff_ub <= max_diff_s) & (diff_ub < diff_lb)
    take_lb = ~take_ub & (diff_lb <= max_diff_s) & (diff_lb <= diff_ub)
    ok = in_range & (take_ub | take_lb)
    idx_short = np.flatnonzero(ok).astype(np.int64)
    idx_long = np.where(take_ub, upper, upper - 1)[ok].astype(np.int64)
    if order is not None:
        idx_long = order[idx_long].astype(np.int64)
    return idx_short, idx_long


def associate(est: Trajectory, ref: Trajectory, max_diff_s: float = 0.01,
              offset_s: float = 0.0) -> tuple[Trajectory, Trajectory]:
    """Pair the poses of two trajectories by nearest timestamp.

    Same semantics as evo's ``sync.associate_trajectories(ref, est, max_diff=...,
    offset_2=...)``: every pose of the trajectory with fewer poses (the estimate on a tie) is
    matched with the nearest pose of the other one, if their stamps differ by at most
    ``max_diff_s``. Each pose of the shorter trajectory is used at most once; a pose of the
    longer one can only be used twice when the longer trajectory is locally sparser than the
    shorter one by more than ``2 * max_diff_s``.

    Args:
        est: Estimated trajectory.
        ref: Reference trajectory.
        max_diff_s: Largest accepted stamp difference (s).
        offset_s: Offset added to the estimate's stamps for matching (s); the returned
            trajectories keep their own stamps.

    Returns:
        The matched poses of ``est`` and of ``ref``, in the same order and of equal length,
        in the order of the estimate's stamps (whatever the order of the files).

    Raises:
        EvaluationError: If ``max_diff_s`` is negative or no stamps match.
    """
    if not max_diff_s >= 0.0:
        msg = f'max_diff_s must be >= 0, got {max_diff_s}'
        raise EvaluationError(msg)
    _check_index_stamps(est, ref)
    if len(est) > len(ref):
        idx_ref, idx_est = match_stamps(ref.stamps_s, est.stamps_s, max_diff_s, offset_s)
    else:
        idx_est, idx_ref = match_stamps(est.stamps_s, ref.stamps_s, max_diff_s, -offset_s)
    if idx_est.size == 0:
        msg = (f'no matching timestamps between the estimate ({len(est)} poses, '
               f'{_span(est)}) and the reference ({len(ref)} poses, {_span(ref)}) with '
               f'max. difference {max_diff_s} s and offset {offset_s} s')
        raise EvaluationError(msg)
    logger.debug('Associated %d of max. %d poses (max_diff %g s, offset %g s)',
                 idx_est.size, min(len(est), len(ref)), max_diff_s, offset_s)
    # The pairs come in the file order of one side; RPE takes consecutive pairs as consecutive
    # poses, so a file written out of time order gave RPE between random poses (5x the
    # true value on a shuffled estimate). Sorted input keeps its order (stable sort).
    order = np.argsort(est.stamps_s[idx_est], kind='stable')
    return est.take(idx_est[order]), ref.take(idx_ref[order])


def _check_index_stamps(est: Trajectory, ref: Trajectory) -> None:
    """Refuse to match pose numbers (a KITTI file without times) with stamps in seconds.

    Pose numbers 0, 1, 2, ... meet a 10 Hz estimate's seconds at every tenth keyframe, so
    an ATE over those few came out without a warning. Both sides numbered (two KITTI files,
    or an estimate stamped with its pose numbers, whole numbers) compare pose i with pose i.

    Raises:
        EvaluationError: If exactly one side has index stamps and the other's stamps are
            not all whole numbers; the message says how to give the KITTI file its times.
    """
    for numbered, other, name, other_name, option in (
            (ref, est, 'the ground truth', 'the estimate', '--gt-times'),
            (est, ref, 'the estimate', 'the ground truth', '--times')):
        if not numbered.index_stamps or other.index_stamps:
            continue
        stamps = other.stamps_s
        if np.all(np.abs(stamps - np.round(stamps)) <= 1e-6):
            continue
        msg = (f'{name} is a KITTI file without stamps (its poses are numbered 0, 1, 2, ...) '
               f'but {other_name} has stamps in seconds ({_span(other)}): they would match '
               'only where a stamp falls on a whole number, by accident. Give the KITTI '
               f'file its times.txt ({option} FILE) or use a trajectory with stamps (TUM, '
               'EuRoC CSV)')
        raise EvaluationError(msg)


def association_warning(est: Trajectory, ref: Trajectory, max_diff_s: float = 0.01,
                        offset_s: float = 0.0) -> str:
    """Return a warning when few poses find a partner in the other trajectory ('' if not).

    Counted as :func:`associate` matches: the poses of the trajectory with fewer poses (the
    estimate on a tie) that lie inside the other's time span, of which fewer than
    :data:`MIN_MATCHED_FRACTION` found a stamp within ``max_diff_s`` (see there why).
    Poses outside the other's span (a ground truth that covers part of the run) are not
    counted against it.

    Args:
        est: Estimated trajectory.
        ref: Reference trajectory.
        max_diff_s: Largest accepted stamp difference (s).
        offset_s: Offset added to the estimate's stamps for matching (s).

    Returns:
        One line naming the counts and what to check, or ''.
    """
    if len(est) > len(ref):
        short, long_, name = ref.stamps_s, est.stamps_s + offset_s, 'reference'
    else:
        short, long_, name = est.stamps_s + offset_s, ref.stamps_s, 'estimated'
    if short.size == 0 or long_.size == 0:
        return ''
    inside = int(np.count_nonzero((short >= long_.min() - max_diff_s)
                                  & (short <= long_.max() + max_diff_s)))
    matched = match_stamps(short, long_, max_diff_s)[0].size
    if inside < MIN_MATCHES or matched >= MIN_MATCHED_FRACTION * inside:
        return ''
    return (f"only {matched} of the {inside} {name} poses inside the other trajectory's "
            f'time span have a stamp within {max_diff_s:g} s there ({100 * matched / inside:.0f} '
            f'%, fewer than {100 * MIN_MATCHED_FRACTION:.0f} %): the result covers a chance '
            'selection of the poses; check that both are stamped on the same clock (time '
            'offset), --max-diff against their rates, and the gaps of the ground truth')


def repeated_stamps_warning(traj: Trajectory, name: str) -> str:
    """Return a warning when poses of a trajectory share a stamp ('' if none do).

    Such poses are kept, each matched as a pose of its own, as evo does: real files repeat
    a few stamps (evo's own V102 estimate does) and the results equal evo's on them. But a
    file whose poses share few stamps (all one, say) matched every pose with one partner and
    reported them all matched, without a word: the count names it.

    Args:
        traj: The trajectory.
        name: What it is, for the message (e.g. 'estimated').

    Returns:
        One line counting the poses whose stamp an earlier pose has, or ''.
    """
    n = len(traj)
    distinct = int(np.unique(traj.stamps_s).size)
    if distinct == n:
        return ''
    return (f'{n - distinct} of the {n} {name} poses repeat the stamp of an earlier pose '
            f'(distinct stamps: {distinct}): each is matched as a pose of its own, as evo '
            'does, so the poses of one stamp share their partner; check how the file was '
            'written')


def _span(traj: Trajectory) -> str:
    """Describe the stamp range of a trajectory for error messages."""
    if len(traj) == 0:
        return 'no stamps'
    note = f' {traj.stamps_note}' if traj.stamps_note else ''
    return f'stamps {_stamp(traj.stamps_s.min())}..{_stamp(traj.stamps_s.max())} s{note}'


def _stamp(t: float) -> str:
    """Format a stamp to the microsecond; beyond any clock (an absurd one), in exponent form."""
    return f'{t:.6f}' if abs(t) < 1e15 else f'{t:.6g}'


# --------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------

def _check_align(align: str) -> None:
    """Raise EvaluationError if ``align`` is not one of :data:`ALIGN_MODES`."""
    if align not in ALIGN_MODES:
        msg = f'unknown alignment {align!r}; expected one of {", ".join(ALIGN_MODES)}'
        raise EvaluationError(msg)


class _Aligned(NamedTuple):
    """An associated estimate aligned onto its reference, and how."""

    est: Trajectory
    alignment: UmeyamaResult
    mode: str
    note: str


def _align_pairs(est: Trajectory, ref: Trajectory, align: str) -> _Aligned:
    """Align associated ``est`` onto ``ref`` with the given mode (no-op for ``'none'``).

    Positions that cannot fix the asked alignment (collinear: no Sim(3) or SE(3) rotation
    about their line; coincident: pure rotation; a Sim(3) scale that noise sets, see
    :func:`~pmba_ros.eval.align.align_sim3`) fall back to SE(3), and then to the rigid
    transform that maps the first estimated pose onto the first reference pose
    ('first_pose'), with a note instead of an error.

    Returns:
        The aligned estimate, the alignment, the mode used and the note ('' if none).
    """
    if len(est) < MIN_MATCHES:
        msg = (f'only {len(est)} associated poses; at least {MIN_MATCHES} are needed '
               f'(check the stamps, --max-diff and the time offset)')
        raise EvaluationError(msg)
    if align == 'none':
        return _Aligned(est, UmeyamaResult(np.eye(3), np.zeros(3), 1.0), align, '')
    notes = []
    for mode in dict.fromkeys((align, 'se3')):
        try:
            aligned, fit = (align_sim3 if mode == 'sim3' else align_se3)(est, ref)
        except DegenerateGeometryError as err:
            notes.append(f'cannot align with {mode} ({err})')
            continue
        note = '; '.join([*notes, f'aligned with {mode}']) if notes else ''
        return _Aligned(aligned, fit, mode, note)
    rotation = ref.R_wc[0] @ est.R_wc[0].T
    fit = UmeyamaResult(rotation, ref.positions_xyz[0] - rotation @ est.positions_xyz[0], 1.0)
    note = '; '.join([*notes, 'aligned by the first pose'])
    logger.warning('%s', note)
    return _Aligned(apply_alignment(est, fit), fit, 'first_pose', note)


def _result(metric: str, align: str, errors: FloatArray, n_matched: int,
            alignment: UmeyamaResult, delta_frames: int | None = None,
            note: str = '') -> EvalResult:
    """Build an EvalResult with evo's statistics of ``errors``."""
    squared = errors * errors
    return EvalResult(
        metric=metric, align=align,
        rmse=float(np.sqrt(np.mean(squared))), mean=float(np.mean(errors)),
        median=float(np.median(errors)), std=float(np.std(errors)),
        min=float(np.min(errors)), max=float(np.max(errors)), sse=float(np.sum(squared)),
        n_pairs=int(errors.size), n_matched=n_matched,
        rotation=alignment.rotation, translation=alignment.translation,
        scale=float(alignment.scale), errors=errors, delta_frames=delta_frames, note=note)


def _ate_aligned(fit: _Aligned, ref: Trajectory) -> EvalResult:
    """ATE of an associated estimate aligned onto ``ref``."""
    # |trans(Q_i^-1 S P_i)| = |R_q,i^T (p_i - q_i)| = |p_i - q_i|, eq. (3); evo's APE also
    # uses the position difference directly.
    errors = np.linalg.norm(fit.est.positions_xyz - ref.positions_xyz, axis=1)
    return _result('ate', fit.mode, errors, len(ref), fit.alignment, note=fit.note)


def _pair_indices(n: int, delta: int, all_pairs: bool) -> tuple[IntArray, IntArray]:
    """Index pairs (i, i + delta): every i, or only i = 0, delta, 2 delta, ... (evo's rule)."""
    if all_pairs:
        first = np.arange(max(n - delta, 0), dtype=np.int64)
        return first, first + delta
    ids = np.arange(0, n, delta, dtype=np.int64)
    return ids[:-1], ids[1:]


def _rpe_aligned(fit: _Aligned, ref: Trajectory, delta: int, all_pairs: bool) -> EvalResult:
    """RPE (translation part) of an associated estimate aligned onto ``ref``."""
    aligned = fit.est
    i, j = _pair_indices(len(ref), delta, all_pairs)
    if i.size == 0:
        msg = f'no pose pairs {delta} frames apart among {len(ref)} associated poses'
        raise EvaluationError(msg)
    # t_Q = trans(Q_i^-1 Q_j), t_P = trans(P_i^-1 P_j)
    t_q = np.einsum('nji,nj->ni', ref.R_wc[i], ref.positions_xyz[j] - ref.positions_xyz[i])
    t_p = np.einsum('nji,nj->ni', aligned.R_wc[i],
                    aligned.positions_xyz[j] - aligned.positions_xyz[i])
    # trans(E_i) = R_rel^T (t_P - t_Q) with R_rel = R_q,i^T R_q,j, eq. (1)
    R_rel = np.einsum('nki,nkj->nij', ref.R_wc[i], ref.R_wc[j])
    errors = np.linalg.norm(np.einsum('nji,nj->ni', R_rel, t_p - t_q), axis=1)
    return _result('rpe', fit.mode, errors, len(ref), fit.alignment, delta_frames=delta,
                   note=fit.note)


def _check_delta(delta: int, delta_unit: str) -> int:
    """Validate the RPE distance and return it as an int."""
    if delta_unit != 'frames':
        msg = f"unsupported RPE delta unit {delta_unit!r}; only 'frames' is implemented"
        raise EvaluationError(msg)
    if isinstance(delta, bool) or int(delta) != delta or delta < 1:
        msg = f'RPE delta must be a positive whole number of frames, got {delta!r}'
        raise EvaluationError(msg)
    return int(delta)


def ate(est: Trajectory, ref: Trajectory, align: AlignMode | str = 'se3',
        max_diff_s: float = 0.01, offset_s: float = 0.0) -> EvalResult:
    """Absolute trajectory error of the positions (``evo_ape tum REF EST [-a [-s]]``).

    Args:
        est: Estimated trajectory.
        ref: Reference (ground-truth) trajectory.
        align: ``'se3'`` (rigid, ``-a``), ``'sim3'`` (with scale, ``-as``) or ``'none'``.
        max_diff_s: Largest stamp difference for association (s).
        offset_s: Offset added to the estimate's stamps for association (s).

    Returns:
        Statistics of ``|p_i - q_i|`` over the associated poses after alignment.

    Raises:
        EvaluationError: If ``align`` is unknown, fewer than 3 poses associate, or the
            associated positions cannot be aligned (collinear, coincident).
    """
    _check_align(align)
    est_a, ref_a = associate(est, ref, max_diff_s, offset_s)
    return _ate_aligned(_align_pairs(est_a, ref_a, align), ref_a)


def rpe(est: Trajectory, ref: Trajectory, delta: int = 1, delta_unit: str = 'frames',
        align: AlignMode | str = 'se3', max_diff_s: float = 0.01, offset_s: float = 0.0,
        all_pairs: bool = True) -> EvalResult:
    """Relative pose error, translation part (``evo_rpe tum REF EST -d D -u f [-a [-s]]``).

    A rigid alignment does not change the RPE; a Sim(3) alignment rescales the estimate.

    Args:
        est: Estimated trajectory.
        ref: Reference (ground-truth) trajectory.
        delta: Distance between the poses of a pair, in frames of the associated sequence.
        delta_unit: Unit of ``delta``; only ``'frames'`` is supported.
        align: ``'se3'``, ``'sim3'`` or ``'none'``, applied before the relative errors.
        max_diff_s: Largest stamp difference for association (s).
        offset_s: Offset added to the estimate's stamps for association (s).
        all_pairs: Use every pair (i, i + delta) (``--all_pairs``); otherwise only
            i = 0, delta, 2 delta, ... (evo's default; identical when ``delta == 1``).

    Returns:
        Statistics of ``|trans(E_i)|`` over the pose pairs.

    Raises:
        EvaluationError: If an option is invalid, fewer than 3 poses associate, no pair is
            ``delta`` frames apart, or alignment fails.
    """
    _check_align(align)
    delta = _check_delta(delta, delta_unit)
    est_a, ref_a = associate(est, ref, max_diff_s, offset_s)
    return _rpe_aligned(_align_pairs(est_a, ref_a, align), ref_a, delta, all_pairs)


def evaluate(est: Trajectory, gt: Trajectory, align: AlignMode | str = 'sim3',
             max_diff_s: float = 0.01, delta: int = 1,
             offset_s: float = 0.0) -> Mapping[str, EvalResult]:
    """Compute ATE and RPE (translation part) of an estimate against ground truth.

    The trajectories are associated and aligned once, for both metrics.

    Args:
        est: Estimated trajectory.
        gt: Ground-truth trajectory.
        align: ``'se3'``, ``'sim3'`` or ``'none'``.
        max_diff_s: Largest stamp difference for association (s).
        delta: RPE pose distance in frames (all pairs).
        offset_s: Offset added to the estimate's stamps for association (s).

    Returns:
        ``{'ate': EvalResult, 'rpe': EvalResult}``.

    Raises:
        EvaluationError: If the trajectories cannot be associated or aligned, or an option
            is invalid.
    """
    _check_align(align)
    delta = _check_delta(delta, 'frames')
    est_a, gt_a = associate(est, gt, max_diff_s, offset_s)
    # One alignment: a fallback's warning was logged twice, once per metric.
    fit = _align_pairs(est_a, gt_a, align)
    return {'ate': _ate_aligned(fit, gt_a),
            'rpe': _rpe_aligned(fit, gt_a, delta, all_pairs=True)}
