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
"""KITTI stereo tracks with the right image (``import-tracks --stereo``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from pmba_ros.backend.config import BackendConfig
from pmba_ros.cli.main import main
from pmba_ros.core import so3
from pmba_ros.eval.trajectory import read_tum
from pmba_ros.io.bags import list_topics
from pmba_ros.io.kitti_tracks import (
    CALIBRATION_FILE,
    FACTORS_FILE,
    POSES_FILE,
    read_kitti_tracks,
    right_camera,
)
from pmba_ros.replay import replay
import pytest

from ..conftest import shared_file

FX, CX, CY, BASELINE = 700.0, 600.0, 180.0, 0.54
N_KEYFRAMES = 30


def _kitti_like(directory: Path, seed: int = 0) -> np.ndarray:
    """Write a small KITTI-like VO folder; return the true camera centres.

    Forward motion of 1 m per keyframe with a gentle yaw; the VO poses have a 6 % scale
    error. Pixels have 0.3 px of noise.
    """
    rng = np.random.default_rng(seed)
    yaw = 0.05 * np.sin(np.arange(N_KEYFRAMES) / 5.0)
    R = so3.exp(np.column_stack([np.zeros(N_KEYFRAMES), yaw, np.zeros(N_KEYFRAMES)]))
    C = np.column_stack([np.cumsum(np.sin(yaw)), np.zeros(N_KEYFRAMES),
                         np.arange(N_KEYFRAMES, dtype=float)])
    X = np.column_stack([rng.uniform(-12, 12, 900), rng.uniform(-3, 2, 900),
                         rng.uniform(4, N_KEYFRAMES + 40, 900)])
    rows = []
    for k in range(N_KEYFRAMES):
        h = (X - C[k]) @ R[k]
        z = np.maximum(h[:, 2], 1e-9)
        uL, v = FX * h[:, 0] / z + CX, FX * h[:, 1] / z + CY
        uR = FX * (h[:, 0] - BASELINE) / z + CX
        seen = (h[:, 2] > 3.0) & (h[:, 2] < 40.0) & (uL > 0) & (uL < 1241) & (uR > 0) & \
            (v > 0) & (v < 376)
        for j in np.flatnonzero(seen):
            noise = rng.normal(0.0, 0.3, 3)
            rows.append([k, j, uL[j] + noise[0], uR[j] + noise[1], v[j] + noise[2], *X[j]])
    (directory / CALIBRATION_FILE).write_text(f'{FX} {FX} 0.0 {CX} {CY} {BASELINE}\n')
    vo = np.zeros((N_KEYFRAMES, 4, 4))
    vo[:, :3, :3], vo[:, :3, 3], vo[:, 3, 3] = R, 1.06 * C, 1.0
    np.savetxt(directory / POSES_FILE, np.column_stack([np.arange(N_KEYFRAMES),
                                                        vo.reshape(-1, 16)]))
    np.savetxt(directory / FACTORS_FILE, np.array(rows), fmt='%d %d %.4f %.4f %.4f %.4f %.4f %.4f')
    return C


def test_stereo_tracks_hold_the_right_image_as_camera_1(tmp_path: Path) -> None:
    """``(uR, v)`` of every factor as camera 1, normalized with the left intrinsics."""
    _kitti_like(tmp_path)
    mono = read_kitti_tracks(tmp_path)
    stereo = read_kitti_tracks(tmp_path, stereo=True)
    factors = np.loadtxt(tmp_path / FACTORS_FILE)
    assert sum(len(f) for f in stereo.frames) == 2 * sum(len(f) for f in mono.frames)
    frame = stereo.frames[3]
    right = frame.camera_ids == 1
    assert frame.pixels is not None and frame.normalized is not None
    mine = factors[factors[:, 0] == 3]
    order = np.argsort(mine[:, 1])
    np.testing.assert_array_equal(frame.feature_ids[right], mine[order, 1].astype(np.int64))
    np.testing.assert_allclose(frame.pixels[right], mine[order][:, [3, 4]])
    np.testing.assert_allclose(frame.normalized[right],
                               (frame.pixels[right] - [CX, CY]) / FX)
    np.testing.assert_allclose(right_camera(stereo.baseline_m).translation, [BASELINE, 0, 0])


def test_import_tracks_stereo_replays_to_metric_scale(tmp_path: Path) -> None:
    """The right camera fixes the scale: the VO's 6 % scale error is gone after the replay."""
    C_true = _kitti_like(tmp_path)
    bag = tmp_path / 'bag'
    assert main(['import-tracks', '--stereo', '--tracks-dir', str(tmp_path), '--gt', 'none',
                 '--times', 'none', '--out', str(bag)]) == 0
    assert {'/camera_info', '/camera1/camera_info', '/tf_static'} <= set(list_topics([bag]))
    config = BackendConfig(num_cams=2, init_batch_size=8,
                           camera_info_topics=('/camera_info', '/camera1/camera_info'))
    report = replay([bag], tmp_path / 'out', config)
    data = json.loads((tmp_path / 'out' / 'report.json').read_text())
    assert report.keyframes_out == N_KEYFRAMES
    assert 'other_camera_observations' not in data['counters']
    optimized = read_tum(tmp_path / 'out' / 'keyframes_optimized.tum').positions_xyz
    frontend = read_tum(tmp_path / 'out' / 'keyframes_frontend.tum').positions_xyz
    true_length = np.linalg.norm(C_true[-1] - C_true[0])
    frontend_scale = np.linalg.norm(frontend[-1] - frontend[0]) / true_length
    assert frontend_scale == pytest.approx(1.06, abs=1e-3)
    assert abs(np.linalg.norm(optimized[-1] - optimized[0]) / true_length - 1.0) < 0.02


def test_shared_kitti00_stereo_tracks() -> None:
    """The shared KITTI-00 tracks: every factor also as a right-image observation."""
    tracks = read_kitti_tracks(shared_file('kitti00_stereo_vo'), stereo=True)
    assert sum(len(f) for f in tracks.frames) == 2 * 52544
    frame = tracks.frames[5]
    assert np.count_nonzero(frame.camera_ids == 1) == np.count_nonzero(frame.camera_ids == 0)
