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
"""Compiled ordering of a window's tracks, the back-end's observation gathering in one pass.

Mirrors the numpy reference :func:`pmba_ros.backend.window.ordered_tracks` (the filter by
feature id, the stable sort by id, the thinning of long tracks and the order by track
length) with the same arithmetic, so both give the same indices.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import IntArray
from pmba_ros.core import jit

_jit = jit.jit

#: The largest id table, in observations and keys (:func:`_places`).
_TABLE_FACTOR = 8


@_jit
def _thin_keeps(rank: int, n: int, cap: int) -> bool:
    """Return whether observation ``rank`` of a track of ``n`` (> cap) is kept.

    The numpy reference's arithmetic: k = rint(rank (cap - 1) / span), kept where
    rint(k span / (cap - 1)) is rank again.
    """
    span = max(n - 1, 1)
    k = np.rint((rank * (cap - 1)) / span)
    return bool(np.rint(k * span / (cap - 1)) == rank)


@_jit
def _places(keys: Any, ids: Any) -> Any:
    """Return the place of each id among the sorted ``keys`` (the first equal), or -1.

    Through a table over the keys' range where it is small (ids of one run's features are),
    else by binary search, whose mispredicted branches cost more than the table's fill.
    """
    K, n_keys = ids.shape[0], keys.shape[0]
    out = np.full(K, -1, np.int64)
    if n_keys == 0:
        return out
    low, span = keys[0], keys[n_keys - 1] - keys[0] + 1
    if span <= _TABLE_FACTOR * (K + n_keys):
        table = np.full(span, -1, np.int64)
        for b in range(n_keys - 1, -1, -1):   # backwards: a repeated key keeps its first place
            table[keys[b] - low] = b
        for k in range(K):
            offset = ids[k] - low
            if 0 <= offset < span:
                out[k] = table[offset]
        return out
    for k in range(K):
        pos = np.searchsorted(keys, ids[k])
        if pos < n_keys and keys[pos] == ids[k]:
            out[k] = pos
    return out


@_jit
def _stable_order(counts: Any) -> Any:
    """Return numpy's stable argsort of small non-negative counts, by a counting sort."""
    n = counts.shape[0]
    top = 0
    for t in range(n):
        top = max(top, counts[t])
    fill = np.zeros(top + 2, np.int64)
    for t in range(n):
        fill[counts[t] + 1] += 1
    for c in range(top + 1):
        fill[c + 1] += fill[c]
    perm = np.empty(n, np.int64)
    for t in range(n):
        perm[fill[counts[t]]] = t
        fill[counts[t]] += 1
    return perm


@_jit
def _ordered_tracks(ids: Any, offsets: Any, keep_ids: Any, filtered: bool, cap: int,
                    by_length: bool) -> tuple[Any, Any, Any, Any]:
    K = ids.shape[0]
    if filtered:
        keys = keep_ids
        for i in range(1, keys.shape[0]):
            if keys[i] < keys[i - 1]:
                keys = np.sort(keep_ids)
                break
    else:
        keys = np.unique(ids)
    # A counting sort by the id's place among the keys: by id, then (stable) by position,
    # as numpy's stable argsort of the ids.
    n_keys = keys.shape[0]
    bucket = _places(keys, ids)
    fill = np.zeros(n_keys + 1, np.int64)
    for k in range(K):
        if bucket[k] >= 0:
            fill[bucket[k] + 1] += 1
    for b in range(n_keys):
        fill[b + 1] += fill[b]
    m = fill[n_keys]
    sel = np.empty(m, np.int64)
    for k in range(K):
        b = bucket[k]
        if b >= 0:
            sel[fill[b]] = k
            fill[b] += 1
    sorted_ids = ids[sel]
    # Tracks (runs of one id) and the observations each keeps.
    starts = np.empty(m + 1, np.int64)
    n_tracks = 0
    for i in range(m):
        if i == 0 or sorted_ids[i] != sorted_ids[i - 1]:
            starts[n_tracks] = i
            n_tracks += 1
    starts[n_tracks] = m
    kept = np.empty(m, np.int64)
    counts = np.empty(n_tracks, np.int64)
    kept_start = np.empty(n_tracks, np.int64)
    n_kept = 0
    for t in range(n_tracks):
        lo, hi = starts[t], starts[t + 1]
        n = hi - lo
        kept_start[t] = n_kept
        for r in range(n):
            if cap == 0 or n <= cap or _thin_keeps(r, n, cap):
                kept[n_kept] = lo + r
                n_kept += 1
        counts[t] = n_kept - kept_start[t]
    perm = _stable_order(counts) if by_length else np.arange(n_tracks)
    # The keyframe of every observation (its part of the concatenation).
    owner = np.empty(K, np.int64)
    for p in range(offsets.shape[0] - 1):
        for k in range(offsets[p], offsets[p + 1]):
            owner[k] = p
    out_sel = np.empty(n_kept, np.int64)
    local = np.empty(n_kept, np.int64)
    feat_idx = np.empty(n_kept, np.int64)
    feature_ids = np.empty(n_tracks, np.int64)
    pos = 0
    for j in range(n_tracks):
        t = perm[j]
        feature_ids[j] = sorted_ids[starts[t]]
        for q in range(kept_start[t], kept_start[t] + counts[t]):
            s = sel[kept[q]]
            out_sel[pos] = s
            local[pos] = owner[s]
            feat_idx[pos] = j
            pos += 1
    return out_sel, local, feat_idx, feature_ids


def ordered_tracks(ids: IntArray, offsets: IntArray, feature_filter: IntArray | None, cap: int,
                   by_length: bool) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """Return :func:`pmba_ros.backend.window.ordered_tracks` (same arguments, same indices)."""
    keep = (np.zeros(0, np.int64) if feature_filter is None
            else np.asarray(feature_filter, dtype=np.int64))
    out: tuple[IntArray, IntArray, IntArray, IntArray] = _ordered_tracks(
        np.asarray(ids, dtype=np.int64), np.asarray(offsets, dtype=np.int64), keep,
        feature_filter is not None, int(cap), bool(by_length))
    return out
