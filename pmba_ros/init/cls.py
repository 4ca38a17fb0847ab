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
"""Convex least squares for the camera positions with rotations known (PMBA eq. 14).

With rotations R-bar, parallax angles theta-bar and frames Q_j frozen, the linearised ray of
observation k (feature j, camera i) is linear and homogeneous in the positions (eq. 12)::

    N-bar_k(P) = sin(alpha-bar - theta-bar) Q_j (P_a - P_m) + sin(theta-bar) (P_m - P_i)
               = C_a P_a + C_m P_m + C_i P_i

with C_a = s Q_j, C_m = -s Q_j + sin(theta-bar) I, C_i = -sin(theta-bar) I, s = sin(alpha-bar -
theta-bar). Blocks of the same camera (i = m or i = a) simply add up. Eq. (14) minimises
sum_k ||[r_k]x N-bar_k(P)||^2, r_k = R-bar_i v_k, subject to cheirality.

==========  ============  ==========  ===================================================
paper       code          shape       meaning
==========  ============  ==========  ===================================================
r_k         rays          (K,3)       R-bar_i v_k, measured ray in the world frame
C           coeff         (K,3,3,3)   [slot (a, m, i)] 3x3 blocks of N-bar on P_slot
h_k         (rows)        (K,3,3)     r_k^T C_slot: the cheirality row r_k . N-bar_k(P)
==========  ============  ==========  ===================================================
"""

from __future__ import annotations

from dataclasses import dataclass
import logging

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import so3
from pmba_ros.core.problem import ParallaxFeatures
from pmba_ros.errors import InitError
from pmba_ros.init.anchors import LinearizationFrames
import scipy.linalg

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class LinearRays:
    """Coefficient blocks of the linearised rays N-bar_k(P) of eq. (12).

    Attributes:
        slots: Cameras (a, m, i) of every observation, shape (K, 3).
        coeff: 3x3 blocks of N-bar on P_a, P_m, P_i, shape (K, 3, 3, 3).
        rays: Measured world rays R-bar_i v_k, shape (K, 3).
    """

    slots: IntArray
    coeff: FloatArray
    rays: FloatArray

    def evaluate(self, centers_w: FloatArray) -> FloatArray:
        """Return N-bar_k(P) for camera centres (M, 3), shape (K, 3)."""
        return np.matmul(self.coeff, centers_w[self.slots][..., None]).sum(axis=1)[..., 0]


def linear_rays(R_wc: FloatArray, features: ParallaxFeatures, frames: LinearizationFrames,
                cam_idx: IntArray, feat_idx: IntArray, bearings_c: FloatArray) -> LinearRays:
    """Build the coefficient blocks of the linearised ray of every observation (eq. 12).

    Args:
        R_wc: Rotations, shape (M, 3, 3).
        features: theta-bar, n-bar and anchors.
        frames: alpha-bar and Q_j of every feature.
        cam_idx: Observing camera, shape (K,).
        feat_idx: Observed feature, shape (K,).
        bearings_c: Unit bearings, shape (K, 3).

    Returns:
        The blocks.

    References:
        PMBA eq. (12); pmba.md §4.5.
    """
    j = feat_idx
    s = frames.sin_am_t[j]
    st = frames.sin_t[j]
    sQ = s[:, None, None] * frames.Q[j]
    eye = np.eye(3)[None]
    coeff = np.empty((j.shape[0], 3, 3, 3))
    coeff[:, 0] = sQ  # on P_a
    coeff[:, 1] = -sQ + st[:, None, None] * eye  # on P_m
    coeff[:, 2] = -st[:, None, None] * eye  # on P_i, eq. (12)
    slots = np.stack([features.assoc_idx[j], features.main_idx[j], cam_idx], axis=1)
    rays = np.einsum('kij,kj->ki', R_wc[cam_idx], bearings_c)
    return LinearRays(slots.astype(np.int64), coeff, rays)


