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
"""COLMAP rigs held rigid: one pose per frame, each image through its camera's offset.

A model whose frames' rigs have more than one camera is solved with one pose per frame, the
rig frame's, and a :class:`~pmba_ros.core.problem.Rig` whose cameras are every (rig, camera)
pair of the model's rigs: an observation names its image's pair, so a frame is observed only
through its own rig's cameras, and the offsets of one rig stay those of its file. The offsets
(``sensor_from_rig``) are held fixed: COLMAP can refine them, this package does not. An image
in no frame (not a model COLMAP writes) is a pose of its own through an identity camera.

Each image keeps its own camera: the bearings and pixel Jacobians are those of the
independent-image problem of :func:`~pmba_ros.io.colmap.to_problem` (each image undistorted
by its own camera model), and the pixels are nominal ones, the bearings through the pinhole
of the frame's first image, as the back-end's rig does (its errors are weighed by each
camera's own pixels, ``pixel_jac``).

Conventions: ``sensor_from_rig`` (R_sr, t_sr) is the core rig's ``R_rc = R_sr^T``,
``t_rc = -R_sr^T t_sr``; a frame's ``rig_from_world`` (q, t) is the pose
``R_wc = R(q)^T, C = -R(q)^T t`` of the rig frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import logging
from typing import TYPE_CHECKING

import numpy as np
from pmba_ros.core import so3
from pmba_ros.core.camera import Intrinsics, project, projection_jacobian
from pmba_ros.core.problem import make_problem, Rig
from pmba_ros.errors import FormatError, ProblemError
from pmba_ros.io.colmap_poses import check_poses, poses_from_colmap, poses_to_colmap

if TYPE_CHECKING:
    from pmba_ros._typing import BoolArray, FloatArray, IntArray
    from pmba_ros.core.problem import BAProblem
    from pmba_ros.io.colmap import ColmapModel
    from pmba_ros.io.colmap_rigs import ColmapRigs

logger = logging.getLogger(__name__)

__all__ = ['RigLayout', 'frames_from_images', 'image_poses', 'rig_layout', 'to_rig_problem',
           'unknown_offsets', 'updated_frames']


@dataclass(frozen=True, eq=False)
class RigLayout:
    """Where a model's images sit on the poses and cameras of its rig problem.

    Attributes:
        image_ids: The images, in the order of :func:`~pmba_ros.io.colmap.to_problem`'s
            cameras, shape (I,).
        pose_of_image: Pose of each image, shape (I,).
        camera_of_image: Rig camera of each image, shape (I,).
        frame_ids: COLMAP frame of each pose, shape (M,); -1 for an image in no frame.
        rig: The rig cameras (every (rig, camera) pair; an identity one for lone images).
        R_wc: Each pose's rotation in the file (rig -> world), shape (M, 3, 3).
        centers_w: Each pose's rig-frame origin in the file, shape (M, 3).
    """

    image_ids: IntArray
    pose_of_image: IntArray
    camera_of_image: IntArray
    frame_ids: IntArray
    rig: Rig
    R_wc: FloatArray
    centers_w: FloatArray

    @property
    def metric(self) -> bool:
        """Return True if the rig's cameras have a baseline (the scale is observed)."""
        return bool(np.any(np.abs(self.rig.t_rc) > 0.0))


def unknown_offsets(rigs: ColmapRigs) -> list[str]:
    """Return the camera sensors of the frames' rigs without a ``sensor_from_rig``.

    Such a rig cannot be held rigid (COLMAP cannot pose their images either).
    """
    used = sorted({f.rig_id for f in rigs.frames.values()})
    return [f'rig {r} camera {c}' for r in used for c in rigs.rigs[r].cameras()
            if rigs.rigs[r].sensor_from_rig(0, c) is None]


