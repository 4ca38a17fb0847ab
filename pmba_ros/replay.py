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
"""Offline ("serial") replay: recorded front-end topics -> back-end -> result bag and files.

:func:`replay` reads one or more recordings with rosbags, feeds the tracks, keyframe poses
and camera info to :class:`~pmba_ros.backend.logic.BackendLogic` in header-stamp order, and
writes into ``out_dir``:

==========================  ================================================================
``result.mcap``             rosbag2 MCAP with every output of the node (``/tf`` included),
                            logged at the stamp of the input that produced them
``keyframes_frontend.tum``  front-end keyframe poses (TUM)
``keyframes_optimized.tum`` optimized keyframe poses in the map frame (TUM)
``landmarks.ply``           landmarks (binary PLY)
``report.json``             counters, per-keyframe solve times and iterations, throughput,
                            and with ground truth an accuracy block
``*.png``                   with ``plot=True``: top view, cost per solve, solve time
==========================  ================================================================

The result bag is finalized even when the replay stops with an error or an interrupt, and the
files of whatever was processed are still written (``report.json`` then has ``"complete":
false`` and the error). With ``config.deterministic`` (forced here) two replays of the same
bag give byte-identical TUM and PLY files.

Integrity: a damaged recording is read past (undecodable messages are skipped and counted,
reading resumes after a corrupt part of the storage), and the messages read are compared
with the counts the bag announces; any shortfall is a warning and makes the report
``"complete": false`` with ``"input_complete": false`` (``pmba replay`` then exits with 3).
Every file is written to a temporary name and renamed into place, ``report.json`` last; the
outputs of an earlier run in the same folder are removed first, so they never mix with this
run's. A lock file (``.pmba_replay.lock``) refuses a second replay into a folder in use, and
SIGINT / SIGTERM wait while the outputs are written.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
import functools
import heapq
import logging
import math
import os
from pathlib import Path
import shutil
import time
from typing import Any

import numpy as np
from pmba_ros._json import dumps_report, to_jsonable
from pmba_ros.errors import BagError, EvaluationError, MessageError
from pmba_ros.io.atomic import deferred_interrupts, write_atomic, write_text_atomic
from pmba_ros.io.bags import BagMessage, iter_messages, list_topics, open_writer, ReadStats

logger = logging.getLogger(__name__)

ProgressCallback = Callable[[int, int], None]
"""``progress(messages_done, messages_total)``, called while replaying."""

RESULT_BAG = 'result.mcap'
FRONTEND_TUM = 'keyframes_frontend.tum'
OPTIMIZED_TUM = 'keyframes_optimized.tum'
LANDMARKS_PLY = 'landmarks.ply'
REPORT_JSON = 'report.json'
LOCK_FILE = '.pmba_replay.lock'
PLOT_FILES = ('trajectories_top.png', 'ate_per_keyframe.png', 'cost_per_solve.png',
              'solve_time.png')
OUTPUT_FILES = (REPORT_JSON, RESULT_BAG, FRONTEND_TUM, OPTIMIZED_TUM, LANDMARKS_PLY,
                *PLOT_FILES)
"""Every file a replay writes; report.json first, so it goes first when they are removed."""

TRACKS_TYPES = {'named': ('sensor_msgs/msg/PointCloud2',)}
"""Accepted message types of the tracks topic per layout (default: PointCloud)."""
KEYFRAME_TYPES = {'odometry': ('nav_msgs/msg/Odometry',),
                  'pose_stamped': ('geometry_msgs/msg/PoseStamped',)}
CAMERA_INFO_TYPES = ('sensor_msgs/msg/CameraInfo',)
TF_TOPICS = ('/tf_static', '/tf')
"""Transform topics read when recorded (body -> camera extrinsic, see BackendLogic.on_tf)."""
TF_TYPES = ('tf2_msgs/msg/TFMessage',)

REORDER_BUFFER = 256
"""Messages held back to sort the log-time stream into header-stamp order."""
MAX_REJECTED_BEFORE_ANY_ACCEPTED = 10
"""Rejected tracks messages, with none accepted, after which the replay stops."""

REJECTION_COUNTERS = frozenset({'bad_tracks', 'bad_keyframes', 'bad_camera_info',
                                'bad_tf', 'keyframe_stamp_not_increasing', 'stale_tracks',
                                'keyframe_pose_jumps'})
"""Back-end counters (``BackendLogic.stats.counters``) that mean an input was rejected."""

SUSPECT_COUNTERS = {
    'feature_ids_inexact': 'observations dropped: feature ids that cannot be exact in the '
                           "message's number type (>= 2^24 in float32: tracks would merge)",
    'duplicate_observations': 'repeated feature ids in one message, resolved by the copy '
                              "nearest to the track's previous observation",
    'ambiguous_duplicate_observations': 'repeated feature ids without a previous observation '
                                        '(every copy dropped)',
    'keyframe_pose_jumps': 'keyframe poses rejected: they jump far beyond the recent motion',
    'cost_explosions': 'solves whose cost per observation exploded relative to their '
                       'history (inconsistent tracks?)',
}
"""Back-end counters of suspect input, each worth a warning in the report."""

_KIND_ORDER = {'tf': 0, 'camera_info': 1, 'tracks': 2, 'keyframe': 3}


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


def resolve_topic(name: str, namespace: str = '/') -> str:
    """Resolve a (relative) ROS topic name in a namespace, as rclpy does for a plain node.

    Args:
        name: Absolute ('/a/b') or relative ('a/b') name; '~' is not supported.
        namespace: Node namespace.

    Returns:
        The absolute name.
    """
    if name.startswith('/'):
        return name
    ns = '/' + namespace.strip('/')
    return f'{ns.rstrip("/")}/{name}'


def _find_topic(wanted: str, recorded: Iterable[str]) -> str | None:
    """Return the recorded topic matching ``wanted`` (ROS 1 bags may lack the '/')."""
    names = list(recorded)
    if wanted in names:
        return wanted
    bare = wanted.lstrip('/')
    return next((n for n in names if n.lstrip('/') == bare), None)


@dataclass(frozen=True)
class _Input:
    """Input topics of a replay."""

    tracks: str
    keyframes: str | None
    camera_info: str | None
    tf: tuple[str, ...] = ()


def _select_inputs(bags: Sequence[Path], config: Any, camera_given: bool,
                   warnings: list[str]) -> tuple[_Input, dict[str, int]]:
    """Check the recorded topics against the configuration; return topics and counts.

    Raises:
        BagError: If a needed topic is missing.
        MessageError: If the tracks / keyframe topic has a type the layout cannot read.
    """
    topics = list_topics(bags)
    names = ', '.join(f'{t} [{i.msgtype}]' for t, i in sorted(topics.items())) or 'none'
    where = ', '.join(str(b) for b in bags)

    def need(option: str, name: str) -> str:
        found = _find_topic(resolve_topic(name), topics)
        if found is None:
            msg = (f'{where}: {option} topic {resolve_topic(name)!r} is not in the bag '
                   f'(recorded: {names})')
            raise BagError(msg)
        return found

    tracks = need('tracks', config.features_topic)
    layout = config.feature_layout
    accepted = TRACKS_TYPES.get(layout, ('sensor_msgs/msg/PointCloud',))
    if topics[tracks].msgtype not in accepted:
        msg = (f'{where}: tracks topic {tracks!r} has type {topics[tracks].msgtype}, but layout '
               f'{layout!r} reads {" or ".join(accepted)} (wrong --tracks-layout?)')
        raise MessageError(msg)
    keyframes = None
    if config.keyframe_source == 'keyframe_topic':
        keyframes = need('keyframes', config.keyframe_topic)
        accepted = KEYFRAME_TYPES[config.keyframe_type]
        if topics[keyframes].msgtype not in accepted:
            msg = (f'{where}: keyframes topic {keyframes!r} has type '
                   f'{topics[keyframes].msgtype}, but --keyframes-type '
                   f'{config.keyframe_type!r} reads {accepted[0]}')
            raise MessageError(msg)
    camera_info = _find_topic(resolve_topic(config.camera_info_topic), topics)
    if camera_info is not None and topics[camera_info].msgtype not in CAMERA_INFO_TYPES:
        msg = (f'{where}: camera info topic {camera_info!r} has type '
               f'{topics[camera_info].msgtype}, expected {CAMERA_INFO_TYPES[0]}')
        raise BagError(msg)
    if camera_given:
        camera_info = None
    elif camera_info is None:
        text = (f'camera info topic {resolve_topic(config.camera_info_topic)!r} is not in the '
                f'bag and no intrinsics were given; using normalized coordinates from the tracks')
        logger.warning(text)
        warnings.append(text)
    tf = tuple(t for t in (_find_topic(name, topics) for name in TF_TOPICS)
               if t is not None and topics[t].msgtype in TF_TYPES)
    counts = {t: topics[t].count for t in (tracks, keyframes, camera_info, *tf)
              if t is not None}
    return _Input(tracks, keyframes, camera_info, tf), counts


def _rig_camera_infos(bags: Sequence[Path], config: Any, warnings: list[str],
                      counts: dict[str, int]) -> dict[str, int]:
    """Return the recorded ``camera_info_topics`` of a rig: topic -> camera id.

    A missing topic leaves its camera unused (its observations are counted as
    ``other_camera_observations``), with a warning. ``counts`` gets each topic's message
    count.
    """
    if not config.camera_info_topics:
        return {}
    topics = list_topics(bags)
    found: dict[str, int] = {}
    for cam, name in enumerate(config.camera_info_topics):
        topic = _find_topic(resolve_topic(name), topics)
        if topic is not None and topics[topic].msgtype in CAMERA_INFO_TYPES:
            found[topic] = cam
            counts[topic] = topics[topic].count
        else:
            text = (f'camera info topic {resolve_topic(name)!r} of camera {cam} is not in the '
                    'bag: that camera is not used')
            logger.warning(text)
            warnings.append(text)
    return found


def _stamp_ns(msg: Any, fallback: int) -> int:
    """Return a message's header stamp in ns (``fallback`` if it has no header)."""
    try:
        stamp = msg.header.stamp
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    except AttributeError:
        return fallback


