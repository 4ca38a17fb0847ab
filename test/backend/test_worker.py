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
"""The node's solver thread without ROS: queue, drops, staged parameters, dispatch.

Also what a stop, a reset, the shutdown or a pause does to a solve in progress.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
import threading
import time
from typing import Any

import numpy as np
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.logic import BackendLogic
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.backend.worker import LogicWorker
from pmba_ros.eval.metrics import ate
from pmba_ros.sim.sequence import SimSequence, simulate_sequence
import pytest

from .test_logic import camera_info_msg, keyframe_msg, tracks_msg


class RecordingLogic(BackendLogic):
    """The real back-end, recording which handler each message reached."""

    def __init__(self) -> None:
        """Create a deterministic back-end."""
        super().__init__(BackendConfig(deterministic=True), RosbagsBackend())
        self.calls: list[tuple[str, Any]] = []

    def on_tracks(self, msg: Any) -> None:
        """Record tracks."""
        self.calls.append(('tracks', msg))

    def on_keyframe(self, msg: Any) -> None:
        """Record a keyframe pose."""
        self.calls.append(('keyframe', msg))

    def on_camera_info(self, msg: Any, camera_id: int | None = None) -> None:
        """Record a CameraInfo (with the camera id of a rig's other camera)."""
        self.calls.append(('camera_info' if camera_id is None else f'camera_info.{camera_id}',
                           msg))

    def on_tf(self, msg: Any) -> None:
        """Record transforms."""
        self.calls.append(('tf', msg))


def test_messages_reach_their_handler_in_order_and_outputs_are_published() -> None:
    """Each kind goes to its handler, in queue order, and every step's outputs are published."""
    logic = RecordingLogic()
    published: list[list[tuple[str, Any]]] = []
    worker = LogicWorker(logic, published.append, queue_size=10)
    for kind in ('camera_info', 'tracks', 'keyframe', 'tf'):
        worker.enqueue(kind, kind.upper())
    assert worker.queue_length() == 4
    assert worker.process_pending() == 4
    assert logic.calls == [('camera_info', 'CAMERA_INFO'), ('tracks', 'TRACKS'),
                           ('keyframe', 'KEYFRAME'), ('tf', 'TF')]
    assert len(published) == 4
    assert worker.received() == {'camera_info': 1, 'tracks': 1, 'keyframe': 1, 'tf': 1}


def test_a_full_queue_drops_and_the_logic_counts_the_drops() -> None:
    """Messages beyond the queue size are dropped and counted as queue_full_<kind>."""
    logic = RecordingLogic()
    worker = LogicWorker(logic, lambda outputs: None, queue_size=2)
    for i in range(5):
        worker.enqueue('tracks', i)
    assert worker.process_pending() == 2
    assert logic.stats.counters['queue_full_tracks'] == 3
    assert worker.received() == {'tracks': 5}


def test_staged_parameters_apply_before_the_next_message() -> None:
    """A staged config reaches the logic at its next message, with publish_tf kept on."""
    logic = RecordingLogic()
    worker = LogicWorker(logic, lambda outputs: None, queue_size=4)
    worker.stage_config(replace(logic.config, max_iterations=7, publish_tf=False))
    assert logic.config.max_iterations != 7
    worker.enqueue('tracks', None)
    worker.process_pending()
    assert logic.config.max_iterations == 7 and logic.config.publish_tf


def test_tf_does_not_count_as_front_end_input() -> None:
    """Only front-end messages move last_input; transforms keep flowing without a front-end."""
    worker = LogicWorker(RecordingLogic(), lambda outputs: None, queue_size=4)
    worker.enqueue('tf', None)
    assert worker.last_input == -1.0
    worker.enqueue('keyframe', None)
    assert 0 < worker.last_input <= time.monotonic()


def test_an_unknown_kind_is_an_error_not_a_camera_info() -> None:
    """A kind the worker does not know is refused; a rig camera's CameraInfo carries its id."""
    logic = RecordingLogic()
    worker = LogicWorker(logic, lambda outputs: None, queue_size=4)
    worker.enqueue('camera_info.1', 'CAM1')  # a rig's camera 1
    assert worker.process_pending() == 1
    assert logic.calls == [('camera_info.1', 'CAM1')]
    worker.enqueue('tracks.1', None)
    with pytest.raises(ValueError, match=r"unknown input kind 'tracks\.1'"):
        worker.process_pending()
    assert logic.calls == [('camera_info.1', 'CAM1')]


def test_the_thread_handles_messages_and_stops() -> None:
    """Started, the thread handles what is queued; stop() ends it."""
    logic = RecordingLogic()
    worker = LogicWorker(logic, lambda outputs: None, queue_size=4)
    worker.start()
    worker.enqueue('tracks', 1)
    deadline = time.monotonic() + 10.0
    while not logic.calls and time.monotonic() < deadline:
        time.sleep(0.01)
    worker.stop()
    assert logic.calls == [('tracks', 1)]


class SolvingLogic(RecordingLogic):
    """A back-end whose step after tracks "solves" for a minute, at the estimator's checkpoints."""

    def __init__(self) -> None:
        """Create it with nothing to solve."""
        super().__init__()
        self.solving = threading.Event()
        self.ended = threading.Event()
        self.release = threading.Event()
        self._tracks_to_solve = False

    def on_tracks(self, msg: Any) -> None:
        """Record tracks; the next step solves."""
        super().on_tracks(msg)
        self._tracks_to_solve = True

    def step(self) -> list[tuple[str, Any]]:
        """Solve until released (or a minute passed), checking in as the solver does."""
        if not self._tracks_to_solve:
            return []
        self._tracks_to_solve = False
        self.solving.set()
        try:
            deadline = time.monotonic() + 60.0
            while not self.release.wait(0.01) and time.monotonic() < deadline:
                self.estimator.checkpoint()
        finally:
            self.ended.set()
        return [('pmba/path', len(self.calls))]


def _wait_for(condition: Callable[[], bool]) -> None:
    """Wait (10 s at most) until ``condition()`` holds."""
    deadline = time.monotonic() + 10.0
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)


