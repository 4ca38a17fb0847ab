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
"""Compiled Schur complement on the poses: V^-1, S and its right-hand side, back-substitution.

Mirrors :func:`pmba_ros.core.normal_equations.solve_schur`'s reduction; pair blocks are
addressed as in :mod:`pmba_ros.core.compiled.assembly`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import jit
from pmba_ros.core.compiled import chunks

_jit = jit.jit


@_jit
def _schur(W: Any, V_inv: Any, starts: Any, w_block: Any, pair_index: Any, out: Any,
           sign: float, f0: int, f1: int) -> None:
    """Add sign W_a V^-1 W_b^T of features f0..f1-1's observation pairs (a <= b) to ``out``."""
    longest = 0
    for f in range(f0, f1):
        longest = max(longest, starts[f + 1] - starts[f])
    Y = np.empty((longest, 3, 6))                      # V^-1 W^T of each observation
    for f in range(f0, f1):
        lo, hi = starts[f], starts[f + 1]
        for a in range(hi - lo):
            for r in range(3):
                for k in range(6):
                    Y[a, r, k] = sign * (V_inv[f, r, 0] * W[lo + a, k, 0]
                                         + V_inv[f, r, 1] * W[lo + a, k, 1]
                                         + V_inv[f, r, 2] * W[lo + a, k, 2])
        for a in range(hi - lo):
            ba = w_block[lo + a]
            if ba < 0:
                continue
            for b in range(a, hi - lo):
                bb = w_block[lo + b]
                if bb < 0:
                    continue
                y0, y1, y2 = Y[b, 0], Y[b, 1], Y[b, 2]
                if ba <= bb:
                    # Observations run in camera order, so this is the usual case: written
                    # out per column, the products stay in registers.
                    p = pair_index[ba, bb]
                    for i in range(6):
                        w0, w1, w2 = W[lo + a, i, 0], W[lo + a, i, 1], W[lo + a, i, 2]
                        o = out[p, i]
                        o[0] += w0 * y0[0] + w1 * y1[0] + w2 * y2[0]
                        o[1] += w0 * y0[1] + w1 * y1[1] + w2 * y2[1]
                        o[2] += w0 * y0[2] + w1 * y1[2] + w2 * y2[2]
                        o[3] += w0 * y0[3] + w1 * y1[3] + w2 * y2[3]
                        o[4] += w0 * y0[4] + w1 * y1[4] + w2 * y2[4]
                        o[5] += w0 * y0[5] + w1 * y1[5] + w2 * y2[5]
                if ba > bb or (ba == bb and a != b):
                    p = pair_index[min(ba, bb), max(ba, bb)]
                    for i in range(6):
                        w0, w1, w2 = W[lo + a, i, 0], W[lo + a, i, 1], W[lo + a, i, 2]
                        for k in range(6):
                            out[p, k, i] += w0 * y0[k] + w1 * y1[k] + w2 * y2[k]


