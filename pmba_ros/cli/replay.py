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
r"""``pmba replay BAG... --out DIR``: run the back-end over recorded front-end topics.

Usage examples::

    pmba replay --out demo                      # simulated street, replayed and evaluated
    pmba simulate --scenario street --keyframes 200 --out street_bag
    pmba replay street_bag --out street_out --gt street_bag/groundtruth.tum
    pmba replay vins.mcap --out out --tracks-topic /feature_tracker/feature \
        --tracks-layout vins_mono --keyframes-topic /vins_estimator/keyframe_pose \
        --intrinsics 458.654,457.296,367.215,248.375 --mode sliding --plot
    pmba_bag_replay run.mcap --out out --params config/pmba.yaml --quiet

Options left unset take their values from ``--params FILE.yaml`` (a ROS 2 parameter file of
the node), or else the node's defaults. Writes ``DIR/result.mcap``,
``DIR/keyframes_frontend.tum``, ``DIR/keyframes_optimized.tum``, ``DIR/landmarks.ply`` and
``DIR/report.json`` (plus PNGs with ``--plot``).

Exit codes: 0 success; 1 error (one ``error:`` line; ``report.json`` says ``"complete":
false``); 2 usage error; 3 the replay ran to the end but the recording was damaged (messages
the bag announces were missing or undecodable; see the report's ``warnings``); 130
interrupted.
"""

from __future__ import annotations

import argparse
from dataclasses import fields, replace
import logging
from pathlib import Path
import signal
import sys
import time
from typing import Any, TextIO, TYPE_CHECKING

from pmba_ros.errors import PmbaError

if TYPE_CHECKING:
    from pmba_ros.replay import ReplayReport

_KEYFRAME_SOURCES = ('keyframe_topic', 'tracks')
_MODES = ('global', 'sliding')

INCOMPLETE_INPUT = 3
"""Exit code of a replay that ran to the end over a damaged recording."""

_OVERRIDES = {'tracks_topic': 'features_topic', 'tracks_layout': 'feature_layout',
              'keyframes_topic': 'keyframe_topic', 'keyframes_type': 'keyframe_type',
              'keyframes_from': 'keyframe_source', 'extrinsic_topic': 'extrinsic_topic',
              'mode': 'mode'}
"""Command-line option (dest) -> BackendConfig field."""


