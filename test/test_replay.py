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
"""Tests of pmba_ros.replay: outputs, determinism, bad inputs, and a small simulated replay."""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from pmba_ros import replay as replay_mod
from pmba_ros.backend.cameras import FrontendCameras
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.outputs import make_path, make_tf
from pmba_ros.backend.status import BackendStats
from pmba_ros.backend.tracks import parse_camera_info, parse_keyframe, parse_tracks
from pmba_ros.errors import BagError, EvaluationError, MessageError
from pmba_ros.eval.trajectory import read_tum, Trajectory, write_tum
from pmba_ros.io.bag_inputs import resolve_topic, stamp_ordered
from pmba_ros.io.bags import iter_messages, jazzy_typestore, list_topics
from pmba_ros.io.ply import read_ply
from pmba_ros.io.recorded_formats import PEEK_MESSAGES
from pmba_ros.replay import replay
from pmba_ros.sim.bag import groundtruth_path, write_sequence_bag
from pmba_ros.sim.sequence import simulate_sequence
import pytest

from .io.test_ros1_mcap import write_ros1_mcap


class StubLogic:
    """A stand-in back-end: parses inputs like the real one and echoes front-end poses.

    It has the attributes of :class:`~pmba_ros.backend.logic.BackendLogic` that the replay
    reads, and no solver.
    """

    def __init__(self, config: BackendConfig, backend: Any) -> None:
        """Keep the config and message backend."""
        self.config = config
        self.backend = backend
        self.poses: list[Any] = []
        self.pending: list[Any] = []
        self.stats = BackendStats()
        self.last_error = ''
        self.cameras = FrontendCameras(config)
        self.estimator = SimpleNamespace(state='collecting', last_message='')

    def on_camera_info(self, msg: Any) -> None:
        """Parse a CameraInfo."""
        parse_camera_info(msg)

    def on_tracks(self, msg: Any) -> None:
        """Parse tracks with the configured layout."""
        parse_tracks(msg, self.config.feature_layout)

    def on_tf(self, msg: Any) -> None:
        """Ignore transforms (the stub has no extrinsic)."""

    def on_extrinsic(self, msg: Any) -> None:
        """Ignore the front-end's extrinsic (the stub has none)."""

    def on_keyframe(self, msg: Any) -> None:
        """Queue a keyframe pose."""
        pose = parse_keyframe(msg, self.config.keyframe_type)
        self.poses.append(pose)
        self.pending.append(pose)

    def end_of_input(self) -> None:
        """Hold nothing back (the stub judges no stamps)."""

    def step(self) -> list[tuple[str, Any]]:
        """Emit a path and a TF per queued keyframe."""
        out = []
        for pose in self.pending:
            n = len(self.poses)
            out.append(('pmba/path', make_path(
                pose.stamp_ns, 'map', [p.position for p in self.poses],
                [p.quat_xyzw for p in self.poses], [p.stamp_ns for p in self.poses],
                self.backend)))
            out.append(('/tf', make_tf(pose.stamp_ns, 'map', 'odom', np.zeros(3),
                                       np.array([0, 0, 0, 1.0]), self.backend)))
            self.stats.solve_ms.append(1.0)
            self.stats.iterations.append(n % 3)
            self.stats.counters['keyframes'] += 1
        self.pending = []
        return out

    def frontend_trajectory(self) -> Trajectory:
        """Return the received poses."""
        from pmba_ros.core import so3
        return Trajectory(np.array([p.stamp_ns * 1e-9 for p in self.poses]),
                          np.array([p.position for p in self.poses]).reshape(-1, 3),
                          so3.from_quat_xyzw(np.array([p.quat_xyzw for p in self.poses])
                                             .reshape(-1, 4)))

    optimized_trajectory = frontend_trajectory

    def landmarks(self) -> np.ndarray:
        """Return no landmarks."""
        return np.zeros((0, 3))


def _recorded_paths(bag: Path) -> list[Any]:
    """Return the result bag's /pmba/path messages, in order."""
    from rosbags.rosbag2 import Reader

    ts = jazzy_typestore()
    with Reader(bag) as reader:
        return [ts.deserialize_cdr(raw, conn.msgtype) for conn, _, raw in reader.messages()
                if conn.topic == '/pmba/path']