def rig_layout(model: ColmapModel, rigs: ColmapRigs, image_ids: IntArray) -> RigLayout:
    """Return the poses and rig cameras of a model's images.

    Poses are the frames holding an image, in frame id order, then the images in no frame.

    Raises:
        FormatError: If a camera of a frame's rig has no ``sensor_from_rig``
            (:func:`unknown_offsets`).
    """
    missing = unknown_offsets(rigs)
    if missing:
        msg = f'{rigs.rigs_path}: {", ".join(missing)} without sensor_from_rig: not rigid'
        raise FormatError(msg)
    frame_of = rigs.frame_of_image()
    ids = [int(i) for i in image_ids]
    frame_ids = sorted({frame_of[i] for i in ids if i in frame_of})
    lone = [i for i in ids if i not in frame_of]
    if lone:
        logger.warning('COLMAP model: %d images in no frame (the first: %d), each solved as a '
                       'pose of its own', len(lone), lone[0])
    pairs = sorted({(rigs.frames[f].rig_id, c) for f in frame_ids
                    for c in rigs.rigs[rigs.frames[f].rig_id].cameras()})
    offsets = [rigs.rigs[r].sensor_from_rig(0, c) for r, c in pairs]
    if lone:
        offsets.append(np.array([1.0, 0, 0, 0, 0, 0, 0]))
    s = np.array(offsets, dtype=float).reshape(-1, 7)
    check_poses(s[:, :4], s[:, 4:], [f'rig {r} camera {c} sensor_from_rig' for r, c in pairs]
                + ['identity'] * len(lone))
    R_rc, t_rc = poses_from_colmap(s[:, :4], s[:, 4:])     # the camera's pose in the rig frame
    rig = Rig(R_rc, t_rc)
    pose_of = {f: k for k, f in enumerate(frame_ids)}
    pose_of.update({-i: len(frame_ids) + k for k, i in enumerate(lone)})
    camera_of = {p: k for k, p in enumerate(pairs)}
    pose_of_image = [pose_of[frame_of[i]] if i in frame_of else pose_of[-i] for i in ids]
    camera_of_image = [camera_of[(rigs.frames[frame_of[i]].rig_id, model.images[i].camera_id)]
                       if i in frame_of else len(pairs) for i in ids]
    q = np.array([rigs.frames[f].qvec for f in frame_ids] + [model.images[i].qvec for i in lone])
    t = np.array([rigs.frames[f].tvec for f in frame_ids] + [model.images[i].tvec for i in lone])
    check_poses(q.reshape(-1, 4), t.reshape(-1, 3),
                [f'frame {f}' for f in frame_ids] + [f'image {i}' for i in lone])
    R_wc, centers = poses_from_colmap(q, t)
    return RigLayout(np.array(ids, dtype=np.int64), np.array(pose_of_image, dtype=np.int64),
                     np.array(camera_of_image, dtype=np.int64),
                     np.array(frame_ids + [-1] * len(lone), dtype=np.int64), rig, R_wc, centers)


def to_rig_problem(images: BAProblem, layout: RigLayout, R_wc: FloatArray,
                   centers_w: FloatArray, points_w: FloatArray,
                   poses: IntArray | None = None) -> tuple[BAProblem, IntArray]:
    """Return the rig problem of an independent-image problem, and the layout pose of each pose.

    Args:
        images: :func:`~pmba_ros.io.colmap.to_problem`'s problem (a camera per image).
        layout: Its images' poses and rig cameras.
        R_wc: Start rotations (rig -> world) of the layout's poses, shape (M, 3, 3).
        centers_w: Start rig-frame origins, shape (M, 3).
        points_w: Start points of ``images``' features, shape (N, 3) (non-finite: dropped).
        poses: The layout poses to solve (default: all); the other poses' images are left out.

    Raises:
        FormatError: If the problem cannot be built.
    """
    poses = np.arange(layout.frame_ids.shape[0]) if poses is None else np.asarray(poses)
    new_pose = np.full(layout.frame_ids.shape[0], -1, dtype=np.int64)
    new_pose[poses] = np.arange(poses.shape[0])
    obs = images.obs
    pose = new_pose[layout.pose_of_image[obs.cam_idx]]
    keep = pose >= 0
    img = obs.cam_idx[keep]
    bearings = obs.bearings_c[keep]
    jac = (obs.pixel_jac[keep] if obs.pixel_jac is not None
           else projection_jacobian(bearings, images.intrinsics, img)[1])
    # Each pose's nominal pinhole: its first image's (the pixels are weighed by their own).
    first = np.full(poses.shape[0], -1, dtype=np.int64)
    first[pose[keep][::-1]] = img[::-1]
    first = np.where(first >= 0, first, 0)
    pin = images.intrinsics.take(first)
    zeros = np.zeros(poses.shape[0])
    pinhole = Intrinsics(pin.fx, pin.fy, pin.cx, pin.cy, zeros, zeros.copy())
    pixels = project(bearings, pinhole, pose[keep])
    try:
        problem = make_problem(R_wc[poses], centers_w[poses], pinhole, pose[keep],
                               obs.feat_idx[keep], pixels, bearings_c=bearings,
                               points_w=points_w, n_feats=images.n_feats,
                               feature_ids=images.feature_ids,
                               camera=layout.camera_of_image[img], rig=layout.rig,
                               pixel_jac=jac)
    except ProblemError as err:
        msg = f'COLMAP model with rigs: {err}'
        raise FormatError(msg) from err
    return problem, poses.astype(np.int64)


