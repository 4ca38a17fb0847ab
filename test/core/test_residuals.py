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
"""Tests of PMBA rays, errors and analytic Jacobians (pmba.md §1.2-1.7)."""

from __future__ import annotations

import numpy as np
from pmba_ros.core import conversions, so3, sphere
from pmba_ros.core.compiled import camera as compiled_camera
from pmba_ros.core.compiled import residuals as compiled_residuals
from pmba_ros.core.engine import Engine
from pmba_ros.core.models import ParallaxModel
from pmba_ros.core.problem import ParallaxFeatures
from pmba_ros.core.residuals import pose_slots, ray_residuals
import pytest

from .helpers import check_jacobians, engine_named, forward_problem, perturbed_state


def _perturbed(seed: int = 3):
    problem = forward_problem(seed)
    return (problem, *perturbed_state(problem, seed))


def test_observation_rays_eq6_equals_eq2_projection(engine: Engine) -> None:
    """xi(N_ji) of eq. (6) equals the direction from P_i to the eq. (2) point."""
    problem, R, P, feats = _perturbed()
    X = conversions.parallax_to_xyz(R, P, feats)
    near = feats.theta > 1e-3  # sin(theta) > 0: N = sin(theta) (F - P_i)
    N = engine.rays_and_residuals(R, P, feats, problem.obs, None)[0].N
    obs_near = near[problem.obs.feat_idx]
    d = X[problem.obs.feat_idx] - P[problem.obs.cam_idx]
    np.testing.assert_allclose(sphere.normalize(N[obs_near]), sphere.normalize(d[obs_near]),
                               atol=1e-9)


def test_theta_zero_is_a_point_at_infinity(engine: Engine) -> None:
    """At theta = 0 every observer's predicted ray is R_m n (pmba.md §1.3)."""
    problem, R, P, feats = _perturbed()
    feats0 = ParallaxFeatures(np.zeros_like(feats.theta), feats.n, feats.main_idx,
                              feats.assoc_idx)
    N = engine.rays_and_residuals(R, P, feats0, problem.obs, None)[0].N
    u = np.einsum('kij,kj->ki', R[feats.main_idx[problem.obs.feat_idx]],
                  feats.n[problem.obs.feat_idx])
    np.testing.assert_allclose(sphere.normalize(N), u, atol=1e-12)


@pytest.mark.parametrize('pixel_weighted', [False, True])
def test_jacobians_match_central_differences(pixel_weighted: bool, engine: Engine) -> None:
    """All blocks, all observer kinds, incl. near-collinear and 1e4-baseline features."""
    problem, R, P, feats = _perturbed()
    slots = pose_slots(feats, problem.obs)
    kinds = {'main': np.all(slots[:, 1:] < 0, axis=1),
             'assoc': slots[:, 0] == slots[:, 2], 'generic': slots[:, 0] != slots[:, 2]}
    assert all(k.any() for k in kinds.values())
    model = ParallaxModel(problem, pixel_weighted, engine)
    pose_err, feat_err = check_jacobians(model, R, P, feats)
    scale = 500.0 if pixel_weighted else 1.0
    assert pose_err < 1e-6 * scale
    assert feat_err < 1e-6 * scale
    # The solver linearizes from its evaluation (rays and residuals reused): the same rows.
    reused = model.linearize(R, P, feats, model.evaluate(R, P, feats))
    np.testing.assert_allclose(reused.rows, model.linearize(R, P, feats).rows, rtol=0, atol=0)


def test_jacobians_at_tiny_parallax(engine: Engine) -> None:
    """Jacobians stay exact as theta -> 0 (far features are harmless)."""
    problem, R, P, feats = _perturbed()
    tiny = ParallaxFeatures(np.full_like(feats.theta, 1e-9), feats.n, feats.main_idx,
                            feats.assoc_idx)
    pose_err, feat_err = check_jacobians(ParallaxModel(problem, engine=engine), R, P, tiny)
    assert pose_err < 1e-6 and feat_err < 1e-6


@pytest.mark.parametrize('pixel_weighted', [False, True])
def test_compiled_rows_equal_numpy_rows(pixel_weighted: bool) -> None:
    """The compiled PMBA evaluation and rows (pmba_ros.core.compiled) equal numpy's."""
    problem, R, P, feats = _perturbed()
    rows, evals = {}, {}
    for on in (False, True):
        model = ParallaxModel(problem, pixel_weighted, engine_named('compiled' if on else 'numpy'))
        evals[on] = model.evaluate(R, P, feats)
        rows[on] = model.linearize(R, P, feats, evals[on]).rows
    scale = np.max(np.abs(rows[False]))
    np.testing.assert_allclose(rows[True], rows[False], rtol=0, atol=1e-12 * scale)
    for name in ('residuals', 'rays_c'):
        np.testing.assert_allclose(getattr(evals[True], name), getattr(evals[False], name),
                                   rtol=0, atol=1e-12 * scale)
    for name in ('N', 'N_hat', 'norm', 'g', 's', 'c', 'main'):
        np.testing.assert_allclose(getattr(evals[True].geometry, name),
                                   getattr(evals[False].geometry, name), rtol=1e-12, atol=1e-12)


def test_cost_invariant_under_similarity() -> None:
    """|e| does not change under R -> Q R, P -> s Q P + b of all poses (pmba.md §2)."""
    problem, R, P, feats = _perturbed()
    Q = so3.exp(np.array([0.3, -0.2, 0.9]))
    s, b = 3.7, np.array([1.0, -2.0, 5.0])
    e0 = np.linalg.norm(ray_residuals(R, P, feats, problem.obs), axis=1)
    e1 = np.linalg.norm(ray_residuals(Q @ R, s * P @ Q.T + b, feats, problem.obs), axis=1)
    np.testing.assert_allclose(e1, e0, atol=1e-12)


