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
"""What a replay did and wrote: :class:`ReplayReport` (``report.json``)."""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any, TYPE_CHECKING

import numpy as np
from pmba_ros._json import to_jsonable

if TYPE_CHECKING:
    from pmba_ros.backend.extrinsics import Rigid
    from pmba_ros.backend.logic import BackendLogic

SUSPECT_COUNTERS = {
    'feature_ids_inexact': 'observations dropped: feature ids that cannot be exact in the '
                           "message's number type (>= 2^24 in float32: tracks would merge)",
    'duplicate_observations': 'repeated feature ids in one message, resolved by the copy '
                              "nearest to the track's previous observation",
    'ambiguous_duplicate_observations': 'repeated feature ids without a previous observation '
                                        '(every copy dropped)',
    'keyframe_pose_jumps': 'keyframe poses rejected: they jump far beyond the recent motion',
    'duplicate_keyframe_poses': 'keyframe poses dropped: stamped like one received before (a '
                                'repeated message; the first copy kept)',
    'keyframe_stamp_leaps': 'keyframe poses dropped: stamped far ahead of the next one (a '
                            'clock glitch)',
    'track_stamp_leaps': 'tracks messages dropped: stamped far ahead of the next one (a clock '
                         'glitch)',
    'input_restarts': 'times the input started again (stamps back at an earlier time, a '
                      'recording played twice?): the back-end started over, the outputs are '
                      "the last run's",
    'cost_explosions': 'solves whose cost per observation exploded relative to their '
                       'history (inconsistent tracks?)',
    # Input accepted and then not used, or used another way than the recording meant: only
    # a counter before, so a replay that lost a rig's second camera, or the tracks of the
    # keyframes before the CameraInfo, said nothing of it.
    'other_camera_observations': 'observations by cameras other than the reference one not '
                                 'used: no CameraInfo or no body -> camera transform for '
                                 'their camera (camera_info_topics, camera_extrinsics or TF)',
    'tracks_without_camera_info': "keyframes' tracks (pixels only) not used: no CameraInfo "
                                  'had arrived for them',
    'keyframes_without_pose': 'keyframes the pose stream gave no pose (none within 0.5 s on '
                              'either side, or a jump of its frame between): taken without one',
    'odom_frame_jumps': "front-end steps found far off the map's by the solve: a new odom "
                        'segment starts at each',
    'keyframe_buffer_overflow': 'keyframe poses dropped: more than buffer_size waited for '
                                'their tracks',
    'extrinsic_changes': "times the front-end's extrinsic moved from the one fixed at the first "
                         'keyframe, which was kept (an online calibration?)',
    'camera_info_folds': 'CameraInfo models whose distortion folds over inside the image: '
                         'observations past the fold dropped',
    'tracks_buffer_overflow': 'tracks messages dropped: more than buffer_size waited for '
                              'their keyframe',
    # Counted and logged once, and before only in `counters`: a recording of two runs, a
    # recalibrating driver or damaged pixels replayed to exit 0 with no warning.
    'feature_id_restarts': "times the front-end's feature ids started again (a relaunched "
                           'front-end, or two runs in one recording?): the later ids were '
                           'taken as new features, shifted past the earlier ones',
    'camera_info_changes': 'CameraInfo messages whose intrinsics differ from those before: '
                           'the newest were used from each on (a recalibrating driver, or '
                           'two cameras on one topic?)',
    'non_finite_observations': 'observations dropped: their pixels undistort to no finite '
                               "point (far outside the camera model's image?)",
    'keyframes_dropped': 'keyframes dropped: neither a front-end pose nor enough observations '
                         '(not in the outputs)',
    'keyframes_dropped_before_init': 'keyframes without a front-end pose dropped from an '
                                     'initialization batch over init_max_batch (not in the '
                                     'outputs)',
    'internal_errors': 'keyframe updates failed with an internal error (a bug: please report '
                       'it with the command line); their keyframes may be missing',
    'output_errors': 'building the outputs failed with an internal error (a bug: please '
                     'report it with the command line); some outputs may be missing',
}
"""Back-end counters of suspect input, each worth a warning in the report."""