@_jit
def _inverse3(A: Any, out: Any) -> bool:
    """Write A^-1 of a 3x3 matrix (by its adjugate) to out; False if A is singular."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    if not (abs(det) > 0.0 and np.isfinite(det)):
        return False
    inv = 1.0 / det
    out[0, 0] = c00 * inv
    out[1, 0] = c01 * inv
    out[2, 0] = c02 * inv
    out[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) * inv
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) * inv
    out[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) * inv
    out[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) * inv
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) * inv
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) * inv
    return True


@_jit
def _reduce(W: Any, V: Any, damp_feat: Any, g_feat: Any, starts: Any, w_block: Any,
            pair_index: Any, V_inv: Any, S: Any, rhs: Any, f0: int, f1: int) -> int:
    """Schur terms of the damped feature blocks f0..f1-1; returns -1, or a singular feature.

    Adds -sum_f W_f V_f^-1 W_f^T to S (upper pair blocks) and W V^-1 g_F to rhs, which
    start at U and -g_T (or at zero, for a chunk's own copy).
    """
    A = np.empty((3, 3))
    Vg = np.empty(3)
    for f in range(f0, f1):
        for i in range(3):
            for m in range(3):
                A[i, m] = V[f, i, m]
            A[i, i] += damp_feat[f, i]
        if not _inverse3(A, V_inv[f]):
            return f
        for i in range(3):
            Vg[i] = V_inv[f, i, 0] * g_feat[f, 0] + V_inv[f, i, 1] * g_feat[f, 1] \
                + V_inv[f, i, 2] * g_feat[f, 2]
        for k in range(starts[f], starts[f + 1]):
            b = w_block[k]
            if b >= 0:
                for i in range(6):
                    rhs[b, i] += W[k, i, 0] * Vg[0] + W[k, i, 1] * Vg[1] + W[k, i, 2] * Vg[2]
    _schur(W, V_inv, starts, w_block, pair_index, S, -1.0, f0, f1)
    return -1


def _schur_work(starts: IntArray) -> FloatArray:
    """Return each feature's share of the Schur terms: they grow with its observations squared."""
    per_feature = np.diff(starts).astype(float)
    out: FloatArray = per_feature * (per_feature + 1.0)
    return out


def reduce(U: FloatArray, W: FloatArray, V: FloatArray, damp_feat: FloatArray,
           g_pose: FloatArray, g_feat: FloatArray, starts: IntArray, obs_block: IntArray,
           pair_index: IntArray) -> tuple[FloatArray, FloatArray, FloatArray, int]:
    """Return S (upper pair blocks), the right-hand side, V^-1, and -1 or a singular feature."""
    n = chunks.threads_for(W.shape[0], U.nbytes + g_pose.nbytes)
    V_inv = np.empty_like(V)
    # Pose blocks are shared between features: chunks after the first fill their own.
    S = [U.copy(), *(np.zeros_like(U) for _ in range(1, n))]
    rhs = [-g_pose, *(np.zeros_like(g_pose) for _ in range(1, n))]
    cut = chunks.cuts(n, starts.shape[0] - 1, lambda: _schur_work(starts))
    bad = chunks.run(lambda t: int(_reduce(W, V, damp_feat, g_feat, starts, obs_block,
                                           pair_index, V_inv, S[t], rhs[t], int(cut[t]),
                                           int(cut[t + 1]))), n)
    for t in range(1, n):
        S[0] += S[t]
        rhs[0] += rhs[t]
    return S[0], rhs[0], V_inv, next((b for b in bad if b >= 0), -1)


@_jit
def _back_substitute(W: Any, V_inv: Any, g_feat: Any, x_pose: Any, starts: Any,
                     w_block: Any, x_feat: Any) -> None:
    """x_F = V^-1 (-g_F - W^T x_T), feature by feature."""
    r = np.empty(3)
    for f in range(starts.shape[0] - 1):
        for m in range(3):
            r[m] = -g_feat[f, m]
        for k in range(starts[f], starts[f + 1]):
            b = w_block[k]
            if b < 0:
                continue
            for m in range(3):
                acc = 0.0
                for i in range(6):
                    acc += W[k, i, m] * x_pose[b, i]
                r[m] -= acc
        for i in range(3):
            x_feat[f, i] = V_inv[f, i, 0] * r[0] + V_inv[f, i, 1] * r[1] + V_inv[f, i, 2] * r[2]


def back_substitute(W: FloatArray, V_inv: FloatArray, g_feat: FloatArray,
                    x_pose: FloatArray, starts: IntArray, obs_block: IntArray) -> FloatArray:
    """Return x_F = V^-1 (-g_F - W^T x_T)."""
    x_feat = np.empty_like(g_feat)
    _back_substitute(W, V_inv, g_feat, np.ascontiguousarray(x_pose), starts, obs_block, x_feat)
    return x_feat
