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
"""Accuracy of a replay: the front-end and the optimized keyframes against ground truth."""

from __future__ import annotations

import logging
from typing import Any, TYPE_CHECKING

from pmba_ros.errors import EvaluationError
from pmba_ros.eval.metrics import association_warning, evaluate, repeated_stamps_warning

if TYPE_CHECKING:
    from pmba_ros.eval.trajectory import Trajectory

logger = logging.getLogger(__name__)


def accuracy(frontend: Trajectory, optimized: Trajectory, gt: Trajectory, *,
             align: str = 'sim3', max_diff_s: float = 0.01,
             warnings: list[str] | None = None) -> dict[str, Any]:
    """Return ATE / RPE of the front-end and optimized keyframes against ground truth.

    Args:
        frontend: Front-end trajectory.
        optimized: Optimized trajectory.
        gt: Ground truth.
        align: Alignment mode for both ('sim3', 'se3' or 'none').
        max_diff_s: Largest stamp difference for association, s.
        warnings: Appended to: one line per trajectory of which few keyframes found a
            ground-truth pose (:func:`~pmba_ros.eval.metrics.association_warning`), and one
            per trajectory whose poses repeat stamps
            (:func:`~pmba_ros.eval.metrics.repeated_stamps_warning`), as ``pmba evaluate``
            warns.

    Returns:
        ``ate_frontend_m``, ``ate_optimized_m``, ``ate_ratio`` (optimized / front-end),
        ``rpe_frontend``, ``rpe_optimized`` (RMSE, m, consecutive keyframes), ``rpe_ratio``,
        ``alignment`` and the full results under ``frontend`` / ``optimized``. The
        optimized entries are None if the back-end optimized no keyframe.

    Raises:
        EvaluationError: If a trajectory has no stamps overlapping the ground truth, or
            one of them is a KITTI file without times and the other is not.
    """
    _warn_repeated_stamps(frontend, optimized, gt, warnings)
    results = {}
    for name, traj in (('frontend', frontend), ('optimized', optimized)):
        if len(traj) == 0 and name == 'optimized':
            logger.warning('the back-end optimized no keyframe; no optimized accuracy')
            continue
        try:
            results[name] = evaluate(traj, gt, align=align, max_diff_s=max_diff_s)
        except EvaluationError as err:
            hint = ' (try --align none)' if 'degenerate' in str(err) and align != 'none' else ''
            msg = f'ground truth vs {name} keyframes: {err}{hint}'
            raise EvaluationError(msg) from err
        if text := association_warning(traj, gt, max_diff_s):
            text = f'ground truth vs {name} keyframes: {text}'
            logger.warning('%s', text)
            if warnings is not None:
                warnings.append(text)
    ate_f, rpe_f = results['frontend']['ate'].rmse, results['frontend']['rpe'].rmse
    opt = results.get('optimized')
    ate_o = opt['ate'].rmse if opt is not None else None
    rpe_o = opt['rpe'].rmse if opt is not None else None
    return {
        'alignment': align,
        'ate_frontend_m': ate_f,
        'ate_optimized_m': ate_o,
        'ate_ratio': ate_o / ate_f if ate_o is not None and ate_f > 0 else None,
        'rpe_frontend': rpe_f,
        'rpe_optimized': rpe_o,
        'rpe_ratio': rpe_o / rpe_f if rpe_o is not None and rpe_f > 0 else None,
        'matched_frontend': results['frontend']['ate'].n_matched,
        'matched_optimized': opt['ate'].n_matched if opt is not None else 0,
        'notes': sorted({r.note for res in results.values() for r in res.values() if r.note}),
        'frontend': {k: v.to_dict() for k, v in results['frontend'].items()},
        'optimized': {k: v.to_dict() for k, v in opt.items()} if opt is not None else None,
    }


def _warn_repeated_stamps(frontend: Trajectory, optimized: Trajectory, gt: Trajectory,
                          warnings: list[str] | None) -> None:
    """Warn of each trajectory whose poses repeat stamps, as ``pmba evaluate`` does.

    Such poses are each matched on their own, so a ground truth of one stamp matched every
    keyframe with one pose and the replay reported them all matched, without a word.
    """
    for traj, name in ((gt, 'ground-truth'), (frontend, 'front-end keyframe'),
                       (optimized, 'optimized keyframe')):
        if text := repeated_stamps_warning(traj, name):
            logger.warning('%s', text)
            if warnings is not None:
                warnings.append(text)
