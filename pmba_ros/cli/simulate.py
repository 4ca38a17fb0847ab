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
"""``pmba simulate``: write a simulated front-end recording, or a BAL problem.

Usage examples::

    pmba simulate --scenario street --keyframes 200 --seed 0 --out street_bag
    pmba simulate --scenario loop --keyframes 300 --layout named --out loop.mcap
    pmba simulate --format bal --scenario street --out street.txt     # for `pmba solve`
    pmba simulate --format bal --scenario table3 --seed 1 --out table3.txt
    pmba simulate --stop 60:100 --keyframes 300 --out stop_bag   # at rest for 100 keyframes
    pmba simulate --frontend openvins --out ov_bag     # OpenVINS's topics and track layout

A bag (``--format bag``, the default) holds VINS-layout ``PointCloud`` tracks (``PointCloud2``
with ``--layout named``), drifting ``Odometry`` keyframe poses, ``CameraInfo`` and the ground
truth as ``PoseStamped``, on the topics the node reads by default; the ground truth also goes
to ``BAG/groundtruth.tum`` (``<stem>_groundtruth.tum`` beside a ``.mcap`` file).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import TYPE_CHECKING

from pmba_ros.backend.frontends import PAIRINGS
from pmba_ros.cli.argtypes import (
    int_at_least,
    non_negative_float,
    non_negative_int,
    positive_float,
)
from pmba_ros.errors import PmbaError
from pmba_ros.eval.trajectory import MAX_TIME_S
from pmba_ros.sim.sequence import MIN_KEYFRAMES, START_NS

if TYPE_CHECKING:
    from pmba_ros.sim.bag import SimTopics

_BAG_SCENARIOS = ('street', 'aerial', 'loop', 'rotation')
_BAL_SCENARIOS = ('street', 'table3')
_LAYOUTS = ('vins_mono', 'vins_fusion', 'per_point', 'named')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the arguments of the ``simulate`` verb.

    Args:
        parser: Parser (or subparser) to add the arguments to.
    """
    parser.add_argument('--format', choices=('bag', 'bal'), default='bag',
                        help='bag: front-end recording; bal: BA problem for `pmba solve`')
    parser.add_argument('--scenario', default='street',
                        choices=sorted(set(_BAG_SCENARIOS) | set(_BAL_SCENARIOS)),
                        help='bag: street|aerial|loop|rotation; bal: street|table3')
    parser.add_argument('--keyframes', type=int_at_least(MIN_KEYFRAMES), default=200,
                        metavar='N', help=f'keyframes (bag) or cameras (bal street), at '
                        f'least {MIN_KEYFRAMES}')
    parser.add_argument('--seed', type=non_negative_int, default=0, metavar='S',
                        help='random seed')
    parser.add_argument('--out', required=True, type=Path, metavar='BAG|FILE',
                        help='bag folder or .mcap file (bag), or problem file (bal)')
    parser.add_argument('--layout', choices=_LAYOUTS, default=None,
                        help='track layout (named = PointCloud2 with named fields; default: '
                        "the front-end's, else vins_fusion)")
    parser.add_argument('--frontend', choices=sorted(PAIRINGS), default=None,
                        help="bag: on this front-end's topics, in its track layout (the "
                        'pairings of launch/pmba.launch.py); default: the topics the node '
                        'reads by default')
    parser.add_argument('--noise-px', type=non_negative_float, default=0.5, metavar='PX',
                        help='pixel noise standard deviation')
    parser.add_argument('--drift', type=non_negative_float, default=0.02,
                        help='front-end drift (about this fraction of the distance)')
    parser.add_argument('--rate-hz', type=positive_float, default=10.0, metavar='HZ',
                        help='keyframe rate')
    parser.add_argument('--extrinsic', choices=('none', 'euroc'), default='none',
                        help='bag: keyframe poses and ground truth of a body with this body -> '
                        'camera transform on /tf_static (euroc: the cam0 of EuRoC; default: '
                        'the poses are the camera poses)')
    parser.add_argument('--cameras', type=int, choices=(1, 2), default=1,
                        help='bag: 2 writes a stereo rig (EuRoC cam1 beside cam0, its '
                        'observations as camera 1, a second CameraInfo topic '
                        '/camera1/camera_info and its transform on /tf_static)')
    parser.add_argument('--stop', type=_stop, metavar='FIRST:COUNT',
                        help='bag: at rest for COUNT keyframes from keyframe FIRST, slowing '
                        'down and speeding up over 30 keyframes on either side (a car at a '
                        'traffic light)')
    parser.add_argument('--turn', type=float, default=0.0, metavar='DEG',
                        help='bag, with --stop: turn on the spot while at rest, by up to DEG '
                        'about the vertical and back')
    parser.add_argument('--overwrite', action='store_true', help='replace an existing output')


