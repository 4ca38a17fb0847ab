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
"""Chordal rotation averaging (Martinec & Pajdla 2007; Carlone et al. ICRA 2015).

Notation (pmba.md §4.3):

==========  ============  ========  =====================================================
paper       code          shape     meaning
==========  ============  ========  =====================================================
R_k         R_wc[k]       (M,3,3)   camera -> world rotation (unknown), R_root = I
R_cv        R_rel[p]      (P,3,3)   pair (a, b): R_a = R_b R_cv
X_k         x[:, r]       (3(M-1),) relaxed rows of R_k (row r of X_k stacked over k)
w_ab        weights[p]    (P,)      pair weight (cheirality inliers)
==========  ============  ========  =====================================================

min sum_p w_p ||X_a - X_b R_cv||_F^2 is linear. Row r of X_a equals row r of X_b times R_cv,
i.e. x_a,r = R_cv^T x_b,r as column vectors: three sparse least-squares problems with the
same matrix A (3 rows per pair), one for each row r. The root's rows move to the right-hand
side. The normal matrix A^T W A is factored once; each X_k is then projected onto SO(3).
"""

from __future__ import annotations

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import so3
from pmba_ros.errors import InitError
from scipy.sparse import coo_matrix
from scipy.sparse.linalg import splu


def chordal_rotation_averaging(n_cams: int, root: int, cam_a: IntArray, cam_b: IntArray,
                               R_rel: FloatArray, weights: FloatArray | None = None,
                               ) -> FloatArray:
    """Average relative rotations into absolute camera -> world rotations (R_root = I).

    Args:
        n_cams: Number of cameras M; every camera must be connected to the root.
        root: Reference camera.
        cam_a: First camera of each pair, shape (P,).
        cam_b: Second camera of each pair, shape (P,).
        R_rel: R_cv = R_b^T R_a of each pair, shape (P, 3, 3).
        weights: Pair weights (P,) (default: 1).

    Returns:
        Rotations R_wc, shape (M, 3, 3), each projected onto SO(3).

    Raises:
        InitError: If the normal matrix is singular (a camera not connected to the root).

    References:
        PMBA Sec. 3 (rotation averaging, [13] chordal relaxation); pmba.md §4.3.
    """
    P = cam_a.shape[0]
    w = np.ones(P) if weights is None else np.asarray(weights, dtype=float)
    sw = np.sqrt(w)
    # Unknown index of every camera (-1 for the root).
    col = np.full(n_cams, -1, dtype=np.int64)
    others = np.flatnonzero(np.arange(n_cams) != root)
    col[others] = np.arange(others.shape[0])
    n_unk = 3 * others.shape[0]
    # Rows 3p..3p+2: sw (x_a - R_cv^T x_b) = 0.
    rows_p = 3 * np.arange(P)[:, None] + np.arange(3)[None, :]  # (P, 3)
    ii, jj = np.meshgrid(np.arange(3), np.arange(3), indexing='ij')
    R_t = np.swapaxes(R_rel, 1, 2)
    entries_r: list[np.ndarray] = []
    entries_c: list[np.ndarray] = []
    entries_v: list[np.ndarray] = []
    a_free = col[cam_a] >= 0
    b_free = col[cam_b] >= 0
    # Identity block on x_a.
    entries_r.append(rows_p[a_free].ravel())
    entries_c.append((3 * col[cam_a][a_free][:, None] + np.arange(3)[None, :]).ravel())
    entries_v.append(np.repeat(sw[a_free], 3))
    # -R_cv^T block on x_b.
    entries_r.append((3 * np.flatnonzero(b_free)[:, None, None] + ii[None]).ravel())
    entries_c.append((3 * col[cam_b][b_free][:, None, None] + jj[None]).ravel())
    entries_v.append((-sw[b_free][:, None, None] * R_t[b_free]).ravel())
    A = coo_matrix((np.concatenate(entries_v), (np.concatenate(entries_r),
                                                np.concatenate(entries_c))),
                   shape=(3 * P, n_unk)).tocsc()
    # Right-hand sides: the root's known rows e_r.
    rhs = np.zeros((3 * P, 3))
    eye = np.eye(3)
    a_root = ~a_free
    b_root = ~b_free
    for r in range(3):
        rhs[rows_p[a_root].ravel(), r] = (-sw[a_root][:, None] * eye[r][None, :]).ravel()
        rhs[rows_p[b_root].ravel(), r] = (sw[b_root][:, None] * (R_t[b_root] @ eye[r])).ravel()
    H = (A.T @ A).tocsc()
    try:
        # H is symmetric positive definite: a symmetric fill-reducing order and no pivoting
        # (COLAMD with partial pivoting filled a dense collection's factor several-fold).
        lu = splu(H, permc_spec='MMD_AT_PLUS_A', diag_pivot_thresh=0.0,
                  options={'SymmetricMode': True})
    except RuntimeError as err:
        msg = f'rotation averaging: singular normal matrix ({err}); is the graph connected?'
        raise InitError(msg) from err
    x = lu.solve(np.asarray(A.T @ rhs))  # (n_unk, 3): column r = rows r of all X_k
    if not np.all(np.isfinite(x)):
        msg = 'rotation averaging: non-finite solution; is the graph connected?'
        raise InitError(msg)
    X = np.empty((n_cams, 3, 3))
    X[root] = eye
    # x[3 col_k + j, r] = X_k[r, j]
    X[others] = np.swapaxes(x.reshape(others.shape[0], 3, 3), 1, 2)
    return so3.project(X)