def stamp_ordered(messages: Iterable[BagMessage], kinds: dict[str, str],
                  window: int = REORDER_BUFFER) -> Iterator[tuple[int, str, BagMessage]]:
    """Reorder a log-time message stream into header-stamp order with a bounded buffer.

    At equal stamps transforms come first, then camera info, tracks and keyframe poses (a
    keyframe then finds its tracks and extrinsic). Messages more than ``window`` positions
    out of order are passed on late rather than held indefinitely.

    Args:
        messages: Messages in log-time order.
        kinds: Topic -> 'tf' | 'camera_info' | 'tracks' | 'keyframe'.
        window: Messages held back.

    Yields:
        ``(stamp_ns, kind, message)`` in (almost) stamp order.
    """
    heap: list[tuple[int, int, int, str, BagMessage]] = []
    for seq, message in enumerate(messages):
        kind = kinds[message.topic]
        stamp = _stamp_ns(message.msg, message.log_time_ns)
        heapq.heappush(heap, (stamp, _KIND_ORDER[kind], seq, kind, message))
        if len(heap) > window:
            stamp, _, _, kind, message = heapq.heappop(heap)
            yield stamp, kind, message
    while heap:
        stamp, _, _, kind, message = heapq.heappop(heap)
        yield stamp, kind, message


