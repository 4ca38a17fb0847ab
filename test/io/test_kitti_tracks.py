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
"""Tests of pmba_ros.io.kitti_tracks on the shared KITTI-00 stereo tracks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pmba_ros.cli.main import main
from pmba_ros.core import so3
from pmba_ros.errors import FormatError
from pmba_ros.eval.trajectory import read_kitti, Trajectory
from pmba_ros.io.kitti_tracks import (
    CALIBRATION_FILE,
    FACTORS_FILE,
    find_frame_offset,
    kitti_sequence,
    KittiTracks,
    POSES_FILE,
    read_kitti_tracks,
)
import pytest

from ..conftest import shared_file


@pytest.fixture(scope='module')
def kitti_dir() -> Path:
    """Return the shared KITTI-00 track folder (skip when absent)."""
    return shared_file('kitti00_stereo_vo')


def test_reads_77_keyframes_and_all_observations(kitti_dir: Path) -> None:
    """Counts match SOURCES.md §3 and normalized coordinates follow from K."""
    tracks = read_kitti_tracks(kitti_dir)
    assert len(tracks.frames) == 77
    assert sum(len(f) for f in tracks.frames) == 52544
    ids = np.concatenate([f.feature_ids for f in tracks.frames])
    assert np.unique(ids).shape[0] == 15638
    assert tracks.camera.fx == pytest.approx(718.856)
    assert tracks.baseline_m == pytest.approx(0.537, abs=1e-3)
    frame = tracks.frames[5]
    assert frame.pixels is not None and frame.normalized is not None
    np.testing.assert_allclose(tracks.camera.normalize(frame.pixels), frame.normalized)
    np.testing.assert_allclose(tracks.centers[0], 0.0)


def test_frame_offset_is_found_from_relative_motions(kitti_dir: Path) -> None:
    """The 77 VO poses are KITTI 00 frames 0..76 (stride 1)."""
    tracks = read_kitti_tracks(kitti_dir)
    times = np.loadtxt(shared_file('trajectories', 'evo', 'KITTI_00_gt_times.txt'))
    gt = read_kitti(shared_file('trajectories', 'evo', 'KITTI_00_gt.txt'), times)
    offset, stride, rot_deg, trans_m = find_frame_offset(tracks.R_wc, tracks.centers, gt)
    assert (offset, stride) == (0, 1)
    assert rot_deg < 0.2
    assert trans_m < 0.1
    seq = kitti_sequence(tracks, times, gt)
    assert seq.stamps_ns[1] == round(times[1] * 1e9)
    assert seq.R_wc_gt is not None
    np.testing.assert_allclose(seq.centers_gt, gt.positions_xyz[:77])


def test_frame_offset_recovers_a_synthetic_shift() -> None:
    """A sub-sequence of a random-walk trajectory is located at its offset and stride."""
    rng = np.random.default_rng(0)
    n = 300
    R = so3.exp(np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0))
    C = np.cumsum(rng.normal(size=(n, 3)), axis=0)
    gt = Trajectory(np.arange(n) * 0.1, C, R)
    idx = 40 + 2 * np.arange(30)
    # the VO frame differs from the GT world frame by a rigid motion
    G = so3.exp(np.array([0.3, -0.2, 1.0]))
    R_vo = np.einsum('ij,kjl->kil', G, R[idx])
    C_vo = C[idx] @ G.T + np.array([5.0, 1.0, -2.0])
    assert find_frame_offset(R_vo, C_vo, gt)[:2] == (40, 2)


def test_missing_folder_raises_format_error(tmp_path: Path) -> None:
    """A folder without the files gives a FormatError naming the file."""
    with pytest.raises(FormatError, match=r'VO_calibration00s\.txt'):
        read_kitti_tracks(tmp_path)


@pytest.mark.parametrize(('first_frame', 'stride'), [(-5, 1), (0, 0), (3, -2)])
def test_negative_first_frame_or_stride_is_a_format_error(kitti_dir: Path, first_frame: int,
                                                          stride: int) -> None:
    """A negative first frame (which would wrap the times array) or stride < 1 is refused."""
    tracks = read_kitti_tracks(kitti_dir)
    with pytest.raises(FormatError, match='first_frame must be >= 0 and stride >= 1'):
        kitti_sequence(tracks, None, None, first_frame=first_frame, stride=stride)


def _random_walk(n: int = 300) -> Trajectory:
    """Return a random-walk ground truth whose frames 200-239 repeat the motion of 100-139."""
    rng = np.random.default_rng(0)
    steps = rng.normal(scale=0.05, size=(n, 3))
    moves = rng.normal(size=(n, 3))
    steps[200:240], moves[200:240] = steps[100:140], moves[100:140]
    # composed, so that the relative motions repeat with the steps
    R, C = np.empty((n, 3, 3)), np.zeros((n, 3))
    R[0] = np.eye(3)
    for k in range(1, n):
        R[k] = R[k - 1] @ so3.exp(steps[k])
        C[k] = C[k - 1] + R[k - 1] @ moves[k]
    return Trajectory(np.arange(n) * 0.1, C, R)


def _noisy(gt: Trajectory, idx: np.ndarray, deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Return the GT poses ``idx`` with rotation noise of ``deg`` per axis."""
    rng = np.random.default_rng(1)
    noise = so3.exp(np.radians(rng.normal(scale=deg, size=(idx.size, 3))))
    return np.einsum('kij,kjl->kil', gt.R_wc[idx], noise), gt.positions_xyz[idx]


