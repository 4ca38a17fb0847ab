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
"""``pmba import-tracks``: KITTI-00 stereo feature tracks -> a monocular front-end bag.

Usage examples::

    pmba import-tracks --out kitti00_bag
    pmba replay kitti00_bag --out kitti00_out --gt kitti00_bag/groundtruth.tum

The left image of GTSAM's KITTI-00 stereo VO example (``VO_*00s.txt``) acts as a monocular
front-end: its ``(uL, v)`` observations become tracks, the VO poses the keyframe poses. With
the KITTI ground truth (default: the shared data) the keyframes' KITTI frames are found by
comparing relative motions, the stamps come from KITTI's times file, and the ground truth of
those frames is written as ``BAG/groundtruth.tum`` and a ``PoseStamped`` topic.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from pmba_ros.cli.argtypes import non_negative_int, positive_int

if TYPE_CHECKING:
    import argparse


def shared_data_dir() -> Path:
    """Return the shared data folder (``$PMBA_SHARED_DATA`` or ``../shared/data``)."""
    env = os.environ.get('PMBA_SHARED_DATA')
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / 'shared' / 'data'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the arguments of the ``import-tracks`` verb.

    Args:
        parser: Parser (or subparser) to add the arguments to.
    """
    data = shared_data_dir()
    parser.add_argument('--out', required=True, type=Path, metavar='BAG',
                        help='output bag folder or .mcap file')
    parser.add_argument('--tracks-dir', type=Path, default=data / 'kitti00_stereo_vo',
                        metavar='DIR', help='folder with the VO_*00s.txt files')
    parser.add_argument('--gt', type=Path, default=data / 'trajectories/evo/KITTI_00_gt.txt',
                        metavar='FILE', help='KITTI 00 ground truth (KITTI format); "none" '
                        'to skip')
    parser.add_argument('--times', type=Path,
                        default=data / 'trajectories/evo/KITTI_00_gt_times.txt',
                        metavar='FILE', help='KITTI 00 times.txt (stamps); "none": 10 Hz')
    parser.add_argument('--first-frame', type=non_negative_int, default=None, metavar='N',
                        help='KITTI frame of the first VO pose (default: found from the GT)')
    parser.add_argument('--stride', type=positive_int, default=None, metavar='S',
                        help='KITTI frames between VO poses (default: found from the GT)')
    parser.add_argument('--layout', choices=('vins_mono', 'vins_fusion', 'per_point', 'named'),
                        default='vins_fusion', help='track layout')
    parser.add_argument('--stereo', action='store_true',
                        help='also the right image observations (camera 1, a second CameraInfo '
                        'on /camera1/camera_info; both cameras on /tf_static)')
    parser.add_argument('--overwrite', action='store_true', help='replace an existing output')


def _optional(path: Path | None) -> Path | None:
    """Return None for the path 'none'."""
    return None if path is None or str(path).lower() == 'none' else path


def run(args: argparse.Namespace) -> int:
    """Convert the KITTI tracks into a bag.

    Args:
        args: Parsed arguments (see :func:`add_arguments`).

    Returns:
        0 on success.

    Raises:
        PmbaError: If an input is missing or malformed, or the bag cannot be written.
    """
    from pmba_ros.backend.extrinsics import Rigid
    from pmba_ros.eval.trajectory import read_kitti, read_times
    from pmba_ros.io.kitti_tracks import kitti_sequence, read_kitti_tracks, right_camera
    from pmba_ros.sim.bag import write_sequence_bag

    stereo = bool(getattr(args, 'stereo', False))
    tracks = read_kitti_tracks(args.tracks_dir, stereo=stereo)
    times_path, gt_path = _optional(args.times), _optional(args.gt)
    # Read as evaluate reads them: a line that is no time, or an absurd time, is named.
    times = read_times(times_path) if times_path is not None else None
    gt = read_kitti(gt_path, times) if gt_path is not None else None
    seq = kitti_sequence(tracks, times, gt, first_frame=args.first_frame, stride=args.stride)
    # Stereo: the keyframe poses are the left camera's, the body frame of a two-camera rig.
    info = write_sequence_bag(seq, args.out, layout=args.layout, overwrite=args.overwrite,
                              extrinsic=Rigid.identity() if stereo else None,
                              rig_extrinsics=[right_camera(tracks.baseline_m)] if stereo else [])
    last = seq.first_frame + seq.stride * (info.n_keyframes - 1)
    print(f'wrote {info.bag}: {info.n_keyframes} keyframes = KITTI 00 frames '
          f'{seq.first_frame}..{last} (stride {seq.stride}), {info.n_observations} '
          f'observations, {info.duration_s:.2f} s')
    if info.groundtruth_tum is not None:
        print(f'ground truth: {info.groundtruth_tum}')
    if stereo:
        print('replay it with: pmba replay BAG --camera-info-topic /camera_info '
              '--camera-info-topic /camera1/camera_info --align se3')
    return 0
