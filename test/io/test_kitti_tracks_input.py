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
"""Malformed ``VO_*00s.txt`` inputs: refused naming file and line, or warned and salvaged."""

from __future__ import annotations

import logging
from pathlib import Path
import warnings

import numpy as np
from pmba_ros.errors import FormatError
from pmba_ros.io.kitti_tracks import (
    CALIBRATION_FILE,
    FACTORS_FILE,
    POSES_FILE,
    read_kitti_tracks,
)
import pytest

CALIBRATION = '718.856 718.856 0.0 607.1928 185.2157 0.5371657189\n'
FACTORS = ['0 7 322.5 299.5 11.7 -6.6 -4.1 16.8', '1 7 330.1 306.9 12.0 -6.6 -4.1 15.8',
           '2 7 338.0 314.6 12.4 -6.6 -4.1 14.8', '2 8 500.0 480.0 100.0 -1.0 -1.0 20.0']


def _pose_lines(n: int = 3) -> list[str]:
    """Return ``n`` pose lines: identity rotations, 1 m apart along z."""
    lines = []
    for k in range(n):
        mat = np.eye(4)
        mat[2, 3] = float(k)
        lines.append(' '.join([str(k), *(f'{v:g}' for v in mat.reshape(-1))]))
    return lines


def _write(directory: Path, calibration: str = CALIBRATION, poses: list[str] | None = None,
           factors: list[str] | None = None) -> Path:
    """Write the three files (defaults: three poses, four observations); return the folder."""
    (directory / CALIBRATION_FILE).write_text(calibration)
    rows = _pose_lines() if poses is None else poses
    (directory / POSES_FILE).write_text(''.join(f'{r}\n' for r in rows))
    rows = FACTORS if factors is None else factors
    (directory / FACTORS_FILE).write_text(''.join(f'{r}\n' for r in rows))
    return directory


def test_the_defaults_read(tmp_path: Path) -> None:
    """The helper's files are valid: three keyframes, four observations."""
    tracks = read_kitti_tracks(_write(tmp_path), stereo=True)
    assert [len(f) for f in tracks.frames] == [2, 2, 4]


def test_an_empty_factors_file_is_one_error_without_numpy_warnings(tmp_path: Path) -> None:
    """No ``loadtxt: input contained no data`` UserWarning precedes the FormatError."""
    _write(tmp_path, factors=[])
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        with pytest.raises(FormatError, match=r'VO_stereo_factors00s\.txt: no data'):
            read_kitti_tracks(tmp_path)


def test_a_pose_that_is_no_rotation_is_refused(tmp_path: Path) -> None:
    """A rotation entry set to 2 names the line and pose (it was projected silently)."""
    poses = _pose_lines()
    values = poses[2].split()
    values[1] = '2'
    poses[2] = ' '.join(values)
    _write(tmp_path, poses=poses)
    with pytest.raises(FormatError, match=r'VO_camera_poses00s\.txt:3: pose 2 is not a rigid'):
        read_kitti_tracks(tmp_path)


def test_a_repeated_pose_id_is_refused(tmp_path: Path) -> None:
    """A pose id twice is named as such (it was 'observations of unknown keyframes')."""
    poses = _pose_lines()
    poses[2] = '1' + poses[2][1:]
    _write(tmp_path, poses=poses, factors=FACTORS[:2])
    with pytest.raises(FormatError, match=r'poses00s\.txt:3: pose id 1 repeats line 2'):
        read_kitti_tracks(tmp_path)


