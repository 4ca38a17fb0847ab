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
"""The numpy engine's Schur plan: J^T J and W V^-1 W^T from batched products.

The anchor rows of J^T J are summed per feature, by one (c d x A) product per feature of c
observations, and only the observer rows are formed per observation; features come ordered
by their number of observations, so every per-feature product is a reshape, never a gather.

The Schur complement forms each feature's W V^-1 W^T blocks for observation pairs (a, b),
a <= b, only: one product per offset b - a for chunks of many features, one per pair for
small chunks, in cache-sized batches; the blocks of both orders of a pose pair meet in a
final fold. Small problems (few poses) instead take one dense product over all pose columns,
whichever needs fewer multiply-adds. Every index array that depends only on the structure is
built once in :class:`NumpySchurPlan`; each iteration fills values, with no Python loop over
observations (scatter-adds are sparse products with 0/1 matrices).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.jacobian import ANCHOR_START, Linearization
from pmba_ros.core.normal_equations import NormalEquations, SchurLayout
from pmba_ros.errors import ReducedSystemError
import scipy.sparse

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
    out: IntArray = np.where(sorted_keys[idx] == keys, idx, n)
    return out


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
class NumpySchurPlan:
    """Aggregators and product batches of the numpy engine (a :class:`SchurPlan`).

    Attributes:
        layout: The structure's common part.
        pair_rows, pair_cols: Block pairs of U and S, upper triangle incl. the diagonal.
        n_dir: Number of directed block pairs (a, b) that receive off-diagonal sums.
    """

    layout: SchurLayout
    pair_rows: IntArray
    pair_cols: IntArray
    n_dir: int
    anchor_self: list[scipy.sparse.csr_matrix]         # per slot s: (n_blocks, N)
    anchor_cross: dict[tuple[int, int], scipy.sparse.csr_matrix]  # s < t: (n_dir, N)
    obs_chunks: list[_ObsChunk]
    feat_chunks: list[_FeatChunk]
    schur_batches: list[_SchurBatch]
    dense: bool
    fold_fwd: IntArray       # directed pair (row, col) of each upper pair, or n_dir (zero)
    fold_bwd: IntArray       # directed pair (col, row), or n_dir

    @classmethod
    def build(cls, layout: SchurLayout) -> NumpySchurPlan:
        """Build the aggregators and Schur batches of a layout."""
        n_blocks, n_feats, feat_idx = layout.n_blocks, layout.n_feats, layout.feat_idx
        obs_block, anchor_block, starts = layout.obs_block, layout.anchor_block, layout.starts
        K = feat_idx.shape[0]
        n_anchor = anchor_block.shape[1]
        counts = np.diff(starts)

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
        return cls(layout, pair_rows, pair_cols, n_dir, anchor_self, anchor_cross, obs_chunks,
                   feat_chunks, batches, dense, fold_fwd, fold_bwd)

    def fold(self, self_blocks: FloatArray, cross: FloatArray) -> FloatArray:
        """Return upper pair blocks (n_pairs, 6, 6) from per-block and directed-pair sums.

        A pair (x, y), x <= y, is cross(x, y) + cross(y, x)^T, plus self(x) on the diagonal.
        """
        padded = np.concatenate([cross, np.zeros((1, 6, 6))])
        out: FloatArray = padded[self.fold_fwd] + np.swapaxes(padded[self.fold_bwd], 1, 2)
        diag = np.flatnonzero(self.pair_rows == self.pair_cols)
        out[diag] += self_blocks[self.pair_rows[diag]]
        return out

    @property
    def obs_fixed(self) -> BoolArray:
        """Observations whose observer is fixed (their W block is zero)."""
        return self.layout.obs_block < 0

    def assemble(self, lin: Linearization) -> NormalEquations:
        """Return U, W, V and the gradient of rows ``lin`` (observer rows per chunk)."""
        lt = self.layout
        E = lin.rows
        K, d, width = E.shape
        nb, N, n_dir = lt.n_blocks, lt.n_feats, self.n_dir
        offs = lin.anchor_offsets()
        A = width - ANCHOR_START

        self_blocks = np.zeros((nb, 6, 6))
        cross = np.zeros((n_dir, 6, 6))
        g_pose = np.zeros((nb, 6))
        W = np.empty((K, 6, 3))
        for ch in self.obs_chunks:
            Ec = E[ch.lo:ch.hi]
            n = ch.hi - ch.lo
            # Observer rows of J^T [J | r], as separate contiguous products (no slicing copies).
            Jt = np.ascontiguousarray(np.swapaxes(Ec[:, :, :6], 1, 2))
            summed = ch.self_agg @ (Jt @ Ec[:, :, :7]).reshape(n, 42)    # [U_ii | g_i] rows
            self_blocks += summed.reshape(nb, 6, 7)[:, :, :6]
            g_pose += summed.reshape(nb, 6, 7)[:, :, 6]
            np.matmul(Jt, Ec[:, :, 7:10], out=W[ch.lo:ch.hi])
            for s, (lo, hi) in enumerate(lt.anchor_cols):
                block = (Jt @ Ec[:, :, offs[s]:offs[s + 1]]).reshape(n, -1)
                cross[:, :, lo:hi] += (ch.cross_aggs[s] @ block).reshape(n_dir, 6, hi - lo)

        # Anchor rows, V and g_F: one (A + 4) x (A + 4) product per feature, over the columns
        # [residual | feature | anchors] (Q's index 0 is the residual, 1:4 the feature).
        Q = np.empty((N, A + 4, A + 4))
        for fc in self.feat_chunks:
            G = E[fc.lo:fc.hi].reshape(fc.f_hi - fc.f_lo, fc.c * d, width)[:, :, 6:]
            Q[fc.f_lo:fc.f_hi] = np.swapaxes(G, 1, 2) @ G
        q_offs = [o - 6 for o in offs]
        for s, (lo, hi) in enumerate(lt.anchor_cols):
            rs = slice(q_offs[s], q_offs[s + 1])
            w = hi - lo
            blocks = self.anchor_self[s] @ np.concatenate(
                [Q[:, rs, rs].reshape(N, -1), Q[:, rs, 0]], axis=1)
            self_blocks[:, lo:hi, lo:hi] += blocks[:, :w * w].reshape(nb, w, w)
            g_pose[:, lo:hi] += blocks[:, w * w:]
            for t in range(s + 1, len(lt.anchor_cols)):
                lo_t, hi_t = lt.anchor_cols[t]
                rt = slice(q_offs[t], q_offs[t + 1])
                cross[:, lo:hi, lo_t:hi_t] += (
                    self.anchor_cross[s, t] @ Q[:, rs, rt].reshape(N, -1)
                ).reshape(n_dir, w, hi_t - lo_t)
            has = lt.anchor_block[:, s] >= 0
            W[lt.anchor_obs[has, s], lo:hi] += Q[has, rs, 1:4]
        W[self.obs_fixed] = 0.0
        V = np.ascontiguousarray(Q[:, 1:4, 1:4])
        g_feat = np.ascontiguousarray(Q[:, 1:4, 0])
        return NormalEquations(self.fold(self_blocks, cross), W, V, g_pose, g_feat)

    def scale_w(self, W: FloatArray, c_pose: FloatArray, c_feat: FloatArray) -> None:
        """Scale the W blocks in place by their pose and feature column scales."""
        W *= c_pose[self.layout.w_block][:, :, None]
        W *= c_feat[self.layout.feat_idx][:, None, :]

    def _schur_blocks(self, W: FloatArray, V_inv: FloatArray) -> FloatArray:
        """Return sum_f W_f V_f^-1 W_f^T as upper pair blocks (n_pairs, 6, 6).

        Block (a, b) of a feature is W_a (V^-1 W_b^T); V^-1 W^T is formed per feature chunk
        with V^-1 broadcast over the chunk's observations (no gather).
        """
        lt = self.layout
        nb = lt.n_blocks
        if self.dense:
            own = ~self.obs_fixed
            Wd = np.zeros((lt.n_feats, 3, nb, 6))      # W^T of every feature, all pose columns
            Wd[lt.feat_idx[own], :, lt.w_block[own], :] = np.swapaxes(W[own], 1, 2)
            flat = Wd.reshape(lt.n_feats * 3, 6 * nb)
            Y = (V_inv @ Wd.reshape(lt.n_feats, 3, 6 * nb)).reshape(lt.n_feats * 3, 6 * nb)
            S = (flat.T @ Y).reshape(nb, 6, nb, 6)
            return S[self.pair_rows, :, self.pair_cols, :]
        acc = np.zeros((nb + self.n_dir, 36))
        cached = -1
        for batch in self.schur_batches:
            buf = np.empty((batch.n_rows, 6, 6))
            for fi, delta, row in batch.tasks:
                fc = self.feat_chunks[fi]
                n, c = fc.f_hi - fc.f_lo, fc.c
                if fi != cached:
                    W_f = W[fc.lo:fc.hi].reshape(n, c, 6, 3)
                    Vi_Wt = V_inv[fc.f_lo:fc.f_hi, None] @ np.swapaxes(W_f, 2, 3)  # (n, c, 3, 6)
                    cached = fi
                out = buf[row:row + n * (c - delta)].reshape(n, c - delta, 6, 6)
                np.matmul(W_f[:, :c - delta], Vi_Wt[:, delta:], out=out)     # (a, a + delta)
            if batch.pair_a.size:
                b = batch.pair_b
                np.matmul(W[batch.pair_a], V_inv[lt.feat_idx[b]] @ np.swapaxes(W[b], 1, 2),
                          out=buf[batch.n_rows - b.shape[0]:])
            acc += batch.agg @ buf.reshape(-1, 36)
        return self.fold(acc[:nb].reshape(nb, 6, 6), acc[nb:].reshape(-1, 6, 6))

    def reduce(self, eqs: NormalEquations, damp_feat: FloatArray,
               ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Return S = U - W V^-1 W^T (upper pair blocks), -g_T + W V^-1 g_F and V^-1.

        Raises:
            ReducedSystemError: If a damped feature block is singular.
        """
        lt = self.layout
        V = eqs.V + damp_feat[:, :, None] * np.eye(3)
        try:
            V_inv = np.asarray(np.linalg.inv(V), dtype=np.float64)
        except np.linalg.LinAlgError as err:
            msg = 'singular feature block'
            raise ReducedSystemError(msg) from err
        S_blocks = eqs.U - self._schur_blocks(eqs.W, V_inv)
        Vg = np.einsum('nij,nj->ni', V_inv, eqs.g_feat)
        rhs = -eqs.g_pose + _scatter_add(lt.w_block,
                                         np.einsum('qij,qj->qi', eqs.W, Vg[lt.feat_idx]),
                                         lt.n_blocks)
        return S_blocks, rhs, V_inv

    def back_substitute(self, eqs: NormalEquations, V_inv: FloatArray,
                        x_pose: FloatArray) -> FloatArray:
        """Return x_F = V^-1 (-g_F - W^T x_T)."""
        lt = self.layout
        Wt_x = np.einsum('qji,qj->qi', eqs.W, x_pose[lt.w_block])
        W_x = _scatter_add(lt.feat_idx, Wt_x, lt.n_feats)
        out: FloatArray = np.einsum('nij,nj->ni', V_inv, -eqs.g_feat - W_x)
        return out

    def quadratic_form(self, eqs: NormalEquations, x_pose: FloatArray,
                       x_feat: FloatArray) -> float:
        """Return x^T H x for H held as (upper) U, W and V blocks."""
        lt = self.layout
        r, c = self.pair_rows, self.pair_cols
        Ux = np.einsum('pij,pj->pi', eqs.U, x_pose[c])
        weight = np.where(r == c, 1.0, 2.0)  # off-diagonal blocks stand for themselves and U^T
        quad = float(np.sum(weight * np.sum(x_pose[r] * Ux, axis=1)))
        Wx = np.einsum('qij,qj->qi', eqs.W, x_feat[lt.feat_idx])
        quad += 2.0 * float(np.sum(x_pose[lt.w_block] * Wx))
        quad += float(np.sum(x_feat * np.einsum('nij,nj->ni', eqs.V, x_feat)))
        return quad


def _scatter_add(index: IntArray, values: FloatArray, n_rows: int) -> FloatArray:
    """Sum rows of ``values`` (n, c) into (n_rows, c) by ``index`` (n,), one bincount a column."""
    out = np.empty((n_rows, values.shape[1]))
    for i in range(values.shape[1]):
        out[:, i] = np.bincount(index, weights=values[:, i], minlength=n_rows)
    return out
