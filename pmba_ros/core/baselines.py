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
"""Baseline parameterizations with pixel errors: XYZ-BA and inverse-depth (IDP) BA.

Both predict a camera-frame direction h and compare its projection with the measured pixel:

* XYZ: h = R_i^T (X - P_i); one pose slot (i).
* IDP: h = R_i^T (R_h [a, b, 1]^T + rho (P_h - P_i)), i.e. rho times the XYZ direction, which
  keeps points at infinity (rho = 0) finite; two pose slots (i, h), h the anchor camera.

Jacobian layout: :mod:`pmba_ros.core.jacobian`, columns [d phi, d P] (R <- R Exp(d phi)).
"""

from __future__ import annotations

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import so3
from pmba_ros.core.camera import Intrinsics, project, projection_jacobian
from pmba_ros.core.jacobian import Linearization
from pmba_ros.core.problem import IdpFeatures, Observations, XyzFeatures


def xyz_camera_rays(R_wc: FloatArray, centers_w: FloatArray, feats: XyzFeatures,
                    obs: Observations) -> FloatArray:
    """Camera-frame points h = R_i^T (X_j - P_i), shape (K, 3)."""
    d = feats.points_w[obs.feat_idx] - centers_w[obs.cam_idx]
    out: FloatArray = np.einsum('kji,kj->ki', R_wc[obs.cam_idx], d)
    return out


def pixel_errors(h_c: FloatArray, obs: Observations, intr: Intrinsics) -> FloatArray:
    """Pixel errors pi(h) - (u, v) of predicted camera-frame directions, shape (K, 2)."""
    return project(h_c, intr, obs.cam_idx) - obs.pixels


def xyz_jacobians(R_wc: FloatArray, centers_w: FloatArray, feats: XyzFeatures,
                  obs: Observations, intr: Intrinsics, h: FloatArray | None = None,
                  ) -> Linearization:
    """Pixel errors and Jacobian of XYZ-BA (no anchor slots); h: the camera rays, if known."""
    if h is None:
        h = xyz_camera_rays(R_wc, centers_w, feats, obs)
    pix, J_h = projection_jacobian(h, intr, obs.cam_idx)
    lin = Linearization.empty(h.shape[0], 2)
    E = lin.rows
    E[:, :, 0:3] = so3.times_hat(J_h, h)                          # dh/d phi_i = [h]x
    np.matmul(J_h, R_wc[obs.cam_idx].swapaxes(1, 2), out=E[:, :, 7:10])  # dh/dX = R_i^T
    np.negative(E[:, :, 7:10], out=E[:, :, 3:6])                  # dh/dP_i = -R_i^T
    E[:, :, 6] = pix - obs.pixels
    return lin


def xyz_slots(obs: Observations) -> IntArray:
    """Pose slots of XYZ-BA observations, shape (K, 1)."""
    return obs.cam_idx[:, None].astype(np.int64)


#: IDP's one anchor slot touches all six columns of the anchor pose.
IDP_ANCHOR_COLS = ((0, 6),)


def idp_camera_rays(R_wc: FloatArray, centers_w: FloatArray, feats: IdpFeatures,
                    obs: Observations) -> FloatArray:
    """Camera-frame directions h = R_i^T (R_h m + rho (P_h - P_i)), shape (K, 3)."""
    j = obs.feat_idx
    h_idx = feats.anchor_idx[j]
    m = np.concatenate([feats.ab[j], np.ones((j.shape[0], 1))], axis=1)
    world = (np.einsum('kij,kj->ki', R_wc[h_idx], m)
             + feats.rho[j][:, None] * (centers_w[h_idx] - centers_w[obs.cam_idx]))
    out: FloatArray = np.einsum('kji,kj->ki', R_wc[obs.cam_idx], world)
    return out


def idp_slots(feats: IdpFeatures, obs: Observations) -> IntArray:
    """Pose slots (i, h) of IDP observations, shape (K, 2); the anchor's own has none."""
    h_idx = feats.anchor_idx[obs.feat_idx]
    slots = np.stack([obs.cam_idx, h_idx], axis=1).astype(np.int64)
    slots[obs.cam_idx == h_idx] = -1
    return slots


def idp_jacobians(R_wc: FloatArray, centers_w: FloatArray, feats: IdpFeatures,
                  obs: Observations, intr: Intrinsics, h: FloatArray | None = None,
                  ) -> Linearization:
    """Pixel errors and Jacobian of IDP-BA, anchor slot h with all six columns.

    h: the camera rays of :func:`idp_camera_rays`, if known.
    """
    j = obs.feat_idx
    h_idx = feats.anchor_idx[j]
    rho = feats.rho[j]
    if h is None:
        h = idp_camera_rays(R_wc, centers_w, feats, obs)
    pix, J_h = projection_jacobian(h, intr, obs.cam_idx)
    R_i_T = np.swapaxes(R_wc[obs.cam_idx], 1, 2)
    R_h = R_wc[h_idx]
    m = np.concatenate([feats.ab[j], np.ones((j.shape[0], 1))], axis=1)
    Ri_T_Rh = R_i_T @ R_h
    lin = Linearization.empty(h.shape[0], 2, IDP_ANCHOR_COLS)
    E = lin.rows
    E[:, :, 0:3] = so3.times_hat(J_h, h)
    J_h_Ri_T = J_h @ R_i_T
    E[:, :, 3:6] = -rho[:, None, None] * J_h_Ri_T
    E[:, :, 6] = pix - obs.pixels
    J_h_Ri_T_Rh = J_h @ Ri_T_Rh
    E[:, :, 7:9] = J_h_Ri_T_Rh[:, :, :2]
    np.einsum('kij,kj->ki', J_h_Ri_T, centers_w[h_idx] - centers_w[obs.cam_idx],
              out=E[:, :, 9])
    E[:, :, 10:13] = -so3.times_hat(J_h_Ri_T_Rh, m)
    np.negative(E[:, :, 3:6], out=E[:, :, 13:16])
    # At the anchor h = m exactly: the pose terms cancel, so drop them rather than add noise.
    at_anchor = obs.cam_idx == h_idx
    E[at_anchor, :, :6] = 0.0
    E[at_anchor, :, 10:] = 0.0
    return lin
