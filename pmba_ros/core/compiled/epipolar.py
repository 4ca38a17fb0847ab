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
"""Compiled checks of the 5-point models of all EG pairs (mirrors ``init.two_view``).

After the RANSAC, every correspondence of every candidate pair is tested against its pair's
essential matrix (Sampson distance), the four (R, t) of the matrix are voted on by
cheirality, and the parallax that the best pure rotation leaves is measured: a few dozen
numpy passes over all correspondences there, one pass per step here. Correspondences are
sorted by pair.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import jit

_jit = jit.jit

#: The cheirality bits of the four candidates of each correspondence.
UInt8Array = NDArray[np.uint8]

#: Triangulated points farther than this many baselines do not vote (``init.two_view``).
MAX_DEPTH_BASELINES = 50.0


@_jit
def _epipolar_votes(E: Any, R: Any, t: Any, thr: Any, b1: Any, b2: Any, seg: Any,
                    epi: Any, good: Any, votes: Any, n_epi: Any) -> None:
    """Sampson inliers, and the cheirality of each inlier under the four (R, +-t) of E.

    ``good[k]`` has bit 2 r + s set when candidate (R[r], (-1)^s t) puts inlier k in front of
    both cameras, closer than MAX_DEPTH_BASELINES; ``votes[p, 2 r + s]`` counts them.
    Sums run in the order of the numpy reference (einsum over a contiguous axis adds terms
    0 and 2 first), so that both engines agree to the last bit where they can.
    """
    for k in range(seg.shape[0]):
        p = seg[k]
        good[k] = 0
        x10, x11 = b1[k, 0] / b1[k, 2], b1[k, 1] / b1[k, 2]
        x20, x21 = b2[k, 0] / b2[k, 2], b2[k, 1] / b2[k, 2]
        # x1, x2 have a third coordinate b / b_z = 1 exactly.
        ex0 = E[p, 0, 0] * x10 + E[p, 0, 2] + E[p, 0, 1] * x11
        ex1 = E[p, 1, 0] * x10 + E[p, 1, 2] + E[p, 1, 1] * x11
        ex2 = E[p, 2, 0] * x10 + E[p, 2, 2] + E[p, 2, 1] * x11
        et0 = E[p, 0, 0] * x20 + E[p, 1, 0] * x21 + E[p, 2, 0]
        et1 = E[p, 0, 1] * x20 + E[p, 1, 1] * x21 + E[p, 2, 1]
        num = x20 * ex0 + x21 * ex1 + ex2
        den = ex0 * ex0 + ex1 * ex1 + et0 * et0 + et1 * et1
        epi[k] = abs(num) / np.sqrt(max(den, 1e-300)) <= thr[p]
        if not epi[k]:
            continue
        n_epi[p] += 1
        for r in range(2):
            r0 = R[p, r, 0, 0] * b1[k, 0] + R[p, r, 0, 2] * b1[k, 2] + R[p, r, 0, 1] * b1[k, 1]
            r1 = R[p, r, 1, 0] * b1[k, 0] + R[p, r, 1, 2] * b1[k, 2] + R[p, r, 1, 1] * b1[k, 1]
            r2 = R[p, r, 2, 0] * b1[k, 0] + R[p, r, 2, 2] * b1[k, 2] + R[p, r, 2, 1] * b1[k, 1]
            m0 = r1 * b2[k, 2] - r2 * b2[k, 1]
            m1 = r2 * b2[k, 0] - r0 * b2[k, 2]
            m2 = r0 * b2[k, 1] - r1 * b2[k, 0]
            mm = max(m0 * m0 + m1 * m1 + m2 * m2, 1e-300)
            t0, t1, t2 = t[p, 0], t[p, 1], t[p, 2]
            c0 = t1 * b2[k, 2] - t2 * b2[k, 1]
            c1 = t2 * b2[k, 0] - t0 * b2[k, 2]
            c2 = t0 * b2[k, 1] - t1 * b2[k, 0]
            lam1 = -(c0 * m0 + c1 * m1 + c2 * m2) / mm
            d0 = t1 * r2 - t2 * r1
            d1 = t2 * r0 - t0 * r2
            d2 = t0 * r1 - t1 * r0
            lam2 = -(d0 * m0 + d1 * m1 + d2 * m2) / mm
            if not (abs(lam1) * b1[k, 2] < MAX_DEPTH_BASELINES
                    and abs(lam2) * b2[k, 2] < MAX_DEPTH_BASELINES):
                continue
            if lam1 > 0.0 and lam2 > 0.0:
                good[k] |= 1 << (2 * r)
                votes[p, 2 * r] += 1
            elif -lam1 > 0.0 and -lam2 > 0.0:
                good[k] |= 1 << (2 * r + 1)
                votes[p, 2 * r + 1] += 1


def epipolar_votes(E: FloatArray, R: FloatArray, t: FloatArray, thresholds: FloatArray,
                   b1: FloatArray, b2: FloatArray, seg: IntArray,
                   ) -> tuple[BoolArray, IntArray, UInt8Array, IntArray]:
    """Return the Sampson inliers (C,), their count per pair (P,), the bits and the votes.

    ``good[k]`` (C,) has bit 2 r + s set when the candidate (R[r], (-1)^s t) puts inlier k in
    front of both cameras; ``votes[p, 2 r + s]`` (P, 4) counts them.

    Args:
        E: Essential matrix of every pair, shape (P, 3, 3).
        R: The two rotations of every pair's E, shape (P, 2, 3, 3).
        t: The translation (up to sign) of every pair's E, shape (P, 3).
        thresholds: Sampson threshold of every pair, shape (P,).
        b1: Unit bearings in camera 1 (z > 0), shape (C, 3).
        b2: Unit bearings in camera 2 (z > 0), shape (C, 3).
        seg: Pair of every correspondence, shape (C,).
    """
    C, P = seg.shape[0], E.shape[0]
    epi, good = np.empty(C, dtype=np.bool_), np.empty(C, dtype=np.uint8)
    votes, n_epi = np.zeros((P, 4), dtype=np.int64), np.zeros(P, dtype=np.int64)
    _epipolar_votes(np.ascontiguousarray(E), np.ascontiguousarray(R), np.ascontiguousarray(t),
                    thresholds, np.ascontiguousarray(b1), np.ascontiguousarray(b2), seg, epi,
                    good, votes, n_epi)
    return epi, n_epi, good, votes


@_jit
def _rotation_covariances(b1: Any, b2: Any, seg: Any, mask: Any, cov: Any) -> None:
    """Add b2 b1^T of every masked correspondence to its pair's cov (P, 3, 3)."""
    for k in range(seg.shape[0]):
        if mask[k]:
            p = seg[k]
            for i in range(3):
                for j in range(3):
                    cov[p, i, j] += b2[k, i] * b1[k, j]


