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
"""Tests of pmba_ros.eval.align: Umeyama alignment and its application to trajectories."""

from __future__ import annotations

import numpy as np
from pmba_ros.core import so3
from pmba_ros.errors import DegenerateGeometryError, EvaluationError
from pmba_ros.eval.align import (
    align_se3,
    align_sim3,
    apply_alignment,
    scale_p_value,
    umeyama_alignment,
    UmeyamaResult,
)
from pmba_ros.eval.trajectory import Trajectory
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    """Seeded random generator."""
    return np.random.default_rng(1991)


def random_sim3(rng: np.random.Generator) -> UmeyamaResult:
    """Return a random similarity transform with a scale in [0.2, 5]."""
    return UmeyamaResult(so3.exp(rng.normal(size=3)), rng.normal(scale=10.0, size=3),
                         float(np.exp(rng.uniform(np.log(0.2), np.log(5.0)))))


def random_trajectory(rng: np.random.Generator, n: int) -> Trajectory:
    """Return a trajectory with random positions and rotations."""
    return Trajectory(np.arange(n, dtype=float), rng.normal(scale=3.0, size=(n, 3)),
                      so3.exp(rng.normal(size=(n, 3))))


@pytest.mark.parametrize('n', [3, 10, 500])
def test_umeyama_recovers_known_sim3_exactly(rng: np.random.Generator, n: int) -> None:
    """With noise-free points, Umeyama returns the generating Sim(3) to rounding."""
    truth = random_sim3(rng)
    x = rng.normal(size=(n, 3))
    y = truth.apply(x)
    got = umeyama_alignment(x, y, with_scale=True)
    np.testing.assert_allclose(got.rotation, truth.rotation, atol=1e-12)
    np.testing.assert_allclose(got.translation, truth.translation, atol=1e-10)
    assert got.scale == pytest.approx(truth.scale, rel=1e-12)
    np.testing.assert_allclose(got.apply(x), y, atol=1e-10)


def test_umeyama_without_scale_recovers_known_se3(rng: np.random.Generator) -> None:
    """with_scale=False returns scale 1 and the generating rigid motion."""
    truth = random_sim3(rng)._replace(scale=1.0)
    x = rng.normal(size=(50, 3))
    got = umeyama_alignment(x, truth.apply(x), with_scale=False)
    assert got.scale == 1.0
    np.testing.assert_allclose(got.rotation, truth.rotation, atol=1e-12)
    np.testing.assert_allclose(got.translation, truth.translation, atol=1e-10)


def test_umeyama_returns_proper_rotation_for_mirrored_points(rng: np.random.Generator) -> None:
    """A reflection between the point sets still gives det(R) = +1 (eq. 43)."""
    x = rng.normal(size=(40, 3))
    y = x * np.array([1.0, 1.0, -1.0])
    got = umeyama_alignment(x, y, with_scale=True)
    assert np.linalg.det(got.rotation) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(got.rotation @ got.rotation.T, np.eye(3), atol=1e-12)


def test_umeyama_matches_evo_on_noisy_points(rng: np.random.Generator) -> None:
    """On noisy data the result equals evo's loop implementation (transposed layout)."""
    geometry = pytest.importorskip('evo.core.geometry')
    x = rng.normal(size=(200, 3))
    y = random_sim3(rng).apply(x) + rng.normal(scale=0.05, size=x.shape)
    for with_scale in (False, True):
        ours = umeyama_alignment(x, y, with_scale)
        r, t, c = geometry.umeyama_alignment(x.T, y.T, with_scale)
        np.testing.assert_allclose(ours.rotation, r, atol=1e-12)
        np.testing.assert_allclose(ours.translation, t, atol=1e-10)
        assert ours.scale == pytest.approx(c, rel=1e-12)


def test_umeyama_works_in_two_dimensions(rng: np.random.Generator) -> None:
    """The dimension m is taken from the input shape."""
    angle = 0.7
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    x = rng.normal(size=(10, 2))
    got = umeyama_alignment(x, 2.0 * x @ rotation.T + 1.0, with_scale=True)
    np.testing.assert_allclose(got.rotation, rotation, atol=1e-12)
    assert got.scale == pytest.approx(2.0)


@pytest.mark.parametrize('points', [
    np.zeros((5, 3)),
    np.outer(np.arange(6.0), [1.0, 2.0, 3.0]),
    np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]),
])
def test_umeyama_raises_on_degenerate_points(points: np.ndarray) -> None:
    """Coincident or collinear points have covariance rank < 2."""
    with pytest.raises(DegenerateGeometryError, match='covariance rank'):
        umeyama_alignment(points, points + 1.0, with_scale=True)


