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
"""Normal equations of a block-sparse BA and their Schur complement on the poses.

With pose columns T and feature columns F, the Gauss-Newton system is
``[[U, W], [W^T, V]] [x_T; x_F] = -[g_T; g_F]``, where U = J_T^T J_T (with the off-diagonal
pose blocks that PMBA's three-slot observations create, pmba.md §1.7), W = J_T^T J_F and
V = J_F^T J_F is block-diagonal with 3x3 blocks. The reduced camera system is

    S x_T = -g_T + W V^-1 g_F,   S = U - W V^-1 W^T,

and x_F = V^-1 (-g_F - W^T x_T).

Every parameterization has the same shape: an observation's Jacobian has one *observer*
block (its own pose) and *anchor* blocks that are the same for all observations of a feature
(PMBA: main anchor, and the associate anchor's centre; IDP: the anchor pose; XYZ: none).
Features are ordered by their number of observations (see :func:`feature_order`), so the
features with c observations hold a contiguous range of observations.

A :class:`SchurStructure` is the part every engine shares (:class:`SchurLayout`: the free
pose of each observation, each feature's anchors) and the engine's :class:`SchurPlan`, which
forms U, W, V, g, S, the back-substitution and x^T H x: the numpy plan
(:mod:`pmba_ros.core.numpy_schur`) or the compiled loops' (:mod:`pmba_ros.core.compiled.plan`),
chosen by the engine (:mod:`pmba_ros.core.engine`). Both give the same numbers to rounding
(``test_normal_equations.py`` runs every one). This module solves the reduced system.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

import numpy as np
from pmba_ros._threads import blas_threads_for
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.jacobian import Linearization
from pmba_ros.core.sparse_factor import sparse_reduced_matrix, sparse_solve
from pmba_ros.errors import ReducedSystemError as ReducedSystemError
from pmba_ros.errors import SolverError
import scipy.linalg
import scipy.linalg.lapack
import scipy.sparse
import scipy.sparse.linalg

#: Up to this many free pose columns the reduced system is factored as a dense matrix.
DENSE_LIMIT = 6000

#: Above this many it is factored as a sparse matrix (a dense one takes 8 n^2 bytes: 3.2 GB).
SPARSE_LIMIT = 20000

#: Between the two, the share of its factor's lower triangle that a sparse factorization
#: fills (:attr:`SchurStructure.sparse_fill`) above which the dense one is taken. A sequence's
#: cameras see their neighbours only and fill little; a photo collection's see much of one
#: scene, and SuperLU on a factor that fills most of the triangle runs several times slower
#: than LAPACK's dense Cholesky (and the sparse matrix costs more to build).
DENSE_FILL = 0.25


def feature_order(feat_idx: IntArray, n_feats: int) -> IntArray:
    """Return features sorted by their number of observations (stable): new -> old index."""
    counts = np.bincount(feat_idx, minlength=n_feats)
    return np.argsort(counts, kind='stable')


def anchors(cam_idx: IntArray, feat_idx: IntArray, slot_pose: IntArray, starts: IntArray,
            ) -> tuple[IntArray, IntArray, BoolArray]:
    """Return each feature's anchor poses (N, S - 1) and its observation by each, or -1.

    An anchor slot names one pose per feature; unused entries are -1, so it is the maximum.
    Also the errors of each slot (S - 1, 2) that :meth:`SchurLayout.build` raises: it names
    different poses within a feature; an anchor pose does not observe its feature. The numpy
    reference of the compiled engine's (:func:`pmba_ros.core.compiled.assembly.anchors`).
    """
    n_feats, n_anchor = starts.shape[0] - 1, slot_pose.shape[1] - 1
    anchor_pose = np.full((n_feats, n_anchor), -1, dtype=np.int64)
    anchor_obs = np.full((n_feats, n_anchor), -1, dtype=np.int64)
    errors = np.zeros((n_anchor, 2), dtype=bool)
    for s in range(n_anchor):
        col = slot_pose[:, s + 1]
        anchor_pose[:, s] = np.maximum.reduceat(col, starts[:-1])
        per_obs = anchor_pose[feat_idx, s]
        errors[s, 0] = np.any((col >= 0) & (col != per_obs))
        hit = np.flatnonzero(cam_idx == per_obs)
        anchor_obs[feat_idx[hit], s] = hit
        errors[s, 1] = np.any((anchor_pose[:, s] >= 0) & (anchor_obs[:, s] < 0))
    return anchor_pose, anchor_obs, errors


#: An engine's :func:`anchors`.
AnchorSearch = Callable[[IntArray, IntArray, IntArray, IntArray],
                        tuple[IntArray, IntArray, BoolArray]]


@dataclass(frozen=True, eq=False)
class SchurLayout:
    """Where each observation's Jacobian blocks go: the part of the structure every engine shares.

    Observations are sorted by feature, and features by their number of observations
    (:func:`feature_order`).

    Attributes:
        n_blocks: Number of free pose blocks (6 columns each).
        n_feats: Number of features.
        feat_idx: Feature of each observation (and of its W block), shape (K,).
        anchor_cols: Pose columns (start, stop) of each anchor slot.
        starts: First observation of each feature, and K, shape (N + 1,).
        obs_block: Free pose block of each observer, -1 if it is fixed, shape (K,).
        anchor_block: Free block of each feature's anchor slots, or -1, shape (N, S - 1).
        anchor_obs: Observation of the feature by each anchor, or -1, shape (N, S - 1).
    """

    n_blocks: int
    n_feats: int
    feat_idx: IntArray
    anchor_cols: tuple[tuple[int, int], ...]
    starts: IntArray
    obs_block: IntArray
    anchor_block: IntArray
    anchor_obs: IntArray

    @property
    def w_block(self) -> IntArray:
        """Pose block of each W block (0, with a zero W block, where the observer is fixed)."""
        return np.maximum(self.obs_block, 0)

    @classmethod
    def build(cls, cam_idx: IntArray, feat_idx: IntArray, slot_pose: IntArray, n_feats: int,
              free_block: IntArray, anchor_cols: tuple[tuple[int, int], ...] = (),
              find_anchors: AnchorSearch = anchors) -> SchurLayout:
        """Build the layout of K observations.

        Args:
            cam_idx: Observing pose of each observation, shape (K,).
            feat_idx: Feature of each observation, shape (K,), ordered as the class requires.
            slot_pose: Pose of each Jacobian slot, shape (K, S): slot 0 is the observer (or
                -1 where its block is zero), slots 1.. are anchors, the same pose for every
                observation of a feature (or -1 where that block is zero).
            n_feats: Number of features N.
            free_block: Free block of each pose, shape (M,), -1 for fixed poses.
            anchor_cols: Columns (start, stop) of the pose that each anchor slot touches.
            find_anchors: :func:`anchors` or an engine's equal.

        Raises:
            SolverError: If no pose is free, the observations are not ordered or an anchor
                slot does not name one observing pose per feature.
        """
        S = slot_pose.shape[1]
        if len(anchor_cols) != S - 1:
            msg = f'{S - 1} anchor slots but {len(anchor_cols)} column ranges'
            raise SolverError(msg)
        n_blocks = int(free_block.max()) + 1 if free_block.size and free_block.max() >= 0 else 0
        if n_blocks == 0:
            msg = 'no free pose: every pose is fixed'
            raise SolverError(msg)
        counts = np.bincount(feat_idx, minlength=n_feats)
        if (np.any(np.diff(feat_idx) < 0) or np.any(np.diff(counts) < 0)
                or np.any(counts == 0)):
            msg = 'observations must be sorted by feature, features by observation count'
            raise SolverError(msg)
        starts = np.concatenate([[0], np.cumsum(counts)])
        anchor_pose, anchor_obs, errors = find_anchors(cam_idx, feat_idx, slot_pose, starts)
        for s, (mixed, unobserved) in enumerate(errors.tolist(), start=1):
            if mixed:
                msg = f'anchor slot {s} names different poses within one feature'
                raise SolverError(msg)
            if unobserved:
                msg = f'anchor slot {s}: an anchor pose does not observe its feature'
                raise SolverError(msg)
        anchor_block = np.where(anchor_pose >= 0, free_block[np.maximum(anchor_pose, 0)], -1)
        return cls(n_blocks, n_feats, feat_idx, tuple(anchor_cols), starts,
                   free_block[cam_idx], anchor_block, anchor_obs)


@dataclass(frozen=True, eq=False)
class NormalEquations:
    """Values of the normal equations at one linearization point (unscaled).

    Attributes:
        U: Pose blocks per upper pair of the plan, shape (n_pairs, 6, 6).
        W: Pose-feature blocks, one per observation, shape (K, 6, 3).
        V: Feature blocks, shape (N, 3, 3).
        g_pose: Gradient J_T^T r, shape (n_blocks, 6).
        g_feat: Gradient J_F^T r, shape (N, 3).
    """

    U: FloatArray
    W: FloatArray
    V: FloatArray
    g_pose: FloatArray
    g_feat: FloatArray


class SchurPlan(Protocol):
    """An engine's way of forming the normal equations and the Schur complement.

    ``pair_rows`` and ``pair_cols`` list the pose block pairs (row <= col, the diagonal
    included) whose U and S blocks it forms; S is symmetric and its lower blocks are the
    transposes.
    """

    @property
    def pair_rows(self) -> IntArray:
        """Row block of each upper pair."""

    @property
    def pair_cols(self) -> IntArray:
        """Column block of each upper pair."""

    def assemble(self, lin: Linearization) -> NormalEquations:
        """Return U, W, V and the gradient of residuals and Jacobian rows ``lin``."""

    def scale_w(self, W: FloatArray, c_pose: FloatArray, c_feat: FloatArray) -> None:
        """Scale the W blocks in place by their pose and feature column scales."""

    def reduce(self, eqs: NormalEquations, damp_feat: FloatArray,
               ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Return S (upper pair blocks), -g_T + W V^-1 g_F and V^-1 of the damped V.

        Raises:
            ReducedSystemError: If a damped feature block is singular.
        """

    def back_substitute(self, eqs: NormalEquations, V_inv: FloatArray,
                        x_pose: FloatArray) -> FloatArray:
        """Return x_F = V^-1 (-g_F - W^T x_T)."""

    def quadratic_form(self, eqs: NormalEquations, x_pose: FloatArray,
                       x_feat: FloatArray) -> float:
        """Return x^T H x for H held as the plan's U, W and V blocks."""


