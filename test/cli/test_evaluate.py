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
"""Tests of the ``evaluate`` CLI verb (pmba_ros.cli.evaluate), run in-process."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from pmba_ros.cli import evaluate as cli
from pmba_ros.core import so3
from pmba_ros.errors import EvaluationError, FormatError, PmbaError
from pmba_ros.eval.metrics import ALIGN_MODES, evaluate
from pmba_ros.eval.trajectory import FORMATS, read_trajectory, Trajectory, write_tum
import pytest

from ..conftest import SHARED_DATA as DATA

EVO_DIR = DATA / 'trajectories' / 'evo'
needs_data = pytest.mark.skipif(not EVO_DIR.is_dir(), reason=f'{EVO_DIR} is not available')


def parse(argv: list[str]) -> argparse.Namespace:
    """Parse ``argv`` with the verb's arguments, as the dispatcher does."""
    parser = argparse.ArgumentParser(prog='pmba evaluate')
    cli.add_arguments(parser)
    return parser.parse_args(argv)


@pytest.fixture
def tum_pair(tmp_path: Path) -> tuple[Path, Path]:
    """Write a ground truth and a noisy, scaled estimate as TUM files."""
    rng = np.random.default_rng(7)
    n = 60
    stamps = 10.0 + 0.05 * np.arange(n)
    positions = np.cumsum(rng.normal(scale=0.1, size=(n, 3)), axis=0)
    rotations = so3.exp(np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0))
    gt = Trajectory(stamps, positions, rotations)
    est = Trajectory(stamps + 0.002,
                     0.5 * positions + rng.normal(scale=0.005, size=(n, 3)), rotations)
    write_tum(tmp_path / 'gt.txt', gt)
    write_tum(tmp_path / 'est.txt', est)
    return tmp_path / 'est.txt', tmp_path / 'gt.txt'


def test_defaults_are_auto_format_and_sim3() -> None:
    """Defaults: auto formats, Sim(3) alignment, 10 ms tolerance, delta 1, no report."""
    args = parse(['e.txt', 'g.txt'])
    assert (args.est_format, args.gt_format, args.align) == ('auto', 'auto', 'sim3')
    assert (args.max_diff, args.t_offset, args.delta, args.report) == (0.01, 0.0, 1, None)


def test_choices_match_the_library() -> None:
    """The parser's choices are the library's formats and alignment modes."""
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    choices = {a.dest: tuple(a.choices) for a in parser._actions if a.choices}
    assert choices['est_format'] == choices['gt_format'] == FORMATS
    assert choices['align'] == ALIGN_MODES


