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
"""Tests of the pose stream sampled at the tracks' stamps (``keyframe_source: tracks``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pmba_ros.backend.logic import BackendLogic
from pmba_ros.backend.pose_stream import MAX_GAP_S, PoseStream
from pmba_ros.backend.types import KeyframePose
from pmba_ros.core import so3
from pmba_ros.replay_report import collect_stats, ReplayReport
from pmba_ros.sim.sequence import SimSequence, simulate_sequence
import pytest

from .test_logic import BACKEND, camera_info_msg, config, keyframe_msg, run, tracks_msg

MS = 1_000_000


def _pose(stamp_ns: int, x: float, yaw: float, cov: float | None = None) -> KeyframePose:
    R = so3.exp(np.array([0.0, 0.0, yaw]))
    return KeyframePose(stamp_ns, 'odom', 'imu', np.array([x, 2.0 * x, 0.0]),
                        so3.to_quat_xyzw(R), None if cov is None else np.eye(6) * cov)


def test_a_pose_at_the_stamp_is_taken_others_are_interpolated() -> None:
    """At a pose's stamp: that pose; between two: lerp / slerp / lerp of the covariance."""
    stream = PoseStream(10)
    stream.add(_pose(100 * MS, 1.0, 0.1, 1e-3))
    stream.add(_pose(200 * MS, 3.0, 0.5, 3e-3))
    pose, ready, jumped = stream.sample(200 * MS, give_up=False)
    assert ready and not jumped and pose is not None and pose.stamp_ns == 200 * MS
    np.testing.assert_array_equal(pose.position, [3.0, 6.0, 0.0])
    pose, ready, _ = stream.sample(175 * MS, give_up=False)
    assert ready and pose is not None and pose.stamp_ns == 175 * MS
    np.testing.assert_allclose(pose.position, [2.5, 5.0, 0.0])
    np.testing.assert_allclose(so3.from_quat_xyzw(pose.quat_xyzw),
                               so3.exp(np.array([0.0, 0.0, 0.4])), atol=1e-12)
    assert pose.covariance is not None
    np.testing.assert_allclose(pose.covariance, np.eye(6) * 2.5e-3)
    assert pose.child_frame_id == 'imu' and pose.frame_id == 'odom'


def test_the_stream_is_waited_for_until_it_passes_the_stamp() -> None:
    """Before a pose at or after the stamp: not ready, unless given up; before the first: none."""
    stream = PoseStream(10)
    assert stream.sample(50 * MS, give_up=False) == (None, False, False)
    assert stream.sample(50 * MS, give_up=True) == (None, True, False)
    stream.add(_pose(100 * MS, 1.0, 0.0))
    assert stream.sample(150 * MS, give_up=False) == (None, False, False)
    assert stream.sample(50 * MS, give_up=False) == (None, True, False)   # before the first
    stream.add(_pose(200 * MS, 2.0, 0.0))
    pose, ready, _ = stream.sample(150 * MS, give_up=False)
    assert ready and pose is not None


