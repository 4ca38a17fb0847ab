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
"""Relative-motion priors: Jacobians against central differences, and solves with them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pmba_ros.core import so3
from pmba_ros.core.conversions import xyz_to_parallax
from pmba_ros.core.engine import Engine
from pmba_ros.core.loss import Loss
from pmba_ros.core.normal_equations import NormalEquations, SchurStructure
from pmba_ros.core.pose_prior import (
    PriorAssembly,
    RelativePosePrior,
    right_jacobian_inverse,
    StepChanges,
    WindowScale,
)
from pmba_ros.core.problem import BAProblem, Parameterization
from pmba_ros.core.solve import solve, SolveOptions, SolveResult, SolverKind
from pmba_ros.errors import ProblemError
from pmba_ros.sim.scenes import street_scene
import pytest


def _prior(R: np.ndarray, P: np.ndarray, a: np.ndarray, b: np.ndarray, w_rot: float,
           w_trans: float, noise: float = 0.0, seed: int = 0) -> RelativePosePrior:
    """Return factors measuring the relative motions of (R, P), optionally perturbed."""
    rng = np.random.default_rng(seed)
    R_ab = np.einsum('mji,mjk->mik', R[a], R[b]) @ so3.exp(rng.normal(0, noise, (a.size, 3)))
    t_ab = np.einsum('mji,mj->mi', R[a], P[b] - P[a]) + rng.normal(0, noise, (a.size, 3))
    W = np.tile(np.diag([w_trans, 2.0 * w_trans, w_trans]), (a.size, 1, 1))  # anisotropic
    return RelativePosePrior(a, b, R_ab, t_ab, np.full(a.size, w_rot), W)


def test_right_jacobian_inverse_inverts_the_right_jacobian() -> None:
    """log(Exp(w) Exp(d)) ~ w + J_r^-1(w) d (to second order in d), also at tiny angles."""
    rng = np.random.default_rng(0)
    w = np.concatenate([rng.normal(0, 1.0, (5, 3)), rng.normal(0, 1e-8, (2, 3))])
    J = right_jacobian_inverse(w)
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-6
        num = (so3.log(so3.exp(w) @ so3.exp(d)) - so3.log(so3.exp(w) @ so3.exp(-d))) / 2e-6
        np.testing.assert_allclose(num, J[:, :, k], atol=1e-6)


def test_jacobians_match_central_differences() -> None:
    """Both 6x6 blocks of every factor against central differences of the residual."""
    rng = np.random.default_rng(1)
    n = 5
    R = so3.exp(rng.normal(0, 1.0, (n, 3)))
    P = rng.normal(0, 3.0, (n, 3))
    a, b = np.array([0, 1, 3, 4]), np.array([1, 2, 0, 2])
    prior = _prior(R, P, a, b, 7.0, 3.0, noise=0.2)
    Ja, Jb = prior.jacobians(R, P)
    h = 1e-6
    for pose, J, sel in ((a, Ja, 'a'), (b, Jb, 'b')):
        for col in range(6):
            plus, minus = [], []
            for sign, out in ((1.0, plus), (-1.0, minus)):
                Rp, Pp = R.copy(), P.copy()
                for m in range(len(prior)):
                    d = np.zeros(6)
                    d[col] = sign * h
                    R_m, P_m = R.copy(), P.copy()
                    R_m[pose[m]] = R[pose[m]] @ so3.exp(d[:3])
                    P_m[pose[m]] = P[pose[m]] + d[3:]
                    out.append(prior.residuals(R_m, P_m)[m])
                del Rp, Pp
            num = (np.array(plus) - np.array(minus)) / (2 * h)
            np.testing.assert_allclose(J[:, :, col], num, atol=2e-6, err_msg=f'{sel} col {col}')


def _empty_equations(engine: Engine, cam: np.ndarray, feat: np.ndarray, free_block: np.ndarray,
                     ) -> tuple[SchurStructure, NormalEquations]:
    """Return the Schur structure of observations (cam, feat) and zero equations on it."""
    n_feats, n_free = int(feat.max()) + 1, int(free_block.max()) + 1
    st = SchurStructure.build(cam, feat, free_block[cam][:, None], n_feats, free_block, (),
                              engine.schur_plan)
    zero = NormalEquations(np.zeros((st.pair_rows.shape[0], 6, 6)),
                           np.zeros((cam.size, 6, 3)), np.zeros((n_feats, 3, 3)),
                           np.zeros((n_free, 6)), np.zeros((n_feats, 3)))
    return st, zero


def test_add_to_places_the_factors_normal_equations_in_the_covisible_blocks(
        engine: Engine) -> None:
    """add_to adds J^T J and J^T r of the stacked factors to the structure's blocks.

    Pose 0 is fixed (no columns); the factor (1, 3) joins poses that share no feature, so its
    cross block is added only where the engine's plan has that block.
    """
    rng = np.random.default_rng(2)
    n = 5
    R = so3.exp(rng.normal(0, 1.0, (n, 3)))
    P = rng.normal(0, 3.0, (n, 3))
    a, b = np.array([0, 1, 2, 3, 3]), np.array([1, 2, 3, 1, 4])
    prior = _prior(R, P, a, b, 7.0, 3.0, noise=0.2)
    free_block = np.array([-1, 0, 1, 2, 3])
    st, zero = _empty_equations(engine, np.array([0, 1, 1, 2, 2, 3, 3, 4]),
                                np.repeat(np.arange(4), 2), free_block)
    eqs = prior.add_to(st, zero, R, P, free_block)

    Ja, Jb = prior.jacobians(R, P)
    J = np.zeros((len(prior), 6, 4, 6))           # dense Jacobian over the free blocks
    for m in range(len(prior)):
        for pose, Jm in ((a[m], Ja[m]), (b[m], Jb[m])):
            if free_block[pose] >= 0:
                J[m, :, free_block[pose]] = Jm
    J_flat = J.reshape(6 * len(prior), 24)
    H = (J_flat.T @ J_flat).reshape(4, 6, 4, 6)
    np.testing.assert_allclose(eqs.g_pose.ravel(), J_flat.T @ prior.residuals(R, P).ravel(),
                               rtol=1e-12, atol=1e-9)
    pairs = set(zip(st.pair_rows.tolist(), st.pair_cols.tolist(), strict=True))
    assert (0, 1) in pairs
    # Poses 1 and 3 (blocks 0 and 2) share no feature: a sparse plan has no block for them
    # and the factor's cross block is left out; a dense plan holds it, and it is added.
    for p, (r, c) in enumerate(zip(st.pair_rows, st.pair_cols, strict=True)):
        np.testing.assert_allclose(eqs.U[p], H[r, :, c, :], rtol=1e-12, atol=1e-9,
                                   err_msg=f'pair ({r}, {c})')


def test_huber_cost_and_its_gradient_in_the_normal_equations(engine: Engine) -> None:
    """Huber factors: their cost, and its gradient is the one added to the equations.

    Beyond the threshold k the cost is k|r| - k^2/2 and each factor is weighted k / |r|;
    the pose gradient added to the equations matches central differences of the cost.
    """
    from dataclasses import replace

    rng = np.random.default_rng(3)
    n = 4
    R = so3.exp(rng.normal(0, 1.0, (n, 3)))
    P = rng.normal(0, 3.0, (n, 3))
    a, b = np.array([0, 1, 2]), np.array([1, 2, 3])
    plain = _prior(R, P, a, b, 7.0, 3.0, noise=0.2)
    norms = np.linalg.norm(plain.residuals(R, P), axis=1)
    k = float(np.median(norms))        # one factor within, two beyond (or the reverse)
    prior = replace(plain, huber=k)
    ev = prior.evaluate(R, P)
    inside = norms <= k
    assert 0 < np.count_nonzero(inside) < len(prior)
    expected = np.where(inside, 0.5 * norms ** 2, k * norms - 0.5 * k * k)
    assert ev.cost == pytest.approx(float(np.sum(expected)))
    np.testing.assert_allclose(ev.weights, np.where(inside, 1.0, k / norms))
    assert plain.evaluate(R, P).cost == pytest.approx(0.5 * float(np.sum(norms ** 2)))

    cam = np.array([0, 1, 1, 2, 2, 3])
    feat = np.repeat(np.arange(3), 2)
    free_block = np.array([-1, 0, 1, 2])
    st = SchurStructure.build(cam, feat, free_block[cam][:, None], 3, free_block, (),
                              engine.schur_plan)
    zero = NormalEquations(np.zeros((st.pair_rows.shape[0], 6, 6)), np.zeros((6, 6, 3)),
                           np.zeros((3, 3, 3)), np.zeros((3, 6)), np.zeros((3, 3)))
    g = prior.add_to(st, zero, R, P, free_block).g_pose
    h = 1e-6
    for pose in (1, 2, 3):
        for col in range(6):
            costs = []
            for sign in (1.0, -1.0):
                R_m, P_m = R.copy(), P.copy()
                d = np.zeros(6)
                d[col] = sign * h
                R_m[pose] = R[pose] @ so3.exp(d[:3])
                P_m[pose] = P[pose] + d[3:]
                costs.append(prior.cost(R_m, P_m))
            assert g[free_block[pose], col] == pytest.approx((costs[0] - costs[1]) / (2 * h),
                                                             rel=1e-5, abs=1e-6)


def test_bad_factors_are_rejected() -> None:
    """A factor of a pose with itself, a negative weight, a Huber threshold <= 0: errors."""
    from dataclasses import replace

    R, P = np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 3))
    with pytest.raises(ProblemError, match='itself'):
        _prior(R, P, np.array([1]), np.array([1]), 1.0, 1.0)
    with pytest.raises(ProblemError, match='weights'):
        _prior(R, P, np.array([0]), np.array([1]), -1.0, 1.0)
    good = _prior(R, P, np.array([0]), np.array([1]), 1.0, 1.0)
    for bad in (0.0, -1.0, float('nan')):
        with pytest.raises(ProblemError, match='Huber'):
            replace(good, huber=bad)


def _window() -> tuple[BAProblem, BAProblem]:
    scene = street_scene(seed=3, n_cams=12, n_points=200, pos_noise_m=0.05)
    fixed = np.zeros(scene.start.n_cams, dtype=bool)
    fixed[:2] = True
    start = replace(scene.start, fixed=fixed)
    start = start.with_poses(np.where(fixed[:, None, None], scene.gt.R_wc, start.R_wc),
                             np.where(fixed[:, None], scene.gt.centers_w, start.centers_w))
    return start, scene.gt


def _solve(problem: BAProblem, prior: RelativePosePrior | None) -> SolveResult:
    feats, ok = xyz_to_parallax(problem, problem.R_wc, problem.centers_w,
                                np.asarray(problem.points_w))
    assert np.all(ok)
    options = SolveOptions(param=Parameterization.PMBA, solver=SolverKind.DOGLEG,
                           loss=Loss.CAUCHY, max_iterations=30)
    return solve(problem, options, feats, pose_prior=prior)


def test_solve_with_a_prior_follows_it_and_reports_its_cost() -> None:
    """A strong exact prior pins the relative motions; a zero-weight prior changes nothing."""
    start, gt = _window()
    n = start.n_cams
    a, b = np.arange(n - 1), np.arange(1, n)
    plain = _solve(start, None)
    zero = _solve(start, _prior(gt.R_wc, gt.centers_w, a, b, 0.0, 0.0))
    np.testing.assert_allclose(zero.centers_w, plain.centers_w, atol=1e-9)
    strong = _prior(gt.R_wc, gt.centers_w, a, b, 1e4, 1e4)
    res = _solve(start, strong)
    assert res.final_cost < res.initial_cost
    err = np.linalg.norm(res.centers_w - gt.centers_w, axis=1).max()
    err_plain = np.linalg.norm(plain.centers_w - gt.centers_w, axis=1).max()
    assert err < 5e-3 and err < 0.2 * err_plain, (err, err_plain)
    assert strong.cost(res.R_wc, res.centers_w) <= res.final_cost
    # The result carries the prior's residuals at its poses; without a prior, none.
    np.testing.assert_array_equal(res.prior_residuals, strong.residuals(res.R_wc, res.centers_w))
    assert plain.prior_residuals.shape == (0, 6)


def test_prior_leverage_is_the_fit_share_of_each_residual() -> None:
    """A leverage h is d(fit)/d(measurement): moving a measurement moves its residual by 1 - h.

    Checked by re-solving with one measurement moved (rotation and translation rows, a
    factor between free poses and one next to a held pose), against the hat-matrix
    diagonal the solve reports; a factor between held poses has none.
    """
    start, gt = _window()
    n = start.n_cams
    a, b = np.arange(n - 1), np.arange(1, n)
    prior = _prior(gt.R_wc, gt.centers_w, a, b, 300.0, 30.0, noise=0.003, seed=1)
    tight = SolveOptions(param=Parameterization.PMBA, solver=SolverKind.DOGLEG,
                         max_iterations=50, function_tolerance=1e-14,
                         gradient_tolerance=1e-14, parameter_tolerance=1e-14,
                         prior_leverage=True)
    feats, _ = xyz_to_parallax(start, start.R_wc, start.centers_w, np.asarray(start.points_w))
    first = solve(start, tight, feats, pose_prior=prior)
    at = start.with_poses(first.R_wc, first.centers_w)
    res = solve(at, tight, first.features, pose_prior=prior)
    hat = res.prior_leverage
    assert hat.shape == (n - 1, 6, 6)
    np.testing.assert_allclose(hat, np.swapaxes(hat, 1, 2), atol=1e-12)
    assert np.all(np.isnan(hat[0]))   # poses 0 and 1 are held: no fit shares in it
    lev = np.diagonal(hat, axis1=1, axis2=2)
    assert np.all((lev[1:] > 0) & (lev[1:] < 1))
    eps = 1e-4
    for m, row in [(1, 2), (3, 0), (3, 4), (7, 5)]:
        R_ab, t_ab = prior.R_ab.copy(), prior.t_ab.copy()
        if row < 3:   # r_rot = w log(R_ab^T R_a^T R_b): R_ab Exp(-d) adds w d to it
            d = np.zeros(3)
            d[row] = eps / prior.w_rot[m]
            R_ab[m] = R_ab[m] @ so3.exp(-d)
        else:
            t_ab[m] -= np.linalg.solve(prior.W_trans[m], np.eye(3)[row - 3] * eps)
        moved = replace(prior, R_ab=R_ab, t_ab=t_ab)
        start_r = moved.residuals(res.R_wc, res.centers_w)[m, row]
        refit = solve(at.with_poses(res.R_wc, res.centers_w), tight, res.features,
                      pose_prior=moved)
        kept = (refit.prior_residuals[m, row] - res.prior_residuals[m, row]) / (
            start_r - res.prior_residuals[m, row])
        assert 1.0 - kept == pytest.approx(lev[m, row], rel=0.02, abs=1e-4), (m, row)
    # Without the option, nothing is formed.
    plain = solve(at, replace(tight, prior_leverage=False), first.features, pose_prior=prior)
    assert np.all(np.isnan(plain.prior_leverage))


def _chain(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, RelativePosePrior]:
    """Return poses 0..n-1 and noisy step factors i -> i+1 with step changes between them."""
    rng = np.random.default_rng(seed)
    R = so3.exp(rng.normal(0, 1.0, (n, 3)))
    P = rng.normal(0, 3.0, (n, 3))
    a = np.arange(n - 1)
    steps = _prior(R, P, a, a + 1, 7.0, 3.0, noise=0.2, seed=seed)
    first = np.arange(n - 2)
    W = rng.normal(0, 1.0, (first.size, 3, 3)) + 4.0 * np.eye(3)
    changes = StepChanges(first, rng.uniform(1.0, 9.0, first.size), W)
    return R, P, replace(steps, changes=changes)


def test_step_change_jacobians_match_central_differences() -> None:
    """The change factors' 6x18 Jacobian (poses a, b, c) against central differences."""
    R, P, prior = _chain(5, 3)
    assert prior.changes is not None
    ev = prior.evaluate(R, P)
    J = prior.changes.jacobian(ev)
    poses = np.stack([prior.a[prior.changes.first], prior.b[prior.changes.first],
                      prior.b[prior.changes.first + 1]], axis=1)
    h = 1e-6
    for m in range(len(prior.changes)):
        for side in range(3):
            for col in range(6):
                out = []
                for sign in (1.0, -1.0):
                    d = np.zeros(6)
                    d[col] = sign * h
                    R_m, P_m = R.copy(), P.copy()
                    R_m[poses[m, side]] = R[poses[m, side]] @ so3.exp(d[:3])
                    P_m[poses[m, side]] = P[poses[m, side]] + d[3:]
                    changes = prior.evaluate(R_m, P_m).changes
                    assert changes is not None
                    out.append(changes.residuals[m])
                np.testing.assert_allclose(J[m, :, 6 * side + col], (out[0] - out[1]) / (2 * h),
                                           atol=2e-6, err_msg=f'factor {m} pose {side} {col}')