@dataclass(frozen=True, eq=False)
class SchurStructure:
    """Index structure of the normal equations, fixed during a solve: layout and plan.

    Attributes:
        layout: The engine-independent part.
        plan: The engine's plan, built from the layout.
    """

    layout: SchurLayout
    plan: SchurPlan

    @classmethod
    def build(cls, cam_idx: IntArray, feat_idx: IntArray, slot_pose: IntArray, n_feats: int,
              free_block: IntArray, anchor_cols: tuple[tuple[int, int], ...],
              planner: Callable[[SchurLayout], SchurPlan],
              find_anchors: AnchorSearch = anchors) -> SchurStructure:
        """Build the layout (:meth:`SchurLayout.build`, same arguments) and ``planner``'s plan.

        ``planner`` is an engine's ``schur_plan``, ``find_anchors`` :func:`anchors` or an
        engine's ``schur_anchors`` (:mod:`pmba_ros.core.engine`).

        Raises:
            SolverError: If no pose is free or the observations are not ordered.
        """
        layout = SchurLayout.build(cam_idx, feat_idx, slot_pose, n_feats, free_block,
                                   anchor_cols, find_anchors)
        return cls(layout, planner(layout))

    @property
    def n_blocks(self) -> int:
        """Number of free pose blocks."""
        return self.layout.n_blocks

    @property
    def n_feats(self) -> int:
        """Number of features."""
        return self.layout.n_feats

    @property
    def feat_idx(self) -> IntArray:
        """Feature of each observation, shape (K,)."""
        return self.layout.feat_idx

    @property
    def anchor_cols(self) -> tuple[tuple[int, int], ...]:
        """Pose columns (start, stop) of each anchor slot."""
        return self.layout.anchor_cols

    @property
    def pair_rows(self) -> IntArray:
        """Row block of each upper pair of U and S."""
        return self.plan.pair_rows

    @property
    def pair_cols(self) -> IntArray:
        """Column block of each upper pair of U and S."""
        return self.plan.pair_cols

    @cached_property
    def sparse_fill(self) -> float:
        """Return the share of the lower triangle a sparse factorization of S fills.

        Predicted on S's pattern of pose blocks (one entry per 6 x 6 block, 36 times
        smaller), factored as :func:`~pmba_ros.core.sparse_factor.sparse_solve` does: the
        fill follows the blocks, whose orderings agree.
        """
        nb = self.n_blocks
        if nb < 2:
            return 1.0
        rows, cols = self.pair_rows, self.pair_cols
        off = rows != cols
        degree = np.bincount(np.concatenate([rows[off], cols[off]]), minlength=nb)
        pattern = scipy.sparse.csc_matrix(
            (np.concatenate([np.ones(2 * int(off.sum())), degree + 1.0]),
             (np.concatenate([rows[off], cols[off], np.arange(nb)]),
              np.concatenate([cols[off], rows[off], np.arange(nb)]))), shape=(nb, nb))
        lu = scipy.sparse.linalg.splu(pattern, permc_spec='MMD_AT_PLUS_A', diag_pivot_thresh=0.0,
                                      options={'SymmetricMode': True})
        return float(lu.L.nnz - nb) / (nb * (nb - 1) / 2)