def robust_rotation_averaging(n_cams: int, root: int, cam_a: IntArray, cam_b: IntArray,
                              R_rel: FloatArray, weights: FloatArray | None = None, *,
                              cauchy_deg: float = 1.0, max_iterations: int = 20,
                              tolerance_deg: float = 1e-4,
                              ) -> tuple[FloatArray, FloatArray, int]:
    """Chordal averaging with iteratively reweighted pairs (Cauchy kernel on the pair angle).

    Each round solves the weighted chordal problem, measures every pair's disagreement
    angle e_p = angle(R_b^T R_a, R_cv) and reweights it by w_p / (1 + (e_p / c)^2), so pairs
    that disagree with the consensus by many c lose their pull instead of bending it. Stops
    when no rotation moves by more than ``tolerance_deg``.

    Args:
        n_cams: Number of cameras M (all connected to the root).
        root: Reference camera.
        cam_a: First camera of each pair, shape (P,).
        cam_b: Second camera, shape (P,).
        R_rel: R_cv = R_b^T R_a of each pair, shape (P, 3, 3).
        weights: Prior pair weights (P,) (default: 1).
        cauchy_deg: Cauchy scale c in degrees.
        max_iterations: Reweighting rounds (a safeguard; the tolerance ends it first).
        tolerance_deg: Stop when the largest rotation change is below this.

    Returns:
        Rotations R_wc (M, 3, 3), the final robust factors (P,) in (0, 1] and the rounds run.

    References:
        IRLS rotation averaging (Chatterjee & Govindu, ICCV 2013) on the chordal relaxation
        of pmba.md §4.3.
    """
    w0 = np.ones(cam_a.shape[0]) if weights is None else np.asarray(weights, dtype=float)
    factor = np.ones_like(w0)
    R = chordal_rotation_averaging(n_cams, root, cam_a, cam_b, R_rel, w0)
    rounds = 0
    moved = np.inf
    while rounds < max_iterations and moved >= tolerance_deg:
        R_pred = np.swapaxes(R[cam_b], 1, 2) @ R[cam_a]
        e = np.rad2deg(so3.angle(R_pred, R_rel))
        factor = 1.0 / (1.0 + (e / cauchy_deg) ** 2)
        R_new = chordal_rotation_averaging(n_cams, root, cam_a, cam_b, R_rel, w0 * factor)
        moved = float(np.max(np.rad2deg(so3.angle(R_new, R))))
        R = R_new
        rounds += 1
    return R, factor, rounds
