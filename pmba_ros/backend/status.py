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
"""What the back-end reports about itself: its statistics and its diagnostics status."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
import math

Factors = tuple[float, float, float]
"""Rotation, step-length and step-direction factors of the front-end's motion prior."""

DIAGNOSTICS_NAME = 'pmba_ros: back-end'
INFO_COUNTERS = frozenset({'tracks_without_keyframe', 'resets', 'init_attempts',
                           'init_failures', 'keyframes_passed_through',
                           'keyframe_poses_recovered', 'solves_deferred'})
"""Counters of normal events (VINS publishes tracks of every frame): no WARN, not drops."""


def waiting_for_parallax(count: int, need: int, keyframes: int, min_px: float,
                         focal_px: float) -> str:
    """Return the status of an initialization waiting for features with parallax."""
    # The angle too: it shows a gate out of reach (a focal length of 1 px, normalized
    # coordinates given as pixels).
    angle = math.degrees(min(min_px / focal_px, math.pi))
    return (f'waiting for parallax: {count} features with >= {min_px:g} px of parallax '
            f'({angle:.3g} deg at {focal_px:.4g} px focal length), need {need}, over '
            f'{keyframes} keyframes')


@dataclass
class UpdateInfo:
    """What one keyframe update did (for diagnostics and stats).

    Attributes:
        kind: 'collect', 'init', 'init_failed', 'refine', 'deferred' (added, its solve left
            to a later update), 'dead_reckoned' or 'dropped'.
        keyframe: Index of the keyframe (-1 if it was dropped).
        solve_ms: Solver wall time, ms (0 if no solve).
        iterations: Solver iterations.
        cost_before: Cost before the solve.
        cost_after: Cost after the solve.
        n_cams: Poses in the problem.
        n_free: Free poses in the problem.
        n_feats: Features in the problem.
        n_obs: Observations in the problem.
        message: Human-readable note (failure reason).
    """

    kind: str
    keyframe: int = -1
    solve_ms: float = 0.0
    iterations: int = 0
    cost_before: float = math.nan
    cost_after: float = math.nan
    n_cams: int = 0
    n_free: int = 0
    n_feats: int = 0
    n_obs: int = 0
    message: str = ''
    dropped: dict[str, int] = field(default_factory=dict)


@dataclass
class BackendStats:
    """Per-keyframe statistics and event counters.

    Attributes:
        solve_ms: Solver time of each optimized keyframe update, ms.
        update_ms: Whole update time (association, solve, bookkeeping) per keyframe, ms.
        iterations: Solver iterations per optimized update.
        cost_before: Cost before each solve.
        cost_after: Cost after each solve.
        counters: Event counts by reason (rejected inputs, drops, errors, ...).
        keyframes: Keyframes handed to the estimator.
        not_optimized: Keyframes in the outputs at their front-end pose (never optimized).
        map_scale: Scale of the map <- odom similarity after each keyframe since the
            initialization (a monocular map drifting in scale against odom shows here).
        noise: Since the initialization, the tracks' pixel noise, the factors on the
            front-end's rotation, step-length and step-direction sigmas (>= 1) and the
            measured scatter of its single steps (``FrontendNoise.white``; None until known).
    """

    solve_ms: list[float] = field(default_factory=list)
    update_ms: list[float] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)
    cost_before: list[float] = field(default_factory=list)
    cost_after: list[float] = field(default_factory=list)
    counters: Counter[str] = field(default_factory=Counter)
    keyframes: int = 0
    not_optimized: int = 0
    map_scale: list[float] = field(default_factory=list)
    noise: tuple[float, Factors, Factors | None] | None = None

    def count(self, reason: str, n: int = 1) -> None:
        """Count ``n`` events under ``reason`` (a reason is listed once it has happened)."""
        if n:
            self.counters[reason] += int(n)

    def record_update(self, info: UpdateInfo) -> None:
        """Count one keyframe update: its drops, its kind and, after a solve, its figures."""
        self.keyframes += 1
        if info.kind in ('dropped', 'dead_reckoned', 'passed_through'):
            self.count(f'keyframes_{info.kind}')
        if info.kind in ('init', 'init_failed'):
            self.count('init_attempts')
            self.count('init_failures', int(info.kind == 'init_failed'))
        self.count('solves_deferred', int(info.kind == 'deferred'))
        self.record_solve(info)

    def record_solve(self, info: UpdateInfo) -> None:
        """Count an update's drops and, after a solve, its figures (a deferred solve alone)."""
        for reason, n in info.dropped.items():
            self.count(reason, n)
        if info.kind in ('refine', 'init'):
            self.solve_ms.append(info.solve_ms)
            self.iterations.append(info.iterations)
            self.cost_before.append(info.cost_before)
            self.cost_after.append(info.cost_after)


