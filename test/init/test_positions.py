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
"""Tests of the position stages: eq. (11) frames, eq. (12) rays, CLS (eq. 14), NLS (eq. 13)."""

from __future__ import annotations

from dataclasses import dataclass
from test.init.scenes import street_scene

import numpy as np
from pmba_ros.core import conversions, residuals
from pmba_ros.core.engine import Engine
from pmba_ros.core.problem import BAProblem, ParallaxFeatures
from pmba_ros.init import anchors, cls, nls
import pytest


@dataclass
class _Setup:
    problem: BAProblem
    features: ParallaxFeatures
    frames: anchors.LinearizationFrames
    lin: cls.LinearRays
    root: int


def _setup(seed: int, noise_px: float = 0.0, jitter_m: float = 0.4) -> _Setup:
    """Anchors, features and frames from the true rotations and true anchor directions."""
    p = street_scene(seed, n_cams=8, n_points=200, noise_px=noise_px,
                     translation_jitter_m=jitter_m).gt
    allowed = np.ones((p.n_cams, p.n_cams), dtype=bool)
    main_idx, assoc_idx, ok = conversions.select_anchors(p, p.R_wc, allowed_pairs=allowed)
    assert ok.all()
    feats = conversions.features_from_rotations(p, p.R_wc, main_idx, assoc_idx)
    d_ma = p.centers_w[main_idx] - p.centers_w[assoc_idx]
    d_ma /= np.linalg.norm(d_ma, axis=1, keepdims=True)
    frames = anchors.linearization_frames(p.R_wc, feats, d_ma)
    lin = cls.linear_rays(p.R_wc, feats, frames, p.obs.cam_idx, p.obs.feat_idx,
                          p.obs.bearings_c)
    return _Setup(p, feats, frames, lin, 0)


def _aligned_error(P: np.ndarray, P_true: np.ndarray, root: int) -> float:
    """Relative error of P against P_true after removing translation (root) and scale."""
    A = P - P[root]
    B = P_true - P_true[root]
    s = float(np.sum(A * B) / np.sum(A * A))
    return float(np.linalg.norm(s * A - B) / np.linalg.norm(B))


def test_eq11_frame_maps_the_baseline_onto_the_main_ray() -> None:
    """Q_j xi(P_a - P_m) = R_m n (eq. 11 with n_z normalised), alpha = angle(d_ma, u)."""
    st = _setup(0)
    p, f = st.problem, st.features
    d_am = p.centers_w[f.assoc_idx] - p.centers_w[f.main_idx]
    d_am /= np.linalg.norm(d_am, axis=1, keepdims=True)
    u = np.einsum('nij,nj->ni', p.R_wc[f.main_idx], f.n)
    np.testing.assert_allclose(np.einsum('nij,nj->ni', st.frames.Q, d_am), u, atol=1e-10)
    assert st.frames.consistent.all()


def test_eq12_linear_ray_equals_eq6_ray_at_the_linearization_point() -> None:
    """N-bar(P) of eq. (12) at the true positions is eq. (6)'s N, vector for vector."""
    st = _setup(1)
    p = st.problem
    N_bar = st.lin.evaluate(p.centers_w)
    geo = residuals.observation_rays(p.R_wc, p.centers_w, st.features, p.obs)
    np.testing.assert_allclose(N_bar, geo.N, atol=1e-9 * np.abs(geo.N).max())


def test_anchor_directions_follow_the_anchor_order() -> None:
    """d_ma is +d_ab when the main anchor is the pair's first camera, else -d_ab."""
    cam_a, cam_b = np.array([0, 1]), np.array([2, 2])
    d_ab = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    d = anchors.anchor_directions(3, cam_a, cam_b, d_ab, np.array([0, 2, 1]),
                                  np.array([2, 0, 2]))
    np.testing.assert_allclose(d, [[1, 0, 0], [-1, 0, 0], [0, 1, 0]])


def test_orient_anchors_swaps_a_collinear_feature_behind_its_main_anchor() -> None:
    """A point ahead on the line of motion with the later camera as main anchor is swapped."""
    R = np.broadcast_to(np.eye(3), (2, 3, 3))
    # Cameras at z = 0 and z = 1 looking along +z; the point at z = 50 slightly off-axis.
    X = np.array([0.01, 0.0, 50.0])
    v0 = X / np.linalg.norm(X)
    v1 = (X - [0, 0, 1]) / np.linalg.norm(X - [0, 0, 1])
    theta = np.arccos(v0 @ v1) + 5e-4  # noisy theta-bar: larger than alpha with main = 1
    feats = ParallaxFeatures(np.array([theta]), v1[None], np.array([1]), np.array([0]))
    d_ma = np.array([[0.0, 0.0, 1.0]])  # xi(P_1 - P_0)
    out, swapped = anchors.orient_anchors(R, feats, d_ma, v0[None])
    assert swapped.tolist() == [True]
    assert out.main_idx.tolist() == [0] and out.assoc_idx.tolist() == [1]
    np.testing.assert_allclose(out.n[0], v0)


@pytest.mark.parametrize('jitter_m', [0.4, 0.0])
def test_cls_recovers_true_positions_up_to_scale_without_noise(jitter_m: float) -> None:
    """Exact rotations, theta and directions: the CLS solution is the truth (incl. collinear)."""
    st = _setup(2, jitter_m=jitter_m)
    res = cls.solve_cls(st.lin, st.problem.n_cams, st.root)
    assert _aligned_error(res.centers_w, st.problem.centers_w, st.root) < 1e-8
    assert res.cheirality_violations == 0
    assert np.all(res.centers_w[st.root] == 0.0)
    # Scale constraint: sum_k r_k . N-bar_k(P) = K.
    N = st.lin.evaluate(res.centers_w)
    assert np.sum(st.lin.rays * N) == pytest.approx(st.problem.n_obs, rel=1e-9)


