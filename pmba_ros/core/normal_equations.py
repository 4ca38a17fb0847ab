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
    """0/1 matrix A with A[index[e], e] = 1: A @ values sums values into rows (scatter-add).

    Entries with index -1 are left out.
    """
    keep = index >= 0
    # At most one entry per column: the CSC arrays are direct, and CSC -> CSR is linear.
    indptr = np.concatenate([[0], np.cumsum(keep)])
    rows = index[keep]
    agg = scipy.sparse.csc_matrix((np.ones(rows.shape[0]), rows, indptr),
                                  shape=(n_rows, index.shape[0]))
    return agg.tocsr()


def _schur_chunks(counts: IntArray, starts: IntArray, w_block: IntArray, n_blocks: int,
                  pair_uniq: IntArray) -> list[tuple[IntArray, scipy.sparse.csr_matrix]]:
    """Group features by their number c of W blocks for one (6c x 3)(3 x 6c) product each.

    Returns (W index (n, c), aggregator) per group: the aggregator adds row i of block (a, b),
    a <= b, of every feature's W V^-1 W^T (rows of 6 values, flat row (f 6c + 6a + i) c + b)
    to row 6 pair(a, b) + i of the reduced system.
    """
    chunks = []
    for c in np.unique(counts[counts > 0]):
        feats = np.flatnonzero(counts == c)
        per_feat = 36 * c * c
        step = max(1, _CHUNK * 18 // per_feat)
        for lo in range(0, feats.shape[0], step):
            idx = starts[feats[lo:lo + step]][:, None] + np.arange(c)      # (n, c)
            blk = w_block[idx]
            keys = blk[:, :, None] * n_blocks + blk[:, None, :]           # (n, a, b)
            pair = np.searchsorted(pair_uniq, keys)[:, :, None, :]           # (n, a, 1, b)
            rows = pair * 6 + np.arange(6)[:, None]                        # (n, a, i, b)
            lower = np.arange(c)[:, None] > np.arange(c)[None, :]
            rows[np.broadcast_to(lower[None, :, None, :], rows.shape)] = -1
            chunks.append((idx, _aggregator(rows.reshape(-1), 6 * pair_uniq.shape[0])))
    return chunks


def _unique_inverse(keys: IntArray, n_keys: int) -> tuple[IntArray, IntArray]:
    """np.unique(keys, return_inverse=True) for keys in [0, n_keys), without sorting if small."""
    if n_keys > 50_000_000:
        uniq, inv = np.unique(keys, return_inverse=True)
        return uniq, inv.reshape(-1)
    present = np.zeros(n_keys, dtype=bool)
    present[keys] = True
    rank = np.cumsum(present) - 1
    return np.flatnonzero(present), rank[keys]


@dataclass(frozen=True, eq=False)
class _ObsChunk:
    """Aggregators of one chunk of observations [lo, hi) (entries are (k, s) or (k, s, t))."""

    lo: int
    hi: int
    u_agg: scipy.sparse.csr_matrix  # (6 n_pairs, 6 n S S): rows of U blocks, see assemble
    w_agg: scipy.sparse.csr_matrix  # (nW, n * S): W blocks per slot
    g_agg: scipy.sparse.csr_matrix  # (n_blocks, n * S): pose gradient per slot


@dataclass(frozen=True, eq=False)
class SchurStructure:
    """Index structure of the normal equations, fixed during a solve.

    Attributes:
        n_blocks: Number of free pose blocks (6 columns each).
        n_feats: Number of features.
        slot_block: Free block of each observation slot, shape (K, S), -1 if none.
        feat_idx: Feature of each observation, shape (K,).
        pair_rows, pair_cols: Covisible block pairs, upper triangle (row <= col) incl. the
            diagonal: S is symmetric and its lower blocks are the transposes.
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
    _obs_chunks: list[_ObsChunk]
    _s_chunks: list[tuple[IntArray, scipy.sparse.csr_matrix]]
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
        valid = (slot_block >= 0).reshape(-1)               # per entry e = k * S + s
        entry_block = slot_block.reshape(-1)
        entry_feat = np.repeat(feat_idx, S)

        # W blocks: one per distinct (feature, block), sorted by feature, then block.
        keys = entry_feat * n_blocks + entry_block
        uniq, inv = _unique_inverse(keys[valid], n_feats * n_blocks)
        w_block, w_feat = uniq % n_blocks, uniq // n_blocks
        entry_w = np.full(K * S, -1)
        entry_w[valid] = inv

        # Schur pairs: every ordered pair of W blocks of one feature.
        counts = np.bincount(w_feat, minlength=n_feats)
        starts = np.concatenate([[0], np.cumsum(counts)])[:-1]
        per_entry = counts[w_feat]
        q1 = np.repeat(np.arange(w_feat.shape[0]), per_entry)
        first = np.repeat(starts[w_feat], per_entry)
        offs = np.cumsum(per_entry) - per_entry
        q2 = first + (np.arange(q1.shape[0]) - np.repeat(offs, per_entry))
        # S is symmetric: keep the upper block triangle only (a feature's W blocks are sorted
        # by pose block, so q1 <= q2 means block(q1) <= block(q2)).
        upper = q1 <= q2
        q1, q2 = q1[upper], q2[upper]

        # U entries (k, s, t) with both slots valid, upper block triangle only; entries of two
        # slots on the same pose (observer = associate anchor) are all kept.
        vs = valid.reshape(K, S)
        u_valid = (vs[:, :, None] & vs[:, None, :]
                   & (slot_block[:, :, None] <= slot_block[:, None, :])).reshape(-1)
        u_keys = (slot_block[:, :, None] * n_blocks + slot_block[:, None, :]).reshape(-1)

        pair_keys = np.concatenate([u_keys[u_valid], w_block[q1] * n_blocks + w_block[q2],
                                    np.arange(n_blocks) * (n_blocks + 1)])
        pair_uniq, pair_inv = _unique_inverse(pair_keys, n_blocks * n_blocks)
        n_pairs = pair_uniq.shape[0]
        u_pair = np.full(u_keys.shape[0], -1)
        u_pair[u_valid] = pair_inv[:int(u_valid.sum())]

        # Row i of the (s, t) block of observation k's J^T J (6S x 6S, row-major) starts at
        # flat row (k * 6S + 6s + i) * S + t of the (., 6) view; it adds to row 6 pair + i.
        u_pair_kst = u_pair.reshape(K, S, 1, S)
        u_rows = u_pair_kst * 6 + np.arange(6)[:, None]              # order (k, s, i, t)
        u_rows[np.broadcast_to(u_pair_kst < 0, u_rows.shape)] = -1
        u_rows = u_rows.reshape(-1)
        step = max(1, _CHUNK // (S * S))
        obs_chunks = []
        for lo in range(0, K, step):
            hi = min(lo + step, K)
            per_obs = 6 * S * S
            obs_chunks.append(_ObsChunk(
                lo, hi, _aggregator(u_rows[lo * per_obs:hi * per_obs], 6 * n_pairs),
                _aggregator(entry_w[lo * S:hi * S], w_block.shape[0]),
                _aggregator(entry_block[lo * S:hi * S], n_blocks)))
        s_chunks = _schur_chunks(counts, starts, w_block, n_blocks, pair_uniq)
        pair_rows = pair_uniq // n_blocks
        pair_cols = pair_uniq % n_blocks
        return cls(n_blocks, n_feats, slot_block, feat_idx, pair_rows, pair_cols, w_block,
                   w_feat, obs_chunks, s_chunks, np.flatnonzero(pair_rows == pair_cols))


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
    S, d = J_pose.shape[1], J_pose.shape[2]
    n_pairs = structure.pair_rows.shape[0]
    U = np.zeros((6 * n_pairs, 6))
    W = np.zeros((structure.w_block.shape[0], 18))
    g_pose = np.zeros((structure.n_blocks, 6))
    for ch in structure._obs_chunks:
        n = ch.hi - ch.lo
        # One observation's pose Jacobian as d x 6S: J^T J holds all its slot-pair blocks.
        Jk = np.swapaxes(J_pose[ch.lo:ch.hi], 1, 2).reshape(n, d, 6 * S)
        JkT = np.swapaxes(Jk, 1, 2)
        U += ch.u_agg @ (JkT @ Jk).reshape(-1, 6)
        W += ch.w_agg @ (JkT @ J_feat[ch.lo:ch.hi]).reshape(-1, 18)
        g_pose += ch.g_agg @ (JkT @ residuals[ch.lo:ch.hi, :, None]).reshape(-1, 6)
    JfT = np.swapaxes(J_feat, 1, 2)
    V = _scatter_add(structure.feat_idx, (JfT @ J_feat).reshape(-1, 9), structure.n_feats)
    g_feat = _scatter_add(structure.feat_idx, np.einsum('kid,kd->ki', JfT, residuals),
                          structure.n_feats)
    return NormalEquations(U.reshape(-1, 6, 6), W.reshape(-1, 6, 3), V.reshape(-1, 3, 3),
                           g_pose, g_feat)


def _scatter_add(index: IntArray, values: FloatArray, n_rows: int) -> FloatArray:
    """Sum rows of ``values`` (n, c) into (n_rows, c) by ``index`` (n,), one bincount a column."""
    out = np.empty((n_rows, values.shape[1]))
    for i in range(values.shape[1]):
        out[:, i] = np.bincount(index, weights=values[:, i], minlength=n_rows)
    return out


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
    S_flat = eqs.U.reshape(-1, 6).copy()
    for idx, agg in structure._s_chunks:
        n, c = idx.shape
        T_f = T[idx].reshape(n, 6 * c, 3)
        W_f = eqs.W[idx].reshape(n, 6 * c, 3)
        S_flat -= agg @ (T_f @ np.swapaxes(W_f, 1, 2)).reshape(-1, 6)
    nb = structure.n_blocks
    Vg = np.einsum('nij,nj->ni', V_inv, eqs.g_feat)
    rhs = -eqs.g_pose + _scatter_add(structure.w_block,
                                     np.einsum('qij,qj->qi', eqs.W, Vg[structure.w_feat]),
                                     structure.n_blocks)
    free = pose_free.reshape(-1)
    dim = nb * 6
    rows = (structure.pair_rows[:, None] * 6 + np.arange(6)[None, :])
    cols = (structure.pair_cols[:, None] * 6 + np.arange(6)[None, :])
    S_blocks = S_flat.reshape(-1, 6, 6)
    d_idx = np.arange(nb)
    x = np.zeros(dim)
    if int(free.sum()) <= DENSE_LIMIT:
        S = np.zeros((dim, dim))
        S[rows[:, :, None], cols[:, None, :]] = S_blocks
        S[cols[:, :, None], rows[:, None, :]] = np.swapaxes(S_blocks, 1, 2)
        S[d_idx[:, None] * 6 + np.arange(6), d_idx[:, None] * 6 + np.arange(6)] += damp_pose
        try:
            factor = scipy.linalg.cho_factor(S[np.ix_(free, free)], check_finite=False)
        except (np.linalg.LinAlgError, ValueError) as err:
            msg = 'reduced camera system is not positive definite'
            raise ReducedSystemError(msg) from err
        x[free] = scipy.linalg.cho_solve(factor, rhs.reshape(-1)[free], check_finite=False)
    else:
        off = structure.pair_rows != structure.pair_cols
        r_idx = np.broadcast_to(rows[:, :, None], S_blocks.shape)
        c_idx = np.broadcast_to(cols[:, None, :], S_blocks.shape)
        diag = np.arange(dim)
        S_sp = scipy.sparse.csc_matrix(
            (np.concatenate([S_blocks.reshape(-1), S_blocks[off].reshape(-1),
                             damp_pose.reshape(-1)]),
             (np.concatenate([r_idx.reshape(-1), c_idx[off].reshape(-1), diag]),
              np.concatenate([c_idx.reshape(-1), r_idx[off].reshape(-1), diag]))),
            shape=(dim, dim))
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
    W_x = _scatter_add(structure.w_feat, Wt_x, structure.n_feats)
    x_feat = np.einsum('nij,nj->ni', V_inv, -eqs.g_feat - W_x)
    return x_pose, x_feat


def quadratic_form(structure: SchurStructure, eqs: NormalEquations, x_pose: FloatArray,
                   x_feat: FloatArray) -> float:
    """Return x^T H x for H = J^T J held as (upper) U, W and V blocks; cheaper than |J x|^2."""
    r, c = structure.pair_rows, structure.pair_cols
    Ux = np.einsum('pij,pj->pi', eqs.U, x_pose[c])
    weight = np.where(r == c, 1.0, 2.0)  # off-diagonal blocks stand for themselves and U^T
    quad = float(np.sum(weight * np.sum(x_pose[r] * Ux, axis=1)))
    Wx = np.einsum('qij,qj->qi', eqs.W, x_feat[structure.w_feat])
    quad += 2.0 * float(np.sum(x_pose[structure.w_block] * Wx))
    quad += float(np.sum(x_feat * np.einsum('nij,nj->ni', eqs.V, x_feat)))
    return quad