def backend_level(update_kind: str, state: str, counters: Counter[str],
                  reported: Counter[str]) -> str:
    """Return the back-end's diagnostics level: 'error', 'warn' or 'ok'.

    Args:
        update_kind: Kind of the last keyframe update (``UpdateInfo.kind``).
        state: The back-end's state ('tracking', 'paused', ...).
        counters: The event counters now.
        reported: The event counters at the last diagnostics message.

    Returns:
        'error' after a failed update or new internal errors among new drops, 'warn' when
        not tracking or after new drops (counters outside :data:`INFO_COUNTERS` that grew),
        else 'ok'.
    """
    new_drops = any(counters[k] > reported[k] for k in counters if k not in INFO_COUNTERS)
    if update_kind == 'error' or (new_drops and counters['internal_errors']
                                  > reported['internal_errors']):
        return 'error'
    if state != 'tracking' or new_drops:
        return 'warn'
    return 'ok'


def backend_message(state: str, estimator_message: str, update_kind: str,
                    update_message: str) -> str:
    """Return the back-end's diagnostics message: its state, and a noteworthy update's note."""
    message = {'paused': 'paused', 'tracking': 'tracking'}.get(state, estimator_message)
    if update_message and update_kind not in ('refine', 'collect') and message != update_message:
        message = f'{message}; {update_message}'
    return message


def update_values(info: UpdateInfo) -> dict[str, str | float]:
    """Return the diagnostics key-values of a keyframe update (solve figures, problem size)."""
    return {'iterations': info.iterations,
            'cost_before': info.cost_before, 'cost_after': info.cost_after,
            'problem_poses': info.n_cams, 'problem_free_poses': info.n_free,
            'problem_features': info.n_feats, 'problem_observations': info.n_obs}


def counter_values(counters: Counter[str]) -> dict[str, str | float]:
    """Return the diagnostics key-values of the counters: ``dropped_total`` and ``count.*``."""
    values: dict[str, str | float] = {
        'dropped_total': int(sum(v for k, v in counters.items() if k not in INFO_COUNTERS))}
    for reason in sorted(counters):
        values[f'count.{reason}'] = int(counters[reason])
    return values


def node_level_and_message(input_age_s: float, any_input: bool, stale_input_s: float,
                           tf_off: str | None, map_to_odom_topic: str,
                           input_problems: Sequence[str] = ()) -> tuple[str, str]:
    """Return the node's own diagnostics level and message.

    Args:
        input_age_s: Seconds since the last front-end input (or since the start).
        any_input: Whether any front-end input has arrived.
        stale_input_s: Input age from which the input counts as stale.
        tf_off: Why map -> odom is not sent on TF although ``publish_tf`` asks for it, or None.
        map_to_odom_topic: The topic map -> odom goes to instead.
        input_problems: Why inputs receive nothing although their topics have publishers
            (:class:`~pmba_ros.backend.input_check.InputCheck`).

    Returns:
        ``(level, message)``: 'warn' for stale input, input problems or TF off, else 'ok'.
    """
    level, message = 'ok', 'receiving input'
    if input_problems:
        level, message = 'warn', '; '.join(input_problems)
    elif input_age_s > stale_input_s:
        level = 'warn'
        what = 'no input for' if any_input else 'no input received in'
        message = f'{what} {input_age_s:.1f} s (check the topics, remaps and QoS)'
    elif not any_input:
        message = 'waiting for input'
    if tf_off is not None:
        level = 'warn'
        message = f'{message}; TF {tf_off}, map -> odom on {map_to_odom_topic}'
    return level, message


def received_values(received: Mapping[str, int]) -> dict[str, str | float]:
    """Return the node's ``received.<kind>`` diagnostics values (a rig's ``camera_info.c`` too)."""
    kinds = ['tracks', 'keyframe', 'camera_info',
             *sorted(k for k in received if k.startswith('camera_info.'))]
    return {f'received.{kind}': received.get(kind, 0) for kind in kinds}


__all__ = ['DIAGNOSTICS_NAME', 'INFO_COUNTERS', 'BackendStats', 'backend_level', 'backend_message',
           'counter_values', 'node_level_and_message', 'received_values', 'update_values']