def test_a_location_two_places_fit_is_refused_naming_both() -> None:
    """Frames 100-111 move as 200-211 do: the best of the two was taken silently."""
    gt = _random_walk()
    R_vo, C_vo = _noisy(gt, 100 + np.arange(12), 0.05)
    with pytest.raises(FormatError, match='cannot be located') as err:
        find_frame_offset(R_vo, C_vo, gt)
    assert 'frames 100.. stride 1' in str(err.value)
    assert 'frames 200.. stride 1' in str(err.value)
    assert '--first-frame N' in str(err.value)
    assert find_frame_offset(R_vo, C_vo, gt, first_frame=200)[:2] == (200, 1)


def test_a_noisy_distinct_location_is_accepted() -> None:
    """Twelve noisy poses where the motion does not repeat are located (frames 20-31)."""
    gt = _random_walk()
    R_vo, C_vo = _noisy(gt, 20 + np.arange(12), 0.05)
    assert find_frame_offset(R_vo, C_vo, gt)[:2] == (20, 1)
    assert find_frame_offset(R_vo, C_vo, gt, first_frame=20)[:2] == (20, 1)


def test_one_pose_is_not_located_but_takes_a_given_frame(kitti_dir: Path) -> None:
    """One pose has no relative motion: the error says so (not 'ground truth has fewer')."""
    tracks = read_kitti_tracks(kitti_dir)
    one = KittiTracks(tracks.keyframe_ids[:1], tracks.R_wc[:1], tracks.centers[:1],
                      tracks.frames[:1], tracks.camera, tracks.baseline_m)
    gt = _random_walk()
    with pytest.raises(FormatError, match=r'one VO pose cannot be located.*--first-frame N'):
        kitti_sequence(one, None, gt)
    seq = kitti_sequence(one, None, gt, first_frame=7)
    assert (seq.first_frame, seq.stride) == (7, 1)
    np.testing.assert_allclose(seq.centers_gt, gt.positions_xyz[7:8])


def test_the_first_12_kitti_poses_are_not_located(kitti_dir: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """Frames 0-11 fit frames 4038-4049 about as well: refused, and --first-frame imports."""
    for name in (CALIBRATION_FILE, POSES_FILE):
        lines = (kitti_dir / name).read_text().splitlines(keepends=True)
        (tmp_path / name).write_text(''.join(lines[:12]))
    factors = (kitti_dir / FACTORS_FILE).read_text().splitlines(keepends=True)
    (tmp_path / FACTORS_FILE).write_text(''.join(f for f in factors if int(f.split()[0]) < 12))
    gt_args = ['--gt', str(shared_file('trajectories', 'evo', 'KITTI_00_gt.txt')), '--times',
               str(shared_file('trajectories', 'evo', 'KITTI_00_gt_times.txt'))]
    argv = ['import-tracks', '--tracks-dir', str(tmp_path), '--out', str(tmp_path / 'bag'),
            *gt_args]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert 'frames 4038.. stride 1' in err and '--first-frame N' in err
    assert not (tmp_path / 'bag').exists()
    assert main([*argv, '--first-frame', '0', '--stride', '1']) == 0
    assert 'frames 0..11 (stride 1)' in capsys.readouterr().out
