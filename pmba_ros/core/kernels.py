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
"""Compiled loops (numba) for the solver's per-observation work.

The numpy engine forms rays, Jacobian rows, J^T J and the Schur complement from batched
products and 0/1 scatter matrices: a few dozen numpy calls per step whatever the size, which
on a sliding window (a few thousand observations) take more time than the arithmetic. These
loops visit each observation, feature or observation pair once and write in place:

- PMBA rays, camera rays and errors (eqs. 6-8), Jacobian rows (pmba.md §1.6), pixel errors,
  the pixel weights' projection Jacobians and the sphere retraction (eq. 4);
- the robust cost and row weights (loss.py);
- J^T J (U, W, V, g), its Jacobi scaling, V^-1 with the Schur complement and right-hand side,
  the back-substitution and x^T H x (normal_equations.py), and the covisible pose pairs;
- the widest-pair anchor search (conversions.select_anchors).

They are used when numba is installed (the ``fast`` extra) and give the numpy code's results
to rounding: the tests run both. ``PMBA_NUMBA=0`` turns them off (:mod:`jit`). Each jitted
loop has a typed wrapper without the underscore; the numpy functions they replace stay the
reference.

Block addressing: ``pair_index[a, b]`` (a <= b) is the row of the upper pair block (a, b) in
``U``; a pair (a, b) with a > b is stored transposed at ``pair_index[b, a]``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import jit
from pmba_ros.core.jacobian import ANCHOR_START

#: Whether the compiled loops are used (numba importable and not turned off).
ENABLED = jit.NUMBA is not None
#: Guard for |t x u| = 0 (ray exactly along the baseline) and |N| = 0; pmba.md §1.3.
TINY = 1e-300
#: Largest number of free pose blocks for the compiled loops: their (n, n) pair index
#: stays under 75 MB; larger problems take the numpy path.
MAX_BLOCKS = 3000
_jit = jit.jit


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
              g_pose: Any, g_feat: Any) -> None:
    """J^T [J | r] of every observation into U, W, V, g (zeroed by the caller).

    As in the numpy assembly, the observer's rows are formed per observation and the rows
    of the residual, the feature and the anchors summed per feature (Q) and added once.
    """
    width = E.shape[2]
    n_anchor = anchor_lo.shape[0]
    P = np.empty((6, width))        # observer rows of one observation
    Q = np.empty((width - 6, width - 6))
    for f in range(starts.shape[0] - 1):
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


@_jit
def _schur(W: Any, V_inv: Any, starts: Any, w_block: Any, pair_index: Any, out: Any,
           sign: float) -> None:
    """Add sign W_a V^-1 W_b^T of every feature's observation pairs (a <= b) to ``out``."""
    longest = 0
    for f in range(starts.shape[0] - 1):
        longest = max(longest, starts[f + 1] - starts[f])
    Y = np.empty((longest, 3, 6))                      # V^-1 W^T of each observation
    for f in range(starts.shape[0] - 1):
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
    U = np.zeros((n_pairs, 6, 6))
    W = np.zeros((K, 6, 3))
    V = np.zeros((N, 3, 3))
    g_pose = np.zeros((n_blocks, 6))
    g_feat = np.zeros((N, 3))
    _assemble(np.ascontiguousarray(E), starts, obs_block, anchor_block, anchor_obs,
              anchor_lo, anchor_w, pair_index, U, W, V, g_pose, g_feat)
    return U, W, V, g_pose, g_feat


@_jit
def _cross_into(out: Any, a0: float, a1: float, a2: float, b0: float, b1: float,
                b2: float) -> None:
    """Write a x b to ``out``, a row or column view of length 3."""
    out[0] = a1 * b2 - a2 * b1
    out[1] = a2 * b0 - a0 * b2
    out[2] = a0 * b1 - a1 * b0