def camera_info_from_intrinsics(intrinsics: Sequence[float], stamp_ns: int = 0) -> Any:
    """Return a Jazzy ``sensor_msgs/msg/CameraInfo`` for ``(fx, fy, cx, cy)``, no distortion.

    Raises:
        MessageError: If the intrinsics are not four positive, finite numbers.
    """
    from pmba_ros.backend.outputs import make_camera_info, RosbagsBackend
    from pmba_ros.backend.types import CameraModel
    from pmba_ros.io.bags import jazzy_typestore

    values = [float(v) for v in intrinsics]
    if len(values) != 4:
        msg = f'intrinsics must be fx,fy,cx,cy (4 numbers), got {len(values)}'
        raise MessageError(msg)
    camera = CameraModel(fx=values[0], fy=values[1], cx=values[2], cy=values[3])
    return make_camera_info(stamp_ns, 'camera', camera, RosbagsBackend(jazzy_typestore()))


class _Run:
    """State of one replay (feeds the logic, writes its outputs)."""

    def __init__(self, logic: Any, writer: Any, report: ReplayReport,
                 progress: ProgressCallback | None, total: int, keyframe_kind: str) -> None:
        self.logic = logic
        self.keyframe_kind = keyframe_kind
        self.writer = writer
        self.report = report
        self.progress = progress
        self.total = total
        self.first_stamp: int | None = None
        self.last_stamp = 0
        self.camera_ids: dict[str, int] = {}   # CameraInfo topic of a rig -> camera id
        self.tracks_accepted = 0
        self.tracks_rejected = 0
        self.first_error: str | None = None

    def feed(self, stamp: int, kind: str, message: BagMessage) -> None:
        """Feed one input message, then write whatever the logic produced."""
        report = self.report
        report.messages_in += 1
        if self.first_stamp is None:
            self.first_stamp = stamp
        self.last_stamp = max(self.last_stamp, stamp)
        if kind == self.keyframe_kind:
            report.keyframes_in += 1
        handler = getattr(self.logic, {'camera_info': 'on_camera_info', 'tracks': 'on_tracks',
                                       'keyframe': 'on_keyframe', 'tf': 'on_tf'}[kind])
        if message.topic in self.camera_ids:
            handler = functools.partial(handler, camera_id=self.camera_ids[message.topic])
        before = self._rejections()
        try:
            handler(message.msg)
        except MessageError as err:
            self._rejected(kind, message, stamp, str(err))
        else:
            if self._rejections() > before:
                self._rejected(kind, message, stamp, str(getattr(self.logic, 'last_error', '')))
            elif kind == 'tracks':
                self.tracks_accepted += 1
        self.step()
        if self.progress is not None:
            self.progress(report.messages_in, self.total)

    def _rejections(self) -> int:
        """Return the logic's count of rejected input messages."""
        counters = getattr(getattr(self.logic, 'stats', None), 'counters', None) or {}
        return int(sum(v for k, v in counters.items() if k in REJECTION_COUNTERS))

    def _rejected(self, kind: str, message: BagMessage, stamp: int, error: str) -> None:
        """Count a rejected input; stop if no tracks message has been usable."""
        report = self.report
        report.messages_rejected += 1
        logger.debug('rejected %s message at %d ns: %s', message.topic, stamp, error)
        if self.first_error is None:
            self.first_error = f'{message.topic} at {stamp} ns: {error}'
        if kind == 'tracks':
            self.tracks_rejected += 1
            if not self.tracks_accepted and \
                    self.tracks_rejected >= MAX_REJECTED_BEFORE_ANY_ACCEPTED:
                self._raise_all_rejected()

    def _raise_all_rejected(self) -> None:
        """Raise the error for a tracks topic none of whose messages parse."""
        msg = (f'{self.tracks_rejected} tracks messages rejected and none accepted '
               f'(wrong --tracks-layout?); first error: {self.first_error}')
        raise MessageError(msg)

    def step(self) -> None:
        """Run the logic's pending work and write its outputs."""
        for topic, msg in self.logic.step():
            name = resolve_topic(topic)
            self.writer.write(name, msg, _stamp_ns(msg, self.last_stamp))
            self.report.messages_out += 1

    def finish(self) -> None:
        """Drain the logic and check that the tracks were usable."""
        finish = getattr(self.logic, 'finish', None)
        if callable(finish):
            for topic, msg in finish() or []:
                self.writer.write(resolve_topic(topic), msg, _stamp_ns(msg, self.last_stamp))
                self.report.messages_out += 1
        self.step()
        if self.tracks_rejected and not self.tracks_accepted:
            self._raise_all_rejected()


