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
"""PMBA observation rays, ray-direction errors and their analytic Jacobians (pmba.md §1.3-1.6).

Notation (per observation k of feature j by camera i; all world frame unless noted). Only N
and P_m - P_i depend on the observer; the rest is computed once per feature (N features):

=======  ===========  ======  ==================================================
paper    code         shape   meaning
=======  ===========  ======  ==================================================
u        u            (N,3)   R_m n, the main anchor's ray
t        t            (N,3)   P_m - P_a, anchor baseline (D = |t|)
s, c     s, c         (N,)    |t x u| = D sin(alpha), t . u = D cos(alpha)
g        g            (N,)    s cos(theta) - c sin(theta) = D sin(alpha - theta)
N_ji     N            (K,3)   g u + sin(theta) (P_m - P_i), eq. (6) arccos-free
e_ji     residuals    (K,3)   xi(N) - R_i v, eq. (8)
J_N      (in L)       (K,3,3) (I - N^ N^T) / |N|, the Jacobian of xi at N
=======  ===========  ======  ==================================================

Jacobian layout (:mod:`pmba_ros.core.jacobian`): each observation touches up to three pose
"slots", (i, m, a), columns ``[d phi (right perturbation R <- R Exp(d phi)), d P]`` (the
associate anchor's d P only), and 3 feature columns ``[d theta, d n_1, d n_2]``
(n <- Exp(A_n dn) n). When i equals a the two slots name the same pose and their blocks add
up to pmba.md's merged associate-anchor block; main-anchor observations (i = m) use the
closed forms of §1.6, which touch R_m and n only.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import so3, sphere
from pmba_ros.core.jacobian import Linearization
from pmba_ros.core.problem import Observations, ParallaxFeatures

#: Pose columns of the anchor slots: the main anchor's rotation and centre, the associate
#: anchor's centre (its rotation does not enter eq. 6).
ANCHOR_COLS = ((0, 6), (3, 6))
#: Guard for |t x u| = 0 (ray exactly along the baseline) and |N| = 0 (pmba.md §1.3).
TINY = 1e-300


@dataclass(frozen=True, eq=False)
class RayGeometry:
    """Intermediate quantities of eq. (6) (see the module table).

    u, t, s, c, g, sin_t and cos_t are per feature; the rest per observation: N, P_m - P_i,
    the unit ray N_hat = xi(N) and |N| (floored), and which observations are the main
    anchor's own. The main anchor's N_hat is u = R_m n itself (pmba.md §1.3): exact, without
    the cancellation in g u + sin(theta) 0, and continuous where g changes sign (a point
    passing the main anchor's centre), which sign(g) u is not.
    """

    u: FloatArray
    t: FloatArray
    s: FloatArray
    c: FloatArray
    g: FloatArray
    sin_t: FloatArray
    cos_t: FloatArray
    N: FloatArray
    P_m_minus_P_i: FloatArray
    N_hat: FloatArray
    norm: FloatArray
    main: BoolArray


def anchor_terms(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                 ) -> tuple[FloatArray, ...]:
    """Return the per-feature terms of eq. (6): u, t, s, c, sin(theta), cos(theta), g.

    See the module table; each has one row per feature.
    """
    u = np.einsum('kij,kj->ki', R_wc[feats.main_idx], feats.n)
    t = centers_w[feats.main_idx] - centers_w[feats.assoc_idx]
    s = sphere.norms(so3.cross(t, u))
    c = sphere.dots(t, u)
    sin_t, cos_t = np.sin(feats.theta), np.cos(feats.theta)
    return u, t, s, c, sin_t, cos_t, s * cos_t - c * sin_t


def observation_rays(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                     obs: Observations) -> RayGeometry:
    """Compute N_ji = g u + sin(theta)(P_m - P_i) for all observations (PMBA eq. 6).

    References:
        PMBA eq. (6), arccos-free form (pmba.md §1.3).
    """
    u, t, s, c, sin_t, cos_t, g = anchor_terms(R_wc, centers_w, feats)
    j = obs.feat_idx
    d = centers_w[feats.main_idx[j]] - centers_w[obs.cam_idx]
    N = (g[:, None] * u)[j] + sin_t[j, None] * d  # eq. (6)
    norm = np.maximum(sphere.norms(N), TINY)
    N_hat = N / norm[:, None]
    main = _is_main(feats, obs)
    jm = j[main]
    N_hat[main] = u[jm]
    return RayGeometry(u, t, s, c, g, sin_t, cos_t, N, d, N_hat, norm, main)


def rays_and_residuals(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                       obs: Observations, weights: FloatArray | None = None,
                       ) -> tuple[RayGeometry, FloatArray, FloatArray]:
    """Return the rays of eq. (6), R_i^T xi(N) and the errors of eq. (8) (weighted: in pixels).

    ``weights`` as in :func:`ray_jacobians`.
    """
    geo = observation_rays(R_wc, centers_w, feats, obs)
    rays_c = camera_rays_from(geo, R_wc, obs)
    if weights is None:
        return geo, rays_c, residuals_from(geo, R_wc, obs)
    return geo, rays_c, pixel_weighted_residuals(weights, rays_c, obs)


def ray_residuals(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                  obs: Observations) -> FloatArray:
    """Ray-direction errors e_ji = xi(N_ji) - R_i v_ji, shape (K, 3) (PMBA eq. 8).

    References:
        PMBA eq. (8); |e| = 2 sin(beta/2) for the angle beta between the rays (pmba.md §1.4).
    """
    return residuals_from(observation_rays(R_wc, centers_w, feats, obs), R_wc, obs)


def _is_main(feats: ParallaxFeatures, obs: Observations) -> np.ndarray:
    out: np.ndarray = obs.cam_idx == feats.main_idx[obs.feat_idx]
    return out


def residuals_from(geo: RayGeometry, R_wc: FloatArray, obs: Observations) -> FloatArray:
    """Ray-direction errors (PMBA eq. 8) from the rays of :func:`observation_rays`."""
    out: FloatArray = geo.N_hat - np.einsum('kij,kj->ki', R_wc[obs.cam_idx], obs.bearings_c)
    return out


def pixel_weights(jac_px: FloatArray, bearings_c: FloatArray) -> FloatArray:
    """Return the (K, 3, 3) maps of observer-frame ray errors to pixel-weighted residuals.

    Rows 1-2 are d pi/d h at the measured bearing v (``jac_px``, (K, 2, 3)). They cannot see
    the error along v, so on their own a ray turned by an angle beta has a residual growing
    like sin(beta): it falls again past 90 degrees and vanishes at the antipode, a false
    minimum that a poor start (a street's far features) drifts towards. Row 3 is
    sigma_max v^T (sigma_max the largest singular value of ``jac_px``): it adds
    sigma_max^2 (1 - cos beta)^2 to the squared residual, fourth order in the error near the
    measurement (the pixel weighting holds there), and makes the norm increase up to
    beta = 180 degrees.
    """
    # sigma_max^2: the larger eigenvalue of the 2x2 J J^T (its entries as row products:
    # batched 2x3 @ 3x2 products cost more than the arithmetic).
    g00 = np.einsum('ki,ki->k', jac_px[:, 0], jac_px[:, 0])
    g11 = np.einsum('ki,ki->k', jac_px[:, 1], jac_px[:, 1])
    g01 = np.einsum('ki,ki->k', jac_px[:, 0], jac_px[:, 1])
    half_trace = 0.5 * (g00 + g11)
    det = g00 * g11 - g01 * g01
    sigma_max = np.sqrt(half_trace + np.sqrt(np.maximum(half_trace ** 2 - det, 0.0)))
    return np.concatenate([jac_px, (sigma_max[:, None] * bearings_c)[:, None, :]], axis=1)


def pixel_weighted_residuals(weights: FloatArray, rays_c: FloatArray,
                             obs: Observations) -> FloatArray:
    """Return weights (R_i^T xi(N) - v), the ray errors mapped to pixels, shape (K, 3)."""
    out: FloatArray = np.einsum('kij,kj->ki', weights, rays_c - obs.bearings_c)
    return out


def pose_slots(feats: ParallaxFeatures, obs: Observations) -> IntArray:
    """Pose index of each observation's Jacobian slots (i, m, a), shape (K, 3); -1 = unused."""
    j = obs.feat_idx
    slots = np.stack([obs.cam_idx, feats.main_idx[j], feats.assoc_idx[j]], axis=1)
    main = _is_main(feats, obs)
    slots[main, 1:] = -1
    return slots.astype(np.int64)


def ray_jacobians(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                  obs: Observations, weights: FloatArray | None = None,
                  geo: RayGeometry | None = None, rays_c: FloatArray | None = None,
                  ) -> Linearization:
    """Residuals and analytic Jacobians of eq. (8), vectorized over observations.

    Args:
        R_wc: Camera -> world rotations, shape (M, 3, 3).
        centers_w: Camera centres, shape (M, 3).
        feats: PMBA features.
        obs: Observations.
        weights: Optional (K, 3, 3) maps of observer-frame errors to pixels
            (:func:`pixel_weights`): the residual becomes ``weights (R_i^T xi(N) - v)``.
        geo: :func:`observation_rays` at this state, if the caller has it.
        rays_c: :func:`camera_rays_from` of ``geo``, if the caller has it (weighted only).

    Returns:
        The residuals and Jacobian in the layout of :mod:`pmba_ros.core.jacobian`, anchor
        slots (m, a) with :data:`ANCHOR_COLS`; feature columns [d theta, d n_1, d n_2];
        d = 3 rows.

    References:
        pmba.md §1.6 (checked against central differences in the tests).
    """
    if geo is None:
        geo = observation_rays(R_wc, centers_w, feats, obs)
    K = obs.cam_idx.shape[0]
    if weights is not None and rays_c is None:
        rays_c = camera_rays_from(geo, R_wc, obs)
    # Blocks are written in place into the rows of pmba_ros.core.jacobian (strided views).
    lin = Linearization.empty(K, 3, ANCHOR_COLS)
    E = lin.rows
    j = obs.feat_idx
    R_i = R_wc[obs.cam_idx]
    v = obs.bearings_c
    u, t, s, c, g = geo.u, geo.t, geo.s, geo.c, geo.g
    sin_t, cos_t = geo.sin_t, geo.cos_t
    # Per-feature factors: R_m [n]x, A_n and the derivatives of g (shared by a feature's
    # observations):
    # dg/du = cos(theta) (D^2 u - c t)/s - sin(theta) t
    # dg/dt = cos(theta) (t - c u)/s - sin(theta) u
    Rm_hat_n = so3.times_hat(R_wc[feats.main_idx], feats.n)
    A_f = sphere.tangent_basis(feats.n)
    cos_over_s = cos_t / np.maximum(s, TINY)
    D_sq = np.sum(t * t, axis=1)
    dg_du_f = cos_over_s[:, None] * (D_sq[:, None] * u - c[:, None] * t) - sin_t[:, None] * t
    dg_dt_f = cos_over_s[:, None] * (t - c[:, None] * u) - sin_t[:, None] * u
    dth_u = (-(s * sin_t + c * cos_t))[:, None] * u      # d N / d theta without cos(theta) d
    dg_du, dg_dt = dg_du_f[j], dg_dt_f[j]

    N_hat, norm, main = geo.N_hat, geo.norm, geo.main
    # L, the left factor of every block, is d xi / d N = (I - N^ N^T) / |N| (weighted:
    # weights R_i^T times it, formed as (B - (B N^) N^T) / |N| without the 3x3 product).
    # The main anchor's N^ = u equals N / |N| up to rounding where g > 0.
    if weights is None or rays_c is None:     # rays_c is set whenever weights are
        L = (np.eye(3) - N_hat[:, :, None] * N_hat[:, None, :]) / norm[:, None, None]
        E[:, :, 6] = residuals_from(geo, R_wc, obs)
        E[:, :, 0:3] = so3.times_hat(R_i, v)                     # d e / d phi_i
    else:
        B = weights @ np.swapaxes(R_i, 1, 2)
        L = (B - np.einsum('kij,kj->ki', B, N_hat)[:, :, None] * N_hat[:, None, :]
             ) / norm[:, None, None]
        E[:, :, 6] = pixel_weighted_residuals(weights, rays_c, obs)
        E[:, :, 0:3] = so3.times_hat(weights, rays_c)
    u_j = u[j]
    Lu = np.einsum('kij,kj->ki', L, u_j)
    # L dN/du = L (g I + u dg/du^T) and L u dg/dt^T, as outer products of small vectors.
    L_dNdu = g[j, None, None] * L + Lu[:, :, None] * dg_du[:, None, :]
    L_u_dgdt = Lu[:, :, None] * dg_dt[:, None, :]
    dN_dtheta = dth_u[j] + cos_t[j, None] * geo.P_m_minus_P_i

    L_sin = sin_t[j, None, None] * L
    np.negative(L_sin, out=E[:, :, 3:6])                         # d e / d P_i
    np.einsum('kij,kj->ki', L, dN_dtheta, out=E[:, :, 7])        # d e / d theta
    np.matmul(L_dNdu, -Rm_hat_n[j], out=E[:, :, 10:13])          # d e / d phi_m
    np.matmul(E[:, :, 10:13], A_f[j], out=E[:, :, 8:10])         # d e / d n
    np.add(L_u_dgdt, L_sin, out=E[:, :, 13:16])                  # d e / d P_m
    np.negative(L_u_dgdt, out=E[:, :, 16:19])                    # d e / d P_a

    if np.any(main):
        rows = np.flatnonzero(main)
        jm = j[rows]
        hat_n_A = so3.hat(feats.n[jm]) @ A_f[jm]
        res_main = E[rows, :, 6]
        E[rows] = 0.0
        E[rows, :, 6] = res_main
        if weights is None:
            R_m = R_wc[feats.main_idx[jm]]
            E[rows, :, 0:3] = so3.times_hat(R_m, v[rows]) - Rm_hat_n[jm]
            E[rows, :, 8:10] = -(R_m @ hat_n_A)
        else:
            # In the main anchor's own frame its error n - v does not depend on R_m.
            E[rows, :, 8:10] = -(weights[rows] @ hat_n_A)
    return lin


def retract_features(feats: ParallaxFeatures, delta: FloatArray,
                     retract: Callable[[FloatArray, FloatArray], FloatArray] = sphere.retract,
                     ) -> ParallaxFeatures:
    """Apply theta <- theta + d theta and n <- Exp(A_n dn) n (PMBA eqs. 3-4); delta (N, 3).

    ``retract`` is :func:`pmba_ros.core.sphere.retract` or an engine's equal.
    """
    return ParallaxFeatures(feats.theta + delta[:, 0], retract(feats.n, delta[:, 1:]),
                            feats.main_idx, feats.assoc_idx)


def camera_rays_from(geo: RayGeometry, R_wc: FloatArray, obs: Observations) -> FloatArray:
    """Predicted unit directions in each observer's camera frame, R_i^T xi(N_ji), (K, 3).

    Projecting them gives the pixel reprojection of eq. (2) points without dividing by
    sin(theta), so points at infinity project to their direction.
    """
    out: FloatArray = np.einsum('kji,kj->ki', R_wc[obs.cam_idx], geo.N_hat)
    return out
