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
"""Compiled J^T J accumulation: U, W, V, g, their Jacobi scaling and x^T H x.

Mirrors the numpy assembly of :mod:`pmba_ros.core.normal_equations`. Block addressing:
``pair_index[a, b]`` (a <= b) is the row of the upper pair block (a, b) in ``U``; a pair
(a, b) with a > b is stored transposed at ``pair_index[b, a]``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import jit
from pmba_ros.core.compiled import chunks
from pmba_ros.core.jacobian import ANCHOR_START

_jit = jit.jit


#: Largest number of free pose blocks for the compiled loops: their (n, n) pair index
#: stays under 75 MB; larger problems take the numpy path.
MAX_BLOCKS = 3000


@_jit
def _add_block(U: Any, pair_index: Any, a: int, b: int, src: Any, i0: int, k0: int,
               n_r: int, n_c: int, r0: int, c0: int, symmetric: bool) -> None:
    """Add src[i0:i0+n_r, k0:k0+n_c] at rows r0.. of pose a, columns c0.. of pose b.

    Pairs a > b go to the transposed upper block. On a diagonal block (a = b) the transpose
    is added too, unless the block is a ``symmetric`` product of one slot with itself.
    """
    # Transposed adds loop over the target's rows first: contiguous stores.
    if a > b:
        p = pair_index[b, a]
        for k in range(n_c):
            for i in range(n_r):
                U[p, c0 + k, r0 + i] += src[i0 + i, k0 + k]
        return
    p = pair_index[a, b]
    for i in range(n_r):
        for k in range(n_c):
            U[p, r0 + i, c0 + k] += src[i0 + i, k0 + k]
    if a == b and not symmetric:
        for k in range(n_c):
            for i in range(n_r):
                U[p, c0 + k, r0 + i] += src[i0 + i, k0 + k]


@_jit
def _outer_add(E: Any, k: int, i0: int, m0: int, out: Any) -> None:
    """Add E_k[:, i0 + i]^T E_k[:, m0 + m] to out[i, m] (E_k = E[k], d rows).

    Two rows at a time: the inner loops run along contiguous columns and vectorize.
    """
    d = E.shape[1]
    n_i, n_m = out.shape
    for r in range(0, d - 1, 2):
        for i in range(n_i):
            x0, x1 = E[k, r, i0 + i], E[k, r + 1, i0 + i]
            for m in range(n_m):
                out[i, m] += x0 * E[k, r, m0 + m] + x1 * E[k, r + 1, m0 + m]
    if d % 2:
        for i in range(n_i):
            x = E[k, d - 1, i0 + i]
            for m in range(n_m):
                out[i, m] += x * E[k, d - 1, m0 + m]


@_jit
def _assemble(E: Any, starts: Any, obs_block: Any, anchor_block: Any, anchor_obs: Any,
              anchor_lo: Any, anchor_w: Any, pair_index: Any, U: Any, W: Any, V: Any,
              g_pose: Any, g_feat: Any, f0: int, f1: int) -> None:
    """J^T [J | r] of the observations of features f0..f1-1 into U, W, V, g (zeroed).

    As in the numpy assembly, the observer's rows are formed per observation and the rows
    of the residual, the feature and the anchors summed per feature (Q) and added once.
    """
    width = E.shape[2]
    n_anchor = anchor_lo.shape[0]
    P = np.empty((6, width))        # observer rows of one observation
    Q = np.empty((width - 6, width - 6))
    for f in range(f0, f1):
        Q[:] = 0.0
        for k in range(starts[f], starts[f + 1]):
            _outer_add(E, k, 6, 6, Q)
            b0 = obs_block[k]
            if b0 < 0:
                continue
            P[:] = 0.0
            _outer_add(E, k, 0, 0, P)
            _add_block(U, pair_index, b0, b0, P, 0, 0, 6, 6, 0, 0, True)
            for i in range(6):
                g_pose[b0, i] += P[i, 6]
                for m in range(3):
                    W[k, i, m] += P[i, 7 + m]
            col = ANCHOR_START
            for s in range(n_anchor):
                a = anchor_block[f, s]
                if a >= 0:
                    _add_block(U, pair_index, b0, a, P, 0, col, 6, anchor_w[s], 0, anchor_lo[s],
                               False)
                col += anchor_w[s]
        for i in range(3):
            g_feat[f, i] = Q[1 + i, 0]
            for m in range(3):
                V[f, i, m] = Q[1 + i, 1 + m]
        row = 4
        for s in range(n_anchor):
            a = anchor_block[f, s]
            w_s, lo_s = anchor_w[s], anchor_lo[s]
            if a >= 0:
                _add_block(U, pair_index, a, a, Q, row, row, w_s, w_s, lo_s, lo_s, True)
                for i in range(w_s):
                    g_pose[a, lo_s + i] += Q[row + i, 0]
                    for m in range(3):
                        W[anchor_obs[f, s], lo_s + i, m] += Q[row + i, 1 + m]
                row_t = row + w_s
                for t in range(s + 1, n_anchor):
                    b = anchor_block[f, t]
                    if b >= 0:
                        _add_block(U, pair_index, a, b, Q, row, row_t, w_s, anchor_w[t], lo_s,
                                   anchor_lo[t], False)
                    row_t += anchor_w[t]
            row += w_s


def assemble(E: FloatArray, starts: IntArray, obs_block: IntArray, anchor_block: IntArray,
             anchor_obs: IntArray, anchor_cols: tuple[tuple[int, int], ...],
             pair_index: IntArray, n_pairs: int,
             ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Return U (upper pair blocks), W, V, g_pose, g_feat of rows E (jacobian.py layout).

    ``obs_block`` is each observation's free pose block (-1: fixed), ``anchor_block`` and
    ``anchor_obs`` each feature's anchor blocks and its observation by each anchor.
    """
    K = E.shape[0]
    n_blocks, N = pair_index.shape[0], starts.shape[0] - 1
    anchor_lo = np.array([lo for lo, _ in anchor_cols], dtype=np.int64)
    anchor_w = np.array([hi - lo for lo, hi in anchor_cols], dtype=np.int64)
    E = np.ascontiguousarray(E)
    n = chunks.threads_for(K, 8 * (36 * n_pairs + 6 * n_blocks))
    W, V, g_feat = np.zeros((K, 6, 3)), np.zeros((N, 3, 3)), np.zeros((N, 3))
    # Pose blocks are shared between features: each chunk fills its own.
    U = [np.zeros((n_pairs, 6, 6)) for _ in range(n)]
    g_pose = [np.zeros((n_blocks, 6)) for _ in range(n)]
    cut = chunks.cuts(n, N, lambda: np.diff(starts))
    chunks.run(lambda t: _assemble(E, starts, obs_block, anchor_block, anchor_obs, anchor_lo,
                                   anchor_w, pair_index, U[t], W, V, g_pose[t], g_feat,
                                   int(cut[t]), int(cut[t + 1])), n)
    for t in range(1, n):
        U[0] += U[t]
        g_pose[0] += g_pose[t]
    return U[0], W, V, g_pose[0], g_feat