def test_poses_out_of_id_order_are_sorted_with_a_warning(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Swapped pose lines are taken in id order, not in file order."""
    poses = _pose_lines()
    _write(tmp_path, poses=[poses[0], poses[2], poses[1]])
    with caplog.at_level(logging.WARNING):
        tracks = read_kitti_tracks(tmp_path)
    assert tracks.keyframe_ids.tolist() == [0, 1, 2]
    np.testing.assert_allclose(tracks.centers[:, 2], [0.0, 1.0, 2.0])
    assert 'poses00s.txt:3: pose id 1 after 2' in caplog.text


@pytest.mark.parametrize('column', [2, 4, 7])
def test_a_non_finite_factor_value_is_refused(tmp_path: Path, column: int) -> None:
    """A NaN in uL, v or the point names the line (uL = NaN was imported)."""
    values = FACTORS[1].split()
    values[column] = 'nan'
    _write(tmp_path, factors=[FACTORS[0], ' '.join(values), *FACTORS[2:]])
    with pytest.raises(FormatError, match=r'factors00s\.txt:2: non-finite value'):
        read_kitti_tracks(tmp_path)


def _negative_disparity(directory: Path) -> Path:
    """Write the defaults with uR 50 px right of uL on line 3."""
    values = FACTORS[2].split()
    values[3] = str(float(values[2]) + 50.0)
    return _write(directory, factors=[*FACTORS[:2], ' '.join(values), FACTORS[3]])


def test_negative_disparity_is_refused_with_the_right_image(tmp_path: Path) -> None:
    """``--stereo``: uR > uL puts the point behind the cameras: the line is named."""
    _negative_disparity(tmp_path)
    with pytest.raises(FormatError, match=r'factors00s\.txt:3: uR > uL by 50 px'):
        read_kitti_tracks(tmp_path, stereo=True)


def test_negative_disparity_warns_for_the_left_image_alone(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Monocular tracks do not use uR: a warning, and every observation kept."""
    _negative_disparity(tmp_path)
    with caplog.at_level(logging.WARNING):
        tracks = read_kitti_tracks(tmp_path)
    assert sum(len(f) for f in tracks.frames) == 4
    assert 'factors00s.txt:3: uR > uL by 50 px' in caplog.text


@pytest.mark.parametrize('baseline', ['0', '-0.537', '-0'])
def test_a_baseline_not_positive_is_refused_with_the_right_image(
        tmp_path: Path, baseline: str) -> None:
    """``--stereo`` with a baseline of 0 or below is refused; the left image alone reads."""
    _write(tmp_path, calibration=f'718.856 718.856 0.0 607.1928 185.2157 {baseline}\n')
    with pytest.raises(FormatError, match=r'calibration00s\.txt:1: a stereo baseline must'):
        read_kitti_tracks(tmp_path, stereo=True)
    assert len(read_kitti_tracks(tmp_path).frames) == 3


def test_a_skew_is_refused(tmp_path: Path) -> None:
    """The camera model has no skew: a skew of 50 was dropped silently."""
    _write(tmp_path, calibration='718.856 718.856 50 607.1928 185.2157 0.537\n')
    with pytest.raises(FormatError, match=r'calibration00s\.txt:1: skew 50 is not supported'):
        read_kitti_tracks(tmp_path)


def test_a_repeated_observation_is_dropped_with_a_warning(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The same line twice counts once."""
    _write(tmp_path, factors=[*FACTORS, FACTORS[0]])
    with caplog.at_level(logging.WARNING):
        tracks = read_kitti_tracks(tmp_path, stereo=True)
    assert [len(f) for f in tracks.frames] == [2, 2, 4]
    assert 'factors00s.txt:5: 1 observation(s) repeat an earlier line' in caplog.text


def test_a_landmark_observed_twice_at_other_pixels_is_refused(tmp_path: Path) -> None:
    """Keyframe 0 cannot see landmark 7 at two places."""
    _write(tmp_path, factors=[*FACTORS, '0 7 100 90 11.7 -6.6 -4.1 16.8'])
    with pytest.raises(FormatError, match=r'factors00s\.txt:5: keyframe 0 observes landmark 7'):
        read_kitti_tracks(tmp_path)


@pytest.mark.parametrize(('name', 'text', 'needle'), [
    (POSES_FILE, '0 1 0 0\n', r'poses00s\.txt:1: expected at least 17 numbers, got 4'),
    (FACTORS_FILE, '0 7 1 1 1\n0 7 1 1\n', r'factors00s\.txt:2: expected at least 5'),
    (FACTORS_FILE, '0 7.5 1 1 1\n', r'factors00s\.txt:1: landmark id 7.5 is not an integer'),
    (FACTORS_FILE, '9 7 1 1 1\n', r'factors00s\.txt:1: observation of keyframe 9, which has'),
    (FACTORS_FILE, '0 7 1 x 1\n', r"factors00s\.txt:1: non-numeric token 'x'"),
])
def test_malformed_lines_are_named(tmp_path: Path, name: str, text: str, needle: str) -> None:
    """Short, non-integer, unknown and non-numeric rows name their line."""
    _write(tmp_path)
    (tmp_path / name).write_text(text)
    with pytest.raises(FormatError, match=needle):
        read_kitti_tracks(tmp_path)
