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
"""Replay of a body-pose recording: the extrinsic comes from the bag's /tf_static."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from pmba_ros.core import so3
from pmba_ros.eval.metrics import ate
from pmba_ros.eval.trajectory import read_tum
from pmba_ros.io.bag_writer import open_writer
from pmba_ros.io.bags import iter_messages, list_topics
from pmba_ros.replay import replay
from pmba_ros.sim.bag import EUROC_CAM0, groundtruth_path, write_sequence_bag
from pmba_ros.sim.sequence import simulate_sequence


def test_body_pose_bag_replays_to_body_poses(tmp_path: Path) -> None:
    """EuRoC-like cam0 on /tf_static: every keyframe out as a body pose, better than odom."""
    seq = simulate_sequence('street', n_keyframes=60, seed=2)
    bag = tmp_path / 'bag'
    write_sequence_bag(seq, bag, extrinsic=EUROC_CAM0)
    topics = list_topics([bag])
    assert topics['/tf_static'].msgtype == 'tf2_msgs/msg/TFMessage'
    gt = read_tum(groundtruth_path(bag))
    R_b = seq.R_wc_gt @ EUROC_CAM0.rotation.T  # the ground truth is the body's
    np.testing.assert_allclose(gt.R_wc, R_b, atol=1e-6)

    report = replay([bag], tmp_path / 'out', gt=groundtruth_path(bag))
    data = json.loads((tmp_path / 'out' / 'report.json').read_text())
    assert data['extrinsic']['source'] == 'tf'
    np.testing.assert_allclose(data['extrinsic']['body_to_camera'], EUROC_CAM0.to_flat(),
                               atol=1e-8)
    assert report.keyframes_out == 60 and data['keyframes_not_optimized'] == 0
    assert report.accuracy is not None
    assert report.accuracy['ate_optimized_m'] < 0.5 * report.accuracy['ate_frontend_m']
    optimized = read_tum(tmp_path / 'out' / 'keyframes_optimized.tum')
    result = ate(optimized, gt, 'sim3')
    rel = np.einsum('nji,njk->nik', result.rotation @ optimized.R_wc, gt.R_wc)
    assert np.rad2deg(np.linalg.norm(so3.log(rel), axis=1).max()) < 2.0


def test_pure_rotation_replay_passes_the_front_end_through(tmp_path: Path) -> None:
    """No baseline: no initialization, every keyframe at its front-end pose.

    The evaluation falls back to a first-pose alignment with a note instead of failing.
    """
    seq = simulate_sequence('rotation', n_keyframes=40, seed=0)
    bag = tmp_path / 'bag'
    write_sequence_bag(seq, bag)
    report = replay([bag], tmp_path / 'out', gt=groundtruth_path(bag))
    assert report.complete and report.keyframes_out == 40
    assert report.keyframes_not_optimized == 40
    assert report.accuracy is not None
    assert any('aligned by the first pose' in note for note in report.accuracy['notes'])
    assert report.accuracy['ate_optimized_m'] == report.accuracy['ate_frontend_m']


def test_static_transform_recorded_after_the_first_keyframe_is_used(tmp_path: Path) -> None:
    """/tf_static logged and stamped a second into the run still gives the extrinsic.

    It holds at every time; before, the extrinsic was fixed at the first keyframe pose as
    the identity (with no warning) and the run's RPE tripled.
    """
    seq = simulate_sequence('street', n_keyframes=30, seed=2)
    bag = tmp_path / 'bag'
    write_sequence_bag(seq, bag, extrinsic=EUROC_CAM0)
    late = tmp_path / 'late.mcap'
    messages = list(iter_messages([bag]))
    shift = 1_000_000_000
    with open_writer(late) as writer:
        for m in sorted(messages, key=lambda m: m.log_time_ns + shift * (m.topic == '/tf_static')):
            if m.topic == '/tf_static':
                for transform in m.msg.transforms:
                    transform.header.stamp.sec += 1
                writer.write(m.topic, m.msg, m.log_time_ns + shift)
            else:
                writer.write(m.topic, m.msg, m.log_time_ns)
    replay([late], tmp_path / 'out')
    data = json.loads((tmp_path / 'out' / 'report.json').read_text())
    assert data['extrinsic']['source'] == 'tf'
    np.testing.assert_allclose(data['extrinsic']['body_to_camera'], EUROC_CAM0.to_flat(),
                               atol=1e-8)
    assert 'extrinsic_unknown' not in data['counters']


def test_a_vins_recording_gives_its_extrinsic_on_its_own_topic(tmp_path: Path) -> None:
    """VINS' keyframe poses name no body frame: the extrinsic comes from its topic.

    VINS stamps it with its newest frame; here all of them are stamped and logged two
    seconds later still (a front-end that publishes it late), after the first 20 keyframes
    in stamp order: the first message is still the run's extrinsic. The result is the TF
    recording's.
    """
    from pmba_ros.backend.config import BackendConfig
    from pmba_ros.sim.bag import SimTopics

    seq = simulate_sequence('street', n_keyframes=30, seed=2)
    vins, tf_only, late = tmp_path / 'vins', tmp_path / 'tf', tmp_path / 'late.mcap'
    topic = '/vins_estimator/extrinsic'
    write_sequence_bag(seq, vins, extrinsic=EUROC_CAM0, layout='per_point',
                       topics=SimTopics(extrinsic=topic))
    write_sequence_bag(seq, tf_only, extrinsic=EUROC_CAM0, layout='per_point')
    assert all(m.msg.child_frame_id == ''
               for m in iter_messages([vins], topics=['/keyframe_pose']))
    with open_writer(late) as writer:
        for m in iter_messages([vins]):
            late_s = 2 if m.topic == topic else 0
            if late_s:
                m.msg.header.stamp.sec += late_s
            writer.write(m.topic, m.msg, m.log_time_ns + late_s * 10**9)
    config = BackendConfig(feature_layout='per_point', extrinsic_topic=topic)
    replay([late], tmp_path / 'out', config)
    replay([tf_only], tmp_path / 'out_tf', BackendConfig(feature_layout='per_point'))
    data = json.loads((tmp_path / 'out' / 'report.json').read_text())
    assert data['extrinsic']['source'] == 'extrinsic_topic'
    assert data['topics']['extrinsic'] == topic
    np.testing.assert_allclose(data['extrinsic']['body_to_camera'], EUROC_CAM0.to_flat(),
                               atol=1e-8)
    assert 'extrinsic_unknown' not in data['counters']
    assert (tmp_path / 'out' / 'keyframes_optimized.tum').read_bytes() == (
        tmp_path / 'out_tf' / 'keyframes_optimized.tum').read_bytes()


def test_an_online_calibration_converging_is_used_where_it_settled(tmp_path: Path) -> None:
    """VINS estimating its extrinsic: the recording's settled value, not its first guess.

    The extrinsic topic starts 1.5 degrees and 7 cm off and converges over the first third
    of the run (``estimate_extrinsic``); the replay uses where it settled, says so, and ends
    where the recording with the right extrinsic throughout does. Before, the first guess
    was fixed for the whole run, in silence (RPE 2.08x the front-end's on an 80-keyframe
    VINS-Fusion street whose calibration converged over 3 s; here 0.437x against 0.434x).
    """
    from pmba_ros.backend import outputs as out
    from pmba_ros.backend.config import BackendConfig
    from pmba_ros.backend.extrinsics import Rigid
    from pmba_ros.backend.msg_backend import RosbagsBackend
    from pmba_ros.backend.tracks import stamp_of
    from pmba_ros.io.bags import jazzy_typestore
    from pmba_ros.sim.bag import SimTopics

    seq = simulate_sequence('street', n_keyframes=60, seed=1)
    vins, online = tmp_path / 'vins', tmp_path / 'online.mcap'
    topic = '/vins_estimator/extrinsic'
    write_sequence_bag(seq, vins, extrinsic=EUROC_CAM0, layout='per_point',
                       topics=SimTopics(extrinsic=topic))
    backend = RosbagsBackend(jazzy_typestore())
    n = sum(m.topic == topic for m in iter_messages([vins]))
    done = 0
    with open_writer(online) as writer:
        for m in iter_messages([vins]):
            if m.topic == topic:
                share, done = max(0.0, 1.0 - 3.0 * done / n), done + 1
                off = Rigid(so3.exp(np.array([0.0, 0.0, np.deg2rad(1.5) * share])),
                            EUROC_CAM0.translation * (1.0 - share))
                T = Rigid(EUROC_CAM0.rotation @ off.rotation, off.translation)
                m = m._replace(msg=out.make_odometry(
                    stamp_of(m.msg), 'world', '', T.translation, so3.to_quat_xyzw(T.rotation),
                    np.eye(6) * 1e-6, backend))
            writer.write(m.topic, m.msg, m.log_time_ns)
    config = BackendConfig(feature_layout='per_point', extrinsic_topic=topic)
    report = replay([online], tmp_path / 'out', config, gt=groundtruth_path(vins))
    right = replay([vins], tmp_path / 'right', config, gt=groundtruth_path(vins))
    assert any('moved by' in w and 'settled' in w for w in report.warnings), report.warnings
    assert report.complete and not any('damaged' in w for w in report.warnings)
    data = json.loads((tmp_path / 'out' / 'report.json').read_text())
    np.testing.assert_allclose(data['extrinsic']['body_to_camera'], EUROC_CAM0.to_flat(),
                               atol=1e-8)
    assert 'extrinsic_changes' not in data['counters']
    assert report.accuracy is not None and right.accuracy is not None
    assert report.accuracy['rpe_optimized'] <= 1.05 * right.accuracy['rpe_optimized']
    assert not any('moved by' in w for w in right.warnings)


def test_an_extrinsic_topic_of_another_type_is_a_warning(tmp_path: Path) -> None:
    """A recorded 'extrinsic' topic that is not a pose is named in a warning and not read."""
    from pmba_ros.backend.msg_backend import RosbagsBackend
    from pmba_ros.io.bags import jazzy_typestore
    from pmba_ros.sim.inputs import make_camera_info

    seq = simulate_sequence('street', n_keyframes=30, seed=2)
    bag, mixed = tmp_path / 'bag', tmp_path / 'mixed.mcap'
    write_sequence_bag(seq, bag, extrinsic=EUROC_CAM0)
    backend = RosbagsBackend(jazzy_typestore())
    with open_writer(mixed) as writer:
        for m in iter_messages([bag]):
            writer.write(m.topic, m.msg, m.log_time_ns)
        writer.write('/extrinsic', make_camera_info(0, 'camera', seq.camera, backend), 1)
    report = replay([mixed], tmp_path / 'out')
    assert any("extrinsic topic '/extrinsic' has type sensor_msgs/msg/CameraInfo" in w
               for w in report.warnings), report.warnings
    data = json.loads((tmp_path / 'out' / 'report.json').read_text())
    assert data['extrinsic']['source'] == 'tf' and 'extrinsic' not in data['topics']
    assert report.keyframes_out == 30
