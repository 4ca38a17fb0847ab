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
"""Write a simulated sequence as a recording that looks like a real visual front-end's output.

The bag carries, per keyframe stamp (``ros2_notes.md`` §3.1):

The default topics are the node's default (relative) input names resolved in the root
namespace, so ``pmba replay`` reads the bag without topic options.

* feature tracks on :attr:`SimTopics.tracks`: ``sensor_msgs/PointCloud`` in a VINS layout
  (default ``vins_fusion``, the node's default) or ``sensor_msgs/PointCloud2`` with named
  fields (``named``);
* the drifting front-end keyframe pose on :attr:`SimTopics.keyframes` as
  ``nav_msgs/Odometry`` (frame ``world``, child ``body``). Without ``extrinsic`` the body is
  the camera; with it (:data:`EUROC_CAM0` for EuRoC's cam0) the keyframe poses and the ground
  truth are body poses and ``/tf_static`` carries body -> camera, as VINS-style front-ends
  publish them;
* ``sensor_msgs/CameraInfo`` on :attr:`SimTopics.camera_info` (camera c > 0 of a rig on
  :meth:`SimTopics.camera_info_of`, with its body -> camera transform on ``/tf_static``);
* the ground truth as ``geometry_msgs/PoseStamped`` on :attr:`SimTopics.groundtruth`;
* with :attr:`SimTopics.extrinsic` (``--frontend``), the front-end's own body -> camera 0
  ``nav_msgs/Odometry`` there, stamped with the newest frame as VINS publishes it (two
  keyframes ahead of the pose it comes with), and keyframe poses without a child frame.

Messages are logged with a small, fixed receive latency after their header stamp (tracks
5 ms, keyframe poses 30 ms, like an estimator that publishes after its update), so the log
order differs from the stamp order as in a real recording. The ground truth also goes to a
TUM file. Everything is deterministic: the same sequence gives the same bytes.
"""

from __future__ import annotations

from dataclasses import dataclass
import logging
from pathlib import Path
from typing import Protocol, TYPE_CHECKING

import numpy as np
from pmba_ros.backend.extrinsics import Rigid
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.backend.outputs import make_odometry, make_pose_stamped, make_tf
from pmba_ros.backend.tracks import LAYOUTS
from pmba_ros.core import so3
from pmba_ros.errors import BagError
from pmba_ros.eval.trajectory import Trajectory, write_tum
from pmba_ros.io.bag_writer import open_writer
from pmba_ros.io.bags import jazzy_typestore
from pmba_ros.sim.inputs import make_camera_info, make_tracks

if TYPE_CHECKING:
    from collections.abc import Sequence

    from pmba_ros._typing import FloatArray, IntArray
    from pmba_ros.backend.types import CameraModel, TrackFrame

logger = logging.getLogger(__name__)

TRACKS_LATENCY_NS = 5_000_000
"""Log time minus header stamp of a tracks message, ns."""
KEYFRAME_LATENCY_NS = 30_000_000
"""Log time minus header stamp of a keyframe pose, ns."""
GT_FILENAME = 'groundtruth.tum'
"""Name of the ground-truth TUM file inside a bag folder."""
TF_STATIC_TOPIC = '/tf_static'

EUROC_CAM0 = Rigid(
    so3.project(np.array([[0.0148655429818, -0.999880929698, 0.00414029679422],
                          [0.999557249008, 0.0149672133247, 0.025715529948],
                          [-0.0257744366974, 0.00375618835797, 0.999660727178]])),
    np.array([-0.0216401454975, -0.064676986768, 0.00981073058949]))
"""EuRoC MAV cam0 extrinsic T_BS (body = IMU -> camera), from the dataset's sensor.yaml."""


class SequenceLike(Protocol):
    """What :func:`write_sequence_bag` reads from a simulated sequence (read-only)."""

    @property
    def stamps_ns(self) -> IntArray:
        """Keyframe stamps, shape (F,), ns."""

    @property
    def R_wc_gt(self) -> FloatArray | None:
        """True camera -> world rotations, shape (F, 3, 3), or None."""

    @property
    def centers_gt(self) -> FloatArray | None:
        """True camera centres, shape (F, 3), or None."""

    @property
    def R_wc_odom(self) -> FloatArray:
        """Front-end rotations, shape (F, 3, 3)."""

    @property
    def centers_odom(self) -> FloatArray:
        """Front-end camera centres, shape (F, 3)."""

    @property
    def frames(self) -> Sequence[TrackFrame]:
        """One track frame per keyframe."""

    @property
    def camera(self) -> CameraModel:
        """The camera model."""

    @property
    def points_w(self) -> FloatArray:
        """True points (row j = feature id j), shape (N, 3)."""