def test_step_changes_cancel_an_error_that_stays() -> None:
    """Steps all off by the same body-frame error: the step factors see it, the changes not."""
    rng = np.random.default_rng(4)
    n = 6
    R = np.tile(so3.exp(rng.normal(0, 0.5, (1, 3))), (n, 1, 1))   # a straight drive
    P = np.outer(np.arange(n), [1.0, 0.2, 0.0])
    a = np.arange(n - 1)
    t_ab = np.einsum('mji,mj->mi', R[a], P[a + 1] - P[a]) - np.array([0.03, -0.01, 0.02])
    R_ab = np.einsum('mji,mjk->mik', R[a], R[a + 1]) @ so3.exp(np.array([[0.0, 0.0, 0.01]]))
    first = np.arange(n - 2)
    prior = RelativePosePrior(a, a + 1, R_ab, t_ab, np.full(n - 1, 100.0),
                              np.tile(100.0 * np.eye(3), (n - 1, 1, 1)),
                              changes=StepChanges(first, np.full(n - 2, 100.0),
                                                  np.tile(100.0 * np.eye(3), (n - 2, 1, 1))))
    ev = prior.evaluate(R, P)
    assert ev.changes is not None
    assert np.abs(ev.residuals).max() > 0.9
    np.testing.assert_allclose(ev.changes.residuals, 0.0, atol=1e-9)
    assert ev.cost == pytest.approx(0.5 * float(np.sum(ev.residuals ** 2)))