def test_feature_block_bounded_below_by_0382() -> None:
    """H_FF of the two anchors alone has lambda_min = (3 - sqrt 5)/2 (pmba.md §1.7, FLAG)."""
    problem, R, P, feats = _perturbed()
    model = ParallaxModel(problem)
    J_feat = model.linearize(R, P, feats).J_feat
    slots = pose_slots(feats, problem.obs)
    anchor = np.all(slots[:, 1:] < 0, axis=1) | (slots[:, 0] == slots[:, 2])
    V = np.zeros((problem.n_feats, 3, 3))
    np.add.at(V, problem.obs.feat_idx[anchor],
              np.swapaxes(J_feat[anchor], 1, 2) @ J_feat[anchor])
    lam = np.linalg.eigvalsh(V)[:, 0]
    assert np.all(lam > 0.38)
    assert np.min(lam) < 0.39  # the bound is attained, not 1 as Theorem 1 says


def test_compiled_reprojection_errors_equal_numpy() -> None:
    """Pixel errors and projection Jacobians from the compiled loops equal camera.py's.

    Radial distortion included.
    """
    pytest.importorskip('numba')
    from dataclasses import replace

    problem, R, P, feats = _perturbed()
    M = problem.n_cams
    intr = replace(problem.intrinsics, k1=np.linspace(-0.2, 0.1, M), k2=np.full(M, 0.03))
    errors = {}
    for on in (False, True):
        model = ParallaxModel(replace(problem, intrinsics=intr), pixel_weighted=True,
                              engine=engine_named('compiled' if on else 'numpy'))
        errors[on] = model.reprojection_errors_px(model.evaluate(R, P, feats))
    assert np.all(errors[False] > 0)
    np.testing.assert_allclose(errors[True], errors[False], rtol=1e-9, atol=1e-9)
    from pmba_ros.core.camera import projection_jacobian
    _, weights = projection_jacobian(problem.obs.bearings_c, intr, problem.obs.cam_idx)
    np.testing.assert_allclose(
        compiled_camera.projection_jacobian(problem.obs.bearings_c, intr, problem.obs.cam_idx),
        weights, rtol=1e-12, atol=1e-12 * np.max(np.abs(weights)))


def test_pixel_weighted_error_grows_with_the_angle_up_to_the_antipode() -> None:
    """|W (r - v)| increases with the angle between r and v up to 180 degrees.

    The projection Jacobian alone (rows 1-2) peaks at 90 degrees and is 0 at the antipode;
    near the measurement the third row adds a term of second order in the angle (relative).
    Distorted, off-axis and wide cameras.
    """
    from pmba_ros.core.camera import Intrinsics, projection_jacobian
    from pmba_ros.core.residuals import pixel_weights

    rng = np.random.default_rng(0)
    K = 200
    v = sphere.normalize(rng.normal(size=(K, 3)) * [0.6, 0.6, 1.0] + [0.0, 0.0, 1.5])
    cams = np.arange(K) % 4
    intr = Intrinsics(np.array([300.0, 500.0, 1500.0, 8000.0]),
                      np.array([300.0, 550.0, 1400.0, 8000.0]), np.full(4, 320.0),
                      np.full(4, 240.0), np.array([-0.2, 0.0, 0.05, 0.0]),
                      np.array([0.03, 0.0, 0.0, 0.0]))
    J = projection_jacobian(v, intr, cams)[1]
    W = pixel_weights(J, v)
    assert W.shape == (K, 3, 3)
    np.testing.assert_array_equal(W[:, :2], J)
    axis = sphere.normalize(np.cross(v, rng.normal(size=(K, 3))))
    angles = np.linspace(1e-3, np.pi - 1e-3, 400)
    norms = np.empty((len(angles), K))
    for a, beta in enumerate(angles):
        r = np.einsum('kij,kj->ki', so3.exp(beta * axis), v)
        norms[a] = np.linalg.norm(np.einsum('kij,kj->ki', W, r - v), axis=1)
    assert np.all(np.diff(norms, axis=0) > 0.0)
    small = np.einsum('kij,kj->ki', so3.exp(1e-4 * axis), v) - v
    two_rows = np.linalg.norm(np.einsum('kij,kj->ki', J, small), axis=1)
    np.testing.assert_allclose(np.linalg.norm(np.einsum('kij,kj->ki', W, small), axis=1),
                               two_rows, rtol=1e-6)


def test_compiled_sphere_retraction_equals_numpy() -> None:
    """compiled_residuals.sphere_retract equals sphere.retract.

    Small, zero and large steps; rays on the axes and diagonals (the tangent basis' ties).
    """
    pytest.importorskip('numba')
    rng = np.random.default_rng(7)
    n = np.concatenate([rng.normal(size=(50, 3)), np.eye(3), -np.eye(3),
                        np.ones((1, 3)), np.array([[1.0, 1.0, 0.0], [0.0, -1.0, 1.0]])])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    delta = rng.normal(size=(n.shape[0], 2)) * np.logspace(-9, 0.5, n.shape[0])[:, None]
    delta[:3] = 0.0
    np.testing.assert_allclose(compiled_residuals.sphere_retract(n, delta),
                               sphere.retract(n, delta), rtol=0, atol=1e-14)