def _make_logic(config: Any) -> Any:
    """Create the back-end for a replay (deterministic, rosbags messages)."""
    from pmba_ros.backend.logic import BackendLogic
    from pmba_ros.backend.outputs import RosbagsBackend
    from pmba_ros.io.bags import jazzy_typestore
    return BackendLogic(config, RosbagsBackend(jazzy_typestore()))


def replay(bags: Sequence[Path | str], out_dir: Path | str, config: Any = None, *,
           gt: Path | str | None = None, plot: bool = False,
           progress: ProgressCallback | None = None,
           intrinsics: Sequence[float] | None = None, align: str = 'sim3') -> ReplayReport:
    """Run the back-end over recorded front-end topics and write the results.

    Args:
        bags: rosbag2 folders / storage files, or ROS 1 bags (merged in time).
        out_dir: Output folder (created; existing outputs are replaced).
        config: A :class:`~pmba_ros.backend.config.BackendConfig` (default: the node's
            defaults); ``deterministic`` is forced on.
        gt: Ground-truth trajectory file (TUM, EuRoC CSV or KITTI) for the accuracy block.
        plot: Also write PNG plots (needs matplotlib).
        progress: Called as ``progress(done, total)`` after each input message.
        intrinsics: ``(fx, fy, cx, cy)`` to use instead of the bag's CameraInfo.
        align: Alignment of the trajectories onto the ground truth ('sim3', 'se3', 'none').

    Returns:
        The report (also written to ``out_dir/report.json``).

    Raises:
        BagError: If a bag is missing, unreadable, corrupt or lacks a needed topic.
        MessageError: If the tracks do not fit the configured layout.
        FormatError: If the ground-truth file cannot be read.
        EvaluationError: If the ground truth has no stamps overlapping the keyframes.
        PmbaError: If plotting was asked for without matplotlib.
        BagError: Also if another replay is writing into ``out_dir``, or the bag is damaged
            before its first readable message (later damage is a warning in the report).
        OSError: If an output cannot be written (a full disk); the report names the cause.
    """
    from pmba_ros.backend.config import BackendConfig

    t_start = time.perf_counter()
    bag_paths = [Path(b) for b in bags]
    out = Path(out_dir)
    config = BackendConfig() if config is None else config
    config = replace(config, deterministic=True)
    report = ReplayReport(bags=bag_paths, out_dir=out)
    gt_traj = _read_gt(gt) if gt is not None else None
    if plot:
        from pmba_ros.plot import pyplot
        pyplot()  # fail before the replay if matplotlib is missing
    inputs, counts = _select_inputs(bag_paths, config, intrinsics is not None, report.warnings)
    report.topics = {'tracks': inputs.tracks}
    if inputs.keyframes:
        report.topics['keyframes'] = inputs.keyframes
    if inputs.camera_info:
        report.topics['camera_info'] = inputs.camera_info
    kinds = {inputs.tracks: 'tracks'}
    if inputs.keyframes:
        kinds[inputs.keyframes] = 'keyframe'
    if inputs.camera_info:
        kinds[inputs.camera_info] = 'camera_info'
    for topic in inputs.tf:
        kinds[topic] = 'tf'
    camera_ids = _rig_camera_infos(bag_paths, config, report.warnings, counts)
    for topic in camera_ids:
        kinds[topic] = 'camera_info'
    if camera_ids:
        report.topics['camera_info'] = ', '.join(camera_ids)
    if inputs.tf:
        report.topics['tf'] = ', '.join(inputs.tf)
    report.messages_announced = sum(counts.values())
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        msg = f'{out}: cannot create output folder: {err}'
        raise BagError(msg) from err
    with output_lock(out):
        _remove_outputs(out)
        _run_and_write(config, intrinsics, report, bag_paths, kinds, inputs, out,
                       _Outputs(gt_traj, plot, align, t_start, camera_ids), progress)
    return report


