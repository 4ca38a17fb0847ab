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
"""Tests of pmba_ros.core.sphere: the S^2 retraction of PMBA eqs. (3)-(4)."""

from __future__ import annotations

import numpy as np
from pmba_ros.core import so3, sphere
import pytest


def test_tangent_basis_is_a_rotation(rng: np.random.Generator) -> None:
    """[a1 a2 n] is a rotation for random and axis-aligned n (PMBA eq. 3)."""
    n = sphere.normalize(np.vstack([rng.normal(size=(50, 3)), np.eye(3), -np.eye(3)]))
    A = sphere.tangent_basis(n)
    frame = np.concatenate([A, n[:, :, None]], axis=2)
    np.testing.assert_allclose(frame @ np.swapaxes(frame, 1, 2),
                               np.broadcast_to(np.eye(3), frame.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(frame), 1.0)


def test_retract_stays_on_sphere_and_matches_exp(rng: np.random.Generator) -> None:
    """Exp(A_n dn) n, closed form == Rodrigues, and unit norm for large steps (eq. 4)."""
    n = sphere.normalize(rng.normal(size=(30, 3)))
    delta = rng.normal(size=(30, 2)) * 2.0
    out = sphere.retract(n, delta)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)
    k = np.einsum('nij,nj->ni', sphere.tangent_basis(n), delta)
    np.testing.assert_allclose(out, np.einsum('nij,nj->ni', so3.exp(k), n), atol=1e-12)
    np.testing.assert_allclose(sphere.retract(n, np.zeros((30, 2))), n, atol=1e-15)


def test_retract_derivative_at_zero(rng: np.random.Generator) -> None:
    """The derivative d n / d dn at 0 is [-a2, a1] (pmba.md §1.5)."""
    n = sphere.normalize(rng.normal(size=(5, 3)))
    A = sphere.tangent_basis(n)
    eps = 1e-6
    for col, expected in ((0, -A[:, :, 1]), (1, A[:, :, 0])):
        d = np.zeros((5, 2))
        d[:, col] = eps
        num = (sphere.retract(n, d) - sphere.retract(n, -d)) / (2 * eps)
        np.testing.assert_allclose(num, expected, atol=1e-8)


def test_tangent_basis_of_zero_vector_is_zero_and_follows_batch_shape() -> None:
    """A zero direction (zero baseline) gives a zero basis, not NaN; batch axes are kept."""
    A = sphere.tangent_basis(np.zeros((2, 4, 3)))
    assert A.shape == (2, 4, 3, 2)
    np.testing.assert_array_equal(A, 0.0)
    assert sphere.tangent_basis(np.array([0.0, 0.0, 1.0])).shape == (3, 2)


@pytest.mark.parametrize('shape', [(0, 3), (1, 3), (7, 3), (2500, 3), (4, 9, 3)])
def test_norms_and_dots_are_numpys_to_the_bit(shape: tuple[int, ...]) -> None:
    """The three-term sums add in numpy's order (it matters: a0 + (a1 + a2) often differs)."""
    rng = np.random.default_rng(len(shape) * 100 + shape[0])
    a = rng.normal(size=shape) * rng.lognormal(0, 4, size=shape)
    b = rng.normal(size=shape)
    for x in (a, np.asfortranarray(a), np.concatenate([a, b], axis=-1)[..., ::2]):
        np.testing.assert_array_equal(sphere.norms(x), np.linalg.norm(x, axis=-1))
        np.testing.assert_array_equal(sphere.dots(x, b), np.sum(x * b, axis=-1))


def test_finite_rows_is_all_isfinite_per_row() -> None:
    """finite_rows equals np.all(np.isfinite(x), axis=1) for any number of columns."""
    from pmba_ros.core.problem import finite_rows

    rng = np.random.default_rng(4)
    for cols in (0, 1, 2, 3, 4):
        x = rng.normal(size=(50, cols))
        x[rng.random(x.shape) < 0.1] = rng.choice([np.nan, np.inf, -np.inf])
        np.testing.assert_array_equal(finite_rows(x), np.all(np.isfinite(x), axis=1))