def _solving(closing: Callable[[], bool] = lambda: False,
             ) -> tuple[SolvingLogic, LogicWorker, list[Any]]:
    """Return a started worker that is solving the tracks message 1, and what it publishes."""
    logic = SolvingLogic()
    published: list[Any] = []
    worker = LogicWorker(logic, published.append, queue_size=10, closing=closing)
    worker.start()
    worker.enqueue('tracks', 1)
    assert logic.solving.wait(10.0)
    return logic, worker, published


def test_stop_abandons_the_solve_in_progress() -> None:
    """stop() ends a solve at its next iteration (not after it), and nothing is published."""
    logic, worker, published = _solving()
    worker.stop()
    assert logic.ended.wait(10.0)
    assert published == []


def test_the_shutdown_abandons_the_solve_and_what_is_queued() -> None:
    """Once ``closing()`` holds, the solve stops, nothing is published, nothing handled."""
    closing = threading.Event()
    logic, worker, published = _solving(closing.is_set)
    worker.enqueue('keyframe', 2)
    closing.set()
    assert logic.ended.wait(10.0)
    worker.enqueue('keyframe', 3)
    time.sleep(0.3)   # time for the thread to take them (it must not handle them)
    worker.stop()
    assert published == [] and logic.calls == [('tracks', 1)]


def test_reset_abandons_the_solve_and_discards_the_queue() -> None:
    """A reset does not wait for the solve: it is abandoned, unpublished; later input works."""
    logic, worker, published = _solving()
    for i in (2, 3, 4):
        worker.enqueue('tracks', i)
    result: list[int] = []
    reset = threading.Thread(target=lambda: result.append(
        worker.reset(lambda: logic.calls.append(('reset', None)))))
    reset.start()
    reset.join(10.0)
    # Message 2 may have been taken off the queue already: dropped all the same, uncounted.
    assert result in ([2], [3]) and logic.ended.is_set()
    logic.release.set()
    worker.enqueue('tracks', 5)
    _wait_for(lambda: any(published))
    worker.stop()
    assert logic.calls == [('tracks', 1), ('reset', None), ('tracks', 5)]
    assert [outputs for outputs in published if outputs] == [[('pmba/path', 3)]]


