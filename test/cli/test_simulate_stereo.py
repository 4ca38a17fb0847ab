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
"""``pmba simulate --cameras 2``: a stereo recording."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pmba_ros.backend.tracks import parse_tracks
from pmba_ros.cli.main import main
from pmba_ros.io.bags import iter_messages, list_topics
from pmba_ros.sim.bag import EUROC_CAM0
from pmba_ros.sim.rig import EUROC_CAM1
import pytest


@pytest.mark.parametrize('extrinsic', ['euroc', 'none'])
def test_simulate_two_cameras(tmp_path: Path, extrinsic: str) -> None:
    """Camera 1's observations in the tracks, its CameraInfo and transform recorded."""
    bag = tmp_path / 'bag'
    assert main(['simulate', '--scenario', 'street', '--keyframes', '8', '--cameras', '2',
                 '--extrinsic', extrinsic, '--out', str(bag)]) == 0
    topics = list_topics([bag])
    assert topics['/camera1/camera_info'].count == 8
    tf = {m.msg.transforms[0].child_frame_id: m.msg.transforms[0].transform
          for m in iter_messages([bag], topics=['/tf_static'])}
    want = EUROC_CAM1 if extrinsic == 'euroc' else EUROC_CAM0.inverse() @ EUROC_CAM1
    t = tf['camera1'].translation
    np.testing.assert_allclose([t.x, t.y, t.z], want.translation, atol=1e-9)
    frame = parse_tracks(next(iter_messages([bag], topics=['/features'])).msg, 'vins_fusion', 2)
    both = np.intersect1d(frame.feature_ids[frame.camera_ids == 0],
                          frame.feature_ids[frame.camera_ids == 1])
    assert both.shape[0] > 50


@pytest.mark.parametrize(('options', 'named'), [
    (['--frontend', 'vins_fusion'], 'layout per_point, which has no camera id'),
    (['--frontend', 'openvins'], 'layout per_point, which has no camera id'),
    (['--layout', 'per_point'], 'layout per_point, which has no camera id'),
    (['--frontend', 'vins_mono'], '--frontend vins_mono is monocular'),
])
def test_two_cameras_in_tracks_of_one_camera_are_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], options: list[str],
        named: str) -> None:
    """A layout or front-end that carries one camera's tracks cannot hold a rig: named, early."""
    bag = tmp_path / 'bag'
    assert main(['simulate', '--keyframes', '8', '--cameras', '2', *options,
                 '--out', str(bag)]) == 1
    assert named in capsys.readouterr().err
    assert not bag.exists()


def test_a_vins_mono_rig_says_how_to_replay_it(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """Its ids hold the camera but not the camera count: the replay needs both CameraInfos."""
    bag = tmp_path / 'bag'
    assert main(['simulate', '--keyframes', '8', '--cameras', '2', '--layout', 'vins_mono',
                 '--out', str(bag)]) == 0
    assert ('--camera-info-topic /camera_info --camera-info-topic /camera1/camera_info'
            in capsys.readouterr().out)
    frame = parse_tracks(next(iter_messages([bag], topics=['/features'])).msg, 'vins_mono', 2)
    assert set(frame.camera_ids.tolist()) == {0, 1}
