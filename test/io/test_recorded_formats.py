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
"""A replay's input settings fitted to what a recording holds."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.errors import BagError
from pmba_ros.io.bags import jazzy_typestore, open_bags, OpenBags, TopicInfo
from pmba_ros.io.recorded_formats import _fitting_layout, _rig_camera_infos, fit_to_recording
from pmba_ros.replay import replay
from pmba_ros.sim.bag import SimTopics, write_sequence_bag
from pmba_ros.sim.inputs import make_tracks
from pmba_ros.sim.sequence import simulate_sequence
import pytest

INFO = 'sensor_msgs/msg/CameraInfo'


@pytest.fixture(scope='module')
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Return a 12-keyframe street in every layout."""
    seq = simulate_sequence('street', n_keyframes=12, seed=4)
    root = tmp_path_factory.mktemp('layouts')
    out = {}
    for layout in ('vins_mono', 'vins_fusion', 'per_point', 'named'):
        out[layout] = root / layout
        write_sequence_bag(seq, out[layout], layout=layout)
    return out


def _fit(bag: Path, config: BackendConfig, chosen: set[str] | None = None,
         ) -> tuple[BackendConfig, list[str]]:
    warnings: list[str] = []
    with open_bags([bag]) as opened:
        return fit_to_recording(opened, config, warnings, chosen or set()), warnings


@pytest.mark.parametrize('recorded', ['vins_mono', 'vins_fusion', 'per_point', 'named'])
@pytest.mark.parametrize('configured', ['vins_mono', 'vins_fusion', 'per_point', 'named'])
def test_layout_follows_the_recording(bags: dict[str, Path], recorded: str,
                                      configured: str) -> None:
    """Every layout is found from every other; a layout that reads is kept, silently."""
    config, warnings = _fit(bags[recorded], BackendConfig(feature_layout=configured))
    assert config.feature_layout == recorded
    assert config.num_cams == 1 and config.keyframe_type == 'odometry'
    assert len(warnings) == (recorded != configured)


def test_chosen_layout_is_kept(bags: dict[str, Path]) -> None:
    """A layout the user chose is not replaced, even where it cannot read the tracks."""
    config, warnings = _fit(bags['vins_mono'], BackendConfig(), {'feature_layout'})
    assert config.feature_layout == 'vins_fusion' and warnings == []


def test_keyframe_type_follows_the_topic(bags: dict[str, Path]) -> None:
    """A PoseStamped keyframe topic is read as such, unless the type was chosen."""
    config = BackendConfig(keyframe_topic='/groundtruth/pose')
    fitted, warnings = _fit(bags['vins_fusion'], config)
    assert fitted.keyframe_type == 'pose_stamped'
    assert 'geometry_msgs/msg/PoseStamped' in warnings[0]
    assert _fit(bags['vins_fusion'], config, {'keyframe_type'})[0].keyframe_type == 'odometry'


def test_tracks_no_layout_reads_keep_the_configuration() -> None:
    """Tracks no layout reads (three channels) leave the layout to the replay's error."""
    seq = simulate_sequence('street', n_keyframes=2, seed=1)
    msg = make_tracks(seq.frames[0], 'vins_fusion', RosbagsBackend(jazzy_typestore()))
    garbled = replace(msg, channels=msg.channels[:3])
    warnings: list[str] = []
    layout, frames = _fitting_layout([garbled], 'sensor_msgs/msg/PointCloud',
                                     BackendConfig(), warnings)
    assert layout == 'vins_fusion' and frames is None and warnings == []


def _recorded(*infos: str) -> OpenBags:
    topics = {t: TopicInfo(t, INFO, 5) for t in infos}
    topics['/features'] = TopicInfo('/features', 'sensor_msgs/msg/PointCloud', 5)
    return OpenBags([], None, topics)


@pytest.mark.parametrize(('infos', 'cameras', 'rig'), [
    (('/camera1/camera_info', '/camera_info'), 2, ('/camera_info', '/camera1/camera_info')),
    (('/cam1/camera_info', '/cam0/camera_info'), 2, ('/cam0/camera_info', '/cam1/camera_info')),
    (('/cam0/camera_info', '/cam1/camera_info', '/cam2/camera_info'), 2, ()),
    (('/camera_info',), 2, ()),
])
def test_rig_camera_infos_need_one_topic_per_camera(infos: tuple[str, ...], cameras: int,
                                                    rig: tuple[str, ...]) -> None:
    """The reference camera's topic first, the rest by name; any other count: no rig."""
    assert _rig_camera_infos(_recorded(*infos), BackendConfig(), cameras) == rig


def test_configured_rig_is_kept() -> None:
    """Configured rig topics are not replaced by the recorded ones."""
    config = BackendConfig(num_cams=2, camera_info_topics=('/a', '/b'))
    assert _rig_camera_infos(_recorded('/cam0/camera_info', '/cam1/camera_info'), config, 2) == ()


@pytest.mark.parametrize(('frontend', 'layout', 'topics'), [
    ('openvins', 'per_point', SimTopics(tracks='/ov_msckf/loop_feats',
                                        keyframes='/ov_msckf/loop_pose',
                                        camera_info='/ov_msckf/loop_intrinsics')),
    ('vins_mono', 'vins_mono', SimTopics(tracks='/feature_tracker/feature',
                                         keyframes='/vins_estimator/keyframe_pose')),
])
def test_a_front_ends_recording_replays_without_options(tmp_path: Path, frontend: str,
                                                        layout: str, topics: SimTopics) -> None:
    """A front-end's own topic names are found; the result is the explicit replay's."""
    seq = simulate_sequence('street', n_keyframes=30, seed=6)
    bag = tmp_path / 'bag'
    write_sequence_bag(seq, bag, layout=layout, topics=topics)
    explicit = BackendConfig(features_topic=topics.tracks, keyframe_topic=topics.keyframes,
                             camera_info_topic=topics.camera_info, feature_layout=layout)
    replay([bag], tmp_path / 'explicit', explicit)
    report = replay([bag], tmp_path / 'found')
    assert report.complete and report.keyframes_out == 30 and report.messages_rejected == 0
    found = f"reading {frontend}'s topics: {topics.tracks}, {topics.keyframes}"
    assert found in report.warnings[0]
    assert report.topics['camera_info'] == topics.camera_info
    for name in ('keyframes_optimized.tum', 'landmarks.ply'):
        assert ((tmp_path / 'found' / name).read_bytes()
                == (tmp_path / 'explicit' / name).read_bytes()), name


def test_chosen_tracks_topic_is_not_replaced(tmp_path: Path) -> None:
    """A tracks topic given on the command line that is not recorded stays an error."""
    seq = simulate_sequence('street', n_keyframes=4, seed=6)
    topics = SimTopics(tracks='/ov_msckf/loop_feats', keyframes='/ov_msckf/loop_pose')
    write_sequence_bag(seq, tmp_path / 'bag', layout='per_point', topics=topics)
    with pytest.raises(BagError, match="tracks topic '/features' is not in the bag"):
        replay([tmp_path / 'bag'], tmp_path / 'o', chosen={'features_topic'})