@_jit
def _pmba_rows(cam_idx: Any, feat_idx: Any, main_idx: Any, is_main: Any, R_wc: Any, v: Any,
               N_hat: Any, norm: Any, d_mi: Any, n: Any, u: Any, g: Any, sin_t: Any,
               cos_t: Any, dg_du: Any, dg_dt: Any, dth_u: Any, Rm_hat_n: Any, A_f: Any,
               weights: Any, rays_c: Any, E: Any) -> None:
    """Residual and Jacobian rows of PMBA observations; see residuals.ray_jacobians."""
    K, d, width = E.shape
    weighted = weights.shape[0] > 0
    L = np.empty((d, 3))
    B = np.empty((d, 3))
    Lu = np.empty(d)
    LdN = np.empty((d, 3))
    nA = np.empty((3, 2))
    for k in range(K):
        j = feat_idx[k]
        R = R_wc[cam_idx[k]]
        nh0, nh1, nh2 = N_hat[k, 0], N_hat[k, 1], N_hat[k, 2]
        inv = 1.0 / norm[k]
        e = E[k]
        for r in range(d):
            if weighted:
                for c in range(3):
                    B[r, c] = (weights[k, r, 0] * R[c, 0] + weights[k, r, 1] * R[c, 1]
                               + weights[k, r, 2] * R[c, 2])
                e[r, 6] = (weights[k, r, 0] * (rays_c[k, 0] - v[k, 0])
                           + weights[k, r, 1] * (rays_c[k, 1] - v[k, 1])
                           + weights[k, r, 2] * (rays_c[k, 2] - v[k, 2]))
                _cross_into(e[r], weights[k, r, 0], weights[k, r, 1], weights[k, r, 2],
                            rays_c[k, 0], rays_c[k, 1], rays_c[k, 2])   # d e / d phi_i
            else:
                for c in range(3):
                    B[r, c] = 1.0 if r == c else 0.0
                e[r, 6] = N_hat[k, r] - (R[r, 0] * v[k, 0] + R[r, 1] * v[k, 1]
                                         + R[r, 2] * v[k, 2])
                _cross_into(e[r], R[r, 0], R[r, 1], R[r, 2], v[k, 0], v[k, 1], v[k, 2])
            bn = B[r, 0] * nh0 + B[r, 1] * nh1 + B[r, 2] * nh2
            L[r, 0] = (B[r, 0] - bn * nh0) * inv
            L[r, 1] = (B[r, 1] - bn * nh1) * inv
            L[r, 2] = (B[r, 2] - bn * nh2) * inv
        if is_main[k]:
            # The main anchor's own observation: closed forms of pmba.md §1.6.
            sgn = 1.0 if g[j] >= 0.0 else -1.0
            for q in range(2):
                _cross_into(nA[:, q], n[j, 0], n[j, 1], n[j, 2], A_f[j, 0, q], A_f[j, 1, q],
                            A_f[j, 2, q])
            Rm = R_wc[main_idx[j]]
            for r in range(d):
                for c in range(width):
                    if c != 6 and (c >= 3 or weighted):
                        e[r, c] = 0.0
                for c in range(3):
                    if not weighted:
                        e[r, c] -= sgn * Rm_hat_n[j, r, c]
                for q in range(2):
                    acc = 0.0
                    for c in range(3):
                        m = weights[k, r, c] if weighted else Rm[r, c]
                        acc += m * nA[c, q]
                    e[r, 8 + q] = -sgn * acc
            continue
        s_t, c_t, g_j = sin_t[j], cos_t[j], g[j]
        for r in range(d):
            Lu[r] = L[r, 0] * u[j, 0] + L[r, 1] * u[j, 1] + L[r, 2] * u[j, 2]
            acc = 0.0
            for c in range(3):
                LdN[r, c] = g_j * L[r, c] + Lu[r] * dg_du[j, c]
                acc += L[r, c] * (dth_u[j, c] + c_t * d_mi[k, c])
                L_u_dgdt = Lu[r] * dg_dt[j, c]
                e[r, 3 + c] = -s_t * L[r, c]
                e[r, 13 + c] = L_u_dgdt + s_t * L[r, c]
                e[r, 16 + c] = -L_u_dgdt
            e[r, 7] = acc
            for c in range(3):
                e[r, 10 + c] = -(LdN[r, 0] * Rm_hat_n[j, 0, c] + LdN[r, 1] * Rm_hat_n[j, 1, c]
                                 + LdN[r, 2] * Rm_hat_n[j, 2, c])
            for q in range(2):
                e[r, 8 + q] = (e[r, 10] * A_f[j, 0, q] + e[r, 11] * A_f[j, 1, q]
                               + e[r, 12] * A_f[j, 2, q])


