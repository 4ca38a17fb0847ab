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
"""Compiled PMBA rays, errors and Jacobian rows, and the sphere retraction.

Mirrors :mod:`pmba_ros.core.residuals`: the rays N = g u + sin(theta) (P_m - P_i) and errors
(PMBA eqs. 6-8), the Jacobian rows (pmba.md §1.6) and the retraction of eq. (4).
"""

from __future__ import annotations

from typing import Any, NamedTuple, TYPE_CHECKING

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import jit
from pmba_ros.core.compiled import chunks
from pmba_ros.core.residuals import RayGeometry, TINY

if TYPE_CHECKING:
    from pmba_ros.core.problem import Observations, ParallaxFeatures

_jit = jit.jit


class ObsArrays(NamedTuple):
    """The observations' arrays (:class:`~pmba_ros.core.problem.Observations`), (K,) / (K, 3)."""

    cam_idx: IntArray
    feat_idx: IntArray
    bearings_c: FloatArray


class FeatureArrays(NamedTuple):
    """PMBA features (:class:`~pmba_ros.core.problem.ParallaxFeatures`), one row each."""

    theta: FloatArray
    n: FloatArray
    main_idx: IntArray
    assoc_idx: IntArray


class FeatureTerms(NamedTuple):
    """Per-feature terms of eq. (6), as in :class:`~pmba_ros.core.residuals.RayGeometry`."""

    u: FloatArray
    t: FloatArray
    s: FloatArray
    c: FloatArray
    g: FloatArray
    sin_t: FloatArray
    cos_t: FloatArray


class RayTerms(NamedTuple):
    """Per-observation rays of eq. (6): N, P_m - P_i, xi(N), |N| and main-anchor flags."""

    N: FloatArray
    P_m_minus_P_i: FloatArray
    N_hat: FloatArray
    norm: FloatArray
    main: BoolArray


class FeatureFactors(NamedTuple):
    """Per-feature factors of the Jacobian rows: R_m [n]x, A_n, dg/du, dg/dt, dN/dtheta part."""

    Rm_hat_n: FloatArray
    A_f: FloatArray
    dg_du: FloatArray
    dg_dt: FloatArray
    dth_u: FloatArray


def _obs_arrays(obs: Observations) -> ObsArrays:
    return ObsArrays(obs.cam_idx, obs.feat_idx, obs.bearings_c)


def _feature_arrays(feats: ParallaxFeatures) -> FeatureArrays:
    return FeatureArrays(feats.theta, feats.n, feats.main_idx, feats.assoc_idx)


def _split(geo: RayGeometry) -> tuple[FeatureTerms, RayTerms]:
    return (FeatureTerms(geo.u, geo.t, geo.s, geo.c, geo.g, geo.sin_t, geo.cos_t),
            RayTerms(geo.N, geo.P_m_minus_P_i, geo.N_hat, geo.norm, geo.main))


@_jit
def _cross_into(out: Any, a0: float, a1: float, a2: float, b0: float, b1: float,
                b2: float) -> None:
    """Write a x b to ``out``, a row or column view of length 3."""
    out[0] = a1 * b2 - a2 * b1
    out[1] = a2 * b0 - a0 * b2
    out[2] = a0 * b1 - a1 * b0