@dataclass(frozen=True)
class _Outputs:
    """What to write after the replay."""

    gt: Any
    plot: bool
    align: str
    t_start: float
    camera_ids: dict[str, int] = field(default_factory=dict)


def _run_and_write(config: Any, intrinsics: Sequence[float] | None, report: ReplayReport,
                   bag_paths: list[Path], kinds: dict[str, str], inputs: _Input, out: Path,
                   outputs: _Outputs, progress: ProgressCallback | None) -> None:
    """Feed the bags to a new back-end into the result bag, then write the other outputs."""
    report.files['result_bag'] = out / RESULT_BAG
    run: _Run | None = None
    logic: Any = None
    finished = False
    try:
        logic = _make_logic(config)
        if intrinsics is not None:
            logic.on_camera_info(camera_info_from_intrinsics(intrinsics))
        with open_writer(out / RESULT_BAG, overwrite=True) as writer:
            keyframe_kind = 'keyframe' if inputs.keyframes else 'tracks'
            run = _Run(logic, writer, report, progress, report.messages_announced,
                       keyframe_kind)
            run.camera_ids = outputs.camera_ids
            damage = ReadStats()
            stream = iter_messages(bag_paths, topics=list(kinds), damage=damage)
            for stamp, kind, message in stamp_ordered(_counted(stream, report), kinds):
                run.feed(stamp, kind, message)
            _check_input(report, damage)
            run.finish()
        finished = True
        report.complete = report.input_complete
    except BaseException as err:
        report.error = _describe_error(err)
        raise
    finally:
        if run is not None and run.first_stamp is not None:
            report.bag_duration_s = (run.last_stamp - run.first_stamp) * 1e-9
        if run is not None and run.first_error and report.messages_rejected:
            report.warnings.append(f'{report.messages_rejected} messages rejected; first: '
                                   f'{run.first_error}')
        with deferred_interrupts():
            _write_outputs(logic, report, out, outputs, finished)


