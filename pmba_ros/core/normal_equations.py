"""Normal equations of a block-sparse BA and their Schur complement on the poses.

With pose columns T and feature columns F, the Gauss-Newton system is
``[[U, W], [W^T, V]] [x_T; x_F] = -[g_T; g_F]``, where U = J_T^T J_T (with the off-diagonal
pose blocks that PMBA's three-slot observations create, pmba.md §1.7), W = J_T^T J_F and
V = J_F^T J_F is block-diagonal with 3x3 blocks. The reduced camera system is

    S x_T = -g_T + W V^-1 g_F,   S = U - W V^-1 W^T,

and x_F = V^-1 (-g_F - W^T x_T). S has the covisibility pattern, so it is assembled from the
list of covisible block pairs. Every index array that depends only on the problem's
structure is built once in :class:`SchurStructure`; each iteration only fills values, with
no Python loop over observations (scatter-adds are sparse products with 0/1 matrices).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.errors import SolverError

#: Observations / pairs processed per vectorized chunk (bounds temporary memory).
_CHUNK = 200_000
#: Above this many free pose columns the reduced system is solved as a sparse matrix.
DENSE_LIMIT = 6000


def _aggregator(index: IntArray, n_rows: int) -> scipy.sparse.csr_matrix:
    """0/1 matrix A with A[index[e], e] = 1: A @ values sums values into rows (scatter-add)."""
    n = index.shape[0]
    return scipy.sparse.csr_matrix((np.ones(n), (index, np.arange(n))), shape=(n_rows, n))


@dataclass(frozen=True, eq=False)
class SchurStructure:
    """Index structure of the normal equations, fixed during a solve.

    Attributes:
        n_blocks: Number of free pose blocks (6 columns each).
        n_feats: Number of features.
        slot_block: Free block of each observation slot, shape (K, S), -1 if none.
        feat_idx: Feature of each observation, shape (K,).
        pair_rows, pair_cols: Covisible block pairs (both orders, diagonal included).
        w_block, w_feat: Block and feature of each non-zero W block, shape (nW,).
    """

    n_blocks: int
    n_feats: int
    slot_block: IntArray
    feat_idx: IntArray
    pair_rows: IntArray
    pair_cols: IntArray
    w_block: IntArray
    w_feat: IntArray
    _u_chunks: list[tuple[slice, IntArray, IntArray, IntArray, scipy.sparse.csr_matrix]]
    _w_agg: scipy.sparse.csr_matrix
    _w_entries: IntArray
    _v_agg: scipy.sparse.csr_matrix
    _g_agg: scipy.sparse.csr_matrix
    _s_chunks: list[tuple[IntArray, IntArray, scipy.sparse.csr_matrix]]
    _diag_pairs: IntArray

    @classmethod
    def build(cls, slot_pose: IntArray, feat_idx: IntArray, n_feats: int,
              free_block: IntArray) -> SchurStructure:
        """Build the structure from pose slots (K, S), features (K,) and free blocks (M,)."""
        K, S = slot_pose.shape
        n_blocks = int(free_block.max()) + 1 if free_block.size and free_block.max() >= 0 else 0
        if n_blocks == 0:
            msg = 'no free pose: every pose is fixed'
            raise SolverError(msg)
        slot_block = np.where(slot_pose >= 0, free_block[np.maximum(slot_pose, 0)], -1)

        # W blocks: one per distinct (block, feature) among the observation slots.
        valid = slot_block >= 0
        kk, ss = np.nonzero(valid)
        keys = slot_block[kk, ss] * n_feats + feat_idx[kk]
        uniq, inv = np.unique(keys, return_inverse=True)
        w_block = uniq // n_feats
        w_feat = uniq % n_feats
        order = np.argsort(w_feat, kind='stable')
        rank = np.empty_like(order)
        rank[order] = np.arange(order.shape[0])
        w_block, w_feat = w_block[order], w_feat[order]
        w_entry_of = rank[inv]
        w_agg = _aggregator(w_entry_of, w_block.shape[0])
        w_entries = kk * S + ss

        # Schur pairs: every ordered pair of W blocks of one feature.
        counts = np.bincount(w_feat, minlength=n_feats)
        starts = np.concatenate([[0], np.cumsum(counts)])[:-1]
        per_entry = counts[w_feat]
        q1 = np.repeat(np.arange(w_feat.shape[0]), per_entry)
        first = np.repeat(starts[w_feat], per_entry)
        offs = np.cumsum(per_entry) - per_entry
        q2 = first + (np.arange(q1.shape[0]) - np.repeat(offs, per_entry))

        # U pairs: every ordered pair of valid slots of one observation.
        u_k, u_s, u_t = [], [], []
        for s in range(S):
            for t in range(S):
                k = np.flatnonzero(valid[:, s] & valid[:, t])
                u_k.append(k)
                u_s.append(np.full(k.shape[0], s))
                u_t.append(np.full(k.shape[0], t))
        uk, us, ut = np.concatenate(u_k), np.concatenate(u_s), np.concatenate(u_t)
        o = np.argsort(uk, kind='stable')
        uk, us, ut = uk[o], us[o], ut[o]

        pair_keys = np.concatenate([
            slot_block[uk, us] * n_blocks + slot_block[uk, ut],
            w_block[q1] * n_blocks + w_block[q2],
            np.arange(n_blocks) * (n_blocks + 1)])
        pair_uniq, pair_inv = np.unique(pair_keys, return_inverse=True)
        n_u = uk.shape[0]
        n_s = q1.shape[0]
        u_pair = pair_inv[:n_u]
        s_pair = pair_inv[n_u:n_u + n_s]
        n_pairs = pair_uniq.shape[0]
        u_chunks = []
        for lo in range(0, n_u, _CHUNK):
            sl = slice(lo, min(lo + _CHUNK, n_u))
            u_chunks.append((sl, uk[sl], us[sl], ut[sl], _aggregator(u_pair[sl], n_pairs)))
        s_chunks = []
        for lo in range(0, n_s, _CHUNK):
            sl = slice(lo, min(lo + _CHUNK, n_s))
            s_chunks.append((q1[sl], q2[sl], _aggregator(s_pair[sl], n_pairs)))
        pair_rows = pair_uniq // n_blocks
        pair_cols = pair_uniq % n_blocks
        diag_pairs = np.flatnonzero(pair_rows == pair_cols)
        g_index = slot_block[kk, ss]
        return cls(n_blocks, n_feats, slot_block, feat_idx, pair_rows, pair_cols, w_block,
                   w_feat, u_chunks, w_agg, w_entries, _aggregator(feat_idx, n_feats),
                   _aggregator(g_index, n_blocks), s_chunks, diag_pairs)


@dataclass(frozen=True, eq=False)
class NormalEquations:
    """Values of the normal equations at one linearization point (unscaled).

    Attributes:
        U: Pose blocks per covisible pair, shape (n_pairs, 6, 6).
        W: Pose-feature blocks, shape (nW, 6, 3).
        V: Feature blocks, shape (N, 3, 3).
        g_pose: Gradient J_T^T r, shape (n_blocks, 6).
        g_feat: Gradient J_F^T r, shape (N, 3).
    """

    U: FloatArray
    W: FloatArray
    V: FloatArray
    g_pose: FloatArray
    g_feat: FloatArray


def assemble(structure: SchurStructure, residuals: FloatArray, J_pose: FloatArray,
             J_feat: FloatArray) -> NormalEquations:
    """Assemble U, W, V and the gradient from residuals (K, d) and Jacobians.

    Args:
        structure: The problem's :class:`SchurStructure`.
        residuals: Residuals, shape (K, d).
        J_pose: Pose Jacobian blocks per slot, shape (K, S, d, 6).
        J_feat: Feature Jacobian blocks, shape (K, d, 3).
    """
    K, S = structure.slot_block.shape
    n_pairs = structure.pair_rows.shape[0]
    U = np.zeros((n_pairs, 36))
    for sl, uk, us, ut, agg in structure._u_chunks:
        del sl
        blocks = np.swapaxes(J_pose[uk, us], 1, 2) @ J_pose[uk, ut]
        U += agg @ blocks.reshape(-1, 36)
    Jp_flat = J_pose.reshape(K * S, J_pose.shape[2], 6)[structure._w_entries]
    Jf_of = J_feat[structure._w_entries // S]
    W = structure._w_agg @ (np.swapaxes(Jp_flat, 1, 2) @ Jf_of).reshape(-1, 18)
    V = structure._v_agg @ (np.swapaxes(J_feat, 1, 2) @ J_feat).reshape(-1, 9)
    r_of = residuals[structure._w_entries // S]
    g_pose = structure._g_agg @ np.einsum('kdi,kd->ki', Jp_flat, r_of)
    g_feat = structure._v_agg @ np.einsum('kdi,kd->ki', J_feat, residuals)
    return NormalEquations(U.reshape(-1, 6, 6), W.reshape(-1, 6, 3), V.reshape(-1, 3, 3),
                           np.asarray(g_pose), np.asarray(g_feat))


def diagonal(structure: SchurStructure, eqs: NormalEquations) -> tuple[FloatArray, FloatArray]:
    """Return diag(J^T J) split into pose (n_blocks, 6) and feature (N, 3) parts."""
    d_pose = np.zeros((structure.n_blocks, 6))
    d_pose[structure.pair_rows[structure._diag_pairs]] = np.diagonal(
        eqs.U[structure._diag_pairs], axis1=1, axis2=2)
    return d_pose, np.diagonal(eqs.V, axis1=1, axis2=2).copy()


def scale(structure: SchurStructure, eqs: NormalEquations, c_pose: FloatArray,
          c_feat: FloatArray) -> NormalEquations:
    """Return the equations of the column-scaled Jacobian J diag(c) (Jacobi scaling)."""
    cp_r = c_pose[structure.pair_rows]
    cp_c = c_pose[structure.pair_cols]
    return NormalEquations(
        eqs.U * cp_r[:, :, None] * cp_c[:, None, :],
        eqs.W * c_pose[structure.w_block][:, :, None] * c_feat[structure.w_feat][:, None, :],
        eqs.V * c_feat[:, :, None] * c_feat[:, None, :],
        eqs.g_pose * c_pose, eqs.g_feat * c_feat)


class ReducedSystemError(SolverError):
    """The reduced camera system is not positive definite."""


def solve_schur(structure: SchurStructure, eqs: NormalEquations, damp_pose: FloatArray,
                damp_feat: FloatArray, pose_free: BoolArray,
                ) -> tuple[FloatArray, FloatArray]:
    """Solve (H + diag(damp)) x = -g by the Schur complement on the poses.

    Args:
        structure: Index structure.
        eqs: Normal equations (already scaled, if scaling is used).
        damp_pose: Diagonal added to the pose blocks, shape (n_blocks, 6).
        damp_feat: Diagonal added to the feature blocks, shape (N, 3).
        pose_free: Pose columns that are solved for, shape (n_blocks, 6); the others (gauge)
            are held at zero.

    Returns:
        x_pose (n_blocks, 6) and x_feat (N, 3).

    Raises:
        ReducedSystemError: If S or a feature block is not positive definite.
    """
    V = eqs.V + damp_feat[:, :, None] * np.eye(3)
    try:
        V_inv = np.linalg.inv(V)
    except np.linalg.LinAlgError as err:
        msg = 'singular feature block'
        raise ReducedSystemError(msg) from err
    if not np.all(np.isfinite(V_inv)):
        msg = 'singular feature block'
        raise ReducedSystemError(msg)
    T = eqs.W @ V_inv[structure.w_feat]                         # W V^-1, per W block
    S_blocks = eqs.U.reshape(-1, 36).copy()
    for q1, q2, agg in structure._s_chunks:
        S_blocks -= agg @ (T[q1] @ np.swapaxes(eqs.W[q2], 1, 2)).reshape(-1, 36)
    nb = structure.n_blocks
    Vg = np.einsum('nij,nj->ni', V_inv, eqs.g_feat)
    rhs = -eqs.g_pose + _scatter_w(structure, np.einsum('qij,qj->qi', eqs.W, Vg[structure.w_feat]))
    free = pose_free.reshape(-1)
    dim = nb * 6
    rows = (structure.pair_rows[:, None] * 6 + np.arange(6)[None, :])
    cols = (structure.pair_cols[:, None] * 6 + np.arange(6)[None, :])
    S_blocks = S_blocks.reshape(-1, 6, 6)
    d_idx = np.arange(nb)
    x = np.zeros(dim)
    if int(free.sum()) <= DENSE_LIMIT:
        S = np.zeros((dim, dim))
        S[rows[:, :, None], cols[:, None, :]] = S_blocks
        S[d_idx[:, None] * 6 + np.arange(6), d_idx[:, None] * 6 + np.arange(6)] += damp_pose
        try:
            factor = scipy.linalg.cho_factor(S[np.ix_(free, free)], check_finite=False)
        except (np.linalg.LinAlgError, ValueError) as err:
            msg = 'reduced camera system is not positive definite'
            raise ReducedSystemError(msg) from err
        x[free] = scipy.linalg.cho_solve(factor, rhs.reshape(-1)[free], check_finite=False)
    else:
        r_idx = np.broadcast_to(rows[:, :, None], S_blocks.shape).reshape(-1)
        c_idx = np.broadcast_to(cols[:, None, :], S_blocks.shape).reshape(-1)
        diag = np.arange(dim)
        S_sp = scipy.sparse.csc_matrix(
            (np.concatenate([S_blocks.reshape(-1), damp_pose.reshape(-1)]),
             (np.concatenate([r_idx, diag]), np.concatenate([c_idx, diag]))), shape=(dim, dim))
        S_sp = S_sp[free][:, free]
        try:
            lu = scipy.sparse.linalg.splu(S_sp.tocsc(), permc_spec='MMD_AT_PLUS_A')
        except RuntimeError as err:
            msg = 'reduced camera system is singular'
            raise ReducedSystemError(msg) from err
        x[free] = lu.solve(rhs.reshape(-1)[free])
    if not np.all(np.isfinite(x)):
        msg = 'reduced camera system solve produced non-finite values'
        raise ReducedSystemError(msg)
    x_pose = x.reshape(nb, 6)
    Wt_x = np.einsum('qji,qj->qi', eqs.W, x_pose[structure.w_block])
    x_feat = np.einsum('nij,nj->ni', V_inv, -eqs.g_feat - _scatter_feat(structure, Wt_x))
    return x_pose, x_feat


def _scatter_w(structure: SchurStructure, values: FloatArray) -> FloatArray:
    """Sum per-W-block pose vectors (nW, 6) into blocks (n_blocks, 6)."""
    out = np.zeros((structure.n_blocks, 6))
    for i in range(6):
        out[:, i] = np.bincount(structure.w_block, weights=values[:, i],
                                minlength=structure.n_blocks)
    return out


def _scatter_feat(structure: SchurStructure, values: FloatArray) -> FloatArray:
    """Sum per-W-block feature vectors (nW, 3) into features (N, 3)."""
    out = np.zeros((structure.n_feats, 3))
    for i in range(3):
        out[:, i] = np.bincount(structure.w_feat, weights=values[:, i],
                                minlength=structure.n_feats)
    return out


def jacobian_product(structure: SchurStructure, J_pose: FloatArray, J_feat: FloatArray,
                     x_pose: FloatArray, x_feat: FloatArray) -> FloatArray:
    """Return J x per observation, shape (K, d), for pose (n_blocks, 6) and feature (N, 3) steps."""
    blocks = structure.slot_block
    xp = np.where((blocks >= 0)[:, :, None], x_pose[np.maximum(blocks, 0)], 0.0)
    return (np.einsum('ksdi,ksi->kd', J_pose, xp)
            + np.einsum('kdi,ki->kd', J_feat, x_feat[structure.feat_idx]))
