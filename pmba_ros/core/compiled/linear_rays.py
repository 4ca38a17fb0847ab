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
"""Compiled normal matrix of the linearised rays (mirrors ``init.cls.LinearRays``).

The position steps of the global initialization (CLS, eq. 14, and NLS, eq. 13) assemble
sum_k G_k^T A_k G_k over all observations at every iteration, with G_k = dN-bar_k / dP: the
blocks -sin(theta_j) I on the observer P_i and C_a, C_m on the anchors P_a, P_m of feature j.
The sum goes into the non-zero 3x3 blocks only (their slots come from
``init.normal_blocks.block_pattern``); the dense or sparse matrix is built from them.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import jit

_jit = jit.jit


@_jit
def _ray_normal_matrix(feat: Any, coeff: Any, sin_t: Any, A: Any, slot_obs: Any,
                       slot_cross: Any, slot_anchor: Any, blocks: Any) -> None:
    """Add sum_k G_k^T A_k G_k to the non-zero 3x3 ``blocks`` (B, 3, 3) of their slots.

    The observer's blocks are added per observation, the anchors' once per feature from the
    sum B_j of its observations' A_k.
    """
    B = np.zeros((coeff.shape[0], 3, 3))
    for k in range(feat.shape[0]):
        j = feat[k]
        s = sin_t[j]
        d = slot_obs[k]
        for r in range(3):
            for c in range(3):
                B[j, r, c] += A[k, r, c]
                blocks[d, r, c] += s * s * A[k, r, c]
        for t in range(2):
            ia, ai = slot_cross[k, t, 0], slot_cross[k, t, 1]
            for r in range(3):
                for c in range(3):
                    v = -s * (A[k, r, 0] * coeff[j, t, 0, c] + A[k, r, 1] * coeff[j, t, 1, c]
                              + A[k, r, 2] * coeff[j, t, 2, c])
                    blocks[ia, r, c] += v
                    blocks[ai, c, r] += v
    for j in range(coeff.shape[0]):
        for t in range(2):
            for u in range(2):
                b = slot_anchor[j, t, u]
                for r in range(3):
                    for c in range(3):
                        v = 0.0
                        for p in range(3):
                            for q in range(3):
                                v += coeff[j, t, p, r] * B[j, p, q] * coeff[j, u, q, c]
                        blocks[b, r, c] += v


def ray_normal_blocks(feat: IntArray, coeff: FloatArray, sin_t: FloatArray, A: FloatArray,
                      slot_obs: IntArray, slot_cross: IntArray, slot_anchor: IntArray,
                      n_blocks: int) -> FloatArray:
    """Return the (B, 3, 3) blocks of sum_k G_k^T A_k G_k (``init.cls.LinearRays``).

    ``slot_*`` as in ``init.normal_blocks.BlockPattern``.
    """
    blocks = np.zeros((n_blocks, 3, 3))
    _ray_normal_matrix(feat, np.ascontiguousarray(coeff), sin_t, np.ascontiguousarray(A),
                       slot_obs, slot_cross, slot_anchor, blocks)
    return blocks


@_jit
def _ray_gradient(cam: Any, feat: Any, assoc: Any, main: Any, coeff: Any, sin_t: Any, y: Any,
                  g: Any) -> None:
    """Write sum_k G_k^T y_k to g (3M,), summed in the numpy reference's order."""
    n_cams = g.shape[0] // 3
    g_cam = np.zeros((n_cams, 3))
    Y = np.zeros((coeff.shape[0], 3))
    for k in range(cam.shape[0]):
        j, i = feat[k], cam[k]
        s = sin_t[j]
        for r in range(3):
            g_cam[i, r] += -s * y[k, r]
            Y[j, r] += y[k, r]
    g_a = np.zeros((n_cams, 3))
    g_m = np.zeros((n_cams, 3))
    for j in range(coeff.shape[0]):
        a, m = assoc[j], main[j]
        for c in range(3):
            g_a[a, c] += (coeff[j, 0, 0, c] * Y[j, 0] + coeff[j, 0, 1, c] * Y[j, 1]
                          + coeff[j, 0, 2, c] * Y[j, 2])
            g_m[m, c] += (coeff[j, 1, 0, c] * Y[j, 0] + coeff[j, 1, 1, c] * Y[j, 1]
                          + coeff[j, 1, 2, c] * Y[j, 2])
    for i in range(n_cams):
        for c in range(3):
            g[3 * i + c] = g_cam[i, c] + (g_a[i, c] + g_m[i, c])


