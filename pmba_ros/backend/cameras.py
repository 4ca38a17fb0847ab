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
"""The front-end's cameras: intrinsics and frames per camera id, body -> camera extrinsics.

The reference camera ``camera_id`` carries the keyframe poses; every other camera of a rig
is used through its pose in the reference camera's frame, once that is known. Extrinsics
come, in order, from ``camera_extrinsics``, from agreeing frames, or from the TF chain between
the keyframe poses' body frame and each CameraInfo's ``frame_id`` (issue #12).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.distortion import pinhole_jacobian
from pmba_ros.backend.extrinsics import extrinsics_from_params, Rigid, TransformTree
from pmba_ros.backend.tracks import parse_keyframe
from pmba_ros.backend.types import CameraModel, KeyframePose, TrackFrame
from pmba_ros.backend.window import KeyframeObs
from pmba_ros.core import so3, sphere
from pmba_ros.errors import MessageError


def frame_id_of(msg: Any) -> str:
    """Return a message's header ``frame_id`` ('' without one)."""
    return str(getattr(getattr(msg, 'header', None), 'frame_id', '') or '')


EXTRINSIC_MOVED_M = 0.01
"""Translation by which the front-end's extrinsic may move from the one fixed, unreported, m."""

EXTRINSIC_MOVED_DEG = 0.5
"""Rotation by which it may move, unreported, degrees (a calibration's usual precision)."""


def extrinsic_moved(old: Rigid, new: Rigid) -> str:
    """Return how far an extrinsic moved (``'0.012 m, 0.60 deg'``), or '' if within precision.

    Within :data:`EXTRINSIC_MOVED_M` and :data:`EXTRINSIC_MOVED_DEG`, a move is none.
    """
    metres = float(np.linalg.norm(new.translation - old.translation))
    degrees = float(np.rad2deg(so3.angle(old.rotation, new.rotation)))
    if metres <= EXTRINSIC_MOVED_M and degrees <= EXTRINSIC_MOVED_DEG:
        return ''
    return f'{metres:.3f} m, {degrees:.2f} deg'