def test_no_pose_across_a_gap_or_a_jump_of_the_frame() -> None:
    """Poses over MAX_GAP_S apart, or with a jump of the front-end's frame between: none."""
    gap = round(MAX_GAP_S * 1e9)
    stream = PoseStream(10)
    stream.add(_pose(0, 0.0, 0.0))
    stream.add(_pose(gap + MS, 1.0, 0.0))
    assert stream.sample(gap // 2, give_up=False) == (None, True, False)
    stream.add(_pose(gap + 101 * MS, 2.0, 0.0), jumped=True)
    assert stream.sample(gap + 51 * MS, give_up=False) == (None, True, False)
    pose, ready, jumped = stream.sample(gap + 101 * MS, give_up=False)
    assert ready and jumped and pose is not None   # the pose after the jump itself


def test_forget_before_keeps_the_last_pose_before_the_stamp() -> None:
    """Poses no later stamp needs go; the one before the stamp stays for interpolation."""
    stream = PoseStream(3)
    for i in range(6):
        stream.add(_pose(i * 100 * MS, float(i), 0.0))
    assert stream.count == 6
    assert stream.sample(250 * MS, give_up=False)[0] is None   # capacity 3: 300-500 kept
    stream.forget_before(450 * MS)
    pose, ready, _ = stream.sample(450 * MS, give_up=False)
    assert ready and pose is not None
    np.testing.assert_allclose(pose.position[0], 4.5)


def _stream_run(seq: SimSequence, per_keyframe: int, offset_ns: int,
                source: str, tracks_lead: int = 0) -> BackendLogic:
    """Run the back-end over tracks and a pose stream ``per_keyframe`` times their rate.

    The tracks of keyframe ``i + tracks_lead`` arrive before the poses after keyframe i.
    """
    logic = BackendLogic(config(keyframe_source=source), BACKEND)
    logic.on_camera_info(camera_info_msg(seq))
    for i in range(tracks_lead):
        logic.on_tracks(tracks_msg(seq, i))
    for i in range(len(seq)):
        if i + tracks_lead < len(seq):
            logic.on_tracks(tracks_msg(seq, i + tracks_lead))
        logic.step()
        last = i + 1 == len(seq)
        i0, j = (i - 1, i) if last else (i, i + 1)   # the last keyframe: its segment's end
        step = int(seq.stamps_ns[j] - seq.stamps_ns[i0])
        for k in range(1 if last else per_keyframe):
            # The front-end's path between keyframes: straight, at constant rates.
            stamp = int(seq.stamps_ns[i]) + k * step // per_keyframe + offset_ns
            a = (stamp - int(seq.stamps_ns[i0])) / step
            msg: Any = keyframe_msg(seq, i)
            R = seq.R_wc_odom[i0] @ so3.exp(a * so3.log(seq.R_wc_odom[i0].T @ seq.R_wc_odom[j]))
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            p = (1 - a) * seq.centers_odom[i0] + a * seq.centers_odom[j]
            msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z = p
            q = so3.to_quat_xyzw(R)
            o = msg.pose.pose.orientation
            o.x, o.y, o.z, o.w = q
            logic.on_keyframe(msg)
            logic.step()
    logic.end_of_input()
    logic.step()
    return logic


@pytest.fixture(scope='module')
def street40() -> SimSequence:
    """Return a 40-keyframe street."""
    return simulate_sequence('street', n_keyframes=40, seed=0)


def test_a_pose_stream_ten_times_the_tracks_rate_gives_the_keyframes_poses(
        street40: SimSequence) -> None:
    """Sampled at the tracks, a 100 Hz stream gives what one pose per keyframe gives.

    As keyframes (the default), its poses between the tracks would be keyframes without
    tracks: 9 in 10 of them, breaking every window.
    """
    reference = BackendLogic(config(), BACKEND)
    run(reference, street40)
    stream = _stream_run(street40, 10, 0, 'tracks')
    assert not stream.stats.counters.get('keyframes_without_pose')
    ref_traj, traj = reference.optimized_trajectory(), stream.optimized_trajectory()
    np.testing.assert_array_equal(traj.stamps_s, ref_traj.stamps_s)
    np.testing.assert_allclose(traj.positions_xyz, ref_traj.positions_xyz, atol=1e-9)
    as_keyframes = _stream_run(street40, 10, 0, 'keyframe_topic')
    assert as_keyframes.stats.counters['keyframes_without_tracks'] > 300
    report, fine = ReplayReport(bags=[], out_dir=Path()), ReplayReport(bags=[], out_dir=Path())
    collect_stats(as_keyframes, report)
    collect_stats(stream, fine)
    assert any('--keyframes-from tracks' in w for w in report.warnings), report.warnings
    assert not any('--keyframes-from' in w for w in fine.warnings)


def test_a_stream_behind_the_tracks_is_waited_for(street40: SimSequence) -> None:
    """Poses arriving 0.3 s after the tracks of their time: not stale input, not a restart.

    The keyframes whose tracks came before any pose are taken without one (none was known to
    come); every later one gets its pose.
    """
    logic = _stream_run(street40, 10, 0, 'tracks', tracks_lead=3)
    counters = logic.stats.counters
    assert not counters['input_restarts'] and not counters['keyframes_without_pose']
    fe = logic.frontend_trajectory()
    np.testing.assert_array_equal(fe.stamps_s, street40.stamps_ns[4:] * 1e-9)
    np.testing.assert_allclose(fe.positions_xyz, street40.centers_odom[4:], atol=1e-9)
    assert len(logic.optimized_trajectory()) == len(street40)


def test_a_slow_streams_first_poses_are_waited_for_while_they_are_judged() -> None:
    """At 2 Hz the checks hold the first poses for 3 s, past the association timeout.

    Before, the first keyframe was taken without its pose, which had come and was held:
    lost from every output when nothing initializes (a rotation), without a front-end pose
    otherwise.
    """
    seq = simulate_sequence('street', n_keyframes=12, seed=0, rate_hz=2.0)
    logic = _stream_run(seq, 1, 0, 'tracks')
    assert not logic.stats.counters.get('keyframes_without_pose')
    fe = logic.frontend_trajectory()
    np.testing.assert_array_equal(fe.stamps_s, seq.stamps_ns * 1e-9)
    np.testing.assert_allclose(fe.positions_xyz, seq.centers_odom, atol=1e-9)


def test_a_stream_offset_from_the_tracks_is_interpolated(street40: SimSequence) -> None:
    """Poses 3 ms after each 10 ms slot: every keyframe but the first gets a pose between two."""
    reference = BackendLogic(config(), BACKEND)
    run(reference, street40)
    logic = _stream_run(street40, 10, 3 * MS, 'tracks')
    assert logic.stats.counters['keyframes_without_pose'] == 1   # the first: none before it
    fe = logic.frontend_trajectory()
    assert len(fe) == 39
    # Interpolated across a keyframe, where the path bends: within a millimetre of it.
    np.testing.assert_allclose(fe.positions_xyz, street40.centers_odom[1:], atol=1e-3)
    traj, ref = logic.optimized_trajectory(), reference.optimized_trajectory()
    assert len(traj) == 40
    np.testing.assert_allclose(traj.positions_xyz, ref.positions_xyz, atol=0.05)
