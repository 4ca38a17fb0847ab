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
"""The ROS-free back-end: messages in, optimized keyframes, map, TF and diagnostics out.

:class:`BackendLogic` is shared by the node (``pmba_ros.node``) and the bag replay tool. Its
``on_*`` callbacks are cheap (parse and buffer) and never raise on bad input: every rejected
message or observation is counted under a reason and shows up in the diagnostics. ``step()``
associates keyframe poses with track frames by stamp (``stamp_tolerance_s``), feeds the
:class:`~pmba_ros.backend.estimator.Estimator`, and returns the outputs as ``(topic, msg)``
pairs: the config's relative topic names, ``'/tf'`` and ``'/diagnostics'``.

Every output stamp comes from input headers (the newest processed keyframe; map -> odom is
future-dated by ``transform_tolerance_s``), never from a clock. With ``deterministic=True``
(bag replay) there are no time budgets and no timings: identical inputs, identical outputs.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
import logging
from pathlib import Path
import time
from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.backend import feature_ids, status, tracks
from pmba_ros.backend import outputs as out
from pmba_ros.backend.cameras import (
    extrinsic_from_message,
    frame_id_of,
    frame_observations,
    FrontendCameras,
)
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.estimator import Estimator
from pmba_ros.backend.extrinsics import Rigid
from pmba_ros.backend.input_restart import InputRestarts
from pmba_ros.backend.keyframe_outputs import KeyframeOutputs, TF_TOPIC
from pmba_ros.backend.msg_backend import MsgBackend
from pmba_ros.backend.pose_stream import PoseStream
from pmba_ros.backend.results import save_results
from pmba_ros.backend.sanity import DUPLICATE_POSES, held_from, PoseJumpCheck, StampLeapCheck
from pmba_ros.backend.types import CameraModel, KeyframePose, TrackFrame
from pmba_ros.backend.window import KeyframeObs
from pmba_ros.core import so3
from pmba_ros.eval.trajectory import Trajectory

logger = logging.getLogger(__name__)

__all__ = ['DIAGNOSTICS_TOPIC', 'TF_TOPIC', 'BackendLogic']

DIAGNOSTICS_TOPIC = '/diagnostics'


@dataclass(frozen=True)
class _Keyframe:
    stamp_ns: int
    pose: KeyframePose | None
    odom_jumped: bool = False   # the front-end's frame jumped just before this pose


class BackendLogic:
    """Online PMBA back-end driven by messages of any backend (rclpy, rosbags, mcap_ros2).

    Args:
        config: The configuration.
        msg_backend: Builds the output messages (:class:`~pmba_ros.backend.msg_backend.
            RclpyBackend` in the node, ``RosbagsBackend`` in the replay tool and tests).
    """

    def __init__(self, config: BackendConfig, msg_backend: MsgBackend) -> None:
        """Create the logic in state ``collecting``."""
        self.config = config
        self.backend = msg_backend
        self.camera: CameraModel | None = None
        self.estimator = Estimator(config)
        self._stats = status.BackendStats()
        self._paused = False
        self.last_error = ''
        self.cameras = FrontendCameras(config)
        self._stream_mode = config.keyframe_source == 'tracks'   # poses sampled at tracks
        self.input_waiting: Callable[[], bool] = lambda: False
        """Whether more input waits to be handled (the node's queue): a keyframe's solve is
        then left to a later one's (:meth:`Estimator.add_keyframe`'s ``solve``), and run
        once the input is handled, so that a node behind its input catches up instead of
        dropping it. Never with ``deterministic``."""
        self._init_buffers()

    def _init_buffers(self) -> None:
        self._tracks: deque[TrackFrame] = deque()
        self._pending: deque[_Keyframe] = deque()
        self._last_kf_stamp = -1
        self._newest_input_ns, self._ended_at_ns = -1, -1
        self.outputs = KeyframeOutputs(self.estimator, self.cameras, self.backend, self.config)
        self._last_info = status.UpdateInfo('none')
        self._diag_dirty = True
        self._counters_at_diag: Counter[str] = Counter()
        self._track_memory = tracks.TrackMemory()
        self._feature_ids = feature_ids.FeatureIdRestarts()
        self._pose_check = PoseJumpCheck()
        self._track_stamps = StampLeapCheck('track_stamp_leaps')
        self._keyframe_stamps = StampLeapCheck('keyframe_stamp_leaps',
                                               repeat_reason=DUPLICATE_POSES)
        self._pose_stream = PoseStream(10 * self.config.buffer_size)
        self._restarts = InputRestarts(max_kept=self.config.buffer_size)
        self.cameras.forget_extrinsics()

    # --- inputs ---------------------------------------------------------------------------

    def count(self, reason: str, n: int = 1) -> None:
        """Count ``n`` events under ``reason`` (also used by the node for queue drops)."""
        self._stats.count(reason, n)

    def _reject(self, reason: str, err: Exception | str) -> None:
        self.count(reason)
        self.last_error = f'{reason}: {err}'
        # A misconfigured input is every message: warned at the 1st, 10th, 100th... only.
        if str(n := self._stats.counters[reason]).rstrip('0') == '1':
            logger.warning('%s%s', self.last_error, f' ({n} so far)' if n > 1 else '')

    def on_camera_info(self, msg: Any, camera_id: int | None = None) -> None:
        """Take the intrinsics from a ``sensor_msgs/CameraInfo`` (bad ones are counted).

        Changed intrinsics replace a camera's (:meth:`FrontendCameras.take_intrinsics`); the
        first change is a warning, each is counted as ``camera_info_changes``.

        Args:
            msg: The message.
            camera_id: Front-end camera id it describes (``camera_info_topics`` order);
                None: the reference camera ``camera_id``.
        """
        try:
            camera = tracks.parse_camera_info(msg)
        except Exception as err:
            self._reject('bad_camera_info', err)
            return
        cam = self.config.camera_id if camera_id is None else int(camera_id)
        refused, old = self.cameras.take_intrinsics(cam, camera, frame_id_of(msg))
        if refused:
            self._reject('bad_camera_info', refused)
            return
        if old is None:
            logger.info('camera info of camera %d: %s', cam, camera.describe())
            self._diag_dirty = True
        elif change := camera.change_from(old):   # warned once, counted always
            self.count('camera_info_changes')
            if self._stats.counters['camera_info_changes'] == 1:
                logger.warning('camera info of camera %d changed: %s; the newest is used '
                               '(further changes are only counted)', cam, change)
        if old is not camera and (fold := camera.fold_in_image()):   # taken, but named
            self._reject('camera_info_folds', f'camera {cam}: {fold}')
        if cam == self.config.camera_id:
            self.camera = camera
            self.estimator.set_pinhole(*camera.image_pinhole)

    def on_tf(self, msg: Any) -> None:
        """Take the transforms of a ``/tf`` or ``/tf_static`` message (bad ones are counted).

        They give the body -> camera extrinsic, keyframe ``child_frame_id`` -> CameraInfo
        ``frame_id`` (:meth:`FrontendCameras.extrinsic_missing`).
        """
        try:
            self.cameras.tf_tree.add_message(msg)
        except Exception as err:
            self._reject('bad_tf', err)

    def on_extrinsic(self, msg: Any) -> None:
        """Take an ``extrinsic_topic`` message: camera ``camera_id``'s pose in the body frame.

        Odometry or PoseStamped (VINS' ``/vins_estimator/extrinsic``, OpenVINS'
        ``loop_extrinsic``). The newest one before the first keyframe with a front-end pose
        is used where neither ``camera_extrinsics`` nor TF gives the extrinsic; bad ones are
        counted (``bad_extrinsic``), and later ones that moved from it (an online
        calibration) as ``extrinsic_changes`` (a reset takes the newest).
        """
        try:
            moved = self.cameras.take_topic_extrinsic(extrinsic_from_message(msg))
        except Exception as err:
            self._reject('bad_extrinsic', err)
            return
        if moved:   # warned once, counted always
            self.count('extrinsic_changes')
            if self._stats.counters['extrinsic_changes'] == 1:
                logger.warning("the front-end's extrinsic moved by %s from the one fixed at "
                               'the first keyframe, which is kept (a reset takes the newest; '
                               'further changes are only counted)', moved)

    def on_tracks(self, msg: Any) -> None:
        """Parse and buffer a feature-track message (bad ones are counted)."""
        if self._paused:
            self.count('dropped_while_paused')
            return
        if self._restarted('tracks', msg, self._track_stamps.newest_ns):
            return
        try:
            frame = tracks.parse_tracks(msg, self.config.feature_layout, self.config.num_cams,
                                        self._track_memory)
        except Exception as err:
            self._reject('bad_tracks', err)
            return
        for reason, n in [('dropped_observations', frame.dropped), *frame.drop_reasons.items()]:
            self.count(reason, n)
        frame, restarted = self._feature_ids.shift(frame)   # a relaunched front-end's ids
        self.count('feature_id_restarts', int(restarted))
        for taken in self._track_stamps.admit(frame.stamp_ns, frame, self._reject):
            self._take_tracks(taken)

    def _take_tracks(self, frame: TrackFrame) -> None:
        if frame.stamp_ns <= self._last_kf_stamp:
            self.count('stale_tracks')
            self.last_error = (f'stale_tracks: stamped {frame.stamp_ns} ns, not after the last '
                               f'keyframe ({self._last_kf_stamp} ns; association_timeout_s past?)')
            return
        self._newest_input_ns = max(self._newest_input_ns, frame.stamp_ns)
        if len(self._tracks) >= self.config.buffer_size:
            self._tracks.popleft()
            self.count('tracks_buffer_overflow')
        self._tracks.append(frame)
        if self._stream_mode:
            self._push_keyframe(_Keyframe(frame.stamp_ns, None))

    def on_keyframe(self, msg: Any) -> None:
        """Parse and buffer a keyframe pose message (bad ones are counted)."""
        if self._paused:
            self.count('dropped_while_paused')
            return
        if self._restarted('keyframes', msg, self._keyframe_stamps.newest_ns):
            return
        try:
            pose = tracks.parse_keyframe(msg, self.config.keyframe_type)
        except Exception as err:
            self._reject('bad_keyframes', err)
            stamp = tracks.stamp_of(msg)   # its tracks still count, as a keyframe without a pose
            if (stamp is not None and self._pose_check.idle() and not self._stream_mode
                    and self._keyframe_stamps.fits(stamp)):
                self._push_keyframe(_Keyframe(stamp, None))
            return
        for taken in self._keyframe_stamps.admit(pose.stamp_ns, pose, self._reject):
            self._take_keyframe_pose(taken)

    def _take_keyframe_pose(self, pose: KeyframePose) -> None:
        jump = self._pose_check.check(pose.stamp_ns, pose.position, pose)
        if jump is not None:   # this pose, or a first one held with it: then the others go on
            self._reject('keyframe_pose_jumps', jump)
        self._newest_input_ns = max(self._newest_input_ns, pose.stamp_ns)
        for held, jumped, recovered in self._pose_check.release():   # and any held before
            self.count('keyframe_poses_recovered', int(recovered))
            self._take_pose(held, jumped)

    def _take_pose(self, pose: KeyframePose, jumped: bool = False) -> None:
        if self._stream_mode:
            self._pose_stream.add(pose, jumped)
        else:
            self._push_keyframe(_Keyframe(pose.stamp_ns, pose, jumped))

    def end_of_input(self) -> None:
        """Take what waits for later input (held stamps, keyframes missing tracks): none comes."""
        for frame in self._track_stamps.flush():
            self._take_tracks(frame)
        for pose in self._keyframe_stamps.flush():
            self._take_keyframe_pose(pose)
        for held, _, _ in self._pose_check.flush():   # the first poses, too few to judge
            self._take_pose(held)
        self._ended_at_ns = self._newest_input_ns   # input after it is waited for again

    def _push_keyframe(self, kf: _Keyframe) -> None:
        newest = self._pending[-1].stamp_ns if self._pending else self._last_kf_stamp
        if kf.stamp_ns <= newest:
            self._reject('keyframe_stamp_not_increasing', f'{kf.stamp_ns} ns after {newest} ns')
            return
        if len(self._pending) >= self.config.buffer_size:
            self._pending.popleft()
            self.count('keyframe_buffer_overflow')
        self._pending.append(kf)

    # --- control --------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget all keyframes, tracks and the map (the camera model is kept)."""
        self.estimator.reset()
        self._init_buffers()
        self.last_error, self._stats.not_optimized = '', 0   # of the run forgotten (counts stay)
        self.count('resets')
        logger.info('back-end reset')

    def _restarted(self, stream: str, msg: Any, taken_ns: int) -> bool:
        """Start over from ``msg`` if it ends a stretch of input that started again."""
        if not self._restarts.see(stream, tracks.stamp_of(msg), taken_ns, msg):
            return False
        stretch = self._restarts.stretch()
        self.estimator.reset()
        self._init_buffers()
        self._reject('input_restarts', f'{len(stretch)} messages stamped before the last '
                     'ones, in order among themselves: the input started again (a recording '
                     'played in a loop?); the back-end starts over from them')
        for name, kept in stretch:
            (self.on_keyframe if name == 'keyframes' else self.on_tracks)(kept)
        return True

    def apply_config(self, config: BackendConfig) -> None:
        """Use ``config`` from the next keyframe on (the node's run-time parameter changes).

        Only fields read at use time take effect; the node declares the others read-only.
        """
        self.config = config
        self.estimator.config = config

    def set_paused(self, paused: bool) -> None:
        """Pause (drop and count inputs) or resume."""
        if bool(paused) != self._paused:
            self._paused, self._diag_dirty = bool(paused), True
            logger.info('back-end %s', 'paused' if paused else 'resumed')

    @property
    def paused(self) -> bool:
        """Return True while paused."""
        return self._paused

    @property
    def state(self) -> str:
        """Return the state: 'paused' or the estimator's ('collecting', 'tracking', ...)."""
        return 'paused' if self._paused else self.estimator.state

    @property
    def stats(self) -> status.BackendStats:
        """Return the statistics (live object)."""
        return self._stats

    # --- processing -----------------------------------------------------------------------

    def step(self) -> list[tuple[str, Any]]:
        """Process every keyframe whose tracks are available and return the outputs.

        Returns:
            ``(topic, message)`` pairs: path, keyframes, landmarks, odometry, ``/tf`` and
            ``/diagnostics`` after keyframe updates and solves; only ``/diagnostics`` after a
            keyframe whose solve was deferred (:attr:`input_waiting`) or when something else
            changed (rejected input, pause); nothing otherwise.
        """
        processed = 0
        while self._pending and not self._paused:
            kf = self._pending[0]
            frame, ready = self._match(kf.stamp_ns)
            if ready and self._stream_mode:   # its pose: the stream's at its stamp
                held = held_from(kf.stamp_ns, self._keyframe_stamps, self._pose_check)
                pose, ready, jumped = self._pose_stream.sample(
                    kf.stamp_ns, (self._timed_out(kf.stamp_ns) and not held)   # or none come
                    or not (self._pose_stream.count or self._pose_check.holding()
                            or self._keyframe_stamps.holding()))
                kf = _Keyframe(kf.stamp_ns, pose, jumped)
                if ready and pose is None and self._pose_stream.count:
                    self.count('keyframes_without_pose')
            if not ready or (kf.pose is not None and not self._timed_out(kf.stamp_ns)
                             and self.cameras.extrinsic_missing(kf.pose, frame)):
                break   # its inputs, or an extrinsic that may still come, until they time out
            self._pending.popleft()
            self._process(kf, frame)
            processed += 1
        if not (processed or self._paused or self.input_waiting()):
            processed = self._solve_deferred()
        try:
            if processed and self._last_info.kind == 'deferred':
                # Behind the input: the path and the map wait for the solve that catches up
                # (a long run's path takes longer to publish than a keyframe interval).
                return [self._diagnostics(self._last_kf_stamp)]
            if processed:
                return self._outputs()
            if self._diag_dirty or self._stats.counters != self._counters_at_diag:
                return [self._diagnostics(max(self._newest_input_ns, self._last_kf_stamp, 0))]
        except Exception as err:
            logger.exception('building outputs failed')
            self._reject('output_errors', err)
        return []

    def _timed_out(self, stamp_ns: int) -> bool:
        """Return whether input for ``stamp_ns`` can no longer come."""
        return stamp_ns <= self._ended_at_ns or self._newest_input_ns > stamp_ns + round(
            self.config.association_timeout_s * 1e9)

    def _match(self, stamp_ns: int) -> tuple[TrackFrame | None, bool]:
        """Return (tracks of the keyframe or None, whether the keyframe can be processed)."""
        tol = round(self.config.stamp_tolerance_s * 1e9)
        timed_out = self._timed_out(stamp_ns)
        best, best_dt = None, tol + 1
        for frame in self._tracks:
            dt = abs(frame.stamp_ns - stamp_ns)
            if dt < best_dt:
                best, best_dt = frame, dt
        if best is None:
            if timed_out:
                self.count('keyframes_without_tracks')
            return None, timed_out
        if best.normalized is None and self.camera is None:
            self.count('tracks_without_camera_info', int(timed_out))
            return None, timed_out
        return best, True

    def _process(self, kf: _Keyframe, frame: TrackFrame | None) -> None:
        t0 = time.perf_counter()
        tol = round(self.config.stamp_tolerance_s * 1e9)
        while self._tracks and self._tracks[0].stamp_ns <= kf.stamp_ns + tol:
            old = self._tracks.popleft()
            if old is not frame and old.stamp_ns < kf.stamp_ns - tol:
                self.count('tracks_without_keyframe')
        if frame is not None and frame in self._tracks:
            self._tracks.remove(frame)
        self._last_kf_stamp = kf.stamp_ns
        self._pose_stream.forget_before(kf.stamp_ns)
        odom = None
        if kf.pose is not None:
            T_bc = self._resolve_extrinsic(kf.pose, frame)
            odom = T_bc.apply_to_poses(so3.from_quat_xyzw(kf.pose.quat_xyzw),
                                       np.asarray(kf.pose.position))
            self.outputs.name_frames(self.config, kf.pose.frame_id, kf.pose.child_frame_id)
        try:
            obs = self._observations(frame) if frame is not None else None
            info = self.estimator.add_keyframe(
                kf.stamp_ns, odom, obs, None if kf.pose is None else kf.pose.covariance,
                odom_jumped=kf.odom_jumped,
                solve=self.config.deterministic or not self.input_waiting())
        except Exception as err:
            logger.exception('keyframe update failed')
            self._reject('internal_errors', err)
            info = status.UpdateInfo('error', message=str(err))
        self._stats.record_update(info)
        self._note_update(info, t0)

    def _solve_deferred(self) -> int:
        """Run the solve deferred keyframes left, if any; return 1 if one ran, else 0."""
        t0 = time.perf_counter()
        try:
            info = self.estimator.solve_deferred()
        except Exception as err:
            logger.exception('deferred solve failed')
            self._reject('internal_errors', err)
            info = status.UpdateInfo('error', message=str(err))
        if info is None:
            return 0
        self._stats.record_solve(info)
        self._note_update(info, t0)
        return 1

    def _note_update(self, info: status.UpdateInfo, t0: float) -> None:
        """Keep an update's figures (``t0``: its start, ``time.perf_counter()``)."""
        est = self.estimator
        self._stats.not_optimized = int(np.count_nonzero(~est.optimized(est.estimated())))
        if est.state == 'tracking':
            self._stats.map_scale.append(est.map_from_odom.scale)
            noise = est.frontend_noise
            self._stats.noise = (est.pixel_noise.sigma, noise.factors, noise.white)
        if info.dropped.get('cost_explosions'):   # counted with the update's drops
            self.last_error = f'cost_explosions: {info.message}'
        self._stats.update_ms.append(1e3 * (time.perf_counter() - t0))
        self._last_info = info

    def _resolve_extrinsic(self, pose: KeyframePose, frame: TrackFrame | None) -> Rigid:
        """Return the body -> camera extrinsic, fixing it at the first keyframe pose processed.

        See :meth:`FrontendCameras.resolve_extrinsic`; without one, the keyframe poses are
        taken as camera poses with a warning (counted as ``extrinsic_unknown``).
        """
        cams = self.cameras
        if cams.extrinsic is not None:
            return cams.extrinsic
        camera_frame = cams.camera_frame(frame)
        found, source = cams.resolve_extrinsic(pose.child_frame_id, camera_frame, pose.frame_id)
        if found is None:
            self._reject('extrinsic_unknown',
                         f'no body -> camera transform from '
                         f'{pose.child_frame_id or "(no child_frame_id)"!r} to '
                         f'{camera_frame or "(no camera frame)"!r} (parameter '
                         'camera_extrinsics, TF or extrinsic_topic); taking the keyframe poses '
                         'as camera poses')
        else:
            logger.info('body -> camera extrinsic from %s: %s', source,
                        [round(v, 6) for v in found.to_flat()])
        return cams.extrinsic  # type: ignore[return-value]

    def _observations(self, frame: TrackFrame) -> KeyframeObs:
        """Return the observations of the reference camera and the usable others.

        Another camera counts once its offset is known (:meth:`_rig_camera`); the others'
        observations are counted as ``other_camera_observations`` (see
        :func:`~pmba_ros.backend.cameras.frame_observations`).
        """
        ref, usable = self.config.camera_id, {self.config.camera_id: self.camera}
        for cam in np.unique(frame.camera_ids).tolist():
            if cam != ref and self._rig_camera(int(cam), frame) is not None:
                usable[int(cam)] = self.cameras.others.get(int(cam))
        obs, other, non_finite = frame_observations(frame, usable)
        self.count('other_camera_observations', other)
        self.count('non_finite_observations', non_finite)
        return obs

    def _rig_camera(self, cam: int, frame: TrackFrame) -> Rigid | None:
        """Return camera ``cam``'s pose in the reference camera's frame, or None (unusable).

        See :meth:`FrontendCameras.rig_camera`; an unusable camera is named once in a
        warning, a new one is handed to the estimator.
        """
        known = cam in self.cameras.rig
        offset, source = self.cameras.rig_camera(cam, frame.normalized is not None)
        if offset is None:
            if cam not in self.cameras.unconfigured_warned:
                self.cameras.unconfigured_warned.add(cam)
                self.last_error = f'other_camera_observations: camera id {cam} unused: {source}'
                logger.warning('%s', self.last_error)
        elif not known:
            self.estimator.set_rig_camera(cam, offset.rotation, offset.translation)
            logger.info('camera %d in the reference camera frame (from %s): %s', cam, source,
                        [round(v, 6) for v in offset.to_flat()])
            self._diag_dirty = True
        return offset

    # --- outputs --------------------------------------------------------------------------

    def _outputs(self) -> list[tuple[str, Any]]:
        result = self.outputs.messages(self.config, self._last_kf_stamp)
        result.append(self._diagnostics(self._last_kf_stamp))
        return result

    def _diagnostics(self, stamp: int) -> tuple[str, Any]:
        cfg = self.config
        info = self._last_info
        counters = self._stats.counters
        state = self.state
        level = status.backend_level(info.kind, state, counters, self._counters_at_diag)
        message = status.backend_message(state, self.estimator.last_message, info.kind,
                                         info.message)
        values: dict[str, str | float] = {
            'state': state, 'mode': cfg.mode, 'last_update': info.kind,
            'keyframes': self._stats.keyframes,
            'optimized_keyframes': int(self.estimator.estimated().shape[0]),
            **status.update_values(info),
            'input_lag_ms': max(0.0, (self._newest_input_ns - self._last_kf_stamp) * 1e-6)
            if self._last_kf_stamp >= 0 else 0.0,
            'pending_keyframes': len(self._pending), 'buffered_tracks': len(self._tracks),
            'landmarks': int(len(self.estimator.landmarks) + len(self.estimator.features)),
            'camera_info_received': self.camera is not None,
            'map_from_odom_scale': self.estimator.map_from_odom.scale,
            'not_optimized_keyframes': self._stats.not_optimized,
            'init_attempts': self.estimator.init_attempts,
            'tracks_noise_px': round(self.estimator.pixel_noise.sigma, 4) if state == 'tracking'
            else 'not measured before the initialization',
            'frontend_noise_factors': ' '.join(
                f'{k:.3g}' for k in self.estimator.frontend_noise.factors),
            'extrinsic_source': self.cameras.extrinsic_source or 'none',
            'cameras_used': ','.join(map(str, sorted([self.config.camera_id, *self.cameras.rig]))),
        }
        if not cfg.deterministic:
            values['solve_ms'] = info.solve_ms
            values['update_ms'] = self._stats.update_ms[-1] if self._stats.update_ms else 0.0
        values.update(status.counter_values(counters))
        if self.last_error:
            values['last_error'] = self.last_error
        self._diag_dirty = False
        self._counters_at_diag = Counter(counters)
        return DIAGNOSTICS_TOPIC, out.make_diagnostics(
            stamp, status.DIAGNOSTICS_NAME, level, message, values, self.backend)

    # --- accessors ------------------------------------------------------------------------

    def optimized_trajectory(self) -> Trajectory:
        """Return the keyframes' body poses in map_frame (stamps in seconds).

        Every keyframe with a pose is included; the ones never optimized (before the
        initialization, too few observations) are at their front-end pose through map <- odom.
        """
        R, C = self.outputs.body_poses(idx := self.estimator.estimated())
        return Trajectory(self.estimator.kf.stamps_ns[idx].astype(np.float64) * 1e-9, C, R)

    def frontend_trajectory(self) -> Trajectory:
        """Return the front-end body poses of the keyframes received (odom frame)."""
        kf = self.estimator.kf
        R, C = self.outputs.frontend_body_poses(idx := np.flatnonzero(kf.has_odom[:kf.n]))
        return Trajectory(kf.stamps_ns[idx].astype(np.float64) * 1e-9, C, R)

    def landmarks(self) -> FloatArray:
        """Return the map's landmarks in map_frame, shape (N, 3)."""
        return self.estimator.landmark_points()

    def save(self, directory: Path | str) -> list[Path]:
        """Write the trajectories and the landmarks into ``directory`` (:func:`save_results`)."""
        return save_results(directory, self.optimized_trajectory(), self.frontend_trajectory(),
                            self.landmarks())
