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
"""Simulated multi-camera rigs: a second (third, ...) camera observing a sequence's features.

A stereo front-end such as VINS-Fusion tracks features in the left camera and matches them in
the right one: :func:`add_camera` projects every feature a keyframe's camera 0 observes into
another camera rigidly mounted on it (``T_c0c``, the camera in camera 0's frame) and appends
the visible ones, with pixel noise, under that camera id. The ground truth and front-end poses
stay camera 0's.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pmba_ros.backend.extrinsics import Rigid
from pmba_ros.backend.types import TrackFrame
from pmba_ros.core import so3
from pmba_ros.sim.sequence import SimSequence

EUROC_CAM1 = Rigid(
    so3.project(np.array([[0.0125552670891, -0.999755099723, 0.0182237714554],
                          [0.999598781151, 0.0130119051815, 0.0251588363115],
                          [-0.0253898008918, 0.0179005838253, 0.999517347078]])),
    np.array([-0.0198435579556, 0.0453689425024, 0.00786212447038]))
"""EuRoC MAV cam1 extrinsic T_BS (body = IMU -> camera), from the dataset's sensor.yaml."""

_MIN_DEPTH_M = 0.5


def add_camera(seq: SimSequence, T_c0c: Rigid, camera_id: int = 1, seed: int = 0) -> SimSequence:
    """Return ``seq`` with the observations of one more rig camera in every frame.

    Args:
        seq: The sequence (its frames are camera 0's).
        T_c0c: The new camera's pose in camera 0's frame.
        camera_id: Its camera id in the track frames (>= 1).
        seed: Seed of its pixel noise (``seq.noise_px``).

    Returns:
        A sequence whose frames also hold the new camera's observations of the features
        camera 0 sees there (those in front of it and inside its image).

    Raises:
        ValueError: If ``camera_id`` is 0 or already in the frames.
    """
    if camera_id < 1 or any(np.any(f.camera_ids == camera_id) for f in seq.frames):
        msg = f'add_camera: camera id {camera_id} must be >= 1 and new to the sequence'
        raise ValueError(msg)
    rng = np.random.default_rng(seed)
    cam = seq.camera
    R_wc, C_w = T_c0c.apply_to_poses(seq.R_wc_gt, seq.centers_gt)
    frames = []
    for i, frame in enumerate(seq.frames):
        first = frame.camera_ids == 0
        ids = frame.feature_ids[first]
        h = (seq.points_w[ids] - C_w[i]) @ R_wc[i]
        vis = h[:, 2] > _MIN_DEPTH_M
        pix = cam.denormalize(h[:, :2] / np.where(vis, h[:, 2], 1.0)[:, None])
        vis &= ((pix[:, 0] >= 0) & (pix[:, 0] < cam.width) & (pix[:, 1] >= 0)
                & (pix[:, 1] < cam.height) & np.all(np.isfinite(pix), axis=1))
        pix = pix[vis] + rng.normal(0.0, seq.noise_px, (int(vis.sum()), 2))
        frames.append(_extended(frame, ids[vis], camera_id, pix, cam.normalize(pix)))
    return replace(seq, frames=frames)


def _extended(frame: TrackFrame, ids: np.ndarray, camera_id: int, pixels: np.ndarray,
              normalized: np.ndarray) -> TrackFrame:
    """Return ``frame`` with observations of ``camera_id`` appended."""
    def cat(a: np.ndarray | None, b: np.ndarray) -> np.ndarray | None:
        return None if a is None else np.concatenate([a, b])
    return TrackFrame(frame.stamp_ns, frame.frame_id,
                      np.concatenate([frame.feature_ids, ids.astype(np.int64)]),
                      np.concatenate([frame.camera_ids,
                                      np.full(ids.shape[0], camera_id, dtype=np.int64)]),
                      cat(frame.pixels, pixels), cat(frame.normalized, normalized),
                      frame.dropped)