def frames_from_images(layout: RigLayout, image_index: IntArray, R_wc: FloatArray,
                       centers_w: FloatArray, fit_scale: bool = True,
                       ) -> tuple[IntArray, FloatArray, FloatArray, float]:
    """Return rig poses from image poses solved alone (a global initialization's).

    Each rotation is the chordal mean of its images' (through their cameras' offsets). The
    images' solution has a scale of its own: the one that best fits its centres within each
    frame to the rig's baselines is applied, and each origin is the mean of its images'.

    Args:
        layout: The images' layout.
        image_index: Solved images (indices into ``layout.image_ids``), shape (S,).
        R_wc: Their rotations, shape (S, 3, 3).
        centers_w: Their centres, shape (S, 3).
        fit_scale: Fit the scale; False: the images' solution is at the rig's scale.

    Returns:
        The layout poses with a solved image (P,), their rotations (P, 3, 3) and origins
        (P, 3), and the scale applied to the images' solution (to its points too).
    """
    pose = layout.pose_of_image[image_index]
    cam = layout.camera_of_image[image_index]
    R_rc, t_rc = layout.rig.R_rc[cam], layout.rig.t_rc[cam]
    poses, group = np.unique(pose, return_inverse=True)
    P = poses.shape[0]
    R_wr = so3.project(_group_sum(R_wc @ np.swapaxes(R_rc, 1, 2), group, P))
    counts = np.bincount(group, minlength=P).astype(float)[:, None]
    # s C_i = C_r + R_wr t_i in each frame: with the frame means taken out,
    # s (C_i - mean C) = R_wr (t_i - mean t), least squares in s.
    lever = np.einsum('kij,kj->ki', R_wr[group], t_rc)
    c_dev = centers_w - (_group_sum(centers_w, group, P) / counts)[group]
    l_dev = lever - (_group_sum(lever, group, P) / counts)[group]
    denom = float(np.sum(c_dev * c_dev))
    scale = float(np.sum(c_dev * l_dev)) / denom if denom > 0 and fit_scale else 1.0
    if not scale > 0:
        logger.warning('COLMAP rigs: no frame has two initialized images with a baseline; '
                       'the rig problem starts at scale 1')
        scale = 1.0
    origins = _group_sum(scale * centers_w - lever, group, P) / counts
    return poses.astype(np.int64), R_wr, origins, scale


def _group_sum(x: FloatArray, group: IntArray, n: int) -> FloatArray:
    """Return the sums of the rows of ``x`` (K, ...) in each of ``n`` groups, shape (n, ...)."""
    flat = x.reshape(x.shape[0], -1)
    sums = [np.bincount(group, flat[:, j], minlength=n) for j in range(flat.shape[1])]
    out: FloatArray = np.stack(sums, axis=1).reshape((n, *x.shape[1:]))
    return out


def image_poses(layout: RigLayout, poses: IntArray, R_wc: FloatArray, centers_w: FloatArray,
                ) -> tuple[IntArray, FloatArray, FloatArray]:
    """Return the images on ``poses`` and their camera poses through the rig.

    Args:
        layout: The images' layout.
        poses: Layout poses, shape (P,).
        R_wc: Their rotations (rig -> world), shape (P, 3, 3).
        centers_w: Their rig-frame origins, shape (P, 3).

    Returns:
        The images (indices into ``layout.image_ids``) (S,), their rotations (S, 3, 3) and
        centres (S, 3).
    """
    index = np.full(layout.frame_ids.shape[0], -1, dtype=np.int64)
    index[poses] = np.arange(np.asarray(poses).shape[0])
    at = index[layout.pose_of_image]
    images = np.flatnonzero(at >= 0)
    k, c = at[images], layout.camera_of_image[images]
    R = R_wc[k] @ layout.rig.R_rc[c]
    C = centers_w[k] + np.einsum('kij,kj->ki', R_wc[k], layout.rig.t_rc[c])
    return images.astype(np.int64), R, C


def updated_frames(rigs: ColmapRigs, layout: RigLayout, poses: IntArray, R_wc: FloatArray,
                   centers_w: FloatArray) -> ColmapRigs:
    """Return the rigs and frames with new ``rig_from_world`` for the frames of ``poses``.

    Rigs and the other frames are kept as read.
    """
    frame_ids = layout.frame_ids[poses]
    mine: BoolArray = frame_ids >= 0
    q, t = poses_to_colmap(np.asarray(R_wc)[mine], np.asarray(centers_w)[mine])
    frames = dict(rigs.frames)
    for k, fid in enumerate(frame_ids[mine].tolist()):
        frames[fid] = replace(frames[fid], qvec=q[k], tvec=t[k])
    return replace(rigs, frames=frames)
