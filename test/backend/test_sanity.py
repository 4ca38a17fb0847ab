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
"""Input sanity across messages: pose jumps, exploding costs, inexact ids (issue #13)."""

from __future__ import annotations

from collections import Counter
import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from pmba_ros.backend.input_restart import InputRestarts
from pmba_ros.backend.logic import BackendLogic, DIAGNOSTICS_TOPIC
from pmba_ros.backend.sanity import CostMonitor, PoseJumpCheck, StampLeapCheck
from pmba_ros.backend.status import BackendStats
from pmba_ros.backend.types import TrackFrame
from pmba_ros.io.bags import iter_messages
from pmba_ros.replay import replay
from pmba_ros.replay_report import collect_stats, ReplayReport
from pmba_ros.sim.bag import write_sequence_bag
from pmba_ros.sim.sequence import SimSequence, simulate_sequence
import pytest

from .test_logic import BACKEND, camera_info_msg, config, diag_values, keyframe_msg, tracks_msg

STEP_NS = 100_000_000


def _walk(n: int) -> list[tuple[int, np.ndarray]]:
    """Keyframes 0.1 s apart moving 1 m each."""
    return [(i * STEP_NS, np.array([float(i), 0.0, 0.0])) for i in range(n)]


def test_pose_spike_of_three_keyframes_is_rejected_then_followed_again() -> None:
    """A 1e6 m spike for three keyframes is rejected; the return to the path is accepted."""
    check = PoseJumpCheck()
    poses = _walk(20)
    for k in (10, 11, 12):
        poses[k] = (poses[k][0], poses[k][1] + np.array([1e6, 0.0, 0.0]))
    verdicts = [check.check(stamp, pos) for stamp, pos in poses]
    rejected = [k for k, v in enumerate(verdicts) if v is not None]
    assert rejected == [10, 11, 12]
    assert 'jumps 1e+06 in 0.1 s' in str(verdicts[10])
    assert 'rejected as an outlier' in str(verdicts[10])


def test_a_second_spike_right_after_the_first_is_rejected_too() -> None:
    """The recent speeds outlive a glitch: a spike two keyframes after another is judged."""
    check = PoseJumpCheck()
    poses = _walk(20)
    for k, offset in ((10, 1e12), (13, -1e30)):
        poses[k] = (poses[k][0], poses[k][1] + np.array([0.0, offset, 0.0]))
    verdicts = [check.check(stamp, pos) for stamp, pos in poses]
    assert [k for k, v in enumerate(verdicts) if v is not None] == [10, 13]


@pytest.mark.parametrize('bad', [0, 1, 3])
def test_a_first_pose_far_off_is_judged_by_the_next_ones(bad: int) -> None:
    """The first four poses are held and judged against each other; the far one is dropped."""
    poses = _walk(12)
    poses[bad] = (poses[bad][0], poses[bad][1] + np.array([0.0, 1e30, 0.0]))
    check = PoseJumpCheck()
    verdicts = [check.check(stamp, pos, k) for k, (stamp, pos) in enumerate(poses[:3])]
    assert verdicts == [None] * 3 and check.release() == []   # held, not yet judged
    verdict = check.check(*poses[3], 3)
    assert verdict is not None and f'[{poses[bad][0]}]' in verdict
    assert [k for k, _, _ in check.release()] == [k for k in range(4) if k != bad]
    # After them the recent speeds judge as usual.
    assert _released(check, [(s, p) for s, p in poses[4:]]) == [(k, False) for k in range(8)]
    assert check.check(poses[-1][0] + STEP_NS, poses[-1][1] + 1e6) is not None


def test_first_poses_from_rest_or_too_few_are_all_kept() -> None:
    """A start from rest is no outlier; fewer than four poses come back at the end of input."""
    rest = [(k * STEP_NS, np.array([max(0.0, k - 1.5) * 2.0, 0.0, 0.0])) for k in range(6)]
    assert _released(PoseJumpCheck(), rest) == [(k, False) for k in range(6)]
    assert _released(PoseJumpCheck(), _walk(2)) == [(0, False), (1, False)]


