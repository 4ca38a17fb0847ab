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
"""Tests of pmba_ros.sim.bag: simulated front-end recordings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pmba_ros.backend.tracks import parse_keyframe, parse_tracks
from pmba_ros.backend.types import CameraModel
from pmba_ros.errors import BagError
from pmba_ros.eval.trajectory import read_tum
from pmba_ros.io.bags import iter_messages, list_topics
from pmba_ros.sim.bag import groundtruth_path, SimTopics, write_sequence_bag
from pmba_ros.sim.sequence import SimSequence, simulate_sequence
import pytest


@pytest.fixture(scope='module')
def sequence() -> SimSequence:
    """Return a short simulated street."""
    return simulate_sequence('street', n_keyframes=12, seed=3)


@pytest.mark.parametrize('layout', ['vins_mono', 'vins_fusion', 'per_point', 'named'])
def test_bag_round_trips_tracks_and_poses(tmp_path: Path, sequence: SimSequence,
                                          layout: str) -> None:
    """Every layout parses back to the simulated observations; poses and GT are exact."""
    out = tmp_path / 'bag'
    info = write_sequence_bag(sequence, out, layout=layout)
    topics = list_topics([out])
    want_type = ('sensor_msgs/msg/PointCloud2' if layout == 'named'
                 else 'sensor_msgs/msg/PointCloud')
    t = SimTopics()
    assert topics[t.tracks].msgtype == want_type
    assert topics[t.keyframes].msgtype == 'nav_msgs/msg/Odometry'
    assert topics[t.camera_info].msgtype == 'sensor_msgs/msg/CameraInfo'
    assert topics[t.groundtruth].msgtype == 'geometry_msgs/msg/PoseStamped'
    assert {i.count for i in topics.values()} == {12}
    frames = [parse_tracks(m.msg, layout) for m in iter_messages([out], [t.tracks])]
    for got, want in zip(frames, sequence.frames, strict=True):
        np.testing.assert_array_equal(got.feature_ids, want.feature_ids)
        assert got.pixels is not None and want.pixels is not None
        np.testing.assert_allclose(got.pixels, want.pixels, atol=1e-3)
    poses = [parse_keyframe(m.msg) for m in iter_messages([out], [t.keyframes])]
    np.testing.assert_allclose([p.position for p in poses], sequence.centers_odom, atol=1e-12)
    assert [p.stamp_ns for p in poses] == sequence.stamps_ns.tolist()
    cams = [CameraModel.from_camera_info(m.msg) for m in iter_messages([out], [t.camera_info])]
    assert cams[0].fx == sequence.camera.fx
    assert cams[0].distortion_model == sequence.camera.distortion_model
    gt = read_tum(info.groundtruth_tum)
    np.testing.assert_allclose(gt.positions_xyz, sequence.centers_gt, atol=1e-6)
    assert info.n_messages == 48


def test_log_times_lag_header_stamps(tmp_path: Path, sequence: SimSequence) -> None:
    """Keyframe poses are logged after their tracks, like a real estimator's output."""
    out = tmp_path / 'b.mcap'
    write_sequence_bag(sequence, out)
    for message in iter_messages([out], [SimTopics().keyframes]):
        stamp = message.msg.header.stamp
        assert message.log_time_ns > stamp.sec * 10**9 + stamp.nanosec
    assert groundtruth_path(out) == tmp_path / 'b_groundtruth.tum'
    assert groundtruth_path(out).exists()


def test_bag_reads_with_mcap_ros2(tmp_path: Path, sequence: SimSequence) -> None:
    """The recording decodes without rosbags (mcap + mcap_ros2)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out = tmp_path / 'bag'
    write_sequence_bag(sequence, out, layout='vins_fusion')
    with (out / 'bag.mcap').open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        counts: dict[str, int] = {}
        for _, channel, _, msg in reader.iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == '/features':
                frame = parse_tracks(msg, 'vins_fusion')
                assert len(frame) > 0
    assert counts == dict.fromkeys(['/camera_info', '/groundtruth/pose', '/features',
                                    '/keyframe_pose'], 12)


def test_same_sequence_gives_identical_bytes(tmp_path: Path, sequence: SimSequence) -> None:
    """Writing twice gives the same MCAP and TUM bytes."""
    a, b = tmp_path / 'a' / 'bag.mcap', tmp_path / 'b' / 'bag.mcap'
    write_sequence_bag(sequence, a)
    write_sequence_bag(sequence, b)
    assert a.read_bytes() == b.read_bytes()
    assert groundtruth_path(a).read_bytes() == groundtruth_path(b).read_bytes()


def test_unknown_layout_and_existing_output(tmp_path: Path, sequence: SimSequence) -> None:
    """Bad options raise BagError."""
    with pytest.raises(BagError, match='unknown track layout'):
        write_sequence_bag(sequence, tmp_path / 'x', layout='vins')
    write_sequence_bag(sequence, tmp_path / 'y')
    with pytest.raises(BagError, match='exists already'):
        write_sequence_bag(sequence, tmp_path / 'y')