OBSERVATION_DROPS = ('feature_ids_inexact', 'duplicate_observations',
                     'ambiguous_duplicate_observations')
"""Counters of the observations dropped from tracks messages (``dropped_observations``) for
a reason other than a value that is not finite."""

IDENTITY_EXTRINSIC = ('no body -> camera extrinsic at the first keyframe (parameter '
                      "camera_extrinsics, TF from the keyframe poses' child_frame_id to the "
                      "camera's frame_id, the front-end's extrinsic topic, or equal frames): "
                      'the keyframe poses were taken as camera poses, right only if the '
                      'front-end publishes camera poses')
"""The warning of ``extrinsic_unknown``: the front-end's poses may be its IMU's."""


@dataclass
class ReplayReport:
    """What a replay did and wrote (``report.json`` is :meth:`to_dict`).

    Attributes:
        bags: Input recordings.
        out_dir: Output folder.
        files: Output name -> path (result bag, TUM files, PLY, report, plots).
        topics: Input role -> topic read ('tracks', 'keyframes', 'camera_info').
        messages_in: Input messages fed to the back-end.
        messages_rejected: Input messages the back-end rejected (parse errors).
        messages_out: Output messages written to the result bag.
        keyframes_in: Keyframe messages read.
        keyframes_out: Keyframes in the optimized trajectory (every keyframe with a pose).
        map_scale: Scale of map <- odom after each keyframe since the initialization.
        measured_noise: At the end, the tracks' pixel noise (``tracks_px``), the factors
            on the front-end's rotation, step-length and step-direction sigmas
            (``frontend_factors``, >= 1: noisier than the parameters) and the measured
            scatter of its single steps against them (``frontend_white``, below 1: the
            step-change factors weigh it in; null until measured); empty if the back-end
            never initialized.
        keyframes_not_optimized: Of those, keyframes at their front-end pose through
            map <- odom (before the initialization, too few observations).
        solve_ms: Solve time per keyframe solve, ms.
        iterations: Solver iterations per solve.
        costs: Cost after each solve.
        costs_before: Cost before each solve.
        update_ms: Whole update time (association, solve, bookkeeping) per keyframe, ms.
        counters: The back-end's counters.
        bag_duration_s: Header-stamp span of the inputs, s.
        wall_s: Wall time of the replay, s.
        accuracy: With ground truth: ATE / RPE of front-end and optimized poses.
        extrinsic: The body -> camera transform used (``source``: 'parameters', 'tf',
            'frames_agree' or 'identity'; ``body_to_camera``: x, y, z, qx, qy, qz, qw);
            with a rig, ``rig_cameras``: each other camera's source and pose in the
            reference camera's frame.
        complete: False if the replay stopped early or the input was incomplete.
        error: The error that stopped it, if any.
        warnings: Non-fatal problems.
        messages_announced: Messages the bags' metadata announces on the topics read.
        messages_read: Messages read from the bags (decoded).
        messages_undecodable: Messages skipped because they do not deserialize.
        damaged_parts: Corrupt parts of the storage skipped (reading resumed after them).
        read_error: The first of them, if any.
    """

    bags: list[Path]
    out_dir: Path
    files: dict[str, Path] = field(default_factory=dict)
    topics: dict[str, str] = field(default_factory=dict)
    messages_in: int = 0
    messages_rejected: int = 0
    messages_out: int = 0
    keyframes_in: int = 0
    keyframes_out: int = 0
    keyframes_not_optimized: int = 0
    map_scale: list[float] = field(default_factory=list)
    measured_noise: dict[str, Any] = field(default_factory=dict)
    solve_ms: list[float] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)
    costs: list[float] = field(default_factory=list)
    costs_before: list[float] = field(default_factory=list)
    update_ms: list[float] = field(default_factory=list)
    counters: dict[str, Any] = field(default_factory=dict)
    bag_duration_s: float = 0.0
    wall_s: float = 0.0
    accuracy: dict[str, Any] | None = None
    extrinsic: dict[str, Any] | None = None
    complete: bool = False
    error: str | None = None
    warnings: list[str] = field(default_factory=list)
    messages_announced: int = 0
    messages_read: int = 0
    messages_undecodable: int = 0
    damaged_parts: int = 0
    read_error: str | None = None

    @property
    def input_complete(self) -> bool:
        """Return True if every announced message was read and decoded."""
        return (not self.damaged_parts and not self.messages_undecodable
                and self.messages_read >= self.messages_announced)

    @property
    def realtime_factor(self) -> float:
        """Bag duration divided by wall time (how much faster than real time)."""
        return self.bag_duration_s / self.wall_s if self.wall_s > 0 else math.inf

    def to_dict(self) -> dict[str, Any]:
        """Return the JSON-serializable report."""
        solve = np.asarray(self.solve_ms, dtype=np.float64)
        out: dict[str, Any] = {
            'bags': [str(b) for b in self.bags],
            'out_dir': str(self.out_dir),
            'files': {k: str(v) for k, v in sorted(self.files.items())},
            'topics': dict(self.topics),
            'complete': self.complete,
            'input_complete': self.input_complete,
            'messages_announced': self.messages_announced,
            'messages_read': self.messages_read,
            'messages_undecodable': self.messages_undecodable,
            'damaged_parts': self.damaged_parts,
            'read_error': self.read_error,
            'keyframes_in': self.keyframes_in,
            'keyframes_out': self.keyframes_out,
            'keyframes_not_optimized': self.keyframes_not_optimized,
            'map_from_odom_scale': [round(float(v), 6) for v in self.map_scale],
            'measured_noise': to_jsonable(self.measured_noise),
            'messages_in': self.messages_in,
            'messages_rejected': self.messages_rejected,
            'messages_out': self.messages_out,
            'counters': to_jsonable(self.counters),
            'solves': len(self.solve_ms),
            'solve_ms': [round(float(v), 3) for v in self.solve_ms],
            'solve_ms_mean': float(solve.mean()) if solve.size else None,
            'solve_ms_max': float(solve.max()) if solve.size else None,
            'iterations': [int(v) for v in self.iterations],
            'costs': [_finite(v) for v in self.costs],
            'costs_before': [_finite(v) for v in self.costs_before],
            'update_ms': [round(float(v), 3) for v in self.update_ms],
            'bag_duration_s': self.bag_duration_s,
            'wall_s': self.wall_s,
            'realtime_factor': (self.realtime_factor if math.isfinite(self.realtime_factor)
                                else None),
            'warnings': list(self.warnings),
        }
        if self.extrinsic is not None:
            out['extrinsic'] = self.extrinsic
        if self.accuracy is not None:
            out['accuracy'] = self.accuracy
        if self.error is not None:
            out['error'] = self.error
        return out