def test_persistent_pose_jump_is_accepted_after_max_rejections() -> None:
    """A jump that stays (a relocalization) becomes the new reference."""
    check = PoseJumpCheck(max_rejections=5)
    poses = _walk(20)
    poses = [*poses[:10], *[(s, p + np.array([500.0, 0, 0])) for s, p in poses[10:]]]
    verdicts = [check.check(stamp, pos) for stamp, pos in poses]
    assert [k for k, v in enumerate(verdicts) if v is not None] == [10, 11, 12, 13, 14]


def _released(check: PoseJumpCheck, poses: list[tuple[int, np.ndarray]],
              ) -> list[tuple[int, bool]]:
    """Return (keyframe, jumped) of what ``check`` lets through, in order."""
    out: list[tuple[int, bool]] = []
    for k, (stamp, pos) in enumerate(poses):
        check.check(stamp, pos, k)
        out += [(p, jumped) for p, jumped, _ in check.release()]
    return out + [(p, jumped) for p, jumped, _ in check.flush()]


def test_a_persisting_jump_releases_the_held_poses_as_a_new_frame() -> None:
    """Poses rejected while a jump is judged come back if it persists; a glitch's do not."""
    walk = _walk(20)
    spike = [(s, p + np.array([1e6, 0, 0]) if k in (10, 11) else p) for k, (s, p) in
             enumerate(walk)]
    assert _released(PoseJumpCheck(), spike) == [(k, False) for k in range(20) if k not in
                                                 (10, 11)]
    moved = [(s, p + np.array([500.0, 0, 0]) if k >= 10 else p) for k, (s, p) in enumerate(walk)]
    assert _released(PoseJumpCheck(), moved) == [(k, k == 10) for k in range(20)]
    # 30 m: the second pose after it is under the rejection factor, still a jump.
    moved = [(s, p + np.array([30.0, 0, 0]) if k >= 10 else p) for k, (s, p) in enumerate(walk)]
    assert _released(PoseJumpCheck(), moved) == [(k, k == 10) for k in range(20)]


@pytest.fixture(scope='module')
def long_street() -> tuple[SimSequence, float]:
    """Return a 120-keyframe street and the optimized ATE of its replay without any jump."""
    from pmba_ros.eval.metrics import ate

    seq = simulate_sequence('street', n_keyframes=120, seed=0)
    logic, _ = _run(seq)
    return seq, ate(logic.optimized_trajectory(), seq.gt_trajectory(), 'sim3').rmse


@pytest.mark.parametrize(('jump_m', 'yaw_deg', 'at'), [(30.0, 10.0, 70), (200.0, -30.0, 70),
                                                       (50.0, 20.0, 10), (3.0, 0.0, 70),
                                                       (1.0, 2.0, 70)])
def test_front_end_relocalization_starts_a_new_odom_frame(
        long_street: tuple[SimSequence, float], jump_m: float, yaw_deg: float,
        at: int) -> None:
    """A relocalization of the front-end: the map goes on as without it, TF takes the jump.

    The front-end's frame jumps and turns, before or after the initialization; the small
    jumps pass the pose check as motion and are found by the solve (a step far off the
    front-end's). Before odom segments, a 30 m jump took the map far off.
    """
    from pmba_ros.eval.metrics import ate

    seq, ate_without = long_street
    logic, _ = _run(seq.with_odom_jump(at, np.deg2rad(yaw_deg),
                                       np.array([jump_m, jump_m / 2, 0.0])))
    kf = logic.estimator.kf
    assert int(kf.segment[:kf.n].max()) == 1
    gt, opt = seq.gt_trajectory(), logic.optimized_trajectory()
    assert len(opt) == len(seq)   # the poses rejected before the jump was seen to stay too
    counters = logic.stats.counters
    assert counters['keyframe_poses_recovered'] == counters['keyframe_pose_jumps']
    # Seen in the poses, or, smaller, found by a solve (and counted there).
    assert (counters['keyframe_pose_jumps'] > 0) != (counters['odom_frame_jumps'] == 1)
    assert ate(opt, gt, 'sim3').rmse <= 1.25 * ate_without
    last = kf.n - 1
    T = logic.outputs.map_from_odom_at(last)   # REP-105 still holds in the new frame
    R_o, C_o = logic.outputs.frontend_body_poses(np.array([last]))
    R_m, C_m = logic.outputs.body_poses(np.array([last]))
    np.testing.assert_allclose(T.rotation @ R_o[0], R_m[0], atol=1e-9)
    np.testing.assert_allclose(T.rotation @ C_o[0] + T.translation, C_m[0], atol=1e-9)