@_jit
def _tangent_basis_into(n0: float, n1: float, n2: float, A: Any) -> None:
    """Write sphere.tangent_basis of n to A (3, 2): a1 = xi(e_k x n), a2 = n x a1.

    e_k is the axis least aligned with n (the first on ties, as numpy's argmin).
    """
    k = 0
    if abs(n1) < abs(n0):
        k = 1
    if abs(n2) < abs((n0, n1)[k]):
        k = 2
    a0, a1, a2 = (0.0, -n2, n1) if k == 0 else ((n2, 0.0, -n0) if k == 1 else (-n1, n0, 0.0))
    na = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    if na > 0.0:
        a0, a1, a2 = a0 / na, a1 / na, a2 / na
    A[0, 0], A[1, 0], A[2, 0] = a0, a1, a2
    A[0, 1] = n1 * a2 - n2 * a1
    A[1, 1] = n2 * a0 - n0 * a2
    A[2, 1] = n0 * a1 - n1 * a0


@_jit
def _pmba_feature_factors(R_wc: Any, n: Any, main_idx: Any, u: Any, t: Any, s: Any, c: Any,
                          sin_t: Any, cos_t: Any, Rm_hat_n: Any, A_f: Any, dg_du: Any,
                          dg_dt: Any, dth_u: Any) -> None:
    """Compute the per-feature factors of residuals.ray_jacobians.

    R_m [n]x, A_n (as sphere.tangent_basis), dg/du, dg/dt and -(s sin(theta) + c cos(theta)) u.
    """
    for j in range(n.shape[0]):
        R = R_wc[main_idx[j]]
        n0, n1, n2 = n[j, 0], n[j, 1], n[j, 2]
        for r in range(3):
            _cross_into(Rm_hat_n[j, r], R[r, 0], R[r, 1], R[r, 2], n0, n1, n2)
        _tangent_basis_into(n0, n1, n2, A_f[j])
        cos_over_s = cos_t[j] / max(s[j], TINY)
        D_sq = t[j, 0] * t[j, 0] + t[j, 1] * t[j, 1] + t[j, 2] * t[j, 2]
        for r in range(3):
            dg_du[j, r] = cos_over_s * (D_sq * u[j, r] - c[j] * t[j, r]) - sin_t[j] * t[j, r]
            dg_dt[j, r] = cos_over_s * (t[j, r] - c[j] * u[j, r]) - sin_t[j] * u[j, r]
            dth_u[j, r] = -(s[j] * sin_t[j] + c[j] * cos_t[j]) * u[j, r]


def pmba_rows(obs: Any, feats: Any, R_wc: FloatArray, geo: Any, weights: FloatArray | None,
              rays_c: FloatArray | None, E: FloatArray) -> None:
    """Fill E (K, d, 19) with the PMBA rows of residuals.ray_jacobians."""
    N = feats.n.shape[0]
    Rm_hat_n = np.empty((N, 3, 3))
    A_f = np.empty((N, 3, 2))
    dg_du, dg_dt, dth_u = np.empty((N, 3)), np.empty((N, 3)), np.empty((N, 3))
    R_wc = np.ascontiguousarray(R_wc)
    _pmba_feature_factors(R_wc, feats.n, feats.main_idx, geo.u, geo.t, geo.s, geo.c,
                          geo.sin_t, geo.cos_t, Rm_hat_n, A_f, dg_du, dg_dt, dth_u)
    _pmba_rows(obs.cam_idx, obs.feat_idx, feats.main_idx, geo.main, R_wc, obs.bearings_c,
               geo.N_hat, geo.norm, geo.P_m_minus_P_i, feats.n, geo.u, geo.g, geo.sin_t,
               geo.cos_t, dg_du, dg_dt, dth_u, Rm_hat_n, A_f,
               np.zeros((0, 2, 3)) if weights is None else weights,
               geo.N_hat if rays_c is None else rays_c, E)


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
def _reduce(U: Any, W: Any, V: Any, damp_feat: Any, g_pose: Any, g_feat: Any, starts: Any,
            w_block: Any, pair_index: Any, V_inv: Any, S: Any, rhs: Any) -> int:
    """Schur complement of the damped feature blocks; returns -1, or the singular feature.

    S = U - sum_f W_f V_f^-1 W_f^T (upper pair blocks) and rhs = -g_T + W V^-1 g_F.
    """
    A = np.empty((3, 3))
    Vg = np.empty(3)
    S[:] = U
    for b in range(rhs.shape[0]):
        for i in range(6):
            rhs[b, i] = -g_pose[b, i]
    for f in range(starts.shape[0] - 1):
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
    _schur(W, V_inv, starts, w_block, pair_index, S, -1.0)
    return -1


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


