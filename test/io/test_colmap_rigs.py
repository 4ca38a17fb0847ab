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
"""Tests of the COLMAP rigs and frames reader and writer (pmba_ros.io.colmap_rigs)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from pmba_ros.errors import FormatError
from pmba_ros.io import colmap, colmap_rigs
import pytest

pycolmap = pytest.importorskip('pycolmap')


def synthesize(directory: Path, binary: bool, model: str = 'SIMPLE_RADIAL',
               params: tuple[float, ...] = (300.0, 320.0, 240.0, 0.05), noise: bool = False,
               seed: int = 0) -> object:
    """Write a pycolmap-synthesized model of 3 rigs x 2 cameras, 3 frames each; return it.

    With ``noise``: 0.5 px pixel noise, the frames' poses and the points perturbed.
    """
    options = pycolmap.SyntheticDatasetOptions()
    options.num_rigs, options.num_cameras_per_rig, options.num_frames_per_rig = 3, 2, 3
    options.num_points3D = 80
    options.camera_model_id = getattr(pycolmap.CameraModelId, model)
    options.camera_params = list(params)
    options.camera_width, options.camera_height = 640, 480
    pycolmap.set_random_seed(seed)
    rec = pycolmap.synthesize_dataset(options)
    if noise:
        n = pycolmap.SyntheticNoiseOptions()
        n.point2D_stddev, n.point3D_stddev = 0.5, 0.02
        n.rig_from_world_rotation_stddev, n.rig_from_world_translation_stddev = 0.2, 0.02
        pycolmap.synthesize_noise(n, rec)
    directory.mkdir(parents=True, exist_ok=True)
    (rec.write if binary else rec.write_text)(str(directory))
    return rec


@pytest.mark.parametrize('binary', [False, True], ids=['text', 'binary'])
def test_rigs_and_frames_round_trip_byte_for_byte(tmp_path: Path, binary: bool) -> None:
    """What pycolmap writes is read as pycolmap has it, and written back byte for byte."""
    rec = synthesize(tmp_path / 'in', binary)
    model = colmap.read_colmap(tmp_path / 'in')
    rigs = colmap_rigs.read_rigs(tmp_path / 'in', model.images)
    assert rigs is not None and rigs.has_multi_camera_rig()
    assert sorted(rigs.rigs) == sorted(rec.rigs) and sorted(rigs.frames) == sorted(rec.frames)
    for fid, frame in rec.frames.items():
        ours = rigs.frames[fid]
        assert ours.rig_id == frame.rig_id
        assert sorted(i for _, i in ours.image_ids()) == sorted(d.id for d in frame.data_ids)
        np.testing.assert_array_equal(np.concatenate([ours.qvec, ours.tvec]),
                                      frame.rig_from_world.params[[3, 0, 1, 2, 4, 5, 6]])
    for rid, rig in rec.rigs.items():
        assert rigs.rigs[rid].cameras()[0] == rig.ref_sensor_id.id
        for sensor_id, pose in rig.non_ref_sensors.items():
            ours_pose = rigs.rigs[rid].sensor_from_rig(0, sensor_id.id)
            assert ours_pose is not None
            np.testing.assert_array_equal(ours_pose, pose.params[[3, 0, 1, 2, 4, 5, 6]])
    colmap_rigs.write_rigs(tmp_path / 'out', rigs, binary=binary)
    ext = '.bin' if binary else '.txt'
    for name in ('rigs', 'frames'):
        assert (tmp_path / 'out' / f'{name}{ext}').read_bytes() == \
            (tmp_path / 'in' / f'{name}{ext}').read_bytes()


def test_a_model_without_rigs_has_none(tmp_path: Path) -> None:
    """A model from before COLMAP 3.12 (no rigs, no frames) reads as None."""
    synthesize(tmp_path, binary=True)
    (tmp_path / 'rigs.bin').unlink()
    (tmp_path / 'frames.bin').unlink()
    assert colmap_rigs.read_rigs(tmp_path, colmap.read_colmap(tmp_path).images) is None


def _damage_frames_txt(path: Path, old: str, new: str) -> None:
    lines = path.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if not line.startswith('#'))
    assert old in lines[k]
    lines[k] = lines[k].replace(old, new, 1)
    path.write_text('\n'.join(lines) + '\n')


@pytest.mark.parametrize(('old', 'new', 'match'), [
    (' CAMERA 1 1', ' CAMERA 1 999', 'frames.txt: frame 1 refers to unknown image 999'),
    (' CAMERA 1 1', ' CAMERA 3 1', 'frames.txt: frame 1 has data of sensor CAMERA 3'),
    (' CAMERA 1 1', ' LIDAR 1 1', r"frames.txt:4: unknown sensor type 'LIDAR'"),
    (' CAMERA 1 1', ' CAMERA 1', r'frames.txt:4: 2 data ids need 6 values'),
    ('1 1 ', '1 7 ', 'frames.txt: frame 1 refers to unknown rig 7'),
    (' CAMERA 1 1', ' CAMERA 1 inf', 'frames.txt:4: not an integer in data id'),
    ('1 1 ', '1 1.5 ', 'frames.txt:4: not an integer in frame id / rig id'),
])
def test_damaged_text_frames_are_refused_naming_the_file(tmp_path: Path, old: str, new: str,
                                                         match: str) -> None:
    """Unknown images, sensors, sensor types and rigs, and short lines: a FormatError."""
    synthesize(tmp_path, binary=False)
    _damage_frames_txt(tmp_path / 'frames.txt', old, new)
    with pytest.raises(FormatError, match=match):
        colmap_rigs.read_rigs(tmp_path, colmap.read_colmap(tmp_path).images)


def test_damaged_binary_frames_are_refused_naming_the_file(tmp_path: Path) -> None:
    """A truncated frames.bin, an unknown image id and a missing rigs.bin: a FormatError."""
    synthesize(tmp_path, binary=True)
    images = colmap.read_colmap(tmp_path).images
    rigs = colmap_rigs.read_rigs(tmp_path, images)
    assert rigs is not None
    data = (tmp_path / 'frames.bin').read_bytes()
    (tmp_path / 'frames.bin').write_bytes(data[:-5])
    with pytest.raises(FormatError, match=r'frames\.bin: truncated file'):
        colmap_rigs.read_rigs(tmp_path, images)
    frame = rigs.frames[1]
    ids = frame.data_ids.copy()
    ids[0, 2] = 999
    colmap_rigs.write_rigs(tmp_path, dataclasses.replace(
        rigs, frames={**rigs.frames, 1: dataclasses.replace(frame, data_ids=ids)}), binary=True)
    with pytest.raises(FormatError, match=r'frames\.bin: frame 1 refers to unknown image 999'):
        colmap_rigs.read_rigs(tmp_path, images)
    (tmp_path / 'rigs.bin').unlink()
    with pytest.raises(FormatError, match=r'rigs\.bin is missing'):
        colmap_rigs.read_rigs(tmp_path, images)


@pytest.mark.parametrize('name', ['rigs', 'frames'])
@pytest.mark.parametrize('binary', [False, True], ids=['text', 'binary'])
def test_absurd_rig_and_frame_translations_are_refused(tmp_path: Path, name: str,
                                                       binary: bool) -> None:
    """A rig camera's offset or a frame's translation beyond 1e150 names file and line."""
    synthesize(tmp_path, binary)
    images = colmap.read_colmap(tmp_path).images
    rigs = colmap_rigs.read_rigs(tmp_path, images)
    assert rigs is not None
    rig = rigs.rigs[1]
    assert rig.sensors[0].pose is not None
    if name == 'rigs':
        pose = rig.sensors[0].pose.copy()
        pose[5] = -1e300
        sensor = dataclasses.replace(rig.sensors[0], pose=pose)
        rigs = dataclasses.replace(rigs, rigs={**rigs.rigs, 1: dataclasses.replace(
            rig, sensors=(sensor, *rig.sensors[1:]))})
        what = f'rig 1 camera {sensor.sensor_id} has translation coordinate -1e\\+300 beyond'
    else:
        tvec = rigs.frames[1].tvec.copy()
        tvec[0] = -1e300
        rigs = dataclasses.replace(rigs, frames={
            **rigs.frames, 1: dataclasses.replace(rigs.frames[1], tvec=tvec)})
        what = 'frame 1 has translation coordinate -1e\\+300 beyond 1e\\+150'
    colmap_rigs.write_rigs(tmp_path, rigs, binary=binary)
    where = f'{name}\\.bin' if binary else f'{name}\\.txt:\\d+'
    with pytest.raises(FormatError, match=f'{where}: {what}'):
        colmap_rigs.read_rigs(tmp_path, images)


def test_an_image_in_two_frames_is_refused(tmp_path: Path) -> None:
    """Each image belongs to one frame."""
    synthesize(tmp_path, binary=True)
    images = colmap.read_colmap(tmp_path).images
    rigs = colmap_rigs.read_rigs(tmp_path, images)
    assert rigs is not None
    other = next(f for fid, f in rigs.frames.items() if fid != 1 and f.rig_id == 1)
    ids = other.data_ids.copy()
    ids[0] = rigs.frames[1].data_ids[0]
    fid = next(k for k, f in rigs.frames.items() if f is other)
    colmap_rigs.write_rigs(tmp_path, dataclasses.replace(
        rigs, frames={**rigs.frames, fid: dataclasses.replace(other, data_ids=ids)}),
        binary=True)
    with pytest.raises(FormatError, match=r'frames\.bin: image \d+ is in frames'):
        colmap_rigs.read_rigs(tmp_path, images)


@pytest.mark.parametrize('name', ['rigs', 'frames'])
@pytest.mark.parametrize('binary', [False, True], ids=['text', 'binary'])
def test_repeated_rig_and_frame_ids_are_refused(tmp_path: Path, name: str,
                                                binary: bool) -> None:
    """A rig or frame id that appears twice names the file (and line); it replaced the first."""
    synthesize(tmp_path / 'in', binary)
    images = colmap.read_colmap(tmp_path / 'in').images
    rigs = colmap_rigs.read_rigs(tmp_path / 'in', images)
    assert rigs is not None
    path = tmp_path / 'in' / f'{name}{".bin" if binary else ".txt"}'
    if binary:   # the first record again at the end (written alone), the count one more
        first = dataclasses.replace(rigs, rigs={1: rigs.rigs[1]}, frames={1: rigs.frames[1]})
        colmap_rigs.write_rigs(tmp_path / 'one', first, binary=True)
        record = (tmp_path / 'one' / path.name).read_bytes()[8:]
        data = path.read_bytes()
        count = int.from_bytes(data[:8], 'little') + 1
        path.write_bytes(count.to_bytes(8, 'little') + data[8:] + record)
        where = rf'{name}\.bin'
    else:
        lines = path.read_text().splitlines()
        first = next(line for line in lines if not line.startswith('#'))
        path.write_text('\n'.join([*lines, first]) + '\n')
        where = rf'{name}\.txt:{len(lines) + 1}'
    what = name[:-1]
    with pytest.raises(FormatError, match=f'{where}: {what} id 1 appears twice'):
        colmap_rigs.read_rigs(tmp_path / 'in', images)
