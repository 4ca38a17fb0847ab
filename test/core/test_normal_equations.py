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
"""Tests of the Schur-complement normal equations (pmba.md §1.7)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from pmba_ros.core import conversions, numpy_schur
from pmba_ros.core import normal_equations as ne
from pmba_ros.core.compiled import assembly as compiled_assembly
from pmba_ros.core.compiled import chunks
from pmba_ros.core.compiled.plan import CompiledSchurPlan
from pmba_ros.core.engine import Engine, NUMPY
from pmba_ros.core.gauge import choose_gauge
from pmba_ros.core.models import IdpModel, ParallaxModel, XyzModel
from pmba_ros.core.numpy_schur import NumpySchurPlan
from pmba_ros.core.problem import BAProblem, make_problem, permute_features, XyzFeatures
from pmba_ros.core.sparse_factor import sparse_solve
from pmba_ros.errors import SolverError
import pytest
import scipy.sparse
import scipy.sparse.linalg

from .helpers import engine_named, forward_problem

#: Ways of assembling J^T J and forming W V^-1 W^T: numpy's (one dense product; per pair or
#: per delta, in small batches) and the compiled loops of pmba_ros.core.compiled, on one
#: thread or with the features split into three chunks (as a large problem on three cores).
SCHUR_PATHS = ['dense', 'pairs', 'per_delta', 'compiled', 'compiled_chunks']


def _select_path(schur_products: str, monkeypatch: pytest.MonkeyPatch) -> Engine:
    """Return the engine of a path; pick the numpy plan's strategy by its thresholds."""
    if schur_products != 'dense':
        monkeypatch.setattr(numpy_schur, 'DENSE_SCHUR_RATIO', 0)
    if schur_products == 'per_delta':
        monkeypatch.setattr(numpy_schur, 'LOOP_MIN_FEATURES', 1)
    if schur_products == 'compiled_chunks':
        _split_in_three(monkeypatch)
    return engine_named('numpy' if schur_products in NUMPY_PATHS else 'compiled')


NUMPY_PATHS = ('dense', 'pairs', 'per_delta')


