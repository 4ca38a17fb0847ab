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
"""Tests of the block normal matrices of the position steps, dense and sparse (eqs. 13-14)."""

from __future__ import annotations

from test.init.scenes import street_scene

import numpy as np
from pmba_ros.core import conversions
from pmba_ros.core.engine import Engine
from pmba_ros.init import anchors, cls, nls, normal_blocks
import pytest
import scipy.sparse


def _local_rays(rng: np.random.Generator, n_cams: int = 20, n_feats: int = 80,
                window: int = 4) -> cls.LinearRays:
    """Linear rays with random coefficients, each feature seen by a window of cameras.

    The anchors are two of the feature's observers, so the coupled camera pairs are those
    within ``window`` of each other: most of the M^2 blocks are zero.
    """
    first = rng.integers(0, n_cams - window + 1, n_feats)
    cam = (first[:, None] + np.arange(window)).ravel()
    feat = np.repeat(np.arange(n_feats), window)
    keep = rng.uniform(size=cam.shape[0]) < 0.85
    keep[::window] = keep[1::window] = True  # the anchors observe their feature
    pick = np.stack([rng.permutation(window)[:2] for _ in range(n_feats)])
    main = first + pick[:, 0]
    assoc = first + pick[:, 1]
    K = int(np.count_nonzero(keep))
    rays = rng.normal(size=(K, 3))
    return cls.LinearRays(cam[keep], feat[keep], assoc, main,
                          rng.normal(size=(n_feats, 2, 3, 3)), rng.uniform(0.1, 1.0, n_feats),
                          rays / np.linalg.norm(rays, axis=1, keepdims=True))


def test_block_pattern_holds_the_coupled_camera_pairs_only(rng: np.random.Generator) -> None:
    """Blocks exist exactly for the pairs among a feature's observers and anchors."""
    lin = _local_rays(rng)
    pat = lin.pattern
    expected = set()
    for j in range(lin.anchor_coeff.shape[0]):
        obs = lin.cam[lin.feat == j].tolist()
        ends = [int(lin.assoc[j]), int(lin.main[j])]
        expected |= {(i, i) for i in obs}
        expected |= {(i, a) for i in obs for a in ends} | {(a, i) for i in obs for a in ends}
        expected |= {(a, b) for a in ends for b in ends}
    assert set(zip(pat.rows.tolist(), pat.cols.tolist(), strict=True)) == expected
    assert pat.n_blocks < 0.5 * 20 * 20
    assert np.all(np.diff(pat.rows * 20 + pat.cols) > 0)  # sorted, no duplicates


def test_dense_and_sparse_normal_matrices_equal_the_jacobian_products(
        rng: np.random.Generator, engine: Engine) -> None:
    """Both forms of sum_k G_k^T A_k G_k equal J^T blockdiag(A) J, also restricted.

    J's columns are N-bar at unit positions (eq. 12 is linear in P), independent of the
    block assembly; the restriction drops the root and one more coordinate as the NLS does.
    """
    lin = _local_rays(rng)
    M, K = 20, lin.n_obs
    J = np.empty((K, 3, 3 * M))
    for col in range(3 * M):
        unit = np.zeros(3 * M)
        unit[col] = 1.0
        J[:, :, col] = lin.evaluate(unit.reshape(M, 3), 'numpy')
    L = rng.normal(size=(K, 3, 3))
    A = L @ np.swapaxes(L, 1, 2)
    H_ref = np.einsum('kai,kab,kbj->ij', J, A, J)
    tol = 1e-12 * np.abs(H_ref).max()
    blocks = lin.normal_blocks(A, engine.name)
    np.testing.assert_allclose(lin.pattern.dense(blocks, M), H_ref, atol=tol)
    np.testing.assert_allclose(lin.normal_matrix(A, M, engine.name), H_ref, atol=tol)
    keep = np.setdiff1d(np.arange(3 * M), [0, 1, 2, 3 * 7 + 1])
    H_s = lin.pattern.sparse_layout(M, keep).matrix(blocks)
    assert isinstance(H_s, scipy.sparse.csc_array) and H_s.has_sorted_indices
    structure = lin.pattern.dense(np.ones_like(blocks), M)[np.ix_(keep, keep)]
    assert H_s.nnz == np.count_nonzero(structure)  # every entry of the kept blocks, no other
    np.testing.assert_allclose(H_s.toarray(), H_ref[np.ix_(keep, keep)], atol=tol)


def test_numpy_blocks_equal_the_compiled_blocks(rng: np.random.Generator) -> None:
    """The numpy assembly and the compiled loop fill the same slots with the same sums."""
    pytest.importorskip('numba')
    lin = _local_rays(rng)
    A = rng.normal(size=(lin.n_obs, 3, 3))
    A = A + np.swapaxes(A, 1, 2)
    ref = lin.normal_blocks(A, 'numpy')
    np.testing.assert_allclose(lin.normal_blocks(A, 'compiled'), ref,
                               atol=1e-13 * np.abs(ref).max())


