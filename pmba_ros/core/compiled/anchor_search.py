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
"""Compiled widest-pair anchor search (mirrors :mod:`pmba_ros.core.anchor_search`).

Also the whole of conversions.xyz_to_parallax in one pass (its numpy reference is
:func:`pmba_ros.core.conversions._point_features`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import jit

_jit = jit.jit


@_jit
def _widest_pair(rays: Any, cam_idx: Any, lo: int, hi: int, allowed: Any, close: Any,
                 M: int) -> tuple[float, int, int]:
    """Return the smallest admissible |ray cosine| of observations lo..hi and its pair (a < b).

    The first such pair in row-major order, as numpy's argmin; (2.0, lo, lo) without one.
    """
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
            cos = abs(rays[a, 0] * rays[b, 0] + rays[a, 1] * rays[b, 1]
                      + rays[a, 2] * rays[b, 2])    # |cos|, as the numpy reference
            if cos < best:
                best, best_a, best_b = cos, a, b
    return best, best_a, best_b


@_jit
def _widest_pairs(rays: Any, cam_idx: Any, starts: Any, allowed: Any, close: Any, M: int,
                  main_idx: Any, assoc_idx: Any, ok: Any) -> None:
    """Find each feature's admissible observation pair of smallest |ray cosine|.

    The later observation's camera is the main anchor.
    """
    for f in range(starts.shape[0] - 1):
        lo, hi = starts[f], starts[f + 1]
        best, best_a, best_b = _widest_pair(rays, cam_idx, lo, hi, allowed, close, M)
        if hi - lo >= 2:
            main_idx[f] = cam_idx[best_b]
            assoc_idx[f] = cam_idx[best_a]
            ok[f] = best < 2.0


@_jit
def _first_observation(cam_idx: Any, lo: int, hi: int, cam: int) -> int:
    """Return the first of observations lo..hi made by ``cam``, or -1."""
    for k in range(lo, hi):
        if cam_idx[k] == cam:
            return k
    return -1


@_jit
def _clip_unit(c: float) -> float:
    """Return c clipped to [-1, 1] as np.clip (NaN stays NaN)."""
    if c < -1.0:
        return -1.0
    if c > 1.0:
        return 1.0
    return c


@_jit
def _coincident_keys(centers_w: Any, min_baseline: float) -> Any:
    """Return the sorted keys a * M + b (both orders) of camera pairs without baseline.

    conversions._coincident_pairs: its sweep along x, its tolerance and arithmetic.
    """
    M = centers_w.shape[0]
    scale = 0.0
    if M > 1:
        for d in range(3):
            ptp = np.max(centers_w[:, d]) - np.min(centers_w[:, d])
            scale = ptp if d == 0 or ptp > scale else scale
    tol = max(max(scale, 1.0) * 1e-9, min_baseline)
    order = np.argsort(centers_w[:, 0], kind='mergesort')
    keys = np.empty(0, dtype=np.int64)
    for sweep in range(2):   # count, then fill
        count = 0
        for i in range(M):
            a = order[i]
            lim = centers_w[a, 0] + tol
            for j in range(i + 1, M):
                b = order[j]
                if centers_w[b, 0] > lim:
                    break
                d0 = centers_w[a, 0] - centers_w[b, 0]
                d1 = centers_w[a, 1] - centers_w[b, 1]
                d2 = centers_w[a, 2] - centers_w[b, 2]
                # numpy's einsum order (see _point_features' rays).
                if (d0 * d0 + d2 * d2) + d1 * d1 <= tol * tol:
                    if sweep == 1:
                        keys[2 * count] = a * M + b
                        keys[2 * count + 1] = b * M + a
                    count += 1
        if sweep == 0:
            if count == 0:
                return keys
            keys = np.empty(2 * count, dtype=np.int64)
    return np.sort(keys)


@_jit
def _point_features(R_wc: Any, centers_w: Any, points_w: Any, v: Any, cam_idx: Any,
                    feat_idx: Any, allowed: Any, swap_ratio: float, min_baseline: float,
                    main_idx: Any, assoc_idx: Any, ok: Any, cos_t: Any, n: Any, valid: Any,
                    ) -> tuple[int, int]:
    """Anchors, cos(theta), n and validity of each feature from its point, in one pass.

    The steps and their arithmetic order are those of conversions.xyz_to_parallax's numpy
    path: pairs without baseline, widest pair, depth-ratio swap, the point's ray and parallax,
    and the rotation-only values where the point is unusable. Returns the first feature whose
    anchor camera does not observe it (a feature seen from one pose; -1: none), and how many
    features with an anchor pair took the rotation-only values.
    """
    K, N, M = cam_idx.shape[0], points_w.shape[0], R_wc.shape[0]
    close = _coincident_keys(centers_w, min_baseline)
    starts = np.zeros(N + 1, dtype=np.int64)   # the problem's feature_offsets()
    for k in range(K):
        starts[feat_idx[k] + 1] += 1
    for f in range(N):
        starts[f + 1] += starts[f]
    rays = np.empty((K, 3))
    for k in range(K):
        c = cam_idx[k]
        for i in range(3):
            # The order in which numpy's einsum adds a contiguous three-term product (its two
            # SIMD lanes), so that the pairs' cosines and both engines' fall-backs agree.
            rays[k, i] = ((R_wc[c, i, 0] * v[k, 0] + R_wc[c, i, 2] * v[k, 2])
                          + R_wc[c, i, 1] * v[k, 1])
    n_reinit = 0
    for f in range(N):
        lo, hi = starts[f], starts[f + 1]
        best, a, b = _widest_pair(rays, cam_idx, lo, hi, allowed, close, M)
        m, s = 0, 0
        if hi - lo >= 2:
            m, s = cam_idx[b], cam_idx[a]
            ok[f] = best < 2.0
        x, y, z = points_w[f, 0], points_w[f, 1], points_w[f, 2]
        mx, my, mz = x - centers_w[m, 0], y - centers_w[m, 1], z - centers_w[m, 2]
        ax, ay, az = x - centers_w[s, 0], y - centers_w[s, 1], z - centers_w[s, 2]
        d_m = np.sqrt(mx * mx + my * my + mz * mz)
        d_a = np.sqrt(ax * ax + ay * ay + az * az)
        if d_m > swap_ratio * d_a:
            m, s, mx, my, mz, ax, ay, az, d_m, d_a = s, m, ax, ay, az, mx, my, mz, d_a, d_m
        main_idx[f], assoc_idx[f] = m, s
        km = _first_observation(cam_idx, lo, hi, m)
        ka = _first_observation(cam_idx, lo, hi, s)
        if km < 0 or ka < 0:
            return f, n_reinit
        # The point's ray in the main anchor's frame, R_m^T (F - P_m), normalized.
        nx = R_wc[m, 0, 0] * mx + R_wc[m, 1, 0] * my + R_wc[m, 2, 0] * mz
        ny = R_wc[m, 0, 1] * mx + R_wc[m, 1, 1] * my + R_wc[m, 2, 1] * mz
        nz = R_wc[m, 0, 2] * mx + R_wc[m, 1, 2] * my + R_wc[m, 2, 2] * mz
        norm = np.sqrt(nx * nx + ny * ny + nz * nz)
        norm = norm if norm > 0.0 else 1.0
        nx, ny, nz = nx / norm, ny / norm, nz / norm
        d_m = d_m if d_m > 0.0 else 1.0
        d_a = d_a if d_a > 0.0 else 1.0
        cos = ((mx / d_m) * (ax / d_a) + (my / d_m) * (ay / d_a)) + (mz / d_m) * (az / d_a)
        # Usable if finite, in front of the main anchor and on its measured side.
        usable = (np.isfinite(x) and np.isfinite(y) and np.isfinite(z) and nz > 0.0
                  and nx * v[km, 0] + ny * v[km, 1] + nz * v[km, 2] > 0.0)
        valid[f] = usable
        if usable:
            n[f, 0], n[f, 1], n[f, 2] = nx, ny, nz
        else:
            n[f, 0], n[f, 1], n[f, 2] = v[km, 0], v[km, 1], v[km, 2]
            cos = (rays[km, 0] * rays[ka, 0] + rays[km, 1] * rays[ka, 1]
                   + rays[km, 2] * rays[ka, 2])
            if ok[f]:
                n_reinit += 1
        cos_t[f] = _clip_unit(cos)
    return -1, n_reinit


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


def _frozen(x: Any, dtype: Any) -> Any:
    """Return a contiguous read-only view of ``x``: one argument type for every caller."""
    out = np.ascontiguousarray(x, dtype=dtype).view()
    out.flags.writeable = False
    return out


def point_features(R_wc: FloatArray, centers_w: FloatArray, points_w: FloatArray,
                   v: FloatArray, cam_idx: IntArray, feat_idx: IntArray, allowed: Any,
                   swap_ratio: float, min_baseline: float = 0.0,
                   ) -> tuple[IntArray, IntArray, Any, FloatArray, FloatArray, Any, int, int]:
    """Return the anchors and features of points (conversions.xyz_to_parallax), in one pass.

    Args:
        R_wc: Camera -> world rotations, shape (M, 3, 3).
        centers_w: Camera centres, shape (M, 3).
        points_w: The features' points, shape (N, 3).
        v: Bearings in the pose (rig) frame, shape (K, 3).
        cam_idx: Pose of each observation (sorted by feature, then pose), shape (K,).
        feat_idx: Feature of each observation, shape (K,), values below N.
        allowed: (M, M) mask of admissible camera pairs, or None (all but those without
            baseline).
        swap_ratio: Depth ratio above which the anchors are swapped.
        min_baseline: Pairs closer than this are not anchors either.

    Returns:
        main_idx, assoc_idx, ok, clipped cos(theta), n, valid (the point gave theta and n),
        the first feature whose anchor camera does not observe it (-1: none) and the number
        of features with an anchor pair whose point was not usable.
    """
    N = points_w.shape[0]
    main_idx = np.zeros(N, dtype=np.int64)
    assoc_idx = np.zeros(N, dtype=np.int64)
    ok = np.zeros(N, dtype=np.bool_)
    valid = np.zeros(N, dtype=np.bool_)
    cos_t, n = np.empty(N), np.empty((N, 3))
    mask = np.zeros((0, 0), dtype=np.bool_) if allowed is None else allowed
    f64 = np.float64
    unseen, n_reinit = _point_features(
        _frozen(R_wc, f64), _frozen(centers_w, f64), _frozen(points_w, f64), _frozen(v, f64),
        _frozen(cam_idx, np.int64), _frozen(feat_idx, np.int64), _frozen(mask, np.bool_),
        swap_ratio, float(min_baseline), main_idx, assoc_idx, ok, cos_t, n, valid)
    return main_idx, assoc_idx, ok, cos_t, n, valid, int(unseen), int(n_reinit)


def coincident_keys(centers_w: FloatArray, min_baseline: float = 0.0) -> IntArray:
    """Return conversions._coincident_pairs' keys, sorted (the one used by point_features)."""
    out: IntArray = _coincident_keys(_frozen(centers_w, np.float64), float(min_baseline))
    return out
