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
"""Init-specific anchor quantities: EG-pair masks and the frozen frames of eqs. (11)-(12).

The anchors themselves are chosen by :func:`pmba_ros.core.conversions.select_anchors`
restricted to EG pairs, and theta-bar, n-bar by
:func:`pmba_ros.core.conversions.features_from_rotations` (PMBA Remark 5). This module adds
what only the initialization needs: before positions exist, the direction
d_ma = xi(P_m - P_a) comes from the EG pair's translation (pmba.md §8 item 4), giving

==========  ============  ========  =====================================================
paper       code          shape     meaning
==========  ============  ========  =====================================================
d_ma        d_ma          (N,3)     xi(P_m - P_a) from the EG pair (m, a), world frame
u           u             (N,3)     R-bar_m n-bar, main-anchor ray, world frame
alpha-bar   alpha         (N,)      arccos(d_ma . u), eq. (11)
n_z         axis          (N,3)     xi(-d_ma x u), NORMALISED (pmba.md §8 item 1)
Q_j         Q             (N,3,3)   Exp((pi - alpha-bar) n_z): Q (P_a - P_m) = D u
==========  ============  ========  =====================================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import so3, sphere
from pmba_ros.core.problem import ParallaxFeatures
from pmba_ros.errors import InitError


def allowed_pair_mask(n_cams: int, cam_a: IntArray, cam_b: IntArray) -> BoolArray:
    """Return the symmetric (M, M) mask of camera pairs that may anchor a feature (EG pairs).

    References:
        PMBA Sec. 3.3: "co-visible poses that participate in anchor selection have to be part
        of an EG-pair" (pmba.md §3.1).
    """
    mask = np.zeros((n_cams, n_cams), dtype=bool)
    mask[cam_a, cam_b] = True
    mask[cam_b, cam_a] = True
    return mask


def anchor_directions(n_cams: int, cam_a: IntArray, cam_b: IntArray, d_ab: FloatArray,
                      main_idx: IntArray, assoc_idx: IntArray) -> FloatArray:
    """Return d_ma = xi(P_m - P_a) of every feature from its anchors' EG pair, shape (N, 3).

    Args:
        n_cams: Number of cameras M.
        cam_a: First camera of each EG pair, shape (P,) (cam_a < cam_b).
        cam_b: Second camera, shape (P,).
        d_ab: World direction xi(P_a - P_b) of each pair, shape (P, 3).
        main_idx: Main anchor of each feature, shape (N,).
        assoc_idx: Associate anchor, shape (N,).

    Raises:
        InitError: If an anchor pair is not an EG pair.

    References:
        pmba.md §4.4, §8 item 4 ([inferred] d_ma from the EG translation direction).
    """
    lo = np.minimum(main_idx, assoc_idx)
    hi = np.maximum(main_idx, assoc_idx)
    keys = cam_a * n_cams + cam_b
    order = np.argsort(keys)
    want = lo * n_cams + hi
    pos = np.searchsorted(keys[order], want)
    pos = np.minimum(pos, max(keys.shape[0] - 1, 0))
    if keys.shape[0] == 0 or np.any(keys[order][pos] != want):
        msg = 'anchor_directions: some anchor pair is not an EG pair'
        raise InitError(msg)
    d = d_ab[order][pos]
    # d_ab = xi(P_lo - P_hi); d_ma = +d_ab when m is the lower camera.
    return np.where((main_idx == lo)[:, None], d, -d)


@dataclass(frozen=True, eq=False)
class LinearizationFrames:
    """Frozen quantities of the linearised ray (eq. 12) of every feature.

    Attributes:
        alpha: alpha-bar, radians, shape (N,).
        Q: Q_j, shape (N, 3, 3), with Q_j xi(P_a - P_m) = R-bar_m n-bar.
        sin_am_t: sin(alpha-bar - theta-bar), shape (N,) (clamped >= 0).
        sin_t: sin(theta-bar), shape (N,).
        consistent: alpha-bar > theta-bar (a valid triangle), shape (N,).
    """

    alpha: FloatArray
    Q: FloatArray
    sin_am_t: FloatArray
    sin_t: FloatArray
    consistent: BoolArray


def linearization_frames(R_wc: FloatArray, features: ParallaxFeatures,
                         d_ma: FloatArray) -> LinearizationFrames:
    """Compute alpha-bar and Q_j of eq. (11) from rotations and EG directions only.

    Args:
        R_wc: Averaged camera -> world rotations, shape (M, 3, 3).
        features: theta-bar, n-bar and anchors from rotations (Remark 5).
        d_ma: xi(P_m - P_a) of every feature, shape (N, 3).

    Returns:
        The frames. Features with alpha-bar <= theta-bar (possible under noise for
        near-collinear features, pmba.md §3.3) are flagged in ``consistent`` and get
        sin(alpha-bar - theta-bar) = 0: their linearised ray is that of a point at infinity.

    References:
        PMBA eq. (11), with n_z normalised (pmba.md §8 item 1).
    """
    u = np.einsum('nij,nj->ni', R_wc[features.main_idx], features.n)
    alpha = np.arccos(np.clip(np.sum(d_ma * u, axis=1), -1.0, 1.0))  # eq. (11)
    axis = np.cross(-d_ma, u)
    norm = np.linalg.norm(axis, axis=1)
    # u parallel to the baseline: any axis perpendicular to d_ma does (rotation by 0 or pi).
    fallback = sphere.tangent_basis(d_ma)[..., 0]
    # DEVIATION(eq. 11): n_z is normalised; as printed |n_z| = sin(alpha) (pmba.md §8 item 1).
    axis = np.where((norm > 1e-12)[:, None], axis / np.maximum(norm, 1e-300)[:, None], fallback)
    Q = so3.exp((np.pi - alpha)[:, None] * axis)  # eq. (11)
    diff = alpha - features.theta
    consistent = diff > 0.0
    return LinearizationFrames(alpha, Q, np.sin(np.clip(diff, 0.0, np.pi)),
                               np.sin(features.theta), consistent)


def orient_anchors(R_wc: FloatArray, features: ParallaxFeatures, d_ma: FloatArray,
                   bearing_assoc: FloatArray) -> tuple[ParallaxFeatures, BoolArray]:
    """Swap main and associate anchors where only the swapped order gives a valid triangle.

    A feature needs theta < alpha (pmba.md §1.1). For a feature nearly on the line of motion,
    alpha is close to 0 with one anchor order and close to pi with the other, so a noisy
    theta-bar can put the point "behind" (g <= 0) with the first order only. Swapping keeps
    theta-bar, makes n-bar the associate's bearing and replaces alpha by the angle at the
    other end of the baseline.

    Args:
        R_wc: Rotations, shape (M, 3, 3).
        features: Features from rotations (n = v_m).
        d_ma: xi(P_m - P_a) of every feature, shape (N, 3).
        bearing_assoc: The associate anchor's measured bearing v_a, shape (N, 3).

    Returns:
        The features with swapped anchors where needed, and the swapped mask (N,).

    References:
        pmba.md §3.3 ("inconsistent triangle at init: pick another EG anchor pair").
    """
    u_m = np.einsum('nij,nj->ni', R_wc[features.main_idx], features.n)
    u_a = np.einsum('nij,nj->ni', R_wc[features.assoc_idx], bearing_assoc)
    alpha_m = np.arccos(np.clip(np.sum(d_ma * u_m, axis=1), -1.0, 1.0))
    alpha_a = np.arccos(np.clip(np.sum(-d_ma * u_a, axis=1), -1.0, 1.0))
    theta = features.theta
    swap = (alpha_m <= theta) & (alpha_a - theta > alpha_m - theta)
    main_idx = np.where(swap, features.assoc_idx, features.main_idx)
    assoc_idx = np.where(swap, features.main_idx, features.assoc_idx)
    n = np.where(swap[:, None], bearing_assoc, features.n)
    return ParallaxFeatures(theta.copy(), n, main_idx, assoc_idx), swap