def _finite(value: float) -> float | None:
    """Return ``value`` or None if it is not finite (JSON has no NaN)."""
    return float(value) if math.isfinite(value) else None


def collect_stats(logic: BackendLogic, report: ReplayReport) -> None:
    """Copy timings, iterations, costs, counters and the extrinsic used from ``logic``."""
    stats = logic.stats
    report.solve_ms = [float(v) for v in stats.solve_ms]
    report.iterations = [int(v) for v in stats.iterations]
    report.costs = [float(v) for v in stats.cost_after]
    report.costs_before = [float(v) for v in stats.cost_before]
    report.update_ms = [float(v) for v in stats.update_ms]
    report.counters = dict(sorted(stats.counters.items()))
    for name, text in SUSPECT_COUNTERS.items():
        if report.counters.get(name):
            report.warnings.append(f'{report.counters[name]} {text}')
    # The rows dropped for the reasons above are warned of there: the rest were not finite.
    if (non_finite := report.counters.get('dropped_observations', 0) - sum(
            report.counters.get(name, 0) for name in OBSERVATION_DROPS)) > 0:
        report.warnings.append(f'{non_finite} observations dropped from tracks messages: a '
                               'feature id, camera id or coordinate not finite (NaN or inf)')
    report.counters['keyframes_processed'] = stats.keyframes
    without = report.counters.get('keyframes_without_tracks', 0)
    if 2 * without > stats.keyframes > 0:
        report.warnings.append(
            f'{without} of {stats.keyframes} keyframe poses found no tracks within '
            'stamp_tolerance_s: if the keyframe topic is a pose stream faster than the tracks, '
            '--keyframes-from tracks (parameter keyframe_source: tracks) takes the keyframes '
            'from the tracks and samples it there; if the two are stamped apart, that also '
            'interpolates, or raise stamp_tolerance_s')
    report.keyframes_not_optimized = stats.not_optimized
    report.map_scale = [float(v) for v in stats.map_scale]
    if stats.noise is not None:
        tracks_px, factors, white = stats.noise
        report.measured_noise = {'tracks_px': tracks_px,
                                 'frontend_factors': [round(k, 4) for k in factors],
                                 'frontend_white': None if white is None
                                 else [round(w, 4) for w in white]}
    fallbacks = {'solve_rollbacks': 'window solves rolled back (inconsistent with the front-end)',
                 'reinitializations': 'window re-initializations from the front-end',
                 'scale_steps_left_out': "steps of the rig's map scale left out (beyond 3 "
                                         "sigmas of its scale filter's expectation)"}
    for name, what in fallbacks.items():
        if report.counters.get(name):
            report.warnings.append(f'{report.counters[name]} {what}')
    if not report.solve_ms and (attempts := report.counters.get('init_attempts')):
        report.warnings.append(
            f'the initialization never succeeded ({attempts} attempts): nothing was optimized, '
            f"the keyframes are the front-end's; last: {logic.estimator.last_message}")
    elif not report.solve_ms and logic.estimator.state == 'waiting_for_parallax':
        report.warnings.append(
            'the initialization never started: nothing was optimized, the keyframes are the '
            f"front-end's; {logic.estimator.last_message}")
    elif report.keyframes_not_optimized:
        report.warnings.append(_not_optimized(report, logic.config.min_observations))
    cameras = logic.cameras
    if report.counters.get('extrinsic_unknown'):
        report.warnings.append(IDENTITY_EXTRINSIC)
    if cameras.extrinsic is not None:
        report.extrinsic = {'source': cameras.extrinsic_source,
                            'body_to_camera': [round(v, 9) for v in cameras.extrinsic.to_flat()]}
        report.extrinsic |= _rig_report(cameras.rig)


