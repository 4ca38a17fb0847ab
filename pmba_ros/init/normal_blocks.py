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
"""Block normal matrices of the position steps (CLS eq. 14, NLS eq. 13), dense or sparse.

sum_k G_k^T A_k G_k couples cameras through features only: observer i with itself, observer i
with the anchors a, m of its feature, and the anchors with each other. The non-zero 3x3
blocks are those camera pairs (a few dozen per camera where covisibility is local, against
M per camera in a dense matrix). :class:`BlockPattern` finds them once per set of
observations and gives every term of the sum its block's slot; an assembly then adds the
terms into a (B, 3, 3) array, and the matrix is built from it either dense (LAPACK, faster for
a few hundred cameras) or in CSC form for SuperLU with a fill-reducing ordering.

==========  ============  ==========  ===================================================
code        shape         meaning
==========  ============  ==========  ===================================================
slot_obs    (K,)          block (i, i) of observation k
slot_cross  (K,2,2)       [k, t, 0]: block (i, anchor t); [k, t, 1]: block (anchor t, i)
slot_anchor (N,2,2)       [j, s, t]: block (anchor s, anchor t) of feature j
blocks      (B,3,3)       the summed 3x3 blocks, in (row, col) order
==========  ============  ==========  ===================================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

#: Largest number of free position coordinates (3 per camera) solved dense: below it LAPACK
#: is as fast as SuperLU or faster (crossover at 150-200 cameras on simulated streets).
DENSE_MAX_UNKNOWNS = 600

#: Smallest share of non-zero entries at which the matrix is solved dense at any size: where
#: most camera pairs share features (a 300-camera street whose 500 points are seen by all,
#: 42 % of the blocks) LAPACK was 5x faster than SuperLU; at 2 % (1500-camera streets and
#: aerial grids with local tracks) SuperLU was 10-40x faster.
DENSE_MIN_SHARE = 0.1

#: SuperLU's column ordering: minimum degree on the structure of A^T + A, the one meant for
#: symmetric matrices (applied to rows and columns alike in symmetric mode).
_ORDERING = 'MMD_AT_PLUS_A'

#: Largest backward error of the CLS's sparse KKT solve with diagonal pivots (LAPACK's
#: pivoted solves reach ~1e-16).
_BACKWARD_TOLERANCE = 1e-12


@dataclass(frozen=True, eq=False)
class BlockPattern:
    """The non-zero 3x3 blocks of sum_k G_k^T A_k G_k and the slot of every term.

    Attributes:
        rows: Block row (camera) of every non-zero block, shape (B,), sorted with ``cols``.
        cols: Block column of every non-zero block, shape (B,).
        slot_obs: Slot of the observer's own block (i, i), shape (K,).
        slot_cross: Slots of (i, a_t) at [k, t, 0] and (a_t, i) at [k, t, 1], shape (K, 2, 2).
        slot_anchor: Slot of (anchor s, anchor t) of every feature at [j, s, t], (N, 2, 2).
    """

    rows: IntArray
    cols: IntArray
    slot_obs: IntArray
    slot_cross: IntArray
    slot_anchor: IntArray

    @property
    def n_blocks(self) -> int:
        """Return the number of non-zero blocks B."""
        return int(self.rows.shape[0])

    def sum_blocks(self, obs: FloatArray, cross: FloatArray, anchor: FloatArray,
                   ) -> FloatArray:
        """Return the (B, 3, 3) sums of the observer, cross and anchor terms in their slots.

        Args:
            obs: Block (i, i) of every observation, shape (K, 3, 3).
            cross: Block (i, a_t) of every observation, shape (K, 2, 3, 3); (a_t, i) gets
                its transpose.
            anchor: Block (anchor s, anchor t) of every feature, shape (N, 2, 2, 3, 3).
        """
        B = self.n_blocks
        cross_t = np.swapaxes(cross, 2, 3)

        def total(slots: IntArray, terms: FloatArray, c: int) -> FloatArray:
            count = np.bincount(slots, weights=terms[:, c], minlength=B)
            return count.astype(float, copy=False)

        out = np.empty((9, B))
        o = obs.reshape(-1, 9)
        c0, c1 = cross[:, 0].reshape(-1, 9), cross[:, 1].reshape(-1, 9)
        t0, t1 = cross_t[:, 0].reshape(-1, 9), cross_t[:, 1].reshape(-1, 9)
        an = anchor.reshape(-1, 9)
        s = self.slot_cross
        for c in range(9):  # nine entries of a block, each a bincount over the terms
            # Summed as the dense assembly did, (i, i) + ((i, a) + (a, i)^T) + anchors, so
            # that a dense matrix built from the blocks is the same to the bit.
            hc = total(s[:, 0, 0], c0, c) + total(s[:, 1, 0], c1, c)
            hc_t = total(s[:, 0, 1], t0, c) + total(s[:, 1, 1], t1, c)
            out[c] = total(self.slot_obs, o, c) + (hc + hc_t)
            out[c] += total(self.slot_anchor.reshape(-1), an, c)
        return out.T.reshape(B, 3, 3)

    def dense(self, blocks: FloatArray, n_cams: int) -> FloatArray:
        """Return the (3M, 3M) matrix of the (B, 3, 3) ``blocks``."""
        H = np.zeros((n_cams, 3, n_cams, 3))
        H[self.rows, :, self.cols, :] = blocks
        out: FloatArray = H.reshape(3 * n_cams, 3 * n_cams)
        return out

    def sparse_layout(self, n_cams: int, keep: IntArray) -> SparseLayout:
        """Return the CSC structure of the matrix restricted to the scalar indices ``keep``."""
        B = self.n_blocks
        indptr = np.searchsorted(self.rows, np.arange(n_cams + 1)).astype(np.int64)
        # Every block entry tagged with its position + 1 (exact in float64, never 0, so no
        # entry is dropped): the CSC conversion and the selection then say where each stored
        # value comes from, and every later assembly is one gather.
        tag = np.arange(1, 9 * B + 1, dtype=float).reshape(B, 3, 3)
        full = scipy.sparse.bsr_array((tag, self.cols, indptr),
                                      shape=(3 * n_cams, 3 * n_cams)).tocsc()
        sub = scipy.sparse.csc_array(full[keep, :][:, keep])
        sub.sort_indices()
        return SparseLayout(int(keep.shape[0]), sub.indices.astype(np.int64),
                            sub.indptr.astype(np.int64), sub.data.astype(np.int64) - 1)


@dataclass(frozen=True, eq=False)
class SparseLayout:
    """CSC structure of a block matrix restricted to some scalar rows and columns.

    Attributes:
        size: Number of rows and columns n.
        indices: CSC row indices, shape (nnz,).
        indptr: CSC column pointers, shape (n + 1,).
        gather: Position in ``blocks.reshape(-1)`` of every stored value, shape (nnz,).
    """

    size: int
    indices: IntArray
    indptr: IntArray
    gather: IntArray

    def matrix(self, blocks: FloatArray) -> scipy.sparse.csc_array:
        """Return the restricted matrix of the (B, 3, 3) ``blocks``."""
        return scipy.sparse.csc_array((blocks.reshape(-1)[self.gather], self.indices,
                                       self.indptr), shape=(self.size, self.size))


def block_pattern(cam: IntArray, feat: IntArray, assoc: IntArray, main: IntArray,
                  ) -> BlockPattern:
    """Find the non-zero blocks of sum_k G_k^T A_k G_k and the slot of every term (eq. 12).

    Args:
        cam: Observing camera i of every observation, shape (K,).
        feat: Feature j of every observation, shape (K,).
        assoc: Associate anchor a of every feature, shape (N,).
        main: Main anchor m of every feature, shape (N,).
    """
    anchors = np.stack([assoc, main], axis=1)  # (N, 2)
    span = 1 + max(int(np.max(cam, initial=0)), int(np.max(anchors, initial=0)))
    obs_anchor = anchors[feat]  # (K, 2)
    i = cam[:, None]
    keys = np.concatenate([
        (cam * span + cam),
        np.stack([i * span + obs_anchor, obs_anchor * span + i], axis=2).reshape(-1),
        (anchors[:, :, None] * span + anchors[:, None, :]).reshape(-1)])
    uniq, slot = np.unique(keys, return_inverse=True)
    K, N = cam.shape[0], anchors.shape[0]
    return BlockPattern(uniq // span, uniq % span, slot[:K], slot[K:5 * K].reshape(K, 2, 2),
                        slot[5 * K:].reshape(N, 2, 2))


def use_sparse(n_unknowns: int, n_blocks: int, sparse: bool | None) -> bool:
    """Return whether a system is solved sparse (``None``: by its size and its blocks' share).

    Args:
        n_unknowns: Free coordinates n.
        n_blocks: Non-zero 3x3 blocks B of the whole matrix.
        sparse: The caller's choice, or None.
    """
    if sparse is not None:
        return bool(sparse)
    return (n_unknowns > DENSE_MAX_UNKNOWNS
            and 9.0 * n_blocks < DENSE_MIN_SHARE * float(n_unknowns) ** 2)


def _superlu(A: scipy.sparse.csc_array, pivot_threshold: float,
             ) -> scipy.sparse.linalg.SuperLU:
    """Factor A with SuperLU in symmetric mode (diagonal pivots preferred)."""
    try:
        return scipy.sparse.linalg.splu(A, permc_spec=_ORDERING,
                                        diag_pivot_thresh=pivot_threshold,
                                        options={'SymmetricMode': True})
    except RuntimeError as err:  # SuperLU's "Factor is exactly singular"
        raise np.linalg.LinAlgError(str(err)) from err


def solve_spd(H: FloatArray | scipy.sparse.csc_array, damping: FloatArray,
              g: FloatArray) -> FloatArray:
    """Return (H + diag(damping))^-1 g for a symmetric H, dense (LAPACK) or CSC (SuperLU).

    Raises:
        np.linalg.LinAlgError: If H + diag(damping) is not positive definite (the caller
            damps more).
    """
    if isinstance(H, np.ndarray):
        c_f = scipy.linalg.cho_factor(H + np.diag(damping))
        step: FloatArray = scipy.linalg.cho_solve(c_f, g)
        return step
    # Diagonal pivots only, as Cholesky: the pivots are then those of LDL^T, all positive
    # exactly when the matrix is positive definite.
    lu = _superlu(scipy.sparse.csc_array(H + scipy.sparse.diags_array(damping)), 0.0)
    if not np.all(lu.U.diagonal() > 0.0):
        msg = 'damped normal matrix is not positive definite'
        raise np.linalg.LinAlgError(msg)
    out: FloatArray = lu.solve(g)
    return out


def solve_kkt(H: FloatArray | scipy.sparse.csc_array, c: FloatArray, target: float,
              ) -> FloatArray:
    """Return (p, l) solving [H c; c^T 0] [p; l] = [0; target] (eq. 14's scale constraint).

    Dense: LAPACK's symmetric indefinite solve. CSC: SuperLU with diagonal pivots (the
    ordering puts the dense constraint row last, so the H part is factored as by Cholesky
    with little fill); where that is not backward stable (H singular, e.g. noise-free
    rays), again with threshold pivoting, which fills in far more.

    Raises:
        np.linalg.LinAlgError: If the system is singular.
        ValueError: From LAPACK, on non-finite input.
    """
    n = c.shape[0]
    rhs = np.zeros(n + 1)
    rhs[-1] = target
    if isinstance(H, np.ndarray):
        kkt = np.zeros((n + 1, n + 1))
        kkt[:-1, :-1] = H
        kkt[:-1, -1] = c
        kkt[-1, :-1] = c
        sol: FloatArray = scipy.linalg.solve(kkt, rhs, assume_a='sym')
        return sol
    col = scipy.sparse.csc_array(c[:, None])
    kkt_s = scipy.sparse.csc_array(scipy.sparse.block_array([[H, col], [col.T, None]],
                                                            format='csc'))
    scale = float(scipy.sparse.linalg.norm(kkt_s, 1))
    for threshold in (0.0, 0.1):
        try:
            out: FloatArray = _superlu(kkt_s, threshold).solve(rhs)
        except np.linalg.LinAlgError:
            if threshold > 0.0:
                raise
            continue
        backward = (float(np.linalg.norm(kkt_s @ out - rhs, 1))
                    / (scale * float(np.linalg.norm(out, 1)) + abs(target)))
        if backward < _BACKWARD_TOLERANCE:
            break
    return out