@pytest.fixture
def stub(monkeypatch: pytest.MonkeyPatch) -> None:
    """Replace the back-end with :class:`StubLogic`."""
    monkeypatch.setattr(replay_mod, '_make_logic',
                        lambda config: StubLogic(config, _backend()))


def _backend() -> Any:
    from pmba_ros.backend.msg_backend import RosbagsBackend
    return RosbagsBackend(jazzy_typestore())


@pytest.fixture(scope='module')
def street_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Write a 60-keyframe simulated street bag (vins_fusion layout, the node's default)."""
    out = tmp_path_factory.mktemp('bags') / 'street'
    write_sequence_bag(simulate_sequence('street', n_keyframes=60, seed=0), out)
    return out


def test_resolve_topic() -> None:
    """Relative names resolve in the root namespace or a given one."""
    assert resolve_topic('pmba/path') == '/pmba/path'
    assert resolve_topic('/tf') == '/tf'
    assert resolve_topic('path', '/robot1/') == '/robot1/path'


def test_stamp_ordered_sorts_by_header_stamp_and_kind() -> None:
    """Out-of-order log times come out in stamp order; tracks before keyframes at a tie."""
    from pmba_ros.io.bags import BagMessage

    def msg(topic: str, stamp: int, log: int) -> BagMessage:
        header = SimpleNamespace(stamp=SimpleNamespace(sec=0, nanosec=stamp))
        return BagMessage(topic, '', log, SimpleNamespace(header=header))

    stream = [msg('/kf', 10, 30), msg('/tr', 20, 31), msg('/tr', 10, 32), msg('/kf', 20, 50)]
    got = [(s, k) for s, k, _ in stamp_ordered(stream, {'/kf': 'keyframe', '/tr': 'tracks'})]
    assert got == [(10, 'tracks'), (10, 'keyframe'), (20, 'tracks'), (20, 'keyframe')]


@pytest.mark.usefixtures('stub')
def test_replay_writes_all_outputs(street_bag: Path, tmp_path: Path) -> None:
    """The output folder holds a readable result bag, TUM files, PLY and the report."""
    out = tmp_path / 'out'
    report = replay([street_bag], out, gt=groundtruth_path(street_bag))
    assert report.complete
    assert report.keyframes_in == 60
    assert report.messages_in == 180
    topics = list_topics([out / 'result.mcap'])
    assert topics['/tf'].count == 60 and topics['/tf'].msgtype == 'tf2_msgs/msg/TFMessage'
    # The paths, each holding the run so far, from 5 % of growth to 5 %, and the last.
    paths = _recorded_paths(out / 'result.mcap')
    assert len(paths) == topics['/pmba/path'].count and 30 <= len(paths) < 60
    sizes = [len(p.poses) for p in paths]
    assert sizes[:20] == list(range(1, 21)) and sizes[-1] == 60
    assert all(b >= 1.05 * a for a, b in itertools.pairwise(sizes[19:-1]))
    assert len(read_tum(out / 'keyframes_frontend.tum')) == 60
    points, _ = read_ply(out / 'landmarks.ply')
    assert points.shape == (0, 3)
    data = json.loads((out / 'report.json').read_text())
    for key in ('keyframes_in', 'keyframes_out', 'messages_rejected', 'solve_ms', 'iterations'):
        assert key in data
    acc = data['accuracy']
    for key in ('ate_frontend_m', 'ate_optimized_m', 'rpe_frontend', 'rpe_optimized',
                'alignment', 'ate_ratio'):
        assert key in acc
    assert acc['ate_ratio'] == pytest.approx(1.0)


@pytest.mark.usefixtures('stub')
def test_empty_tracks_topic_is_a_warning(street_bag: Path, tmp_path: Path) -> None:
    """A tracks topic recorded without a message: the front-end's poses, and a warning."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    typestore = jazzy_typestore()
    bag = tmp_path / 'no_tracks'
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {'/features': writer.add_connection('/features', 'sensor_msgs/msg/PointCloud',
                                                    typestore=typestore)}
        for m in iter_messages([street_bag], topics=['/keyframe_pose']):
            conn = conns.get(m.topic) or writer.add_connection(m.topic, m.msgtype,
                                                               typestore=typestore)
            conns[m.topic] = conn
            writer.write(conn, m.log_time_ns, typestore.serialize_cdr(m.msg, m.msgtype))
    report = replay([bag], tmp_path / 'o')
    assert report.complete and report.keyframes_in == 60
    assert "no tracks message on '/features': nothing was optimized" in report.warnings[-1]


@pytest.mark.usefixtures('stub')
def test_missing_topic_is_one_bag_error(street_bag: Path, tmp_path: Path) -> None:
    """A tracks topic that is not recorded names the topic and what is recorded."""
    config = BackendConfig(features_topic='/feature_tracker/feature')
    with pytest.raises(BagError, match=r"tracks topic '/feature_tracker/feature' is not in "
                                       r'the bag \(recorded: /camera_info'):
        replay([street_bag], tmp_path / 'o', config)


@pytest.mark.usefixtures('stub')
@pytest.mark.parametrize('layout', ['named', 'vins_mono', 'per_point'])
def test_tracks_are_read_in_the_recorded_layout(street_bag: Path, tmp_path: Path,
                                                layout: str) -> None:
    """A layout that cannot read the recording gives way to the one that can, with a warning."""
    report = replay([street_bag], tmp_path / 'o', BackendConfig(feature_layout=layout))
    assert report.complete and report.messages_rejected == 0 and report.keyframes_out == 60
    assert f"tracks are not in layout {layout!r} but in 'vins_fusion'" in report.warnings[0]


@pytest.mark.usefixtures('stub')
def test_chosen_layout_of_another_type_is_one_message_error(street_bag: Path,
                                                            tmp_path: Path) -> None:
    """A PointCloud topic replayed as the chosen 'named' (PointCloud2) is refused first."""
    config = BackendConfig(feature_layout='named')
    with pytest.raises(MessageError, match='wrong --tracks-layout'):
        replay([street_bag], tmp_path / 'o', config, chosen={'feature_layout'})


@pytest.mark.usefixtures('stub')
def test_chosen_layout_channels_is_one_message_error(street_bag: Path, tmp_path: Path) -> None:
    """VINS-Fusion tracks read as the chosen VINS-Mono: all rejected, one error, a result bag."""
    config = BackendConfig(feature_layout='vins_mono')
    out = tmp_path / 'o'
    with pytest.raises(MessageError, match=r'tracks messages rejected and none accepted '
                                           r'\(wrong --tracks-layout\?\); first error'):
        replay([street_bag], out, config, chosen={'feature_layout'})
    assert sum(1 for _ in iter_messages([out / 'result.mcap'])) >= 0
    report = json.loads((out / 'report.json').read_text())
    assert report['complete'] is False
    assert 'wrong --tracks-layout' in report['error']


@pytest.mark.usefixtures('stub')
def test_truncated_bag_is_one_bag_error(street_bag: Path, tmp_path: Path) -> None:
    """Half a recording gives a BagError."""
    storage = street_bag / 'street.mcap'
    bad = tmp_path / 'half.mcap'
    bad.write_bytes(storage.read_bytes()[: storage.stat().st_size // 2])
    with pytest.raises(BagError, match=r'half\.mcap: cannot open bag'):
        replay([bad], tmp_path / 'o')


@pytest.mark.usefixtures('stub')
def test_gt_without_overlap_is_one_evaluation_error(street_bag: Path, tmp_path: Path) -> None:
    """Ground truth whose stamps miss every keyframe is an EvaluationError; outputs stay."""
    gt = read_tum(groundtruth_path(street_bag))
    shifted = tmp_path / 'shifted.tum'
    write_tum(shifted, Trajectory(gt.stamps_s + 1000.0, gt.positions_xyz, gt.R_wc))
    out = tmp_path / 'o'
    with pytest.raises(EvaluationError, match='ground truth vs frontend keyframes'):
        replay([street_bag], out, gt=shifted)
    assert len(read_tum(out / 'keyframes_optimized.tum')) == 60
    assert len(_recorded_paths(out / 'result.mcap')[-1].poses) == 60


@pytest.mark.usefixtures('stub')
def test_gt_repeating_stamps_is_a_warning(street_bag: Path, tmp_path: Path) -> None:
    """Ground truth whose every pose is written twice: counted in a warning, as evaluate does.

    Before, the replay's accuracy block matched each keyframe with its stamp's poses and said
    nothing of the repeats.
    """
    gt = read_tum(groundtruth_path(street_bag))
    twice = tmp_path / 'twice.tum'
    write_tum(twice, Trajectory(np.repeat(gt.stamps_s, 2), np.repeat(gt.positions_xyz, 2, 0),
                                np.repeat(gt.R_wc, 2, 0)))
    report = replay([street_bag], tmp_path / 'o', gt=twice)
    text = (f'{len(gt)} of the {2 * len(gt)} ground-truth poses repeat the stamp of an earlier '
            f'pose (distinct stamps: {len(gt)})')
    assert any(w.startswith(text) for w in report.warnings)
    assert not any('front-end keyframe poses repeat' in w for w in report.warnings)


@pytest.mark.usefixtures('stub')
def test_interrupted_replay_leaves_valid_result_bag(street_bag: Path, tmp_path: Path) -> None:
    """An interrupt mid-replay still finalizes result.mcap with what was written."""
    calls = {'n': 0}

    def progress(done: int, total: int) -> None:
        calls['n'] += 1
        if done == 90:
            raise KeyboardInterrupt

    out = tmp_path / 'o'
    with pytest.raises(KeyboardInterrupt):
        replay([street_bag], out, progress=progress)
    n = list_topics([out / 'result.mcap'])['/pmba/path'].count
    assert 0 < n < 60
    assert json.loads((out / 'report.json').read_text())['complete'] is False


# --- the real back-end -------------------------------------------------------------------


@pytest.fixture(scope='module')
def real_replay(street_bag: Path, tmp_path_factory: pytest.TempPathFactory,
                ) -> tuple[Path, replay_mod.ReplayReport]:
    """One replay of the 60-keyframe street with the real back-end."""
    out = tmp_path_factory.mktemp('real') / 'a'
    return out, replay([street_bag], out, gt=groundtruth_path(street_bag))


def test_an_initialization_that_never_succeeds_is_said(
        street_bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every attempt failing: the front-end's poses out, and a warning naming the attempts.

    Before, the replay exited 0 in silence, printing 'optimized keyframes: 60'.
    """
    from pmba_ros.errors import InitError
    from pmba_ros.init import pipeline

    def fail(*_: Any, **__: Any) -> None:
        raise InitError('no EG pair could be estimated')

    monkeypatch.setattr(pipeline, 'global_init', fail)
    report = replay([street_bag], tmp_path / 'o')
    assert report.keyframes_out == report.keyframes_not_optimized == 60
    (warning,) = [w for w in report.warnings if 'initialization never succeeded' in w]
    assert f'({report.counters["init_attempts"]} attempts)' in warning
    assert 'no EG pair could be estimated' in warning


@pytest.mark.parametrize('focal', [1e-300, 1.0])
def test_an_initialization_that_never_starts_is_said(street_bag: Path, tmp_path: Path,
                                                     focal: float) -> None:
    """A focal length that is no camera's puts the parallax gate out of reach: said, not a crash.

    Before, 1e-300 px failed every keyframe with a ZeroDivisionError (fx * fy underflowed),
    and 1 px (normalized coordinates given as pixels) ended with nothing optimized, in silence.
    """
    report = replay([street_bag], tmp_path / 'o', intrinsics=(focal, focal, 0.0, 0.0))
    assert report.counters.get('internal_errors', 0) == 0
    assert report.keyframes_out == report.keyframes_not_optimized == 60
    (warning,) = [w for w in report.warnings if 'initialization never started' in w]
    assert f' deg at {focal:.4g} px focal length' in warning


def test_small_simulated_replay_improves_on_frontend(
        real_replay: tuple[Path, replay_mod.ReplayReport]) -> None:
    """60 simulated keyframes: the optimized ATE is below the front-end's."""
    _, report = real_replay
    assert report.complete
    assert report.messages_rejected == 0
    assert report.keyframes_in == 60
    assert report.accuracy is not None
    assert report.accuracy['ate_optimized_m'] < report.accuracy['ate_frontend_m']
    assert len(report.solve_ms) > 0
    assert len(report.iterations) == len(report.solve_ms)


def test_report_gives_the_measured_noise(
        real_replay: tuple[Path, replay_mod.ReplayReport]) -> None:
    """The tracks' pixel noise (simulated: 0.5 px) and the front-end's factors, in report.json."""
    out, _ = real_replay
    noise = json.loads((out / 'report.json').read_text())['measured_noise']
    assert noise['tracks_px'] == pytest.approx(0.5, rel=0.15)
    # The simulator's default front-end is within the parameters' sigmas: its single steps
    # scatter less (the step-change factors weigh that in).
    assert noise['frontend_factors'] == [1.0, 1.0, 1.0]
    assert 0.1 < min(noise['frontend_white']) and max(noise['frontend_white']) < 0.9


def test_replay_twice_gives_identical_tum_bytes(
        real_replay: tuple[Path, replay_mod.ReplayReport], street_bag: Path,
        tmp_path: Path) -> None:
    """Deterministic replay: same bag, same TUM and PLY bytes."""
    a, _ = real_replay
    b = tmp_path / 'b'
    replay([street_bag], b, gt=groundtruth_path(street_bag))
    for name in ('keyframes_frontend.tum', 'keyframes_optimized.tum', 'landmarks.ply'):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_ros1_recording_replays_like_the_rosbag2_one(
        real_replay: tuple[Path, replay_mod.ReplayReport], street_bag: Path, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The street converted to ROS 1 (as VINS-Mono records): same trajectory, same map.

    Its tracks take the vectorized ROS 1 decoder, not rosbags' per-point one.
    """
    from pmba_ros.io import cloud_decode
    from rosbags.convert.converter import convert
    from rosbags.typesys import get_typestore, Stores

    ros1 = tmp_path / 'street.bag'
    convert([street_bag], ros1, 'sqlite3', 9, None, 'file', None,
            get_typestore(Stores.ROS1_NOETIC), [], [], [], [])
    decoded: list[bool] = []
    decode = cloud_decode.decode_point_cloud

    def spy(raw: Any, typestore: Any, *, ros1: bool = False) -> Any:
        decoded.append(ros1)
        return decode(raw, typestore, ros1=ros1)

    monkeypatch.setattr(cloud_decode, 'decode_point_cloud', spy)
    out = tmp_path / 'o'
    report = replay([ros1], out, gt=groundtruth_path(street_bag))
    assert report.complete and report.messages_rejected == 0
    # Every keyframe's tracks once, and the first ones again where the replay checks their layout.
    peeked = min(PEEK_MESSAGES, report.keyframes_in)
    assert decoded and all(decoded) and len(decoded) == report.keyframes_in + peeked
    a, _ = real_replay
    for name in ('keyframes_frontend.tum', 'keyframes_optimized.tum', 'landmarks.ply'):
        assert (out / name).read_bytes() == (a / name).read_bytes(), name
    # The same in MCAP, as `mcap convert street.bag street.mcap` writes it (ROS 1 messages).
    mcap, out = tmp_path / 'street.mcap', tmp_path / 'm'
    write_ros1_mcap(ros1, mcap)
    report = replay([mcap], out, gt=groundtruth_path(street_bag))
    assert report.input_complete and not report.damaged_parts and report.messages_rejected == 0
    for name in ('keyframes_frontend.tum', 'keyframes_optimized.tum', 'landmarks.ply'):
        assert (out / name).read_bytes() == (a / name).read_bytes(), name


def test_keyframe_poses_with_covariance_replay_as_odometry(
        real_replay: tuple[Path, replay_mod.ReplayReport], street_bag: Path,
        tmp_path: Path) -> None:
    """Keyframe poses as PoseWithCovarianceStamped (ROVIO's pose output) replay as Odometry.

    The recorded type is read (with its covariance), and the trajectory is the Odometry
    recording's. Before, the replay refused the topic's type (no keyframe kind read it).
    """
    from pmba_ros.io.bag_writer import open_writer

    bag = tmp_path / 'pwcs.mcap'
    backend = _backend()
    with open_writer(bag) as writer:
        for m in iter_messages([street_bag]):
            msg = m.msg
            if m.topic == '/keyframe_pose':
                msg = backend.new('geometry_msgs/msg/PoseWithCovarianceStamped',
                                  header=msg.header, pose=msg.pose)
            writer.write(m.topic, msg, m.log_time_ns)
    report = replay([bag], tmp_path / 'o', gt=groundtruth_path(street_bag))
    assert report.input_complete and report.messages_rejected == 0
    assert any("keyframe_type 'pose_with_covariance'" in w for w in report.warnings)
    a, _ = real_replay
    assert (tmp_path / 'o' / 'keyframes_optimized.tum').read_bytes() == (
        a / 'keyframes_optimized.tum').read_bytes()


def test_result_bag_deserializes_with_jazzy_and_mcap_ros2(
        real_replay: tuple[Path, replay_mod.ReplayReport]) -> None:
    """Every result message deserializes with the Jazzy typestore and with mcap_ros2."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.rosbag2 import Reader

    out, report = real_replay
    ts = jazzy_typestore()
    counts: dict[str, int] = {}
    with Reader(out / 'result.mcap') as reader:
        for conn, _, raw in reader.messages():
            ts.deserialize_cdr(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    assert {'/pmba/path', '/pmba/keyframes', '/pmba/landmarks', '/pmba/odometry', '/tf',
            '/diagnostics'} <= set(counts)
    assert sum(counts.values()) == report.messages_out
    with (out / 'result.mcap').open('rb') as stream:
        n = sum(1 for _ in make_reader(stream, decoder_factories=[DecoderFactory()])
                .iter_decoded_messages())
    assert n == report.messages_out


@pytest.mark.slow
def test_street_200_optimized_ate_at_most_30_percent_of_frontend(tmp_path: Path) -> None:
    """Acceptance: on the 200-keyframe default street the optimized ATE is at most 30 %."""
    bag = tmp_path / 'street'
    write_sequence_bag(simulate_sequence('street', n_keyframes=200, seed=0), bag)
    report = replay([bag], tmp_path / 'o', gt=groundtruth_path(bag))
    assert report.accuracy is not None
    assert report.accuracy['ate_optimized_m'] <= 0.3 * report.accuracy['ate_frontend_m']


@pytest.mark.slow
def test_kitti00_replay_reports_both_ates(tmp_path: Path) -> None:
    """KITTI-00 tracks: front-end and optimized ATE against the KITTI ground truth."""
    from pmba_ros.eval.trajectory import read_kitti
    from pmba_ros.io.kitti_tracks import kitti_sequence, read_kitti_tracks

    from .conftest import shared_file

    tracks = read_kitti_tracks(shared_file('kitti00_stereo_vo'))
    times = np.loadtxt(shared_file('trajectories', 'evo', 'KITTI_00_gt_times.txt'))
    gt = read_kitti(shared_file('trajectories', 'evo', 'KITTI_00_gt.txt'), times)
    bag = tmp_path / 'kitti'
    write_sequence_bag(kitti_sequence(tracks, times, gt), bag)
    report = replay([bag], tmp_path / 'o', gt=groundtruth_path(bag))
    assert report.accuracy is not None
    assert report.accuracy['matched_optimized'] == 77
    assert 0.0 < report.accuracy['ate_frontend_m'] < 1.0
    assert 0.0 < report.accuracy['ate_optimized_m'] < 1.0


@pytest.mark.usefixtures('stub')
def test_several_bags_are_merged_in_time(street_bag: Path, tmp_path: Path) -> None:
    """Tracks and keyframe poses recorded into two bags replay like one bag."""
    from pmba_ros.io.bag_writer import open_writer

    first, second = tmp_path / 'tracks.mcap', tmp_path / 'poses.mcap'
    with open_writer(first) as a, open_writer(second) as b:
        for message in iter_messages([street_bag]):
            target = b if message.topic == '/keyframe_pose' else a
            target.write(message.topic, message.msg, message.log_time_ns)
    merged = replay([first, second], tmp_path / 'm')
    single = replay([street_bag], tmp_path / 's')
    assert merged.keyframes_in == single.keyframes_in == 60
    assert ((tmp_path / 'm' / 'keyframes_frontend.tum').read_bytes()
            == (tmp_path / 's' / 'keyframes_frontend.tum').read_bytes())


def test_no_optimized_keyframes_reports_frontend_only(street_bag: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """A back-end that never initializes gives front-end accuracy and empty optimized fields."""
    class Uninitialized(StubLogic):
        def optimized_trajectory(self) -> Trajectory:
            return Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3)))

    monkeypatch.setattr(replay_mod, '_make_logic',
                        lambda config: Uninitialized(config, _backend()))
    report = replay([street_bag], tmp_path / 'o', gt=groundtruth_path(street_bag))
    assert report.accuracy is not None
    assert report.accuracy['ate_frontend_m'] > 0
    assert report.accuracy['ate_optimized_m'] is None
    assert report.accuracy['ate_ratio'] is None
    assert report.keyframes_out == 0
    lines = (tmp_path / 'o' / 'keyframes_optimized.tum').read_text().splitlines()
    assert lines == ['# timestamp tx ty tz qx qy qz qw']