def _split_in_three(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make every problem large enough for the compiled loops to run in three chunks."""
    monkeypatch.setattr(chunks, 'CHUNK_OBSERVATIONS', 1)
    monkeypatch.setattr(chunks, 'max_threads', lambda: 3)


def _dense_jacobian(J_pose, J_feat, slot_block, feat_idx, n_blocks, n_feats):
    K, S, d, _ = J_pose.shape
    J = np.zeros((K * d, 6 * n_blocks + 3 * n_feats))
    for k in range(K):  # a reference implementation: loops are fine in a test
        rows = slice(k * d, (k + 1) * d)
        for s in range(S):
            b = slot_block[k, s]
            if b >= 0:
                J[rows, 6 * b:6 * b + 6] += J_pose[k, s]
        f = feat_idx[k]
        J[rows, 6 * n_blocks + 3 * f:6 * n_blocks + 3 * f + 3] = J_feat[k]
    return J


def _uneven_tracks(problem):
    """Drop observations so that features have 2 to 5 observers (uneven Schur groups)."""
    obs = problem.obs
    keep = (obs.feat_idx + obs.cam_idx) % 5 < 2 + obs.feat_idx % 4
    return make_problem(problem.R_wc, problem.centers_w, problem.intrinsics,
                        obs.cam_idx[keep], obs.feat_idx[keep], obs.pixels[keep],
                        points_w=problem.points_w)


def _model_and_features(problem, param: str, weighted: bool = False, engine: Engine = NUMPY):
    if param == 'pmba':
        feats, _ = conversions.xyz_to_parallax(problem, problem.R_wc, problem.centers_w,
                                               problem.points_w, engine=engine)
        return ParallaxModel(problem, pixel_weighted=weighted, engine=engine), feats
    if param == 'idp':
        return IdpModel(problem, engine), conversions.xyz_to_idp(
            problem, problem.R_wc, problem.centers_w, problem.points_w)
    return XyzModel(problem, engine), XyzFeatures(np.array(problem.points_w))


@pytest.mark.parametrize(('param', 'weighted'),
                         [('pmba', False), ('pmba', True), ('xyz', False), ('idp', False)])
@pytest.mark.parametrize('sparse_limit', [ne.SPARSE_LIMIT, 0])
@pytest.mark.parametrize('tracks', ['full', 'uneven'])
@pytest.mark.parametrize('schur_products', SCHUR_PATHS)
def test_schur_solution_equals_dense_solve(param: str, weighted: bool, sparse_limit: int,
                                           tracks: str, schur_products: str,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """The Schur path solves J^T J exactly; x^T H x equals |J x|^2.

    Every way of forming W V^-1 W^T (:data:`SCHUR_PATHS`), and both a dense and a sparse
    reduced system.
    """
    monkeypatch.setattr(ne, 'DENSE_LIMIT', min(ne.DENSE_LIMIT, sparse_limit))
    monkeypatch.setattr(ne, 'SPARSE_LIMIT', sparse_limit)
    engine = _select_path(schur_products, monkeypatch)
    monkeypatch.setattr(numpy_schur, '_SCHUR_BATCH', 37)
    problem = forward_problem(6, n_cams=5, n_points=25)
    if tracks == 'uneven':
        problem = _uneven_tracks(problem)
        assert len(set(np.bincount(problem.obs.feat_idx).tolist())) >= 3
    problem = permute_features(problem, ne.feature_order(problem.obs.feat_idx,
                                                         problem.n_feats))
    model, feats = _model_and_features(problem, param, weighted, engine)
    gauge = choose_gauge(problem.centers_w, problem.fixed, problem.obs.cam_idx,
                         problem.obs.feat_idx, problem.n_feats)
    free_block = gauge.free_block()
    slots = model.slots(feats)
    st = ne.SchurStructure.build(problem.obs.cam_idx, problem.obs.feat_idx, slots,
                                 problem.n_feats, free_block, model.anchor_cols,
                                 engine.schur_plan)
    assert isinstance(st.plan, NumpySchurPlan) == (schur_products in NUMPY_PATHS)
    assert getattr(st.plan, 'dense', False) == (schur_products == 'dense')
    lin = model.linearize(problem.R_wc, problem.centers_w, feats)
    r, Jp, Jf = lin.residuals, lin.J_pose(), lin.J_feat
    eqs = ne.assemble(st, lin)
    damp_p = np.full((st.n_blocks, 6), 1e-3)
    damp_f = np.full((problem.n_feats, 3), 1e-3)
    mask = gauge.column_mask()
    x_p, x_f = ne.solve_schur(st, eqs, damp_p, damp_f, mask)
    slot_block = np.where(slots >= 0, free_block[np.maximum(slots, 0)], -1)
    J = _dense_jacobian(Jp, Jf, slot_block, problem.obs.feat_idx, st.n_blocks,
                        problem.n_feats)
    H = J.T @ J + np.diag(np.concatenate([damp_p.ravel(), damp_f.ravel()]))
    g = J.T @ r.ravel()
    x_rand = np.random.default_rng(0).normal(size=J.shape[1])
    quad = ne.quadratic_form(st, eqs, x_rand[:6 * st.n_blocks].reshape(-1, 6),
                             x_rand[6 * st.n_blocks:].reshape(-1, 3))
    assert quad == pytest.approx(float(np.sum((J @ x_rand) ** 2)), rel=1e-10)
    free = np.concatenate([mask.ravel(), np.ones(3 * problem.n_feats, dtype=bool)])
    x = np.zeros(free.shape[0])
    x[free] = np.linalg.solve(H[np.ix_(free, free)], -g[free])
    np.testing.assert_allclose(np.concatenate([x_p.ravel(), x_f.ravel()]), x,
                               rtol=1e-6, atol=1e-9)


def _held_pose_system(problem, model, feats, free_block, engine):
    """Return the structure, linearization, equations and dense Jacobian of held poses."""
    slots = model.slots(feats)
    st = ne.SchurStructure.build(problem.obs.cam_idx, problem.obs.feat_idx, slots,
                                 problem.n_feats, free_block, model.anchor_cols,
                                 engine.schur_plan)
    lin = model.linearize(problem.R_wc, problem.centers_w, feats)
    slot_block = np.where(slots >= 0, free_block[np.maximum(slots, 0)], -1)
    J = _dense_jacobian(lin.J_pose(), lin.J_feat, slot_block, problem.obs.feat_idx,
                        st.n_blocks, problem.n_feats)
    return st, lin, ne.assemble(st, lin), J


@pytest.mark.parametrize('param', ['pmba', 'xyz', 'idp'])
@pytest.mark.parametrize('schur_products', SCHUR_PATHS)
@pytest.mark.parametrize('seed', [1, 2])
def test_schur_with_fixed_poses_equals_dense_solve(param: str, schur_products: str, seed: int,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Poses held fixed (anchors and observers alike), as the sliding window does."""
    engine = _select_path(schur_products, monkeypatch)
    monkeypatch.setattr(numpy_schur, '_SCHUR_BATCH', 29)
    base = forward_problem(seed, n_cams=7, n_points=30)
    rng = np.random.default_rng(seed)
    keep = rng.random(base.n_obs) < 0.7
    problem = make_problem(base.R_wc, base.centers_w, base.intrinsics, base.obs.cam_idx[keep],
                           base.obs.feat_idx[keep], base.obs.pixels[keep],
                           points_w=base.points_w)
    problem = permute_features(problem, ne.feature_order(problem.obs.feat_idx,
                                                         problem.n_feats))
    model, feats = _model_and_features(problem, param, weighted=param == 'pmba', engine=engine)
    fixed = rng.permutation(7)[:3]
    free_block = np.full(7, -1)
    free_block[np.setdiff1d(np.arange(7), fixed)] = np.arange(4)
    st, lin, eqs, J = _held_pose_system(problem, model, feats, free_block, engine)
    damp_p = np.full((st.n_blocks, 6), 1e-3)
    damp_f = np.full((problem.n_feats, 3), 1e-3)
    x_p, x_f = ne.solve_schur(st, eqs, damp_p, damp_f, np.ones((st.n_blocks, 6), dtype=bool))
    H = J.T @ J + np.diag(np.concatenate([damp_p.ravel(), damp_f.ravel()]))
    x = np.linalg.solve(H, -J.T @ lin.residuals.ravel())
    np.testing.assert_allclose(np.concatenate([x_p.ravel(), x_f.ravel()]), x,
                               rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize('schur_products', ['dense', 'compiled'])
def test_pose_covariance_is_the_pose_block_of_the_dense_inverse(
        schur_products: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """S^-1 with the features marginalized: the pose rows of (J^T J)^-1; held poses zero."""
    engine = _select_path(schur_products, monkeypatch)
    problem = forward_problem(4, n_cams=6, n_points=30)
    problem = permute_features(problem, ne.feature_order(problem.obs.feat_idx,
                                                         problem.n_feats))
    model, feats = _model_and_features(problem, 'pmba', weighted=True, engine=engine)
    st, _, eqs, J = _held_pose_system(problem, model, feats, np.array([-1, 0, 1, 2, 3, 4]),
                                      engine)
    mask = np.ones((st.n_blocks, 6), dtype=bool)
    mask[0, 3] = False   # one more held column, as a gauge would hold
    cov = ne.pose_covariance(st, eqs, np.zeros((problem.n_feats, 3)), mask)
    free = np.concatenate([mask.ravel(), np.ones(3 * problem.n_feats, dtype=bool)])
    want = np.zeros((free.shape[0], free.shape[0]))
    want[np.ix_(free, free)] = np.linalg.inv((J.T @ J)[np.ix_(free, free)])
    dim = 6 * st.n_blocks
    np.testing.assert_allclose(cov, want[:dim, :dim], rtol=1e-6,
                               atol=1e-9 * np.abs(want[:dim, :dim]).max())
    assert not np.any(cov[3]) and not np.any(cov[:, 3])


def test_pose_covariance_refuses_a_singular_system() -> None:
    """Poses no feature pins (a free gauge) make S singular: a ReducedSystemError."""
    problem = forward_problem(4, n_cams=4, n_points=20)
    problem = permute_features(problem, ne.feature_order(problem.obs.feat_idx,
                                                         problem.n_feats))
    model, feats = _model_and_features(problem, 'xyz')
    st = ne.SchurStructure.build(problem.obs.cam_idx, problem.obs.feat_idx, model.slots(feats),
                                 problem.n_feats, np.arange(4), model.anchor_cols,
                                 NUMPY.schur_plan)
    eqs = ne.assemble(st, model.linearize(problem.R_wc, problem.centers_w, feats))
    with pytest.raises(ne.ReducedSystemError):
        ne.pose_covariance(st, eqs, np.zeros((problem.n_feats, 3)),
                           np.ones((4, 6), dtype=bool))


def _record_superlu(monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    """Record whether each SuperLU factorization is in symmetric mode (no pivot search)."""
    calls: list[bool] = []
    splu = scipy.sparse.linalg.splu

    def recording(A, **kwargs):
        calls.append(kwargs.get('options', {}).get('SymmetricMode', False))
        return splu(A, **kwargs)

    monkeypatch.setattr(scipy.sparse.linalg, 'splu', recording)
    return calls


def _six_camera_system() -> tuple[BAProblem, ne.SchurStructure, ne.NormalEquations]:
    """Return a PMBA problem of 6 cameras that all see its 30 features, and its system."""
    problem = forward_problem(3, n_cams=6, n_points=30)
    problem = permute_features(problem, ne.feature_order(problem.obs.feat_idx,
                                                         problem.n_feats))
    model, feats = _model_and_features(problem, 'pmba', weighted=True)
    st, _, eqs, _ = _held_pose_system(problem, model, feats, np.array([-1, 0, 1, 2, 3, 4]),
                                      NUMPY)
    return problem, st, eqs


def test_sparse_reduced_system_is_factored_without_pivots_as_the_dense_one(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Past SPARSE_LIMIT: one symmetric-mode factorization, the dense path's step to rounding."""
    problem, st, eqs = _six_camera_system()
    mask = np.ones((st.n_blocks, 6), dtype=bool)
    mask[0, 3] = False
    damp_p = np.full((st.n_blocks, 6), 1e-4)
    damp_f = np.full((problem.n_feats, 3), 1e-4)
    dense = ne.solve_schur(st, eqs, damp_p, damp_f, mask)
    calls = _record_superlu(monkeypatch)
    monkeypatch.setattr(ne, 'DENSE_LIMIT', 0)
    monkeypatch.setattr(ne, 'SPARSE_LIMIT', 0)
    sparse = ne.solve_schur(st, eqs, damp_p, damp_f, mask)
    assert calls == [True]
    for got, want in zip(sparse, dense, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())


@pytest.mark.parametrize('sparse', [False, True])
def test_a_low_rank_downdate_is_solved_as_the_dense_system(
        sparse: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """H less sum_k u_k u_k^T / d_k on the pose columns (Woodbury on S): the dense solution.

    Both factorizations; a held pose column stays zero.
    """
    problem = forward_problem(6, n_cams=5, n_points=25)
    problem = permute_features(problem, ne.feature_order(problem.obs.feat_idx,
                                                         problem.n_feats))
    model, feats = _model_and_features(problem, 'pmba')
    free_block = np.array([-1, 0, 1, 2, 3])
    st, lin, eqs, J = _held_pose_system(problem, model, feats, free_block, NUMPY)
    if sparse:
        monkeypatch.setattr(ne, 'DENSE_LIMIT', 0)
        monkeypatch.setattr(ne, 'SPARSE_LIMIT', 0)
    mask = np.ones((st.n_blocks, 6), dtype=bool)
    mask[0, 3] = False
    damp_p = np.full((st.n_blocks, 6), 1e-4)
    damp_f = np.full((problem.n_feats, 3), 1e-4)
    H = J.T @ J + np.diag(np.concatenate([damp_p.ravel(), damp_f.ravel()]))
    g = J.T @ lin.residuals.ravel()
    dim = 6 * st.n_blocks
    free = np.concatenate([mask.ravel(), np.ones(3 * problem.n_feats, dtype=bool)])
    u = np.random.default_rng(2).normal(size=(2, dim)) * mask.reshape(-1)
    # d_k = 4 u_k H^-1 u_k keeps each term below H / 4: the downdated H stays positive.
    H_f = H[np.ix_(free, free)]
    u_full = np.zeros((2, H.shape[0]))
    u_full[:, :dim] = u
    d = 4.0 * np.einsum('ki,ki->k', u_full[:, free], np.linalg.solve(H_f, u_full[:, free].T).T)
    x = np.zeros(H.shape[0])
    x[free] = np.linalg.solve(H_f - (u_full[:, free].T / d) @ u_full[:, free], -g[free])
    x_p, x_f, _ = ne.solve_schur_factored(st, eqs, damp_p, damp_f, mask, (u, d))
    np.testing.assert_allclose(np.concatenate([x_p.ravel(), x_f.ravel()]), x,
                               rtol=1e-6, atol=1e-9 * np.abs(x).max())
    assert x_p[0, 3] == 0.0
    plain, _, _ = ne.solve_schur_factored(st, eqs, damp_p, damp_f, mask)
    assert np.abs(plain - x_p).max() > 1e-3 * np.abs(x_p).max()


def _fill(pairs: list[tuple[int, int]], n_blocks: int) -> float:
    """Return SchurStructure.sparse_fill of S's upper pose-block pairs ``pairs``."""
    rows, cols = np.array(pairs).T
    structure = SimpleNamespace(n_blocks=n_blocks, pair_rows=rows, pair_cols=cols)
    return ne.SchurStructure.sparse_fill.func(structure)   # type: ignore[attr-defined]


def test_sparse_fill_is_low_for_a_sequence_and_high_for_a_collection() -> None:
    """A sequence's cameras share features with their neighbours: a banded S fills its band.

    A photo collection's see one scene: S is dense, and so are two groups joined by one pair.
    """
    n = 300
    band = [(i, j) for i in range(n) for j in range(i, min(n, i + 6))]
    assert _fill(band, n) < 1.2 * 2 * 5 / n   # its band: 5 blocks below each diagonal one
    full = [(i, j) for i in range(40) for j in range(i, 40)]
    assert _fill(full, 40) == pytest.approx(1.0)
    groups = [(i, j) for g in (0, 20) for i in range(g, g + 20) for j in range(i, g + 20)]
    assert 0.4 < _fill([*groups, (0, 20)], 40) < 0.6
    assert _fill([(0, 0)], 1) == 1.0


@pytest.mark.parametrize('fill_limit', [0.0, 1.0])
def test_between_the_limits_the_fill_chooses_the_factorization(
        fill_limit: float, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every camera sees every feature: dense Cholesky (its factor comes back), not SuperLU."""
    problem, st, eqs = _six_camera_system()
    assert st.sparse_fill == pytest.approx(1.0)
    mask = np.ones((st.n_blocks, 6), dtype=bool)
    damp_p, damp_f = np.full((st.n_blocks, 6), 1e-4), np.full((problem.n_feats, 3), 1e-4)
    monkeypatch.setattr(ne, 'DENSE_LIMIT', 0)
    monkeypatch.setattr(ne, 'DENSE_FILL', fill_limit)
    calls = _record_superlu(monkeypatch)
    *_, factor = ne.solve_schur_factored(st, eqs, damp_p, damp_f, mask)
    assert (factor is not None) == (fill_limit < 1.0)
    assert len(calls) == (fill_limit >= 1.0)   # the fill was predicted once, before


def test_sparse_solve_pivots_where_diagonal_pivots_fail(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A tiny first pivot: unpivoted LU loses the solution, partial pivoting does not."""
    S = np.array([[1e-20, 1.0, 0.0], [1.0, 1.0, 2.0], [0.0, 2.0, 3.0]])
    b = np.array([1.0, 2.0, 3.0])
    calls = _record_superlu(monkeypatch)
    x = sparse_solve(scipy.sparse.csc_matrix(S), b)
    assert calls == [True, False]
    np.testing.assert_allclose(x, np.linalg.solve(S, b), rtol=1e-12)


def test_sparse_solve_refuses_a_singular_system(monkeypatch: pytest.MonkeyPatch) -> None:
    """Singular with diagonal and with partial pivots: a ReducedSystemError."""
    S = scipy.sparse.csc_matrix(np.array([[1.0, 1.0], [1.0, 1.0]]))
    calls = _record_superlu(monkeypatch)
    with pytest.raises(ne.ReducedSystemError, match='singular'):
        sparse_solve(S, np.ones(2))
    assert calls == [True, False]


def test_structure_rejects_unordered_features() -> None:
    """Observations whose features are not ordered by track length are refused."""
    problem = _uneven_tracks(forward_problem(6, n_cams=5, n_points=25))
    model, feats = _model_and_features(problem, 'xyz')
    with pytest.raises(SolverError, match='sorted by feature'):
        ne.SchurStructure.build(problem.obs.cam_idx, problem.obs.feat_idx,
                                model.slots(feats), problem.n_feats, np.arange(5), (),
                                NUMPY.schur_plan)


@pytest.mark.parametrize('param', ['pmba', 'idp', 'xyz'])
def test_engines_find_the_same_anchors(param: str) -> None:
    """The compiled anchor pass gives numpy's poses, observations and errors."""
    problem = _uneven_tracks(forward_problem(3, n_cams=6, n_points=30))
    problem = permute_features(problem, ne.feature_order(problem.obs.feat_idx,
                                                         problem.n_feats))
    model, feats = _model_and_features(problem, param)
    slots = model.slots(feats)
    counts = np.bincount(problem.obs.feat_idx, minlength=problem.n_feats)
    starts = np.concatenate([[0], np.cumsum(counts)])
    cam = problem.obs.cam_idx
    mixed, unobserved = slots.copy(), slots.copy()
    if slots.shape[1] > 1:
        f = int(np.flatnonzero(np.maximum.reduceat(slots[:, 1], starts[:-1]) > 0)[0])
        rows = slots[starts[f]:starts[f + 1], 1]   # two or more: another row keeps the pose
        mixed[starts[f] + np.argmin(rows), 1] = rows.max() - 1   # a second pose
        unobserved[starts[4]:starts[5], 1] = problem.n_cams  # a pose that does not observe
    for case in (slots, mixed, unobserved):
        want = ne.anchors(cam, problem.obs.feat_idx, case, starts)
        got = engine_named('compiled').schur_anchors(cam, problem.obs.feat_idx, case, starts)
        for w, g in zip(want, got, strict=True):
            np.testing.assert_array_equal(g, w)
    if slots.shape[1] > 1:
        assert ne.anchors(cam, problem.obs.feat_idx, mixed, starts)[2][0, 0]
        assert ne.anchors(cam, problem.obs.feat_idx, unobserved, starts)[2][0, 1]
        with pytest.raises(SolverError, match='names different poses'):
            ne.SchurLayout.build(cam, problem.obs.feat_idx, mixed, problem.n_feats,
                                 np.arange(problem.n_cams), model.anchor_cols)


def test_pmba_gauge_has_seven_dimensions() -> None:
    """Without gauge fixing, J^T J of PMBA has exactly 7 zero eigenvalues (Sim(3))."""
    problem = forward_problem(7, n_cams=5, n_points=30, noise_px=0.0)
    feats, _ = conversions.xyz_to_parallax(problem, problem.R_wc, problem.centers_w,
                                           problem.points_w)
    model = ParallaxModel(problem)
    lin = model.linearize(problem.R_wc, problem.centers_w, feats)
    Jp, Jf = lin.J_pose(), lin.J_feat
    slot_block = model.slots(feats)
    J = _dense_jacobian(Jp, Jf, slot_block, problem.obs.feat_idx, problem.n_cams,
                        problem.n_feats)
    ev = np.linalg.eigvalsh(J.T @ J)
    assert ev[6] < 1e-9 * ev[-1]
    assert ev[7] > 1e-7 * ev[-1]


@pytest.mark.parametrize('split', [False, True])
def test_singular_feature_block_is_a_clear_error(engine: Engine, split: bool,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """A feature whose Jacobian columns are zero, undamped: ReducedSystemError, not NaN.

    Also when the feature is in a later chunk of a problem split between threads.
    """
    if split:
        _split_in_three(monkeypatch)
    problem = forward_problem(4, n_cams=5, n_points=20)
    problem = permute_features(problem, ne.feature_order(problem.obs.feat_idx,
                                                         problem.n_feats))
    model, feats = _model_and_features(problem, 'xyz', engine=engine)
    free_block = np.arange(problem.n_cams)
    st = ne.SchurStructure.build(problem.obs.cam_idx, problem.obs.feat_idx, model.slots(feats),
                                 problem.n_feats, free_block, model.anchor_cols,
                                 engine.schur_plan)
    lin = model.linearize(problem.R_wc, problem.centers_w, feats)
    bad = problem.n_feats - 2  # features run by track length: in the last chunk
    lin.rows[problem.obs.feat_idx == bad, :, 7:10] = 0.0
    eqs = ne.assemble(st, lin)
    with pytest.raises(ne.ReducedSystemError, match='singular feature block'):
        ne.solve_schur(st, eqs, np.full((st.n_blocks, 6), 1e-3),
                       np.zeros((problem.n_feats, 3)), np.ones((st.n_blocks, 6), dtype=bool))


def test_problems_over_the_pair_index_limit_take_the_numpy_path(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Above compiled.assembly.MAX_BLOCKS free poses the structure is numpy's, and still solves."""
    engine = engine_named('compiled')
    problem = forward_problem(2, n_cams=5, n_points=20)
    problem = permute_features(problem, ne.feature_order(problem.obs.feat_idx,
                                                         problem.n_feats))
    model, feats = _model_and_features(problem, 'pmba', weighted=True, engine=engine)
    args = (problem.obs.cam_idx, problem.obs.feat_idx, model.slots(feats), problem.n_feats,
            np.arange(problem.n_cams), model.anchor_cols, engine.schur_plan)
    assert isinstance(ne.SchurStructure.build(*args).plan, CompiledSchurPlan)
    monkeypatch.setattr(compiled_assembly, 'MAX_BLOCKS', problem.n_cams - 1)
    st = ne.SchurStructure.build(*args)
    assert isinstance(st.plan, NumpySchurPlan)
    eqs = ne.assemble(st, model.linearize(problem.R_wc, problem.centers_w, feats))
    x_p, x_f = ne.solve_schur(st, eqs, np.full((st.n_blocks, 6), 1e-3),
                              np.full((problem.n_feats, 3), 1e-3),
                              np.ones((st.n_blocks, 6), dtype=bool))
    assert np.all(np.isfinite(x_p)) and np.all(np.isfinite(x_f))


@pytest.mark.parametrize('jacobi', [True, False])
@pytest.mark.parametrize('plan', ['compiled', 'numpy'])
def test_engines_scale_the_equations_alike(jacobi: bool, plan: str) -> None:
    """The compiled Jacobi scaling gives numpy's numbers exactly, on either plan.

    The scales are 1 / (1 + |J_k|), the scaled equations those of J diag(c), the held gauge
    columns carry no gradient, and a NaN gradient gives a NaN maximum.
    """
    compiled = engine_named('compiled')
    problem = _uneven_tracks(forward_problem(4, n_cams=6, n_points=30))
    problem = permute_features(problem, ne.feature_order(problem.obs.feat_idx,
                                                         problem.n_feats))
    model, feats = _model_and_features(problem, 'pmba', weighted=True, engine=compiled)
    gauge = choose_gauge(problem.centers_w, problem.fixed, problem.obs.cam_idx,
                         problem.obs.feat_idx, problem.n_feats)
    mask = gauge.column_mask()
    assert not mask.all()
    st = ne.SchurStructure.build(problem.obs.cam_idx, problem.obs.feat_idx, model.slots(feats),
                                 problem.n_feats, gauge.free_block(), model.anchor_cols,
                                 compiled.schur_plan if plan == 'compiled' else NUMPY.schur_plan)
    lin = model.linearize(problem.R_wc, problem.centers_w, feats)
    eqs = ne.assemble(st, lin)

    def fresh() -> ne.NormalEquations:
        return ne.NormalEquations(eqs.U, eqs.W.copy(), eqs.V, eqs.g_pose, eqs.g_feat)

    ref = NUMPY.jacobi_scale(st, fresh(), mask, jacobi)
    got = compiled.jacobi_scale(st, fresh(), mask, jacobi)
    for name in ('c_pose', 'c_feat', 'D_pose', 'D_feat', 'g_pose', 'g_feat', 'gradient_max'):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
    for name in ('U', 'W', 'V', 'g_pose', 'g_feat'):
        np.testing.assert_array_equal(getattr(got.eqs, name), getattr(ref.eqs, name),
                                      err_msg=name)
    J = lin.J_feat   # the feature columns' scales, from the Jacobian itself
    col_norm = np.sqrt(np.add.reduceat((J ** 2).sum(axis=1), st.layout.starts[:-1]))
    np.testing.assert_allclose(ref.c_feat, 1.0 / (1.0 + col_norm) if jacobi else 1.0,
                               rtol=1e-12)
    assert np.all(ref.g_pose[~mask] == 0.0)
    assert ref.gradient_max == np.abs(np.concatenate(
        [np.where(mask, eqs.g_pose, 0.0).ravel(), eqs.g_feat.ravel()])).max()
    g_feat = eqs.g_feat.copy()
    g_feat[1, 2] = np.nan
    nan_eqs = ne.NormalEquations(eqs.U, eqs.W.copy(), eqs.V, eqs.g_pose, g_feat)
    for engine in (NUMPY, compiled):
        assert np.isnan(engine.jacobi_scale(st, nan_eqs, mask, jacobi).gradient_max)
