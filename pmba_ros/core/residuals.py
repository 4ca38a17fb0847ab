"""PMBA observation rays, ray-direction errors and their analytic Jacobians (pmba.md §1.3-1.6).

Notation (per observation k of feature j by camera i; all world frame unless noted):

=======  ===========  ======  ==================================================
paper    code         shape   meaning
=======  ===========  ======  ==================================================
u        u            (K,3)   R_m n, the main anchor's ray
t        t            (K,3)   P_m - P_a, anchor baseline (D = |t|)
s, c     s, c         (K,)    |t x u| = D sin(alpha), t . u = D cos(alpha)
g        g            (K,)    s cos(theta) - c sin(theta) = D sin(alpha - theta)
N_ji     N            (K,3)   g u + sin(theta) (P_m - P_i), eq. (6) arccos-free
e_ji     residuals    (K,3)   xi(N) - R_i v, eq. (8)
J_N      J_N          (K,3,3) (I - N^ N^T) / |N|, the Jacobian of xi at N
=======  ===========  ======  ==================================================

Jacobian layout: each observation touches up to three pose "slots", (i, m, a), with 6 columns
each, ``[d phi (right perturbation R <- R Exp(d phi)), d P]``, and 3 feature columns
``[d theta, d n_1, d n_2]`` (n <- Exp(A_n dn) n). When i equals a the two slots name the same
pose and their blocks add up to pmba.md's merged associate-anchor block; main-anchor
observations (i = m) use the closed forms of §1.6, which touch R_m and n only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import so3, sphere
from pmba_ros.core.problem import Observations, ParallaxFeatures

#: Guard for |t x u| = 0 (ray exactly along the baseline) and |N| = 0; pmba.md §1.3.
_TINY = 1e-300


@dataclass(frozen=True, eq=False)
class RayGeometry:
    """Intermediate quantities of eq. (6) for every observation (see the module table)."""

    u: FloatArray
    t: FloatArray
    s: FloatArray
    c: FloatArray
    g: FloatArray
    N: FloatArray
    P_m_minus_P_i: FloatArray
    sin_t: FloatArray
    cos_t: FloatArray


def observation_rays(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                     obs: Observations) -> RayGeometry:
    """Compute N_ji = g u + sin(theta)(P_m - P_i) for all observations (PMBA eq. 6).

    References:
        PMBA eq. (6), arccos-free form (pmba.md §1.3).
    """
    j = obs.feat_idx
    m = feats.main_idx[j]
    P_m = centers_w[m]
    u = np.einsum('kij,kj->ki', R_wc[m], feats.n[j])
    t = P_m - centers_w[feats.assoc_idx[j]]
    s = np.linalg.norm(np.cross(t, u), axis=1)
    c = np.sum(t * u, axis=1)
    theta = feats.theta[j]
    sin_t, cos_t = np.sin(theta), np.cos(theta)
    g = s * cos_t - c * sin_t
    d = P_m - centers_w[obs.cam_idx]
    N = g[:, None] * u + sin_t[:, None] * d  # eq. (6)
    return RayGeometry(u, t, s, c, g, N, d, sin_t, cos_t)


def ray_residuals(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                  obs: Observations) -> FloatArray:
    """Ray-direction errors e_ji = xi(N_ji) - R_i v_ji, shape (K, 3) (PMBA eq. 8).

    References:
        PMBA eq. (8); |e| = 2 sin(beta/2) for the angle beta between the rays (pmba.md §1.4).
    """
    geo = observation_rays(R_wc, centers_w, feats, obs)
    return _residuals_from(geo, R_wc, feats, obs)


def _is_main(feats: ParallaxFeatures, obs: Observations) -> np.ndarray:
    return obs.cam_idx == feats.main_idx[obs.feat_idx]


def _residuals_from(geo: RayGeometry, R_wc: FloatArray, feats: ParallaxFeatures,
                    obs: Observations) -> FloatArray:
    norm = np.linalg.norm(geo.N, axis=1, keepdims=True)
    N_hat = geo.N / np.maximum(norm, _TINY)
    # The main anchor's ray is exactly sign(g) u; computing it so avoids cancellation.
    main = _is_main(feats, obs)
    sign_g = np.where(geo.g >= 0.0, 1.0, -1.0)
    N_hat = np.where(main[:, None], sign_g[:, None] * geo.u, N_hat)
    return N_hat - np.einsum('kij,kj->ki', R_wc[obs.cam_idx], obs.bearings_c)


def pose_slots(feats: ParallaxFeatures, obs: Observations) -> IntArray:
    """Pose index of each observation's Jacobian slots (i, m, a), shape (K, 3); -1 = unused."""
    j = obs.feat_idx
    slots = np.stack([obs.cam_idx, feats.main_idx[j], feats.assoc_idx[j]], axis=1)
    main = _is_main(feats, obs)
    slots[main, 1:] = -1
    return slots.astype(np.int64)


