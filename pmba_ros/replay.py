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
                            logged at the stamp of the input that produced them; the
                            path, keyframe array and landmarks, which hold the whole run,
                            when it grew by 5 % since the last one recorded, and the last
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

from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
import functools
import logging
import math
from pathlib import Path
import time
from typing import Any, TYPE_CHECKING

from pmba_ros._json import dumps_report
from pmba_ros.backend.cameras import extrinsic_from_message, extrinsic_moved, settled_extrinsic
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.logic import BackendLogic
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.errors import BagError, MessageError
from pmba_ros.eval.accuracy import accuracy
from pmba_ros.eval.trajectory import read_trajectory, Trajectory, write_tum
from pmba_ros.io import ply
from pmba_ros.io.atomic import deferred_interrupts, write_atomic, write_text_atomic
from pmba_ros.io.bag_inputs import (
    header_stamp_ns,
    ReplayInputs,
    resolve_topic,
    rig_camera_infos,
    select_inputs,
    stamp_ordered,
    static_transforms,
)
from pmba_ros.io.bag_writer import open_writer
from pmba_ros.io.bags import (
    BagMessage,
    iter_messages,
    jazzy_typestore,
    open_bags,
    OpenBags,
    ReadStats,
)
from pmba_ros.io.output_dir import output_lock, remove_outputs
from pmba_ros.io.recorded_formats import fit_to_recording
from pmba_ros.plot import pyplot, write_replay_plots
from pmba_ros.replay_report import collect_stats, ReplayReport

if TYPE_CHECKING:
    from pmba_ros.backend.extrinsics import Rigid
    from pmba_ros.io.bag_writer import BagWriter

logger = logging.getLogger(__name__)

ProgressCallback = Callable[[int, int], None]
"""``progress(messages_done, messages_total)``, called while replaying."""

RESULT_BAG = 'result.mcap'
FRONTEND_TUM = 'keyframes_frontend.tum'
OPTIMIZED_TUM = 'keyframes_optimized.tum'
LANDMARKS_PLY = 'landmarks.ply'
REPORT_JSON = 'report.json'
PLOT_FILES = ('trajectories_top.png', 'ate_per_keyframe.png', 'cost_per_solve.png',
              'solve_time.png')
OUTPUT_FILES = (REPORT_JSON, RESULT_BAG, FRONTEND_TUM, OPTIMIZED_TUM, LANDMARKS_PLY,
                *PLOT_FILES)
"""Every file a replay writes; report.json first, so it goes first when they are removed."""

RESULT_GROWTH = 1.05
"""An output that holds the whole run so far (the path, the keyframe array, the landmarks)
goes into the result bag when the run has grown by this factor since the last one recorded,
and the last one always: a run of n keyframes records O(n) poses, not O(n^2) (every one of a
3,000-keyframe street's paths made a 452 MB bag of a 6.6 MB recording)."""

MAX_REJECTED_BEFORE_ANY_ACCEPTED = 10
"""Rejected tracks messages, with none accepted, after which the replay stops."""

REJECTION_COUNTERS = frozenset({'bad_tracks', 'bad_keyframes', 'bad_camera_info',
                                'bad_tf', 'bad_extrinsic', 'keyframe_stamp_not_increasing',
                                'stale_tracks', 'keyframe_pose_jumps', 'keyframe_stamp_leaps',
                                'track_stamp_leaps', 'duplicate_keyframe_poses'})
"""Back-end counters (``BackendLogic.stats.counters``) that mean an input was rejected."""


def camera_info_from_intrinsics(intrinsics: Sequence[float], stamp_ns: int = 0) -> Any:
    """Return a Jazzy ``sensor_msgs/msg/CameraInfo`` for ``(fx, fy, cx, cy)``, no distortion.

    Raises:
        MessageError: If the intrinsics are not four positive, finite numbers.
    """
    from pmba_ros.backend.types import CameraModel
    from pmba_ros.sim.inputs import make_camera_info

    values = [float(v) for v in intrinsics]
    if len(values) != 4:
        msg = f'intrinsics must be fx,fy,cx,cy (4 numbers), got {len(values)}'
        raise MessageError(msg)
    camera = CameraModel(fx=values[0], fy=values[1], cx=values[2], cy=values[3])
    return make_camera_info(stamp_ns, 'camera', camera, RosbagsBackend(jazzy_typestore()))


@dataclass
class _Growing:
    """A result-bag topic whose messages hold the whole run so far (see RESULT_GROWTH)."""

    offered: int = 0
    due: int = 1   # the offer that is recorded next
    held: tuple[Any, int] | None = None   # the newest message not recorded, and its stamp