def _stop(text: str) -> tuple[int, int]:
    """Parse ``FIRST:COUNT`` of ``--stop``."""
    first, sep, count = text.partition(':')
    try:
        values = (int(first), int(count))
    except ValueError:
        values = (-1, 0)
    if not sep or values[0] < 0 or values[1] < 1:
        msg = f'expected FIRST:COUNT with FIRST >= 0 and COUNT >= 1, got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return values


def run(args: argparse.Namespace) -> int:
    """Simulate and write the recording or problem.

    Args:
        args: Parsed arguments (see :func:`add_arguments`).

    Returns:
        0 on success.

    Raises:
        PmbaError: On invalid options or if the output cannot be written.
    """
    if args.format == 'bal':
        return _run_bal(args)
    if args.scenario not in _BAG_SCENARIOS:
        msg = f'--scenario {args.scenario} is for --format bal; bags: {", ".join(_BAG_SCENARIOS)}'
        raise PmbaError(msg)
    _check_rate(args.keyframes, args.rate_hz)
    layout, topics = _front_end(args.frontend, args.layout)
    if args.cameras == 2:
        _check_two_cameras(args.frontend, layout)
    from pmba_ros.backend.extrinsics import Rigid
    from pmba_ros.sim.bag import EUROC_CAM0, write_sequence_bag
    from pmba_ros.sim.rig import add_camera, EUROC_CAM1
    from pmba_ros.sim.sequence import simulate_sequence

    try:
        seq = simulate_sequence(args.scenario, n_keyframes=args.keyframes, seed=args.seed,
                                noise_px=args.noise_px, drift=args.drift, rate_hz=args.rate_hz,
                                stop=args.stop, turn_deg=args.turn)
    except ValueError as err:
        raise PmbaError(str(err)) from err
    extrinsic = EUROC_CAM0 if args.extrinsic == 'euroc' else None
    rig: list[Rigid] = []
    if args.cameras == 2:
        # EuRoC's cam1 where it sits relative to cam0 (camera 0 is the body without --extrinsic).
        T_c0c1 = EUROC_CAM0.inverse() @ EUROC_CAM1
        seq = add_camera(seq, T_c0c1, camera_id=1, seed=args.seed + 1)
        rig = [EUROC_CAM1 if extrinsic is not None else T_c0c1]
        extrinsic = extrinsic or Rigid.identity()
    info = write_sequence_bag(seq, args.out, layout=layout, overwrite=args.overwrite,
                              extrinsic=extrinsic, rig_extrinsics=rig, topics=topics)
    print(f'wrote {info.bag}: {args.scenario}, {info.n_keyframes} keyframes '
          f'({info.duration_s:.1f} s), {info.n_observations} observations, '
          f'{info.n_messages} messages')
    print(f'ground truth: {info.groundtruth_tum}')
    if args.cameras == 2:
        print('a metric map: evaluate its replay with --align se3')
        if layout == 'vins_mono':   # its ids hold the camera, but not the camera count
            print('replay it with --camera-info-topic /camera_info --camera-info-topic '
                  '/camera1/camera_info (tracks in layout vins_mono do not tell num_cams)')
    if args.frontend is not None:
        print(f'the node on its topics: ros2 launch pmba_ros pmba.launch.py '
              f'frontend:={args.frontend}, then pmba play {args.out}')
    return 0