def rotation_covariances(b1: FloatArray, b2: FloatArray, seg: IntArray, mask: BoolArray,
                         n_pairs: int) -> FloatArray:
    """Return sum b2 b1^T over each pair's masked correspondences, shape (P, 3, 3)."""
    cov = np.zeros((n_pairs, 3, 3))
    _rotation_covariances(np.ascontiguousarray(b1), np.ascontiguousarray(b2), seg, mask, cov)
    return cov


@_jit
def _median_angles(R: Any, b1: Any, b2: Any, seg: Any, mask: Any, out: Any) -> bool:
    """Median angle between b2 and R_p b1 over each pair's masked correspondences.

    Returns False (with ``out`` incomplete) if ``seg`` is not sorted.
    """
    buf = np.empty(seg.shape[0])
    k = 0
    while k < seg.shape[0]:
        p, n = seg[k], 0
        if k > 0 and p < seg[k - 1]:
            return False
        while k < seg.shape[0] and seg[k] == p:
            if mask[k]:
                c = 0.0
                for i in range(3):
                    c += b2[k, i] * (R[p, i, 0] * b1[k, 0] + R[p, i, 2] * b1[k, 2]
                                     + R[p, i, 1] * b1[k, 1])
                # -cos, which orders as the angle: the median is found before any arccos.
                buf[n] = -min(max(c, -1.0), 1.0)
                n += 1
            k += 1
        if n > 0:
            hi = n // 2
            _select(buf, n, hi)
            lo = buf[hi]
            if n % 2 == 0:
                lo = buf[0]
                for i in range(1, hi):
                    lo = max(lo, buf[i])
            out[p] = 0.5 * (np.arccos(-lo) + np.arccos(-buf[hi]))
    return True


