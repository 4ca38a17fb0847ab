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
"""Keyframes the solver cannot see (too few tracks) placed between the ones it solved.

Through a stretch without tracks (a dark tunnel, a white wall, a lens covered) the keyframes
keep the front-end's motion. Chained on from the last solved keyframe alone, as they come,
the stretch ends where the front-end's drift took it, and the first solved keyframe after it
starts where the vision puts it: a step of the whole stretch's drift between two keyframes.
Each such keyframe is placed by the front-end's motion from both solved neighbours, blended
along the path (:func:`place_unsolved`), so that the correction the solves find on either
side is spread over the stretch rather than left at its end.

Where the front-end's frame also jumped in such a stretch (a VIO restarted in the dark), the
keyframes after it have no front-end motion to the map, and a few tracks seen again may be
all that ties them to it: :func:`untied_chains` finds them, to be held where the front-end's
motion put them until they are tied.
"""

from __future__ import annotations

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.backend.motion import row_norms
from pmba_ros.backend.window import KeyframeStatus, KeyframeStore
from pmba_ros.core import so3
from pmba_ros.core.pose_prior import RelativePosePrior
from pmba_ros.core.problem import BAProblem

STILL_REL = 1e-3
"""A path shorter than this share of the stretch's median step per keyframe is no motion: a
front-end at rest moves by its noise, whose share of the path says nothing of time."""


def place_unsolved(kf: KeyframeStore, solved: BoolArray, scale: float, moved_from: int) -> None:
    """Place the dead-reckoned keyframes whose solved neighbours may have moved.

    Each keyframe's pose is the front-end's motion from the solved keyframe before it and
    from the one after it, each seen through its own map <- odom (the neighbour's rotation
    and position, the front-end's translation times ``scale``), blended by the share of the
    front-end's path between them travelled (by time where the front-end stood still).
    A neighbour in another odom segment or without a front-end pose does not count; with
    one side only, the front-end's motion from that side.

    Args:
        kf: The keyframes; ``R_map`` / ``C_map`` of the dead-reckoned ones are set.
        solved: Which of the ``kf.n`` keyframes carry a solved pose (the neighbours).
        scale: Map units per odom unit.
        moved_from: The oldest keyframe a solve moved: the keyframes from the solved one
            before it on are placed, older ones stay.
    """
    n = kf.n
    anchors = np.flatnonzero(solved[:n] & kf.has_odom[:n])
    older = anchors[anchors < moved_from]
    first = int(older[-1]) + 1 if older.size else 0
    todo = np.flatnonzero(kf.status[first:n] == KeyframeStatus.DEAD_RECKONED) + first
    todo = todo[kf.has_odom[todo]]
    if todo.shape[0] == 0 or anchors.shape[0] == 0:
        return
    pos = np.searchsorted(anchors, todo)
    a = anchors[np.maximum(pos - 1, 0)]
    b = anchors[np.minimum(pos, anchors.shape[0] - 1)]
    has_a = (pos > 0) & (kf.segment[a] == kf.segment[todo])
    has_b = (pos < anchors.shape[0]) & (kf.segment[b] == kf.segment[todo])
    use = has_a | has_b
    todo, a, b, has_a, has_b = todo[use], a[use], b[use], has_a[use], has_b[use]
    if todo.shape[0] == 0:
        return
    a = np.where(has_a, a, b)
    b = np.where(has_b, b, a)
    w = _path_share(kf, a, todo, b)
    D_a = np.einsum('mij,mkj->mik', kf.R_map[a], kf.R_odom[a])   # map <- odom rotation at a
    D_b = np.einsum('mij,mkj->mik', kf.R_map[b], kf.R_odom[b])
    D = np.einsum('mij,mjk->mik', D_a, so3.exp(
        w[:, None] * so3.log(np.einsum('mji,mjk->mik', D_a, D_b))))
    from_a = kf.C_map[a] + scale * np.einsum('mij,mj->mi', D_a, kf.C_odom[todo] - kf.C_odom[a])
    from_b = kf.C_map[b] + scale * np.einsum('mij,mj->mi', D_b, kf.C_odom[todo] - kf.C_odom[b])
    kf.R_map[todo] = so3.project(np.einsum('mij,mjk->mik', D, kf.R_odom[todo]))
    kf.C_map[todo] = (1.0 - w)[:, None] * from_a + w[:, None] * from_b


def _path_share(kf: KeyframeStore, a: IntArray, k: IntArray, b: IntArray) -> FloatArray:
    """Return the share of the front-end's path from a to b travelled at k (0 where a == b)."""
    lo, hi = int(min(a.min(), k.min())), int(max(b.max(), k.max()))   # one side: k beyond
    span = np.arange(lo, hi + 1)
    with_pose = span[kf.has_odom[span]]   # a, k and b have front-end poses; others no path
    steps = row_norms(np.diff(kf.C_odom[with_pose], axis=0))
    path = np.zeros(hi - lo + 1)
    path[with_pose - lo] = np.concatenate([[0.0], np.cumsum(steps)])
    done, total = path[k - lo] - path[a - lo], path[b - lo] - path[a - lo]
    t_done = (kf.stamps_ns[k] - kf.stamps_ns[a]).astype(np.float64)
    t_total = (kf.stamps_ns[b] - kf.stamps_ns[a]).astype(np.float64)
    typical = np.median(steps) if steps.shape[0] else 0.0
    moved = total > STILL_REL * max(typical, 1e-12) * (b - a)
    share = np.where(moved, done / np.where(moved, total, 1.0),
                     t_done / np.where(t_total > 0, t_total, 1.0))
    return np.clip(np.where(b > a, share, 0.0), 0.0, 1.0)


def untied_chains(problem: BAProblem, prior: RelativePosePrior | None, known: BoolArray,
                  min_observations: int) -> BoolArray:
    """Return the oldest pose of each chain of free poses that nothing ties to the map.

    A chain is a run of poses the prior's factors join one to the next (a pose without
    factors is a chain of its own). One with a held pose, or whose poses observe
    ``min_observations`` ``known`` features (with a point before the solve) that poses
    outside it observe too, is tied to the map. Any other is not: a few shared tracks
    (seen again and again by its poses, most of them far), or tracks seen again after a
    while whose points restart from rotations, would place it alone, so its oldest pose is
    to be held.
    """
    m = problem.n_cams
    held = np.zeros(m, dtype=bool)
    if m == 0:
        return held
    linked = np.zeros(m, dtype=bool)   # pose i joined to pose i + 1
    if prior is not None:
        linked[prior.a[prior.b == prior.a + 1]] = True
    chain = np.concatenate([[0], np.cumsum(~linked[:-1])])
    if chain[-1] == 0 and problem.fixed.any():
        return held   # one chain, with a held pose (a sliding window's usual case)
    of_obs = chain[problem.obs.cam_idx]
    starts = problem.feature_offsets()[:-1]   # observations come sorted by feature
    spans = np.minimum.reduceat(of_obs, starts) != np.maximum.reduceat(of_obs, starts)
    feat = problem.obs.feat_idx
    n_chains = int(chain[-1]) + 1
    tying = spans[feat] & known[feat]   # each tying feature counts once per chain
    pairs = np.unique(of_obs[tying] * problem.n_feats + feat[tying])
    ties = np.bincount(pairs // problem.n_feats, minlength=n_chains)
    anchored = np.bincount(chain[problem.fixed], minlength=n_chains) > 0
    loose = ~anchored & (ties < min_observations)
    first = np.flatnonzero(np.concatenate([[True], chain[1:] != chain[:-1]]))
    held[first[loose]] = True
    return held
