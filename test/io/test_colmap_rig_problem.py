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
"""Tests of COLMAP rigs held rigid (pmba_ros.io.colmap_rig_problem, ``pmba solve``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from test.io.test_colmap import _colmap_rms
from test.io.test_colmap_rigs import synthesize
from typing import Any

import numpy as np
from pmba_ros.cli.main import main
from pmba_ros.core.solve import solve
from pmba_ros.io import colmap, colmap_poses, colmap_rigs
from pmba_ros.io import colmap_rig_problem as rp
import pytest

pycolmap = pytest.importorskip('pycolmap')

CAMERAS = {'OPENCV': (280.0, 275.0, 320.0, 240.0, -0.1, 0.02, 0.001, -0.001),
           'SIMPLE_RADIAL': (300.0, 320.0, 240.0, 0.05)}


def _solve(directory: Path, out: Path, *extra: str) -> dict[str, Any]:
    report = out.parent / f'{out.name}.json'
    assert main(['solve', str(directory), '--quiet', '--out', str(out), '--report',
                 str(report), *extra]) == 0
    result: dict[str, Any] = json.loads(report.read_text())
    return result


def _pose(image: Any) -> Any:
    return image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world


def _check_written(out: Path) -> None:
    """Check that pycolmap reads the model; its image poses are ours, and each rig is rigid."""
    rec = pycolmap.Reconstruction(str(out))
    ours = colmap.read_colmap(out)
    for iid, image in rec.images.items():
        matrix = _pose(image).matrix()
        R = colmap_poses.quat_to_R(ours.images[iid].qvec[None])[0]
        np.testing.assert_allclose(matrix[:, :3], R, atol=1e-12)
        np.testing.assert_allclose(matrix[:, 3], ours.images[iid].tvec, atol=1e-9)
    for frame in rec.frames.values():
        rig = rec.rigs[frame.rig_id]
        for data in frame.data_ids:
            relative = (_pose(rec.images[data.id]) * frame.rig_from_world.inverse()).matrix()
            offset = (np.eye(4)[:3] if data.sensor_id == rig.ref_sensor_id
                      else rig.sensor_from_rig(data.sensor_id).matrix())
            np.testing.assert_allclose(relative, offset, atol=1e-9)


@pytest.mark.parametrize('binary', [False, True], ids=['text', 'binary'])
@pytest.mark.parametrize('camera', sorted(CAMERAS))
def test_noise_free_rig_models_solve_to_zero(tmp_path: Path, camera: str, binary: bool) -> None:
    """Noise-free rig models of pycolmap: one pose per frame, zero error, read back rigid."""
    synthesize(tmp_path / 'in', binary, camera, CAMERAS[camera])
    report = _solve(tmp_path / 'in', tmp_path / 'out')
    assert report['n_cams'] == 9 and report['final_rms_px'] < 1e-10
    ext = '.bin' if binary else '.txt'
    assert {p.name for p in (tmp_path / 'out').glob(f'*{ext}')} == {
        f'{n}{ext}' for n in ('cameras', 'images', 'points3D', 'rigs', 'frames')}
    _check_written(tmp_path / 'out')
    assert _colmap_rms(pycolmap.Reconstruction(str(tmp_path / 'out')))[0] < 1e-9


@pytest.mark.parametrize('camera', sorted(CAMERAS))
def test_noisy_rig_models_end_at_or_below_colmaps_rigid_ba(tmp_path: Path, camera: str) -> None:
    """0.5 px noise, perturbed frames: rigid rigs, at or below pycolmap's BA with rigs held.

    Measured by pycolmap on the written model, from the frames (``--init file``) and from
    the tracks alone (``--init global``).
    """
    synthesize(tmp_path / 'in', True, camera, CAMERAS[camera], noise=True, seed=1)
    theirs = pycolmap.Reconstruction(str(tmp_path / 'in'))
    pycolmap.bundle_adjustment(theirs, pycolmap.BundleAdjustmentOptions(
        refine_focal_length=False, refine_principal_point=False, refine_extra_params=False,
        refine_sensor_from_rig=False, print_summary=False))
    colmap_rms = _colmap_rms(theirs)[0]
    for init in ('file', 'global'):
        report = _solve(tmp_path / 'in', tmp_path / init, '--init', init)
        assert report['converged'] and report['n_cams'] == 9
        _check_written(tmp_path / init)
        rms, behind = _colmap_rms(pycolmap.Reconstruction(str(tmp_path / init)))
        assert behind == 0 and 0.3 < rms <= colmap_rms * (1 + 1e-4)
        assert report['final_rms_px'] == pytest.approx(rms, rel=1e-3)


def test_rigs_not_held_are_solved_as_images_and_written_without_them(tmp_path: Path) -> None:
    """--param xyz holds no rigs: independent images, a warning, no rigs or frames written."""
    synthesize(tmp_path / 'in', True, noise=True)
    report = _solve(tmp_path / 'in', tmp_path / 'out', '--param', 'xyz', '--solver', 'lm')
    assert report['n_cams'] == 18
    assert any('rigs not held rigid' in w for w in report['warnings'])
    assert not (tmp_path / 'out' / 'frames.bin').exists()
    assert pycolmap.Reconstruction(str(tmp_path / 'out')).num_images() == 18


def test_one_camera_rigs_are_independent_images_with_their_frames_written(
        tmp_path: Path) -> None:
    """A rig of one camera is today's independent image; its frame follows the image."""
    options = pycolmap.SyntheticDatasetOptions()
    options.num_rigs, options.num_cameras_per_rig, options.num_frames_per_rig = 2, 1, 4
    options.num_points3D = 60
    pycolmap.set_random_seed(2)
    rec = pycolmap.synthesize_dataset(options)
    noise = pycolmap.SyntheticNoiseOptions()
    noise.point2D_stddev = 0.5
    pycolmap.synthesize_noise(noise, rec)
    (tmp_path / 'in').mkdir()
    rec.write_text(str(tmp_path / 'in'))
    report = _solve(tmp_path / 'in', tmp_path / 'out')
    assert report['n_cams'] == 8 and 'warnings' not in report
    assert (tmp_path / 'out' / 'frames.txt').is_file()
    _check_written(tmp_path / 'out')
    assert _colmap_rms(pycolmap.Reconstruction(str(tmp_path / 'out')))[0] == pytest.approx(
        report['final_rms_px'], rel=1e-3)