def _defaults() -> dict[str, Any]:
    """Return the node's default parameters (for the help text)."""
    try:
        from pmba_ros.backend.config import BackendConfig
    except ImportError:  # pragma: no cover - the config module ships with the package
        return {}
    defaults = BackendConfig()
    return {f.name: getattr(defaults, f.name) for f in fields(defaults)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the arguments of the ``replay`` verb.

    Args:
        parser: Parser (or subparser) to add the arguments to.
    """
    from pmba_ros.backend.tracks import KEYFRAME_KINDS, LAYOUTS

    d = _defaults()

    def node_default(name: str) -> str:
        return f'node default: {d[name]}' if name in d else 'node default'

    parser.add_argument('bags', metavar='BAG', nargs='*', type=Path, default=argparse.SUPPRESS,
                        help='rosbag2 folder or .mcap/.db3 file (or ROS 1 .bag files); none: '
                        'simulate the default street (200 keyframes) into DIR/street_bag and '
                        'replay it against its ground truth')
    parser.add_argument('--out', required=True, type=Path, metavar='DIR',
                        default=argparse.SUPPRESS,
                        help='output folder (created; outputs in it are replaced)')
    parser.add_argument('--params', type=Path, metavar='FILE.yaml', default=argparse.SUPPRESS,
                        help='ROS 2 parameter file of the node (defaults for the options below)')
    group = parser.add_argument_group('inputs')
    group.add_argument('--tracks-topic', default=argparse.SUPPRESS, metavar='TOPIC',
                       help=f'feature tracks topic ({node_default("features_topic")})')
    group.add_argument('--tracks-layout', choices=LAYOUTS, default=argparse.SUPPRESS,
                       help=f'track message layout ({node_default("feature_layout")}; '
                            'unless given, the one the recording fits)')
    group.add_argument('--keyframes-topic', default=argparse.SUPPRESS, metavar='TOPIC',
                       help=f'keyframe pose topic ({node_default("keyframe_topic")})')
    group.add_argument('--keyframes-type', choices=KEYFRAME_KINDS, default=argparse.SUPPRESS,
                       help=f'keyframe pose message type ({node_default("keyframe_type")}; '
                            'unless given, the recorded one)')
    group.add_argument('--keyframes-from', choices=_KEYFRAME_SOURCES, default=argparse.SUPPRESS,
                       help='keyframe_topic: each keyframe pose is a keyframe; tracks: each '
                       'tracks message is, its pose sampled from the keyframe topic (an '
                       'odometry stream at any rate) where recorded '
                       f'({node_default("keyframe_source")})')
    group.add_argument('--extrinsic-topic', default=argparse.SUPPRESS, metavar='TOPIC',
                       help='Odometry of the reference camera in the body frame, used where '
                       'neither camera_extrinsics nor TF gives it (VINS: '
                       f'/vins_estimator/extrinsic; {node_default("extrinsic_topic")})')
    camera = group.add_mutually_exclusive_group()
    camera.add_argument('--camera-info-topic', default=argparse.SUPPRESS, metavar='TOPIC',
                        action='append',
                        help=f'CameraInfo topic ({node_default("camera_info_topic")}); '
                        'repeat it for a multi-camera rig, in camera-id order (unless given, '
                        "a rig's are the recorded ones, the reference camera's first)")
    camera.add_argument('--intrinsics', default=argparse.SUPPRESS, metavar='FX,FY,CX,CY',
                        help='pinhole intrinsics (px) instead of a CameraInfo topic')
    algo = parser.add_argument_group('back-end')
    algo.add_argument('--mode', choices=_MODES, default=argparse.SUPPRESS,
                      help=f'estimation mode ({node_default("mode")})')
    evaluation = parser.add_argument_group('evaluation and output')
    evaluation.add_argument('--gt', type=Path, default=argparse.SUPPRESS, metavar='FILE',
                            help='ground truth (TUM, EuRoC CSV or KITTI) for ATE / RPE')
    evaluation.add_argument('--gt-times', type=Path, default=argparse.SUPPRESS, metavar='FILE',
                            help='times.txt of a KITTI --gt (its stamps, s; a KITTI file '
                            'without them matches only keyframes stamped 0, 1, 2, ...)')
    evaluation.add_argument('--align', choices=('sim3', 'se3', 'none'), default='sim3',
                            help='alignment onto the ground truth')
    evaluation.add_argument('--plot', action='store_true', default=argparse.SUPPRESS,
                            help='write PNG plots (needs matplotlib)')
    evaluation.add_argument('--quiet', action='store_true', default=argparse.SUPPRESS,
                            help='no progress bar and no table (for scripts)')


def _parse_intrinsics(text: str | None) -> tuple[float, ...] | None:
    """Parse ``fx,fy,cx,cy``.

    Raises:
        PmbaError: If it is not four numbers.
    """
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(','))
    except ValueError:
        values = ()
    if len(values) != 4:
        msg = f'--intrinsics expects FX,FY,CX,CY (four numbers), got {text!r}'
        raise PmbaError(msg)
    return values


def build_config(args: argparse.Namespace) -> Any:
    """Return the BackendConfig of the ``--params`` file (or defaults) with the overrides.

    Raises:
        PmbaError: If the parameter file cannot be read or a value is invalid.
    """
    from pmba_ros.backend.config import BackendConfig
    import yaml

    try:
        params = getattr(args, 'params', None)
        config = BackendConfig.from_yaml(params) if params is not None else BackendConfig()
        changes = {field: getattr(args, opt) for opt, field in _OVERRIDES.items()
                   if getattr(args, opt, None) is not None}
        changes |= _camera_info_changes(config, getattr(args, 'camera_info_topic', None))
        return replace(config, **changes)
    except (OSError, ValueError) as err:
        where = f'--params {params}: ' if params is not None else ''
        msg = f'{where}{err}'
        raise PmbaError(msg) from err
    except yaml.YAMLError as err:
        problem = ' '.join(str(err).split())
        msg = f'--params {params}: not valid YAML: {problem}'
        raise PmbaError(msg) from err


def _chosen(args: argparse.Namespace) -> set[str]:
    """Return the config fields given on the command line (a replay keeps them as given)."""
    chosen = {field for opt, field in _OVERRIDES.items() if getattr(args, opt, None) is not None}
    if getattr(args, 'camera_info_topic', None):
        chosen |= {'num_cams', 'camera_info_topic'}
    return chosen


def _camera_info_changes(config: Any, topics: list[str] | None) -> dict[str, Any]:
    """Return the config changes of the ``--camera-info-topic`` options (one per camera id).

    One topic is the reference camera's (``camera_info_topic``); several are a rig's
    ``camera_info_topics`` in camera-id order (``num_cams`` grows to their number).
    """
    if not topics:
        return {}
    if len(topics) == 1:
        return {'camera_info_topic': topics[0]}
    num_cams = max(config.num_cams, len(topics))
    if config.camera_id >= len(topics):
        msg = (f'--camera-info-topic: {len(topics)} topics, but camera_id={config.camera_id} '
               'needs one for every camera id up to it')
        raise ValueError(msg)
    return {'camera_info_topics': tuple(topics), 'num_cams': num_cams,
            'camera_info_topic': topics[config.camera_id]}


class ProgressBar:
    """A one-line text progress bar (redrawn at most 10 times a second)."""

    def __init__(self, stream: TextIO, width: int = 30) -> None:
        """Draw on ``stream``."""
        self.stream = stream
        self.width = width
        self.t0 = time.perf_counter()
        self.last = 0.0

    def __call__(self, done: int, total: int) -> None:
        """Redraw with ``done`` of ``total`` messages."""
        now = time.perf_counter()
        if now - self.last < 0.1 and done < total:
            return
        self.last = now
        frac = min(1.0, done / total) if total else 1.0
        filled = round(frac * self.width)
        bar = '#' * filled + '.' * (self.width - filled)
        self.stream.write(f'\rreplay [{bar}] {100 * frac:5.1f}% {done}/{total} messages '
                          f'{now - self.t0:6.1f} s')
        self.stream.flush()

    def close(self) -> None:
        """End the line."""
        self.stream.write('\n')
        self.stream.flush()


def run(args: argparse.Namespace) -> int:
    """Replay the bags, print the accuracy table and where the outputs are.

    Args:
        args: Parsed arguments (see :func:`add_arguments`).

    Returns:
        0 on success, 3 if the recording was damaged (incomplete input).

    Raises:
        PmbaError: BagError / MessageError / FormatError / EvaluationError from the replay.
    """
    from pmba_ros.replay import replay

    opts = {name: getattr(args, name, None) for name in ('intrinsics', 'gt', 'gt_times')}
    quiet, plot = bool(getattr(args, 'quiet', False)), bool(getattr(args, 'plot', False))
    config = build_config(args)
    intrinsics = _parse_intrinsics(opts['intrinsics'])
    backend_logger = logging.getLogger('pmba_ros.backend')
    level = backend_logger.level
    if not getattr(args, 'verbose', False):
        # The report counts rejected inputs; one warning per message would bury the summary.
        backend_logger.setLevel(logging.ERROR)
    bar = ProgressBar(sys.stderr) if not quiet and sys.stderr.isatty() else None
    previous = _interrupt_on_sigterm()
    try:
        bags, gt = list(getattr(args, 'bags', [])), opts['gt']
        if not bags:
            bags, gt = _default_street(args.out, gt, quiet=quiet)
        report = replay(bags, args.out, config, gt=gt, gt_times=opts['gt_times'], plot=plot,
                        progress=bar, intrinsics=intrinsics, align=args.align,
                        chosen=_chosen(args))
    finally:
        backend_logger.setLevel(level)   # run in-process (tests, scripts), the caller's again
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if bar is not None:
            bar.close()
    if not quiet:
        print(format_summary(report))
    if not report.input_complete:
        print(f'warning: the recording is damaged: read {report.messages_read} of '
              f'{report.messages_announced} announced messages '
              f'({report.messages_undecodable} undecodable); see {args.out / "report.json"}',
              file=sys.stderr)
        return INCOMPLETE_INPUT
    return 0


def _interrupt_on_sigterm() -> Any:
    """Make SIGTERM raise KeyboardInterrupt, so that the result bag is finalized.

    Returns:
        The previous handler, or None if none could be installed (not the main thread).
    """
    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    try:
        return signal.signal(signal.SIGTERM, handler)
    except ValueError:
        return None


def _default_street(out: Path, gt: Path | None, *, quiet: bool) -> tuple[list[Path], Path]:
    """Simulate the embedded default (street, 200 keyframes, seed 0) into ``out/street_bag``.

    Returns:
        The bag list and the ground truth to use.

    Raises:
        PmbaError: If the bag cannot be written.
    """
    from pmba_ros.sim.bag import write_sequence_bag
    from pmba_ros.sim.sequence import simulate_sequence

    bag = out / 'street_bag'
    if not quiet:   # simulating takes seconds: say what happens before, not after
        print('no BAG given: simulating the default street ...', flush=True)
    info = write_sequence_bag(simulate_sequence('street', n_keyframes=200, seed=0), bag,
                              overwrite=True)
    if not quiet:
        print(f'no BAG given: simulated the default street ({info.n_keyframes} keyframes, '
              f'{info.duration_s:.1f} s) into {bag}')
    return [bag], gt if gt is not None else (info.groundtruth_tum or bag / 'groundtruth.tum')


def _num(value: float | None) -> str:
    """Format one table cell (12 wide; '-' for a missing value)."""
    return f'{value:>12.4f}' if value is not None else f'{"-":>12}'


def _ratio(value: float | None) -> str:
    """Return a ratio column of the accuracy table ('-' where there is none)."""
    return f'{"-" if value is None else f"{value:.3f}":>9}'


def format_summary(report: ReplayReport) -> str:
    """Return the text printed after a replay: counts, accuracy table, output files.

    Args:
        report: The replay report.

    Returns:
        Several lines, without a trailing newline.
    """
    head = (f'replayed {report.messages_in} messages ({report.keyframes_in} keyframes, '
            f'{report.messages_rejected} rejected) in {report.wall_s:.2f} s '
            f'({report.bag_duration_s:.1f} s of data, {report.realtime_factor:.2f}x real time)')
    optimized = report.keyframes_out - report.keyframes_not_optimized
    counts = (f'keyframes out: {report.keyframes_out} ({optimized} optimized); '
              f'solves: {len(report.solve_ms)}')
    lines = [head, counts]
    acc = report.accuracy
    if acc is not None:
        ate = (f'{_num(acc["ate_frontend_m"])}{_num(acc["ate_optimized_m"])}'
               f'{_ratio(acc["ate_ratio"])}')
        rpe = f'{_num(acc["rpe_frontend"])}{_num(acc["rpe_optimized"])}{_ratio(acc["rpe_ratio"])}'
        matched = f'{acc["matched_frontend"]:>12d}{acc["matched_optimized"]:>12d}'
        lines += ['', f'accuracy vs ground truth (alignment {acc["alignment"]})',
                  f'{"":<22}{"front-end":>12}{"optimized":>12}{"ratio":>9}',
                  f'{"ATE rmse (m)":<22}{ate}', f'{"RPE rmse d=1 (m)":<22}{rpe}',
                  f'{"matched poses":<22}{matched}']
    lines += [f'warning: {text}' for text in report.warnings]
    lines += ['', f'outputs in {report.out_dir}:']
    lines += [f'  {path.name}' for _, path in sorted(report.files.items())]
    return '\n'.join(lines)