def test_nls_returns_to_the_truth_from_a_perturbed_start(rng: np.random.Generator) -> None:
    """Eq. (13) without noise has its minimum (zero) at the true positions."""
    st = _setup(3)
    P_true = st.problem.centers_w
    start = P_true + rng.normal(scale=0.05, size=P_true.shape)
    res = nls.solve_nls(st.lin, start, st.root, f_scale=3.0 / 500.0,
                        function_tolerance=1e-14)
    assert res.final_cost < 1e-12 < res.initial_cost
    assert _aligned_error(res.centers_w, P_true, st.root) < 1e-6


def test_cls_then_nls_are_accurate_with_noise() -> None:
    """With 0.5 px noise (true rotations), CLS and NLS positions are within 2 % of the path."""
    st = _setup(4, noise_px=0.5)
    res_cls = cls.solve_cls(st.lin, st.problem.n_cams, st.root)
    res_nls = nls.solve_nls(st.lin, res_cls.centers_w, st.root, f_scale=3.0 / 500.0)
    P_true = st.problem.centers_w
    assert _aligned_error(res_cls.centers_w, P_true, st.root) < 0.02
    assert _aligned_error(res_nls.centers_w, P_true, st.root) < 0.02
    assert res_nls.final_cost <= res_nls.initial_cost


def test_per_feature_normal_matrix_and_gradient_equal_the_dense_jacobian(
        rng: np.random.Generator, engine: Engine) -> None:
    """sum_k G_k^T A_k G_k and sum_k G_k^T y_k equal J^T blockdiag(A) J and J^T y.

    N-bar is linear in P, so the dense Jacobian's columns are N-bar at unit positions. The
    normal matrix from numpy and from the compiled loop.
    """
    st = _setup(5)
    lin, M, K = st.lin, st.problem.n_cams, st.problem.n_obs
    J = np.empty((K, 3, 3 * M))
    for col in range(3 * M):
        unit = np.zeros(3 * M)
        unit[col] = 1.0
        J[:, :, col] = lin.evaluate(unit.reshape(M, 3))
    L = rng.normal(size=(K, 3, 3))
    A = L @ np.swapaxes(L, 1, 2)
    y = rng.normal(size=(K, 3))
    H_ref = np.einsum('kai,kab,kbj->ij', J, A, J)
    P = rng.normal(size=(M, 3))
    np.testing.assert_allclose(lin.evaluate(P, engine.name), np.einsum('kai,i->ka', J, P.ravel()),
                               atol=1e-12)
    np.testing.assert_allclose(lin.depths(P, engine.name),
                               np.sum(lin.rays * lin.evaluate(P, 'numpy'), axis=1), atol=1e-12)
    # The cheirality rows' blocks; an observer that is also an anchor is not merged here.
    blocks = (np.einsum('kai,ka->ki', lin.anchor_coeff[lin.feat, 0], lin.rays),
              np.einsum('kai,ka->ki', lin.anchor_coeff[lin.feat, 1], lin.rays),
              -lin.sin_t[lin.feat, None] * lin.rays)
    np.testing.assert_allclose(lin.cheirality_row_norms(engine.name),
                               sum(np.sum(b * b, axis=1) for b in blocks), rtol=1e-12)
    np.testing.assert_allclose(lin.normal_matrix(A, M, engine.name), H_ref,
                               atol=1e-10 * np.abs(H_ref).max())
    g_ref = np.einsum('kai,ka->i', J, y)
    np.testing.assert_allclose(lin.gradient(y, M, engine.name), g_ref,
                               atol=1e-10 * np.abs(g_ref).max())
    # Anchors observe their own features: the i = m and i = a blocks add up.
    assert np.any(lin.cam == lin.main[lin.feat]) and np.any(lin.cam == lin.assoc[lin.feat])


def test_nls_engines_agree(engine: Engine) -> None:
    """The compiled NLS gives the numpy reference's cost, normal equations and positions.

    Per-observation Cauchy scales and weights of 0 (dropped tracks) included.
    """
    st = _setup(6, noise_px=0.5)
    lin, M = st.lin, st.problem.n_cams
    start = cls.solve_cls(lin, M, st.root).centers_w
    w = np.ones(lin.n_obs)
    w[::7] = 0.0
    f_scale = np.linspace(2.0, 4.0, lin.n_obs) / 500.0
    cost, N, e = nls._evaluate(lin, start, f_scale, w)
    H, g = nls._normal_blocks(lin, N, e, f_scale, w, M)
    if engine.name.value == 'compiled':
        fast = nls._Compiled(lin, f_scale, w)
        cost_c, N_c, e_c = fast.evaluate(start)
        assert cost_c == pytest.approx(cost, rel=1e-12)
        np.testing.assert_allclose(N_c, N, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(e_c, e, rtol=1e-12, atol=1e-15)
        H_c, g_c = fast.normal_blocks(N, e, M)
        np.testing.assert_allclose(H_c, H, atol=1e-12 * np.abs(H).max())
        np.testing.assert_allclose(g_c, g, atol=1e-12 * np.abs(g).max())
    ref = nls.solve_nls(lin, start, st.root, f_scale=f_scale, weights=w, engine='numpy')
    res = nls.solve_nls(lin, start, st.root, f_scale=f_scale, weights=w, engine=engine.name)
    assert res.iterations == ref.iterations
    assert res.final_cost == pytest.approx(ref.final_cost, rel=1e-9)
    np.testing.assert_allclose(res.centers_w, ref.centers_w,
                               atol=1e-9 * np.abs(ref.centers_w).max())
