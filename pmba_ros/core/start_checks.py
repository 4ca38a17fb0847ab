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
"""Why a solve cannot start: a problem left without features, a start that is not finite."""

from __future__ import annotations

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core.problem import BAProblem
from pmba_ros.errors import ProblemError

__all__ = ['check_not_empty', 'non_finite_start_message']


def check_not_empty(problem: BAProblem) -> None:
    """Raise ProblemError if no feature is left to solve for (all were dropped)."""
    if problem.n_feats == 0 or problem.n_obs == 0:
        dropped = ', '.join(f'{k}: {v}' for k, v in problem.dropped.items()) or 'none'
        # Features seen twice but from one centre are dropped for want of a baseline: "not
        # seen by two cameras" misnamed a file whose cameras all share a centre.
        why = ('no feature is seen by two cameras with a baseline between them'
               if problem.dropped.get('features_without_anchor_baseline') else
               'no feature is seen by two or more cameras')
        msg = f'nothing to solve: {why} (dropped: {dropped})'
        raise ProblemError(msg)


_NAMED_CAMERAS = 5
"""Cameras named by the message of a non-finite start; the rest are counted."""


def non_finite_start_message(residuals: FloatArray, problem: BAProblem) -> str:
    """Return the message of a start whose cost is not finite, naming the cameras at fault.

    Those whose observations have residuals that are not finite, or so large that their
    squares sum past the largest float; and among them first those whose centre or focal
    length squares past it (a PMBA feature anchored at such a camera spoils the residuals
    of every camera that sees it, which alone would hide the culprit).

    Args:
        residuals: Residuals at the start, shape (K, d).
        problem: The problem solved (its observations in the order of ``residuals``).
    """
    with np.errstate(over='ignore', invalid='ignore'):
        squares = np.sum(residuals * residuals, axis=1)
        own = (np.sum(problem.centers_w ** 2, axis=1) + problem.intrinsics.fx ** 2
               + problem.intrinsics.fy ** 2)
    bad = ~np.isfinite(squares)
    if not bad.any() and squares.size:
        bad = squares > np.finfo(float).max / squares.size
    msg = 'residuals are not finite at the initial point'
    if not bad.any():   # the pose prior's cost, or a loss that overflows
        return msg
    cameras = np.unique(problem.obs.cam_idx[bad])
    absurd = np.flatnonzero(~np.isfinite(own))
    cameras = np.concatenate([absurd, np.setdiff1d(cameras, absurd)])
    more = (f' and {cameras.size - _NAMED_CAMERAS} more' if cameras.size > _NAMED_CAMERAS
            else '')
    named = (f'; of these, camera(s) {absurd[:_NAMED_CAMERAS].tolist()} have a centre or '
             'focal length beyond about 1e154' if absurd.size else '')
    return (f'{msg}: {int(np.count_nonzero(bad))} observations of camera(s) '
            f'{cameras[:_NAMED_CAMERAS].tolist()}{more}{named}; check their focal lengths '
            'and poses, and the points they see')