def _describe_error(err: BaseException) -> str:
    """Return the text of an error for the report (OSErrors with their file)."""
    if isinstance(err, KeyboardInterrupt):
        return 'interrupted'
    if isinstance(err, OSError) and err.strerror:
        where = f'{err.filename}: ' if err.filename else ''
        return f'{where}{err.strerror}'
    return str(err) or type(err).__name__


def _counted(stream: Iterable[BagMessage], report: ReplayReport) -> Iterator[BagMessage]:
    """Pass the messages on, counting them in ``report.messages_read``."""
    for message in stream:
        report.messages_read += 1
        yield message


def _check_input(report: ReplayReport, damage: ReadStats) -> None:
    """Compare what was read with what the bags announce; warn about any shortfall.

    Raises:
        BagError: If the bag is damaged before its first readable message.
    """
    report.messages_undecodable = damage.undecodable
    report.damaged_parts = damage.damaged_parts
    report.read_error = damage.first_damage
    if damage.first_damage is not None and not report.messages_read:
        raise BagError(damage.first_damage)
    found = []
    if damage.undecodable:
        found.append(f'{damage.undecodable} messages skipped (they do not deserialize); '
                     f'first: {damage.first_undecodable}')
    if damage.damaged_parts:
        found.append(f'{damage.damaged_parts} corrupt part(s) of the bag skipped, reading '
                     f'resumed after each; first: {damage.first_damage}')
    missing = report.messages_announced - report.messages_read - damage.undecodable
    if missing > 0:
        found.append(f'the bags announce {report.messages_announced} messages on the topics '
                     f'read, but only {report.messages_read} were read ({damage.undecodable} '
                     f'undecodable, {missing} missing): the recording is damaged or truncated')
    for text in found:
        logger.warning('%s', text)
    report.warnings.extend(found)


@contextmanager
def output_lock(out: Path) -> Iterator[None]:
    """Hold ``out/.pmba_replay.lock`` while replaying into ``out``.

    Raises:
        BagError: If another process holds it (a replay into the same folder).
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - no advisory locks on this platform
        yield
        return
    path = out / LOCK_FILE
    try:
        fh = open(path, 'a+', encoding='utf-8')
    except OSError as err:
        msg = f'{out}: cannot create the lock file: {err}'
        raise BagError(msg) from err
    with fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            fh.seek(0)
            owner = fh.read().strip() or 'unknown'
            msg = (f'{out}: another replay (process {owner}) is writing into this folder; '
                   'wait for it to finish or choose another --out')
            raise BagError(msg) from err
        fh.seek(0)
        fh.truncate()
        fh.write(f'{os.getpid()}\n')
        fh.flush()
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def _remove_outputs(out: Path) -> None:
    """Remove an earlier run's outputs (report.json first) so none survives this run.

    Raises:
        BagError: If one cannot be removed.
    """
    for name in OUTPUT_FILES:
        path = out / name
        try:
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink(missing_ok=True)
        except OSError as err:
            msg = f'{path}: cannot replace the earlier output: {err}'
            raise BagError(msg) from err


def _read_gt(path: Path | str) -> Any:
    """Read a ground-truth trajectory (format detected)."""
    from pmba_ros.eval.trajectory import read_trajectory
    return read_trajectory(path)


def _write_outputs(logic: Any, report: ReplayReport, out: Path, outputs: _Outputs,
                   finished: bool) -> None:
    """Write TUM, PLY, accuracy, plots and report.json last (also after an error).

    Raises:
        PmbaError, OSError: If writing fails after a replay that finished (after an error,
            the first error stays the one raised; later ones become warnings).
    """
    from pmba_ros.eval.trajectory import write_tum
    from pmba_ros.io.ply import write_ply

    if logic is None:  # stopped before the back-end existed: only the report
        _dump_report(report, out, outputs.t_start)
        return
    _collect_stats(logic, report)
    try:
        frontend = logic.frontend_trajectory()
        optimized = logic.optimized_trajectory()
        write_atomic(out / FRONTEND_TUM, lambda tmp: write_tum(tmp, frontend))
        report.files['frontend_tum'] = out / FRONTEND_TUM
        write_atomic(out / OPTIMIZED_TUM, lambda tmp: write_tum(tmp, optimized))
        report.files['optimized_tum'] = out / OPTIMIZED_TUM
        report.keyframes_out = len(optimized)
        ids, points = _landmarks(logic)
        write_atomic(out / LANDMARKS_PLY, lambda tmp: write_ply(tmp, points, ids))
        report.files['landmarks_ply'] = out / LANDMARKS_PLY
        if outputs.gt is not None and finished:
            report.accuracy = accuracy(frontend, optimized, outputs.gt, align=outputs.align)
        if outputs.plot and finished:
            for name, path in write_plots(out, frontend, optimized, outputs.gt, report,
                                          outputs.align).items():
                report.files[name] = path
    except Exception as err:
        if report.error is None:
            report.error = _describe_error(err)
            report.complete = False
            raise
        report.warnings.append(f'writing outputs after the error failed: {err}')
        logger.warning('writing outputs after an error failed: %s', err)
    finally:
        _dump_report(report, out, outputs.t_start)


def _dump_report(report: ReplayReport, out: Path, t_start: float) -> None:
    """Write report.json atomically (best effort after an error)."""
    report.wall_s = time.perf_counter() - t_start
    report.files['report'] = out / REPORT_JSON
    try:
        write_text_atomic(out / REPORT_JSON, dumps_report(report.to_dict(), sort_keys=False))
    except OSError as err:
        if report.error is None:
            raise
        logger.warning('%s: cannot write report: %s', out / REPORT_JSON, err)


def _landmarks(logic: Any) -> tuple[np.ndarray | None, np.ndarray]:
    """Return ``(ids or None, points (N, 3))`` from the logic's ``landmarks()``."""
    value = logic.landmarks()
    if isinstance(value, tuple) and len(value) == 2:
        ids, points = value
        return (None if ids is None else np.asarray(ids)), np.asarray(points, dtype=np.float64)
    return None, np.asarray(value, dtype=np.float64).reshape(-1, 3)


