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
"""Pairs that see a plane: two relative poses each, chosen by the triangles they close.

Points on one plane, seen from two views, fit two relative poses: the two decompositions of
their homography that put the points in front of both cameras (Faugeras and Lustman, 1988).
The 5-point RANSAC returns either, as the noise has it. Over flat ground seen from above,
more than half the EG pairs can be tens of degrees off, and where the spanning tree takes
one of them, a whole branch of the view graph turns with it. Along a straight flight line
the wrong poses of neighbouring pairs even agree with each other (they bend the line, and
consistently), so neither a pair nor the tree can tell. Triangles across the lines can:
the right relative rotations close every triangle, the wrong ones only some.

DEVIATION(Fig. 5): PMBA's EG pairs have one pose each; here a pair whose homography gives a
second pose that explains its inliers as well keeps the pose its triangles agree on.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import so3
from pmba_ros.core.engine import EngineName
from pmba_ros.init import parallax, two_view

#: An alternative pose must put this share of the pair's inliers in front of both cameras
#: within twice the RANSAC threshold: a plane's second pose does (it explains the same
#: points), that of a scene with depth leaves the points off the plane far off.
SUPPORT = 0.9


@dataclass(frozen=True, eq=False)
class Alternatives:
    """The second relative pose of the EG pairs that have one.

    Attributes:
        pair: EG pair of each alternative, shape (A,).
        R_rel: Its rotation R_cv, shape (A, 3, 3).
        t_rel: Its unit translation t_cv, shape (A, 3).
    """

    pair: IntArray
    R_rel: FloatArray
    t_rel: FloatArray


def alternatives(pairs: two_view.EGPairs, bearings_c: FloatArray, focal_px: FloatArray,
                 threshold_px: float, min_deg: float, *, max_sample: int | None = 200,
                 engine: EngineName | str = EngineName.AUTO) -> Alternatives:
    """Return the pairs' second poses: those of their homography that explain them as well.

    A pose of the homography qualifies if it differs from the pair's by more than
    ``min_deg`` in rotation and puts ``SUPPORT`` of the pair's inliers (a sample of at most
    ``max_sample``) in front of both cameras within twice the RANSAC threshold (the
    homography is fitted to noisy points, its poses are not refined).

    Args:
        pairs: The EG pairs.
        bearings_c: Unit bearings of all observations (camera frame), shape (K, 3).
        focal_px: Focal length of the observing camera of every observation, shape (K,).
        threshold_px: The RANSAC threshold (px).
        min_deg: Rotations closer than this to the pair's are the same pose.
        max_sample: Inliers of a pair used (evenly spread; None: all).
        engine: The engine of the tests (:func:`~pmba_ros.init.two_view.check_models`).
    """
    thresholds = threshold_px / parallax.pair_focal_px(pairs.offsets, pairs.obs_a, pairs.obs_b,
                                                       focal_px)
    R_h, t_h, count = two_view.homography_poses(pairs, bearings_c, max_sample)
    cand_pair, cand_k = np.nonzero(np.arange(4)[None, :] < count[:, None])
    if cand_pair.size == 0:
        return Alternatives(cand_pair, np.zeros((0, 3, 3)), np.zeros((0, 3)))
    # Each candidate is tested on its pair's sampled inliers, as a pair of its own.
    sizes = np.diff(pairs.offsets)
    sample = sizes if max_sample is None else np.minimum(sizes, max_sample)
    n, k = sizes[cand_pair], sample[cand_pair]
    seg = np.repeat(np.arange(cand_pair.shape[0]), k)
    j = np.arange(seg.shape[0]) - np.repeat(np.cumsum(k) - k, k)
    step = (n - 1) / np.maximum(k - 1, 1)   # >= 1: distinct rows, evenly spread
    rows = pairs.offsets[cand_pair][seg] + np.round(j * step[seg]).astype(np.int64)
    R_c, t_c = R_h[cand_pair, cand_k], t_h[cand_pair, cand_k]
    E = so3.hat(t_c) @ R_c
    b1, b2 = bearings_c[pairs.obs_a[rows]], bearings_c[pairs.obs_b[rows]]
    *_, R_best, t_best, _, support = two_view.check_models(E, 2.0 * thresholds[cand_pair], b1,
                                                           b2, seg, engine)
    apart = np.degrees(so3.angle(R_best, pairs.R_rel[cand_pair])) > min_deg
    ok = apart & (support >= SUPPORT * sample[cand_pair])
    # The best-supported qualifying candidate of each pair.
    order = np.lexsort((-support, cand_pair))
    order = order[ok[order]]
    _, first_of_pair = np.unique(cand_pair[order], return_index=True)
    keep = order[first_of_pair]
    return Alternatives(cand_pair[keep], R_best[keep], t_best[keep])


def triangles(cam_a: IntArray, cam_b: IntArray) -> IntArray:
    """Return the triangles of the pair graph as pair indices (T, 3): ab, bc, ac (a < b < c)."""
    lo, hi = np.minimum(cam_a, cam_b), np.maximum(cam_a, cam_b)
    n = int(hi.max()) + 1 if hi.size else 0
    by_lo = np.lexsort((hi, lo))
    keys = lo[by_lo] * n + hi[by_lo]
    starts = np.searchsorted(lo[by_lo], np.arange(n + 1))
    # Every pair ab joined with every pair bc (b < c), then ac looked up.
    n_next = starts[hi + 1] - starts[hi]
    ab = np.repeat(np.arange(lo.shape[0]), n_next)
    within = np.arange(ab.shape[0]) - np.repeat(np.cumsum(n_next) - n_next, n_next)
    bc = by_lo[starts[hi[ab]] + within]
    key_ac = lo[ab] * n + hi[bc]
    at = np.minimum(np.searchsorted(keys, key_ac), max(keys.shape[0] - 1, 0))
    found = keys[at] == key_ac if keys.size else np.zeros(0, dtype=bool)
    return np.stack([ab[found], bc[found], by_lo[at[found]]], axis=1).astype(np.int64)


def triangle_votes(cam_a: IntArray, cam_b: IntArray, R_two: FloatArray, two: BoolArray,
                   tol_deg: float) -> tuple[IntArray, IntArray]:
    """Return the triangles each of a pair's two rotations closes (P, 2), and its triangles (P,).

    A triangle of pairs ab, bc, ac closes with a choice of their rotations (R_ab = R_2^T R_1
    of each pair, oriented from its lower camera) when R_ac^T R_bc R_ab is within
    ``tol_deg`` of the identity; a rotation gets the triangle's vote (one, however many
    choices close with it) when a closing choice holds it. Only the triangles with a pair
    of two rotations (``two``, (P,)) are looked at; the second rotation of the other pairs
    is not read.
    """
    tri = triangles(cam_a, cam_b)
    tri = tri[np.any(two[tri], axis=1)]
    n_tri = np.bincount(tri.ravel(), minlength=cam_a.shape[0])
    member = np.zeros((tri.shape[0], 3, 2), dtype=bool)   # triangle, its pair, rotation
    # Each pair oriented from its lower camera to its higher one.
    R_up = np.where((cam_a <= cam_b)[:, None, None, None], R_two,
                    np.swapaxes(R_two, -1, -2))
    for h in np.ndindex(2, 2, 2):
        valid = np.all(two[tri] | (np.array(h) == 0), axis=1)
        t = tri[valid]
        ab, bc, ac = (R_up[t[:, i], h[i]] for i in range(3))
        loop = np.swapaxes(ac, -1, -2) @ bc @ ab
        closes = np.flatnonzero(valid)[np.degrees(so3.angle(loop, np.eye(3))) <= tol_deg]
        for i in range(3):
            member[closes, i, h[i]] = True
    votes = np.zeros((cam_a.shape[0], 2), dtype=np.int64)
    for i in range(3):
        np.add.at(votes, tri[:, i], member[:, i].astype(np.int64))
    return votes, n_tri


def resolved(pairs: two_view.EGPairs, alt: Alternatives, tol_deg: float,
             ) -> tuple[two_view.EGPairs, int]:
    """Return the pairs with the pose their triangles agree on, and how many changed.

    A pair takes its alternative when its own pose closes fewer than half of its triangles
    and the alternative closes more of them, two at least and half of them
    (:func:`triangle_votes`): one triangle can close by chance, and where the pairs'
    rotations are too noisy for most triangles to close, the vote says nothing. Otherwise (a
    pair in no triangle, or only along a line, or whose pose closes its triangles) it keeps
    the RANSAC's.
    """
    if alt.pair.size == 0:
        return pairs, 0
    R_two = np.repeat(pairs.R_rel[:, None], 2, axis=1)
    R_two[alt.pair, 1] = alt.R_rel
    two = np.zeros(pairs.n_pairs, dtype=bool)
    two[alt.pair] = True
    votes, n_tri = triangle_votes(pairs.cam_a, pairs.cam_b, R_two, two, tol_deg)
    won, own, n = votes[alt.pair, 1], votes[alt.pair, 0], n_tri[alt.pair]
    turn = (won > own) & (won >= 2) & (2 * won >= n) & (2 * own < n)
    if not np.any(turn):
        return pairs, 0
    R, t = pairs.R_rel.copy(), pairs.t_rel.copy()
    R[alt.pair[turn]], t[alt.pair[turn]] = alt.R_rel[turn], alt.t_rel[turn]
    return replace(pairs, R_rel=R, t_rel=t), int(turn.sum())


__all__ = ['SUPPORT', 'Alternatives', 'alternatives', 'resolved', 'triangle_votes',
           'triangles']
