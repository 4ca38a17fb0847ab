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
"""The motion prior weighted by the Odometry's pose covariance."""

from __future__ import annotations

import numpy as np
from pmba_ros.backend import outputs as out
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.estimator import Estimator
from pmba_ros.backend.tracks import parse_keyframe
from pmba_ros.backend.window import KeyframeStatus
from pmba_ros.core import so3
from pmba_ros.core.pose_prior import RelativePosePrior

from .test_logic import BACKEND

Q_T = np.array([[4e-4, 1e-4, 0.0], [1e-4, 1e-4, 0.0], [0.0, 0.0, 9e-4]])  # per step, odom
Q_R = np.diag([1e-6, 2e-6, 3e-6])


def _prior(covariances: list[np.ndarray | None]) -> tuple[RelativePosePrior, np.ndarray]:
    """Return the motion prior of keyframes along x with these covariances, and R_odom."""
    est = Estimator(BackendConfig())
    R = so3.exp(np.array([[0.0, 0.1, 0.0], [0.1, 0.3, -0.2], [0.0, 0.5, 0.1]]))
    for i, cov in enumerate(covariances):
        est.kf.add(i, (R[i], np.array([1.0 * i, 0.1 * i, 0.0])), None, KeyframeStatus.ACTIVE,
                   cov)
    n = len(covariances)
    prior = est._motion_prior(np.arange(n), np.zeros(n, dtype=bool), step=0.0)
    assert prior is not None
    return prior, R


def _cov(step: float) -> np.ndarray:
    cov = np.zeros((6, 6))
    cov[:3, :3], cov[3:, 3:] = step * Q_T, step * Q_R
    return cov


def test_growing_covariance_sets_the_weights() -> None:
    """The covariance a step adds, in the frame of a, replaces the parameter sigmas."""
    prior, R = _prior([_cov(1.0), _cov(2.0), _cov(4.0)])
    for k, (a, b) in enumerate([(1.0, 2.0), (2.0, 4.0)]):
        Q_a = R[k].T @ ((b - a) * Q_T) @ R[k]
        W = prior.W_trans[k]
        np.testing.assert_allclose(W.T @ W, np.linalg.inv(Q_a), rtol=1e-9)
        assert prior.w_rot[k] == np.sqrt(3.0 / np.trace((b - a) * Q_R))


def test_constant_or_missing_covariance_keeps_the_parameters() -> None:
    """No growth (not positive definite) or no covariance: the parameter weights."""
    plain, _ = _prior([None, None, None])
    constant, _ = _prior([_cov(1.0), _cov(1.0), _cov(1.0)])
    partly, _ = _prior([None, _cov(1.0), _cov(3.0)])
    np.testing.assert_array_equal(constant.W_trans, plain.W_trans)
    np.testing.assert_array_equal(constant.w_rot, plain.w_rot)
    np.testing.assert_array_equal(partly.W_trans[0], plain.W_trans[0])
    assert not np.allclose(partly.W_trans[1], plain.W_trans[1])
    assert partly.w_rot[1] != plain.w_rot[1]


def test_odometry_covariance_is_parsed() -> None:
    """Odometry's pose covariance comes along; all zeros means none."""
    cov = _cov(1.0)
    msg = out.make_odometry(5, 'odom', 'body', np.zeros(3), np.array([0, 0, 0, 1.0]), cov,
                            BACKEND)
    pose = parse_keyframe(msg)
    assert pose.covariance is not None
    np.testing.assert_allclose(pose.covariance, cov)
    msg.pose.covariance = np.zeros(36)
    assert parse_keyframe(msg).covariance is None
