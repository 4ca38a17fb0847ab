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
"""Tests of the ``solve`` verb, in process and once through the console entry point."""

from __future__ import annotations

import json
from pathlib import Path
import subprocess
import sys

import numpy as np
from pmba_ros.cli.main import main
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.problem import BAProblem
import pytest

REPORT_KEYS = {'param', 'solver', 'converged', 'iterations', 'linear_solves', 'initial_cost',
               'final_cost', 'initial_rms_px', 'final_rms_px', 'time_s', 'history'}


def test_solve_writes_the_report_and_outputs(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """`solve sim:table3` converges and writes the JSON report, TUM poses and points."""
    report = tmp_path / 'r.json'
    rc = main(['solve', 'sim:table3', '--quiet', '--report', str(report),
               '--out', str(tmp_path / 'out')])
    assert rc == 0
    data = json.loads(report.read_text())
    assert REPORT_KEYS <= set(data)
    assert data['param'] == 'pmba' and data['solver'] == 'dogleg'
    assert data['final_rms_px'] < data['initial_rms_px']
    assert {'cost', 'rms_px', 'accepted', 'time_s'} <= set(data['history'][0])
    poses = (tmp_path / 'out' / 'poses_pmba_dogleg.tum').read_text().splitlines()
    assert len(poses) == 4 and len(poses[0].split()) == 8
    assert 'termination' in capsys.readouterr().out


def test_solve_compare_prints_one_table(capsys: pytest.CaptureFixture[str]) -> None:
    """`--compare` runs PMBA-DL, XYZ-LM and IDP-LM and prints a row for each."""
    assert main(['solve', 'sim:table3', '--compare', '--quiet']) == 0
    out = capsys.readouterr().out
    assert all(label in out for label in ('PMBA-dogleg', 'XYZ-lm', 'IDP-lm'))


def test_solve_shows_progress_unless_quiet(capsys: pytest.CaptureFixture[str]) -> None:
    """Without --quiet every iteration is reported on stderr."""
    assert main(['solve', 'sim:table3', '--max-iters', '3']) == 0
    err = capsys.readouterr().err
    assert err.count(' it ') >= 2


def test_global_init_shows_its_stages_and_iterations_unless_quiet(
        capsys: pytest.CaptureFixture[str]) -> None:
    """--init global reports each stage as it ends and the BA's iterations on stderr."""
    from pmba_ros.init.pipeline import STAGES

    assert main(['solve', 'sim:street', '--init', 'global']) == 0
    err = capsys.readouterr().err
    done = [line.split()[1] for line in err.splitlines() if line.startswith('  init ')]
    assert done == list(STAGES), err
    assert err.count('pmba-dogleg it ') >= 2
    assert main(['solve', 'sim:street', '--init', 'global', '--quiet']) == 0
    assert capsys.readouterr().err == ''


def test_solve_warns_when_an_iteration_cap_stops_it(capsys: pytest.CaptureFixture[str]) -> None:
    """A run stopped by --max-iters says so on stderr; a converged run prints no warning."""
    assert main(['solve', 'sim:table3', '--max-iters', '1', '--quiet']) == 0
    err = capsys.readouterr().err
    assert 'warning: pmba-dogleg stopped at max_iterations after 1 iterations' in err
    assert main(['solve', 'sim:table3', '--quiet']) == 0
    assert 'warning' not in capsys.readouterr().err


def test_solve_global_init_reports_stages(tmp_path: Path) -> None:
    """`--init global` ignores the file's start and reports the stages and one BA."""
    report = tmp_path / 'r.json'
    assert main(['solve', 'sim:street:1', '--init', 'global', '--quiet',
                 '--report', str(report)]) == 0
    data = json.loads(report.read_text())
    assert data['ba_invocations'] == 1
    assert 'init' in data and data['converged']


def test_solve_says_when_the_initializations_ba_was_resumed(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """The summary printed is the last BA's: a line says it was resumed, and why."""
    from dataclasses import replace

    from pmba_ros.init import pipeline
    real = pipeline.global_init

    def resumed(*args: object, **kwargs: object) -> object:
        res = real(*args, **kwargs)  # type: ignore[arg-type]
        res.report['summary'].update(ba_invocations=3, inconsistent_tracks=5,
                                     tracks_readmitted=4)
        res.report['ba']['iterations'] = 17
        return replace(res, ba_invocations=3)

    monkeypatch.setattr(pipeline, 'global_init', resumed)
    assert main(['solve', 'sim:street:1', '--init', 'global', '--quiet']) == 0
    out = capsys.readouterr().out
    assert ('global initialization: the BA above is the last of 3 (17 iterations in all), '
            'resumed to try the 5 tracks dropped before it again: 4 taken back') in out

    def cleaned(*args: object, **kwargs: object) -> object:
        res = resumed(*args, **kwargs)
        res.report['summary'].update(inconsistent_tracks=0)  # type: ignore[attr-defined]
        res.report['ba']['observations_off_after_ba'] = 7  # type: ignore[attr-defined]
        return res

    monkeypatch.setattr(pipeline, 'global_init', cleaned)
    assert main(['solve', 'sim:street:1', '--init', 'global', '--quiet']) == 0
    assert ('(17 iterations in all), resumed without the 7 observations it left far off'
            in capsys.readouterr().out)
    monkeypatch.setattr(pipeline, 'global_init', real)
    assert main(['solve', 'sim:street:1', '--init', 'global', '--quiet']) == 0
    assert 'resumed' not in capsys.readouterr().out


def test_convergence_plot_shows_every_ba_of_a_resumed_initialization(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """--plot draws all of the initialization's BAs, in a row, and the result's RMS."""
    pytest.importorskip('matplotlib')
    from dataclasses import replace

    import pmba_ros.cli.solve as cli_solve
    from pmba_ros.init import pipeline
    real = pipeline.global_init

    def twice(*args: object, **kwargs: object) -> object:
        first = real(*args, **kwargs)  # type: ignore[arg-type]
        again = real(*args, **kwargs)  # type: ignore[arg-type]
        return replace(again, ba_invocations=first.ba_invocations + again.ba_invocations)

    plotted: list[tuple[str, object, float]] = []
    plot = cli_solve.plot_convergence

    def spy(path: Path, traces: list[tuple[str, object, float]]) -> Path:
        plotted.extend(traces)
        return plot(path, traces)  # type: ignore[arg-type]

    monkeypatch.setattr(pipeline, 'global_init', twice)
    monkeypatch.setattr(cli_solve, 'plot_convergence', spy)
    out = tmp_path / 'out'
    assert main(['solve', 'sim:street:1', '--init', 'global', '--quiet', '--out', str(out),
                 '--plot']) == 0
    assert (out / 'convergence.png').stat().st_size > 0
    data = json.loads((out / 'report.json').read_text())
    (label, trace, result_rms), = plotted
    assert label == 'PMBA-dogleg' and result_rms == data['final_rms_px']
    assert isinstance(trace, cli_solve.ConvergenceTrace)
    bas = trace.bas()
    assert len(bas) == data['ba_invocations'] >= 2
    assert bas[-1][1] == pytest.approx([h['rms_px'] for h in data['history']])
    assert np.all(np.diff(trace.times_s) >= 0)


@pytest.mark.parametrize('option', [['--compare'], ['--param', 'xyz'], ['--param', 'idp']])
def test_global_init_with_another_parameterization_is_one_error_line(
        option: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """--init global ends in PMBA's BA: XYZ / IDP or --compare name the options, no traceback."""
    assert main(['solve', 'sim:street:1', '--init', 'global', '--quiet', *option]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('error: --init global ') and option[-1] in err[0]
    assert main(['solve', 'sim:street:1', '--init', 'global', '--quiet', '--solver', 'lm']) == 0


def test_convergence_trace_continues_each_ba_from_the_last_ones_end() -> None:
    """A record of iteration 0 starts a BA where the one before ended."""
    from pmba_ros.core.solve import IterationRecord
    from pmba_ros.plot import ConvergenceTrace

    def rec(iteration: int, time_s: float, rms: float) -> IterationRecord:
        return IterationRecord(iteration, rms ** 2, rms, True, 1.0, 0.0, 1.0, iteration, time_s)

    trace = ConvergenceTrace()
    for r in (rec(0, 0.0, 5.0), rec(1, 0.5, 2.0), rec(0, 0.1, 2.0), rec(1, 0.3, 1.0),
              rec(0, 0.0, 1.0)):
        trace.add(r)
    assert trace.times_s == pytest.approx([0.0, 0.5, 0.6, 0.8, 0.8])
    assert trace.bas() == [([0.0, 0.5], [5.0, 2.0]), (pytest.approx([0.6, 0.8]), [2.0, 1.0]),
                           (pytest.approx([0.8]), [1.0])]


@pytest.mark.parametrize(('content', 'match'), [
    ('3 2\n', 'bad.txt:1:'),
    ('1 1 1\n0 0 1.0 x\n', 'bad.txt:2:'),
])
def test_malformed_problem_file_is_one_error_line(tmp_path: Path, content: str, match: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """A malformed BAL file gives exit code 1 and one `error:` line naming the line."""
    bad = tmp_path / 'bad.txt'
    bad.write_text(content)
    assert main(['solve', str(bad), '--quiet']) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('error:') and match in err[0]


def test_unknown_scene_and_missing_file_are_errors(capsys: pytest.CaptureFixture[str]) -> None:
    """Unknown `sim:` scenes and missing files are one error line, exit code 1."""
    assert main(['solve', 'sim:nowhere', '--quiet']) == 1
    assert main(['solve', '/no/such/problem.txt', '--quiet']) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2 and all(line.startswith('error:') for line in lines)


def test_console_entry_point_runs() -> None:
    """`python -m pmba_ros solve` works as a subprocess (the installed script's path)."""
    proc = subprocess.run([sys.executable, '-m', 'pmba_ros', 'solve', 'sim:table3', '--quiet'],
                          capture_output=True, text=True, check=False, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert 'PMBA / dogleg' in proc.stdout


@pytest.mark.parametrize('init', ['file', 'global'])
def test_solve_refines_a_colmap_model_in_its_own_format(tmp_path: Path, init: str) -> None:
    """`pmba solve MODEL --out DIR` writes the refined COLMAP model (same frame) to DIR."""
    import numpy as np
    from pmba_ros.eval.align import umeyama_alignment
    from pmba_ros.io import colmap
    from pmba_ros.sim.scenes import street_scene

    scene = street_scene(2, n_cams=8, n_points=300, far_fraction=0.0, jitter_m=0.3)
    colmap.write_colmap(tmp_path / 'model', colmap.from_problem(scene.start), binary=True)
    out = tmp_path / 'refined'
    assert main(['solve', str(tmp_path / 'model'), '--init', init, '--quiet',
                 '--out', str(out), '--report', str(tmp_path / 'r.json')]) == 0
    assert (out / 'cameras.bin').is_file() and (out / 'report.json').is_file()
    refined, _ = colmap.to_problem(colmap.read_colmap(out))
    gt = scene.gt

    def error(centers: np.ndarray) -> float:
        sim = umeyama_alignment(centers, gt.centers_w, with_scale=True)
        moved = sim.scale * centers @ sim.rotation.T + sim.translation
        return float(np.linalg.norm(moved - gt.centers_w, axis=1).mean())

    assert error(refined.centers_w) < 0.3 * error(scene.start.centers_w)
    # Written in the model's frame: the refined cameras stay where the input put them.
    assert np.linalg.norm(refined.centers_w - scene.start.centers_w, axis=1).mean() < 0.2
    data = json.loads((tmp_path / 'r.json').read_text())
    assert data['converged']


def test_cameras_the_global_initialization_leaves_out_are_warned_about(tmp_path: Path) -> None:
    """Two scenes in one model share no feature: the smaller one is not solved, and it is said."""
    import dataclasses

    import numpy as np
    from pmba_ros.io import colmap
    from pmba_ros.sim.scenes import street_scene

    a = colmap.from_problem(street_scene(1, n_cams=10, n_points=300).start)
    b = colmap.from_problem(street_scene(2, n_cams=8, n_points=250).start)
    images = dict(a.images)
    for iid, img in b.images.items():   # ids past a's: images + 100, points + 10_000
        images[iid + 100] = dataclasses.replace(
            img, name=f'b_{img.name}',
            point3d_ids=np.where(img.point3d_ids >= 0, img.point3d_ids + 10_000, -1))
    model = dataclasses.replace(
        a, images=images, point_ids=np.concatenate([a.point_ids, b.point_ids + 10_000]),
        xyz=np.concatenate([a.xyz, b.xyz + 100.0]), rgb=np.concatenate([a.rgb, b.rgb]),
        error=np.concatenate([a.error, b.error]),
        tracks=[*a.tracks, *[t + np.array([100, 0]) for t in b.tracks]])
    colmap.write_colmap(tmp_path / 'two', model)
    assert main(['solve', str(tmp_path / 'two'), '--init', 'global', '--quiet', '--report',
                 str(tmp_path / 'r.json')]) == 0
    report = json.loads((tmp_path / 'r.json').read_text())
    assert report['n_cams'] == 10
    (warning,) = report['warnings']
    assert warning.startswith('global initialization: 8 of 18 cameras could not be placed')


def test_a_collection_turned_in_place_is_said_to_lack_baseline(tmp_path: Path) -> None:
    """16 of 20 images taken from one spot: their pairs have no baseline, and it is said.

    The four that move place them all; before, nothing said that most pairs had no baseline.
    """
    import numpy as np
    from pmba_ros.core.camera import project
    from pmba_ros.core.problem import make_problem
    from pmba_ros.io.bal import write_bal
    from pmba_ros.sim.scenes import street_scene

    gt = street_scene(3, n_cams=20, n_points=500).gt
    centers = gt.centers_w.copy()
    centers[:16] = centers[0]
    obs = gt.obs
    points = np.asarray(gt.points_w)
    h_c = np.einsum('kji,kj->ki', gt.R_wc[obs.cam_idx],
                    points[obs.feat_idx] - centers[obs.cam_idx])
    front = h_c[:, 2] > 1.0
    pixels = project(h_c[front], gt.intrinsics, obs.cam_idx[front])
    pixels += np.random.default_rng(0).normal(0.0, 0.5, pixels.shape)
    turned = make_problem(gt.R_wc, centers, gt.intrinsics, obs.cam_idx[front],
                          obs.feat_idx[front], pixels, points_w=points, n_feats=gt.n_feats)
    write_bal(tmp_path / 'turned.txt', turned)
    assert main(['solve', str(tmp_path / 'turned.txt'), '--init', 'global', '--quiet',
                 '--report', str(tmp_path / 'r.json')]) == 0
    report = json.loads((tmp_path / 'r.json').read_text())
    (warning,) = [w for w in report['warnings'] if 'baseline' in w]
    pairs = report['init']['pairs']
    assert pairs['pairs_rejected']['low_parallax'] >= 100 > pairs['pairs_found']
    assert warning.startswith(f'global initialization: {pairs["pairs_rejected"]["low_parallax"]}'
                              f' of {pairs["pairs_candidate"]} image pairs show no baseline')


def test_an_earlier_models_colmap_files_are_removed_from_out(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Binary files and rigs of an earlier run would be read instead of a refined text model."""
    import numpy as np
    from pmba_ros.io import colmap
    from pmba_ros.sim.scenes import street_scene

    scene = street_scene(2, n_cams=6, n_points=200, far_fraction=0.0)
    model = colmap.from_problem(scene.start)
    colmap.write_colmap(tmp_path / 'model', model)
    out = tmp_path / 'refined'
    colmap.write_colmap(out, model, binary=True)        # an earlier run's binary model
    (out / 'rigs.txt').write_text('1 1 CAMERA 1\n')    # and its rigs
    assert main(['solve', str(tmp_path / 'model'), '--quiet', '--out', str(out)]) == 0
    assert 'removed cameras.bin, images.bin, points3D.bin, rigs.txt' in capsys.readouterr().out
    assert sorted(p.name for p in out.glob('*.bin')) == [] and not (out / 'rigs.txt').exists()
    refined, _ = colmap.to_problem(colmap.read_colmap(out))
    assert not np.allclose(refined.centers_w, scene.start.centers_w)
    # In the input's own folder nothing is removed: a warning says what COLMAP may read.
    colmap.write_colmap(tmp_path / 'model', model, binary=True)
    assert main(['solve', str(tmp_path / 'model'), '--quiet', '--out',
                 str(tmp_path / 'model')]) == 0
    assert 'also holds cameras.txt, images.txt, points3D.txt' in capsys.readouterr().err
    assert (tmp_path / 'model' / 'cameras.txt').is_file()


@pytest.mark.parametrize(('init', 'name'), [('file', 'bundle.out'), ('global', 'bundle.out'),
                                            ('file', 'bundle.out.gz')])
def test_solve_refines_a_bundler_file_in_its_own_format(tmp_path: Path, init: str,
                                                        name: str) -> None:
    """`pmba solve bundle.out[.gz] --out DIR` writes DIR/bundle.out with the refined cameras."""
    import gzip
    from test.io.test_bundler import _bundle_text

    import numpy as np
    from pmba_ros.core.camera import Intrinsics, project
    from pmba_ros.core.problem import make_problem
    from pmba_ros.io import bundler
    from pmba_ros.sim.scenes import street_scene

    scene = street_scene(2, n_cams=8, n_points=300, far_fraction=0.0, jitter_m=0.3)
    p = scene.start
    M = p.n_cams
    intr = Intrinsics(p.intrinsics.fx, p.intrinsics.fx, np.zeros(M), np.zeros(M),
                      np.zeros(M), np.zeros(M))
    centred = make_problem(p.R_wc, p.centers_w, intr, p.obs.cam_idx, p.obs.feat_idx,
                           project(p.obs.bearings_c, intr, p.obs.cam_idx),
                           points_w=p.points_w, n_feats=p.n_feats)
    text = _bundle_text(centred).encode()
    (tmp_path / name).write_bytes(gzip.compress(text) if name.endswith('.gz') else text)
    out = tmp_path / 'refined'
    assert main(['solve', str(tmp_path / name), '--init', init, '--quiet',
                 '--out', str(out)]) == 0
    refined, _ = bundler.to_problem(bundler.read_bundler(out / 'bundle.out'))
    gt = scene.gt
    start_err = np.linalg.norm(p.centers_w - gt.centers_w, axis=1).mean()
    assert np.linalg.norm(refined.centers_w - gt.centers_w, axis=1).mean() < 0.5 * start_err


def test_solve_engine_option_gives_the_same_result(tmp_path: Path) -> None:
    """`--engine numpy` and `--engine compiled` reach the same cost; the report says so."""
    pytest.importorskip('numba')
    costs = {}
    for name in ('numpy', 'compiled'):
        report = tmp_path / f'{name}.json'
        assert main(['solve', 'sim:table3', '--quiet', '--engine', name, '--max-iters', '5',
                     '--report', str(report)]) == 0
        costs[name] = json.loads(report.read_text())['final_cost']
    assert costs['compiled'] == pytest.approx(costs['numpy'], rel=1e-6)


def test_solve_threads_option_caps_the_compiled_loops(monkeypatch: pytest.MonkeyPatch) -> None:
    """`--threads N` caps the threads a large problem's loops use; 0 is a usage error."""
    pytest.importorskip('numba')
    from pmba_ros.core import warmup
    from pmba_ros.core.compiled import chunks

    # The loops load before the verb runs (its tiny problem is one chunk without the patch).
    monkeypatch.setattr(warmup, 'warm_up', lambda: 0.0)
    monkeypatch.setattr(chunks, 'available_cores', lambda: 4)
    monkeypatch.setattr(chunks, 'CHUNK_OBSERVATIONS', 1)
    used: list[int] = []
    run = chunks.run
    monkeypatch.setattr(chunks, 'run', lambda fn, n: used.append(n) or run(fn, n))
    try:
        assert main(['solve', 'sim:table3', '--quiet', '--max-iters', '2', '--threads', '3',
                     '--engine', 'compiled']) == 0
    finally:
        chunks.set_max_threads(None)
    assert used and set(used) == {3}
    with pytest.raises(SystemExit):
        main(['solve', 'sim:table3', '--threads', '0'])


def test_global_init_poses_keep_the_input_camera_index(tmp_path: Path) -> None:
    """TUM stamps after `--init global` are the input cameras, not 0.. of the solved subset.

    The file holds two unconnected scenes, the smaller first: the global initialization
    solves the larger one only, whose poses used to be written as cameras 0, 1, ...
    """
    import numpy as np
    from pmba_ros.core.problem import make_problem
    from pmba_ros.io.bal import write_bal
    from pmba_ros.sim.scenes import street_scene
    small = street_scene(2, n_cams=4, n_points=60).gt
    large = street_scene(1).gt
    shift = np.array([1e3, 0.0, 0.0])        # far apart, no common point
    both = make_problem(
        np.concatenate([small.R_wc, large.R_wc]),
        np.concatenate([small.centers_w, large.centers_w + shift]),
        _stack_intrinsics(small, large),
        np.concatenate([small.obs.cam_idx, large.obs.cam_idx + small.n_cams]),
        np.concatenate([small.obs.feat_idx, large.obs.feat_idx + small.n_feats]),
        np.concatenate([small.obs.pixels, large.obs.pixels]),
        points_w=np.concatenate([small.points_w, large.points_w + shift]))
    write_bal(tmp_path / 'two.txt', both)
    assert main(['solve', str(tmp_path / 'two.txt'), '--init', 'global', '--quiet',
                 '--out', str(tmp_path / 'out')]) == 0
    report = json.loads((tmp_path / 'out' / 'report.json').read_text())
    assert report['init']['summary']['cameras_left_out'] == list(range(small.n_cams))
    rows = np.loadtxt(tmp_path / 'out' / 'poses_pmba_dogleg.tum', ndmin=2)
    np.testing.assert_array_equal(rows[:, 0], small.n_cams + np.arange(large.n_cams))
    # The points carry the input's point ids: each is its input point, in the solution's frame.
    from pmba_ros.eval.align import umeyama_alignment
    points = np.loadtxt(tmp_path / 'out' / 'points_pmba_dogleg.xyz', ndmin=2)
    ids = points[:, 3].astype(int)
    assert np.unique(ids).shape[0] == ids.shape[0] > 0.9 * large.n_feats
    assert np.all(ids >= small.n_feats)
    truth = both.points_w[ids]
    depth = np.linalg.norm(truth - both.centers_w[small.n_cams:].mean(axis=0), axis=1)
    near = depth < np.median(depth)   # far points align poorly (their depths are weak)
    sim = umeyama_alignment(points[near, :3], truth[near], with_scale=True)
    moved = sim.scale * points[near, :3] @ sim.rotation.T + sim.translation
    assert np.median(np.linalg.norm(moved - truth[near], axis=1) / depth[near]) < 0.01


def test_cameras_no_feature_joins_are_a_warning(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Two scenes in one file, `--init file`: solved, with a warning that each has its gauge.

    One scene alone gives none.
    """
    import numpy as np
    from pmba_ros.core.problem import make_problem
    from pmba_ros.io.bal import write_bal
    from pmba_ros.sim.scenes import street_scene
    small, large = street_scene(2, n_cams=4, n_points=60).start, street_scene(1).start
    both = make_problem(
        np.concatenate([small.R_wc, large.R_wc]),
        np.concatenate([small.centers_w, large.centers_w]),
        _stack_intrinsics(small, large),
        np.concatenate([small.obs.cam_idx, large.obs.cam_idx + small.n_cams]),
        np.concatenate([small.obs.feat_idx, large.obs.feat_idx + small.n_feats]),
        np.concatenate([small.obs.pixels, large.obs.pixels]),
        points_w=np.concatenate([small.points_w, large.points_w]))
    write_bal(tmp_path / 'two.txt', both)
    write_bal(tmp_path / 'one.txt', large)
    report = tmp_path / 'report.json'
    assert main(['solve', str(tmp_path / 'two.txt'), '--quiet', '--report', str(report)]) == 0
    assert f'2 groups that share no feature ([{small.n_cams}, {large.n_cams}] cameras)' in (
        capsys.readouterr().err)
    assert any('2 groups' in w for w in json.loads(report.read_text())['warnings'])
    assert main(['solve', str(tmp_path / 'one.txt'), '--quiet']) == 0
    assert 'groups' not in capsys.readouterr().err


def _stack_intrinsics(a: BAProblem, b: BAProblem) -> Intrinsics:
    """Return the intrinsics of a's cameras followed by b's."""
    import numpy as np
    fields = ('fx', 'fy', 'cx', 'cy', 'k1', 'k2')
    return Intrinsics(*(np.concatenate([getattr(a.intrinsics, f), getattr(b.intrinsics, f)])
                        for f in fields))


@pytest.mark.parametrize('focal', [1e-9, 1e12])
def test_focal_lengths_the_observations_cannot_have_are_a_warning(
        tmp_path: Path, focal: float, capsys: pytest.CaptureFixture[str]) -> None:
    """A BAL file whose focal lengths are not in pixels: solved, with a warning naming them.

    Before, it converged to a wrong RMS without a word; the file as written gives none.
    """
    from pmba_ros.io.bal import write_bal
    from pmba_ros.sim.scenes import street_scene
    problem = street_scene(1).start
    write_bal(tmp_path / 'good.txt', problem)
    lines = (tmp_path / 'good.txt').read_text().splitlines()
    header = [int(v) for v in lines[0].split()]
    first_camera = 1 + header[2]
    for c in range(problem.n_cams):   # the 7th of 9 values of each camera: f
        lines[first_camera + 9 * c + 6] = f'{focal:.17g}'
    (tmp_path / 'bad.txt').write_text('\n'.join(lines) + '\n')
    report = tmp_path / 'report.json'
    assert main(['solve', str(tmp_path / 'bad.txt'), '--quiet', '--max-iters', '3',
                 '--report', str(report)]) == 0
    err = capsys.readouterr().err
    assert f'{problem.n_cams} cameras (the first: camera 0, focal length {focal:g} px)' in err
    assert ('over 80 degrees' if focal < 1 else 'within 0.01 degrees') in err
    assert any('focal length' in w for w in json.loads(report.read_text())['warnings'])
    assert main(['solve', str(tmp_path / 'good.txt'), '--quiet', '--max-iters', '3']) == 0
    assert 'focal length' not in capsys.readouterr().err


def test_observations_of_points_behind_their_camera_are_a_warning(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A point behind a camera that sees it: a pinhole fits it, PMBA's rays cannot; said so.

    A few such observations (wrong matches) held PMBA without a robust loss at 5.3 px and
    unconverged where XYZ-LM reached 1.24 px, with no word why.
    """
    import dataclasses

    from pmba_ros.io.bal import write_bal
    from pmba_ros.sim.scenes import street_scene
    problem = street_scene(1).gt
    assert problem.points_w is not None
    k = 7
    cam, feat = problem.obs.cam_idx[k], problem.obs.feat_idx[k]
    points = problem.points_w.copy()   # mirrored through the camera: the same pixel there
    points[feat] = 2 * problem.centers_w[cam] - points[feat]
    write_bal(tmp_path / 'p.txt', dataclasses.replace(problem, points_w=points))
    assert main(['solve', str(tmp_path / 'p.txt'), '--quiet', '--max-iters', '1']) == 0
    err = capsys.readouterr().err
    seen = int((problem.obs.feat_idx == feat).sum())
    assert f'{seen} observations see their point behind the camera' in err
    assert '--loss cauchy weighs them down' in err
    write_bal(tmp_path / 'ok.txt', problem)
    assert main(['solve', str(tmp_path / 'ok.txt'), '--quiet', '--max-iters', '1']) == 0
    assert 'behind the camera' not in capsys.readouterr().err