def test_a_pause_does_not_wait_for_the_solve() -> None:
    """A pause is staged at once (the solve goes on and is published), applied after it."""
    logic, worker, published = _solving()
    worker.stage_pause(True)
    assert worker.paused and not logic.paused
    logic.release.set()
    _wait_for(lambda: logic.paused)
    worker.stop()
    assert logic.paused and published[0] == [('pmba/path', 1)]


def _street_messages(n: int) -> tuple[SimSequence, list[tuple[str, Any]]]:
    """Return a street and its messages in arrival order: CameraInfo, then tracks and pose."""
    seq = simulate_sequence('street', n_keyframes=n, seed=2)
    msgs = [('camera_info', camera_info_msg(seq))]
    for i in range(n):
        msgs += [('tracks', tracks_msg(seq, i)), ('keyframe', keyframe_msg(seq, i))]
    return seq, msgs


def _live_config(**kwargs: Any) -> BackendConfig:
    """Return the node's configuration without its solves' wall-time budget (they converge)."""
    return BackendConfig(max_time_s=60.0, **kwargs)


@pytest.mark.parametrize('mode', ['sliding', 'global'])
def test_a_worker_behind_its_input_solves_once_for_several_keyframes(mode: str) -> None:
    """A backlog: each keyframe's solve that finds more input queued is left to a later one.

    Every message is queued before the thread handles any (a node whose solves took longer
    than the front-end's keyframe interval). Nothing is dropped, the last message's step
    solves what was left, every keyframe is in the last path, optimized, and the trajectory
    is well below the front-end's error. Before, each keyframe waited for its own solve,
    and a backlog long enough filled the queue: keyframes were dropped.
    """
    seq, msgs = _street_messages(60)
    gt = seq.gt_trajectory()
    runs: dict[bool, tuple[int, int, float, int]] = {}
    for backlog in (False, True):
        logic = BackendLogic(_live_config(mode=mode), RosbagsBackend())
        published: list[list[tuple[str, Any]]] = []
        worker = LogicWorker(logic, published.append, queue_size=len(msgs))
        for kind, msg in msgs:
            worker.enqueue(kind, msg)
            if not backlog:
                worker.process_pending()
        worker.process_pending()
        counters = logic.stats.counters
        assert not any(k.startswith('queue_full') for k in counters)
        paths = [m for outs in published for t, m in outs if t == 'pmba/path']
        assert len(paths[-1].poses) == 60
        est = logic.estimator
        assert np.all(est.optimized(est.estimated())), 'a keyframe was never solved'
        runs[backlog] = (counters['solves_deferred'], len(logic.stats.solve_ms),
                         ate(logic.optimized_trajectory(), gt, 'sim3').rmse, len(paths))
    (deferred_now, solves_now, ate_now, paths_now) = runs[False]
    (deferred, solves, ate_backlog, paths_backlog) = runs[True]
    assert deferred_now == 0
    assert deferred >= 30 and solves <= solves_now - 30
    # A deferred keyframe's step publishes its diagnostics alone: a long run's path takes
    # longer to publish than a keyframe interval.
    assert paths_backlog == paths_now - deferred
    # Fewer, longer solves land elsewhere in the cost's flat valley of a monocular map
    # (its scale along the street), but well below the front-end's error.
    front_end = ate(seq.odom_trajectory(), gt, 'sim3').rmse
    assert ate_now < 0.4 * front_end
    assert ate_backlog < 0.6 * front_end