@dataclass(frozen=True)
class SimTopics:
    """Topic and frame names of a simulated front-end recording.

    Attributes:
        tracks: Feature tracks.
        keyframes: Keyframe poses (Odometry).
        camera_info: Intrinsics.
        groundtruth: Ground-truth poses (PoseStamped).
        world_frame: Front-end world (odom) frame.
        body_frame: Odometry child frame (with an extrinsic; else the camera frame).
        camera_frame: Camera optical frame (tracks, CameraInfo).
        extrinsic: The front-end's body -> camera 0 Odometry topic ('': none). VINS-Mono,
            VINS-Fusion and OpenVINS publish one and leave the keyframe poses' child frame
            empty, so that TF cannot name their body.
    """

    tracks: str = '/features'
    keyframes: str = '/keyframe_pose'
    camera_info: str = '/camera_info'
    groundtruth: str = '/groundtruth/pose'
    world_frame: str = 'world'
    body_frame: str = 'body'
    camera_frame: str = 'camera'
    extrinsic: str = ''

    def camera_info_of(self, camera: int) -> str:
        """Return the CameraInfo topic of camera id ``camera`` (0: :attr:`camera_info`)."""
        return self.camera_info if camera == 0 else f'/camera{camera}/camera_info'

    def camera_frame_of(self, camera: int) -> str:
        """Return the optical frame of camera id ``camera`` (0: :attr:`camera_frame`)."""
        return self.camera_frame if camera == 0 else f'{self.camera_frame}{camera}'


@dataclass(frozen=True)
class SimBagInfo:
    """What :func:`write_sequence_bag` wrote.

    Attributes:
        bag: The recording (folder, or ``.mcap`` file).
        groundtruth_tum: The ground-truth TUM file (None without ground truth).
        n_keyframes: Keyframes written.
        n_messages: Messages written.
        n_observations: Feature observations written.
        duration_s: Stamp span of the recording, s.
    """

    bag: Path
    groundtruth_tum: Path | None
    n_keyframes: int
    n_messages: int
    n_observations: int
    duration_s: float


def groundtruth_path(bag: Path | str) -> Path:
    """Return where :func:`write_sequence_bag` puts the ground truth of ``bag``.

    Args:
        bag: A bag folder or ``.mcap`` file.

    Returns:
        ``bag/groundtruth.tum`` for a folder, ``<stem>_groundtruth.tum`` beside a file.
    """
    bag = Path(bag)
    if bag.suffix == '.mcap':
        return bag.with_name(f'{bag.stem}_groundtruth.tum')
    return bag / GT_FILENAME


def sequence_trajectory(stamps_ns: IntArray, R_wc: FloatArray, centers: FloatArray) -> Trajectory:
    """Return camera poses as an eval :class:`Trajectory` (stamps in seconds)."""
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    return Trajectory(stamps.astype(np.float64) * 1e-9, np.asarray(centers, dtype=np.float64),
                      np.asarray(R_wc, dtype=np.float64))