def ray_gradient(cam: IntArray, feat: IntArray, assoc: IntArray, main: IntArray,
                 coeff: FloatArray, sin_t: FloatArray, y: FloatArray, n_cams: int) -> FloatArray:
    """Return sum_k G_k^T y_k, shape (3M,) (``init.cls.LinearRays.gradient``)."""
    g = np.empty(3 * n_cams)
    _ray_gradient(cam, feat, assoc, main, np.ascontiguousarray(coeff), sin_t,
                  np.ascontiguousarray(y), g)
    return g


@_jit
def _linear_rays(feat: Any, cam: Any, assoc: Any, main: Any, coeff: Any, sin_t: Any, P: Any,
                 N: Any) -> None:
    """Write N-bar_k(P) (K, 3): X_j = C_a P_a + C_m P_m once per feature, then X_j - s_j P_i."""
    X = np.empty((coeff.shape[0], 3))
    for j in range(coeff.shape[0]):
        a, m = assoc[j], main[j]
        for r in range(3):
            # Terms in the order of numpy's einsum over a contiguous axis (0 + 2, then 1), so
            # that both engines agree to the last bit where they can.
            X[j, r] = ((coeff[j, 0, r, 0] * P[a, 0] + coeff[j, 0, r, 2] * P[a, 2]
                        + coeff[j, 0, r, 1] * P[a, 1])
                       + (coeff[j, 1, r, 0] * P[m, 0] + coeff[j, 1, r, 2] * P[m, 2]
                          + coeff[j, 1, r, 1] * P[m, 1]))
    for k in range(feat.shape[0]):
        j, i = feat[k], cam[k]
        s = sin_t[j]
        for r in range(3):
            N[k, r] = X[j, r] - s * P[i, r]


def linear_ray_values(cam: IntArray, feat: IntArray, assoc: IntArray, main: IntArray,
                      coeff: FloatArray, sin_t: FloatArray, centers_w: FloatArray,
                      ) -> FloatArray:
    """Return N-bar_k(P), shape (K, 3) (``init.cls.LinearRays.evaluate``)."""
    N = np.empty((feat.shape[0], 3))
    _linear_rays(feat, cam, assoc, main, np.ascontiguousarray(coeff), sin_t,
                 np.array(centers_w, dtype=float), N)
    return N


@_jit
def _ray_errors(feat: Any, cam: Any, assoc: Any, main: Any, coeff: Any, sin_t: Any,
                rays: Any, P: Any, f2: Any, w: Any, N: Any, e: Any, w_rho: Any) -> None:
    """Write N-bar_k(P), e_k = xi(N-bar_k) - r_k and w_k rho(|e_k|^2) (Cauchy) per observation."""
    _linear_rays(feat, cam, assoc, main, coeff, sin_t, P, N)
    for k in range(feat.shape[0]):
        n0, n1, n2 = N[k, 0], N[k, 1], N[k, 2]
        norm = max(np.sqrt(n0 * n0 + n1 * n1 + n2 * n2), 1e-300)
        e0 = n0 / norm - rays[k, 0]
        e1 = n1 / norm - rays[k, 1]
        e2 = n2 / norm - rays[k, 2]
        e[k, 0], e[k, 1], e[k, 2] = e0, e1, e2
        w_rho[k] = w[k] * (f2[k] * np.log1p((e0 * e0 + e1 * e1 + e2 * e2) / f2[k]))