def test_a_backlog_in_sliding_mode_still_solves_every_half_window() -> None:
    """However long the backlog, a sliding window solves every ``window_size // 2`` keyframes.

    So that no keyframe leaves the window unsolved (it would be published as optimized).
    """
    _, msgs = _street_messages(50)
    logic = BackendLogic(_live_config(window_size=8), RosbagsBackend())
    logic.input_waiting = lambda: True   # the input never catches up
    kinds: list[str] = []
    record = logic.stats.record_update

    def spy(info: Any) -> None:
        kinds.append(info.kind)
        record(info)

    logic.stats.record_update = spy   # type: ignore[method-assign]
    for kind, msg in msgs:
        getattr(logic, f'on_{kind}')(msg)
        logic.step()
    tracking = kinds[kinds.index('init') + 1:]
    assert tracking and set(tracking) <= {'deferred', 'refine'}
    runs = ''.join('d' if k == 'deferred' else 'r' for k in tracking).split('r')
    assert max(len(r) for r in runs) == 8 // 2
    est = logic.estimator
    assert np.all(est.optimized(est.estimated()))


def test_deterministic_logic_never_defers_a_solve() -> None:
    """``deterministic`` (the replay): a solve per keyframe whatever waits, the same poses."""
    _, msgs = _street_messages(30)
    poses = []
    for waiting in (False, True):
        logic = BackendLogic(BackendConfig(deterministic=True), RosbagsBackend())
        logic.input_waiting = lambda waiting=waiting: waiting  # type: ignore[misc]
        for kind, msg in msgs:
            getattr(logic, f'on_{kind}')(msg)
            logic.step()
        assert logic.stats.counters['solves_deferred'] == 0
        assert logic.estimator.state == 'tracking'
        poses.append(logic.optimized_trajectory().positions_xyz)
    np.testing.assert_array_equal(poses[0], poses[1])


def test_a_solve_left_by_the_last_keyframe_runs_when_the_queue_empties() -> None:
    """The last keyframe found a message behind it (a CameraInfo): that step solves.

    Its outputs carry the solved poses (path and odometry of the newest keyframe).
    """
    seq, msgs = _street_messages(30)
    logic = BackendLogic(_live_config(), RosbagsBackend())
    published: list[list[tuple[str, Any]]] = []
    worker = LogicWorker(logic, published.append, queue_size=len(msgs) + 1)
    for kind, msg in [*msgs, msgs[0]]:
        worker.enqueue(kind, msg)
    worker.process_pending()
    est = logic.estimator
    assert est.deferred == 0 and logic.stats.counters['solves_deferred'] > 0
    last = dict(published[-1])
    assert len(last['pmba/path'].poses) == 30
    newest = seq.stamps_ns[-1]
    stamp = last['pmba/odometry'].header.stamp
    assert stamp.sec * 10**9 + stamp.nanosec == newest
    assert np.all(est.optimized(est.estimated()))


def test_keyframes_waiting_for_tracks_are_taken_once_the_input_pauses() -> None:
    """The front-end stops: its last keyframes, whose tracks never came, are placed.

    After association_timeout_s without input (in the path, and a ``~/save``); later input
    is waited for as before. Before, they waited until more input came: a live run's path
    ended 11 keyframes short.
    """
    seq, msgs = _street_messages(34)
    cut = {('tracks', i) for i in (27, 28, 29)}
    first = [m for j, m in enumerate(msgs[:61])
             if ('tracks', (j - 1) // 2) not in cut or m[0] != 'tracks']
    logic = BackendLogic(_live_config(association_timeout_s=0.3), RosbagsBackend())
    published: list[list[tuple[str, Any]]] = []
    worker = LogicWorker(logic, published.append, queue_size=len(msgs))
    worker.start()
    try:
        for kind, msg in first:
            worker.enqueue(kind, msg)
        _wait_for(lambda: any(len(m.poses) == 30 for outs in published for t, m in outs
                              if t == 'pmba/path'))
        assert logic.stats.counters['keyframes_without_tracks'] == 3
        for i in range(30, 34):   # each pose before its tracks: it waits for them
            worker.enqueue('keyframe', keyframe_msg(seq, i))
            worker.enqueue('tracks', tracks_msg(seq, i))
        _wait_for(lambda: logic.stats.keyframes == 34)
        assert logic.stats.counters['keyframes_without_tracks'] == 3
    finally:
        worker.stop()
