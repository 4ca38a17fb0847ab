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
"""Compiled widest-pair anchor search (mirrors :mod:`pmba_ros.core.anchor_search`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import jit

_jit = jit.jit


@_jit
def _widest_pairs(rays: Any, cam_idx: Any, starts: Any, allowed: Any, close: Any, M: int,
                  main_idx: Any, assoc_idx: Any, ok: Any) -> None:
    """Find each feature's admissible observation pair of smallest ray cosine.

    The first such pair in row-major order, as numpy's argmin; the later observation's
    camera is the main anchor.
    """
    for f in range(starts.shape[0] - 1):
        lo, hi = starts[f], starts[f + 1]
        best, best_a, best_b = 2.0, lo, lo
        for a in range(lo, hi):
            ca = cam_idx[a]
            for b in range(a + 1, hi):
                cb = cam_idx[b]
                if allowed.shape[0] > 0 and not allowed[ca, cb]:
                    continue
                if close.shape[0] > 0:
                    key = ca * M + cb
                    pos = np.searchsorted(close, key)
                    if pos < close.shape[0] and close[pos] == key:
                        continue
                cos = rays[a, 0] * rays[b, 0] + rays[a, 1] * rays[b, 1] + rays[a, 2] * rays[b, 2]
                if cos < best:
                    best, best_a, best_b = cos, a, b
        if hi - lo >= 2:
            main_idx[f] = cam_idx[best_b]
            assoc_idx[f] = cam_idx[best_a]
            ok[f] = best < 2.0


def widest_pairs(rays: FloatArray, cam_idx: IntArray, starts: IntArray,
                 allowed: Any, close: IntArray, n_cams: int,
                 ) -> tuple[IntArray, IntArray, Any]:
    """Return main and associate anchors and ok of each feature (conversions.select_anchors).

    ``allowed`` is an (M, M) mask of admissible camera pairs or None, ``close`` the sorted
    keys a * M + b of inadmissible ones.
    """
    N = starts.shape[0] - 1
    main_idx = np.zeros(N, dtype=np.int64)
    assoc_idx = np.zeros(N, dtype=np.int64)
    ok = np.zeros(N, dtype=np.bool_)
    mask = np.zeros((0, 0), dtype=np.bool_) if allowed is None else np.asarray(allowed, bool)
    _widest_pairs(rays, cam_idx, starts, mask, np.sort(close).astype(np.int64), n_cams,
                  main_idx, assoc_idx, ok)
    return main_idx, assoc_idx, ok