def _collect_stats(logic: Any, report: ReplayReport) -> None:
    """Copy per-solve timings, iterations, costs and counters from ``logic.stats``."""
    stats = getattr(logic, 'stats', None)
    if stats is None:
        return
    report.solve_ms = [float(v) for v in getattr(stats, 'solve_ms', [])]
    report.iterations = [int(v) for v in getattr(stats, 'iterations', [])]
    report.costs = [float(v) for v in getattr(stats, 'cost_after', [])]
    report.costs_before = [float(v) for v in getattr(stats, 'cost_before', [])]
    report.update_ms = [float(v) for v in getattr(stats, 'update_ms', [])]
    report.counters = dict(sorted(dict(getattr(stats, 'counters', {}) or {}).items()))
    for name, text in SUSPECT_COUNTERS.items():
        if report.counters.get(name):
            report.warnings.append(f'{report.counters[name]} {text}')
    if hasattr(stats, 'keyframes'):
        report.counters['keyframes_processed'] = int(stats.keyframes)
    report.keyframes_not_optimized = int(getattr(stats, 'not_optimized', 0))
    report.map_scale = [float(v) for v in getattr(stats, 'map_scale', [])]
    fallbacks = {'solve_rollbacks': 'window solves rolled back (inconsistent with the front-end)',
                 'reinitializations': 'window re-initializations from the front-end'}
    for name, what in fallbacks.items():
        if report.counters.get(name):
            report.warnings.append(f'{report.counters[name]} {what}')
    extrinsic = getattr(logic, 'extrinsic', None)
    if extrinsic is not None:
        report.extrinsic = {'source': getattr(logic, 'extrinsic_source', ''),
                            'body_to_camera': [round(v, 9) for v in extrinsic.to_flat()]}
        report.extrinsic |= _rig_report(getattr(logic, 'rig_cameras', {}))


def _rig_report(rig_cameras: dict[int, tuple[Any, str]]) -> dict[str, Any]:
    """Return the report entry of the other cameras used: pose in the reference camera."""
    if not rig_cameras:
        return {}
    return {'rig_cameras': {str(cam): {'source': source, 'in_reference_camera': [
        round(v, 9) for v in offset.to_flat()]} for cam, (offset, source)
        in sorted(rig_cameras.items())}}