@_jit
def _select(a: Any, n: int, k: int) -> None:
    """Reorder a[:n] so that a[k] is its k-th smallest, none above it before, none below after.

    Hoare's selection, written out: numba's np.partition gives the same values but compiles
    to far more code.
    """
    lo, hi = 0, n - 1
    while lo < hi:
        pivot = a[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return


def median_angles(R: FloatArray, b1: FloatArray, b2: FloatArray, seg: IntArray,
                  mask: BoolArray, n_pairs: int) -> FloatArray:
    """Return each pair's median angle (rad) between b2 and R b1, masked rows (0 if none).

    ``seg`` must be sorted (correspondences stored pair by pair).

    Raises:
        ValueError: If ``seg`` is not sorted.
    """
    out = np.zeros(n_pairs)
    if not _median_angles(np.ascontiguousarray(R), np.ascontiguousarray(b1),
                          np.ascontiguousarray(b2), seg, mask, out):
        msg = 'median_angles: the correspondences must be sorted by pair'
        raise ValueError(msg)
    return out


@_jit
def _rotated_cross(R: Any, b: Any, ia: int, ib: int, p: int) -> tuple[float, ...]:
    """Return R_p b_ia and (R_p b_ia) x b_ib (einsum's order, as in _epipolar_votes)."""
    r0 = R[p, 0, 0] * b[ia, 0] + R[p, 0, 2] * b[ia, 2] + R[p, 0, 1] * b[ia, 1]
    r1 = R[p, 1, 0] * b[ia, 0] + R[p, 1, 2] * b[ia, 2] + R[p, 1, 1] * b[ia, 1]
    r2 = R[p, 2, 0] * b[ia, 0] + R[p, 2, 2] * b[ia, 2] + R[p, 2, 1] * b[ia, 1]
    return (r0, r1, r2, r1 * b[ib, 2] - r2 * b[ib, 1], r2 * b[ib, 0] - r0 * b[ib, 2],
            r0 * b[ib, 1] - r1 * b[ib, 0])


@_jit
def _epipolar_outer(R: Any, b: Any, obs_a: Any, obs_b: Any, offsets: Any, out: Any) -> None:
    """out_k = m m^T for correspondence k of pair p, m = (R_p b_a) x b_b."""
    for p in range(offsets.shape[0] - 1):
        for k in range(offsets[p], offsets[p + 1]):
            _, _, _, m0, m1, m2 = _rotated_cross(R, b, obs_a[k], obs_b[k], p)
            m = (m0, m1, m2)
            for i in range(3):
                for j in range(3):
                    out[k, i, j] = m[i] * m[j]


@_jit
def _translation_votes(R: Any, t: Any, b: Any, obs_a: Any, obs_b: Any, offsets: Any,
                       votes: Any) -> None:
    """Sum of sign(lambda1) + sign(lambda2) over pair p's correspondences (cheirality_depths)."""
    for p in range(offsets.shape[0] - 1):
        t0, t1, t2 = t[p, 0], t[p, 1], t[p, 2]
        for k in range(offsets[p], offsets[p + 1]):
            ib = obs_b[k]
            r0, r1, r2, m0, m1, m2 = _rotated_cross(R, b, obs_a[k], ib, p)
            mm = max(m0 * m0 + m1 * m1 + m2 * m2, 1e-300)
            c0 = t1 * b[ib, 2] - t2 * b[ib, 1]
            c1 = t2 * b[ib, 0] - t0 * b[ib, 2]
            c2 = t0 * b[ib, 1] - t1 * b[ib, 0]
            d0 = t1 * r2 - t2 * r1
            d1 = t2 * r0 - t0 * r2
            d2 = t0 * r1 - t1 * r0
            lam1 = -(c0 * m0 + c1 * m1 + c2 * m2) / mm
            lam2 = -(d0 * m0 + d1 * m1 + d2 * m2) / mm
            votes[p] += np.sign(lam1) + np.sign(lam2)


def epipolar_scatter(R: FloatArray, bearings: FloatArray, obs_a: IntArray, obs_b: IntArray,
                     offsets: IntArray) -> FloatArray:
    """Return sum m m^T, m = (R_p b_a) x b_b, over each pair's correspondences, (P, 3, 3).

    ``init.two_view.refine_translations``: correspondence k of pair p (offsets[p] <= k <
    offsets[p + 1]) joins observations obs_a[k] and obs_b[k] of ``bearings`` (K, 3). The
    products are compiled, their sums are numpy's (``add.reduceat``, as the reference adds
    them), so that both engines give the same translations to the last bit.
    """
    P = offsets.shape[0] - 1
    outer = np.empty((obs_a.shape[0], 3, 3))
    _epipolar_outer(np.ascontiguousarray(R), bearings, obs_a, obs_b, offsets, outer)
    S = np.zeros((P, 3, 3))
    nonempty = np.diff(offsets) > 0
    if outer.shape[0]:
        S[nonempty] = np.add.reduceat(outer, offsets[:-1][nonempty], axis=0)
    return S


def translation_votes(R: FloatArray, t: FloatArray, bearings: FloatArray, obs_a: IntArray,
                      obs_b: IntArray, offsets: IntArray) -> FloatArray:
    """Return each pair's sum of the signs of both depths for (R_p, t_p), shape (P,)."""
    votes = np.zeros(offsets.shape[0] - 1)
    _translation_votes(np.ascontiguousarray(R), np.ascontiguousarray(t), bearings, obs_a,
                       obs_b, offsets, votes)
    return votes
