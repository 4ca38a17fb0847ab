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

X_j = C_a P_a + C_m P_m is shared by all observations of feature j, so normal matrices are
assembled per feature for the anchors and per observation only for P_i
(:meth:`LinearRays.normal_matrix`); the CLS and the NLS (eq. 13) differ only in the 3x3 weight
of each observation's ray.

==========  ============  ==========  ===================================================
paper       code          shape       meaning
==========  ============  ==========  ===================================================
r_k         rays          (K,3)       R-bar_i v_k, measured ray in the world frame
C_a, C_m    anchor_coeff  (N,2,3,3)   3x3 blocks of N-bar on P_a, P_m (per feature)
X_j         points()      (N,3)       C_a P_a + C_m P_m, the feature's homogeneous point
h_k         (gradient)    (3M,)       dN-bar_k/dP^T r_k: the cheirality row r_k . N-bar_k(P)
==========  ============  ==========  ===================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
import logging

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.compiled import linear_rays as compiled_linear_rays
from pmba_ros.core.engine import EngineName, resolve
from pmba_ros.core.problem import ParallaxFeatures
from pmba_ros.errors import InitError
from pmba_ros.init import normal_blocks
from pmba_ros.init.anchors import LinearizationFrames
from pmba_ros.init.normal_blocks import block_pattern, BlockPattern
import scipy.sparse

logger = logging.getLogger(__name__)


def _sum_by(index: IntArray, values: FloatArray, n: int) -> FloatArray:
    """Return sum of ``values`` (K, ...) grouped by ``index`` (K,) into (n, ...)."""
    flat = values.reshape(values.shape[0], -1)
    out = np.empty((flat.shape[1], n))
    for c in range(flat.shape[1]):
        out[c] = np.bincount(index, weights=flat[:, c], minlength=n)
    return out.T.reshape(n, *values.shape[1:])