@_jit
def _anchors(cam_idx: Any, slot_pose: Any, starts: Any, anchor_pose: Any, anchor_obs: Any,
             errors: Any) -> None:
    """Fill each feature's anchor poses and observations; flag a slot's errors.

    ``errors[s, 0]``: slot s + 1 names different poses within a feature; ``errors[s, 1]``:
    an anchor pose does not observe its feature. The last observation by the anchor pose
    is its observation, as numpy's assignment of repeated indices leaves it.
    """
    for s in range(anchor_pose.shape[1]):
        for f in range(starts.shape[0] - 1):
            lo, hi = starts[f], starts[f + 1]
            if hi == lo:   # no observations (the layout rejects such features first)
                continue
            pose = slot_pose[lo, s + 1]
            for k in range(lo + 1, hi):
                pose = max(pose, slot_pose[k, s + 1])
            anchor_pose[f, s] = pose
            for k in range(lo, hi):
                if slot_pose[k, s + 1] >= 0 and slot_pose[k, s + 1] != pose:
                    errors[s, 0] = True
                if cam_idx[k] == pose:
                    anchor_obs[f, s] = k
            if pose >= 0 and anchor_obs[f, s] < 0:
                errors[s, 1] = True


def anchors(cam_idx: IntArray, slot_pose: IntArray, starts: IntArray,
            ) -> tuple[IntArray, IntArray, BoolArray]:
    """Return :func:`pmba_ros.core.normal_equations.anchors` (which also reads feat_idx)."""
    n_feats, n_anchor = starts.shape[0] - 1, slot_pose.shape[1] - 1
    anchor_pose = np.full((n_feats, n_anchor), -1, dtype=np.int64)
    anchor_obs = np.full((n_feats, n_anchor), -1, dtype=np.int64)
    errors = np.zeros((n_anchor, 2), dtype=bool)
    _anchors(cam_idx, slot_pose, starts, anchor_pose, anchor_obs, errors)
    return anchor_pose, anchor_obs, errors


