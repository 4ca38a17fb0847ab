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
"""``pmba evaluate EST GT``: ATE and RPE of an estimated trajectory against ground truth.

Usage examples::

    pmba evaluate est.txt groundtruth.txt                      # TUM vs TUM, Sim(3) alignment
    pmba evaluate V102.txt V102_groundtruth.csv --align se3    # TUM vs EuRoC CSV
    pmba evaluate orb.txt gt.txt --format kitti --gt-format kitti --report result.json
    pmba evaluate est.tum 00.txt --gt-times times.txt          # TUM vs KITTI with its times

The numbers equal ``evo_ape`` / ``evo_rpe`` with the default translation-part metric
(``-a`` for se3, ``-as`` for sim3; RPE with ``--delta N --delta_unit f --all_pairs``).
"""

from __future__ import annotations

from pathlib import Path
import sys
from typing import TYPE_CHECKING

from pmba_ros._json import dumps_report
from pmba_ros.cli.argtypes import finite_float, non_negative_float, positive_int
from pmba_ros.errors import PmbaError
from pmba_ros.io.atomic import prepare_output, write_text_atomic

if TYPE_CHECKING:
    import argparse
    from collections.abc import Mapping

    from pmba_ros.eval.metrics import EvalResult
    from pmba_ros.eval.trajectory import Trajectory

_FORMATS = ('auto', 'tum', 'euroc', 'kitti')
_ALIGN_MODES = ('se3', 'sim3', 'none')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the arguments of the ``evaluate`` verb.

    Args:
        parser: Parser (or subparser) to add the arguments to.
    """
    parser.add_argument('est', metavar='EST', help='estimated trajectory file')
    parser.add_argument('gt', metavar='GT', help='ground-truth trajectory file')
    parser.add_argument('--format', dest='est_format', choices=_FORMATS, default='auto',
                        help='format of EST (KITTI files get index stamps unless --times)')
    parser.add_argument('--gt-format', choices=_FORMATS, default='auto',
                        help='format of GT')
    parser.add_argument('--times', type=Path, default=None, metavar='FILE',
                        help='times.txt of a KITTI EST: its stamps (s), one line per pose')
    parser.add_argument('--gt-times', type=Path, default=None, metavar='FILE',
                        help='times.txt of a KITTI GT: its stamps (s), one line per pose')
    parser.add_argument('--align', choices=_ALIGN_MODES, default='sim3',
                        help='alignment of EST onto GT before the errors')
    parser.add_argument('--max-diff', type=non_negative_float, default=0.01, metavar='S',
                        help='largest timestamp difference for association, s')
    parser.add_argument('--t-offset', type=finite_float, default=0.0, metavar='S',
                        help='offset added to the EST stamps for association, s')
    parser.add_argument('--delta', type=positive_int, default=1, metavar='N',
                        help='RPE pose distance in frames, all pairs')
    parser.add_argument('--report', type=Path, default=None, metavar='FILE.json',
                        help='also write the results as JSON')


def run(args: argparse.Namespace) -> int:
    """Evaluate EST against GT, print a table and optionally write a JSON report.

    Args:
        args: Parsed arguments (see :func:`add_arguments`).

    Returns:
        0 on success.

    Raises:
        FormatError: If a trajectory file is missing or malformed.
        EvaluationError: If the trajectories cannot be associated or aligned.
        PmbaError: If the report cannot be written.
    """
    from pmba_ros.eval.metrics import association_warning, evaluate, repeated_stamps_warning
    from pmba_ros.eval.trajectory import read_trajectory

    if args.report is not None:
        prepare_output(args.report, '--report')
    est = read_trajectory(args.est, args.est_format, times=getattr(args, 'times', None))
    gt = read_trajectory(args.gt, args.gt_format, times=getattr(args, 'gt_times', None))
    warnings = _length_warnings(est, gt)
    warnings += [text for text in (repeated_stamps_warning(est, 'estimated'),
                                   repeated_stamps_warning(gt, 'ground-truth')) if text]
    for text in warnings:
        print(f'warning: {text}', file=sys.stderr)
    results = evaluate(est, gt, align=args.align, max_diff_s=args.max_diff, delta=args.delta,
                       offset_s=args.t_offset)
    if text := association_warning(est, gt, args.max_diff, args.t_offset):
        print(f'warning: {text}', file=sys.stderr)
        warnings.append(text)
    print(format_table(results, n_est=len(est), n_gt=len(gt)))
    if args.report is not None:
        report = {
            'est': str(args.est), 'gt': str(args.gt), 'align': args.align,
            'max_diff_s': args.max_diff, 't_offset_s': args.t_offset, 'delta_frames': args.delta,
            'n_est': len(est), 'n_gt': len(gt),
            'ate': results['ate'].to_dict(), 'rpe': results['rpe'].to_dict(),
            'warnings': warnings,
        }
        try:
            write_text_atomic(args.report, dumps_report(report))
        except OSError as err:
            msg = f'{args.report}: cannot write report: {err}'
            raise PmbaError(msg) from err
        print(f'report written to {args.report}')
    return 0


def _length_warnings(est: Trajectory, gt: Trajectory) -> list[str]:
    """Warn when KITTI files (matched line by line: no stamps) differ in length."""
    n_est, n_gt = len(est), len(gt)
    if not (est.index_stamps and gt.index_stamps) or n_est == n_gt:
        return []
    text = (f'EST has {n_est} poses and GT {n_gt}: KITTI files have no stamps, so poses are '
            f'matched by line number and only the first {min(n_est, n_gt)} are compared; '
            'check that both start at the same frame')
    return [text]


def format_table(results: Mapping[str, EvalResult], n_est: int, n_gt: int) -> str:
    """Return the human-readable result table printed by :func:`run`.

    Args:
        results: ``{'ate': ..., 'rpe': ...}`` from :func:`pmba_ros.eval.metrics.evaluate`.
        n_est: Number of poses in the estimate file.
        n_gt: Number of poses in the ground-truth file.

    Returns:
        Several lines of text, without a trailing newline.
    """
    ate = results['ate']
    rpe = results['rpe']
    header = f'{"metric":<14}' + ''.join(
        f'{name:>11}' for name in ('rmse', 'mean', 'median', 'std', 'min', 'max')) + f'{"n":>8}'
    summary = (f'matched {ate.n_matched} of {n_est} estimated / {n_gt} ground-truth poses; '
               f'alignment {ate.align}, scale {ate.scale:.6g}')
    lines = [summary] + ([f'note: {ate.note}'] if ate.note else []) + [header, '-' * len(header)]
    for label, res in (('ATE (m)', ate), (f'RPE d={rpe.delta_frames} (m)', rpe)):
        stats = (res.rmse, res.mean, res.median, res.std, res.min, res.max)
        lines.append(f'{label:<14}' + ''.join(f'{v:>11.6f}' for v in stats)
                     + f'{res.n_pairs:>8d}')
    return '\n'.join(lines)
