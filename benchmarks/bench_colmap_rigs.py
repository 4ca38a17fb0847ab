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
"""COLMAP rig models pycolmap synthesizes: ``pmba solve`` against pycolmap's BA (not a test).

Usage::

    python benchmarks/bench_colmap_rigs.py            # 3 rigs x 2 cameras, 8 frames each

For each camera model: a noisy model (0.5 px pixels, perturbed frames and points) is solved
by ``pmba solve --init file`` and ``--init global``; the reprojection error RMS is measured
by pycolmap on the written model, against pycolmap's own bundle adjustment with the rigs and
cameras held (``refine_sensor_from_rig=False``); ``rig dev`` is the largest difference
between a written image's pose relative to its frame and its ``sensor_from_rig``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
from pathlib import Path
import tempfile
from typing import Any

import numpy as np
from pmba_ros.cli.main import main as pmba
import pycolmap

CAMERAS = {'OPENCV': [280.0, 275.0, 320.0, 240.0, -0.1, 0.02, 0.001, -0.001],
           'OPENCV_FISHEYE': [250.0, 250.0, 320.0, 240.0, 0.05, -0.01, 0.002, 0.0],
           'SIMPLE_RADIAL': [300.0, 320.0, 240.0, 0.05]}


def _rms_and_rig_deviation(rec: Any) -> tuple[float, float]:
    errors, deviation = [], 0.0
    for image in rec.images.values():
        pose, camera = image.cam_from_world(), rec.cameras[image.camera_id]
        for p in image.points2D:
            if p.has_point3D():
                xyz = pose * rec.points3D[p.point3D_id].xyz
                errors.append(camera.img_from_cam(xyz[None])[0] - p.xy)
    for frame in rec.frames.values():
        rig = rec.rigs[frame.rig_id]
        for data in frame.data_ids:
            rel = (rec.images[data.id].cam_from_world() * frame.rig_from_world.inverse()).matrix()
            offset = (np.eye(4)[:3] if data.sensor_id == rig.ref_sensor_id
                      else rig.sensor_from_rig(data.sensor_id).matrix())
            deviation = max(deviation, float(np.abs(rel - offset).max()))
    return float(np.sqrt(np.mean(np.sum(np.square(errors), axis=1)))), deviation


def main() -> None:
    """Run every camera model and print one line each."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--frames', type=int, default=8, help='frames per rig')
    parser.add_argument('--points', type=int, default=400)
    args = parser.parse_args()
    print(f'{"camera":<16}{"obs":>7}{"start px":>10}{"file px":>10}{"global px":>11}'
          f'{"colmap BA px":>14}{"rig dev":>10}')
    for name, params in CAMERAS.items():
        options = pycolmap.SyntheticDatasetOptions()
        options.num_rigs, options.num_cameras_per_rig = 3, 2
        options.num_frames_per_rig, options.num_points3D = args.frames, args.points
        options.camera_model_id = getattr(pycolmap.CameraModelId, name)
        options.camera_params = params
        options.camera_width, options.camera_height = 640, 480
        pycolmap.set_random_seed(0)
        rec = pycolmap.synthesize_dataset(options)
        noise = pycolmap.SyntheticNoiseOptions()
        noise.point2D_stddev, noise.point3D_stddev = 0.5, 0.02
        noise.rig_from_world_rotation_stddev, noise.rig_from_world_translation_stddev = 0.2, 0.02
        pycolmap.synthesize_noise(noise, rec)
        with tempfile.TemporaryDirectory() as tmp:
            start = Path(tmp) / 'start'
            start.mkdir()
            rec.write(str(start))
            start_rms = _rms_and_rig_deviation(rec)[0]
            ours, worst = [], 0.0
            for init in ('file', 'global'):
                out = Path(tmp) / init
                with contextlib.redirect_stdout(io.StringIO()):   # its summary: not ours
                    pmba(['solve', str(start), '--quiet', '--init', init, '--out', str(out)])
                rms, deviation = _rms_and_rig_deviation(pycolmap.Reconstruction(str(out)))
                ours.append(rms)
                worst = max(worst, deviation)
        pycolmap.bundle_adjustment(rec, pycolmap.BundleAdjustmentOptions(
            refine_focal_length=False, refine_principal_point=False, refine_extra_params=False,
            refine_sensor_from_rig=False, print_summary=False))
        print(f'{name:<16}{rec.compute_num_observations():>7}{start_rms:>10.6f}'
              f'{ours[0]:>10.6f}{ours[1]:>11.6f}{_rms_and_rig_deviation(rec)[0]:>14.6f}'
              f'{worst:>10.1e}')


if __name__ == '__main__':
    main()