def test_replay_of_a_relocalization_uses_every_keyframe(long_street: tuple[SimSequence, float],
                                                        tmp_path: Path) -> None:
    """In a bag: the poses held while the jump was judged are not reported as rejected."""
    seq, _ = long_street
    centers = seq.centers_odom.copy()
    centers[70:] += np.array([200.0, 100.0, 0.0])
    bag = tmp_path / 'reloc.mcap'
    write_sequence_bag(dataclasses.replace(seq, centers_odom=centers), bag)
    report = replay([bag], tmp_path / 'o')
    assert report.counters['keyframe_pose_jumps'] == report.counters[
        'keyframe_poses_recovered'] > 0
    assert report.messages_rejected == 0 and report.keyframes_out == len(seq)


def test_start_from_rest_is_not_a_jump() -> None:
    """Standing still and then driving at 10 m/s stays below the floor times the factor."""
    check = PoseJumpCheck()
    still = [(i * STEP_NS, np.zeros(3)) for i in range(10)]
    moving = [((10 + i) * STEP_NS, np.array([1.0 * (i + 1), 0.0, 0.0])) for i in range(10)]
    assert all(check.check(s, p) is None for s, p in still + moving)


def test_cost_monitor_flags_explosion_and_non_finite() -> None:
    """Cost per observation 20x the recent lowest is flagged; steady costs are not."""
    monitor = CostMonitor()
    rng = np.random.default_rng(0)
    assert all(monitor.check(1000.0 * (1 + 0.1 * rng.random()), 1000) is None
               for _ in range(10))
    text = monitor.check(20_000.0, 1000)
    assert text is not None and 'cost per observation 20' in text
    assert 'inconsistent tracks' in text
    assert 'not finite' in str(monitor.check(float('inf'), 1000))


def test_cost_monitor_judges_a_long_burst_against_the_solves_before_it() -> None:
    """Flagged solves are not remembered; only ``history`` in a row become the new normal."""
    monitor = CostMonitor(history=5)
    assert monitor.check(1000.0, 1000) is None
    assert all(monitor.check(20_000.0, 1000) is not None for _ in range(4))
    assert monitor.check(20_000.0, 1000) is None     # the fifth in a row: tracks got noisier
    assert monitor.check(25_000.0, 1000) is None
    assert monitor.check(300_000.0, 1000) is not None


@pytest.fixture(scope='module')
def street() -> SimSequence:
    """Simulate a 40-keyframe street."""
    return simulate_sequence('street', n_keyframes=40, seed=0)


def _run(seq: SimSequence, frames: list[TrackFrame] | None = None, repeated: tuple[int, ...] = (),
         **params: Any) -> tuple[BackendLogic, list[tuple[str, Any]]]:
    """Feed ``seq`` (config ``params``); the keyframe poses of ``repeated`` twice."""
    logic = BackendLogic(config(**params), BACKEND)
    logic.on_camera_info(camera_info_msg(seq))
    outputs: list[tuple[str, Any]] = []
    for i in range(len(seq)):
        frame = frames[i] if frames is not None else None
        logic.on_tracks(tracks_msg(seq, i, frame=frame))
        outputs += logic.step()
        for _ in range(2 if i in repeated else 1):
            logic.on_keyframe(keyframe_msg(seq, i))
            outputs += logic.step()
    return logic, outputs


def _warned(outputs: list[tuple[str, Any]], counter: str) -> list[dict[str, str]]:
    """Return the diagnostics values of WARN messages that show ``counter``."""
    return [diag_values(m) for t, m in outputs if t == DIAGNOSTICS_TOPIC
            and m.status[0].level == 1 and f'count.{counter}' in diag_values(m)]


