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
"""A front-end's pose stream, sampled at the stamps of the tracks (``keyframe_source: tracks``).

Some front-ends publish odometry at their own rate (every camera frame, the IMU's) rather
than one pose per keyframe, or the poses come from another node than the tracks. With
``keyframe_source: tracks`` every tracks message is a keyframe, and its front-end pose is
the stream's pose at its stamp: the one stamped there, else interpolated between the poses
on either side (linear in position and covariance, along the geodesic in rotation) when they
are at most :data:`MAX_GAP_S` apart and no jump of the front-end's frame lies between them.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from pmba_ros.backend.types import KeyframePose
from pmba_ros.core import so3

MAX_GAP_S = 0.5
"""Poses further apart than this are not interpolated between: a keyframe there has no
front-end pose (a straight line across half a second of turning would be a wrong one)."""


class PoseStream:
    """Recent front-end poses, in stamp order, to sample at keyframe stamps.

    Args:
        capacity: Poses kept (the oldest go first).
    """

    def __init__(self, capacity: int) -> None:
        """Start empty."""
        self._poses: deque[tuple[KeyframePose, bool]] = deque(maxlen=max(2, capacity))
        self.count = 0
        """Poses added so far."""

    def add(self, pose: KeyframePose, jumped: bool = False) -> None:
        """Add a pose stamped after the previous one.

        ``jumped``: the front-end's frame jumped just before it (nothing is interpolated
        across).
        """
        self._poses.append((pose, jumped))
        self.count += 1

    def sample(self, stamp_ns: int, give_up: bool) -> tuple[KeyframePose | None, bool, bool]:
        """Return the pose at ``stamp_ns``, whether it is ready, and whether a jump precedes it.

        A pose at the stamp is taken as it is, else the poses on either side are interpolated
        (the nearest one may be a few milliseconds off, which at speed is centimetres). Not
        ready while the stream has no pose at or after the stamp yet, unless ``give_up`` (no
        later pose will come, or none is expected). Ready without a pose: no pose near enough
        on both sides, or a jump of the front-end's frame between them.
        """
        poses = self._poses
        if not poses or poses[-1][0].stamp_ns < stamp_ns:
            return None, give_up, False
        after = next(i for i, (p, _) in enumerate(poses) if p.stamp_ns >= stamp_ns)
        p1, jumped = poses[after]
        if p1.stamp_ns == stamp_ns:
            return p1, True, jumped
        if after == 0:
            return None, True, False
        p0 = poses[after - 1][0]
        if jumped or p1.stamp_ns - p0.stamp_ns > MAX_GAP_S * 1e9:
            return None, True, False
        return interpolate(p0, p1, stamp_ns), True, False

    def forget_before(self, stamp_ns: int) -> None:
        """Drop the poses that no later stamp needs (all but the last one before ``stamp_ns``)."""
        while len(self._poses) >= 2 and self._poses[1][0].stamp_ns <= stamp_ns:
            self._poses.popleft()


def interpolate(p0: KeyframePose, p1: KeyframePose, stamp_ns: int) -> KeyframePose:
    """Return the pose at ``stamp_ns`` between ``p0`` and ``p1`` (stamped around it)."""
    a = (stamp_ns - p0.stamp_ns) / (p1.stamp_ns - p0.stamp_ns)
    R0, R1 = so3.from_quat_xyzw(p0.quat_xyzw), so3.from_quat_xyzw(p1.quat_xyzw)
    R = R0 @ so3.exp(a * so3.log(R0.T @ R1))
    position = (1.0 - a) * np.asarray(p0.position) + a * np.asarray(p1.position)
    covariance = None
    if p0.covariance is not None and p1.covariance is not None:
        covariance = (1.0 - a) * p0.covariance + a * p1.covariance
    return KeyframePose(stamp_ns, p1.frame_id, p1.child_frame_id, position,
                        so3.to_quat_xyzw(R), covariance)