def accumulate_normal_matrix(blocks: FloatArray, slots: IntArray, n_cams: int,
                             weights: FloatArray | None = None) -> FloatArray:
    """Return the dense (3M, 3M) matrix sum_k sum_{s,t} G_ks^T w_k G_kt.

    Args:
        blocks: Row blocks G_ks of every observation and slot, shape (K, S, R, 3).
        slots: Camera of every slot, shape (K, S).
        n_cams: Number of cameras M.
        weights: Optional observation weights (K,).

    Returns:
        The normal matrix over all camera positions (duplicates of a camera are summed).
    """
    K, S, R, _ = blocks.shape
    w = np.ones(K) if weights is None else weights
    # A_k = [G_k1 ... G_kS] (R x 3S); H_k = A_k^T w_k A_k, scattered block by block.
    A = blocks.transpose(0, 2, 1, 3).reshape(K, R, 3 * S)
    H_k = np.matmul(A.transpose(0, 2, 1) * w[:, None, None], A)  # (K, 3S, 3S)
    n = 3 * n_cams
    idx = (3 * slots[:, :, None] + np.arange(3)[None, None, :]).reshape(K, 3 * S)
    flat = idx[:, :, None] * n + idx[:, None, :]
    H = np.bincount(flat.ravel(), weights=H_k.ravel(), minlength=n * n)
    return np.asarray(H, dtype=np.float64).reshape(n, n)


def accumulate_gradient(blocks: FloatArray, slots: IntArray, n_cams: int,
                        residuals: FloatArray, weights: FloatArray | None = None) -> FloatArray:
    """Return sum_k sum_s G_ks^T w_k e_k as a (3M,) vector (blocks (K,S,R,3), e (K,R))."""
    w = np.ones(slots.shape[0]) if weights is None else weights
    g = np.matmul((residuals * w[:, None])[:, None, None, :], blocks)[:, :, 0, :]  # (K,S,3)
    idx = 3 * slots[:, :, None] + np.arange(3)[None, None, :]
    return np.asarray(np.bincount(idx.ravel(), weights=g.ravel(), minlength=3 * n_cams),
                      dtype=np.float64)


@dataclass(frozen=True, eq=False)
class ClsResult:
    """Result of the convex position problem (eq. 14).

    Attributes:
        centers_w: Camera centres, shape (M, 3); P_root = 0 and the scale constraint holds.
        residual: sqrt(mean ||[r_k]x N-bar_k||^2) at the solution.
        cheirality_violations: Observations with r_k . N-bar_k < 0 at the solution.
        penalty_iterations: Active-set iterations of the cheirality penalty.
    """

    centers_w: FloatArray
    residual: float
    cheirality_violations: int
    penalty_iterations: int