@_jit
def _covisible(starts: Any, obs_block: Any, pair_index: Any) -> None:
    """Write the numbers of the covisible upper block pairs and the diagonal into pair_index."""
    n = pair_index.shape[0]
    pair_index[:] = -1
    for f in range(starts.shape[0] - 1):
        for a in range(starts[f], starts[f + 1]):
            ba = obs_block[a]
            if ba < 0:
                continue
            for b in range(a, starts[f + 1]):
                bb = obs_block[b]
                if bb >= 0:
                    pair_index[min(ba, bb), max(ba, bb)] = 0
    count = 0
    for i in range(n):
        pair_index[i, i] = 0
        for m in range(i, n):
            if pair_index[i, m] == 0:
                pair_index[i, m] = count
                count += 1


def covisible_pairs(starts: IntArray, obs_block: IntArray, n_blocks: int) -> IntArray:
    """Return the (n_blocks, n_blocks) upper pair index of poses that observe a common feature.

    Entry (a, b), a <= b, numbers the pair in row-major order, -1 where a and b share no
    feature; every pose pairs with itself.
    """
    pair_index = np.empty((n_blocks, n_blocks), dtype=np.int64)
    _covisible(starts, obs_block, pair_index)
    return pair_index


@_jit
def _scale_w(W: Any, feat_idx: Any, w_block: Any, c_pose: Any, c_feat: Any) -> None:
    """W_k <- diag(c_pose of its block) W_k diag(c_feat of its feature), in place."""
    for k in range(W.shape[0]):
        b, f = w_block[k], feat_idx[k]
        if b < 0:
            continue
        for i in range(6):
            for m in range(3):
                W[k, i, m] *= c_pose[b, i] * c_feat[f, m]


def scale_w(W: FloatArray, feat_idx: IntArray, obs_block: IntArray, c_pose: FloatArray,
            c_feat: FloatArray) -> None:
    """Scale the W blocks in place by their pose and feature column scales."""
    _scale_w(W, feat_idx, obs_block, c_pose, c_feat)


@_jit
def _column_scale(d: float, jacobi: bool) -> tuple[float, float]:
    """Return the scale c = 1 / (1 + sqrt(d)) of a column (1 without scaling) and D."""
    c = 1.0 / (1.0 + np.sqrt(d)) if jacobi else 1.0
    dc = d * (c * c)
    return c, np.sqrt(1e-6 if dc < 1e-6 else (1e32 if dc > 1e32 else dc))