def assemble(structure: SchurStructure, lin: Linearization) -> NormalEquations:
    """Assemble U, W, V and the gradient from residuals and Jacobian blocks.

    Args:
        structure: The problem's :class:`SchurStructure`.
        lin: Residuals and Jacobian (observations in the structure's order).

    Raises:
        SolverError: If the Jacobian's anchor columns are not the structure's.
    """
    if lin.anchor_cols != structure.anchor_cols:
        msg = (f'anchor columns {lin.anchor_cols} do not match the structure '
               f'{structure.anchor_cols}')
        raise SolverError(msg)
    return structure.plan.assemble(lin)


@dataclass(frozen=True, eq=False)
class ScaledSystem:
    """The normal equations of the column-scaled Jacobian J diag(c), and what a step reads.

    Attributes:
        eqs: The scaled equations (their W is the unscaled equations', scaled in place).
        c_pose, c_feat: Column scales 1 / (1 + sqrt(diag(J^T J))), or ones (no scaling).
        D_pose, D_feat: Square roots of the scaled diagonal, clipped to [1e-6, 1e32] first:
            the trust region's ellipsoid.
        g_pose, g_feat: The scaled gradient over D (zero in the held pose columns).
        gradient_max: max |J^T r| over the free columns of the unscaled gradient (NaN if one
            is NaN: such a gradient never stops the solver).
    """

    eqs: NormalEquations
    c_pose: FloatArray
    c_feat: FloatArray
    D_pose: FloatArray
    D_feat: FloatArray
    g_pose: FloatArray
    g_feat: FloatArray
    gradient_max: float


