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
"""The keyframes' outputs: body poses in map_frame, path, pose array, odometry, map -> odom.

The estimator keeps camera poses; everything published is the body's, through the
body -> camera extrinsic (identity until one is known). Stamps come from the keyframes.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.backend import outputs as out
from pmba_ros.backend.cameras import FrontendCameras
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.estimator import Estimator
from pmba_ros.backend.extrinsics import Rigid
from pmba_ros.backend.msg_backend import MsgBackend
from pmba_ros.backend.window import KeyframeStatus
from pmba_ros.core import so3

TF_TOPIC = '/tf'


class KeyframeOutputs:
    """Builds the keyframe outputs of one run (a reset starts a new one).

    Args:
        estimator: The estimator whose keyframes are published.
        cameras: The front-end's cameras (the reference camera's extrinsic).
        backend: Builds the messages.
        config: The configuration (the frames' names).
    """

    def __init__(self, estimator: Estimator, cameras: FrontendCameras, backend: MsgBackend,
                 config: BackendConfig) -> None:
        """Start a run: no pose message built yet, the configured frames or the defaults."""
        self.estimator = estimator
        self.cameras = cameras
        self.backend = backend
        self.name_frames(config, '', '')
        self._published = out.PoseMessageCache()
        self._map_version = estimator.map_version

    def name_frames(self, config: BackendConfig, odom_frame: str, body_frame: str) -> None:
        """Take the frames of a keyframe pose where the configuration names none.

        Attributes set: ``odom_frame`` and ``base_frame`` (the defaults where neither names one).
        """
        self.odom_frame = config.odom_frame or odom_frame or 'odom'
        self.base_frame = config.base_frame or body_frame or 'base_link'

    def _camera_to_body(self) -> Rigid:
        """Return T_cb (identity until an extrinsic is known)."""
        extrinsic = self.cameras.extrinsic
        return Rigid.identity() if extrinsic is None else extrinsic.inverse()

    def body_poses(self, idx: np.ndarray) -> tuple[FloatArray, FloatArray]:
        """Return the map-frame body poses (R (n, 3, 3), positions (n, 3)) of keyframes idx."""
        kf = self.estimator.kf
        return self._camera_to_body().apply_to_poses(kf.R_map[idx], kf.C_map[idx])

    def frontend_body_poses(self, idx: np.ndarray) -> tuple[FloatArray, FloatArray]:
        """Return the front-end (odom-frame) body poses of keyframes idx, as received."""
        kf = self.estimator.kf
        return self._camera_to_body().apply_to_poses(kf.R_odom[idx], kf.C_odom[idx])

    def map_from_odom_at(self, i: int) -> Rigid:
        """REP-105: T_map_odom = T_map_body (back-end) * T_odom_body (front-end)^-1 at i."""
        idx = np.array([i])
        R_m, C_m = self.body_poses(idx)
        R_o, C_o = self.frontend_body_poses(idx)
        R = so3.project(R_m[0] @ R_o[0].T)
        return Rigid(R, C_m[0] - R @ C_o[0])

    def messages(self, config: BackendConfig, stamp: int) -> list[tuple[str, Any]]:
        """Return path, keyframes and landmarks, and odometry and TF if keyframe ``stamp`` is.

        Args:
            config: The configuration now (topics, frames, ``publish_tf``).
            stamp: The newest processed keyframe's stamp, ns.
        """
        idx = self.estimator.estimated()
        if not idx.shape[0]:
            return []
        kf = self.estimator.kf
        stamped, plain = self._poses(config, idx)
        header = out.header_msg(stamp, config.map_frame, self.backend)
        result = [
            (config.path_topic, self.backend.new('nav_msgs/msg/Path', header=header,
                                                 poses=stamped)),
            (config.keyframes_topic, self.backend.new('geometry_msgs/msg/PoseArray',
                                                      header=header, poses=plain)),
            (config.landmarks_topic, out.make_point_cloud2_xyz(
                stamp, config.map_frame, self.estimator.landmark_points(), self.backend))]
        last = int(idx[-1])
        if int(kf.stamps_ns[last]) == stamp:
            result.append((config.odometry_topic, self._odometry(config, last)))
            if config.publish_tf and kf.has_odom[last]:
                result.append((TF_TOPIC, self._map_to_odom(config, last)))
        return result

    def _poses(self, config: BackendConfig, idx: np.ndarray) -> tuple[list[Any], list[Any]]:
        """Return PoseStamped and Pose messages of keyframes ``idx`` (built incrementally).

        Fixed keyframes are final, and dead-reckoned ones older than a fixed one (placed
        between fixed neighbours, :mod:`~pmba_ros.backend.gaps`), and passed-through ones once
        tracking: their messages are kept (:class:`~pmba_ros.backend.outputs.PoseMessageCache`)
        until the estimator rescales the whole map.
        """
        kf = self.estimator.kf
        if self.estimator.map_version != self._map_version:   # the whole map was rescaled
            self._published = out.PoseMessageCache()
            self._map_version = self.estimator.map_version
        status = kf.status[idx]
        fixed = idx[status == KeyframeStatus.FIXED]
        final = (status == KeyframeStatus.FIXED) | (
            (status == KeyframeStatus.DEAD_RECKONED) & (idx < (fixed[-1] if fixed.size else 0)))
        if self.estimator.state == 'tracking':  # passed through before the initialization
            final |= status == KeyframeStatus.PASSED_THROUGH

        def build(sel: np.ndarray) -> list[Any]:
            R, C = self.body_poses(sel)
            return out.pose_stamped_msgs(kf.stamps_ns[sel], config.map_frame, C,
                                         so3.to_quat_xyzw(R), self.backend)

        return self._published.update(idx, final, build)

    def _odometry(self, config: BackendConfig, i: int) -> Any:
        cov = config.odometry_covariance(
            optimized=bool(self.estimator.optimized(np.array([i]))[0]))
        R, C = self.body_poses(np.array([i]))
        return out.make_odometry(int(self.estimator.kf.stamps_ns[i]), config.map_frame,
                                 self.base_frame, C[0], so3.to_quat_xyzw(R[0]), cov, self.backend)

    def _map_to_odom(self, config: BackendConfig, i: int) -> Any:
        """Return the map -> odom TF at keyframe i (see :meth:`map_from_odom_at`)."""
        T = self.map_from_odom_at(i)
        stamp = int(self.estimator.kf.stamps_ns[i]) + round(config.transform_tolerance_s * 1e9)
        return out.make_tf(stamp, config.map_frame, self.odom_frame, T.translation,
                           so3.to_quat_xyzw(T.rotation), self.backend)