@_jit
def _pmba_rows(obs: ObsArrays, feats: FeatureArrays, R_wc: FloatArray, ft: FeatureTerms,
               rt: RayTerms, ff: FeatureFactors, weights: FloatArray, rays_c: FloatArray,
               E: FloatArray, k0: int, k1: int) -> None:
    """Residual and Jacobian rows of PMBA observations k0..k1-1; see residuals.ray_jacobians."""
    cam_idx, feat_idx, v = obs.cam_idx, obs.feat_idx, obs.bearings_c
    n, main_idx = feats.n, feats.main_idx
    u, g, sin_t, cos_t = ft.u, ft.g, ft.sin_t, ft.cos_t
    d_mi, N_hat, norm, is_main = rt.P_m_minus_P_i, rt.N_hat, rt.norm, rt.main
    Rm_hat_n, A_f, dg_du, dg_dt, dth_u = ff.Rm_hat_n, ff.A_f, ff.dg_du, ff.dg_dt, ff.dth_u
    _, d, width = E.shape
    weighted = weights.shape[0] > 0
    L = np.empty((d, 3))
    B = np.empty((d, 3))
    Lu = np.empty(d)
    LdN = np.empty((d, 3))
    nA = np.empty((3, 2))
    for k in range(k0, k1):
        j = feat_idx[k]
        R = R_wc[cam_idx[k]]
        nh0, nh1, nh2 = N_hat[k, 0], N_hat[k, 1], N_hat[k, 2]
        inv = 1.0 / norm[k]
        e = E[k]
        for r in range(d):
            if weighted:
                for c in range(3):
                    B[r, c] = (weights[k, r, 0] * R[c, 0] + weights[k, r, 1] * R[c, 1]
                               + weights[k, r, 2] * R[c, 2])
                e[r, 6] = (weights[k, r, 0] * (rays_c[k, 0] - v[k, 0])
                           + weights[k, r, 1] * (rays_c[k, 1] - v[k, 1])
                           + weights[k, r, 2] * (rays_c[k, 2] - v[k, 2]))
                _cross_into(e[r], weights[k, r, 0], weights[k, r, 1], weights[k, r, 2],
                            rays_c[k, 0], rays_c[k, 1], rays_c[k, 2])   # d e / d phi_i
            else:
                for c in range(3):
                    B[r, c] = 1.0 if r == c else 0.0
                e[r, 6] = N_hat[k, r] - (R[r, 0] * v[k, 0] + R[r, 1] * v[k, 1]
                                         + R[r, 2] * v[k, 2])
                _cross_into(e[r], R[r, 0], R[r, 1], R[r, 2], v[k, 0], v[k, 1], v[k, 2])
            bn = B[r, 0] * nh0 + B[r, 1] * nh1 + B[r, 2] * nh2
            L[r, 0] = (B[r, 0] - bn * nh0) * inv
            L[r, 1] = (B[r, 1] - bn * nh1) * inv
            L[r, 2] = (B[r, 2] - bn * nh2) * inv
        if is_main[k]:
            # The main anchor's own observation: closed forms of pmba.md §1.6.
            for q in range(2):
                _cross_into(nA[:, q], n[j, 0], n[j, 1], n[j, 2], A_f[j, 0, q], A_f[j, 1, q],
                            A_f[j, 2, q])
            Rm = R_wc[main_idx[j]]
            for r in range(d):
                for c in range(width):
                    if c != 6 and (c >= 3 or weighted):
                        e[r, c] = 0.0
                for c in range(3):
                    if not weighted:
                        e[r, c] -= Rm_hat_n[j, r, c]
                for q in range(2):
                    acc = 0.0
                    for c in range(3):
                        m = weights[k, r, c] if weighted else Rm[r, c]
                        acc += m * nA[c, q]
                    e[r, 8 + q] = -acc
            continue
        s_t, c_t, g_j = sin_t[j], cos_t[j], g[j]
        for r in range(d):
            Lu[r] = L[r, 0] * u[j, 0] + L[r, 1] * u[j, 1] + L[r, 2] * u[j, 2]
            acc = 0.0
            for c in range(3):
                LdN[r, c] = g_j * L[r, c] + Lu[r] * dg_du[j, c]
                acc += L[r, c] * (dth_u[j, c] + c_t * d_mi[k, c])
                L_u_dgdt = Lu[r] * dg_dt[j, c]
                e[r, 3 + c] = -s_t * L[r, c]
                e[r, 13 + c] = L_u_dgdt + s_t * L[r, c]
                e[r, 16 + c] = -L_u_dgdt
            e[r, 7] = acc
            for c in range(3):
                e[r, 10 + c] = -(LdN[r, 0] * Rm_hat_n[j, 0, c] + LdN[r, 1] * Rm_hat_n[j, 1, c]
                                 + LdN[r, 2] * Rm_hat_n[j, 2, c])
            for q in range(2):
                e[r, 8 + q] = (e[r, 10] * A_f[j, 0, q] + e[r, 11] * A_f[j, 1, q]
                               + e[r, 12] * A_f[j, 2, q])


@_jit
def _tangent_basis_into(n0: float, n1: float, n2: float, A: Any) -> None:
    """Write sphere.tangent_basis of n to A (3, 2): a1 = xi(e_k x n), a2 = n x a1.

    e_k is the axis least aligned with n (the first on ties, as numpy's argmin).
    """
    k = 0
    if abs(n1) < abs(n0):
        k = 1
    if abs(n2) < abs((n0, n1)[k]):
        k = 2
    a0, a1, a2 = (0.0, -n2, n1) if k == 0 else ((n2, 0.0, -n0) if k == 1 else (-n1, n0, 0.0))
    na = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    if na > 0.0:
        a0, a1, a2 = a0 / na, a1 / na, a2 / na
    A[0, 0], A[1, 0], A[2, 0] = a0, a1, a2
    A[0, 1] = n1 * a2 - n2 * a1
    A[1, 1] = n2 * a0 - n0 * a2
    A[2, 1] = n0 * a1 - n1 * a0