def solve_cls(lin: LinearRays, n_cams: int, root: int, *, weights: FloatArray | None = None,
              cameras: BoolArray | None = None, max_penalty_iterations: int = 10,
              penalty_weight: float = 100.0) -> ClsResult:
    """Solve eq. (14): min sum_k ||[r_k]x N-bar_k(P)||^2 with cheirality and a scale constraint.

    Args:
        lin: Linearised rays of all observations.
        n_cams: Number of cameras M.
        root: Reference camera, P_root = 0.
        weights: Optional observation weights (K,) (e.g. 0 for inconsistent features).
        cameras: Optional mask (M,) of cameras to solve for; the others are held at 0 and must
            not appear in ``lin``.
        max_penalty_iterations: Maximum active-set iterations for the cheirality penalty.
        penalty_weight: Weight of a violated cheirality row, relative to the mean diagonal of
            the normal matrix per unit row norm.

    Returns:
        Positions and diagnostics.

    Raises:
        InitError: If the linear system is singular or the solution is not finite.

    References:
        PMBA eq. (14); pmba.md §4.6, §8 item 2.
    """
    K = lin.slots.shape[0]
    w = np.ones(K) if weights is None else np.asarray(weights, dtype=float)
    cams = np.ones(n_cams, dtype=bool) if cameras is None else np.asarray(cameras, dtype=bool)
    # Rows [r_k]x C_slot (3 rows per observation), eq. (14).
    B = np.matmul(so3.hat(lin.rays)[:, None], lin.coeff)  # eq. (14): [r_k]x N-bar_k
    H = accumulate_normal_matrix(B, lin.slots, n_cams, w)
    # Cheirality rows h_k = r_k^T C_slot: r_k . N-bar_k(P) >= 0.
    # DEVIATION(eq. 14): the printed z(R_i N) >= 0 is read as "predicted ray on the measured
    # side", r_k . N-bar_k >= 0, which is convention-free and linear (pmba.md §8 item 2).
    h = np.einsum('ka,ksaj->ksj', lin.rays, lin.coeff)  # (K, 3 slots, 3)
    h_idx = 3 * lin.slots[:, :, None] + np.arange(3)[None, None, :]
    # DEVIATION(eq. 14): scale constraint sum_k w_k r_k . N-bar_k(P) = sum_k w_k; without it
    # P = 0 is optimal (pmba.md §8 item 2).
    c = np.bincount(h_idx.ravel(), weights=(h * w[:, None, None]).ravel(),
                    minlength=3 * n_cams)
    free = np.repeat(cams, 3)
    free[3 * root:3 * root + 3] = False
    fidx = np.flatnonzero(free)
    Hf = H[np.ix_(fidx, fidx)]
    cf = c[fidx]
    target = float(np.sum(w))
    scale_diag = float(np.mean(np.diag(Hf))) if fidx.size else 1.0
    row_norm2 = np.bincount(np.arange(K).repeat(9), weights=(h * h).ravel(), minlength=K)
    mu = penalty_weight * scale_diag / max(float(np.mean(row_norm2)), 1e-300)
    active = np.zeros(K, dtype=bool)
    p = np.zeros(3 * n_cams)
    it = 0
    for it in range(max_penalty_iterations + 1):  # noqa: B007 - reported after the loop
        Hp = H.copy()
        if np.any(active):
            ha = h[active]
            Hp += accumulate_normal_matrix(ha[:, :, None, :], lin.slots[active], n_cams,
                                           np.full(int(active.sum()), mu))
        Hpf = Hp[np.ix_(fidx, fidx)]
        kkt = np.zeros((fidx.size + 1, fidx.size + 1))
        kkt[:-1, :-1] = Hpf
        kkt[:-1, -1] = cf
        kkt[-1, :-1] = cf
        rhs = np.zeros(fidx.size + 1)
        rhs[-1] = target
        try:
            sol = scipy.linalg.solve(kkt, rhs, assume_a='sym')
        except (np.linalg.LinAlgError, ValueError) as err:
            msg = f'CLS (eq. 14): singular system ({err})'
            raise InitError(msg) from err
        if not np.all(np.isfinite(sol)):
            msg = 'CLS (eq. 14): non-finite solution'
            raise InitError(msg)
        p = np.zeros(3 * n_cams)
        p[fidx] = sol[:-1]
        depth = np.einsum('ksj,ksj->k', h, p[h_idx])
        violated = (depth < 0.0) & (w > 0)
        new_active = active | violated
        if np.array_equal(new_active, active):
            break
        active = new_active
    P = p.reshape(n_cams, 3)
    N = lin.evaluate(P)
    cross = np.cross(lin.rays, N)
    residual = float(np.sqrt(np.sum(w * np.sum(cross * cross, axis=1)) / max(np.sum(w), 1.0)))
    n_viol = int(np.sum((np.sum(lin.rays * N, axis=1) < 0.0) & (w > 0)))
    logger.info('CLS: residual %.3e, %d cheirality violations, %d penalty iterations',
                residual, n_viol, it)
    return ClsResult(P, residual, n_viol, it)