def jacobi_scale(structure: SchurStructure, eqs: NormalEquations, col_mask: BoolArray,
                 jacobi: bool) -> ScaledSystem:
    """Return the Jacobi scaling of ``eqs`` (the numpy engine's; the compiled one agrees).

    Args:
        structure: Index structure.
        eqs: Unscaled equations; their W blocks, the largest array, are scaled in place.
        col_mask: Pose columns that are solved for, shape (n_blocks, 6).
        jacobi: Scale the columns by 1 / (1 + |J_k|); False: c = 1.
    """
    diag_pairs = np.flatnonzero(structure.pair_rows == structure.pair_cols)
    d_pose = np.zeros((structure.n_blocks, 6))
    d_pose[structure.pair_rows[diag_pairs]] = np.diagonal(eqs.U[diag_pairs], axis1=1, axis2=2)
    d_feat = np.diagonal(eqs.V, axis1=1, axis2=2)
    if jacobi:
        c_pose = 1.0 / (1.0 + np.sqrt(d_pose))
        c_feat = 1.0 / (1.0 + np.sqrt(d_feat))
    else:
        c_pose = np.ones_like(d_pose)
        c_feat = np.ones_like(d_feat)
    cp_r = c_pose[structure.pair_rows]
    cp_c = c_pose[structure.pair_cols]
    structure.plan.scale_w(eqs.W, c_pose, c_feat)
    scaled = NormalEquations(
        eqs.U * cp_r[:, :, None] * cp_c[:, None, :], eqs.W,
        eqs.V * c_feat[:, :, None] * c_feat[:, None, :],
        eqs.g_pose * c_pose, eqs.g_feat * c_feat)
    D_pose = np.sqrt(np.clip(d_pose * c_pose ** 2, 1e-6, 1e32))
    D_feat = np.sqrt(np.clip(d_feat * c_feat ** 2, 1e-6, 1e32))
    g_max = np.maximum(np.max(np.abs(np.where(col_mask, eqs.g_pose, 0.0)), initial=0.0),
                       np.max(np.abs(eqs.g_feat), initial=0.0))
    return ScaledSystem(scaled, c_pose, c_feat, D_pose, D_feat,
                        np.where(col_mask, scaled.g_pose, 0.0) / D_pose,
                        scaled.g_feat / D_feat, float(g_max))