def test_an_image_in_no_frame_is_a_pose_of_its_own(tmp_path: Path) -> None:
    """Not a model COLMAP writes: the lone image is solved through an identity camera."""
    synthesize(tmp_path, True)
    model = colmap.read_colmap(tmp_path)
    rigs = colmap_rigs.read_rigs(tmp_path, model.images)
    assert rigs is not None
    frame = rigs.frames[1]
    rigs = dataclasses.replace(rigs, frames={**rigs.frames, 1: dataclasses.replace(
        frame, data_ids=frame.data_ids[:1])})
    images, image_ids = colmap.to_problem(model)
    layout = rp.rig_layout(model, rigs, image_ids)
    lone = int(frame.data_ids[1, 2])
    assert layout.frame_ids.tolist() == [*range(1, 10), -1] and len(layout.rig) == 7
    k = image_ids.tolist().index(lone)
    assert layout.pose_of_image[k] == 9 and layout.camera_of_image[k] == 6
    assert images.points_w is not None
    problem, poses = rp.to_rig_problem(images, layout, layout.R_wc, layout.centers_w,
                                       images.points_w)
    assert poses.tolist() == list(range(10))
    index, R_wc, centers = rp.image_poses(layout, poses, problem.R_wc, problem.centers_w)
    np.testing.assert_allclose(R_wc, images.R_wc[index], atol=1e-12)
    np.testing.assert_allclose(centers, images.centers_w[index], atol=1e-9)
    assert solve(problem).final_rms_px < 1e-10


def test_frames_from_images_fit_the_rig_scale(tmp_path: Path) -> None:
    """Image poses at another scale and rotation give the frames back, and the scale."""
    synthesize(tmp_path, True)
    model = colmap.read_colmap(tmp_path)
    rigs = colmap_rigs.read_rigs(tmp_path, model.images)
    assert rigs is not None
    images, image_ids = colmap.to_problem(model)
    layout = rp.rig_layout(model, rigs, image_ids)
    some = np.arange(1, image_ids.shape[0])      # one image left out: its frame has one
    poses, R_wr, C_r, scale = rp.frames_from_images(
        layout, some, images.R_wc[some], 0.25 * images.centers_w[some])
    assert poses.tolist() == list(range(9)) and scale == pytest.approx(4.0, rel=1e-9)
    np.testing.assert_allclose(R_wr, layout.R_wc, atol=1e-12)
    np.testing.assert_allclose(C_r, layout.centers_w, atol=1e-9)


def test_a_camera_without_its_offset_is_not_held(tmp_path: Path) -> None:
    """sensor_from_rig unknown: no rig problem (a FormatError naming it) and a fallback."""
    synthesize(tmp_path / 'in', True)
    model = colmap.read_colmap(tmp_path / 'in')
    rigs = colmap_rigs.read_rigs(tmp_path / 'in', model.images)
    assert rigs is not None
    rig = rigs.rigs[1]
    sensors = (dataclasses.replace(rig.sensors[0], pose=None),)
    rigs = dataclasses.replace(rigs, rigs={**rigs.rigs, 1: dataclasses.replace(
        rig, sensors=sensors)})
    assert rp.unknown_offsets(rigs) == [f'rig 1 camera {sensors[0].sensor_id}']
    with pytest.raises(colmap.FormatError, match='without sensor_from_rig'):
        rp.rig_layout(model, rigs, colmap.to_problem(model)[1])
    colmap_rigs.write_rigs(tmp_path / 'in', rigs, binary=True)
    report = _solve(tmp_path / 'in', tmp_path / 'out')
    assert report['n_cams'] == 18 and any('without sensor_from_rig' in w
                                          for w in report['warnings'])


def test_a_frame_whose_pose_is_none_is_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A frame's zero quaternion: one error naming the frame (a rotation of NaNs before)."""
    synthesize(tmp_path, binary=False)
    frames = tmp_path / 'frames.txt'
    lines = frames.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if not line.startswith('#'))
    head = lines[k].split()
    head[2:6] = ['0', '0', '0', '0']
    lines[k] = ' '.join(head)
    frames.write_text('\n'.join(lines) + '\n')
    assert main(['solve', str(tmp_path), '--quiet']) == 1
    err = capsys.readouterr().err
    assert f'error: COLMAP frame {head[0]}: its pose (quaternion 0 0 0 0' in err