@_jit
def _pmba_feature_factors(R_wc: FloatArray, feats: FeatureArrays, ft: FeatureTerms,
                          ff: FeatureFactors) -> None:
    """Compute the per-feature factors of residuals.ray_jacobians.

    R_m [n]x, A_n (as sphere.tangent_basis), dg/du, dg/dt and -(s sin(theta) + c cos(theta)) u.
    """
    n, main_idx = feats.n, feats.main_idx
    u, t, s, c, sin_t, cos_t = ft.u, ft.t, ft.s, ft.c, ft.sin_t, ft.cos_t
    Rm_hat_n, A_f, dg_du, dg_dt, dth_u = ff.Rm_hat_n, ff.A_f, ff.dg_du, ff.dg_dt, ff.dth_u
    for j in range(n.shape[0]):
        R = R_wc[main_idx[j]]
        n0, n1, n2 = n[j, 0], n[j, 1], n[j, 2]
        for r in range(3):
            _cross_into(Rm_hat_n[j, r], R[r, 0], R[r, 1], R[r, 2], n0, n1, n2)
        _tangent_basis_into(n0, n1, n2, A_f[j])
        cos_over_s = cos_t[j] / max(s[j], TINY)
        D_sq = t[j, 0] * t[j, 0] + t[j, 1] * t[j, 1] + t[j, 2] * t[j, 2]
        for r in range(3):
            dg_du[j, r] = cos_over_s * (D_sq * u[j, r] - c[j] * t[j, r]) - sin_t[j] * t[j, r]
            dg_dt[j, r] = cos_over_s * (t[j, r] - c[j] * u[j, r]) - sin_t[j] * u[j, r]
            dth_u[j, r] = -(s[j] * sin_t[j] + c[j] * cos_t[j]) * u[j, r]


def pmba_rows(obs: Observations, feats: ParallaxFeatures, R_wc: FloatArray, geo: RayGeometry,
              weights: FloatArray | None, rays_c: FloatArray | None, E: FloatArray) -> None:
    """Fill E (K, d, 19) with the PMBA rows of residuals.ray_jacobians."""
    N = feats.n.shape[0]
    ff = FeatureFactors(np.empty((N, 3, 3)), np.empty((N, 3, 2)), np.empty((N, 3)),
                        np.empty((N, 3)), np.empty((N, 3)))
    R_wc = np.ascontiguousarray(R_wc)
    fa = _feature_arrays(feats)
    ft, rt = _split(geo)
    _pmba_feature_factors(R_wc, fa, ft, ff)
    oa = _obs_arrays(obs)
    w = np.zeros((0, 3, 3)) if weights is None else weights
    rays = geo.N_hat if rays_c is None else rays_c
    K = E.shape[0]
    n = chunks.threads_for(K)
    cut = chunks.cuts(n, K)
    chunks.run(lambda t: _pmba_rows(oa, fa, R_wc, ft, rt, ff, w, rays, E, int(cut[t]),
                                    int(cut[t + 1])), n)


