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
"""Compiled joins of feature tracks into camera pairs (mirrors ``init.covisibility``).

Observations are sorted by feature, then camera, so a track is a run of equal features. The
numpy code passes over all observations once per offset d inside a track (up to the longest
track, hundreds of views in a photo collection); here, for each d, only the tracks longer
than d are walked, so the work is the number of correspondences. Both visit the
correspondences in the same order (offset first, then position), so they return the same
arrays; the counts, where order does not matter, are counted track by track.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import BoolArray, IntArray
from pmba_ros.core import jit

_jit = jit.jit


@_jit
def _count(f: Any, c: Any, n_cams: int, counts: Any) -> None:
    """Add every correspondence of every track (a run of equal f) to its pair's count."""
    start = 0
    for end in range(1, f.shape[0] + 1):
        if end < f.shape[0] and f[end] == f[start]:
            continue
        for a in range(start, end):
            row = c[a] * n_cams
            for b in range(a + 1, end):
                counts[row + c[b]] += 1
        start = end


#: Columns of a selected pair's state in :func:`_join`: a visit reads one cache line.
_AT, _END, _SEEN, _KEPT, _PLACE, _TOTAL = range(6)


@_jit
def _join(f: Any, c: Any, n_cams: int, max_len: int, max_per_pair: int, slot: Any, state: Any,
          alive: Any, first: Any, second: Any) -> bool:
    """Write the selected correspondences (i, i + d) at their pair's place; False: no room.

    Offset d first, then position i, as the numpy join: for each d the tracks longer than d
    are walked in order (``alive``, shrinking). ``slot[key]`` is a selected pair's row of
    ``state`` (-1: not selected): its next place and the end of its places, and, with
    ``max_per_pair`` > 0, what the sample needs. A correspondence is then kept only at the
    places (i n) // m, i < m, of its pair's n = total (m = min(n, max_per_pair)): the pair's
    correspondences seen so far, those kept, and the next place (increasing with i, as
    m <= n) are counted, so only a kept one costs a division.
    """
    n_alive = 0
    start = 0
    for end in range(1, f.shape[0] + 1):   # the tracks of two views or more
        if end < f.shape[0] and f[end] == f[start]:
            continue
        if end - start > 1:
            alive[n_alive, 0] = start
            alive[n_alive, 1] = end
            n_alive += 1
        start = end
    for d in range(1, max_len):
        kept = 0
        for t in range(n_alive):
            lo, hi = alive[t, 0], alive[t, 1]
            if hi - lo <= d:
                continue
            alive[kept, 0] = lo
            alive[kept, 1] = hi
            kept += 1
            for i in range(lo, hi - d):
                row = slot[c[i] * n_cams + c[i + d]]
                if row < 0:
                    continue
                at = state[row, _AT]
                if at == state[row, _END]:
                    if max_per_pair == 0:
                        return False   # a selected pair with more than its count
                    continue
                if max_per_pair > 0:
                    j = state[row, _SEEN]
                    state[row, _SEEN] = j + 1
                    if j != state[row, _PLACE]:
                        continue
                    n = state[row, _TOTAL]
                    m_k = min(n, max_per_pair)
                    taken = state[row, _KEPT] + 1
                    state[row, _KEPT] = taken
                    state[row, _PLACE] = (taken * n) // m_k if taken < m_k else n
                first[at] = i
                second[at] = i + d
                state[row, _AT] = at + 1
        n_alive = kept
    return True


def count_pairs(f: IntArray, c: IntArray, n_cams: int) -> IntArray:
    """Return the correspondences of every camera pair, flat (M * M,) (key c_a M + c_b).

    ``f`` and ``c`` are the features and cameras of the observations sorted by (feature,
    camera).
    """
    counts = np.zeros(n_cams * n_cams, dtype=np.int64)
    _count(np.ascontiguousarray(f), np.ascontiguousarray(c), n_cams, counts)
    return counts


def join_pairs(f: IntArray, c: IntArray, n_cams: int, max_len: int, selected: BoolArray,
               total: IntArray, max_per_pair: int | None,
               ) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """Return the selected pairs' keys and CSR offsets, and their correspondences' positions.

    ``selected`` and ``total`` (the counts of :func:`count_pairs`) are flat (M * M,); with
    ``max_per_pair``, a pair keeps at most that many of its correspondences, evenly spread
    (``init.covisibility.pair_correspondences``). A pair's correspondences are in the order
    of the numpy join (offset in the track, then position).

    Raises:
        ValueError: If ``total`` is not the count of these tracks' correspondences.
    """
    sizes = np.where(selected, total if max_per_pair is None
                     else np.minimum(total, max_per_pair), 0)
    keys = np.flatnonzero(sizes)
    offsets = np.concatenate([[0], np.cumsum(sizes[keys])]).astype(np.int64)
    state = np.zeros((keys.shape[0], 6), dtype=np.int64)
    state[:, _AT], state[:, _END], state[:, _TOTAL] = offsets[:-1], offsets[1:], total[keys]
    slot = np.full(sizes.shape[0], -1, dtype=np.int32 if keys.shape[0] < 2**31 else np.int64)
    slot[keys] = np.arange(keys.shape[0])
    first = np.empty(int(offsets[-1]), dtype=np.int64)
    second = np.empty(int(offsets[-1]), dtype=np.int64)
    alive = np.empty((f.shape[0] // 2 + 1, 2), dtype=np.int64)   # tracks of 2 views or more
    room = _join(np.ascontiguousarray(f), np.ascontiguousarray(c), n_cams, max_len,
                 0 if max_per_pair is None else max_per_pair, slot, state, alive, first, second)
    if not room or not np.array_equal(state[:, _AT], offsets[1:]):
        msg = "join_pairs: `total` is not the count of these tracks' correspondences"
        raise ValueError(msg)
    return keys, offsets, first, second


__all__ = ['count_pairs', 'join_pairs']
