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
"""Multi-camera rigs: observations through each camera's offset, Jacobians on the rig poses.

The pose variables stay one rig pose per keyframe (:class:`~pmba_ros.core.problem.Rig`).
Every observation of a camera that is not the rig frame itself gets a *camera pose*
``(R_wc R_rc[c], P + R_wc t_rc[c])``, appended after the M rig poses, so the residuals and
Jacobians of a parameterization run unchanged on the extended pose array: features keep
their anchors on the rig poses (indices < M), and only observations in the rig frame are
their main anchor's own (the closed forms of pmba.md §1.6).

The observer columns of a camera-pose observation then map back to its rig pose by the
chain rule of ``R_c = R Exp(d phi) R_rc`` and ``P_c = P + d P + R Exp(d phi) t_rc``:

    d phi_c = R_rc^T d phi,    d P_c = d P - R [t_rc]x d phi,

so ``J_phi = J_phi_c R_rc^T - J_P_c R [t_rc]x`` and ``J_P = J_P_c``.
"""

from __future__ import annotations

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import so3
from pmba_ros.core.problem import BAProblem, Observations, Rig


def _cameras(obs: Observations) -> IntArray:
    return (obs.camera if obs.camera is not None
            else np.zeros(obs.cam_idx.shape[0], dtype=np.int64))


def camera_pose_index(obs: Observations, rig: Rig, n_poses: int) -> IntArray:
    """Return each observation's index into :func:`camera_poses`' arrays, shape (K,).

    Observations in the rig frame keep their pose index; the others point at
    ``n_poses + pose * C + camera``.
    """
    cam = _cameras(obs)
    own = rig.in_rig_frame()[cam]
    return np.where(own, obs.cam_idx, n_poses + obs.cam_idx * len(rig) + cam).astype(np.int64)


def camera_poses(R_wc: FloatArray, centers_w: FloatArray, rig: Rig,
                 ) -> tuple[FloatArray, FloatArray]:
    """Return the rig poses, then every (pose, camera) pose: (M + M C, 3, 3), (M + M C, 3)."""
    M, C = R_wc.shape[0], len(rig)
    R_cam = np.einsum('mij,cjk->mcik', R_wc, rig.R_rc).reshape(M * C, 3, 3)
    P_cam = (centers_w[:, None, :] + np.einsum('mij,cj->mci', R_wc, rig.t_rc)).reshape(M * C, 3)
    return np.concatenate([R_wc, R_cam]), np.concatenate([centers_w, P_cam])


def camera_observations(obs: Observations, rig: Rig, n_poses: int) -> Observations:
    """Return the observations re-pointed at :func:`camera_poses` (no rig cameras)."""
    return Observations(camera_pose_index(obs, rig, n_poses), obs.feat_idx, obs.bearings_c,
                        obs.pixels, pixel_jac=obs.pixel_jac)


def observer_to_rig(rows: FloatArray, R_wc: FloatArray, obs: Observations, rig: Rig) -> None:
    """Map the observer columns (0:6) of camera-pose observations to their rig pose, in place.

    Args:
        rows: Jacobian rows of :mod:`pmba_ros.core.jacobian` over :func:`camera_poses`.
        R_wc: The rig poses' rotations, shape (M, 3, 3).
        obs: The rig observations (pose indices < M, rig cameras).
        rig: The rig.
    """
    cam = _cameras(obs)
    rows_k = np.flatnonzero(~rig.in_rig_frame()[cam])
    if rows_k.shape[0] == 0:
        return
    c = cam[rows_k]
    J_phi, J_P = rows[rows_k, :, 0:3], rows[rows_k, :, 3:6]
    lever = -R_wc[obs.cam_idx[rows_k]] @ so3.hat(rig.t_rc[c])
    rows[rows_k, :, 0:3] = J_phi @ np.swapaxes(rig.R_rc[c], 1, 2) + J_P @ lever


def rig_frame_bearings(problem: BAProblem) -> FloatArray:
    """Return every bearing rotated into its pose's rig frame, R_rc v, shape (K, 3)."""
    obs = problem.obs
    if problem.rig is None or obs.camera is None:
        return obs.bearings_c
    rotated: FloatArray = np.einsum('kij,kj->ki', problem.rig.R_rc[obs.camera], obs.bearings_c)
    return rotated