@pytest.mark.parametrize('sparse', [False, True])
def test_solve_spd_refuses_an_indefinite_matrix(sparse: bool) -> None:
    """A matrix that is not positive definite raises LinAlgError (LM then damps more)."""
    H = np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 3.0]])
    g = np.ones(3)
    mat = scipy.sparse.csc_array(H) if sparse else H
    with pytest.raises(np.linalg.LinAlgError):
        normal_blocks.solve_spd(mat, np.zeros(3), g)
    step = normal_blocks.solve_spd(mat, np.full(3, 2.0), g)
    np.testing.assert_allclose((H + 2.0 * np.eye(3)) @ step, g, atol=1e-14)


def _street_rays(seed: int, noise_px: float) -> tuple[cls.LinearRays, int]:
    """Linear rays of a 12-camera street from true rotations and anchor directions."""
    p = street_scene(seed, n_cams=12, n_points=300, noise_px=noise_px).gt
    allowed = np.ones((p.n_cams, p.n_cams), dtype=bool)
    main_idx, assoc_idx, _ = conversions.select_anchors(p, p.R_wc, allowed_pairs=allowed)
    feats = conversions.features_from_rotations(p, p.R_wc, main_idx, assoc_idx)
    d_ma = p.centers_w[main_idx] - p.centers_w[assoc_idx]
    d_ma /= np.linalg.norm(d_ma, axis=1, keepdims=True)
    frames = anchors.linearization_frames(p.R_wc, feats, d_ma)
    return cls.linear_rays(p.R_wc, feats, frames, p.obs.cam_idx, p.obs.feat_idx,
                           p.obs.bearings_c), p.n_cams


def test_sparse_cls_and_nls_equal_the_dense_ones(engine: Engine) -> None:
    """Same cheirality active set, LM path and centres with either factorization.

    2 px noise: the CLS needs penalty iterations; a fifth of the observations weigh 0.
    """
    lin, M = _street_rays(7, noise_px=2.0)
    w = np.ones(lin.n_obs)
    w[::5] = 0.0
    dense = cls.solve_cls(lin, M, 0, weights=w, sparse=False)
    sparse = cls.solve_cls(lin, M, 0, weights=w, sparse=True)
    assert dense.penalty_iterations >= 2
    assert sparse.penalty_iterations == dense.penalty_iterations
    assert sparse.cheirality_violations == dense.cheirality_violations
    scale = np.abs(dense.centers_w).max()
    np.testing.assert_allclose(sparse.centers_w, dense.centers_w, atol=1e-10 * scale)
    kwargs = {'f_scale': 3.0 / 500.0, 'weights': w, 'engine': engine.name}
    ref = nls.solve_nls(lin, dense.centers_w, 0, sparse=False, **kwargs)
    res = nls.solve_nls(lin, dense.centers_w, 0, sparse=True, **kwargs)
    assert res.iterations == ref.iterations > 1
    assert res.final_cost == pytest.approx(ref.final_cost, rel=1e-10)
    np.testing.assert_allclose(res.centers_w, ref.centers_w, atol=1e-10 * scale)


def test_sparse_cls_recovers_the_truth_without_noise() -> None:
    """Noise-free rays make H singular: the sparse KKT solve still gives the true positions."""
    lin, M = _street_rays(2, noise_px=0.0)
    dense = cls.solve_cls(lin, M, 0, sparse=False)
    sparse = cls.solve_cls(lin, M, 0, sparse=True)
    np.testing.assert_allclose(sparse.centers_w, dense.centers_w,
                               atol=1e-8 * np.abs(dense.centers_w).max())
    N = lin.evaluate(sparse.centers_w)
    assert np.sum(lin.rays * N) == pytest.approx(lin.n_obs, rel=1e-9)


def test_sparse_kkt_solve_pivots_where_diagonal_pivots_break_down() -> None:
    """Tiny diagonal pivots (H indefinite) fall back to threshold pivoting: LAPACK's answer."""
    e = 1e-14
    H = np.array([[e, 1.0, 0.0, 0.2], [1.0, e, 0.3, 0.0], [0.0, 0.3, e, 1.0],
                  [0.2, 0.0, 1.0, e]])
    c = np.array([0.7, 0.5, 1.3, 0.1])
    dense = normal_blocks.solve_kkt(H, c, 3.0)
    sparse = normal_blocks.solve_kkt(scipy.sparse.csc_array(H), c, 3.0)
    np.testing.assert_allclose(sparse, dense, atol=1e-14)
    assert c @ sparse[:4] == pytest.approx(3.0)


def test_sparse_is_chosen_for_large_systems_with_few_coupled_pairs() -> None:
    """Dense below 600 unknowns or where most blocks are non-zero; the caller may force."""
    assert not normal_blocks.use_sparse(597, 5_000, None)
    assert normal_blocks.use_sparse(4497, 42_292, None)  # 1500-camera street, 2 % of blocks
    assert not normal_blocks.use_sparse(897, 38_228, None)  # 300 cameras, 42 % of blocks
    assert normal_blocks.use_sparse(24, 64, True)
    assert not normal_blocks.use_sparse(4497, 42_292, False)
