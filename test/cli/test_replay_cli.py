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
"""Tests of the replay, simulate and import-tracks verbs (in-process, one subprocess each)."""

from __future__ import annotations

import json
from pathlib import Path
import subprocess
import sys

import numpy as np
from pmba_ros import replay as replay_mod
from pmba_ros.backend.frontends import PAIRINGS
from pmba_ros.cli.main import main
from pmba_ros.eval.trajectory import read_tum
from pmba_ros.io.bags import list_topics
from pmba_ros.io.bal import read_bal
import pytest

from ..conftest import shared_file
from ..test_replay import _backend, StubLogic


@pytest.fixture
def stub(monkeypatch: pytest.MonkeyPatch) -> None:
    """Replace the back-end with the replay tests' stub."""
    monkeypatch.setattr(replay_mod, '_make_logic',
                        lambda config: StubLogic(config, _backend()))


@pytest.fixture(scope='module')
def sim_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Return a 20-keyframe street written by the simulate verb."""
    out = tmp_path_factory.mktemp('cli') / 'street'
    assert main(['simulate', '--scenario', 'street', '--keyframes', '20', '--seed', '1',
                 '--out', str(out)]) == 0
    return out


def test_simulate_writes_front_end_topics(sim_bag: Path) -> None:
    """The simulated bag has the node's default input topics and a GT file."""
    topics = list_topics([sim_bag])
    assert topics['/features'].msgtype == 'sensor_msgs/msg/PointCloud'
    assert topics['/keyframe_pose'].msgtype == 'nav_msgs/msg/Odometry'
    assert topics['/camera_info'].count == 20
    assert (sim_bag / 'groundtruth.tum').exists()


def test_simulate_named_layout_writes_pointcloud2(tmp_path: Path) -> None:
    """--layout named gives PointCloud2 tracks."""
    out = tmp_path / 'named.mcap'
    assert main(['simulate', '--keyframes', '5', '--layout', 'named', '--out', str(out)]) == 0
    assert list_topics([out])['/features'].msgtype == 'sensor_msgs/msg/PointCloud2'


def test_simulate_stop_holds_the_ground_truth_still(tmp_path: Path) -> None:
    """--stop 40:5: keyframes 40-44 at one place in the ground truth, moving before and after."""
    out = tmp_path / 'stop'
    assert main(['simulate', '--keyframes', '80', '--stop', '40:5', '--out', str(out)]) == 0
    gt = read_tum(out / 'groundtruth.tum')
    step = np.linalg.norm(np.diff(gt.positions_xyz, axis=0), axis=1)
    assert np.all(step[40:44] == 0.0) and np.all(step[:39] > 0) and np.all(step[44:] > 0)


@pytest.mark.parametrize('scenario', ['street', 'table3'])
def test_simulate_bal(tmp_path: Path, scenario: str) -> None:
    """--format bal writes a problem read_bal accepts."""
    out = tmp_path / f'{scenario}.txt'
    assert main(['simulate', '--format', 'bal', '--scenario', scenario, '--keyframes', '8',
                 '--out', str(out)]) == 0
    problem = read_bal(out)
    assert problem.n_cams == (4 if scenario == 'table3' else 8)