def test_step_changes_enter_the_normal_equations(engine: Engine) -> None:
    """add_to adds the change factors' J^T J and J^T r too (every pair covisible here)."""
    R, P, prior = _chain(5, 5)
    assert prior.changes is not None
    free_block = np.array([-1, 0, 1, 2, 3])
    st, zero = _empty_equations(engine, np.array([0, 1, 2, 3, 4, 0, 2, 4, 1, 3]),
                                np.repeat(np.arange(2), 5), free_block)
    eqs = prior.add_to(st, zero, R, P, free_block)
    ev = prior.evaluate(R, P)
    assert ev.changes is not None
    rows = []
    for J_f, poses, r in ((prior.jacobian(ev), np.stack([prior.a, prior.b], axis=1),
                           ev.residuals),
                          (prior.changes.jacobian(ev),
                           np.stack([prior.a[:-1], prior.b[:-1], prior.b[1:]], axis=1),
                           ev.changes.residuals)):
        for m in range(J_f.shape[0]):
            dense = np.zeros((6, 24))
            for side, pose in enumerate(poses[m]):
                if free_block[pose] >= 0:
                    block = free_block[pose]
                    dense[:, 6 * block:6 * block + 6] = J_f[m, :, 6 * side:6 * side + 6]
            rows.append((dense, r[m]))
    J = np.concatenate([d for d, _ in rows])
    res = np.concatenate([r for _, r in rows])
    H = (J.T @ J).reshape(4, 6, 4, 6)
    np.testing.assert_allclose(eqs.g_pose.ravel(), J.T @ res, rtol=1e-10, atol=1e-8)
    for p, (r, c) in enumerate(zip(st.pair_rows, st.pair_cols, strict=True)):
        np.testing.assert_allclose(eqs.U[p], H[r, :, c, :], rtol=1e-10, atol=1e-8)