@_jit
def _pmba_rays(R_wc: FloatArray, centers_w: FloatArray, feats: FeatureArrays, obs: ObsArrays,
               weights: FloatArray, ft: FeatureTerms, rt: RayTerms, rays_c: FloatArray,
               res: FloatArray) -> None:
    """Rays N = g u + sin(theta) (P_m - P_i) (PMBA eq. 6), R_i^T xi(N) and the errors (eq. 8).

    Writes ``ft``, ``rt``, ``rays_c`` and ``res``.
    """
    theta, n, main_idx, assoc_idx = feats.theta, feats.n, feats.main_idx, feats.assoc_idx
    cam_idx, feat_idx, v = obs.cam_idx, obs.feat_idx, obs.bearings_c
    u, t, s, c, g, sin_t, cos_t = ft.u, ft.t, ft.s, ft.c, ft.g, ft.sin_t, ft.cos_t
    N, d, N_hat, norm, main = rt.N, rt.P_m_minus_P_i, rt.N_hat, rt.norm, rt.main
    for j in range(theta.shape[0]):
        m, a = main_idx[j], assoc_idx[j]
        for r in range(3):
            u[j, r] = R_wc[m, r, 0] * n[j, 0] + R_wc[m, r, 1] * n[j, 1] + R_wc[m, r, 2] * n[j, 2]
            t[j, r] = centers_w[m, r] - centers_w[a, r]
        x0 = t[j, 1] * u[j, 2] - t[j, 2] * u[j, 1]
        x1 = t[j, 2] * u[j, 0] - t[j, 0] * u[j, 2]
        x2 = t[j, 0] * u[j, 1] - t[j, 1] * u[j, 0]
        s[j] = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        c[j] = t[j, 0] * u[j, 0] + t[j, 1] * u[j, 1] + t[j, 2] * u[j, 2]
        sin_t[j], cos_t[j] = np.sin(theta[j]), np.cos(theta[j])
        g[j] = s[j] * cos_t[j] - c[j] * sin_t[j]
    weighted = weights.shape[0] > 0
    for k in range(cam_idx.shape[0]):
        j, i = feat_idx[k], cam_idx[k]
        m = main_idx[j]
        sq = 0.0
        for r in range(3):
            d[k, r] = centers_w[m, r] - centers_w[i, r]
            N[k, r] = g[j] * u[j, r] + sin_t[j] * d[k, r]
            sq += N[k, r] * N[k, r]
        norm[k] = max(np.sqrt(sq), TINY)
        main[k] = i == m
        # The main anchor's ray is u itself (residuals.RayGeometry).
        for r in range(3):
            N_hat[k, r] = u[j, r] if main[k] else N[k, r] / norm[k]
        for r in range(3):
            rays_c[k, r] = (R_wc[i, 0, r] * N_hat[k, 0] + R_wc[i, 1, r] * N_hat[k, 1]
                            + R_wc[i, 2, r] * N_hat[k, 2])
        for r in range(res.shape[1]):
            if weighted:
                res[k, r] = (weights[k, r, 0] * (rays_c[k, 0] - v[k, 0])
                             + weights[k, r, 1] * (rays_c[k, 1] - v[k, 1])
                             + weights[k, r, 2] * (rays_c[k, 2] - v[k, 2]))
            else:
                res[k, r] = N_hat[k, r] - (R_wc[i, r, 0] * v[k, 0] + R_wc[i, r, 1] * v[k, 1]
                                           + R_wc[i, r, 2] * v[k, 2])


def pmba_rays(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
              obs: Observations, weights: FloatArray | None,
              ) -> tuple[RayGeometry, FloatArray, FloatArray]:
    """Return the rays (residuals.RayGeometry), the camera rays and the residuals."""
    N_f, K = feats.theta.shape[0], obs.cam_idx.shape[0]
    ft = FeatureTerms(np.empty((N_f, 3)), np.empty((N_f, 3)),
                      *(np.empty(N_f) for _ in range(5)))
    rt = RayTerms(np.empty((K, 3)), np.empty((K, 3)), np.empty((K, 3)), np.empty(K),
                  np.empty(K, dtype=np.bool_))
    rays_c = np.empty((K, 3))
    res = np.empty((K, 3))
    _pmba_rays(np.ascontiguousarray(R_wc), np.ascontiguousarray(centers_w),
               _feature_arrays(feats), _obs_arrays(obs),
               np.zeros((0, 3, 3)) if weights is None else weights, ft, rt, rays_c, res)
    return RayGeometry(*ft, *rt), rays_c, res


@_jit
def _sphere_retract(n: Any, delta: Any, out: Any) -> None:
    """Retract unit rays: xi(cos(phi) n + sin(phi)/phi A_n (d2, -d1)), phi = |delta|."""
    A = np.empty((3, 2))
    for j in range(n.shape[0]):
        _tangent_basis_into(n[j, 0], n[j, 1], n[j, 2], A)
        d0, d1 = delta[j, 0], delta[j, 1]
        phi_sq = d0 * d0 + d1 * d1
        if phi_sq < 1e-12:
            sinc = 1.0 - phi_sq / 6.0
        else:
            sinc = np.sin(np.sqrt(phi_sq)) / np.sqrt(phi_sq)
        cos_phi = np.cos(np.sqrt(phi_sq))
        sq = 0.0
        for r in range(3):
            out[j, r] = cos_phi * n[j, r] + sinc * (A[r, 0] * d1 - A[r, 1] * d0)
            sq += out[j, r] * out[j, r]
        if sq > 0.0:
            inv = 1.0 / np.sqrt(sq)
            for r in range(3):
                out[j, r] *= inv


def sphere_retract(n: FloatArray, delta: FloatArray) -> FloatArray:
    """Return Exp(A_n delta) n for unit vectors n (N, 3) and delta (N, 2) (PMBA eq. 4)."""
    out = np.empty_like(n)
    _sphere_retract(np.ascontiguousarray(n), np.ascontiguousarray(delta), out)
    return out