def _not_optimized(report: ReplayReport, min_observations: int) -> str:
    """Return the warning of keyframes left at their front-end pose, and why they were."""
    # Keyframes of empty tracks messages were only counted as passed through (a normal
    # event before the initialization): 20 of 40 keyframes unoptimized said nothing.
    counters = report.counters
    few = counters.get('keyframes_passed_through', 0) + counters.get('keyframes_dead_reckoned', 0)
    why = [(f'{few} keyframes had fewer than min_observations ({min_observations}) usable '
            'observations')] if few else []
    if without := counters.get('keyframes_without_tracks', 0):
        why.append(f'{without} found no tracks message')
    return (f'{report.keyframes_not_optimized} of {counters["keyframes_processed"]} keyframes not '
            "optimized: they are the front-end's poses through map <- odom"
            + (f' ({"; ".join(why)})' if why else ''))


def _rig_report(rig_cameras: dict[int, tuple[Rigid, str]]) -> dict[str, Any]:
    """Return the report entry of the other cameras used: pose in the reference camera."""
    if not rig_cameras:
        return {}
    return {'rig_cameras': {str(cam): {'source': source, 'in_reference_camera': [
        round(v, 9) for v in offset.to_flat()]} for cam, (offset, source)
        in sorted(rig_cameras.items())}}