@dataclass(frozen=True, eq=False)
class LinearRays:
    """The linearised rays N-bar_k(P) of eq. (12), in their per-feature form.

    N-bar_k(P) = X_j(P) - sin(theta-bar_j) P_i with X_j(P) = C_a P_a + C_m P_m the feature's
    homogeneous point (pmba.md §1.3): every observation of a feature shares X_j, so the
    products over the anchors are done once per feature.

    Attributes:
        cam: Observing camera i of every observation, shape (K,).
        feat: Feature j of every observation, shape (K,).
        assoc: Associate anchor a of every feature, shape (N,).
        main: Main anchor m of every feature, shape (N,).
        anchor_coeff: C_a and C_m of every feature, shape (N, 2, 3, 3).
        sin_t: sin(theta-bar) of every feature, shape (N,) (C_i = -sin_t I).
        rays: Measured world rays R-bar_i v_k, shape (K, 3).
    """

    cam: IntArray
    feat: IntArray
    assoc: IntArray
    main: IntArray
    anchor_coeff: FloatArray
    sin_t: FloatArray
    rays: FloatArray

    @property
    def n_obs(self) -> int:
        """Return the number of observations K."""
        return int(self.cam.shape[0])

    def subset(self, keep: BoolArray) -> LinearRays:
        """Return the rays of the observations selected by the mask ``keep`` (K,)."""
        return LinearRays(self.cam[keep], self.feat[keep], self.assoc, self.main,
                          self.anchor_coeff, self.sin_t, self.rays[keep])

    def points(self, centers_w: FloatArray) -> FloatArray:
        """Return X_j(P) = C_a P_a + C_m P_m of every feature, shape (N, 3)."""
        points: FloatArray = (
            np.einsum('nij,nj->ni', self.anchor_coeff[:, 0], centers_w[self.assoc])
            + np.einsum('nij,nj->ni', self.anchor_coeff[:, 1], centers_w[self.main]))
        return points

    def evaluate(self, centers_w: FloatArray,
                 engine: EngineName | str = EngineName.AUTO) -> FloatArray:
        """Return N-bar_k(P) for camera centres (M, 3), shape (K, 3).

        ``engine`` as in :meth:`normal_matrix`.
        """
        if resolve(engine).name is EngineName.COMPILED:
            return compiled_linear_rays.linear_ray_values(
                self.cam, self.feat, self.assoc, self.main, self.anchor_coeff, self.sin_t,
                centers_w)
        return (self.points(centers_w)[self.feat]
                - self.sin_t[self.feat, None] * centers_w[self.cam])

    def depths(self, centers_w: FloatArray,
               engine: EngineName | str = EngineName.AUTO) -> FloatArray:
        """Return r_k . N-bar_k(P) for camera centres (M, 3), shape (K,) (cheirality).

        ``engine`` as in :meth:`normal_matrix`.
        """
        if resolve(engine).name is EngineName.COMPILED:
            return compiled_linear_rays.ray_depths(
                self.cam, self.feat, self.assoc, self.main, self.anchor_coeff, self.sin_t,
                self.rays, centers_w)
        depth: FloatArray = np.sum(self.rays * self.evaluate(centers_w, engine), axis=1)
        return depth

    def cheirality_row_norms(self, engine: EngineName | str = EngineName.AUTO) -> FloatArray:
        """Return |C_a^T r_k|^2 + |C_m^T r_k|^2 + sin^2(theta-bar) |r_k|^2, shape (K,).

        The squared norm of the cheirality row h_k = dN-bar_k/dP^T r_k block by block (an
        observer that is also an anchor is not merged): the scale of the CLS penalty.
        ``engine`` as in :meth:`normal_matrix`.
        """
        if resolve(engine).name is EngineName.COMPILED:
            return compiled_linear_rays.cheirality_row_norms(self.feat, self.anchor_coeff,
                                                             self.sin_t, self.rays)
        r = self.rays
        Ct_r = np.einsum('kai,ka->ki', self.anchor_coeff[self.feat, 0], r)
        Cm_r = np.einsum('kai,ka->ki', self.anchor_coeff[self.feat, 1], r)
        norm2: FloatArray = (np.sum(Ct_r ** 2, axis=1) + np.sum(Cm_r ** 2, axis=1)
                             + self.sin_t[self.feat] ** 2 * np.sum(r * r, axis=1))
        return norm2

    @cached_property
    def pattern(self) -> BlockPattern:
        """Return the non-zero 3x3 blocks of the normal matrices (found once, then reused)."""
        return block_pattern(self.cam, self.feat, self.assoc, self.main)

    def normal_blocks(self, A: FloatArray, engine: EngineName | str = EngineName.AUTO,
                      ) -> FloatArray:
        """Return the non-zero blocks of sum_k G_k^T A_k G_k, shape (B, 3, 3) (``pattern``).

        G_k = dN-bar_k / dP (blocks C_a, C_m, -sin_t I on P_a, P_m, P_i; blocks of the same
        camera add up) and A_k a symmetric 3x3 weight of the observation's ray.

        Args:
            A: Symmetric weights, shape (K, 3, 3).
            engine: The compiled loop (``'auto'``: where numba runs) or this numpy code.
        """
        pat = self.pattern
        if resolve(engine).name is EngineName.COMPILED:
            return compiled_linear_rays.ray_normal_blocks(
                self.feat, self.anchor_coeff, self.sin_t, A, pat.slot_obs, pat.slot_cross,
                pat.slot_anchor, pat.n_blocks)
        st = self.sin_t[self.feat]
        C = self.anchor_coeff
        # P_i with itself, and P_i with X_j (then X_j -> P_a, P_m).
        cross = -st[:, None, None] * A
        Ck = C[self.feat]
        cross_blocks = np.stack([cross @ Ck[:, 0], cross @ Ck[:, 1]], axis=1)
        # X_j with itself, once per feature.
        B = _sum_by(self.feat, A, C.shape[0])
        CtB = np.swapaxes(C, 2, 3) @ B[:, None]  # (N, 2, 3, 3)
        CtBC = CtB[:, :, None] @ C[:, None, :]  # (N, 2, 2, 3, 3): C_s^T B C_t
        return pat.sum_blocks((st * st)[:, None, None] * A, cross_blocks, CtBC)

    def normal_matrix(self, A: FloatArray, n_cams: int,
                      engine: EngineName | str = EngineName.AUTO) -> FloatArray:
        """Return sum_k G_k^T A_k G_k over all positions, dense, shape (3M, 3M).

        ``A`` and ``engine`` as in :meth:`normal_blocks`; ``n_cams`` is M.
        """
        return self.pattern.dense(self.normal_blocks(A, engine), n_cams)

    def gradient(self, y: FloatArray, n_cams: int,
                 engine: EngineName | str = EngineName.AUTO) -> FloatArray:
        """Return sum_k G_k^T y_k over all positions, shape (3M,), for y (K, 3).

        ``engine`` as in :meth:`normal_matrix`.
        """
        if resolve(engine).name is EngineName.COMPILED:
            return compiled_linear_rays.ray_gradient(
                self.cam, self.feat, self.assoc, self.main, self.anchor_coeff, self.sin_t, y,
                n_cams)
        st = self.sin_t[self.feat]
        g = _sum_by(self.cam, -st[:, None] * y, n_cams)
        Y = _sum_by(self.feat, y, self.anchor_coeff.shape[0])
        CtY = np.einsum('nsai,na->nsi', self.anchor_coeff, Y)
        g += _sum_by(self.assoc, CtY[:, 0], n_cams) + _sum_by(self.main, CtY[:, 1], n_cams)
        return g.reshape(-1)


