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
"""The back-end fed a simulated street whose messages are damaged at random.

Run::

    python benchmarks/bench_damaged.py [--runs 20] [--keyframes 60] [--rate 0.05]

Each tracks message and each keyframe pose is damaged with probability ``--rate``, one way
drawn at random (NaN / inf / 1e30 / negative values in a coordinate, a channel or the pose;
short or missing channels; no points; duplicated points; stamps 0, -5 s or 2^31 s; an
empty ``frame_id`` or a foreign ``child_frame_id``), then fed to ``BackendLogic`` as the
replay does, ending with ``end_of_input``. Per run it prints the keyframes out, the ATE
against the front-end's (Sim(3)) and the counters of what was rejected; any exception that
escapes the back-end is printed and fails the run (exit status 1).
"""

from __future__ import annotations

import argparse
import copy
import logging
import random
import sys
from typing import Any

import numpy as np
from pmba_ros.backend import outputs as out
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.logic import BackendLogic
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.backend.status import INFO_COUNTERS
from pmba_ros.core import so3
from pmba_ros.eval.metrics import ate
from pmba_ros.sim.inputs import make_camera_info, make_tracks
from pmba_ros.sim.sequence import simulate_sequence

BAD_VALUES = (float('nan'), float('inf'), -float('inf'), 1e30, -1e30, 0.0, -1.0, 2.0 ** 40)
BAD_STAMPS = (0, -5, 2 ** 31 - 1)


def damage_tracks(msg: Any, rng: random.Random) -> str:
    """Damage a vins_fusion PointCloud in place; return what was done."""
    j = rng.randrange(len(msg.points))
    kind = rng.randrange(8)
    if kind == 0:
        axis = rng.choice('xyz')
        setattr(msg.points[j], axis, rng.choice(BAD_VALUES))
        return f'point {axis}'
    if kind in (1, 2):
        c = rng.randrange(len(msg.channels))
        values = msg.channels[c].values.copy()
        if kind == 1:
            values[j] = rng.choice(BAD_VALUES)
        msg.channels[c].values = values if kind == 1 else values[:-1]
        return f'channel {c} value' if kind == 1 else f'channel {c} short'
    if kind == 3:
        msg.channels = msg.channels[:rng.randrange(len(msg.channels))]
        return 'channels missing'
    if kind == 4:
        msg.points = []
        return 'no points'
    if kind == 5:
        msg.header.stamp.sec = rng.choice(BAD_STAMPS)
        return 'stamp'
    if kind == 6:
        msg.points = msg.points + msg.points
        for channel in msg.channels:
            channel.values = np.concatenate([channel.values, channel.values])
        return 'points duplicated'
    msg.header.frame_id = ''
    return 'frame_id empty'


def damage_pose(msg: Any, rng: random.Random) -> str:
    """Damage a nav_msgs/Odometry in place; return what was done."""
    kind = rng.randrange(5)
    if kind == 0:
        setattr(msg.pose.pose.position, rng.choice('xyz'), rng.choice(BAD_VALUES))
        return 'position'
    if kind == 1:
        setattr(msg.pose.pose.orientation, rng.choice('xyzw'), rng.choice(BAD_VALUES))
        return 'orientation'
    if kind == 2:
        cov = msg.pose.covariance.copy()
        cov[rng.randrange(36)] = rng.choice(BAD_VALUES)
        msg.pose.covariance = cov
        return 'covariance'
    if kind == 3:
        msg.header.stamp.sec = rng.choice(BAD_STAMPS)
        return 'stamp'
    msg.child_frame_id = 'other'
    return 'child_frame_id'


def run(seed: int, keyframes: int, rate: float) -> tuple[str, bool]:
    """Feed one damaged street; return its line and whether no exception escaped."""
    rng = random.Random(seed)
    backend = RosbagsBackend()
    seq = simulate_sequence('street', n_keyframes=keyframes, seed=0)
    logic = BackendLogic(BackendConfig(deterministic=True), backend)
    logic.on_camera_info(make_camera_info(int(seq.stamps_ns[0]), 'camera', seq.camera, backend))
    damaged, escaped = 0, []
    for i in range(len(seq)):
        tracks = copy.deepcopy(make_tracks(seq.frames[i], 'vins_fusion', backend))
        pose = out.make_odometry(int(seq.stamps_ns[i]), 'odom', 'camera', seq.centers_odom[i],
                                 so3.to_quat_xyzw(seq.R_wc_odom[i]), np.eye(6) * 1e-3, backend)
        for msg, damage in ((tracks, damage_tracks), (pose, damage_pose)):
            if rng.random() < rate:
                damage(msg, rng)
                damaged += 1
        for feed, msg in ((logic.on_tracks, tracks), (logic.on_keyframe, pose)):
            try:
                feed(msg)
                logic.step()
            except Exception as err:   # what escapes the back-end is the finding
                escaped.append(f'{type(err).__name__}: {err}')
    logic.end_of_input()
    logic.step()
    opt, fe, gt = logic.optimized_trajectory(), seq.odom_trajectory(), seq.gt_trajectory()
    ratio = (ate(opt, gt, 'sim3').rmse / ate(fe, gt, 'sim3').rmse if len(opt) >= 3
             else float('nan'))
    counted = {k: v for k, v in logic.stats.counters.items() if v and k not in INFO_COUNTERS}
    line = (f'run {seed:3d}: {damaged:2d} damaged, {len(opt):3d} / {len(seq)} keyframes out, '
            f'ATE {ratio:.3g}x the front-end; {counted}')
    for text in escaped:
        line += f'\n    ESCAPED {text}'
    return line, not escaped


def main() -> int:
    """Run the damaged streets and print one line each."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=20)
    parser.add_argument('--keyframes', type=int, default=60)
    parser.add_argument('--rate', type=float, default=0.05, help='damage probability')
    args = parser.parse_args()
    logging.disable(logging.WARNING)   # every damaged message is logged; the counts say it
    ok = True
    for seed in range(args.runs):
        line, clean = run(seed, args.keyframes, args.rate)
        print(line, flush=True)
        ok &= clean
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
