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
"""Tests of pmba_ros.core.so3: group identities over batch shapes and edge angles."""

from __future__ import annotations

import numpy as np
from pmba_ros.core import so3
import pytest

BATCHES = [(), (1,), (3, 2)]


@pytest.mark.parametrize('batch', BATCHES)
def test_exp_log_round_trip(batch: tuple[int, ...], rng: np.random.Generator) -> None:
    """log(exp(w)) == w for rotation angles below pi, over batch shapes."""
    axis = rng.normal(size=(*batch, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    w = axis * rng.uniform(0.0, np.pi - 1e-2, size=(*batch, 1))
    np.testing.assert_allclose(so3.log(so3.exp(w)), w, atol=1e-10)


@pytest.mark.parametrize('angle', [0.0, 1e-12, 1e-7, 1e-3, np.pi - 1e-4, np.pi - 1e-7])
def test_exp_log_edge_angles(angle: float) -> None:
    """Small angles and angles near pi survive the round trip without NaN."""
    w = np.array([0.6, -0.48, 0.64]) * angle
    R = so3.exp(w)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    back = so3.log(R)
    assert np.all(np.isfinite(back))
    np.testing.assert_allclose(so3.exp(back), R, atol=1e-9)


def test_hat_vee_and_cross_product(rng: np.random.Generator) -> None:
    """hat(a) b == a x b and vee(hat(a)) == a."""
    a, b = rng.normal(size=(2, 5, 3))
    np.testing.assert_allclose(so3.hat(a) @ b[..., None], np.cross(a, b)[..., None])
    np.testing.assert_allclose(so3.vee(so3.hat(a)), a)


def test_quaternion_round_trip(rng: np.random.Generator) -> None:
    """Quaternions (x, y, z, w) round trip and match the rotation of a known axis."""
    R = so3.exp(rng.normal(size=(20, 3)))
    np.testing.assert_allclose(so3.from_quat_xyzw(so3.to_quat_xyzw(R)), R, atol=1e-12)
    q = so3.to_quat_xyzw(so3.exp(np.array([0.0, 0.0, np.pi / 2])))
    np.testing.assert_allclose(q, [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    # Half turns about each axis and near them: every branch of Shepperd's method.
    near_pi = np.concatenate([np.eye(3) * np.pi, np.eye(3) * (np.pi - 1e-9),
                              rng.normal(size=(30, 3))])
    R = so3.exp(near_pi)
    q = so3.to_quat_xyzw(R)
    np.testing.assert_allclose(so3.from_quat_xyzw(q), R, atol=1e-12)
    assert np.all(q[:, 3] >= 0) and np.allclose(np.linalg.norm(q, axis=1), 1.0)
    np.testing.assert_allclose(np.abs(q[:3, :3]), np.eye(3), atol=1e-12)
    # One matrix takes a scalar path: the very same numbers as the batch, every branch.
    assert np.array_equal(np.array([so3.to_quat_xyzw(r) for r in R]), q)
    assert np.array_equal(so3.to_quat_xyzw(R.reshape(4, 9, 3, 3)), q.reshape(4, 9, 4))
    assert so3.to_quat_xyzw(np.zeros((0, 3, 3))).shape == (0, 4)
    assert np.array_equal(so3.to_quat_xyzw(np.eye(3)), [0.0, 0.0, 0.0, 1.0])


def test_project_returns_nearest_rotation(rng: np.random.Generator) -> None:
    """Projecting a perturbed rotation gives a rotation close to the original."""
    R = so3.exp(rng.normal(size=(4, 3)))
    noisy = R + 1e-3 * rng.normal(size=R.shape)
    P = so3.project(noisy)
    np.testing.assert_allclose(P @ np.swapaxes(P, 1, 2), np.broadcast_to(np.eye(3), P.shape),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(P), 1.0)
    assert np.max(so3.angle(P, R)) < 5e-3


def test_cross_equals_numpy(rng: np.random.Generator) -> None:
    """so3.cross equals np.cross, broadcast shapes included."""
    a, b = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    np.testing.assert_allclose(so3.cross(a, b), np.cross(a, b), rtol=0, atol=1e-15)
    np.testing.assert_allclose(so3.cross(a, b[0]), np.cross(a, b[0]), rtol=0, atol=1e-15)