def test_step_changes_must_join_consecutive_factors() -> None:
    """A change pair whose factors do not share a pose is a clear ProblemError."""
    _, _, prior = _chain(5, 6)
    skip = replace(prior, a=np.array([0, 1, 3, 3]), b=np.array([1, 2, 4, 4]), changes=None)
    with pytest.raises(ProblemError, match='consecutive factors'):
        replace(skip, changes=prior.changes)
    with pytest.raises(ProblemError, match='consecutive factors'):
        replace(prior, changes=StepChanges(np.array([3]), np.ones(1), np.eye(3)[None]))


def _windowed(n: int, seed: int, share: float, groups: np.ndarray,
              ) -> tuple[np.ndarray, np.ndarray, RelativePosePrior]:
    """Return a chain's poses and step factors whose lengths partly follow their group's scale."""
    R, P, _ = _chain(n, seed)
    a = np.arange(n - 1)
    rng = np.random.default_rng(seed)
    prior = _prior(R, P, a, a + 1, 7.0, 3.0, noise=0.2, seed=seed)
    along = prior.t_ab / np.linalg.norm(prior.t_ab, axis=1)[:, None]
    P_along = np.einsum('mi,mj->mij', along, along)
    W = 20.0 * P_along + 3.0 * (np.eye(3) - P_along)
    shares = np.clip(share + rng.uniform(-0.1, 0.1, n - 1), 0.0, 1.0)
    return R, P, replace(prior, W_trans=W, window_scale=WindowScale(shares, groups))


