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
"""Plausibility checks of the front-end's inputs and of the solves, across messages.

Monitors with a little memory:

* :class:`PoseJumpCheck` (in :class:`~pmba_ros.backend.logic.BackendLogic`) rejects a
  keyframe pose that jumps far beyond the recent motion (a front-end glitch of 1e6 m for a
  few keyframes must not be followed). A jump that persists for
  :attr:`PoseJumpCheck.max_rejections` keyframes is taken as the front-end's new truth (a
  relocalization) and accepted.
* :class:`StampLeapCheck` (in :class:`~pmba_ros.backend.logic.BackendLogic`, one per input
  stream) holds a message stamped far past the recent rate until the next one shows whether
  time jumped or the stamp was bad, and can drop a message stamped like a recent one (a
  repeat: the same keyframe pose published or recorded twice).
* :class:`CostMonitor` (in the estimator) flags a solve whose cost per observation rises far
  above the lowest of its recent history (garbage tracks: random, thinned or merged ids); the
  estimator keeps the poses from before such a solve.

They only judge; the caller counts and reports (diagnostics level WARN, replay warnings).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
import itertools
import logging
import math
import statistics
from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray

logger = logging.getLogger(__name__)

DUPLICATE_POSES = 'duplicate_keyframe_poses'
"""Counter of keyframe poses dropped as repeats (:attr:`StampLeapCheck.repeat_reason`)."""


@dataclass
class PoseJumpCheck:
    """Reject keyframe positions that jump far beyond the recent speed.

    Attributes:
        factor: A step is a jump when its speed exceeds ``factor`` times the reference speed.
        min_speed: Floor of the reference speed (odom units per second), so a front-end that
            starts from rest is not judged against a speed near zero.
        min_steps: Steps needed before judging: the first ``min_steps + 1`` poses are held
            and judged against each other (a first pose far off has no history to be judged
            by, and would otherwise become the reference itself).
        max_rejections: Consecutive rejections after which the new position is accepted.
        history: Recent step speeds kept for the reference (their median).
        persist_factor: After rejections, an accepted step faster than this many times the
            reference speed is the front-end's frame having jumped (see :meth:`release`).
    """

    factor: float = 20.0
    min_speed: float = 0.5
    min_steps: int = 3
    max_rejections: int = 5
    history: int = 10
    persist_factor: float = 3.0
    _last: tuple[int, FloatArray] | None = field(default=None, init=False, repr=False)
    _speeds: deque[float] = field(default_factory=deque, init=False, repr=False)
    _rejected: int = field(default=0, init=False, repr=False)
    _held: list[Any] = field(default_factory=list, init=False, repr=False)
    _released: list[tuple[Any, bool, bool]] = field(default_factory=list, init=False,
                                                    repr=False)
    _first: list[tuple[int, FloatArray, Any]] = field(default_factory=list, init=False,
                                                      repr=False)

    def check(self, stamp_ns: int, position: FloatArray, payload: Any = None) -> str | None:
        """Return why the keyframe position is a jump, or None if it is accepted.

        Args:
            stamp_ns: Keyframe stamp, ns (increasing; others are accepted unjudged).
            position: Front-end position, shape (3,).
            payload: The keyframe it belongs to: held while rejected, handed back by
                :meth:`release` if the jump turns out to persist.
        """
        position = np.asarray(position, dtype=np.float64)
        self._released = [(payload, False, False)]
        if self._last is None:
            return self._judge_first(stamp_ns, position, payload)
        last_ns, last_pos = self._last
        dt = (stamp_ns - last_ns) * 1e-9
        if dt <= 0:
            return None
        step = float(np.linalg.norm(position - last_pos))
        speed = step / dt
        reference = math.inf
        if len(self._speeds) >= self.min_steps:
            # np.median's value (finite speeds) at a fraction of its cost per keyframe.
            reference = max(float(statistics.median(self._speeds)), self.min_speed)
            if speed > self.factor * reference and self._rejected < self.max_rejections:
                self._rejected += 1
                self._held.append(payload)
                self._released = []
                return (f'keyframe pose at {stamp_ns} ns jumps {step:.3g} in {dt:.3g} s '
                        f'({speed:.3g}/s, {speed / reference:.0f}x the recent '
                        f'{reference:.3g}/s); rejected as an outlier')
        if self._rejected:
            # A jump that persists is the front-end's new reference, not an outlier; a
            # position back near the old track ends a glitch instead.
            jumped = speed > self.persist_factor * reference
            held = self._held if jumped else []   # in the new frame too, or outliers
            # The step out of a glitch or into a new frame is no speed; the recent speeds
            # still are, and judge the next poses (a second glitch right after the first).
            self._accept(stamp_ns, position, None)
            self._released = [(p, k == 0 and jumped, p is not payload)
                              for k, p in enumerate([*held, payload])]
            return None
        self._accept(stamp_ns, position, speed)
        return None

    def release(self) -> list[tuple[Any, bool, bool]]:
        """Return what the last check accepted, in order: ``(payload, jumped, recovered)``.

        The payload just checked, preceded, where a jump turned out to persist, by the ones
        rejected while it was judged (``recovered``): they are in the front-end's new frame as
        well (a relocalization or a reset), and the first of them, flagged ``jumped``, starts
        it (the step into it is no motion). Empty after a rejection and while the first poses
        are held; then the ones they kept.
        """
        return self._released

    def idle(self) -> bool:
        """Return True when no pose is held (past the first poses, no jump being judged)."""
        return self._last is not None and not self.holding()

    def holding(self) -> bool:
        """Return True while poses are held (the first ones, or a jump being judged)."""
        return bool(self._first or self._held)

    def holds_from(self, stamp_ns: int) -> bool:
        """Return True while a first pose stamped at or after ``stamp_ns`` is held."""
        return bool(self._first) and self._first[-1][0] >= stamp_ns

    def flush(self) -> list[tuple[Any, bool, bool]]:
        """Return the first poses still held, unjudged, as :meth:`release` would: input ended."""
        first, self._first = self._first, []
        return [(p, False, False) for _, _, p in first]

    def _judge_first(self, stamp_ns: int, position: FloatArray, payload: Any) -> str | None:
        """Hold the first poses, then keep those that agree with at least one other."""
        self._released = []
        if self._first and stamp_ns <= self._first[-1][0]:
            return (f'keyframe pose at {stamp_ns} ns is not after the one at '
                    f'{self._first[-1][0]} ns; rejected')
        self._first.append((stamp_ns, position, payload))
        if len(self._first) <= self.min_steps:
            return None
        stamps = np.array([s for s, _, _ in self._first], dtype=np.float64) * 1e-9
        P = np.array([p for _, p, _ in self._first])
        with np.errstate(over='ignore', invalid='ignore'):
            gaps = np.linalg.norm(P[:, None] - P[None], axis=2)
            speeds = gaps / np.maximum(np.abs(stamps[:, None] - stamps[None]), 1e-9)
        pairs = np.sort(speeds[np.triu_indices(len(P), 1)])
        # The lower median: a far-off pose spoils the pairs it is in, under half of them.
        reference = max(float(pairs[(pairs.shape[0] - 1) // 2]), self.min_speed)
        agree = speeds <= self.factor * reference
        np.fill_diagonal(agree, False)
        kept = np.flatnonzero(agree.any(axis=1))
        first, self._first = self._first, []
        for i in kept:
            self._accept(first[i][0], first[i][1], None)
        self._speeds.extend(float(speeds[a, b]) for a, b in itertools.pairwise(kept))
        self._released = [(first[i][2], False, False) for i in kept]
        if kept.shape[0] == len(first):
            return None
        off = [first[i][0] for i in np.setdiff1d(np.arange(len(first)), kept)]
        return (f'keyframe pose(s) at {off} ns far off the other first poses (recent speed '
                f'{reference:.3g}/s); rejected as outliers')

    def _accept(self, stamp_ns: int, position: FloatArray, speed: float | None) -> None:
        self._last = (stamp_ns, position)
        self._rejected = 0
        self._held = []
        if speed is not None:
            self._speeds.append(speed)
            while len(self._speeds) > self.history:
                self._speeds.popleft()


@dataclass
class StampLeapCheck:
    """Hold a message whose stamp leaps far past the recent rate until the next one judges it.

    A single message stamped far in the future (a clock glitch) would otherwise make every
    later one look out of order and be dropped for the rest of the run. The next message
    decides: stamped after the held one, time really jumped (a front-end that paused) and
    both pass, the held one late by a message; stamped before it, the held one is dropped.
    The first ``min_steps + 1`` messages, with no rate yet to judge by, are held and judged
    together: one that leaps past the others although it came before some of them is
    dropped, and the rest pass in stamp order.

    With ``repeat_reason``, a message stamped like one of the last ``repeats_kept`` admitted
    is dropped under that reason before any of this, and the first copy kept: a keyframe
    pose published twice was partly counted as a pose jump (a repeat among the first poses
    is "not after" its original) and partly as a stamp not increasing, and a repeat of a
    pose held as a jump counted towards the jump's persistence.

    Attributes:
        reason: What a dropped message is counted as (``reject``'s first argument).
        factor: A stamp step beyond ``factor`` times the median of the recent ones leaps.
        min_steps: Steps needed before judging.
        history: Recent stamp steps kept for the median.
        repeat_reason: What a repeated stamp is counted as; '' lets repeats pass unjudged.
        repeats_kept: Recent stamps a repeat is looked for among (a message recorded twice
            comes right after itself; merged bags a few messages later).
    """

    reason: str
    factor: float = 20.0
    min_steps: int = 3
    history: int = 10
    repeat_reason: str = ''
    repeats_kept: int = 32
    _recent: deque[int] = field(default_factory=deque, init=False, repr=False)
    _last_ns: int | None = field(default=None, init=False, repr=False)
    _steps: deque[int] = field(default_factory=deque, init=False, repr=False)
    _held: tuple[int, Any] | None = field(default=None, init=False, repr=False)
    _first: list[tuple[int, Any]] = field(default_factory=list, init=False, repr=False)

    def admit(self, stamp_ns: int, payload: Any,
              reject: Callable[[str, str], None]) -> list[Any]:
        """Return the payloads to take now, in order; a held one dropped goes to ``reject``.

        Empty while ``payload`` is held, and for a repeat (``repeat_reason``). Other stamps
        that do not increase pass unjudged (the caller rejects them as before).
        """
        if self.repeat_reason:
            if stamp_ns in self._recent:
                # Stamp 0 again and again is a front-end that leaves its headers unstamped.
                why = ('header stamp 0 again (left unset by the front-end? poses and tracks '
                       'are matched by stamp)' if stamp_ns == 0 else 'a repeat')
                reject(self.repeat_reason, f'message stamped {stamp_ns} ns like one received '
                       f'before: {why}, dropped (the first copy is kept)')
                return []
            self._recent.append(stamp_ns)
            if len(self._recent) > self.repeats_kept:
                self._recent.popleft()
        if self._last_ns is None:
            return self._judge_first(stamp_ns, payload, reject)
        taken: list[Any] = []
        if self._held is not None:
            held_ns, held = self._held
            self._held = None
            if stamp_ns > held_ns:   # time did jump: the held one starts the new stretch
                taken.append(held)
                self._last_ns = held_ns
            else:
                leap_s = (held_ns - (self._last_ns or 0)) * 1e-9
                reject(self.reason, f'message stamped {held_ns} ns, {leap_s:.3g} s after its '
                       f'predecessor, followed by one at {stamp_ns} ns: dropped as a bad stamp')
        last = self._last_ns
        if last is not None and stamp_ns > last:
            step = stamp_ns - last
            if (len(self._steps) >= self.min_steps
                    and step > self.factor * statistics.median(self._steps)):
                self._held = (stamp_ns, payload)
                return taken
            self._steps.append(step)
            while len(self._steps) > self.history:
                self._steps.popleft()
        if last is None or stamp_ns > last:
            self._last_ns = stamp_ns
        return [*taken, payload]

    @property
    def newest_ns(self) -> int:
        """Return the newest stamp taken (held ones are not yet), -1 before any."""
        return -1 if self._last_ns is None else self._last_ns

    def holding(self) -> bool:
        """Return True while messages are held (the first ones, or one stamped far ahead)."""
        return self._held is not None or bool(self._first)

    def holds_from(self, stamp_ns: int) -> bool:
        """Return True while a message stamped at or after ``stamp_ns`` is held."""
        return (self._held is not None and self._held[0] >= stamp_ns) or any(
            ns >= stamp_ns for ns, _ in self._first)

    def fits(self, stamp_ns: int) -> bool:
        """Return True if ``stamp_ns`` would pass now, neither held nor out of order."""
        last = self._last_ns
        if last is None or self._held is not None or stamp_ns <= last:
            return False
        return (len(self._steps) < self.min_steps
                or stamp_ns - last <= self.factor * statistics.median(self._steps))

    def flush(self) -> list[Any]:
        """Return the held payloads (if any) without judging them: the input has ended."""
        held, self._held = self._held, None
        first, self._first = sorted(self._first, key=lambda m: m[0]), []
        return [p for _, p in first] + ([] if held is None else [held[1]])

    def _judge_first(self, stamp_ns: int, payload: Any,
                     reject: Callable[[str, str], None]) -> list[Any]:
        """Hold the first messages; then drop those that leap ahead of ones they came before."""
        self._first.append((stamp_ns, payload))
        if len(self._first) <= self.min_steps:
            return []
        order = sorted(range(len(self._first)), key=lambda k: self._first[k][0])
        stamps = np.array([self._first[k][0] for k in order], dtype=np.int64)
        steps = np.diff(stamps)
        moving = steps[steps > 0]
        leap = int(np.argmax(steps)) + 1
        # Sorted by stamp, a glitch stamped ahead sits after the leap yet arrived earlier.
        if (moving.shape[0] and steps[leap - 1] > self.factor * float(np.median(moving))
                and min(order[leap:]) < max(order[:leap])):
            for k in order[leap:]:
                reject(self.reason, f'message stamped {self._first[k][0]} ns, ahead of ones '
                       f'that came after it (up to {stamps[leap - 1]} ns): dropped as a bad stamp')
            order, stamps = order[:leap], stamps[:leap]
        first, self._first = self._first, []
        self._last_ns = int(stamps[-1])
        self._steps.extend(int(v) for v in np.diff(stamps) if v > 0)
        return [first[k][1] for k in order]


@dataclass
class CostMonitor:
    """Flag solves whose cost per observation explodes relative to their history.

    Flagged solves are not remembered, so a stretch of inconsistent tracks is judged against
    the solves before it, however long it lasts; only ``history`` flagged solves in a row are
    taken as the new normal (tracks that got noisier for good, not garbage).

    Attributes:
        factor: A solve is flagged when its cost per observation exceeds ``factor`` times
            the lowest of the last ``history`` solves.
        history: Solves remembered.
    """

    factor: float = 10.0
    history: int = 50
    _costs: deque[float] = field(default_factory=deque, init=False, repr=False)
    _flagged: list[float] = field(default_factory=list, init=False, repr=False)

    def check(self, cost: float, n_obs: int) -> str | None:
        """Record a solve; return a description if its cost exploded, else None."""
        if n_obs <= 0:
            return None
        per_obs = cost / n_obs
        if not math.isfinite(per_obs):
            return f'solve cost {cost:g} over {n_obs} observations is not finite'
        best = min(self._costs) if self._costs else None
        if best is not None and best > 0 and per_obs > self.factor * best:
            self._flagged.append(per_obs)
            if len(self._flagged) < self.history:
                return (f'cost per observation {per_obs:.4g} is {per_obs / best:.0f}x the '
                        f'lowest of the recent solves ({best:.4g}): inconsistent tracks?')
            self._costs.clear()
            per_obs = min(self._flagged)
            logger.warning('solve costs stayed above %gx their history for %d solves: taken '
                           'as the new normal', self.factor, self.history)
        self._flagged.clear()
        self._costs.append(per_obs)
        while len(self._costs) > self.history:
            self._costs.popleft()
        return None


def held_from(stamp_ns: int, *checks: StampLeapCheck | PoseJumpCheck) -> bool:
    """Return True while one of ``checks`` holds a message stamped at or after ``stamp_ns``.

    Such a message has come: what waits for it (a keyframe's pose sampled from a pose
    stream) waits past the association timeout. At 2 Hz the two checks of a pose stream's
    first poses hold them for 3 s.
    """
    return any(check.holds_from(stamp_ns) for check in checks)