def test_a_first_pose_far_off_does_not_spoil_the_run(street: SimSequence) -> None:
    """The first keyframe pose 1e30 m off: dropped, and the other keyframes as without it."""
    centers = street.centers_odom.copy()
    centers[0, 0] = 1e30
    logic, outputs = _run(dataclasses.replace(street, centers_odom=centers))
    assert logic.stats.counters['keyframe_pose_jumps'] == 1
    opt = logic.optimized_trajectory()
    assert len(opt) == len(street) - 1 and np.abs(opt.positions_xyz).max() < 1e3
    assert logic.state == 'tracking' and not logic.stats.counters['reinitializations']
    assert _warned(outputs, 'keyframe_pose_jumps')


def test_front_end_pose_jump_is_not_followed(street: SimSequence) -> None:
    """Three keyframe poses 1e6 m off are rejected (WARN); the optimized path stays put."""
    centers = street.centers_odom.copy()
    centers[25:28] += 1e6
    logic, outputs = _run(dataclasses.replace(street, centers_odom=centers))
    assert logic.stats.counters['keyframe_pose_jumps'] == 3
    assert np.abs(logic.optimized_trajectory().positions_xyz).max() < 1e3
    assert _warned(outputs, 'keyframe_pose_jumps')


def test_repeated_keyframe_poses_are_duplicates_not_jumps(street: SimSequence) -> None:
    """Poses published twice: counted as duplicates, and the run is the one without them.

    Repeats among the first poses (1), of a pose held as a jump (25) and of a plain one
    (30). Before, the first counted as a pose jump, the second as a second jump (towards
    the jump's persistence) and the third as a stamp not increasing.
    """
    centers = street.centers_odom.copy()
    centers[25] += 1e6
    spiked = dataclasses.replace(street, centers_odom=centers)
    clean, _ = _run(spiked)
    logic, outputs = _run(spiked, repeated=(1, 25, 30))
    counters = logic.stats.counters
    assert counters['duplicate_keyframe_poses'] == 3
    assert _warned(outputs, 'duplicate_keyframe_poses')
    assert counters['keyframe_pose_jumps'] == clean.stats.counters['keyframe_pose_jumps'] == 1
    assert not counters['keyframe_stamp_not_increasing']
    for ours, theirs in ((logic.optimized_trajectory(), clean.optimized_trajectory()),
                         (logic.frontend_trajectory(), clean.frontend_trajectory())):
        np.testing.assert_array_equal(ours.stamps_s, theirs.stamps_s)
        np.testing.assert_array_equal(ours.positions_xyz, theirs.positions_xyz)


def test_a_repeat_of_a_stamp_leap_keeps_the_first_copy() -> None:
    """A repeat of a message held as a leap is the repeat, not the next message judging it."""
    check, taken, dropped = StampLeapCheck('leaps', repeat_reason='repeats'), [], []
    glitch = 1000 * 10 ** 9
    for stamp, payload in [*((k * STEP_NS, k) for k in range(6)), (glitch, 'first'),
                           (glitch, 'copy'), (glitch + STEP_NS, 7), (3 * STEP_NS, 'old')]:
        taken += check.admit(stamp, payload, lambda reason, why: dropped.append(reason))
    assert taken == [0, 1, 2, 3, 4, 5, 'first', 7] and dropped == ['repeats', 'repeats']
    # Without repeat_reason, repeats pass unjudged, as before.
    repeated = [0, STEP_NS, STEP_NS, 2 * STEP_NS]
    assert _stamp_leap_run(repeated)[0] == repeated


def test_unstamped_messages_are_named_as_such() -> None:
    """Header stamps left at 0: the repeat's reason says so (it read as a repeated message)."""
    check, why = StampLeapCheck('leaps', repeat_reason='repeats'), []
    for payload in range(3):
        check.admit(0, payload, lambda reason, text: why.append(text))
    assert len(why) == 2 and all('header stamp 0 again' in w for w in why)


def _stamp_leap_run(stamps: list[int]) -> tuple[list[int], list[str]]:
    """Feed ``stamps`` (payload = stamp) then end the input; return what was taken, dropped."""
    check, taken, dropped = StampLeapCheck('leaps'), [], []
    for stamp in stamps:
        taken += check.admit(stamp, stamp, lambda reason, why: dropped.append(f'{reason}: {why}'))
    return taken + check.flush(), dropped