@_jit
def _jacobi_scale(U: Any, V: Any, g_pose: Any, g_feat: Any, pair_rows: Any, pair_cols: Any,
                  col_mask: Any, jacobi: bool) -> Any:
    """Jacobi scaling of U, V and g: the arithmetic of normal_equations.jacobi_scale."""
    nb, N = g_pose.shape[0], g_feat.shape[0]
    d_pose = np.zeros((nb, 6))
    for p in range(U.shape[0]):
        if pair_rows[p] == pair_cols[p]:
            for i in range(6):
                d_pose[pair_rows[p], i] = U[p, i, i]
    c_pose, D_pose = np.empty((nb, 6)), np.empty((nb, 6))
    gs_pose, z_pose = np.empty((nb, 6)), np.empty((nb, 6))
    c_feat, D_feat = np.empty((N, 3)), np.empty((N, 3))
    gs_feat, z_feat = np.empty((N, 3)), np.empty((N, 3))
    g_max, nan = 0.0, False
    for b in range(nb):
        for i in range(6):
            c_pose[b, i], D_pose[b, i] = _column_scale(d_pose[b, i], jacobi)
            gs_pose[b, i] = g_pose[b, i] * c_pose[b, i]
            free = col_mask[b, i]
            z_pose[b, i] = (gs_pose[b, i] if free else 0.0) / D_pose[b, i]
            a = abs(g_pose[b, i]) if free else 0.0
            nan |= a != a
            g_max = max(g_max, a)
    for f in range(N):
        for i in range(3):
            c_feat[f, i], D_feat[f, i] = _column_scale(V[f, i, i], jacobi)
            gs_feat[f, i] = g_feat[f, i] * c_feat[f, i]
            z_feat[f, i] = gs_feat[f, i] / D_feat[f, i]
            a = abs(g_feat[f, i])
            nan |= a != a
            g_max = max(g_max, a)
    U_s, V_s = np.empty_like(U), np.empty_like(V)
    for p in range(U.shape[0]):
        a, b = pair_rows[p], pair_cols[p]
        for i in range(6):
            for m in range(6):
                U_s[p, i, m] = U[p, i, m] * c_pose[a, i] * c_pose[b, m]
    for f in range(N):
        for i in range(3):
            for m in range(3):
                V_s[f, i, m] = V[f, i, m] * c_feat[f, i] * c_feat[f, m]
    return (U_s, V_s, gs_pose, gs_feat, c_pose, c_feat, D_pose, D_feat, z_pose, z_feat,
            np.nan if nan else g_max)


def jacobi_scale(U: FloatArray, V: FloatArray, g_pose: FloatArray, g_feat: FloatArray,
                 pair_rows: IntArray, pair_cols: IntArray, col_mask: BoolArray, jacobi: bool,
                 ) -> tuple[Any, ...]:
    """Return U, V, g_pose, g_feat scaled, c_pose, c_feat, D_pose, D_feat, g / D and max |g|.

    The arithmetic of :func:`pmba_ros.core.normal_equations.jacobi_scale` (the W blocks
    are the caller's), in one pass.
    """
    out: tuple[Any, ...] = _jacobi_scale(U, V, g_pose, g_feat, pair_rows, pair_cols, col_mask,
                                         bool(jacobi))
    return out


@_jit
def _quadratic_form(U: Any, pair_rows: Any, pair_cols: Any, W: Any, V: Any, x_pose: Any,
                    x_feat: Any, feat_idx: Any, w_block: Any) -> float:
    """x^T H x from upper pair blocks U, W and V."""
    quad = 0.0
    for p in range(U.shape[0]):
        a, b = pair_rows[p], pair_cols[p]
        t = 0.0
        for i in range(6):
            for m in range(6):
                t += x_pose[a, i] * U[p, i, m] * x_pose[b, m]
        quad += t if a == b else 2.0 * t
    for k in range(W.shape[0]):
        b, f = w_block[k], feat_idx[k]
        if b < 0:
            continue
        t = 0.0
        for i in range(6):
            for m in range(3):
                t += x_pose[b, i] * W[k, i, m] * x_feat[f, m]
        quad += 2.0 * t
    for f in range(V.shape[0]):
        for i in range(3):
            for m in range(3):
                quad += x_feat[f, i] * V[f, i, m] * x_feat[f, m]
    return quad


def quadratic_form(U: FloatArray, pair_rows: IntArray, pair_cols: IntArray, W: FloatArray,
                   V: FloatArray, x_pose: FloatArray, x_feat: FloatArray, feat_idx: IntArray,
                   obs_block: IntArray) -> float:
    """Return x^T H x for H held as upper pair blocks U, W and V."""
    return float(_quadratic_form(U, pair_rows, pair_cols, W, V, np.ascontiguousarray(x_pose),
                                 np.ascontiguousarray(x_feat), feat_idx, obs_block))
