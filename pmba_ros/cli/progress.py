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
"""Progress lines of ``pmba solve`` on stderr: the BA's iterations, the initialization's stages."""

from __future__ import annotations

from collections.abc import Callable, Mapping
import math
import sys
import time
from typing import Any

from pmba_ros.core.solve import IterationRecord


def iteration_printer(label: str) -> Callable[[IterationRecord], None]:
    """Return a callback printing one line per iteration, every iteration number included.

    An iteration whose linear system or model gave no usable step has no record: it is
    printed as such, so the numbers run without gaps.
    """
    last = -1

    def show(rec: IterationRecord) -> None:
        nonlocal last
        for skipped in range(last + 1, rec.iteration):
            print(f'  {label} it {skipped:3d}  no usable step (retried with more damping)',
                  file=sys.stderr)
        last = rec.iteration
        outcome = ('start' if rec.iteration == 0 else 'accepted' if rec.accepted
                   else 'converged: step below tolerance' if math.isnan(rec.rho) else 'rejected')
        print(f'  {label} it {rec.iteration:3d}  cost {rec.cost:.6e}'
              f'  rms {rec.rms_px:8.4f} px  radius {rec.trust_radius:9.3e}'
              f'  {rec.time_s:7.2f} s  {outcome}', file=sys.stderr)
    return show


def stage_printer(every_s: float = 5.0) -> Callable[[str, Mapping[str, Any]], None]:
    """Return a progress callback printing one line as each initialization stage ends.

    A stage still running after ``every_s`` seconds gets a line every ``every_s`` seconds.
    """
    t0 = time.perf_counter()
    last = [t0]

    def show(stage: str, entries: Mapping[str, Any]) -> None:
        now = time.perf_counter()
        if not entries.get('running'):
            print(f'  init {stage:10s} done  {now - t0:7.2f} s', file=sys.stderr)
        elif now - last[0] >= every_s:
            print(f'  init {stage:10s} {entries["pairs_taken"]} of '
                  f'{entries["pairs_to_estimate"]} pairs  {now - t0:7.2f} s', file=sys.stderr)
        else:
            return
        last[0] = now
    return show


__all__ = ['iteration_printer', 'stage_printer']
