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
from dataclasses import dataclass, field

DIAGNOSTICS_NAME = 'pmba_ros: back-end'
INFO_COUNTERS = frozenset({'tracks_without_keyframe', 'resets', 'init_attempts',
                           'init_failures', 'keyframes_passed_through'})
"""Counters of normal events (VINS publishes tracks of every frame): no WARN, not drops."""


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


__all__ = ['DIAGNOSTICS_NAME', 'INFO_COUNTERS', 'BackendStats']