def test_stamp_leap_is_held_then_dropped_or_taken_by_the_next_stamp() -> None:
    """A far-future stamp waits for the next: before it, dropped; after it, both taken."""
    steady = [k * STEP_NS for k in range(6)]
    glitch = 1000 * 10 ** 9
    taken, dropped = _stamp_leap_run([*steady, glitch, 6 * STEP_NS, 7 * STEP_NS])
    assert taken == [*steady, 6 * STEP_NS, 7 * STEP_NS]
    assert len(dropped) == 1 and dropped[0].startswith('leaps: ') and str(glitch) in dropped[0]
    # A front-end that paused for 100 s: nothing is lost, the leap is late by one message.
    paused = [*steady, glitch, glitch + STEP_NS]
    assert _stamp_leap_run(paused) == (paused, [])
    # The last message of the input is never judged, only handed back at its end.
    assert _stamp_leap_run([*steady, glitch]) == ([*steady, glitch], [])
    # Repeated or older stamps pass unjudged (the caller rejects them); so do the first steps.
    assert _stamp_leap_run([*steady, 2 * STEP_NS, 6 * STEP_NS]) == (
        [*steady, 2 * STEP_NS, 6 * STEP_NS], [])
    assert _stamp_leap_run([0, STEP_NS, glitch]) == ([0, STEP_NS, glitch], [])


def test_the_first_stamps_are_judged_together() -> None:
    """No rate yet: the first four are held; one stamped ahead of later arrivals is dropped."""
    glitch = 1000 * 10 ** 9
    steady = [k * STEP_NS for k in range(1, 7)]
    taken, dropped = _stamp_leap_run([glitch, *steady])
    assert taken == steady and len(dropped) == 1 and str(glitch) in dropped[0]
    # In arrival order a leap among them is a pause; out of order, they pass sorted.
    paused = [0, STEP_NS, glitch, glitch + STEP_NS, glitch + 2 * STEP_NS]
    assert _stamp_leap_run(paused) == (paused, [])
    assert _stamp_leap_run([STEP_NS, 0, *steady[1:]]) == ([0, *steady], [])
    check = StampLeapCheck('leaps')
    assert check.admit(STEP_NS, 'a', print) == [] and check.flush() == ['a']


@pytest.mark.parametrize('bad', [0, 20])
@pytest.mark.parametrize('where', ['keyframe', 'tracks', 'both'])
def test_one_far_future_stamp_does_not_end_the_run(street: SimSequence, where: str,
                                                   bad: int) -> None:
    """A message stamped 1,000 s ahead is dropped, not every later keyframe as out of order."""
    logic = BackendLogic(config(), BACKEND)
    logic.on_camera_info(camera_info_msg(street))
    for i in range(len(street)):
        tracks, pose = tracks_msg(street, i), keyframe_msg(street, i)
        if i == bad:
            for msg, part in ((tracks, 'tracks'), (pose, 'keyframe')):
                if where in (part, 'both'):
                    msg.header.stamp.sec += 1000
        logic.on_tracks(tracks)
        logic.step()
        logic.on_keyframe(pose)
        logic.step()
    counters = logic.stats.counters
    assert counters['keyframe_stamp_leaps'] == (where != 'tracks')
    assert counters['track_stamp_leaps'] == (where != 'keyframe')
    assert counters['keyframe_stamp_not_increasing'] == 0
    kept = len(street) - (where != 'tracks')
    assert len(logic.optimized_trajectory()) == kept
    assert logic.state == 'tracking'


@pytest.mark.parametrize('bad', [1, 30])
def test_an_unusable_keyframe_pose_keeps_its_tracks(street: SimSequence, bad: int) -> None:
    """A NaN pose: its keyframe is taken without a pose, unless first poses are being judged."""
    logic = BackendLogic(config(), BACKEND)
    logic.on_camera_info(camera_info_msg(street))
    for i in range(len(street)):
        pose = keyframe_msg(street, i)
        if i == bad:
            pose.pose.pose.position.x = float('nan')
        logic.on_tracks(tracks_msg(street, i))
        logic.step()
        logic.on_keyframe(pose)
        logic.step()
    counters = logic.stats.counters
    assert counters['bad_keyframes'] == 1 and counters['keyframe_stamp_not_increasing'] == 0
    opt, fe = logic.optimized_trajectory(), logic.frontend_trajectory()
    assert len(fe) == len(street) - 1
    # Keyframe 1 arrives while the first four poses are held: its tracks cannot wait for them.
    assert len(opt) == len(street) - (bad == 1)
    assert (street.stamps_ns[bad] * 1e-9 in opt.stamps_s.tolist()) == (bad != 1)
    assert logic.state == 'tracking'