def test_window_scale_cost_gradient_is_that_of_the_factors_with_the_scale_held() -> None:
    """Each group's scale is its best fit, so the held-scale Jacobians give the cost's gradient.

    Central differences of the cost (the scales re-fitted at every pose), two groups.
    """
    n = 7
    R, P, prior = _windowed(n, 4, 0.7, np.array([0, 0, 0, 1, 1, 1]))
    ev = prior.evaluate(R, P)
    J = prior.jacobian(ev)
    grad = np.zeros((n, 6))
    for m in range(n - 1):
        g = J[m].T @ ev.residuals[m]
        grad[prior.a[m]] += g[:6]
        grad[prior.b[m]] += g[6:]
    h = 1e-6
    for k in range(n):
        for j in range(6):
            d = np.zeros(6)
            d[j] = h

            def cost(sign: float, k: int = k, d: np.ndarray = d) -> float:
                Rk, Pk = R.copy(), P.copy()
                Rk[k] = R[k] @ so3.exp(sign * d[:3])
                Pk[k] = P[k] + sign * d[3:]
                return prior.cost(Rk, Pk)

            num = (cost(1.0) - cost(-1.0)) / (2 * h)
            assert num == pytest.approx(grad[k, j], rel=1e-5, abs=1e-6), (k, j)


