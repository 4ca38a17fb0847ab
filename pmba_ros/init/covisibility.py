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
"""Co-visible camera pairs and their correspondences, the input of the EG pairs.

Built for all pairs at once with vectorized joins on the feature index (observations sorted
by feature then camera): no loop over pairs or observations, only over the offset inside a
track; where numba runs, one compiled pass over the correspondences instead
(:mod:`pmba_ros.core.compiled.track_pairs`, the same arrays).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.compiled import track_pairs
from pmba_ros.core.engine import EngineName, resolve


@dataclass(frozen=True, eq=False)
class PairCorrespondences:
    """Co-visible camera pairs and their common observations (CSR layout).

    Attributes:
        cam_a: First camera of each pair, shape (P,); cam_a < cam_b.
        cam_b: Second camera of each pair, shape (P,).
        offsets: CSR offsets (P+1,) into ``obs_a``/``obs_b``.
        obs_a: Observation index (into the problem's observations) in cam_a, shape (C,).
        obs_b: Observation index of the same feature in cam_b, shape (C,).
    """

    cam_a: IntArray
    cam_b: IntArray
    offsets: IntArray
    obs_a: IntArray
    obs_b: IntArray

    @property
    def n_pairs(self) -> int:
        """Return the number of pairs P."""
        return int(self.cam_a.shape[0])

    def counts(self) -> IntArray:
        """Return the number of common observations of each pair, shape (P,)."""
        return np.diff(self.offsets)


def _track_layout(cam_idx: IntArray, feat_idx: IntArray) -> tuple[IntArray, int]:
    """Return observation order sorted by (feature, camera) and the max track length."""
    order = np.lexsort((cam_idx, feat_idx)).astype(np.int64)
    max_len = int(np.bincount(feat_idx).max()) if feat_idx.size else 0
    return order, max_len


def _compiled(engine: EngineName | str) -> bool:
    return resolve(engine).name is EngineName.COMPILED


def covisibility_counts(cam_idx: IntArray, feat_idx: IntArray, n_cams: int,
                        engine: EngineName | str = EngineName.AUTO) -> IntArray:
    """Return the number of features seen by both cameras, as a dense (M, M) upper triangle.

    Args:
        cam_idx: Camera of each observation, shape (K,).
        feat_idx: Feature of each observation, shape (K,).
        n_cams: Number of cameras M.
        engine: The compiled pass (``'auto'``: where numba runs) or the numpy code.

    Returns:
        counts[a, b] for a < b (zero elsewhere), shape (M, M).
    """
    order, max_len = _track_layout(cam_idx, feat_idx)
    f, c = feat_idx[order], cam_idx[order]
    if _compiled(engine):
        return track_pairs.count_pairs(f, c, n_cams).reshape(n_cams, n_cams)
    counts = np.zeros(n_cams * n_cams, dtype=np.int64)
    for d in range(1, max_len):  # loop over the offset inside a track, not observations
        same = f[d:] == f[:-d]
        key = c[:-d][same] * n_cams + c[d:][same]
        counts += np.bincount(key, minlength=n_cams * n_cams)
    return counts.reshape(n_cams, n_cams)


def pair_correspondences(cam_idx: IntArray, feat_idx: IntArray, n_cams: int,
                         min_matches: int, *, max_partners: int | None = None,
                         pairs: BoolArray | None = None, max_per_pair: int | None = None,
                         counts: IntArray | None = None,
                         engine: EngineName | str = EngineName.AUTO) -> PairCorrespondences:
    """Return all camera pairs with at least ``min_matches`` common features and their matches.

    Args:
        cam_idx: Camera of each observation, shape (K,).
        feat_idx: Feature of each observation, shape (K,); one observation per (camera, feature).
        n_cams: Number of cameras M.
        min_matches: Minimum number of common features of a pair.
        max_partners: If set, keep a pair only if it is among the ``max_partners`` most
            co-visible partners of one of its cameras (limits the pairs of long sequences).
        pairs: If set, the pairs to join instead, as an (M, M) upper-triangle mask
            (``min_matches`` and ``max_partners`` are then not used).
        max_per_pair: If set, keep at most this many correspondences of each pair, evenly
            spread over the pair's correspondences in the order returned without it (the
            sample of :func:`~pmba_ros.init.parallax.sampled_parallax_px`), without holding
            them all at once.
        counts: :func:`covisibility_counts` of these observations, if the caller has them.
        engine: The compiled pass (``'auto'``: where numba runs) or the numpy code.

    Returns:
        The pairs (sorted by (cam_a, cam_b)) and their correspondences.
    """
    if counts is None:
        counts = covisibility_counts(cam_idx, feat_idx, n_cams, engine)
    if pairs is None:
        pairs = counts >= max(int(min_matches), 1)
        if max_partners is not None:
            a, b = np.nonzero(pairs)
            pairs[a, b] = top_partners(a, b, counts[a, b].astype(float), n_cams, max_partners)
    selected = np.asarray(pairs, dtype=bool).ravel()
    total = counts.ravel()
    order, max_len = _track_layout(cam_idx, feat_idx)
    f, c = feat_idx[order], cam_idx[order]
    if _compiled(engine):
        pair_keys, offsets, pos_a, pos_b = track_pairs.join_pairs(f, c, n_cams, max_len, selected,
                                                                  total, max_per_pair)
        return PairCorrespondences(pair_keys // n_cams, pair_keys % n_cams, offsets,
                                   order[pos_a], order[pos_b])
    seen = np.zeros(n_cams * n_cams, dtype=np.int64)
    keys: list[IntArray] = []
    first: list[IntArray] = []
    second: list[IntArray] = []
    for d in range(1, max_len):
        same = np.flatnonzero(f[d:] == f[:-d])
        key = c[same] * n_cams + c[same + d]
        sel = np.flatnonzero(selected[key])
        if max_per_pair is not None:
            k = key[sel]
            j = seen[k] + _rank_within(k, seen.shape[0])   # place in the pair's full list
            seen += np.bincount(k, minlength=seen.shape[0])
            sel = sel[_evenly_spread(j, total[k], max_per_pair)]
        keys.append(key[sel])
        first.append(order[same[sel]])
        second.append(order[same[sel] + d])
    key_all = np.concatenate(keys) if keys else np.zeros(0, dtype=np.int64)
    obs_a = np.concatenate(first) if first else np.zeros(0, dtype=np.int64)
    obs_b = np.concatenate(second) if second else np.zeros(0, dtype=np.int64)
    return _csr(key_all, obs_a, obs_b, n_cams)


def _csr(key_all: IntArray, obs_a: IntArray, obs_b: IntArray,
         n_cams: int) -> PairCorrespondences:
    """Return the correspondences grouped by pair key (stable: their order kept in a pair)."""
    srt = _stable_order(key_all, n_cams * n_cams)
    key_all, obs_a, obs_b = key_all[srt], obs_a[srt], obs_b[srt]
    pair_keys, starts = np.unique(key_all, return_index=True)
    offsets = np.concatenate([starts, [key_all.shape[0]]]).astype(np.int64)
    return PairCorrespondences(pair_keys // n_cams, pair_keys % n_cams, offsets,
                               obs_a.astype(np.int64), obs_b.astype(np.int64))


def _evenly_spread(j: IntArray, n: IntArray, m_max: int) -> BoolArray:
    """Return whether place j of n is among the min(n, m_max) places (i n) // m, i < m."""
    m = np.minimum(n, m_max)
    i = -(-j * m // n)   # the smallest i with i n / m >= j
    spread: BoolArray = (i < m) & ((i * n) // m == j)
    return spread


def _stable_order(key: IntArray, n_keys: int) -> IntArray:
    """Return np.argsort(key, kind='stable') for keys in [0, n_keys).

    Keys that fit 16 bits are sorted as such: numpy sorts those with a radix sort, several
    times faster than the merge sort of 64-bit keys, into the same (stable) order.
    """
    if n_keys <= 1 << 16:
        return np.argsort(key.astype(np.uint16), kind='stable')
    return np.argsort(key, kind='stable')


def _rank_within(key: IntArray, n_keys: int) -> IntArray:
    """Return each entry's rank among the entries of equal key before it, shape (n,).

    Keys are in [0, n_keys).
    """
    srt = _stable_order(key, n_keys)
    sorted_keys = key[srt]
    rank = np.empty_like(srt)
    rank[srt] = np.arange(key.shape[0]) - np.searchsorted(sorted_keys, sorted_keys, 'left')
    return rank


def top_partners(cam_a: IntArray, cam_b: IntArray, score: FloatArray, n_cams: int,
                 max_partners: int) -> BoolArray:
    """Return the pairs that are among the ``max_partners`` best of one of their cameras.

    Args:
        cam_a: First camera of each pair, shape (P,).
        cam_b: Second camera of each pair, shape (P,).
        score: Score of each pair (higher is better), shape (P,); ties keep the pair order.
        n_cams: Number of cameras M.
        max_partners: Partners kept per camera (>= 1).

    Returns:
        Mask (P,) of the kept pairs.
    """
    P = cam_a.shape[0]
    cam = np.concatenate([cam_a, cam_b])
    pair = np.concatenate([np.arange(P), np.arange(P)])
    order = np.lexsort((pair, -np.concatenate([score, score]), cam))
    cam_sorted = cam[order]
    first = np.searchsorted(cam_sorted, np.arange(n_cams))
    rank = np.arange(cam.shape[0]) - first[cam_sorted]
    keep = np.zeros(P, dtype=bool)
    keep[pair[order][rank < max_partners]] = True
    return keep
