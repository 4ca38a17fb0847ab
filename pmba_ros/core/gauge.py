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
"""Gauge fixing of the 7-DoF similarity freedom of monocular BA (pmba.md §2).

Two choices: :func:`choose_gauge` is ParallaxBA's rule: hold the root pose (6 columns) and the
coordinate of one more camera's centre with the largest |P_k - P_root| component (1 column,
the scale); poses the caller fixes count: one fixed pose replaces the root, two or more fix
the gauge on their own. :func:`free_gauge` holds nothing but the caller's fixed poses and
leaves the null space to the damping, as Ceres does; it converges in fewer iterations.
:func:`scale_tension` measures the cost along the scale direction of that freedom, which a
rig's baseline (and a front-end's metric steps) make observable.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray


@dataclass(frozen=True, eq=False)
class Gauge:
    """Which pose columns are solved for.

    Attributes:
        fixed_poses: Poses held entirely, shape (M,).
        scale_pose: Pose whose centre coordinate ``scale_axis`` is held, or -1.
        scale_axis: Held coordinate (0, 1, 2) of that centre, or -1.
    """

    fixed_poses: BoolArray
    scale_pose: int
    scale_axis: int

    def free_block(self) -> IntArray:
        """Return the block index of each pose in the solved vector, -1 for held poses (M,)."""
        free = ~self.fixed_poses
        out = np.full(free.shape[0], -1, dtype=np.int64)
        out[free] = np.arange(int(free.sum()))
        return out

    def column_mask(self) -> BoolArray:
        """Return the solved pose columns, shape (n_blocks, 6)."""
        mask = np.ones((int((~self.fixed_poses).sum()), 6), dtype=bool)
        if self.scale_pose >= 0:
            mask[self.free_block()[self.scale_pose], 3 + self.scale_axis] = False
        return mask


def free_gauge(n_cams: int, fixed: BoolArray, cam_idx: IntArray) -> Gauge:
    """Hold only the caller's fixed poses and poses without observations (Ceres' way).

    The 7-DoF null space is then left to the trust region's damping mu D^2 (mu >= 1e-8),
    which keeps the reduced system positive definite. Holding a start pose and one
    coordinate of a second, both carrying the start's errors, forces the whole reconstruction
    to move into that gauge: on a 100-camera ring XYZ-LM then needs 28 iterations instead
    of 6 to the same cost.
    """
    held = np.array(fixed, dtype=bool)
    held |= np.bincount(cam_idx, minlength=n_cams) == 0
    return Gauge(held, -1, -1)


def choose_gauge(centers_w: FloatArray, fixed: BoolArray, cam_idx: IntArray,
                 feat_idx: IntArray, n_feats: int, *, metric: bool = False) -> Gauge:
    """Choose the gauge: root pose plus one centre coordinate of its strongest partner.

    Args:
        centers_w: Camera centres, shape (M, 3).
        fixed: Poses the caller holds, shape (M,).
        cam_idx: Observing camera per observation, shape (K,).
        feat_idx: Feature per observation, shape (K,).
        n_feats: Number of features.
        metric: The scale is observed (a multi-camera rig): hold the root pose only.

    Returns:
        The gauge. Poses without observations are held too (they carry no information).
    """
    M = centers_w.shape[0]
    fixed = np.array(fixed, dtype=bool)
    fixed |= np.bincount(cam_idx, minlength=M) == 0
    n_fixed = int(fixed.sum())
    if n_fixed >= 2 or n_fixed == M:
        return Gauge(fixed, -1, -1)
    root = int(np.flatnonzero(fixed)[0]) if n_fixed == 1 else int(
        np.argmax(np.bincount(cam_idx, minlength=M)))
    fixed[root] = True
    if metric:
        return Gauge(fixed, -1, -1)
    # Strongest partner: the camera sharing most features with the root.
    seen_by_root = np.zeros(n_feats, dtype=bool)
    seen_by_root[feat_idx[cam_idx == root]] = True
    shared = np.bincount(cam_idx[seen_by_root[feat_idx]], minlength=M).astype(float)
    shared[fixed] = -1.0
    baseline = np.abs(centers_w - centers_w[root])
    shared[baseline.max(axis=1) <= 0.0] = -1.0
    partner = int(np.argmax(shared))
    if shared[partner] < 0:
        partner = int(np.flatnonzero(~fixed)[0]) if np.any(~fixed) else -1
    if partner < 0:
        return Gauge(fixed, -1, -1)
    axis = int(np.argmax(baseline[partner]))
    return Gauge(fixed, partner, axis)


def camera_components(n_cams: int, cam_idx: IntArray, feat_idx: IntArray,
                      n_feats: int) -> tuple[int, IntArray]:
    """Return the number of groups of cameras joined by shared features, and each camera's.

    Each group has a similarity gauge of its own: a problem of several is solved, but the
    groups' relative position, rotation and scale are whatever the start said.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = n_cams + n_feats
    graph = coo_matrix((np.ones(cam_idx.shape[0]), (cam_idx, n_cams + feat_idx)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    cams = labels[:n_cams]
    _, groups = np.unique(cams, return_inverse=True)
    return int(groups.max()) + 1 if n_cams else 0, groups.astype(np.int64)


SCALE_STEP = 1e-3
"""Relative step of :func:`scale_tension`'s central differences."""


def scale_tension(cost: Callable[[float], float], cost_at_one: float) -> tuple[float, float]:
    """Return the slope and curvature of ``cost(1 + s)`` at s = 0 (central differences).

    ``cost(c)``: the cost with every camera centre times c, rotations and features as they
    are. PMBA's features (a parallax angle and a ray on their anchors) scale with the
    centres, so this is the whole map scaled about the origin: a monocular map's
    reprojections do not change, a rig's other cameras (their baselines are metric) and the
    front-end's step lengths do. Fixed poses scale too: where a sliding window holds the
    older map fixed, the slope is the pull of the window's metric measurements against the
    scale the fixed keyframes impose on it.
    """
    h = SCALE_STEP
    up, down = cost(1.0 + h), cost(1.0 - h)
    return (up - down) / (2.0 * h), (up - 2.0 * cost_at_one + down) / (h * h)