def test_window_scale_takes_a_groups_scaling_out_of_the_curvature() -> None:
    """The Hessian less the low-rank terms is curved along a group's scaling as the cost is.

    J^T J less them is positive semidefinite, and along a scaling of one group's steps (its
    poses moved away from a held pose) curved as the cost is (central differences); the
    held-scale J^T J is far stiffer there.
    """
    n = 7
    R, P, prior = _windowed(n, 5, 0.9, np.array([0, 0, 0, 1, 1, 1]))
    prior = replace(prior, w_rot=np.zeros(n - 1))
    ev = prior.evaluate(R, P)
    J = prior.jacobian(ev)
    H = np.zeros((6 * n, 6 * n))
    for m in range(n - 1):
        cols = np.r_[6 * prior.a[m]:6 * prior.a[m] + 6, 6 * prior.b[m]:6 * prior.b[m] + 6]
        H[np.ix_(cols, cols)] += J[m].T @ J[m]
    assembly = PriorAssembly(prior, None, None, np.arange(n), n)  # type: ignore[arg-type]
    low = assembly.low_rank(ev)
    assert low is not None
    u, d = low
    H_p = H - (u.T / d) @ u
    assert np.linalg.eigvalsh(H_p).min() > -1e-9 * np.abs(H).max()
    # Scale the first group's steps (poses 0..3) about pose 3: P_k + t (P_k - P_3).
    v = np.zeros((n, 6))
    v[:4, 3:] = P[:4] - P[3]

    def cost(t: float) -> float:
        return prior.cost(R, P + t * v[:, 3:])

    t = 1e-4
    curvature = (cost(t) - 2 * cost(0.0) + cost(-t)) / t ** 2
    x = v.ravel()
    assert x @ H_p @ x == pytest.approx(curvature, rel=1e-3)
    assert x @ H @ x > 10.0 * curvature