def test_checks_say_when_a_stamp_fits_and_nothing_is_held() -> None:
    """``fits`` / ``idle`` / ``holding``: what a keyframe without a pose may rely on."""
    stamps, poses = StampLeapCheck('leaps'), PoseJumpCheck()
    assert not stamps.fits(0) and not poses.idle()   # nothing seen yet
    assert not stamps.holding() and not poses.holding()
    for i, (stamp, pos) in enumerate(_walk(5)):
        stamps.admit(stamp, stamp, print)
        poses.check(stamp, pos)
        if i < 2:   # the first ones wait to be judged together
            assert stamps.holding() and poses.holding()
    assert stamps.fits(5 * STEP_NS) and not stamps.fits(4 * STEP_NS)
    assert not stamps.fits(1000 * 10 ** 9) and poses.idle()
    assert not stamps.holding() and not poses.holding()
    poses.check(5 * STEP_NS, np.array([1e6, 0.0, 0.0]))   # a jump being judged
    assert not poses.idle() and poses.holding()
    stamps.admit(1000 * 10 ** 9, 0, print)   # far ahead: held until the next one
    assert stamps.holding()


def test_a_pause_of_the_front_end_loses_nothing(street: SimSequence) -> None:
    """Stamps 100 s later from keyframe 20 on (a front-end that paused): every keyframe out."""
    shift = np.where(np.arange(len(street)) >= 20, 100 * 10 ** 9, 0)
    frames = [dataclasses.replace(f, stamp_ns=f.stamp_ns + int(d))
              for f, d in zip(street.frames, shift, strict=True)]
    paused = dataclasses.replace(street, stamps_ns=street.stamps_ns + shift, frames=frames)
    logic, _ = _run(paused)
    logic.end_of_input()
    logic.step()
    assert len(logic.optimized_trajectory()) == len(street)
    assert not (logic.stats.counters['keyframe_stamp_leaps']
                + logic.stats.counters['track_stamp_leaps'])


def _feed(logic: BackendLogic, seq: SimSequence, indices: range | list[int]) -> None:
    for i in indices:
        logic.on_tracks(tracks_msg(seq, i))
        logic.step()
        logic.on_keyframe(keyframe_msg(seq, i))
        logic.step()


def test_a_recording_played_again_starts_the_back_end_over(street: SimSequence) -> None:
    """``ros2 bag play --loop``: the same stamps again. Before, all of them were rejected.

    The second pass's outputs are those of a back-end that saw it alone, and the restart
    shows in the diagnostics (WARN, ``input_restarts``).
    """
    once, _ = _run(street)
    logic, _ = _run(street)
    diagnostics = []
    for i in range(len(street)):
        logic.on_tracks(tracks_msg(street, i))
        logic.on_keyframe(keyframe_msg(street, i))
        diagnostics += [m for t, m in logic.step() if t == DIAGNOSTICS_TOPIC]
    counters = logic.stats.counters
    assert counters['input_restarts'] == 1 and logic.state == 'tracking'
    assert counters['keyframe_stamp_not_increasing'] == InputRestarts.RUN - 1
    again, first = logic.optimized_trajectory(), once.optimized_trajectory()
    np.testing.assert_array_equal(again.stamps_s, first.stamps_s)
    np.testing.assert_array_equal(again.positions_xyz, first.positions_xyz)
    warned = [m for m in diagnostics if diag_values(m).get('count.input_restarts') == '1']
    assert warned and warned[0].status[0].level == 1


