"""``pmba evaluate EST GT``: ATE and RPE of an estimated trajectory against ground truth.

Usage examples::

    pmba evaluate est.txt groundtruth.txt                      # TUM vs TUM, Sim(3) alignment
    pmba evaluate V102.txt V102_groundtruth.csv --align se3    # TUM vs EuRoC CSV
    pmba evaluate orb.txt gt.txt --format kitti --gt-format kitti --report result.json

The numbers equal ``evo_ape`` / ``evo_rpe`` with the default translation-part metric
(``-a`` for se3, ``-as`` for sim3; RPE with ``--delta N --delta_unit f --all_pairs``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from pmba_ros.errors import PmbaError

if TYPE_CHECKING:
    import argparse
    from collections.abc import Mapping

    from pmba_ros.eval.metrics import EvalResult

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
                        help='format of EST (KITTI files get index stamps)')
    parser.add_argument('--gt-format', choices=_FORMATS, default='auto',
                        help='format of GT')
    parser.add_argument('--align', choices=_ALIGN_MODES, default='sim3',
                        help='alignment of EST onto GT before the errors')
    parser.add_argument('--max-diff', type=float, default=0.01, metavar='S',
                        help='largest timestamp difference for association, s')
    parser.add_argument('--t-offset', type=float, default=0.0, metavar='S',
                        help='offset added to the EST stamps for association, s')
    parser.add_argument('--delta', type=int, default=1, metavar='N',
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
    from pmba_ros.eval.metrics import evaluate
    from pmba_ros.eval.trajectory import read_trajectory

    est = read_trajectory(args.est, args.est_format)
    gt = read_trajectory(args.gt, args.gt_format)
    results = evaluate(est, gt, align=args.align, max_diff_s=args.max_diff, delta=args.delta,
                       offset_s=args.t_offset)
    print(format_table(results, n_est=len(est), n_gt=len(gt)))
    if args.report is not None:
        report = {
            'est': str(args.est), 'gt': str(args.gt), 'align': args.align,
            'max_diff_s': args.max_diff, 't_offset_s': args.t_offset, 'delta_frames': args.delta,
            'n_est': len(est), 'n_gt': len(gt),
            'ate': results['ate'].to_dict(), 'rpe': results['rpe'].to_dict(),
        }
        try:
            args.report.write_text(json.dumps(report, indent=2, sort_keys=True) + '\n',
                                   encoding='utf-8')
        except OSError as err:
            msg = f'{args.report}: cannot write report: {err}'
            raise PmbaError(msg) from err
        print(f'report written to {args.report}')
    return 0


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