@pytest.mark.parametrize('static_is', ['target', 'source'])
def test_umeyama_raises_on_points_that_coincide_up_to_rounding(rng: np.random.Generator,
                                                               static_is: str) -> None:
    """One point repeated away from the origin is coincident, though its mean is rounded.

    The rounding noise passed for a shape: a static ground truth got a scale of 1e-29 that
    mapped any estimate onto it (ATE 0), a static estimate a scale from noise.
    """
    moving = rng.normal(size=(50, 3)) * 5.0
    static = np.tile([1000.1, 2000.3, 5.7], (50, 1))
    assert np.any(static.mean(axis=0) != static[0])   # the noise the test is about
    x, y = (moving, static) if static_is == 'target' else (static, moving)
    with pytest.raises(DegenerateGeometryError, match='covariance rank 0'):
        umeyama_alignment(x, y, with_scale=True)


def test_umeyama_raises_on_shape_mismatch() -> None:
    """Both inputs must be (N, m) with the same shape."""
    with pytest.raises(EvaluationError, match='equal shape'):
        umeyama_alignment(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(EvaluationError, match='equal shape'):
        umeyama_alignment(np.zeros(3), np.zeros(3))


def test_as_matrix_maps_like_apply(rng: np.random.Generator) -> None:
    """The homogeneous matrix and apply() agree."""
    sim3 = random_sim3(rng)
    x = rng.normal(size=(7, 3))
    homogeneous = np.column_stack([x, np.ones(7)]) @ sim3.as_matrix().T
    np.testing.assert_allclose(homogeneous[:, :3], sim3.apply(x), atol=1e-12)


def test_apply_alignment_moves_positions_and_rotations(rng: np.random.Generator) -> None:
    """Positions become c R p + t and orientations R R_wc; the input is untouched."""
    traj = random_trajectory(rng, 12)
    before = traj.positions_xyz.copy()
    sim3 = random_sim3(rng)
    moved = apply_alignment(traj, sim3)
    np.testing.assert_array_equal(traj.positions_xyz, before)
    np.testing.assert_allclose(moved.positions_xyz, sim3.apply(before), atol=1e-12)
    np.testing.assert_allclose(moved.R_wc, sim3.rotation @ traj.R_wc, atol=1e-12)
    np.testing.assert_array_equal(moved.stamps_s, traj.stamps_s)


@pytest.mark.parametrize('with_scale', [False, True])
def test_align_undoes_a_known_transform(rng: np.random.Generator, with_scale: bool) -> None:
    """Aligning a transformed copy back onto the original restores its poses."""
    ref = random_trajectory(rng, 30)
    sim3 = random_sim3(rng)
    if not with_scale:
        sim3 = sim3._replace(scale=1.0)
    est = apply_alignment(ref, sim3)
    aligned, alignment = (align_sim3 if with_scale else align_se3)(est, ref)
    np.testing.assert_allclose(aligned.positions_xyz, ref.positions_xyz, atol=1e-9)
    np.testing.assert_allclose(aligned.R_wc, ref.R_wc, atol=1e-12)
    assert alignment.scale == pytest.approx(1.0 / sim3.scale, rel=1e-12)


def test_align_raises_on_unassociated_lengths(rng: np.random.Generator) -> None:
    """Alignment pairs pose i with pose i, so lengths must agree."""
    with pytest.raises(EvaluationError, match='associate them first'):
        align_se3(random_trajectory(rng, 5), random_trajectory(rng, 6))


@pytest.mark.parametrize('jitter', [1e-6, 1e-3])
def test_align_sim3_refuses_a_scale_set_by_noise(rng: np.random.Generator,
                                                 jitter: float) -> None:
    """An estimate that stands still but for its noise has no scale (was 1e6, ATE printed).

    The refusal does not depend on the size of the noise: the fit explains no more of the
    reference than unrelated points would, at any size.
    """
    ref = random_trajectory(rng, 40)
    still = Trajectory(ref.stamps_s, [5.0, 2.0, 1.0] + jitter * rng.normal(size=(40, 3)),
                       ref.R_wc)
    with pytest.raises(DegenerateGeometryError,
                       match=r'scale .* is not determined by the positions.*F test p = '):
        align_sim3(still, ref)
    # A noisy but real estimate keeps its Sim(3) alignment.
    noisy = Trajectory(ref.stamps_s, 0.01 * ref.positions_xyz + 0.005 * rng.normal(size=(40, 3)),
                       ref.R_wc)
    assert align_sim3(noisy, ref)[1].scale == pytest.approx(100.0, rel=0.2)


def test_scale_p_value_is_uniform_for_unrelated_points(rng: np.random.Generator) -> None:
    """Points unrelated to the reference have p <= 0.01 in about 1 % of the draws."""
    draws = [scale_p_value(*(lambda x, y: (umeyama_alignment(x, y, True).apply(x), y))(
        rng.normal(size=(20, 3)), rng.normal(size=(20, 3))))[1] for _ in range(1000)]
    assert 0.002 <= np.mean(np.array(draws) <= 0.01) <= 0.04
    exact = rng.normal(size=(5, 3))
    assert scale_p_value(exact, exact) == (0.0, 0.0)