def scale_w(W: FloatArray, feat_idx: IntArray, obs_block: IntArray, c_pose: FloatArray,
            c_feat: FloatArray) -> None:
    """Scale the W blocks in place by their pose and feature column scales."""
    _scale_w(W, feat_idx, obs_block, c_pose, c_feat)


def reduce(U: FloatArray, W: FloatArray, V: FloatArray, damp_feat: FloatArray,
           g_pose: FloatArray, g_feat: FloatArray, starts: IntArray, obs_block: IntArray,
           pair_index: IntArray) -> tuple[FloatArray, FloatArray, FloatArray, int]:
    """Return S (upper pair blocks), the right-hand side, V^-1, and -1 or a singular feature."""
    V_inv = np.empty_like(V)
    S = np.empty_like(U)
    rhs = np.empty_like(g_pose)
    bad = _reduce(U, W, V, damp_feat, g_pose, g_feat, starts, obs_block, pair_index, V_inv,
                  S, rhs)
    return S, rhs, V_inv, int(bad)


def back_substitute(W: FloatArray, V_inv: FloatArray, g_feat: FloatArray,
                    x_pose: FloatArray, starts: IntArray, obs_block: IntArray) -> FloatArray:
    """Return x_F = V^-1 (-g_F - W^T x_T)."""
    x_feat = np.empty_like(g_feat)
    _back_substitute(W, V_inv, g_feat, np.ascontiguousarray(x_pose), starts, obs_block, x_feat)
    return x_feat


def quadratic_form(U: FloatArray, pair_rows: IntArray, pair_cols: IntArray, W: FloatArray,
                   V: FloatArray, x_pose: FloatArray, x_feat: FloatArray, feat_idx: IntArray,
                   obs_block: IntArray) -> float:
    """Return x^T H x for H held as upper pair blocks U, W and V."""
    return float(_quadratic_form(U, pair_rows, pair_cols, W, V, np.ascontiguousarray(x_pose),
                                 np.ascontiguousarray(x_feat), feat_idx, obs_block))


@_jit
def _pmba_rays(R_wc: Any, centers_w: Any, theta: Any, n: Any, main_idx: Any, assoc_idx: Any,
               cam_idx: Any, feat_idx: Any, v: Any, weights: Any, u: Any, t: Any, s: Any,
               c: Any, g: Any, sin_t: Any, cos_t: Any, N: Any, d: Any, N_hat: Any, norm: Any,
               main: Any, rays_c: Any, res: Any) -> None:
    """Rays N = g u + sin(theta) (P_m - P_i) (PMBA eq. 6), R_i^T xi(N) and the errors (eq. 8)."""
    for j in range(theta.shape[0]):
        m, a = main_idx[j], assoc_idx[j]
        for r in range(3):
            u[j, r] = R_wc[m, r, 0] * n[j, 0] + R_wc[m, r, 1] * n[j, 1] + R_wc[m, r, 2] * n[j, 2]
            t[j, r] = centers_w[m, r] - centers_w[a, r]
        x0 = t[j, 1] * u[j, 2] - t[j, 2] * u[j, 1]
        x1 = t[j, 2] * u[j, 0] - t[j, 0] * u[j, 2]
        x2 = t[j, 0] * u[j, 1] - t[j, 1] * u[j, 0]
        s[j] = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        c[j] = t[j, 0] * u[j, 0] + t[j, 1] * u[j, 1] + t[j, 2] * u[j, 2]
        sin_t[j], cos_t[j] = np.sin(theta[j]), np.cos(theta[j])
        g[j] = s[j] * cos_t[j] - c[j] * sin_t[j]
    weighted = weights.shape[0] > 0
    for k in range(cam_idx.shape[0]):
        j, i = feat_idx[k], cam_idx[k]
        m = main_idx[j]
        sq = 0.0
        for r in range(3):
            d[k, r] = centers_w[m, r] - centers_w[i, r]
            N[k, r] = g[j] * u[j, r] + sin_t[j] * d[k, r]
            sq += N[k, r] * N[k, r]
        norm[k] = max(np.sqrt(sq), TINY)
        main[k] = i == m
        # The main anchor's ray is exactly sign(g) u (no cancellation in g u + 0).
        sgn = 1.0 if g[j] >= 0.0 else -1.0
        for r in range(3):
            N_hat[k, r] = sgn * u[j, r] if main[k] else N[k, r] / norm[k]
        for r in range(3):
            rays_c[k, r] = (R_wc[i, 0, r] * N_hat[k, 0] + R_wc[i, 1, r] * N_hat[k, 1]
                            + R_wc[i, 2, r] * N_hat[k, 2])
        for r in range(res.shape[1]):
            if weighted:
                res[k, r] = (weights[k, r, 0] * (rays_c[k, 0] - v[k, 0])
                             + weights[k, r, 1] * (rays_c[k, 1] - v[k, 1])
                             + weights[k, r, 2] * (rays_c[k, 2] - v[k, 2]))
            else:
                res[k, r] = N_hat[k, r] - (R_wc[i, r, 0] * v[k, 0] + R_wc[i, r, 1] * v[k, 1]
                                           + R_wc[i, r, 2] * v[k, 2])


