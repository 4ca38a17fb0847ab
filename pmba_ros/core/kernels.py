"""Compiled loops (numba) for the normal equations: assembly and the Schur complement.

The numpy code of :mod:`pmba_ros.core.normal_equations` builds J^T J from batched products
and 0/1 scatter matrices, which costs a few dozen numpy calls per iteration whatever the
size; on a sliding window (a few thousand observations) those calls, not the arithmetic, take
the time. These loops visit each observation once and add its blocks in place. They are used
when numba is installed (the ``fast`` extra, or rosdep's python3-numba) and give the same
results to rounding (the tests compare both); ``PMBA_NUMBA=0`` turns them off.

Block addressing: ``pair_index[a, b]`` (a <= b) is the row of the upper pair block (a, b) in
``U``; a pair (a, b) with a > b is stored transposed at ``pair_index[b, a]``.
"""

from __future__ import annotations

import importlib
import os
from typing import Any

import numpy as np

from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core.jacobian import ANCHOR_START


def _import_numba() -> Any:
    """Return the numba module, or None where it is not installed (an optional extra)."""
    try:
        return importlib.import_module('numba')
    except ImportError:
        return None


_NUMBA = _import_numba()
#: Whether the compiled loops are used (numba importable and not turned off).
ENABLED = _NUMBA is not None and os.environ.get('PMBA_NUMBA', '1') != '0'
#: Largest number of free pose blocks for the compiled loops: their (n, n) pair index
#: stays under 200 MB.
MAX_BLOCKS = 5000


def _jit(fn: Any) -> Any:
    """Compile ``fn`` lazily (cached on disk) when numba is there, else keep it as is."""
    if _NUMBA is None:
        return fn
    return _NUMBA.njit(cache=True, nogil=True)(fn)


@_jit
def _add_block(U: Any, pair_index: Any, a: int, b: int, src: Any, i0: int, k0: int,
               n_r: int, n_c: int, r0: int, c0: int, symmetric: bool) -> None:
    """Add src[i0:i0+n_r, k0:k0+n_c] at rows r0.. of pose a, columns c0.. of pose b.

    Pairs a > b go to the transposed upper block. On a diagonal block (a = b) the transpose
    is added too, unless the block is a ``symmetric`` product of one slot with itself.
    """
    if a > b:
        p = pair_index[b, a]
        for i in range(n_r):
            for k in range(n_c):
                U[p, c0 + k, r0 + i] += src[i0 + i, k0 + k]
        return
    p = pair_index[a, b]
    for i in range(n_r):
        for k in range(n_c):
            U[p, r0 + i, c0 + k] += src[i0 + i, k0 + k]
            if a == b and not symmetric:
                U[p, c0 + k, r0 + i] += src[i0 + i, k0 + k]


@_jit
def _assemble(E: Any, starts: Any, obs_block: Any, anchor_block: Any, anchor_obs: Any,
              anchor_lo: Any, anchor_w: Any, pair_index: Any, U: Any, W: Any, V: Any,
              g_pose: Any, g_feat: Any) -> None:
    """J^T [J | r] of every observation into U, W, V, g (zeroed by the caller).

    As in the numpy assembly, the observer's rows are formed per observation and the rows
    of the residual, the feature and the anchors summed per feature (Q) and added once.
    """
    _, d, width = E.shape
    n_anchor = anchor_lo.shape[0]
    P = np.empty((6, width))        # observer rows of one observation
    Q = np.empty((width - 6, width - 6))
    for f in range(starts.shape[0] - 1):
        Q[:] = 0.0
        for k in range(starts[f], starts[f + 1]):
            # Rank-1 updates row by row: the inner loops run along contiguous columns.
            for r in range(d):
                for i in range(width - 6):
                    x = E[k, r, 6 + i]
                    for m in range(i, width - 6):
                        Q[i, m] += x * E[k, r, 6 + m]
            b0 = obs_block[k]
            if b0 < 0:
                continue
            P[:] = 0.0
            for r in range(d):
                for i in range(6):
                    x = E[k, r, i]
                    for m in range(width):
                        P[i, m] += x * E[k, r, m]
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
        for i in range(width - 6):
            for m in range(i):
                Q[i, m] = Q[m, i]
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
def _schur(W: Any, V_inv: Any, starts: Any, w_block: Any, pair_index: Any, out: Any) -> None:
    """Add W_a V^-1 W_b^T of every feature's observation pairs (a <= b) to ``out``."""
    M = np.empty((6, 6))
    for f in range(starts.shape[0] - 1):
        lo, hi = starts[f], starts[f + 1]
        Y = np.empty((hi - lo, 3, 6))                  # V^-1 W^T of each observation
        for a in range(hi - lo):
            for r in range(3):
                for k in range(6):
                    Y[a, r, k] = (V_inv[f, r, 0] * W[lo + a, k, 0]
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
                for i in range(6):
                    w0, w1, w2 = W[lo + a, i, 0], W[lo + a, i, 1], W[lo + a, i, 2]
                    for k in range(6):
                        M[i, k] = w0 * Y[b, 0, k] + w1 * Y[b, 1, k] + w2 * Y[b, 2, k]
                _add_block(out, pair_index, ba, bb, M, 0, 0, 6, 6, 0, 0, a == b)


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


def schur_blocks(W: FloatArray, V_inv: FloatArray, starts: IntArray, w_block: IntArray,
                 pair_index: IntArray, n_pairs: int) -> FloatArray:
    """Return sum_f W_f V_f^-1 W_f^T as upper pair blocks (n_pairs, 6, 6)."""
    out = np.zeros((n_pairs, 6, 6))
    _schur(np.ascontiguousarray(W), np.ascontiguousarray(V_inv), starts, w_block,
           pair_index, out)
    return out