def linear_rays(R_wc: FloatArray, features: ParallaxFeatures, frames: LinearizationFrames,
                cam_idx: IntArray, feat_idx: IntArray, bearings_c: FloatArray) -> LinearRays:
    """Build the coefficient blocks of the linearised rays (eq. 12).

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
    sQ = frames.sin_am_t[:, None, None] * frames.Q
    coeff = np.stack([sQ, -sQ + frames.sin_t[:, None, None] * np.eye(3)], axis=1)  # eq. (12)
    rays = np.einsum('kij,kj->ki', R_wc[cam_idx], bearings_c)
    return LinearRays(np.asarray(cam_idx, dtype=np.int64), np.asarray(feat_idx, dtype=np.int64),
                      features.assoc_idx.astype(np.int64), features.main_idx.astype(np.int64),
                      coeff, np.asarray(frames.sin_t, dtype=float), rays)


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
              penalty_weight: float = 100.0, sparse: bool | None = None) -> ClsResult:
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
        sparse: Solve with a sparse factorization (True), dense (False), or by the number of
            unknowns and blocks (None, :func:`pmba_ros.init.normal_blocks.use_sparse`).

    Returns:
        Positions and diagnostics.

    Raises:
        InitError: If the linear system is singular or the solution is not finite.

    References:
        PMBA eq. (14); pmba.md §4.6, §8 item 2.
    """
    K = lin.n_obs
    w = np.ones(K) if weights is None else np.asarray(weights, dtype=float)
    cams = np.ones(n_cams, dtype=bool) if cameras is None else np.asarray(cameras, dtype=bool)
    r = lin.rays
    rr = r[:, :, None] * r[:, None, :]
    # Rows [r_k]x N-bar_k (eq. 14): weight [r_k]x^T [r_k]x = |r_k|^2 I - r_k r_k^T.
    cross_w = -rr
    n2 = np.sum(r * r, axis=1)
    for i in range(3):
        cross_w[:, i, i] += n2
    cross_w *= w[:, None, None]
    H_blocks = lin.normal_blocks(cross_w)
    # Cheirality rows h_k = dN-bar_k/dP^T r_k: r_k . N-bar_k(P) >= 0.
    # DEVIATION(eq. 14): the printed z(R_i N) >= 0 is read as "predicted ray on the measured
    # side", r_k . N-bar_k >= 0, which is convention-free and linear (pmba.md §8 item 2).
    # DEVIATION(eq. 14): scale constraint sum_k w_k r_k . N-bar_k(P) = sum_k w_k; without it
    # P = 0 is optimal (pmba.md §8 item 2).
    c = lin.gradient(w[:, None] * r, n_cams)
    free = np.repeat(cams, 3)
    free[3 * root:3 * root + 3] = False
    fidx = np.flatnonzero(free)
    layout = (lin.pattern.sparse_layout(n_cams, fidx)
              if normal_blocks.use_sparse(fidx.size, lin.pattern.n_blocks, sparse) else None)

    def restricted(blocks: FloatArray) -> FloatArray | scipy.sparse.csc_array:
        if layout is not None:
            return layout.matrix(blocks)
        return lin.pattern.dense(blocks, n_cams)[np.ix_(fidx, fidx)]

    H = restricted(H_blocks)
    cf = c[fidx]
    target = float(np.sum(w))
    scale_diag = float(np.mean(H.diagonal())) if fidx.size else 1.0
    row_norm2 = lin.cheirality_row_norms()
    mu = penalty_weight * scale_diag / max(float(np.mean(row_norm2)), 1e-300)
    active = np.zeros(K, dtype=bool)
    p = np.zeros(3 * n_cams)
    it = 0
    for it in range(max_penalty_iterations + 1):  # noqa: B007 - reported after the loop
        Hp = H
        if np.any(active):
            # The penalty rows weighted 0 where inactive: the same blocks (and sums) as the
            # active rows alone, on the pattern already found.
            penalty = (mu * active)[:, None, None] * rr
            Hp = restricted(H_blocks + lin.normal_blocks(penalty))
        try:
            sol = normal_blocks.solve_kkt(Hp, cf, target)
        except (np.linalg.LinAlgError, ValueError) as err:
            msg = f'CLS (eq. 14): singular system ({err})'
            raise InitError(msg) from err
        if not np.all(np.isfinite(sol)):
            msg = 'CLS (eq. 14): non-finite solution'
            raise InitError(msg)
        p = np.zeros(3 * n_cams)
        p[fidx] = sol[:-1]
        depth = lin.depths(p.reshape(n_cams, 3))
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