def _check_rate(keyframes: int, rate_hz: float) -> None:
    """Refuse a rate whose last keyframe a ROS stamp cannot hold, or whose stamps repeat."""
    # Found only when the messages were serialized, in the words of struct's int32 range.
    last_s = START_NS * 1e-9 + (keyframes - 1) / rate_hz
    if last_s >= MAX_TIME_S:
        lowest = (keyframes - 1) / (MAX_TIME_S - START_NS * 1e-9)
        step = 10.0 ** (math.floor(math.log10(lowest)) - 2)   # 3 digits, rounded up
        msg = (f'--rate-hz {rate_hz:g}: keyframe {keyframes} of --keyframes {keyframes} '
               f'would be stamped at {last_s:.4g} s, past the seconds a ROS stamp holds '
               f'(an int32: under {MAX_TIME_S:.0f} s); use --rate-hz '
               f'{math.ceil(lowest / step) * step:.3g} or more, or fewer --keyframes')
        raise PmbaError(msg)
    if rate_hz > 1e9:   # stamps count nanoseconds: every keyframe had the same one
        msg = f'--rate-hz {rate_hz:g}: keyframes under 1 ns apart share their stamps (<= 1e9)'
        raise PmbaError(msg)


def _check_two_cameras(frontend: str | None, layout: str) -> None:
    """Refuse a stereo rig where the front-end or layout carries one camera's tracks.

    Raises:
        PmbaError: Layout ``per_point`` (no camera id: VINS-Fusion's keyframe_point and
            OpenVINS' loop_feats carry the reference camera's features), or VINS-Mono,
            whose estimator is monocular.
    """
    if layout == 'per_point':
        named = f'--frontend {frontend}' if frontend else '--layout per_point'
        msg = (f'--cameras 2: {named} publishes tracks in layout per_point, which has no '
               'camera id (one camera); a stereo rig needs layout vins_fusion (the default), '
               'named or vins_mono')
        raise PmbaError(msg)
    if frontend is not None and PAIRINGS[frontend]['parameters'].get('num_cams') == 1:
        msg = (f'--cameras 2: --frontend {frontend} is monocular; for a two-camera tracker '
               f'in its track layout use --layout {layout} without --frontend')
        raise PmbaError(msg)


def _front_end(frontend: str | None, layout: str | None) -> tuple[str, SimTopics | None]:
    """Return the track layout and topics of ``--frontend`` / ``--layout``.

    Raises:
        PmbaError: If ``--layout`` is not the front-end's.
    """
    from pmba_ros.sim.bag import SimTopics

    if frontend is None:
        return layout or 'vins_fusion', None
    pairing = PAIRINGS[frontend]
    own = pairing['parameters']['feature_layout']
    if layout not in (None, own):
        msg = f'--frontend {frontend} publishes layout {own}, not --layout {layout}'
        raise PmbaError(msg)
    remap = dict(pairing['remappings'])
    return own, SimTopics(tracks=remap['features'], keyframes=remap['keyframe_pose'],
                          camera_info=remap.get('camera_info', SimTopics.camera_info),
                          extrinsic=remap.get('extrinsic', ''))


def _run_bal(args: argparse.Namespace) -> int:
    """Write a BAL problem (the perturbed start of a simulated scene)."""
    from pmba_ros.io.bal import write_bal
    from pmba_ros.sim.scenes import street_scene, table3_scene

    if args.scenario not in _BAL_SCENARIOS:
        msg = f'--format bal supports --scenario {" or ".join(_BAL_SCENARIOS)}'
        raise PmbaError(msg)
    if args.out.exists() and not args.overwrite:
        msg = f'{args.out}: exists already (use --overwrite)'
        raise PmbaError(msg)
    try:
        if args.scenario == 'table3':
            scene = table3_scene(seed=args.seed, noise_px=args.noise_px)
        else:
            scene = street_scene(seed=args.seed, n_cams=args.keyframes, noise_px=args.noise_px)
        write_bal(args.out, scene.start)
    except (ValueError, OSError) as err:
        msg = f'{args.out}: {err}'
        raise PmbaError(msg) from err
    start = scene.start
    print(f'wrote {args.out}: BAL {args.scenario}, {start.n_cams} cameras, {start.n_feats} '
          f'points, {start.n_obs} observations (perturbed start; seed {args.seed})')
    return 0