def test_simulate_bad_scenario_is_one_error_line(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """A BAL-only scenario for a bag is refused with one error line."""
    assert main(['simulate', '--scenario', 'table3', '--out', str(tmp_path / 'x')]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('error: --scenario table3')


@pytest.mark.usefixtures('stub')
def test_replay_prints_table_and_outputs(sim_bag: Path, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """The replay verb prints the accuracy table and the output files."""
    out = tmp_path / 'out'
    assert main(['replay', str(sim_bag), '--out', str(out), '--gt',
                 str(sim_bag / 'groundtruth.tum')]) == 0
    text = capsys.readouterr().out
    assert 'ATE rmse (m)' in text and 'front-end' in text and 'optimized' in text
    assert f'outputs in {out}' in text and 'result.mcap' in text
    report = json.loads((out / 'report.json').read_text())
    assert report['keyframes_in'] == 20
    # RPE has its ratio as ATE has (a 2.7x RPE had read well beside an ATE ratio of 0.12),
    # and the keyframes out say how many were optimized (all of them had read 'optimized').
    acc = report['accuracy']
    assert acc['rpe_ratio'] == pytest.approx(acc['rpe_optimized'] / acc['rpe_frontend'])
    (rpe_line,) = [line for line in text.splitlines() if line.startswith('RPE rmse')]
    assert rpe_line.split()[-1] == f'{acc["rpe_ratio"]:.3f}'
    optimized = report['keyframes_out'] - report['keyframes_not_optimized']
    assert f'keyframes out: {report["keyframes_out"]} ({optimized} optimized)' in text


@pytest.mark.usefixtures('stub')
def test_replay_kitti_gt_needs_its_times(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """A KITTI ground truth without times is an error naming --gt-times; with them, all match.

    Before, 4 of 40 keyframes at 10 Hz met the pose numbers and an ATE was printed.
    """
    bag = tmp_path / 'street40'
    assert main(['simulate', '--keyframes', '40', '--out', str(bag)]) == 0
    gt = read_tum(bag / 'groundtruth.tum')
    kitti, times = tmp_path / 'gt.kitti', tmp_path / 'times.txt'
    np.savetxt(kitti, np.concatenate([gt.R_wc, gt.positions_xyz[:, :, None]], axis=2)
               .reshape(-1, 12))
    np.savetxt(times, gt.stamps_s)
    out = tmp_path / 'out'
    assert main(['replay', str(bag), '--out', str(out), '--gt', str(kitti), '--quiet']) == 1
    assert '--gt-times FILE' in capsys.readouterr().err
    assert main(['replay', str(bag), '--out', str(out), '--gt', str(kitti),
                 '--gt-times', str(times), '--quiet']) == 0
    report = json.loads((out / 'report.json').read_text())
    assert report['accuracy']['matched_frontend'] == 40 and report['warnings'] == []


def test_replay_keyframes_from_tracks_samples_the_pose_topic(sim_bag: Path,
                                                             tmp_path: Path) -> None:
    """--keyframes-from tracks: keyframes from the tracks, poses from the recorded pose topic.

    The simulated poses are stamped as the tracks, so the result is the default replay's; with
    a bag lacking the pose topic each keyframe is taken without a front-end pose.
    """
    outs = {}
    for name, extra in (('default', []), ('tracks', ['--keyframes-from', 'tracks'])):
        outs[name] = tmp_path / name
        assert main(['replay', str(sim_bag), '--out', str(outs[name]), '--quiet',
                     *extra]) == 0
    report = json.loads((outs['tracks'] / 'report.json').read_text())
    assert report['topics']['keyframes'] == '/keyframe_pose' and report['keyframes_out'] == 20
    a, b = (read_tum(outs[n] / 'keyframes_optimized.tum') for n in ('default', 'tracks'))
    np.testing.assert_allclose(b.positions_xyz, a.positions_xyz, atol=1e-6)
    assert len(read_tum(outs['tracks'] / 'keyframes_frontend.tum')) == 20
    assert main(['replay', str(sim_bag), '--out', str(tmp_path / 'none'), '--quiet',
                 '--keyframes-from', 'tracks', '--keyframes-topic', '/absent']) == 0
    frontend = (tmp_path / 'none' / 'keyframes_frontend.tum').read_text().splitlines()
    assert [line for line in frontend if not line.startswith('#')] == []


@pytest.mark.usefixtures('stub')
def test_replay_quiet_prints_nothing(sim_bag: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """--quiet is silent on success."""
    assert main(['replay', str(sim_bag), '--out', str(tmp_path / 'o'), '--quiet']) == 0
    captured = capsys.readouterr()
    assert captured.out == '' and captured.err == ''


@pytest.mark.usefixtures('stub')
@pytest.mark.parametrize(('extra', 'pattern'), [
    (['--tracks-topic', '/nope'], "tracks topic '/nope' is not in the bag"),
    (['--tracks-layout', 'named'], 'wrong --tracks-layout'),
    (['--tracks-layout', 'vins_mono'], 'wrong --tracks-layout'),
    (['--keyframes-type', 'pose_stamped'], "--keyframes-type 'pose_stamped'"),
    (['--intrinsics', '1,2,3'], '--intrinsics expects FX,FY,CX,CY'),
])
def test_replay_errors_are_one_line(sim_bag: Path, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str], extra: list[str],
                                    pattern: str) -> None:
    """Bad options or inputs give exit code 1 and exactly one 'error:' line."""
    code = main(['replay', str(sim_bag), '--out', str(tmp_path / 'o'), '--quiet', *extra])
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith('error: ') and pattern in err[0]


@pytest.mark.usefixtures('stub')
def test_replay_params_file_and_intrinsics(sim_bag: Path, tmp_path: Path) -> None:
    """--params supplies defaults; options override them; --intrinsics replaces CameraInfo."""
    params = tmp_path / 'p.yaml'
    params.write_text('pmba_node:\n  ros__parameters:\n    features_topic: /nope\n'
                      '    mode: global\n')
    out = tmp_path / 'o'
    assert main(['replay', str(sim_bag), '--out', str(out), '--params', str(params),
                 '--tracks-topic', 'features', '--intrinsics', '400,400,320,240',
                 '--quiet']) == 0
    report = json.loads((out / 'report.json').read_text())
    assert report['topics'] == {'tracks': '/features', 'keyframes': '/keyframe_pose'}


def test_replay_bad_params_file(sim_bag: Path, tmp_path: Path,
                                capsys: pytest.CaptureFixture[str]) -> None:
    """An invalid parameter value is one error line naming the file."""
    params = tmp_path / 'p.yaml'
    params.write_text('mode: fast\n')
    assert main(['replay', str(sim_bag), '--out', str(tmp_path / 'o'), '--params',
                 str(params)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f'error: --params {params}')


@pytest.mark.usefixtures('stub')
def test_replay_plot(sim_bag: Path, tmp_path: Path) -> None:
    """--plot writes the PNGs (top view, ATE per keyframe, cost, solve time)."""
    pytest.importorskip('matplotlib')
    out = tmp_path / 'o'
    assert main(['replay', str(sim_bag), '--out', str(out), '--gt',
                 str(sim_bag / 'groundtruth.tum'), '--plot', '--quiet']) == 0
    for name in ('trajectories_top.png', 'ate_per_keyframe.png', 'cost_per_solve.png',
                 'solve_time.png'):
        assert (out / name).stat().st_size > 1000


def test_plot_without_matplotlib_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """A missing matplotlib gives a PmbaError that says how to install it."""
    from pmba_ros import plot
    from pmba_ros.errors import PmbaError

    monkeypatch.setitem(sys.modules, 'matplotlib', None)
    with pytest.raises(PmbaError, match=r'--plot needs matplotlib.*pip install'):
        plot.pyplot()


def test_import_tracks_writes_kitti_bag(tmp_path: Path) -> None:
    """import-tracks turns the shared KITTI-00 tracks into a 77-keyframe bag with GT."""
    shared_file('kitti00_stereo_vo', 'VO_stereo_factors00s.txt')
    out = tmp_path / 'kitti'
    assert main(['import-tracks', '--out', str(out)]) == 0
    topics = list_topics([out])
    assert topics['/features'].count == 77
    assert topics['/groundtruth/pose'].count == 77
    assert (out / 'groundtruth.tum').exists()


def test_console_scripts_run_as_subprocesses(tmp_path: Path) -> None:
    """``python -m pmba_ros simulate`` and the pmba_bag_replay script work end to end."""
    bag = tmp_path / 'b.mcap'
    done = subprocess.run([sys.executable, '-m', 'pmba_ros', 'simulate', '--keyframes', '5',
                           '--out', str(bag)], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    script = Path(sys.executable).with_name('pmba_bag_replay')
    if not script.exists():
        pytest.skip('pmba_bag_replay script not installed')
    done = subprocess.run([str(script), str(tmp_path / 'missing.mcap'), '--out',
                           str(tmp_path / 'o')], capture_output=True, text=True, check=False)
    assert done.returncode == 1
    assert done.stderr.strip() == f'error: {tmp_path / "missing.mcap"}: no such bag'


@pytest.mark.usefixtures('stub')
def test_replay_without_bag_runs_the_default_street(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """No BAG: the default street is simulated into DIR/street_bag and evaluated."""
    out = tmp_path / 'demo'
    assert main(['replay', '--out', str(out)]) == 0
    text = capsys.readouterr().out
    assert 'simulated the default street (200 keyframes' in text
    assert 'ATE rmse (m)' in text
    assert (out / 'street_bag' / 'groundtruth.tum').exists()
    assert json.loads((out / 'report.json').read_text())['keyframes_in'] == 200


def test_wrong_layout_with_real_backend_is_one_error_line(
        sim_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The real back-end rejects mis-laid-out tracks silently; the verb prints one line."""
    code = main(['replay', str(sim_bag), '--out', str(tmp_path / 'o'), '--tracks-layout',
                 'vins_mono'])
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert 'wrong --tracks-layout' in err[0] and 'first error' in err[0]


def test_progress_bar_draws_and_finishes() -> None:
    """The progress bar redraws one line and ends it on close."""
    import io

    from pmba_ros.cli.replay import ProgressBar

    stream = io.StringIO()
    bar = ProgressBar(stream, width=10)
    bar(5, 10)
    bar(10, 10)
    bar.close()
    text = stream.getvalue()
    assert '[#####.....]  50.0% 5/10 messages' in text
    assert '[##########] 100.0% 10/10 messages' in text
    assert text.endswith('\n') and text.count('\n') == 1


@pytest.mark.slow
def test_sigterm_leaves_a_readable_result_bag(tmp_path: Path) -> None:
    """A replay killed with SIGTERM exits non-zero and leaves a finalized result.mcap."""
    import signal
    import time

    bag = tmp_path / 'street'
    # Long enough that the signal lands mid-run: the result bag's outputs grow with the run
    # (RESULT_GROWTH), so its first chunk can be flushed late in a short one.
    assert main(['simulate', '--keyframes', '1000', '--out', str(bag)]) == 0
    out = tmp_path / 'o'
    proc = subprocess.Popen([sys.executable, '-m', 'pmba_ros', 'replay', str(bag), '--out',
                             str(out), '--quiet'], stderr=subprocess.PIPE, text=True)
    # Signal once the writer has flushed a chunk of outputs (the start-up time of the
    # process, imports and the first compilation of the kernels included, varies a lot).
    deadline = time.monotonic() + 120

    def flushed() -> bool:
        return any(f.stat().st_size > 100_000 for f in out.glob('.result.mcap.partial/*.mcap'))

    while not (out / 'report.json').exists() and not flushed():
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip('the replay finished before the signal')
    assert proc.returncode == 130
    assert err.strip().splitlines()[-1] == 'error: interrupted'
    topics = list_topics([out / 'result.mcap'])
    assert 0 < topics['/pmba/path'].count < 1000
    assert json.loads((out / 'report.json').read_text())['complete'] is False


@pytest.mark.usefixtures('stub')
@pytest.mark.parametrize('frontend', sorted(PAIRINGS))
def test_front_end_recordings_replay_without_options(tmp_path: Path, frontend: str) -> None:
    """`simulate --frontend F` writes F's topics and layout; `replay` finds both by itself."""
    bag = tmp_path / 'bag'
    assert main(['simulate', '--frontend', frontend, '--keyframes', '12', '--out',
                 str(bag)]) == 0
    remap = dict(PAIRINGS[frontend]['remappings'])
    assert list_topics([bag])[remap['features']].msgtype == 'sensor_msgs/msg/PointCloud'
    assert main(['replay', str(bag), '--out', str(tmp_path / 'o'), '--quiet']) == 0
    report = json.loads((tmp_path / 'o' / 'report.json').read_text())
    assert report['topics']['tracks'] == remap['features']
    assert report['topics']['keyframes'] == remap['keyframe_pose']
    assert report['keyframes_out'] == 12 and report['messages_rejected'] == 0


def test_simulate_refuses_a_layout_the_front_end_does_not_publish(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--layout must agree with --frontend: one error line."""
    assert main(['simulate', '--frontend', 'openvins', '--layout', 'named', '--out',
                 str(tmp_path / 'b')]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ['error: --frontend openvins publishes layout per_point, not --layout named']