def test_run_prints_table_and_returns_zero(tum_pair: tuple[Path, Path],
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """run() prints ATE and RPE rows with the same numbers as the library."""
    est, gt = tum_pair
    assert cli.run(parse([str(est), str(gt)])) == 0
    out = capsys.readouterr().out
    expected = evaluate(read_trajectory(est), read_trajectory(gt), align='sim3')
    assert 'matched 60 of 60 estimated / 60 ground-truth poses; alignment sim3' in out
    assert f'{expected["ate"].rmse:.6f}' in out
    assert f'{expected["rpe"].rmse:.6f}' in out
    assert 'ATE (m)' in out
    assert 'RPE d=1 (m)' in out


def test_report_json_holds_both_metrics(tum_pair: tuple[Path, Path], tmp_path: Path) -> None:
    """--report writes the options and both results as JSON."""
    est, gt = tum_pair
    report = tmp_path / 'out.json'
    assert cli.run(parse([str(est), str(gt), '--align', 'se3', '--delta', '3',
                          '--report', str(report)])) == 0
    data = json.loads(report.read_text())
    expected = evaluate(read_trajectory(est), read_trajectory(gt), align='se3', delta=3)
    assert data['align'] == 'se3'
    assert data['delta_frames'] == 3
    assert data['ate']['rmse'] == pytest.approx(expected['ate'].rmse, rel=1e-12)
    assert data['rpe']['rmse'] == pytest.approx(expected['rpe'].rmse, rel=1e-12)
    assert data['ate']['alignment']['scale'] == 1.0


def test_report_is_byte_identical_run_to_run(tum_pair: tuple[Path, Path],
                                             tmp_path: Path) -> None:
    """Two runs write the same report bytes."""
    est, gt = tum_pair
    first, second = tmp_path / 'a.json', tmp_path / 'b.json'
    cli.run(parse([str(est), str(gt), '--report', str(first)]))
    cli.run(parse([str(est), str(gt), '--report', str(second)]))
    assert first.read_bytes() == second.read_bytes()


def test_missing_file_raises_format_error(tmp_path: Path) -> None:
    """Library errors propagate as PmbaError subclasses for the dispatcher."""
    with pytest.raises(FormatError, match='cannot read trajectory file'):
        cli.run(parse([str(tmp_path / 'no.txt'), str(tmp_path / 'no.txt')]))


def test_disjoint_stamps_raise_evaluation_error(tum_pair: tuple[Path, Path]) -> None:
    """A wrong time offset leaves nothing to associate."""
    est, gt = tum_pair
    with pytest.raises(EvaluationError, match='no matching timestamps'):
        cli.run(parse([str(est), str(gt), '--t-offset', '100']))


def test_unwritable_report_raises_pmba_error(tum_pair: tuple[Path, Path],
                                             tmp_path: Path) -> None:
    """A report below a file (its folder cannot exist) is a PmbaError before evaluating."""
    est, gt = tum_pair
    blocker = tmp_path / 'no'
    blocker.write_text('')
    with pytest.raises(PmbaError, match='cannot create its folder'):
        cli.run(parse([str(est), str(gt), '--report', str(blocker / 'r.json')]))


@pytest.mark.parametrize('where', ['proc', 'long_name'])
def test_report_the_folder_takes_not_is_refused_before_evaluating(
        tum_pair: tuple[Path, Path], tmp_path: Path, where: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A report its folder will not hold is refused before the table, as `solve` does."""
    if where == 'proc' and not Path('/proc/self').is_dir():
        pytest.skip('no /proc')
    # /proc takes no new file; a 255-character name leaves no room for the temporary one's.
    report = Path('/proc/pmba_report.json') if where == 'proc' else tmp_path / f'{"r" * 250}.json'
    est, gt = tum_pair
    with pytest.raises(PmbaError, match='cannot be written'):
        cli.run(parse([str(est), str(gt), '--report', str(report)]))
    assert capsys.readouterr().out == ''
    assert not report.exists()


@needs_data
def test_run_on_kitti_pair_with_explicit_formats(capsys: pytest.CaptureFixture[str]) -> None:
    """KITTI files (index stamps) evaluate pose i against pose i."""
    argv = [str(EVO_DIR / 'KITTI_00_ORB.txt'), str(EVO_DIR / 'KITTI_00_gt.txt'),
            '--format', 'kitti', '--gt-format', 'kitti', '--align', 'se3']
    assert cli.run(parse(argv)) == 0
    out = capsys.readouterr().out
    assert 'matched 4541 of 4541' in out
    assert '1.303450' in out  # evo_ape kitti ... -a: RMSE 1.303450 m


@needs_data
def test_run_on_tum_vs_euroc_pair(capsys: pytest.CaptureFixture[str]) -> None:
    """A TUM estimate against EuRoC CSV ground truth, detected automatically."""
    argv = [str(EVO_DIR / 'V102.txt'), str(EVO_DIR / 'V102_groundtruth.csv')]
    assert cli.run(parse(argv)) == 0
    out = capsys.readouterr().out
    assert 'matched 798 of 807 estimated / 16702 ground-truth poses' in out


def _kitti_gt(tmp_path: Path) -> tuple[Path, Path, Path]:
    """Write a 40-pose ground truth as TUM stamped 0.0, 0.1, ... and as KITTI + times.txt."""
    rng = np.random.default_rng(11)
    n = 40
    gt = Trajectory(0.1 * np.arange(n), np.cumsum(rng.normal(scale=0.1, size=(n, 3)), axis=0),
                    so3.exp(np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0)))
    write_tum(tmp_path / 'est.tum', gt)
    rows = np.concatenate([gt.R_wc, gt.positions_xyz[:, :, None]], axis=2).reshape(n, 12)
    np.savetxt(tmp_path / 'gt.kitti', rows)
    np.savetxt(tmp_path / 'times.txt', gt.stamps_s)
    return tmp_path / 'est.tum', tmp_path / 'gt.kitti', tmp_path / 'times.txt'


def test_a_csv_header_decides_the_columns(tum_pair: tuple[Path, Path],
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """A CSV with a w-first header and stamps in seconds: the numbers of the TUM file.

    It was read as TUM with commas (quaternion x first): ATE right, RPE 6x too large.
    """
    est, gt = tum_pair
    traj = read_trajectory(gt)
    rows = np.column_stack([traj.stamps_s, traj.positions_xyz, traj.quat_xyzw[:, [3, 0, 1, 2]]])
    csv = gt.with_name('gt.csv')
    np.savetxt(csv, rows, fmt='%.9f', delimiter=',',
               header='timestamp, p_x,p_y,p_z,q_w,q_x,q_y,q_z')
    assert cli.run(parse([str(est), str(gt)])) == 0
    assert cli.run(parse([str(est), str(csv)])) == 0
    tum_out, csv_out = capsys.readouterr().out.split('matched')[1:]
    assert csv_out == tum_out
    with pytest.raises(EvaluationError,
                       match=r'read as nanoseconds \(EuRoC CSV\); these look like seconds'):
        cli.run(parse([str(est), str(csv), '--gt-format', 'euroc']))
    with pytest.raises(FormatError, match=r'gt\.csv:1: the header names the quaternion w'):
        cli.run(parse([str(est), str(csv), '--gt-format', 'tum']))


def test_kitti_gt_without_times_against_stamps_is_an_error(tmp_path: Path) -> None:
    """A KITTI GT against a 10 Hz estimate needs its times (before: 4 of 40 matched, an ATE)."""
    est, gt, times = _kitti_gt(tmp_path)
    with pytest.raises(EvaluationError, match=r'KITTI file without stamps.*--gt-times FILE'):
        cli.run(parse([str(est), str(gt)]))
    report = tmp_path / 'r.json'
    assert cli.run(parse([str(est), str(gt), '--gt-times', str(times),
                          '--report', str(report)])) == 0
    result = json.loads(report.read_text())
    assert result['ate']['n_matched'] == 40 and result['warnings'] == []
    with pytest.raises(FormatError, match='times are for a KITTI file'):
        cli.run(parse([str(est), str(gt), '--times', str(times)]))


def test_few_matched_poses_warn(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An estimate of which few poses find a ground-truth stamp: a warning, in the report."""
    est = _kitti_gt(tmp_path)[0]
    traj = read_trajectory(est)
    shifted = Trajectory(traj.stamps_s + np.where(np.arange(40) % 5 == 0, 0.0, 0.04),
                         traj.positions_xyz, traj.R_wc)
    write_tum(tmp_path / 'shifted.tum', shifted)
    report = tmp_path / 'r.json'
    assert cli.run(parse([str(tmp_path / 'shifted.tum'), str(est),
                          '--report', str(report)])) == 0
    assert 'warning: only 8 of the 39 estimated poses' in capsys.readouterr().err
    assert json.loads(report.read_text())['warnings'][0].startswith('only 8 of the 39')


def test_repeated_stamps_are_counted_in_a_warning(tum_pair: tuple[Path, Path], tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """An estimate whose poses all share one stamp: counted, on stderr and in the report.

    Before, it reported "matched 60 of 60" without a word. The poses are kept (each matched
    on its own, as evo does, whose parity on real files with a few repeats stays).
    """
    est, gt = tum_pair
    traj = read_trajectory(est)
    write_tum(tmp_path / 'same.txt', Trajectory(np.full(len(traj), traj.stamps_s[10]),
                                                traj.positions_xyz, traj.R_wc))
    report = tmp_path / 'r.json'
    assert cli.run(parse([str(tmp_path / 'same.txt'), str(gt), '--report', str(report)])) == 0
    text = ('59 of the 60 estimated poses repeat the stamp of an earlier pose (distinct '
            'stamps: 1)')
    assert f'warning: {text}' in capsys.readouterr().err
    assert json.loads(report.read_text())['warnings'][0].startswith(text)
    assert cli.run(parse([str(est), str(gt), '--report', str(report)])) == 0
    assert json.loads(report.read_text())['warnings'] == []