def accuracy(frontend: Any, optimized: Any, gt: Any, *, align: str = 'sim3',
             max_diff_s: float = 0.01) -> dict[str, Any]:
    """Return ATE / RPE of the front-end and optimized keyframes against ground truth.

    Args:
        frontend: Front-end trajectory.
        optimized: Optimized trajectory.
        gt: Ground truth.
        align: Alignment mode for both ('sim3', 'se3' or 'none').
        max_diff_s: Largest stamp difference for association, s.

    Returns:
        ``ate_frontend_m``, ``ate_optimized_m``, ``ate_ratio`` (optimized / front-end),
        ``rpe_frontend``, ``rpe_optimized`` (RMSE, m, consecutive keyframes),
        ``alignment`` and the full results under ``frontend`` / ``optimized``. The
        optimized entries are None if the back-end optimized no keyframe.

    Raises:
        EvaluationError: If a trajectory has no stamps overlapping the ground truth.
    """
    from pmba_ros.eval.metrics import evaluate

    results = {}
    for name, traj in (('frontend', frontend), ('optimized', optimized)):
        if len(traj) == 0 and name == 'optimized':
            logger.warning('the back-end optimized no keyframe; no optimized accuracy')
            continue
        try:
            results[name] = evaluate(traj, gt, align=align, max_diff_s=max_diff_s)
        except EvaluationError as err:
            hint = ' (try --align none)' if 'degenerate' in str(err) and align != 'none' else ''
            msg = f'ground truth vs {name} keyframes: {err}{hint}'
            raise EvaluationError(msg) from err
    ate_f = results['frontend']['ate'].rmse
    opt = results.get('optimized')
    ate_o = opt['ate'].rmse if opt is not None else None
    return {
        'alignment': align,
        'ate_frontend_m': ate_f,
        'ate_optimized_m': ate_o,
        'ate_ratio': ate_o / ate_f if ate_o is not None and ate_f > 0 else None,
        'rpe_frontend': results['frontend']['rpe'].rmse,
        'rpe_optimized': opt['rpe'].rmse if opt is not None else None,
        'matched_frontend': results['frontend']['ate'].n_matched,
        'matched_optimized': opt['ate'].n_matched if opt is not None else 0,
        'notes': sorted({r.note for res in results.values() for r in res.values() if r.note}),
        'frontend': {k: v.to_dict() for k, v in results['frontend'].items()},
        'optimized': {k: v.to_dict() for k, v in opt.items()} if opt is not None else None,
    }


def write_plots(out: Path, frontend: Any, optimized: Any, gt: Any, report: ReplayReport,
                align: str = 'sim3') -> dict[str, Path]:
    """Write the replay PNGs: top view, cost per solve, solve time per keyframe.

    With ground truth, both estimates are aligned onto it (``align``) for the top view.

    Returns:
        Plot name -> path.

    Raises:
        PmbaError: If matplotlib is missing or a file cannot be written.
    """
    from pmba_ros import plot as plots

    curves: list[tuple[str, Any]] = []
    errors: list[tuple[str, Any]] = []
    if gt is not None:
        from pmba_ros.eval.metrics import ate
        curves.append(('ground truth', gt))
        for label, traj in (('front-end', frontend), ('optimized', optimized)):
            try:
                result = ate(traj, gt, align=align)
            except EvaluationError:
                curves.append((label, traj))
                continue
            curves.append((label, _aligned(traj, result)))
            errors.append((label, result.errors))
    else:
        curves = [('front-end', frontend), ('optimized', optimized)]
    files = {'plot_top_view': plots.plot_top_view(out / 'trajectories_top.png', curves)}
    if errors:
        files['plot_ate'] = plots.plot_curves(out / 'ate_per_keyframe.png', errors,
                                              'position error (m)',
                                              f'ATE per keyframe ({align}-aligned)')
    files['plot_cost'] = plots.plot_curves(out / 'cost_per_solve.png',
                                           [('before', report.costs_before),
                                            ('after', report.costs)],
                                           'cost', 'Cost per solve', log_scale=True,
                                           xlabel='solve')
    files['plot_solve_time'] = plots.plot_series(out / 'solve_time.png', report.solve_ms,
                                                 'solve time (ms)', 'Solve time per keyframe',
                                                 xlabel='keyframe solve')
    return files


def _aligned(traj: Any, result: Any) -> Any:
    """Return ``traj`` moved by the alignment of an ATE result."""
    from pmba_ros.eval.align import apply_alignment, UmeyamaResult
    fit = UmeyamaResult(result.rotation, result.translation, result.scale)
    return apply_alignment(traj, fit)


__all__ = ['FRONTEND_TUM', 'LANDMARKS_PLY', 'OPTIMIZED_TUM', 'REPORT_JSON', 'RESULT_BAG',
           'ReplayReport', 'accuracy', 'camera_info_from_intrinsics', 'replay',
           'resolve_topic', 'stamp_ordered', 'write_plots']