def ray_jacobians(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                  obs: Observations) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Residuals and analytic Jacobians of eq. (8), vectorized over observations.

    Returns:
        residuals (K, 3); J_pose (K, 3, 3, 6), the blocks of slots (i, m, a) as in
        :func:`pose_slots`, columns [d phi, d P]; J_feat (K, 3, 3), columns
        [d theta, d n_1, d n_2].

    References:
        pmba.md §1.6 (checked against central differences in the tests).
    """
    geo = observation_rays(R_wc, centers_w, feats, obs)
    res = _residuals_from(geo, R_wc, feats, obs)
    K = res.shape[0]
    j = obs.feat_idx
    R_i = R_wc[obs.cam_idx]
    R_m = R_wc[feats.main_idx[j]]
    n = feats.n[j]
    A_n = sphere.tangent_basis(n)
    u, t, s, c, g = geo.u, geo.t, geo.s, geo.c, geo.g
    sin_t, cos_t = geo.sin_t, geo.cos_t

    norm = np.maximum(np.linalg.norm(geo.N, axis=1), _TINY)
    N_hat = geo.N / norm[:, None]
    J_N = (np.eye(3) - N_hat[:, :, None] * N_hat[:, None, :]) / norm[:, None, None]
    s_safe = np.maximum(s, _TINY)
    D_sq = np.sum(t * t, axis=1)
    # dg/du = cos(theta) (D^2 u - c t)/s - sin(theta) t
    # dg/dt = cos(theta) (t - c u)/s - sin(theta) u
    dg_du = (cos_t / s_safe)[:, None] * (D_sq[:, None] * u - c[:, None] * t) - sin_t[:, None] * t
    dg_dt = (cos_t / s_safe)[:, None] * (t - c[:, None] * u) - sin_t[:, None] * u
    dN_du = g[:, None, None] * np.eye(3) + u[:, :, None] * dg_du[:, None, :]
    u_dg_dt = u[:, :, None] * dg_dt[:, None, :]
    dN_dtheta = (-(s * sin_t + c * cos_t)[:, None] * u
                 + cos_t[:, None] * geo.P_m_minus_P_i)
    Rm_nx = R_m @ so3.hat(n)
    JN_dNdu_Rm_nx = J_N @ dN_du @ Rm_nx

    J_pose = np.zeros((K, 3, 3, 6))
    J_pose[:, 0, :, :3] = R_i @ so3.hat(obs.bearings_c)            # d e / d phi_i
    J_pose[:, 0, :, 3:] = -sin_t[:, None, None] * J_N              # d e / d P_i
    J_pose[:, 1, :, :3] = -JN_dNdu_Rm_nx                           # d e / d phi_m
    J_pose[:, 1, :, 3:] = J_N @ (u_dg_dt + sin_t[:, None, None] * np.eye(3))  # d e / d P_m
    J_pose[:, 2, :, 3:] = -J_N @ u_dg_dt                           # d e / d P_a
    J_feat = np.empty((K, 3, 3))
    J_feat[:, :, 0] = np.einsum('kij,kj->ki', J_N, dN_dtheta)      # d e / d theta
    J_feat[:, :, 1:] = -JN_dNdu_Rm_nx @ A_n                        # d e / d n

    main = _is_main(feats, obs)
    if np.any(main):
        sign_g = np.where(g[main] >= 0.0, 1.0, -1.0)[:, None, None]
        hat_v = so3.hat(obs.bearings_c[main])
        hat_n = so3.hat(n[main])
        J_pose[main] = 0.0
        J_pose[main, 0, :, :3] = R_m[main] @ (hat_v - sign_g * hat_n)
        J_feat[main, :, 0] = 0.0
        J_feat[main, :, 1:] = -sign_g * (R_m[main] @ hat_n @ A_n[main])
    return res, J_pose, J_feat


def retract_features(feats: ParallaxFeatures, delta: FloatArray) -> ParallaxFeatures:
    """Apply theta <- theta + d theta and n <- Exp(A_n dn) n (PMBA eqs. 3-4); delta (N, 3)."""
    return ParallaxFeatures(feats.theta + delta[:, 0], sphere.retract(feats.n, delta[:, 1:]),
                            feats.main_idx, feats.assoc_idx)


def camera_rays(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                obs: Observations) -> FloatArray:
    """Predicted directions in each observer's camera frame, R_i^T N_ji, shape (K, 3).

    Projecting them gives the pixel reprojection of eq. (2) points without dividing by
    sin(theta), so points at infinity project to their direction.
    """
    geo = observation_rays(R_wc, centers_w, feats, obs)
    main = _is_main(feats, obs)
    N = np.where(main[:, None], np.where(geo.g >= 0, 1.0, -1.0)[:, None] * geo.u, geo.N)
    return np.einsum('kji,kj->ki', R_wc[obs.cam_idx], N)