def pmba_rays(R_wc: FloatArray, centers_w: FloatArray, feats: Any, obs: Any,
              weights: FloatArray | None) -> tuple[tuple[Any, ...], FloatArray, FloatArray]:
    """Return the fields of residuals.RayGeometry, the camera rays and the residuals."""
    N_f, K = feats.theta.shape[0], obs.cam_idx.shape[0]
    per_feat = [np.empty((N_f, 3)), np.empty((N_f, 3))] + [np.empty(N_f) for _ in range(5)]
    N, d, N_hat, rays_c = (np.empty((K, 3)) for _ in range(4))
    norm = np.empty(K)
    main = np.empty(K, dtype=np.bool_)
    res = np.empty((K, 3 if weights is None else 2))
    _pmba_rays(np.ascontiguousarray(R_wc), np.ascontiguousarray(centers_w), feats.theta,
               feats.n, feats.main_idx, feats.assoc_idx, obs.cam_idx, obs.feat_idx,
               obs.bearings_c, np.zeros((0, 2, 3)) if weights is None else weights, *per_feat,
               N, d, N_hat, norm, main, rays_c, res)
    return (*per_feat, N, d, N_hat, norm, main), rays_c, res


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


@_jit
def _reprojection_errors(rays_c: Any, fx: Any, fy: Any, cx: Any, cy: Any, k1: Any, k2: Any,
                         cam_idx: Any, pixels: Any, out: Any) -> None:
    """|pi(h) - (u, v)| per observation, pi as camera.project (radial k1, k2)."""
    for k in range(rays_c.shape[0]):
        i = cam_idx[k]
        z = rays_c[k, 2]
        if abs(z) < 1e-300:
            z = 1e-300
        x, y = rays_c[k, 0] / z, rays_c[k, 1] / z
        r2 = x * x + y * y
        dist = 1.0 + k1[i] * r2 + k2[i] * r2 * r2
        du = fx[i] * dist * x + cx[i] - pixels[k, 0]
        dv = fy[i] * dist * y + cy[i] - pixels[k, 1]
        out[k] = np.sqrt(du * du + dv * dv)


def reprojection_errors(rays_c: FloatArray, intr: Any, cam_idx: IntArray,
                        pixels: FloatArray) -> FloatArray:
    """Return the pixel reprojection error of camera-frame rays, shape (K,)."""
    out = np.empty(rays_c.shape[0])
    _reprojection_errors(rays_c, intr.fx, intr.fy, intr.cx, intr.cy, intr.k1, intr.k2, cam_idx,
                         pixels, out)
    return out


@_jit
def _sphere_retract(n: Any, delta: Any, out: Any) -> None:
    """Retract unit rays: xi(cos(phi) n + sin(phi)/phi A_n (d2, -d1)), phi = |delta|."""
    A = np.empty((3, 2))
    for j in range(n.shape[0]):
        _tangent_basis_into(n[j, 0], n[j, 1], n[j, 2], A)
        d0, d1 = delta[j, 0], delta[j, 1]
        phi_sq = d0 * d0 + d1 * d1
        if phi_sq < 1e-12:
            sinc = 1.0 - phi_sq / 6.0
        else:
            sinc = np.sin(np.sqrt(phi_sq)) / np.sqrt(phi_sq)
        cos_phi = np.cos(np.sqrt(phi_sq))
        sq = 0.0
        for r in range(3):
            out[j, r] = cos_phi * n[j, r] + sinc * (A[r, 0] * d1 - A[r, 1] * d0)
            sq += out[j, r] * out[j, r]
        if sq > 0.0:
            inv = 1.0 / np.sqrt(sq)
            for r in range(3):
                out[j, r] *= inv


