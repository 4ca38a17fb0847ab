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
(PMBA: main anchor, and the associate anchor's centre; IDP: the anchor pose; XYZ: none). So
the anchor rows of J^T J are summed per feature, by one (c d x A) product per feature of c
observations, and only the observer rows are formed per observation. Features are ordered by
their number of observations (see :func:`feature_order`), so the features with c
observations hold a contiguous range of observations and every per-feature product is a
reshape, never a gather.

The Schur complement forms each feature's W V^-1 W^T blocks for observation pairs (a, b),
a <= b, only: one product per offset b - a for chunks of many features, one per pair for
small chunks, in cache-sized batches; the blocks of both orders of a pose pair meet in a
final fold. Small problems (few poses) instead take one dense product over all pose columns,
whichever needs fewer multiply-adds. Every index array that depends only on the structure is
built once in :class:`SchurStructure`; each iteration fills values, with no Python loop over
observations (scatter-adds are sparse products with 0/1 matrices).

Where numba is installed (and up to :data:`compiled.assembly.MAX_BLOCKS` free poses) the
structure is only the covisible pose pairs, and assembly, scaling, reduction,
back-substitution and x^T H x run as the compiled loops of :mod:`pmba_ros.core.compiled`;
both paths give the same numbers to rounding (``test_normal_equations.py`` runs every one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pmba_ros._threads import blas_threads_for
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import compiled
from pmba_ros.core.compiled import assembly as compiled_assembly
from pmba_ros.core.compiled import schur as compiled_schur
from pmba_ros.core.jacobian import ANCHOR_START, Linearization
from pmba_ros.errors import SolverError
import scipy.linalg
import scipy.linalg.lapack
import scipy.sparse
import scipy.sparse.linalg

#: Observations (or 6x6 blocks) per vectorized chunk; bounds temporary memory.
_CHUNK = 100_000
#: 6x6 blocks per Schur batch: the buffer (1.2 MB) stays in cache until it is summed.
_SCHUR_BATCH = 4096
#: Feature chunks with fewer features form their Schur blocks pair by pair (gathers) rather
#: than in one product per delta (Python calls).
LOOP_MIN_FEATURES = 64
#: Dense Schur products when they take fewer multiply-adds than this many times the per-pair
#: ones: long tracks (many observations per feature) favour the dense products, short ones
#: the per-pair path (chosen on the street's and KITTI-00's 20-pose windows).
DENSE_SCHUR_RATIO = 2500
#: Above this many free pose columns the reduced system is solved as a sparse matrix.
DENSE_LIMIT = 6000


def feature_order(feat_idx: IntArray, n_feats: int) -> IntArray:
    """Return features sorted by their number of observations (stable): new -> old index."""
    counts = np.bincount(feat_idx, minlength=n_feats)
    return np.argsort(counts, kind='stable')


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


def _unique_inverse(keys: IntArray, n_keys: int) -> tuple[IntArray, IntArray]:
    """np.unique(keys, return_inverse=True) for keys in [0, n_keys), without sorting if small."""
    if n_keys > 50_000_000:
        uniq, inv = np.unique(keys, return_inverse=True)
        return uniq, inv.reshape(-1)
    present = np.zeros(n_keys, dtype=bool)
    present[keys] = True
    rank = np.cumsum(present) - 1
    return np.flatnonzero(present), rank[keys]


def _lookup(sorted_keys: IntArray, keys: IntArray) -> IntArray:
    """Index of each key in ``sorted_keys`` (all present), -1 where the key is -1."""
    out = np.searchsorted(sorted_keys, np.maximum(keys, 0))
    return np.where(keys >= 0, out, -1)


def _find(sorted_keys: IntArray, keys: IntArray) -> IntArray:
    """Index of each key in ``sorted_keys``, or len(sorted_keys) where it is absent."""
    n = sorted_keys.shape[0]
    if n == 0:
        return np.zeros(keys.shape, dtype=np.int64)
    idx = np.minimum(np.searchsorted(sorted_keys, keys), n - 1)
    return np.where(sorted_keys[idx] == keys, idx, n)


def _pair_key(a: IntArray, b: IntArray, n_blocks: int) -> IntArray:
    """Key a * n_blocks + b of a directed block pair, -1 if either block is -1."""
    return np.where((a >= 0) & (b >= 0), a * n_blocks + b, -1)


@dataclass(frozen=True, eq=False)
class _ObsChunk:
    """Aggregators of the observations [lo, hi)."""

    lo: int
    hi: int
    self_agg: scipy.sparse.csr_matrix     # (n_blocks, n): observer block
    cross_aggs: list[scipy.sparse.csr_matrix]  # per anchor slot, (n_dir, n)


@dataclass(frozen=True, eq=False)
class _FeatChunk:
    """Features [f_lo, f_hi) with c observations each: observations [lo, hi)."""

    lo: int
    hi: int
    f_lo: int
    f_hi: int
    c: int


@dataclass(frozen=True, eq=False)
class _SchurBatch:
    """Schur products written to one buffer and summed by one aggregator.

    Each task (chunk, delta, row) puts the blocks (a, a + delta) of W V^-1 W^T of the chunk's
    features, in (feature, a) order, at buffer rows [row, row + n (c - delta)); then the
    blocks of the observation pairs (pair_a, pair_b) follow, one product each (small chunks,
    where one product per delta would cost more in calls than the gathers). ``agg`` adds the
    rows to [0, n_blocks) (a = b: the pose block) or n_blocks + directed pair.
    """

    n_rows: int
    tasks: list[tuple[int, int, int]]
    pair_a: IntArray
    pair_b: IntArray
    agg: scipy.sparse.csr_matrix


def _anchors(cam_idx: IntArray, feat_idx: IntArray, slot_pose: IntArray, starts: IntArray,
             ) -> tuple[IntArray, IntArray]:
    """Return each feature's anchor poses (N, S - 1) and its observation by each, or -1.

    An anchor slot names one pose per feature; unused entries are -1, so it is the maximum.
    """
    n_feats, n_anchor = starts.shape[0] - 1, slot_pose.shape[1] - 1
    anchor_pose = np.full((n_feats, n_anchor), -1, dtype=np.int64)
    anchor_obs = np.full((n_feats, n_anchor), -1, dtype=np.int64)
    for s in range(n_anchor):
        col = slot_pose[:, s + 1]
        anchor_pose[:, s] = np.maximum.reduceat(col, starts[:-1])
        per_obs = anchor_pose[feat_idx, s]
        if np.any((col >= 0) & (col != per_obs)):
            msg = f'anchor slot {s + 1} names different poses within one feature'
            raise SolverError(msg)
        hit = np.flatnonzero(cam_idx == per_obs)
        anchor_obs[feat_idx[hit], s] = hit
        if np.any((anchor_pose[:, s] >= 0) & (anchor_obs[:, s] < 0)):
            msg = f'anchor slot {s + 1}: an anchor pose does not observe its feature'
            raise SolverError(msg)
    return anchor_pose, anchor_obs


def _batches(tasks: list[tuple[int, int, IntArray]],
             pairs: list[tuple[IntArray, IntArray, IntArray]], obs_block: IntArray,
             dir_uniq: IntArray, n_blocks: int) -> list[_SchurBatch]:
    """Group the Schur products into batches of about _SCHUR_BATCH blocks, one aggregator each.

    Tasks are (chunk, delta, pair keys) and pairs (a rows, b rows, keys; -2 where a = b).
    """
    n_rows = n_blocks + dir_uniq.shape[0]
    none = np.zeros(0, dtype=np.int64)
    batches = []
    batch: list[tuple[int, int, IntArray]] = []
    rows = 0
    for i, task in enumerate(tasks):
        batch.append(task)
        rows += task[2].shape[0]
        if rows >= _SCHUR_BATCH or i == len(tasks) - 1:
            targets = np.concatenate(
                [k if delta == 0 else np.where(k >= 0, n_blocks + _lookup(dir_uniq, k), -1)
                 for _, delta, k in batch])
            offsets = np.cumsum([0] + [k.shape[0] for *_, k in batch])[:-1]
            batches.append(_SchurBatch(
                rows, [(fi, delta, int(off))
                       for (fi, delta, _), off in zip(batch, offsets, strict=True)],
                none, none, _aggregator(targets, n_rows)))
            batch, rows = [], 0
    if pairs:
        ia, ib, keys = (np.concatenate(x) for x in zip(*pairs, strict=True))
        targets = np.where(keys == -2, obs_block[ia],
                           np.where(keys >= 0, n_blocks + _lookup(dir_uniq, keys), -1))
        for lo in range(0, ia.shape[0], _SCHUR_BATCH):
            hi = min(lo + _SCHUR_BATCH, ia.shape[0])
            batches.append(_SchurBatch(hi - lo, [], ia[lo:hi], ib[lo:hi],
                                       _aggregator(targets[lo:hi], n_rows)))
    return batches


@dataclass(frozen=True, eq=False)
class SchurStructure:
    """Index structure of the normal equations, fixed during a solve.

    Observations must be sorted by feature, and features by their number of observations
    (:func:`feature_order`).

    Attributes:
        n_blocks: Number of free pose blocks (6 columns each).
        n_feats: Number of features.
        n_dir: Number of directed block pairs (a, b) that receive off-diagonal sums.
        feat_idx: Feature of each observation (and of its W block), shape (K,).
        anchor_cols: Pose columns (start, stop) of each anchor slot.
        pair_rows, pair_cols: Covisible block pairs, upper triangle (row <= col) incl. the
            diagonal: S is symmetric and its lower blocks are the transposes.
        w_block: Pose block of each W block (one per observation: the block of its observer,
            0 with a zero W block if that pose is fixed), shape (K,).
    """

    n_blocks: int
    n_feats: int
    n_dir: int
    feat_idx: IntArray
    anchor_cols: tuple[tuple[int, int], ...]
    pair_rows: IntArray
    pair_cols: IntArray
    w_block: IntArray
    _obs_fixed: BoolArray
    _anchor_block: IntArray   # (N, S - 1)
    _anchor_obs: IntArray     # (N, S - 1) observation of the feature by each anchor, or -1
    _anchor_self: list[scipy.sparse.csr_matrix]         # per slot s: (n_blocks, N)
    _anchor_cross: dict[tuple[int, int], scipy.sparse.csr_matrix]  # s < t: (n_dir, N)
    _obs_chunks: list[_ObsChunk]
    _feat_chunks: list[_FeatChunk]
    _schur_batches: list[_SchurBatch]
    _dense_schur: bool
    _fold_fwd: IntArray       # directed pair (row, col) of each upper pair, or n_dir (zero)
    _fold_bwd: IntArray       # directed pair (col, row), or n_dir
    _diag_pairs: IntArray
    _starts: IntArray         # (N + 1,) first observation of each feature
    _obs_block: IntArray      # (K,) free block of each observer, -1 if fixed
    _pair_index: IntArray | None  # (n_blocks, n_blocks) upper pair of (a, b), a <= b; compiled

    @classmethod
    def build(cls, cam_idx: IntArray, feat_idx: IntArray, slot_pose: IntArray, n_feats: int,
              free_block: IntArray, anchor_cols: tuple[tuple[int, int], ...] = (),
              ) -> SchurStructure:
        """Build the structure of K observations.

        Args:
            cam_idx: Observing pose of each observation, shape (K,).
            feat_idx: Feature of each observation, shape (K,), ordered as the class requires.
            slot_pose: Pose of each Jacobian slot, shape (K, S): slot 0 is the observer (or
                -1 where its block is zero), slots 1.. are anchors, the same pose for every
                observation of a feature (or -1 where that block is zero).
            n_feats: Number of features N.
            free_block: Free block of each pose, shape (M,), -1 for fixed poses.
            anchor_cols: Columns (start, stop) of the pose that each anchor slot touches.

        Raises:
            SolverError: If no pose is free or the observations are not ordered.
        """
        K, S = slot_pose.shape
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
        obs_block = free_block[cam_idx]

        n_anchor = S - 1
        anchor_pose, anchor_obs = _anchors(cam_idx, feat_idx, slot_pose, starts)
        anchor_block = np.where(anchor_pose >= 0, free_block[np.maximum(anchor_pose, 0)], -1)

        if compiled.ENABLED and n_blocks <= compiled_assembly.MAX_BLOCKS:
            return cls._build_compiled(feat_idx, n_feats, obs_block, anchor_cols,
                                       anchor_block, anchor_obs, starts)

        # Directed block pairs: observer-anchor, anchor-anchor and Schur (a, a + delta).
        obs_anchor_keys = [_pair_key(obs_block, anchor_block[feat_idx, s], n_blocks)
                           for s in range(n_anchor)]
        anchor_keys = {(s, t): _pair_key(anchor_block[:, s], anchor_block[:, t], n_blocks)
                       for s in range(n_anchor) for t in range(s + 1, n_anchor)}
        # Small problems form W V^-1 W^T as one dense product over all pose columns (a few
        # BLAS calls); it pays when (6 n_blocks)^2 3 N multiply-adds cost less than the
        # per-pair products (about DENSE_SCHUR_RATIO times more per multiply-add in numpy).
        n_schur_pairs = int(np.sum(counts * (counts + 1) // 2))
        dense = ((6 * n_blocks) ** 2 * 3 * n_feats < DENSE_SCHUR_RATIO * n_schur_pairs
                 and 18 * n_feats * n_blocks <= 4_000_000)
        if dense:
            own = obs_block >= 0
            keys = feat_idx[own] * n_blocks + obs_block[own]
            dense = np.unique(keys).shape[0] == keys.shape[0]  # one W block per (j, pose)
        # Otherwise the Schur blocks (a, a + delta) of each chunk of features with c
        # observations: one product per delta for chunks of many features, one per pair
        # for the others.
        feat_chunks: list[_FeatChunk] = []
        tasks: list[tuple[int, int, IntArray]] = []
        pairs: list[tuple[IntArray, IntArray, IntArray]] = []
        for c in np.unique(counts):
            c = int(c)
            feats = np.flatnonzero(counts == c)
            step = max(1, _CHUNK // (c * c))
            for f_lo in range(int(feats[0]), int(feats[-1]) + 1, step):
                f_hi = min(f_lo + step, int(feats[-1]) + 1)
                lo, hi = int(starts[f_lo]), int(starts[f_hi])
                feat_chunks.append(_FeatChunk(lo, hi, f_lo, f_hi, c))
                if dense:
                    continue
                if f_hi - f_lo < LOOP_MIN_FEATURES:
                    ta, tb = np.triu_indices(c)
                    first = lo + c * np.arange(f_hi - f_lo)[:, None]
                    ia, ib = (first + ta).reshape(-1), (first + tb).reshape(-1)
                    keys = np.where(ia == ib, -2, _pair_key(obs_block[ia], obs_block[ib],
                                                            n_blocks))
                    pairs.append((ia, ib, keys))
                    continue
                fi = len(feat_chunks) - 1
                blk = obs_block[lo:hi].reshape(f_hi - f_lo, c)
                tasks.append((fi, 0, blk.reshape(-1)))
                tasks += [(fi, delta,
                           _pair_key(blk[:, :c - delta], blk[:, delta:], n_blocks).reshape(-1))
                          for delta in range(1, c)]
        all_keys = np.concatenate(
            [*obs_anchor_keys, *anchor_keys.values(),
             *(k for _, delta, k in tasks if delta > 0), *(k for *_, k in pairs),
             np.zeros(0, dtype=np.int64)])
        all_keys = all_keys[all_keys >= 0]
        dir_uniq, _ = _unique_inverse(all_keys, n_blocks * n_blocks)
        n_dir = dir_uniq.shape[0]

        # Upper pairs: every directed pair folded to row <= col, and the diagonal.
        a, b = dir_uniq // n_blocks, dir_uniq % n_blocks
        pair_keys = np.concatenate([np.minimum(a, b) * n_blocks + np.maximum(a, b),
                                    np.arange(n_blocks) * (n_blocks + 1)])
        if dense:
            upper_r, upper_c = np.triu_indices(n_blocks)
            pair_keys = upper_r * n_blocks + upper_c
        pair_uniq, _ = _unique_inverse(pair_keys, n_blocks * n_blocks)
        pair_rows, pair_cols = pair_uniq // n_blocks, pair_uniq % n_blocks

        # Each upper pair reads directed pair (row, col) and (col, row); n_dir is a zero block.
        fold_fwd = _find(dir_uniq, pair_rows * n_blocks + pair_cols)
        fold_bwd = _find(dir_uniq, pair_cols * n_blocks + pair_rows)

        obs_chunks = []
        for lo in range(0, K, _CHUNK):
            hi = min(lo + _CHUNK, K)
            obs_chunks.append(_ObsChunk(
                lo, hi, _aggregator(obs_block[lo:hi], n_blocks),
                [_aggregator(_lookup(dir_uniq, k[lo:hi]), n_dir) for k in obs_anchor_keys]))
        batches = _batches(tasks, pairs, obs_block, dir_uniq, n_blocks)
        anchor_self = [_aggregator(anchor_block[:, s], n_blocks) for s in range(n_anchor)]
        anchor_cross = {st: _aggregator(_lookup(dir_uniq, k), n_dir)
                        for st, k in anchor_keys.items()}
        return cls(n_blocks, n_feats, n_dir, feat_idx, tuple(anchor_cols), pair_rows, pair_cols,
                   np.maximum(obs_block, 0), obs_block < 0, anchor_block,
                   anchor_obs, anchor_self, anchor_cross, obs_chunks, feat_chunks, batches,
                   dense, fold_fwd, fold_bwd, np.flatnonzero(pair_rows == pair_cols), starts,
                   obs_block, None)

    @classmethod
    def _build_compiled(cls, feat_idx: IntArray, n_feats: int,
                        obs_block: IntArray, anchor_cols: tuple[tuple[int, int], ...],
                        anchor_block: IntArray, anchor_obs: IntArray, starts: IntArray,
                        ) -> SchurStructure:
        """Build the structure that the compiled loops of :mod:`compiled` read.

        The pose pairs are the covisible ones: two free poses that observe one feature (the
        anchors observe their features, so they are among the observers).
        """
        n_blocks = int(obs_block.max()) + 1
        pair_index = compiled_assembly.covisible_pairs(starts, obs_block, n_blocks)
        pair_rows, pair_cols = np.nonzero(pair_index >= 0)
        none = np.zeros(0, dtype=np.int64)
        return cls(n_blocks, n_feats, 0, feat_idx, tuple(anchor_cols), pair_rows, pair_cols,
                   np.maximum(obs_block, 0), obs_block < 0, anchor_block, anchor_obs, [], {},
                   [], [], [], False, none, none, np.flatnonzero(pair_rows == pair_cols),
                   starts, obs_block, pair_index)

    def fold(self, self_blocks: FloatArray, cross: FloatArray) -> FloatArray:
        """Return upper pair blocks (n_pairs, 6, 6) from per-block and directed-pair sums.

        A pair (x, y), x <= y, is cross(x, y) + cross(y, x)^T, plus self(x) on the diagonal.
        """
        padded = np.concatenate([cross, np.zeros((1, 6, 6))])
        out = padded[self._fold_fwd] + np.swapaxes(padded[self._fold_bwd], 1, 2)
        out[self._diag_pairs] += self_blocks[self.pair_rows[self._diag_pairs]]
        return out


@dataclass(frozen=True, eq=False)
class NormalEquations:
    """Values of the normal equations at one linearization point (unscaled).

    Attributes:
        U: Pose blocks per covisible pair, shape (n_pairs, 6, 6).
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


def assemble(structure: SchurStructure, lin: Linearization) -> NormalEquations:
    """Assemble U, W, V and the gradient from residuals and Jacobian blocks.

    Args:
        structure: The problem's :class:`SchurStructure`.
        lin: Residuals and Jacobian (observations in the structure's order).
    """
    st = structure
    if lin.anchor_cols != st.anchor_cols:
        msg = f'anchor columns {lin.anchor_cols} do not match the structure {st.anchor_cols}'
        raise SolverError(msg)
    E = lin.rows
    if st._pair_index is not None:
        return NormalEquations(*compiled_assembly.assemble(
            E, st._starts, st._obs_block, st._anchor_block,
            st._anchor_obs, st.anchor_cols, st._pair_index, st.pair_rows.shape[0]))
    K, d, width = E.shape
    nb, N, n_dir = st.n_blocks, st.n_feats, st.n_dir
    offs = lin.anchor_offsets()
    A = width - ANCHOR_START

    self_blocks = np.zeros((nb, 6, 6))
    cross = np.zeros((n_dir, 6, 6))
    g_pose = np.zeros((nb, 6))
    W = np.empty((K, 6, 3))
    for ch in st._obs_chunks:
        Ec = E[ch.lo:ch.hi]
        n = ch.hi - ch.lo
        # Observer rows of J^T [J | r], as separate contiguous products (no slicing copies).
        Jt = np.ascontiguousarray(np.swapaxes(Ec[:, :, :6], 1, 2))
        summed = ch.self_agg @ (Jt @ Ec[:, :, :7]).reshape(n, 42)    # [U_ii | g_i] rows
        self_blocks += summed.reshape(nb, 6, 7)[:, :, :6]
        g_pose += summed.reshape(nb, 6, 7)[:, :, 6]
        np.matmul(Jt, Ec[:, :, 7:10], out=W[ch.lo:ch.hi])
        for s, (lo, hi) in enumerate(st.anchor_cols):
            block = (Jt @ Ec[:, :, offs[s]:offs[s + 1]]).reshape(n, -1)
            cross[:, :, lo:hi] += (ch.cross_aggs[s] @ block).reshape(n_dir, 6, hi - lo)

    # Anchor rows, V and g_F: one (A + 4) x (A + 4) product per feature, over the columns
    # [residual | feature | anchors] (Q's index 0 is the residual, 1:4 the feature).
    Q = np.empty((N, A + 4, A + 4))
    for fc in st._feat_chunks:
        G = E[fc.lo:fc.hi].reshape(fc.f_hi - fc.f_lo, fc.c * d, width)[:, :, 6:]
        Q[fc.f_lo:fc.f_hi] = np.swapaxes(G, 1, 2) @ G
    q_offs = [o - 6 for o in offs]
    for s, (lo, hi) in enumerate(st.anchor_cols):
        rs = slice(q_offs[s], q_offs[s + 1])
        w = hi - lo
        blocks = st._anchor_self[s] @ np.concatenate(
            [Q[:, rs, rs].reshape(N, -1), Q[:, rs, 0]], axis=1)
        self_blocks[:, lo:hi, lo:hi] += blocks[:, :w * w].reshape(nb, w, w)
        g_pose[:, lo:hi] += blocks[:, w * w:]
        for t in range(s + 1, len(st.anchor_cols)):
            lo_t, hi_t = st.anchor_cols[t]
            rt = slice(q_offs[t], q_offs[t + 1])
            cross[:, lo:hi, lo_t:hi_t] += (st._anchor_cross[s, t] @ Q[:, rs, rt].reshape(N, -1)
                                           ).reshape(n_dir, w, hi_t - lo_t)
        has = st._anchor_block[:, s] >= 0
        W[st._anchor_obs[has, s], lo:hi] += Q[has, rs, 1:4]
    W[st._obs_fixed] = 0.0
    V = np.ascontiguousarray(Q[:, 1:4, 1:4])
    g_feat = np.ascontiguousarray(Q[:, 1:4, 0])
    return NormalEquations(st.fold(self_blocks, cross), W, V, g_pose, g_feat)


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
    """Return the equations of the column-scaled Jacobian J diag(c) (Jacobi scaling).

    The W blocks, the largest array, are scaled in place: ``eqs.W`` is consumed.
    """
    cp_r = c_pose[structure.pair_rows]
    cp_c = c_pose[structure.pair_cols]
    W = eqs.W
    if structure._pair_index is not None:
        compiled_assembly.scale_w(W, structure.feat_idx, structure._obs_block, c_pose, c_feat)
    else:
        W *= c_pose[structure.w_block][:, :, None]
        W *= c_feat[structure.feat_idx][:, None, :]
    return NormalEquations(
        eqs.U * cp_r[:, :, None] * cp_c[:, None, :], W,
        eqs.V * c_feat[:, :, None] * c_feat[:, None, :],
        eqs.g_pose * c_pose, eqs.g_feat * c_feat)


class ReducedSystemError(SolverError):
    """The reduced camera system is not positive definite."""


def _schur_blocks(structure: SchurStructure, W: FloatArray, V_inv: FloatArray) -> FloatArray:
    """Return sum_f W_f V_f^-1 W_f^T as upper pair blocks (n_pairs, 6, 6).

    Block (a, b) of a feature is W_a (V^-1 W_b^T); V^-1 W^T is formed per feature chunk with
    V^-1 broadcast over the chunk's observations (no gather).
    """
    st = structure
    nb = st.n_blocks
    if st._dense_schur:
        own = ~st._obs_fixed
        Wd = np.zeros((st.n_feats, 3, nb, 6))        # W^T of every feature, all pose columns
        Wd[st.feat_idx[own], :, st.w_block[own], :] = np.swapaxes(W[own], 1, 2)
        flat = Wd.reshape(st.n_feats * 3, 6 * nb)
        Y = (V_inv @ Wd.reshape(st.n_feats, 3, 6 * nb)).reshape(st.n_feats * 3, 6 * nb)
        S = (flat.T @ Y).reshape(nb, 6, nb, 6)
        return S[st.pair_rows, :, st.pair_cols, :]
    acc = np.zeros((nb + st.n_dir, 36))
    cached = -1
    for batch in st._schur_batches:
        buf = np.empty((batch.n_rows, 6, 6))
        for fi, delta, row in batch.tasks:
            fc = st._feat_chunks[fi]
            n, c = fc.f_hi - fc.f_lo, fc.c
            if fi != cached:
                W_f = W[fc.lo:fc.hi].reshape(n, c, 6, 3)
                Vi_Wt = V_inv[fc.f_lo:fc.f_hi, None] @ np.swapaxes(W_f, 2, 3)  # (n, c, 3, 6)
                cached = fi
            out = buf[row:row + n * (c - delta)].reshape(n, c - delta, 6, 6)
            np.matmul(W_f[:, :c - delta], Vi_Wt[:, delta:], out=out)     # (a, a + delta)
        if batch.pair_a.size:
            b = batch.pair_b
            np.matmul(W[batch.pair_a], V_inv[st.feat_idx[b]] @ np.swapaxes(W[b], 1, 2),
                      out=buf[batch.n_rows - b.shape[0]:])
        acc += batch.agg @ buf.reshape(-1, 36)
    return st.fold(acc[:nb].reshape(nb, 6, 6), acc[nb:].reshape(-1, 6, 6))


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
    st = structure
    if st._pair_index is not None:
        S_blocks, rhs, V_inv, bad = compiled_schur.reduce(
            eqs.U, eqs.W, eqs.V, damp_feat, eqs.g_pose, eqs.g_feat, st._starts, st._obs_block,
            st._pair_index)
        if bad >= 0:
            msg = f'singular feature block (feature {bad})'
            raise ReducedSystemError(msg)
    else:
        S_blocks, rhs, V_inv = _reduce(st, eqs, damp_feat)
    if not np.all(np.isfinite(V_inv)):
        msg = 'singular feature block'
        raise ReducedSystemError(msg)
    nb = structure.n_blocks
    free = pose_free.reshape(-1)
    dim = nb * 6
    rows = (structure.pair_rows[:, None] * 6 + np.arange(6)[None, :])
    cols = (structure.pair_cols[:, None] * 6 + np.arange(6)[None, :])
    d_idx = np.arange(nb)
    x = np.zeros(dim)
    if int(free.sum()) <= DENSE_LIMIT:
        # The upper triangle only (pair blocks have row <= col): LAPACK's potrf/potrs,
        # called directly, read no more; scipy's cho_factor wrapper costs more than a
        # window's factorization.
        S = np.zeros((dim, dim))
        S[rows[:, :, None], cols[:, None, :]] = S_blocks
        S[d_idx[:, None] * 6 + np.arange(6), d_idx[:, None] * 6 + np.arange(6)] += damp_pose
        with blas_threads_for(dim):
            factor, info = scipy.linalg.lapack.dpotrf(
                S if free.all() else S[np.ix_(free, free)], lower=False, clean=False,
                overwrite_a=True)
        if info != 0:
            msg = 'reduced camera system is not positive definite'
            raise ReducedSystemError(msg)
        x[free], _ = scipy.linalg.lapack.dpotrs(factor, rhs.reshape(-1)[free], lower=False)
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
    if st._pair_index is not None:
        return x_pose, compiled_schur.back_substitute(eqs.W, V_inv, eqs.g_feat, x_pose, st._starts,
                                               st._obs_block)
    Wt_x = np.einsum('qji,qj->qi', eqs.W, x_pose[structure.w_block])
    W_x = _scatter_add(structure.feat_idx, Wt_x, structure.n_feats)
    x_feat = np.einsum('nij,nj->ni', V_inv, -eqs.g_feat - W_x)
    return x_pose, x_feat


def _reduce(structure: SchurStructure, eqs: NormalEquations, damp_feat: FloatArray,
            ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return S = U - W V^-1 W^T (upper pair blocks), -g_T + W V^-1 g_F and V^-1."""
    V = eqs.V + damp_feat[:, :, None] * np.eye(3)
    try:
        V_inv = np.asarray(np.linalg.inv(V), dtype=np.float64)
    except np.linalg.LinAlgError as err:
        msg = 'singular feature block'
        raise ReducedSystemError(msg) from err
    S_blocks = eqs.U - _schur_blocks(structure, eqs.W, V_inv)
    Vg = np.einsum('nij,nj->ni', V_inv, eqs.g_feat)
    rhs = -eqs.g_pose + _scatter_add(structure.w_block,
                                     np.einsum('qij,qj->qi', eqs.W, Vg[structure.feat_idx]),
                                     structure.n_blocks)
    return S_blocks, rhs, V_inv


def quadratic_form(structure: SchurStructure, eqs: NormalEquations, x_pose: FloatArray,
                   x_feat: FloatArray) -> float:
    """Return x^T H x for H = J^T J held as (upper) U, W and V blocks; cheaper than |J x|^2."""
    r, c = structure.pair_rows, structure.pair_cols
    if structure._pair_index is not None:
        return compiled_assembly.quadratic_form(eqs.U, r, c, eqs.W, eqs.V, x_pose, x_feat,
                                      structure.feat_idx, structure._obs_block)
    Ux = np.einsum('pij,pj->pi', eqs.U, x_pose[c])
    weight = np.where(r == c, 1.0, 2.0)  # off-diagonal blocks stand for themselves and U^T
    quad = float(np.sum(weight * np.sum(x_pose[r] * Ux, axis=1)))
    Wx = np.einsum('qij,qj->qi', eqs.W, x_feat[structure.feat_idx])
    quad += 2.0 * float(np.sum(x_pose[structure.w_block] * Wx))
    quad += float(np.sum(x_feat * np.einsum('nij,nj->ni', eqs.V, x_feat)))
    return quad