def test_a_solve_with_window_scale_leaves_the_factors_common_scale_to_the_vision() -> None:
    """With the lengths all against the window's scale, the prior's own scale does not matter.

    The same window solved with exact factors and with every measured step 30 % long ends
    at the same poses, in a few iterations: the downdated Hessian moves the window's scale
    at once (with the scale held in it, the long factors pull the window apart).
    """
    start, gt = _window()
    n = start.n_cams
    a = np.arange(n - 1)
    exact = _prior(gt.R_wc, gt.centers_w, a, a + 1, 1e3, 1e3)
    along = exact.t_ab / np.linalg.norm(exact.t_ab, axis=1)[:, None]
    P_along = np.einsum('mi,mj->mij', along, along)
    W = 1e3 * P_along + 1e2 * (np.eye(3) - P_along)
    ws = WindowScale(np.ones(n - 1), np.zeros(n - 1, dtype=np.int64))
    results = [_solve(start, replace(exact, t_ab=scale * exact.t_ab, W_trans=W,
                                     window_scale=ws))
               for scale in (1.0, 1.3)]
    assert all(r.converged for r in results)
    np.testing.assert_allclose(results[1].centers_w, results[0].centers_w, atol=1e-5)


def test_window_scale_must_fit_the_factors() -> None:
    """A share outside [0, 1], a negative group or a length mismatch: a clear ProblemError."""
    _, _, prior = _windowed(5, 6, 0.5, np.zeros(4, dtype=np.int64))
    for bad in (WindowScale(np.full(4, 1.5), np.zeros(4, dtype=np.int64)),
                WindowScale(np.full(4, 0.5), np.array([0, 0, -1, 0])),
                WindowScale(np.full(3, 0.5), np.zeros(3, dtype=np.int64)),
                WindowScale(np.full(4, np.nan), np.zeros(4, dtype=np.int64))):
        with pytest.raises(ProblemError, match='window_scale'):
            replace(prior, window_scale=bad)