def write_sequence_bag(seq: SequenceLike, out: Path | str, *, layout: str = 'vins_fusion',
                       topics: SimTopics | None = None, overwrite: bool = False,
                       extrinsic: Rigid | None = None,
                       rig_extrinsics: Sequence[Rigid] = ()) -> SimBagInfo:
    """Write a simulated sequence as a front-end-like rosbag2 MCAP recording plus GT TUM.

    Args:
        seq: The sequence (``pmba_ros.sim.sequence.SimSequence``, or a
            :class:`~pmba_ros.io.kitti_tracks.KittiSequence`); ground truth is written when
            ``seq.R_wc_gt`` is not None.
        out: Bag folder, or a ``.mcap`` file path.
        layout: Track layout, one of ``vins_mono``, ``vins_fusion``, ``per_point``
            (PointCloud) or ``named`` (PointCloud2).
        topics: Topic and frame names; default :class:`SimTopics`.
        overwrite: Replace an existing output.
        extrinsic: Body -> camera transform T_bc: keyframe poses and ground truth become body
            poses ``T_wb = T_wc T_bc^-1`` and ``/tf_static`` carries body -> camera. None:
            the poses are the camera's.
        rig_extrinsics: Body -> camera transforms of cameras 1, 2, ... of a rig (their
            observations are in the frames, see :func:`pmba_ros.sim.rig.add_camera`); each
            gets a CameraInfo topic and a ``/tf_static`` transform. Needs ``extrinsic``.

    Returns:
        A summary of what was written.

    Raises:
        BagError: If the output exists or cannot be written, or the layout is unknown.
        MessageError: If a frame cannot be expressed in the layout.
    """
    if layout not in LAYOUTS:
        msg = f'unknown track layout {layout!r} (expected one of {", ".join(LAYOUTS)})'
        raise BagError(msg)
    topics = topics or SimTopics()
    if rig_extrinsics and extrinsic is None:
        msg = 'write_sequence_bag: a rig needs the extrinsic of camera 0 too'
        raise BagError(msg)
    cameras = [extrinsic, *rig_extrinsics] if extrinsic is not None else []
    out = Path(out)
    stamps = np.asarray(seq.stamps_ns, dtype=np.int64)
    n_kf = int(stamps.shape[0])
    if len(seq.frames) != n_kf:
        msg = f'sequence has {n_kf} stamps but {len(seq.frames)} track frames'
        raise BagError(msg)
    backend = RosbagsBackend(jazzy_typestore())
    to_body = (extrinsic or Rigid.identity()).inverse()
    R_odom, c_odom = to_body.apply_to_poses(np.asarray(seq.R_wc_odom),
                                            np.asarray(seq.centers_odom))
    q_odom = so3.to_quat_xyzw(R_odom)
    has_gt = seq.R_wc_gt is not None and seq.centers_gt is not None
    R_gt = c_gt = q_gt = None
    if has_gt:
        R_gt, c_gt = to_body.apply_to_poses(np.asarray(seq.R_wc_gt), np.asarray(seq.centers_gt))
        q_gt = so3.to_quat_xyzw(R_gt)
    points_w = np.asarray(seq.points_w, dtype=np.float64)
    odom_cov = np.diag([1e-2, 1e-2, 1e-2, 1e-3, 1e-3, 1e-3])
    # Without an extrinsic the poses are the camera's: their child frame says so, as a
    # monocular front-end publishing camera poses does (no body -> camera warning). A
    # front-end with an extrinsic topic names no child frame (VINS, OpenVINS).
    pose_frame = topics.body_frame if cameras else topics.camera_frame
    if topics.extrinsic:
        pose_frame = ''
    T_bc0 = extrinsic or Rigid.identity()
    n_obs = 0
    with open_writer(out, overwrite=overwrite, keep_on_error=False) as writer:
        for c, T_bc in enumerate(cameras if n_kf else []):
            writer.write(TF_STATIC_TOPIC, make_tf(int(stamps[0]), topics.body_frame,
                                                  topics.camera_frame_of(c), T_bc.translation,
                                                  so3.to_quat_xyzw(T_bc.rotation),
                                                  backend), int(stamps[0]))
        for i in range(n_kf):
            stamp = int(stamps[i])
            frame = seq.frames[i]
            n_obs += len(frame)
            for c in range(max(1, len(cameras))):
                writer.write(topics.camera_info_of(c),
                             make_camera_info(stamp, topics.camera_frame_of(c), seq.camera,
                                              backend), stamp)
            if q_gt is not None and c_gt is not None:
                writer.write(topics.groundtruth,
                             make_pose_stamped(stamp, topics.world_frame, c_gt[i], q_gt[i],
                                               backend), stamp)
            landmarks = None
            if layout in ('per_point', 'named') and len(frame) and len(points_w):
                ids = np.asarray(frame.feature_ids)
                if ids.max() < points_w.shape[0]:
                    landmarks = points_w[ids]
            tracks = make_tracks(_with_frame(frame, stamp, topics.camera_frame), layout,
                                 backend, max(1, len(cameras)), landmarks_xyz=landmarks)
            writer.write(topics.tracks, tracks, stamp + TRACKS_LATENCY_NS)
            if topics.extrinsic:
                writer.write(topics.extrinsic,
                             make_odometry(int(stamps[min(i + 2, n_kf - 1)]), topics.world_frame,
                                           '', T_bc0.translation, so3.to_quat_xyzw(T_bc0.rotation),
                                           odom_cov, backend),
                             stamp + KEYFRAME_LATENCY_NS)
            writer.write(topics.keyframes,
                         make_odometry(stamp, topics.world_frame, pose_frame,
                                       c_odom[i], q_odom[i], odom_cov, backend),
                         stamp + KEYFRAME_LATENCY_NS)
        n_messages = writer.count
    gt_path = groundtruth_path(out) if has_gt else None
    if gt_path is not None and R_gt is not None and c_gt is not None:
        write_tum(gt_path, sequence_trajectory(stamps, R_gt, c_gt))
    duration = float(stamps[-1] - stamps[0]) * 1e-9 if n_kf else 0.0
    logger.info('wrote %s: %d keyframes, %d messages, %d observations', out, n_kf, n_messages,
                n_obs)
    return SimBagInfo(out, gt_path, n_kf, n_messages, n_obs, duration)


def _with_frame(frame: TrackFrame, stamp_ns: int, frame_id: str) -> TrackFrame:
    """Return ``frame`` with the given stamp and frame id (same observations)."""
    if frame.stamp_ns == stamp_ns and frame.frame_id == frame_id:
        return frame
    return type(frame)(stamp_ns, frame_id, frame.feature_ids, frame.camera_ids, frame.pixels,
                       frame.normalized, frame.dropped)


__all__ = ['EUROC_CAM0', 'GT_FILENAME', 'KEYFRAME_LATENCY_NS', 'TRACKS_LATENCY_NS', 'SimBagInfo',
           'SimTopics', 'groundtruth_path', 'sequence_trajectory', 'write_sequence_bag']