def solve_schur(structure: SchurStructure, eqs: NormalEquations, damp_pose: FloatArray,
                damp_feat: FloatArray, pose_free: BoolArray,
                ) -> tuple[FloatArray, FloatArray]:
    """Solve (H + diag(damp)) x = -g by the Schur complement on the poses.

    See :func:`solve_schur_factored` (which also returns the factor of S).
    """
    x_pose, x_feat, _ = solve_schur_factored(structure, eqs, damp_pose, damp_feat, pose_free)
    return x_pose, x_feat


def solve_schur_factored(structure: SchurStructure, eqs: NormalEquations,
                         damp_pose: FloatArray, damp_feat: FloatArray, pose_free: BoolArray,
                         low_rank: tuple[FloatArray, FloatArray] | None = None,
                         ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Solve (H + diag(damp)) x = -g by the Schur complement on the poses.

    Args:
        structure: Index structure.
        eqs: Normal equations (already scaled, if scaling is used).
        damp_pose: Diagonal added to the pose blocks, shape (n_blocks, 6).
        damp_feat: Diagonal added to the feature blocks, shape (N, 3).
        pose_free: Pose columns that are solved for, shape (n_blocks, 6); the others (gauge)
            are held at zero.
        low_rank: Rows u (k, n_blocks * 6) over the pose columns and d (k,): H is less
            ``sum_k u_k u_k^T / d_k`` (pose columns only, so S is less it too), solved by
            the Woodbury identity on S's factorization (a dense one would fill S).

    Returns:
        x_pose (n_blocks, 6), x_feat (N, 3) and the upper Cholesky factor of the damped S
        on the free columns (None where S was solved as a sparse matrix), for
        :func:`covariance_from_factor`.

    Raises:
        ReducedSystemError: If S or a feature block is not positive definite.
    """
    S_blocks, rhs, V_inv = _reduced(structure, eqs, damp_feat)
    factor = None
    nb = structure.n_blocks
    free = pose_free.reshape(-1)
    dim = nb * 6
    x = np.zeros(dim)
    b = rhs.reshape(-1)[free]
    if low_rank is not None:   # S^-1 u_k with the same factorization, as more columns
        b = np.column_stack([b, low_rank[0][:, free].T])
    n_free = int(free.sum())
    if n_free <= DENSE_LIMIT or (n_free <= SPARSE_LIMIT and structure.sparse_fill > DENSE_FILL):
        factor = _dense_cholesky(structure, S_blocks, damp_pose, free)
        y, _ = scipy.linalg.lapack.dpotrs(factor, b, lower=False)
    else:
        S_sp = sparse_reduced_matrix(structure.pair_rows, structure.pair_cols, S_blocks,
                                     damp_pose)
        y = sparse_solve(S_sp[free][:, free].tocsc(), b)
    x[free] = y if low_rank is None else _woodbury(y, low_rank[0][:, free], low_rank[1])
    if not np.all(np.isfinite(x)):
        msg = 'reduced camera system solve produced non-finite values'
        raise ReducedSystemError(msg)
    x_pose = x.reshape(nb, 6)
    return x_pose, structure.plan.back_substitute(eqs, V_inv, x_pose), factor


def _woodbury(y: FloatArray, u: FloatArray, d: FloatArray) -> FloatArray:
    """Return (S - u^T diag(1/d) u)^-1 b from y = S^-1 [b, u^T] (n, 1 + k).

    Raises:
        ReducedSystemError: If the downdated system is not positive definite.
    """
    x, Z = y[:, 0], y[:, 1:]
    M = np.diag(d) - u @ Z
    try:
        c = scipy.linalg.cho_solve(scipy.linalg.cho_factor(M), u @ x)
    except np.linalg.LinAlgError as err:
        msg = 'reduced camera system less the window scales is not positive definite'
        raise ReducedSystemError(msg) from err
    out: FloatArray = x + Z @ c
    return out


def _reduced(structure: SchurStructure, eqs: NormalEquations, damp_feat: FloatArray,
             ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return the plan's S blocks, right-hand side and V^-1, checking the feature blocks."""
    S_blocks, rhs, V_inv = structure.plan.reduce(eqs, damp_feat)
    if not np.all(np.isfinite(V_inv)):
        msg = 'singular feature block'
        raise ReducedSystemError(msg)
    return S_blocks, rhs, V_inv


def _dense_cholesky(structure: SchurStructure, S_blocks: FloatArray, damp_pose: FloatArray,
                    free: BoolArray) -> FloatArray:
    """Return the upper Cholesky factor of S + diag(damp) on the free columns.

    The upper triangle only (pair blocks have row <= col): LAPACK's potrf, called directly,
    reads no more; scipy's cho_factor wrapper costs more than a window's factorization. S
    is written transposed in C order, which is S in LAPACK's (Fortran) order: f2py passes
    it without a copy.
    """
    nb = structure.n_blocks
    dim = nb * 6
    S_t = np.zeros((nb, 6, nb, 6))
    S_t[structure.pair_cols, :, structure.pair_rows, :] = S_blocks.transpose(0, 2, 1)
    S_t.reshape(-1)[::dim + 1] += damp_pose.reshape(-1)
    S = S_t.reshape(dim, dim).T
    with blas_threads_for(dim):
        factor, info = scipy.linalg.lapack.dpotrf(
            S if bool(free.all()) else S[np.ix_(free, free)], lower=False, clean=False,
            overwrite_a=True)
    if info != 0:
        msg = 'reduced camera system is not positive definite'
        raise ReducedSystemError(msg)
    return np.asarray(factor)


def pose_covariance(structure: SchurStructure, eqs: NormalEquations, damp_feat: FloatArray,
                    pose_free: BoolArray, factor: FloatArray | None = None) -> FloatArray:
    """Return the poses' covariance S^-1 (features marginalized), shape (n_blocks * 6,) * 2.

    In the variables of ``eqs`` (scaled, if scaling is used); the rows and columns of held
    pose columns are zero. ``factor``: S's Cholesky factor if a solve made it
    (:func:`solve_schur_factored`, undamped), which saves forming S again.

    Raises:
        ReducedSystemError: If S or a feature block is not positive definite, or S is
            larger than ``DENSE_LIMIT`` (its inverse is dense).
    """
    free = pose_free.reshape(-1)
    dim = structure.n_blocks * 6
    if int(free.sum()) > DENSE_LIMIT:
        msg = f'a covariance of {int(free.sum())} pose columns is not formed'
        raise ReducedSystemError(msg)
    if factor is None:
        S_blocks, _, _ = _reduced(structure, eqs, damp_feat)
        factor = _dense_cholesky(structure, S_blocks, np.zeros((structure.n_blocks, 6)), free)
    return covariance_from_factor(factor, free, dim)


def covariance_from_factor(factor: FloatArray, free: BoolArray, dim: int) -> FloatArray:
    """Return S^-1 from the upper Cholesky factor of S on the ``free`` columns (dim square).

    Raises:
        ReducedSystemError: If the factor is singular.
    """
    with blas_threads_for(dim):
        inverse, info = scipy.linalg.lapack.dpotri(factor, lower=False)
    if info != 0:
        msg = 'reduced camera system is singular'
        raise ReducedSystemError(msg)
    upper = np.triu(inverse)
    cov = np.zeros((dim, dim))
    cov[np.ix_(free, free)] = upper + np.triu(upper, 1).T
    return cov


def quadratic_form(structure: SchurStructure, eqs: NormalEquations, x_pose: FloatArray,
                   x_feat: FloatArray) -> float:
    """Return x^T H x for H = J^T J held as (upper) U, W and V blocks; cheaper than |J x|^2."""
    return structure.plan.quadratic_form(eqs, x_pose, x_feat)
