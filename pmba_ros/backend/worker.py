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
"""The node's solver thread: a bounded queue in front of a :class:`BackendLogic`.

Subscription callbacks only :meth:`LogicWorker.enqueue`; the worker thread feeds the logic
and hands its outputs to a publish callback, so solving never blocks the executor. While
more messages wait, a keyframe's solve is left to a later keyframe's (one solve, with their
iterations, for several: ``solves_deferred``), so that a thread behind its input catches up.
Messages that find the queue full are dropped and counted (``queue_full_<kind>`` in the
back-end's counters). A stop, a reset or the process's shutdown abandons the update in
progress at the solver's next iteration (:class:`~pmba_ros.errors.Cancelled`), and nothing
of it is published. No rclpy import: the node owns the thread's ROS side.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
import contextvars
from dataclasses import replace
import logging
import queue
import threading
import time
from typing import Any, TYPE_CHECKING

from pmba_ros.errors import Cancelled

if TYPE_CHECKING:
    from pmba_ros.backend.config import BackendConfig
    from pmba_ros.backend.logic import BackendLogic

logger = logging.getLogger(__name__)

Outputs = list[tuple[str, Any]]
"""``(topic, message)`` pairs of :meth:`BackendLogic.step`."""

_STOP = object()
_POLL_S = 0.1
_JOIN_TIMEOUT_S = 1.0


class LogicWorker:
    """Feeds a :class:`BackendLogic` from a bounded queue on its own thread.

    Args:
        logic: The back-end; use it from other threads only under :attr:`lock`.
        publish: Called on the worker thread with the outputs after each message.
        queue_size: Messages held; further ones are dropped and counted.
        closing: Whether the process is shutting down (the node's: its context is no
            longer ok); from then on, as after :meth:`stop`, nothing is handled or published.
    """

    def __init__(self, logic: BackendLogic, publish: Callable[[Outputs], None],
                 queue_size: int, closing: Callable[[], bool] = lambda: False) -> None:
        """Create the queue; the thread starts with :meth:`start`."""
        self.logic = logic
        self.lock = threading.Lock()
        self._publish = publish
        self._closing = closing
        self._cancel = threading.Event()
        self._resets = 0   # each queued message carries the count at its arrival
        self._discarded = 0   # messages the thread dropped while a reset waited
        logic.estimator.checkpoint = self._checkpoint
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=queue_size)
        # Behind its input, the logic leaves solves to later keyframes (one solve for
        # several) rather than the queue filling up and dropping keyframes.
        logic.input_waiting = lambda: not self._queue.empty()
        self._drops: Counter[str] = Counter()
        self._received: Counter[str] = Counter()
        self._counts_lock = threading.Lock()
        self._stop = threading.Event()
        self._staged: BackendConfig | None = None
        self._staged_pause: bool | None = None
        self._thread: threading.Thread | None = None
        self.last_input = -1.0
        """``time.monotonic()`` of the newest front-end input (-1: none yet; TF excluded)."""
        self._ended_input = -1.0   # the last_input the back-end was told ended its input

    def start(self) -> None:
        """Start the solver thread (a daemon: a solve in progress ends with the process).

        It runs in a copy of the caller's context (``contextvars``): the node's log route
        holds there.
        """
        self._thread = threading.Thread(target=contextvars.copy_context().run,
                                        args=(self._run,), name='pmba_solver', daemon=True)
        self._thread.start()

    def enqueue(self, kind: str, msg: Any) -> None:
        """Queue an input ('tracks', 'keyframe', 'camera_info[.c]', 'tf' or 'extrinsic').

        Never blocks. An unknown kind is a ValueError when the message is handled.
        """
        if kind != 'tf':  # TF keeps flowing when the front-end has stopped
            self.last_input = time.monotonic()
        try:
            self._queue.put_nowait((kind, msg, self._resets))
        except queue.Full:
            with self._counts_lock:
                self._drops[f'queue_full_{kind}'] += 1
        with self._counts_lock:
            self._received[kind] += 1

    def request_step(self) -> None:
        """Have the thread run a step without input (diagnostics of a pause or a reset).

        The back-end's status is published from steps, which inputs trigger: a pause or a
        reset while the front-end sent nothing kept showing the old state. A full queue
        needs no such step: its messages come first and each steps.
        """
        try:
            self._queue.put_nowait(('step', None, self._resets))
        except queue.Full:
            pass

    def reset(self, action: Callable[[], None]) -> int:
        """Run ``action`` (a reset) under :attr:`lock` and discard the queued messages.

        Messages queued before the reset belong to what it forgets: handled after it, a
        relaunched front-end's earlier stamps came after them and were refused as not
        increasing (one the thread had just taken off the queue is dropped too, uncounted).
        The update in progress is abandoned (the lock comes within a solver iteration, not
        after the solve), and holding the lock keeps its outputs, or any earlier ones, from
        being published after the reset (the thread publishes under it).

        Returns:
            The number of queued messages discarded.
        """
        self._cancel.set()
        with self.lock:
            discarded, self._discarded = self._discarded, 0
            self._resets += 1
            if not self._stop.is_set():
                self._cancel.clear()
            action()
            while True:
                try:
                    item = self._queue.get_nowait()
                except queue.Empty:
                    break
                if item is _STOP:   # keep a stop request
                    self._queue.put_nowait(item)
                    break
                discarded += item[0] != 'step'
        self.request_step()
        return discarded

    def stage_config(self, config: BackendConfig) -> None:
        """Apply ``config`` to the logic before the next message (``publish_tf`` forced on)."""
        with self._counts_lock:
            self._staged = config

    def stage_pause(self, paused: bool) -> None:
        """Pause or resume the logic before the next message, without waiting for a solve.

        The diagnostics say so at once (:meth:`request_step`); messages still queued are
        handled as the pause finds them (dropped and counted while paused).
        """
        with self._counts_lock:
            self._staged_pause = bool(paused)
        self.request_step()

    @property
    def paused(self) -> bool:
        """Return whether the logic is paused, or will be at its next message."""
        with self._counts_lock:
            staged = self._staged_pause
        return self.logic.paused if staged is None else staged

    def received(self) -> dict[str, int]:
        """Return the inputs received so far per kind."""
        with self._counts_lock:
            return dict(self._received)

    def queue_length(self) -> int:
        """Return the number of queued messages."""
        return self._queue.qsize()

    def process_pending(self) -> int:
        """Handle every queued message (the thread's body; tests call it directly).

        Returns:
            The number of messages handled.
        """
        handled = 0
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return handled
            if item is _STOP:
                self._stop.set()
                return handled
            self._handle(*item)
            handled += 1

    @property
    def cancelled(self) -> bool:
        """Return whether updates are abandoned: stopped, a reset under way or closing.

        Read under :attr:`lock`, True means the logic may hold an update abandoned half-way:
        its state is only good to be dropped (not saved).
        """
        return self._cancel.is_set() or self._closing()

    def _checkpoint(self) -> None:
        """Abandon the update in progress once stopped, reset or closing (estimator hook)."""
        if self.cancelled:
            msg = 'the back-end update in progress was abandoned'
            raise Cancelled(msg)

    def _handle(self, kind: str, msg: Any, resets: int) -> None:
        with self.lock:
            if self.cancelled:   # stopped, or a reset waits for the lock
                self._discarded += kind not in ('step', 'end_of_input')   # not inputs
                return
            if resets != self._resets:   # taken off the queue as a reset came
                return
            with self._counts_lock:
                drops = dict(self._drops)
                self._drops.clear()
                staged, self._staged = self._staged, None
                pause, self._staged_pause = self._staged_pause, None
            if pause is not None:
                self.logic.set_paused(pause)
            if staged is not None:
                # The logic always emits map -> odom: the node needs it for the provisional
                # poses and decides itself whether it goes to TF.
                self.logic.apply_config(replace(staged, publish_tf=True))
            for reason, n in drops.items():
                self.logic.count(reason, n)
            kind, _, camera = kind.partition('.')  # 'camera_info.c': camera c of a rig
            handlers: dict[str, Callable[[Any], None]] = {
                'tracks': self.logic.on_tracks, 'keyframe': self.logic.on_keyframe,
                'camera_info': self.logic.on_camera_info, 'tf': self.logic.on_tf,
                'extrinsic': self.logic.on_extrinsic,
                'end_of_input': lambda _msg: self.logic.end_of_input(),
                'step': lambda _msg: None}   # request_step(): a step without input
            if kind not in handlers or (camera and not (kind == 'camera_info'
                                                        and camera.isdigit())):
                msg_ = (f'unknown input kind {kind + "." * bool(camera) + camera!r} (expected '
                        f"one of {sorted(handlers)} or 'camera_info.<camera id>')")
                raise ValueError(msg_)
            try:
                if camera:
                    self.logic.on_camera_info(msg, int(camera))
                else:
                    handlers[kind](msg)
                outputs = self.logic.step()
            except Cancelled:
                return
            # Under the lock: a reset in between would otherwise see the forgotten run's
            # path and map -> odom published (and remembered by the node) after it; and
            # nothing once a stop or the shutdown began.
            if not self.cancelled:
                self._publish(outputs)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                item = self._queue.get(timeout=_POLL_S)
            except queue.Empty:
                self._end_idle_input()
                continue
            if item is _STOP:
                break
            try:
                self._handle(*item)
            except Exception:
                logger.exception('pmba worker: unexpected error')

    def _end_idle_input(self) -> None:
        """Tell the back-end its input ended once none came for ``association_timeout_s``.

        A front-end that stopped (the robot parked, a recording's end) left its last
        keyframes waiting for tracks that do not come: out of the path, and of a ``~/save``,
        until more input. Input after it is waited for as before.
        """
        last = self.last_input
        if last < 0 or last == self._ended_input or \
                time.monotonic() - last < self.logic.config.association_timeout_s:
            return
        self._ended_input = last
        self._handle('end_of_input', None, self._resets)

    def stop(self) -> None:
        """Stop the thread: the update in progress is abandoned, pending messages discarded.

        Waits for the thread up to ``_JOIN_TIMEOUT_S`` (a solver iteration, or an
        initialization stage, is not cut); from the call on, nothing more is published.
        """
        self._stop.set()
        self._cancel.set()
        try:
            self._queue.put_nowait(_STOP)
        except queue.Full:
            pass
        if self._thread is not None:
            self._thread.join(timeout=_JOIN_TIMEOUT_S)


__all__ = ['LogicWorker', 'Outputs']