def sphere_retract(n: FloatArray, delta: FloatArray) -> FloatArray:
    """Return Exp(A_n delta) n for unit vectors n (N, 3) and delta (N, 2) (PMBA eq. 4)."""
    out = np.empty_like(n)
    _sphere_retract(np.ascontiguousarray(n), np.ascontiguousarray(delta), out)
    return out


@_jit
def _projection_jacobian(h_c: Any, fx: Any, fy: Any, k1: Any, k2: Any, cam_idx: Any,
                         out: Any) -> None:
    """Write d pi / d h of camera.project at each h_c (radial k1, k2) to out (K, 2, 3)."""
    for k in range(h_c.shape[0]):
        i = cam_idx[k]
        z = h_c[k, 2]
        if abs(z) < 1e-300:
            z = 1e-300
        inv_z = 1.0 / z
        x, y = h_c[k, 0] * inv_z, h_c[k, 1] * inv_z
        r2 = x * x + y * y
        dist = 1.0 + k1[i] * r2 + k2[i] * r2 * r2
        dd = 2.0 * (k1[i] + 2.0 * k2[i] * r2)
        a, b = fx[i] * (dist + dd * x * x), fx[i] * dd * x * y
        c, e = fy[i] * dd * x * y, fy[i] * (dist + dd * y * y)
        # [[a, b], [c, e]] times [[1/z, 0, -x/z], [0, 1/z, -y/z]].
        out[k, 0, 0], out[k, 0, 1], out[k, 0, 2] = a * inv_z, b * inv_z, -(a * x + b * y) * inv_z
        out[k, 1, 0], out[k, 1, 1], out[k, 1, 2] = c * inv_z, e * inv_z, -(c * x + e * y) * inv_z


def projection_jacobian(h_c: FloatArray, intr: Any, cam_idx: IntArray) -> FloatArray:
    """Return d(pixel)/d(h_c) (K, 2, 3) of camera.project (camera.projection_jacobian's)."""
    out = np.empty((h_c.shape[0], 2, 3))
    _projection_jacobian(np.ascontiguousarray(h_c), intr.fx, intr.fy, intr.k1, intr.k2,
                         cam_idx, out)
    return out


#: Loss codes of the compiled robust loops (loss.Loss order: none, huber, cauchy).
LOSS_CODES = {'none': 0, 'huber': 1, 'cauchy': 2}


@_jit
def _rho(z: float, code: int) -> tuple[float, float]:
    """Return rho(z) and rho'(z) of a unit-scale loss (loss.rho)."""
    if code == 1:
        if z <= 1.0:
            return z, 1.0
        root = np.sqrt(z)
        return 2.0 * root - 1.0, 1.0 / root
    if code == 2:
        return np.log1p(z), 1.0 / (1.0 + z)
    return z, 1.0


@_jit
def _robust_cost(res: Any, code: int, scale: float) -> float:
    """1/2 sum a^2 rho(|e|^2 / a^2), or inf if a residual is not finite."""
    a2 = scale * scale
    total = 0.0
    for k in range(res.shape[0]):
        sq = 0.0
        for r in range(res.shape[1]):
            sq += res[k, r] * res[k, r]
        if not np.isfinite(sq):
            return np.inf
        total += _rho(sq / a2, code)[0] * a2
    return 0.5 * total


@_jit
def _robust_scale_rows(E: Any, code: int, scale: float) -> None:
    """Scale each observation's rows (residual column 6 included) by sqrt(rho'(|e|^2))."""
    a2 = scale * scale
    for k in range(E.shape[0]):
        sq = 0.0
        for r in range(E.shape[1]):
            sq += E[k, r, 6] * E[k, r, 6]
        w = np.sqrt(_rho(sq / a2, code)[1])
        for r in range(E.shape[1]):
            for c in range(E.shape[2]):
                E[k, r, c] *= w


def robust_cost(residuals: FloatArray, loss: str, scale: float) -> float:
    """Return loss.robust_cost of residuals (K, d), inf if one is not finite."""
    return float(_robust_cost(residuals, LOSS_CODES[loss], scale))


def robust_scale_rows(E: FloatArray, loss: str, scale: float) -> None:
    """Scale Jacobian rows E (K, d, w) in place by loss.robust_weights of their residuals."""
    _robust_scale_rows(E, LOSS_CODES[loss], scale)