@pytest.mark.parametrize('late', [1, InputRestarts.RUN - 1])
def test_late_messages_are_not_a_restart(street: SimSequence, late: int) -> None:
    """Up to RUN - 1 old keyframes and tracks in order, then newer ones: rejected, no restart."""
    older = dataclasses.replace(street, stamps_ns=street.stamps_ns - STEP_NS // 2, frames=[
        dataclasses.replace(f, stamp_ns=f.stamp_ns - STEP_NS // 2) for f in street.frames])
    logic = BackendLogic(config(), BACKEND)
    logic.on_camera_info(camera_info_msg(street))
    _feed(logic, street, range(30))
    _feed(logic, older, range(10, 10 + late))
    _feed(logic, street, range(30, len(street)))
    counters = logic.stats.counters
    assert counters['input_restarts'] == 0
    assert counters['keyframe_stamp_not_increasing'] == counters['stale_tracks'] == late
    assert len(logic.optimized_trajectory()) == len(street)


def test_old_messages_out_of_order_among_themselves_are_not_a_restart() -> None:
    """Each old message must follow the previous one: a scatter of stragglers is none."""
    check = InputRestarts()
    taken = 100
    for stamp in (10, 20, 15, 30, 40, 35, 50, 60):
        assert not check.see('keyframes', stamp, taken, stamp)
    assert not check.see('keyframes', 70, taken, 70)   # 35, 50, 60, 70: four in order
    assert check.see('keyframes', 80, taken, 80)
    assert [m for _, m in check.stretch()] == [35, 50, 60, 70, 80]
    assert not check.see('keyframes', 101, taken, 101)   # a newer message ends any stretch


def test_messages_kept_for_a_possible_restart_stay_within_max_kept() -> None:
    """One stale keyframe, then its stream stalls while tracks flow: at most max_kept are kept.

    Before, the newer tracks were kept for the stretch without a bound, for as long as the
    keyframe stream stayed silent (a front-end that lost track).
    """
    check = InputRestarts(max_kept=10)
    assert not check.see('keyframes', 50, 100, 'stale')
    for stamp in range(101, 1101):
        assert not check.see('tracks', stamp, stamp - 1, stamp)
    assert len(check.stretch()) == 10


def test_keyframes_waiting_for_tracks_are_processed_at_the_end_of_input(
        street: SimSequence) -> None:
    """The tracks of keyframe 35 are unreadable: the keyframes behind it wait, then come out."""
    logic = BackendLogic(config(), BACKEND)
    logic.on_camera_info(camera_info_msg(street))
    for i in range(len(street)):
        tracks = tracks_msg(street, i)
        if i == 35:
            tracks.channels = tracks.channels[:2]
        logic.on_tracks(tracks)
        logic.step()
        logic.on_keyframe(keyframe_msg(street, i))
        logic.step()
    assert logic.stats.counters['bad_tracks'] == 1
    assert len(logic.optimized_trajectory()) == 35   # within the association timeout
    logic.end_of_input()
    logic.step()
    assert len(logic.optimized_trajectory()) == len(street)
    assert logic.stats.counters['keyframes_without_tracks'] == 1


def _random_tracks_after(street: SimSequence, first: int, seed: int) -> list[TrackFrame]:
    """Return the street's frames with random pixels from keyframe ``first`` on."""
    rng = np.random.default_rng(seed)
    frames = list(street.frames)
    for i in range(first, len(frames)):
        f = frames[i]
        xy = rng.uniform(-0.6, 0.6, size=(len(f), 2))
        frames[i] = TrackFrame(f.stamp_ns, f.frame_id, f.feature_ids, f.camera_ids,
                               street.camera.fx * xy + [street.camera.cx, street.camera.cy],
                               xy)
    return frames


@pytest.mark.parametrize('loss', ['cauchy', 'huber', 'none'])
def test_random_tracks_after_keyframe_20_are_flagged(street: SimSequence, loss: str) -> None:
    """Tracks replaced by random pixels: a counted WARN, and no worse than the front-end."""
    from pmba_ros.eval.metrics import ate

    frames = _random_tracks_after(street, 20, seed=1)
    logic, outputs = _run(street, frames, loss=loss)
    assert logic.stats.counters['cost_explosions'] >= 5
    warned = _warned(outputs, 'cost_explosions')
    assert warned and 'cost per observation' in warned[-1]['last_error']
    # The solves that fit the garbage are rolled back: the front-end's motion carries on.
    assert logic.stats.counters['solve_rollbacks'] >= logic.stats.counters['cost_explosions']
    gt = street.gt_trajectory()
    frontend = ate(street.odom_trajectory(), gt, 'sim3').rmse
    assert ate(logic.optimized_trajectory(), gt, 'sim3').rmse <= 1.05 * frontend


@pytest.mark.parametrize('loss', ['huber', 'none'])
def test_clean_tracks_are_no_cost_explosion_under_any_loss(loss: str) -> None:
    """The first 70 keyframes of a clean 200-keyframe street: no solve is rolled back.

    A few rays that a new keyframe sees from behind weigh linearly under Huber and
    quadratically without a loss: judged by those costs, 4 of this street's solves under
    Huber (5 without a loss) were rolled back as cost explosions, the first three here.
    Solves are judged by their cost under Cauchy now, which is the default loss's.
    """
    seq = simulate_sequence('street', n_keyframes=200, seed=2)
    logic = BackendLogic(config(loss=loss), BACKEND)
    logic.on_camera_info(camera_info_msg(seq))
    for i in range(70):
        logic.on_tracks(tracks_msg(seq, i))
        logic.on_keyframe(keyframe_msg(seq, i))
        logic.step()
    assert logic.state == 'tracking'
    assert not logic.stats.counters['cost_explosions']
    assert not logic.stats.counters['solve_rollbacks']


def test_ids_beyond_float32_are_counted_not_merged(street: SimSequence) -> None:
    """Ids >= 2^24 in float32 channels are dropped and counted with a WARN, not merged."""
    logic = BackendLogic(config(), BACKEND)
    logic.on_camera_info(camera_info_msg(street))
    outputs: list[tuple[str, Any]] = []
    for i in range(len(street)):
        msg = tracks_msg(street, i)
        ids = np.array(msg.channels[0].values, dtype=np.float32)
        ids[:4] += np.float32(2 ** 24)  # 2^24 + id: odd ids round onto their neighbours
        msg.channels[0].values = ids
        logic.on_tracks(msg)
        outputs += logic.step()
        logic.on_keyframe(keyframe_msg(street, i))
        outputs += logic.step()
    assert logic.stats.counters['feature_ids_inexact'] == 4 * len(street)
    assert _warned(outputs, 'feature_ids_inexact')
    assert logic.state == 'tracking'


def test_suspect_counters_become_report_warnings() -> None:
    """The replay report lists a warning per suspect-input counter."""
    report = ReplayReport(bags=[], out_dir=Path())
    stats = BackendStats(counters=Counter({'cost_explosions': 7, 'feature_ids_inexact': 12,
                                           'resets': 1}))
    logic = SimpleNamespace(stats=stats, cameras=SimpleNamespace(extrinsic=None),
                            estimator=SimpleNamespace(state='tracking', last_message=''))
    collect_stats(logic, report)
    inexact = ("12 observations dropped: feature ids that cannot be exact in the message's "
               'number type (>= 2^24 in float32: tracks would merge)')
    cost = ('7 solves whose cost per observation exploded relative to their history '
            '(inconsistent tracks?)')
    assert report.warnings == [inexact, cost]


def test_replay_of_random_tracks_warns_in_report_and_diagnostics(street: SimSequence,
                                                                 tmp_path: Path) -> None:
    """Garbage tracks in a bag: report.json has the warning, result.mcap WARN diagnostics."""
    frames = _random_tracks_after(street, 20, seed=2)
    bag = tmp_path / 'random.mcap'
    write_sequence_bag(dataclasses.replace(street, frames=frames), bag)
    out = tmp_path / 'o'
    replay([bag], out)
    data = json.loads((out / 'report.json').read_text())
    assert data['counters']['cost_explosions'] >= 5
    assert any('solves whose cost per observation exploded' in w for w in data['warnings'])
    diagnostics = iter_messages([out / 'result.mcap'], topics=[DIAGNOSTICS_TOPIC])
    levels = [m.msg.status[0].level for m in diagnostics]
    assert 1 in levels[-10:]