def ray_errors(cam: IntArray, feat: IntArray, assoc: IntArray, main: IntArray,
               coeff: FloatArray, sin_t: FloatArray, rays: FloatArray, centers_w: FloatArray,
               f2: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return N-bar (K, 3), e (K, 3) and w_k f_k^2 log(1 + |e_k|^2 / f_k^2) (K,) (init.nls).

    ``f2`` and ``w`` hold one squared Cauchy scale and one weight per observation.
    """
    K = feat.shape[0]
    N, e, w_rho = np.empty((K, 3)), np.empty((K, 3)), np.empty(K)
    _ray_errors(feat, cam, assoc, main, np.ascontiguousarray(coeff), sin_t,
                np.ascontiguousarray(rays), np.array(centers_w, dtype=float), f2, w, N, e,
                w_rho)
    return N, e, w_rho


@_jit
def _nls_weights(N: Any, e: Any, f2: Any, w: Any, A: Any, y: Any) -> None:
    """Write the IRLS weights A_k (K, 3, 3) and the gradient terms y_k (K, 3) of eq. (13).

    J_N = (I - N^ N^T) / |N|; with the Cauchy weight w_k rho'(|e_k|^2) = w_k / (1 + |e|^2/f^2):
    A_k = w_k rho' J_N^T J_N and y_k = w_k rho' J_N^T e_k (0 for a weight of 0).
    """
    for k in range(N.shape[0]):
        n0, n1, n2 = N[k, 0], N[k, 1], N[k, 2]
        norm = max(np.sqrt(n0 * n0 + n1 * n1 + n2 * n2), 1e-150)
        h = (n0 / norm, n1 / norm, n2 / norm)
        e0, e1, e2 = e[k, 0], e[k, 1], e[k, 2]
        wk = w[k] * (1.0 / (1.0 + (e0 * e0 + e1 * e1 + e2 * e2) / f2[k]))
        w_n = wk / norm if wk > 0.0 else 0.0
        c = w_n / norm
        for r in range(3):
            p0 = (1.0 if r == 0 else 0.0) - h[r] * h[0]
            p1 = (1.0 if r == 1 else 0.0) - h[r] * h[1]
            p2 = (1.0 if r == 2 else 0.0) - h[r] * h[2]
            A[k, r, 0], A[k, r, 1], A[k, r, 2] = c * p0, c * p1, c * p2
            y[k, r] = w_n * (p0 * e0 + p2 * e2 + p1 * e1)  # einsum's order, as in X


def nls_weights(N: FloatArray, e: FloatArray, f2: FloatArray, w: FloatArray,
                ) -> tuple[FloatArray, FloatArray]:
    """Return the IRLS weights A (K, 3, 3) and gradient terms y (K, 3) of ``init.nls``."""
    K = N.shape[0]
    A, y = np.empty((K, 3, 3)), np.empty((K, 3))
    _nls_weights(N, e, f2, w, A, y)
    return A, y


@_jit
def _ray_depths(feat: Any, cam: Any, assoc: Any, main: Any, coeff: Any, sin_t: Any,
                rays: Any, P: Any, N: Any, depth: Any) -> None:
    """Write r_k . N-bar_k(P) (K,), the cheirality rows of the CLS (eq. 14)."""
    _linear_rays(feat, cam, assoc, main, coeff, sin_t, P, N)
    for k in range(feat.shape[0]):
        depth[k] = rays[k, 0] * N[k, 0] + rays[k, 1] * N[k, 1] + rays[k, 2] * N[k, 2]


def ray_depths(cam: IntArray, feat: IntArray, assoc: IntArray, main: IntArray,
               coeff: FloatArray, sin_t: FloatArray, rays: FloatArray,
               centers_w: FloatArray) -> FloatArray:
    """Return r_k . N-bar_k(P), shape (K,) (``init.cls.LinearRays.depths``)."""
    K = feat.shape[0]
    N, depth = np.empty((K, 3)), np.empty(K)
    _ray_depths(feat, cam, assoc, main, np.ascontiguousarray(coeff), sin_t,
                np.ascontiguousarray(rays), np.array(centers_w, dtype=float), N, depth)
    return depth


@_jit
def _cheirality_row_norms(feat: Any, coeff: Any, sin_t: Any, rays: Any, out: Any) -> None:
    """Write |C_a^T r_k|^2 + |C_m^T r_k|^2 + sin^2(theta-bar) |r_k|^2 (K,)."""
    for k in range(feat.shape[0]):
        j = feat[k]
        r0, r1, r2 = rays[k, 0], rays[k, 1], rays[k, 2]
        total = 0.0
        for t in range(2):
            sq = 0.0
            for i in range(3):
                v = coeff[j, t, 0, i] * r0 + coeff[j, t, 1, i] * r1 + coeff[j, t, 2, i] * r2
                sq += v * v
            total += sq
        s = sin_t[j]
        out[k] = total + s * s * (r0 * r0 + r1 * r1 + r2 * r2)


def cheirality_row_norms(feat: IntArray, coeff: FloatArray, sin_t: FloatArray,
                         rays: FloatArray) -> FloatArray:
    """Return the CLS cheirality rows' squared norms, shape (K,) (``init.cls.LinearRays``)."""
    out = np.empty(feat.shape[0])
    _cheirality_row_norms(feat, np.ascontiguousarray(coeff), sin_t, np.ascontiguousarray(rays),
                          out)
    return out
