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
"""Widest-pair anchor search: each feature's observer pair of largest sin(parallax) (numpy).

The reference of :mod:`pmba_ros.core.compiled.anchor_search`; used by
:func:`pmba_ros.core.conversions.select_anchors` through the engine.

DEVIATION(pmba.md §3.1): ParallaxBA takes the largest parallax angle (freezing at 0.5 rad,
so in practice a pair below 90 degrees). Taking the largest angle outright picks pairs near
180 degrees wherever cameras surround the scene (turntable, object-centred captures): the
point then lies between its anchors, w = sin(theta) ~ 0 as at infinity, and the Dogleg
needed 27-53 iterations where XYZ-BA needs 3-4 (a 180-degree arc of 30 or 100 cameras).
The pair of smallest |cos| (parallax closest to 90 degrees, largest sin(theta)) is the best
conditioned; below 90 degrees it is the same pair as before.
"""

from __future__ import annotations

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray


def widest_pairs(rays: FloatArray, cam_idx: IntArray, starts: IntArray,
                 allowed: BoolArray | None, close: IntArray, n_cams: int,
                 ) -> tuple[IntArray, IntArray, BoolArray]:
    """Return the main and associate anchors of each feature and whether it has a pair.

    The admissible observation pair of smallest absolute ray cosine (largest sin of the
    parallax), the first in row-major order; the later observation's camera is the main
    anchor.

    Args:
        rays: World rays of the observations (sorted by feature), shape (K, 3).
        cam_idx: Camera of each observation, shape (K,).
        starts: First observation of each feature, and K, shape (N + 1,).
        allowed: (M, M) mask of admissible camera pairs, or None (all).
        close: Keys a * M + b of inadmissible camera pairs.
        n_cams: Number of cameras M.
    """
    N = starts.shape[0] - 1
    main_idx = np.zeros(N, dtype=np.int64)
    assoc_idx = np.zeros(N, dtype=np.int64)
    ok = np.zeros(N, dtype=bool)
    counts = np.diff(starts)
    # Features with c observations at a time: all pairwise cosines as one (c x c) Gram matrix
    # per feature; the first minimum of |cos| in the upper triangle (row-major) is the pair.
    for c in np.unique(counts[counts >= 2]):
        c = int(c)
        feats = np.flatnonzero(counts == c)
        k = starts[:-1][feats][:, None] + np.arange(c)                      # (n, c)
        r = rays[k]
        cos = np.abs(r @ np.swapaxes(r, 1, 2))    # |cos|: see the module docstring
        cams = cam_idx[k]
        # Inadmissible pairs (and the lower triangle) score above every cosine.
        bad = np.broadcast_to(~np.triu(np.ones((c, c), dtype=bool), 1), cos.shape).copy()
        if allowed is not None:
            bad |= ~allowed[cams[:, :, None], cams[:, None, :]]
        if close.size:
            bad |= np.isin(cams[:, :, None] * n_cams + cams[:, None, :], close)
        cos[bad] = 2.0
        best = np.argmin(cos.reshape(-1, c * c), axis=1)
        a, b = best // c, best % c
        rows = np.arange(feats.shape[0])
        main_idx[feats] = cams[rows, b]      # the later camera is the main anchor
        assoc_idx[feats] = cams[rows, a]
        ok[feats] = cos.reshape(-1, c * c)[rows, best] < 2.0
    return main_idx, assoc_idx, ok