def settled_extrinsic(series: Sequence[Rigid]) -> Rigid:
    """Return where an online calibration's series of extrinsics settled: its last half's mean.

    The chordal mean of the rotations and the mean of the translations: a calibration that
    converged by half the run is its converged value, one that jitters about the true value
    the jitter's middle (its last message alone, a draw of the jitter, had put a simulated
    street's RPE at 2x the first message's).
    """
    half = series[len(series) // 2:]
    rotation = so3.project(np.sum([t.rotation for t in half], axis=0))
    return Rigid(rotation, np.mean([t.translation for t in half], axis=0))


def extrinsic_from_message(msg: Any) -> Rigid:
    """Return the body -> camera transform of an Odometry or PoseStamped message's pose.

    VINS-Mono / VINS-Fusion publish their ``tic``, ``ric`` so (``/vins_estimator/extrinsic``)
    and OpenVINS its camera 0 in the IMU frame (``loop_extrinsic``: the JPL quaternion of
    IMU -> camera read as a Hamilton one is camera -> IMU).

    Raises:
        MessageError: If it is neither type, or its pose is not finite or not a rotation.
    """
    try:
        pose = parse_keyframe(msg, 'odometry' if hasattr(msg, 'child_frame_id')
                              else 'pose_stamped')
    except MessageError as err:
        msg_ = f'extrinsic message: {err}'
        raise MessageError(msg_) from err
    return Rigid.from_xyz_quat(pose.position, pose.quat_xyzw, 'extrinsic message')


def frame_observations(frame: TrackFrame, usable: dict[int, CameraModel | None],
                       ) -> tuple[KeyframeObs, int, int]:
    """Return the unit bearings of a frame's finite observations by the ``usable`` cameras.

    ``usable`` maps each camera id to use (the reference one always) to its intrinsics (None:
    no CameraInfo yet, which tracks with normalized coordinates do not need). Also returns
    how many observations were by other cameras and how many were not finite.

    Raises:
        MessageError: Tracks without normalized coordinates, and a camera without intrinsics.
    """
    present = np.unique(frame.camera_ids).tolist()
    # The usual frame: every observation's camera counts, nothing to select.
    every = usable.keys() >= set(present)
    sel = slice(None) if every else np.isin(frame.camera_ids, list(usable))
    cams = frame.camera_ids[sel]
    models = {c: m for c, m in usable.items() if m is not None}
    if frame.normalized is not None:
        xy = frame.normalized[sel]
    elif frame.pixels is not None and all(c in models for c in np.unique(cams).tolist()):
        pixels = frame.pixels[sel]
        xy = np.empty_like(pixels)
        # A damaged pixel overflows the undistortion's Newton steps: it comes out NaN and is
        # counted as not finite below, so numpy's warnings would only be noise.
        with np.errstate(over='ignore', invalid='ignore'):
            for cam in np.unique(cams).tolist():
                on = cams == cam
                xy[on] = models[cam].normalize(pixels[on])
    else:
        msg = 'tracks without normalized coordinates need a CameraInfo'
        raise MessageError(msg)
    finite = np.all(np.isfinite(xy), axis=1)
    xy, seen_by = xy[finite], cams[finite]
    bearings = sphere.normalize(np.column_stack([xy, np.ones(xy.shape[0])]))
    obs = KeyframeObs(frame.feature_ids[sel][finite], bearings, xy,
                      seen_by if len(usable) > 1 else None,
                      _pixel_jacobians(bearings, seen_by, models))
    return (obs, frame.camera_ids.shape[0] - cams.shape[0],
            int(np.count_nonzero(~finite)))


def _pixel_jacobians(bearings: FloatArray, cams: IntArray,
                     models: dict[int, CameraModel]) -> np.ndarray | None:
    """Return each observation's d(pixel) / d(bearing) by its camera's model, float32.

    None where each camera's is the pinhole of its intrinsics (or not known yet): the
    problem's builder takes those. Among cameras that have one, the others get their
    pinhole's; a camera without a model NaN rows (the builder's pinhole).
    """
    # A damaged observation far off axis has a Jacobian that overflows (the distortion
    # polynomial, or the float32 cast): its row goes inf / NaN, and the problem's builder
    # drops observations whose Jacobian is not finite, so numpy's warnings would only be noise.
    with np.errstate(over='ignore', invalid='ignore'):
        jacobians = {c: models[c].pixel_jacobian(bearings[cams == c])
                     for c in np.unique(cams).tolist() if c in models}
        if all(j is None for j in jacobians.values()):
            return None
        out = np.full((bearings.shape[0], 2, 3), np.nan, dtype=np.float32)
        for c, jac in jacobians.items():
            on = cams == c
            out[on] = jac if jac is not None else pinhole_jacobian(
                bearings[on], *models[c].image_pinhole[:2])
    return out


class FrontendCameras:
    """Intrinsics, frames and extrinsics of the front-end's cameras (no logging, no counting).

    Args:
        config: The configuration (``camera_id``, ``num_cams``, ``camera_extrinsics``).
    """

    def __init__(self, config: BackendConfig) -> None:
        """Start with no camera known."""
        self.config = config
        self.tf_tree = TransformTree()
        self.reference: CameraModel | None = None
        self.reference_frame = ''
        self.others: dict[int, CameraModel] = {}
        self.other_frames: dict[int, str] = {}
        self.param_extrinsics = extrinsics_from_params(config.camera_extrinsics,
                                                       config.num_cams)
        self.topic_extrinsic: Rigid | None = None   # the newest on ``extrinsic_topic``
        self.forget_extrinsics()

    def forget_extrinsics(self) -> None:
        """Forget the extrinsics found (a reset: they are looked up again)."""
        self.extrinsic: Rigid | None = None
        self.extrinsic_source = ''
        self.body_frame = ''
        self.rig: dict[int, tuple[Rigid, str]] = {}
        self.unconfigured_warned: set[int] = set()

    def take_intrinsics(self, camera_id: int, camera: CameraModel,
                        frame_id: str) -> tuple[str, CameraModel | None]:
        """Keep a camera's newest intrinsics and frame (of the reference one: :attr:`reference`).

        The newest replaces what a camera had: a relaunched front-end's calibration or
        resolution, or a second driver on the topic (then they alternate). Tracks in pixels
        are normalized with the intrinsics of when they are used, the stored observations
        are bearings and stay.

        Returns:
            Why the camera id is refused ('' if it was taken) and the camera's previous
            intrinsics (None: its first).
        """
        if camera_id == self.config.camera_id:
            old, self.reference, self.reference_frame = self.reference, camera, frame_id
            return '', old
        if not 0 <= camera_id < self.config.num_cams:
            return f'camera id {camera_id} is not in [0, num_cams={self.config.num_cams})', None
        old, self.others[camera_id] = self.others.get(camera_id), camera
        self.other_frames[camera_id] = frame_id
        return '', old

    def take_topic_extrinsic(self, found: Rigid) -> str:
        """Keep the newest ``extrinsic_topic`` transform; say how far it is from the one fixed.

        Returns:
            '' unless the extrinsic was fixed from the topic and this one moved more than
            :data:`EXTRINSIC_MOVED_M` or :data:`EXTRINSIC_MOVED_DEG` from it (an online
            calibration still converging): then what moved.
        """
        self.topic_extrinsic = found
        fixed = self.extrinsic
        if fixed is None or self.extrinsic_source != 'extrinsic_topic':
            return ''
        return extrinsic_moved(fixed, found)

    def camera_frame(self, frame: TrackFrame | None) -> str:
        """Return the reference camera's frame: its CameraInfo's, else its tracks'."""
        return self.reference_frame or (frame.frame_id if frame is not None else '')

    def extrinsic_missing(self, pose: KeyframePose, frame: TrackFrame | None) -> bool:
        """Return whether no extrinsic is fixed and none is found yet for ``pose``.

        The first keyframe with a front-end pose fixes one, identity if none is found. The
        back-end holds it while this is True until ``association_timeout_s`` passed (input
        stamps): a TF publisher or an extrinsic topic started a little after the front-end's
        first keyframe left the identity fixed for a whole run.
        """
        return self.extrinsic is None and self.find_extrinsic(
            pose.child_frame_id, self.camera_frame(frame), pose.frame_id)[0] is None

    def find_extrinsic(self, body: str, camera_frame: str,
                       world: str = '') -> tuple[Rigid | None, str]:
        """Find the reference camera's body -> camera extrinsic, not fixing it.

        In order: ``camera_extrinsics``; the TF chain from the keyframe pose's frame ``body``
        to the CameraInfo's (or else the tracks') frame ``camera_frame``; the newest
        ``extrinsic_topic`` message (VINS and OpenVINS leave the keyframe pose's
        ``child_frame_id`` empty, so TF cannot name the body); identity when ``body`` is the
        camera frame. The frame the keyframe poses are in, ``world``, is neither: VINS-Fusion
        publishes its odometry with ``child_frame_id`` 'world' as well, and its feature
        tracker's tracks in 'world' (as a body and a camera frame, they agreed: identity, and
        the TF chain between them ran through the world, a body pose taken for an extrinsic).

        Returns:
            The extrinsic found (None: none) and its source ('identity' for none).
        """
        body = '' if body == world else body
        camera_frame = '' if camera_frame == world else camera_frame
        if self.param_extrinsics is not None:
            return self.param_extrinsics[self.config.camera_id], 'parameters'
        found = None
        if body and camera_frame and body != camera_frame:
            found = self.tf_tree.lookup(body, camera_frame)
        if found is not None:
            return found, 'tf'
        if self.topic_extrinsic is not None:
            return self.topic_extrinsic, 'extrinsic_topic'
        if body and body == camera_frame:
            return Rigid.identity(), 'frames_agree'
        return None, 'identity'

    def resolve_extrinsic(self, body: str, camera_frame: str,
                          world: str = '') -> tuple[Rigid | None, str]:
        """Find (:meth:`find_extrinsic`) and fix the extrinsic; identity where none is found.

        Returns:
            The extrinsic found (None: taken as identity) and its source.
        """
        found, source = self.find_extrinsic(body, camera_frame, world)
        self.body_frame = '' if body == world else body
        self.extrinsic = found if found is not None else Rigid.identity()
        self.extrinsic_source = source
        return found, source

    def rig_camera(self, cam: int, normalized_tracks: bool) -> tuple[Rigid | None, str]:
        """Find camera ``cam``'s pose in the reference camera's frame (fixed once found).

        From the body -> camera extrinsics of both cameras: ``camera_extrinsics``; the TF
        chain from the keyframe poses' body frame to the camera's CameraInfo ``frame_id``;
        identity when those frames agree. It needs the reference camera's extrinsic from
        parameters, TF or agreeing frames, and, unless the tracks carry normalized
        coordinates, the camera's CameraInfo (``camera_info_topics``).

        Returns:
            The pose (None: unusable) and its source, or why it is unusable.
        """
        if cam in self.rig:
            return self.rig[cam]
        T_bc: Rigid | None = None
        frame_id = self.other_frames.get(cam, '')
        if not normalized_tracks and cam not in self.others:
            return None, 'no CameraInfo (parameter camera_info_topics, one topic per camera id)'
        if self.extrinsic is None or self.extrinsic_source == 'identity':
            return None, 'the reference camera has no known body -> camera extrinsic'
        source = ''
        if self.param_extrinsics is not None:
            T_bc, source = self.param_extrinsics[cam], 'parameters'
        elif self.body_frame and frame_id == self.body_frame:
            T_bc, source = Rigid.identity(), 'frames_agree'
        elif self.body_frame and frame_id:
            T_bc, source = self.tf_tree.lookup(self.body_frame, frame_id), 'tf'
        if T_bc is None:
            return None, (f'no body -> camera transform from {self.body_frame!r} to '
                          f'{frame_id or "(no CameraInfo frame)"!r} (camera_extrinsics or TF)')
        offset = self.extrinsic.inverse() @ T_bc
        self.rig[cam] = (offset, source)
        return offset, source