class _Run:
    """State of one replay (feeds the logic, writes its outputs)."""

    def __init__(self, logic: BackendLogic, writer: BagWriter, report: ReplayReport,
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
        self._handlers: dict[str, Callable[[Any], None]] = {
            'camera_info': logic.on_camera_info, 'tracks': logic.on_tracks,
            'keyframe': logic.on_keyframe, 'tf': logic.on_tf, 'extrinsic': logic.on_extrinsic}
        cfg = logic.config
        self._growing = {resolve_topic(t): _Growing()
                         for t in (cfg.path_topic, cfg.keyframes_topic, cfg.landmarks_topic)}

    def feed(self, stamp: int, kind: str, message: BagMessage) -> None:
        """Feed one input message, then write whatever the logic produced."""
        report = self.report
        report.messages_in += 1
        if self.first_stamp is None:
            self.first_stamp = stamp
        self.last_stamp = max(self.last_stamp, stamp)
        if kind == self.keyframe_kind:
            report.keyframes_in += 1
        handler: Callable[[Any], None] = self._handlers[kind]
        if message.topic in self.camera_ids:
            handler = functools.partial(self.logic.on_camera_info,
                                        camera_id=self.camera_ids[message.topic])
        before = self._rejections()
        counters = self.logic.stats.counters
        recovered = counters['keyframe_poses_recovered']
        try:
            handler(message.msg)
        except MessageError as err:
            self._rejected(kind, message, stamp, str(err))
        else:
            if self._rejections() > before:
                self._rejected(kind, message, stamp, self.logic.last_error)
            elif kind == 'tracks':
                self.tracks_accepted += 1
        # Poses held while a jump of the front-end's frame was judged, used after all.
        report.messages_rejected -= counters['keyframe_poses_recovered'] - recovered
        self.step()
        if self.progress is not None:
            self.progress(report.messages_in, self.total)

    def _rejections(self) -> int:
        """Return the logic's count of rejected input messages."""
        counters = self.logic.stats.counters
        return sum(counters.get(name, 0) for name in REJECTION_COUNTERS)

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
            stamp = header_stamp_ns(msg, self.last_stamp)
            growing = self._growing.get(name)
            if growing is not None:
                growing.offered += 1
                if growing.offered < growing.due:
                    growing.held = (msg, stamp)
                    continue
                growing.due = max(growing.offered + 1,
                                  math.ceil(growing.offered * RESULT_GROWTH))
                growing.held = None
            self._write(name, msg, stamp)

    def _write(self, name: str, msg: Any, stamp: int) -> None:
        self.writer.write(name, msg, stamp)
        self.report.messages_out += 1

    def finish(self) -> None:
        """Run the logic's last pending work and check that the tracks were usable."""
        self.logic.end_of_input()
        self.step()
        for name, growing in self._growing.items():   # the run's last path, keyframes, map
            if growing.held is not None:
                self._write(name, *growing.held)
                growing.held = None
        if self.tracks_rejected and not self.tracks_accepted:
            self._raise_all_rejected()
        if not self.tracks_rejected and not self.tracks_accepted:
            # An empty topic exits 0 with the front-end's poses as the result: say so.
            self.report.warnings.append(
                f'no tracks message on {self.report.topics.get("tracks")!r}: nothing was '
                "optimized, the keyframes are the front-end's")


def _make_logic(config: BackendConfig) -> BackendLogic:
    """Create the back-end for a replay (deterministic, rosbags messages)."""
    return BackendLogic(config, RosbagsBackend(jazzy_typestore()))


def replay(bags: Sequence[Path | str], out_dir: Path | str,
           config: BackendConfig | None = None, *,
           gt: Path | str | None = None, gt_times: Path | str | None = None,
           plot: bool = False,
           progress: ProgressCallback | None = None,
           intrinsics: Sequence[float] | None = None, align: str = 'sim3',
           chosen: Collection[str] = ()) -> ReplayReport:
    """Run the back-end over recorded front-end topics and write the results.

    Args:
        bags: rosbag2 folders / storage files, or ROS 1 bags (merged in time).
        out_dir: Output folder (created; existing outputs are replaced).
        config: A :class:`~pmba_ros.backend.config.BackendConfig` (default: the node's
            defaults); ``deterministic`` is forced on.
        gt: Ground-truth trajectory file (TUM, EuRoC CSV or KITTI) for the accuracy block.
        gt_times: KITTI ``times.txt`` of a KITTI ``gt`` (its stamps, s).
        plot: Also write PNG plots (needs matplotlib).
        progress: Called as ``progress(done, total)`` after each input message.
        intrinsics: ``(fx, fy, cx, cy)`` to use instead of the bag's CameraInfo.
        align: Alignment of the trajectories onto the ground truth ('sim3', 'se3', 'none').
        chosen: ``config`` fields the user chose, kept even where they cannot read the
            recording; the others follow it (keyframe type, track layout, camera count and
            a rig's CameraInfo topics: :func:`pmba_ros.io.recorded_formats.fit_to_recording`).

    Returns:
        The report (also written to ``out_dir/report.json``).

    Raises:
        BagError: If a bag is missing, unreadable, corrupt or lacks a needed topic.
        MessageError: If the tracks do not fit the configured layout.
        FormatError: If the ground-truth file (or its times) cannot be read.
        EvaluationError: If the ground truth has no stamps overlapping the keyframes, or is
            a KITTI file without times against keyframes stamped in seconds.
        PmbaError: If plotting was asked for without matplotlib.
        BagError: Also if another replay is writing into ``out_dir``, or the bag is damaged
            before its first readable message (later damage is a warning in the report).
        OSError: If an output cannot be written (a full disk); the report names the cause.
    """
    t_start = time.perf_counter()
    bag_paths = [Path(b) for b in bags]
    out = Path(out_dir)
    config = BackendConfig() if config is None else config
    config = replace(config, deterministic=True)
    report = ReplayReport(bags=bag_paths, out_dir=out)
    gt_traj = read_trajectory(gt, times=gt_times) if gt is not None else None
    if plot:
        pyplot()  # fail before the replay if matplotlib is missing
    with open_bags(bag_paths) as opened:
        config = fit_to_recording(opened, config, report.warnings, chosen)
        inputs, kinds, camera_ids = _select(opened, config, intrinsics is not None, report)
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            msg = f'{out}: cannot create output folder: {err}'
            raise BagError(msg) from err
        with output_lock(out):
            remove_outputs(out, OUTPUT_FILES)
            _run_and_write(config, intrinsics, report, opened, kinds, inputs, out,
                           _Outputs(gt_traj, plot, align, t_start, camera_ids), progress)
    return report


def _select(bags: OpenBags, config: BackendConfig, camera_given: bool, report: ReplayReport,
            ) -> tuple[ReplayInputs, dict[str, str], dict[str, int]]:
    """Return the input topics, their kinds (topic -> kind) and a rig's camera info topics."""
    inputs, counts = select_inputs(report.bags, config, camera_given, report.warnings,
                                   bags.topics)
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
    if inputs.extrinsic:
        kinds[inputs.extrinsic] = 'extrinsic'
        report.topics['extrinsic'] = inputs.extrinsic
    camera_ids = rig_camera_infos(report.bags, config, report.warnings, counts, bags.topics)
    for topic in camera_ids:
        kinds[topic] = 'camera_info'
    if camera_ids:
        report.topics['camera_info'] = ', '.join(camera_ids)
    if inputs.tf:
        report.topics['tf'] = ', '.join(inputs.tf)
    report.messages_announced = sum(counts.values())
    return inputs, kinds, camera_ids


@dataclass(frozen=True)
class _Outputs:
    """What to write after the replay."""

    gt: Trajectory | None
    plot: bool
    align: str
    t_start: float
    camera_ids: dict[str, int] = field(default_factory=dict)


def _run_and_write(config: BackendConfig, intrinsics: Sequence[float] | None, report: ReplayReport,
                   bags: OpenBags, kinds: dict[str, str], inputs: ReplayInputs, out: Path,
                   outputs: _Outputs, progress: ProgressCallback | None) -> None:
    """Feed the bags to a new back-end into the result bag, then write the other outputs."""
    report.files['result_bag'] = out / RESULT_BAG
    run: _Run | None = None
    logic: BackendLogic | None = None
    finished = False
    try:
        logic = _make_logic(config)
        if intrinsics is not None:
            logic.on_camera_info(camera_info_from_intrinsics(intrinsics))
        _give_static_transforms(logic, bags, inputs.tf)
        kinds = dict(kinds)
        _give_extrinsic(logic, bags, kinds, inputs.extrinsic, report)
        with open_writer(out / RESULT_BAG, overwrite=True) as writer:
            keyframe_kind = 'keyframe' if inputs.keyframes else 'tracks'
            run = _Run(logic, writer, report, progress, report.messages_announced,
                       keyframe_kind)
            run.camera_ids = outputs.camera_ids
            damage = ReadStats()
            if bags.damage:   # parts that could not be opened: read around, reported as damage
                damage.damaged_parts = len(bags.damage)
                damage.first_damage = bags.damage[0]
                report.warnings.extend(bags.damage[1:])   # the first is `read_error`
            stream = iter_messages(bags, topics=list(kinds), damage=damage,
                                   points_as_arrays=True)
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


def _give_extrinsic(logic: BackendLogic, bags: OpenBags, kinds: dict[str, str],
                    topic: str | None, report: ReplayReport) -> None:
    """Give the back-end the front-end's extrinsic before the other messages.

    The recording's first: VINS publishes it stamped with the newest frame, after the
    keyframe poses of older stamps, so in stamp order the first keyframes would come before
    it (live, it arrives first). It passes again in stamp order, where a bad one is counted
    (here it is skipped). Damage is read past here; the replay's pass reports it.

    Where the recording's extrinsic moves (an online calibration converging: VINS'
    ``estimate_extrinsic``, OpenVINS' ``calib_cam_extrinsics``), where it settled instead
    (:func:`settled_extrinsic`), for the whole run, and said: fixed at the first, a run took
    the calibration's first guess (1.5 degrees off and converging: RPE 2.1x the
    front-end's). The topic is then not fed again (each message would count as a change
    from it).
    """
    if topic is None:
        return
    found: list[Rigid] = []
    bad = 0
    for message in iter_messages(bags, topics=[topic], damage=ReadStats()):
        try:
            found.append(extrinsic_from_message(message.msg))
        except MessageError:
            bad += 1
    if not found:
        return
    settled = settled_extrinsic(found)
    moved = extrinsic_moved(found[0], settled)
    logic.cameras.take_topic_extrinsic(settled if moved else found[0])
    if not moved:
        return
    logic.count('bad_extrinsic', bad)
    del kinds[topic]
    report.messages_announced -= bags.topics[topic].count   # not read again: not missing
    report.warnings.append(
        f"the front-end's extrinsic on {topic} moved by {moved} from its first message to "
        'where it settled (an online calibration): the mean of its last half was used for the '
        'whole run (parameter camera_extrinsics sets one; a live node fixes the newest at its '
        'first keyframe)')


def _give_static_transforms(logic: BackendLogic, bags: OpenBags, tf_topics: Sequence[str],
                            ) -> None:
    """Give the back-end every static transform of the recording before its first message.

    They pass again in stamp order, where a bad one is counted (here it is skipped).
    """
    for msg in static_transforms(bags, tf_topics):
        try:
            logic.cameras.tf_tree.add_message(msg)
        except MessageError:
            continue


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
        found.append(f'{damage.damaged_parts} damaged or incomplete part(s) of the recording '
                     f'read around; first: {damage.first_damage}')
    missing = report.messages_announced - report.messages_read - damage.undecodable
    if missing > 0:
        found.append(f'the bags announce {report.messages_announced} messages on the topics '
                     f'read, but only {report.messages_read} were read ({damage.undecodable} '
                     f'undecodable, {missing} missing): the recording is damaged or truncated')
    for text in found:
        logger.warning('%s', text)
    report.warnings.extend(found)


def _write_outputs(logic: BackendLogic | None, report: ReplayReport, out: Path, outputs: _Outputs,
                   finished: bool) -> None:
    """Write TUM, PLY, accuracy, plots and report.json last (also after an error).

    Raises:
        PmbaError, OSError: If writing fails after a replay that finished (after an error,
            the first error stays the one raised; later ones become warnings).
    """
    if logic is None:  # stopped before the back-end existed: only the report
        _dump_report(report, out, outputs.t_start)
        return
    collect_stats(logic, report)
    try:
        frontend = logic.frontend_trajectory()
        optimized = logic.optimized_trajectory()
        write_atomic(out / FRONTEND_TUM, lambda tmp: write_tum(tmp, frontend))
        report.files['frontend_tum'] = out / FRONTEND_TUM
        write_atomic(out / OPTIMIZED_TUM, lambda tmp: write_tum(tmp, optimized))
        report.files['optimized_tum'] = out / OPTIMIZED_TUM
        report.keyframes_out = len(optimized)
        points = logic.landmarks()
        write_atomic(out / LANDMARKS_PLY, lambda tmp: ply.write_ply(tmp, points))
        report.files['landmarks_ply'] = out / LANDMARKS_PLY
        if outputs.gt is not None and finished:
            report.accuracy = accuracy(frontend, optimized, outputs.gt, align=outputs.align,
                                       warnings=report.warnings)
        if outputs.plot and finished:
            for name, path in write_replay_plots(out, frontend, optimized, outputs.gt, report,
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


__all__ = ['FRONTEND_TUM', 'LANDMARKS_PLY', 'OPTIMIZED_TUM', 'REPORT_JSON', 'RESULT_BAG',
           'ReplayReport', 'camera_info_from_intrinsics', 'replay']
