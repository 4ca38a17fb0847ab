"""Baseline parameterizations with pixel errors: XYZ-BA and inverse-depth (IDP) BA.

Both predict a camera-frame direction h and compare its projection with the measured pixel:

* XYZ: h = R_i^T (X - P_i); one pose slot (i).
* IDP: h = R_i^T (R_h [a, b, 1]^T + rho (P_h - P_i)), i.e. rho times the XYZ direction, which
  keeps points at infinity (rho = 0) finite; two pose slots (i, h), h the anchor camera.

Jacobian layout as in :mod:`pmba_ros.core.residuals`: J_pose (K, S, 2, 6) with columns
[d phi, d P] (R <- R Exp(d phi)), J_feat (K, 2, 3).
"""

from __future__ import annotations

import numpy as np

from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import so3
from pmba_ros.core.camera import Intrinsics, project, projection_jacobian
from pmba_ros.core.problem import IdpFeatures, Observations, XyzFeatures


def xyz_camera_rays(R_wc: FloatArray, centers_w: FloatArray, feats: XyzFeatures,
                    obs: Observations) -> FloatArray:
    """Camera-frame points h = R_i^T (X_j - P_i), shape (K, 3)."""
    d = feats.points_w[obs.feat_idx] - centers_w[obs.cam_idx]
    return np.einsum('kji,kj->ki', R_wc[obs.cam_idx], d)


def pixel_errors(h_c: FloatArray, obs: Observations, intr: Intrinsics) -> FloatArray:
    """Pixel errors pi(h) - (u, v) of predicted camera-frame directions, shape (K, 2)."""
    return project(h_c, intr, obs.cam_idx) - obs.pixels


def xyz_jacobians(R_wc: FloatArray, centers_w: FloatArray, feats: XyzFeatures,
                  obs: Observations, intr: Intrinsics,
                  ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Residuals (K, 2), J_pose (K, 1, 2, 6) and J_feat (K, 2, 3) of XYZ-BA."""
    h = xyz_camera_rays(R_wc, centers_w, feats, obs)
    pix, J_h = projection_jacobian(h, intr, obs.cam_idx)
    R_i_T = np.swapaxes(R_wc[obs.cam_idx], 1, 2)
    J_pose = np.empty((h.shape[0], 1, 2, 6))
    J_pose[:, 0, :, :3] = J_h @ so3.hat(h)       # dh/d phi_i = [h]x
    J_feat = J_h @ R_i_T                         # dh/dX = R_i^T
    J_pose[:, 0, :, 3:] = -J_feat                # dh/dP_i = -R_i^T
    return pix - obs.pixels, J_pose, J_feat


def xyz_slots(obs: Observations) -> IntArray:
    """Pose slots of XYZ-BA observations, shape (K, 1)."""
    return obs.cam_idx[:, None].astype(np.int64)


def idp_camera_rays(R_wc: FloatArray, centers_w: FloatArray, feats: IdpFeatures,
                    obs: Observations) -> FloatArray:
    """Camera-frame directions h = R_i^T (R_h m + rho (P_h - P_i)), shape (K, 3)."""
    j = obs.feat_idx
    h_idx = feats.anchor_idx[j]
    m = np.concatenate([feats.ab[j], np.ones((j.shape[0], 1))], axis=1)
    world = (np.einsum('kij,kj->ki', R_wc[h_idx], m)
             + feats.rho[j][:, None] * (centers_w[h_idx] - centers_w[obs.cam_idx]))
    return np.einsum('kji,kj->ki', R_wc[obs.cam_idx], world)


def idp_slots(feats: IdpFeatures, obs: Observations) -> IntArray:
    """Pose slots (i, h) of IDP observations, shape (K, 2); the anchor's own has none."""
    h_idx = feats.anchor_idx[obs.feat_idx]
    slots = np.stack([obs.cam_idx, h_idx], axis=1).astype(np.int64)
    slots[obs.cam_idx == h_idx] = -1
    return slots


def idp_jacobians(R_wc: FloatArray, centers_w: FloatArray, feats: IdpFeatures,
                  obs: Observations, intr: Intrinsics,
                  ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Residuals (K, 2), J_pose (K, 2, 2, 6) and J_feat (K, 2, 3) of IDP-BA."""
    j = obs.feat_idx
    h_idx = feats.anchor_idx[j]
    rho = feats.rho[j]
    h = idp_camera_rays(R_wc, centers_w, feats, obs)
    pix, J_h = projection_jacobian(h, intr, obs.cam_idx)
    R_i_T = np.swapaxes(R_wc[obs.cam_idx], 1, 2)
    R_h = R_wc[h_idx]
    m = np.concatenate([feats.ab[j], np.ones((j.shape[0], 1))], axis=1)
    Ri_T_Rh = R_i_T @ R_h
    J_pose = np.empty((h.shape[0], 2, 2, 6))
    J_pose[:, 0, :, :3] = J_h @ so3.hat(h)
    J_pose[:, 0, :, 3:] = -rho[:, None, None] * (J_h @ R_i_T)
    J_pose[:, 1, :, :3] = -(J_h @ Ri_T_Rh @ so3.hat(m))
    J_pose[:, 1, :, 3:] = -J_pose[:, 0, :, 3:]
    J_feat = np.empty((h.shape[0], 2, 3))
    J_feat[:, :, :2] = J_h @ Ri_T_Rh[:, :, :2]
    J_feat[:, :, 2] = np.einsum('kij,kj->ki', J_h @ R_i_T,
                                centers_w[h_idx] - centers_w[obs.cam_idx])
    # At the anchor h = m exactly: the pose terms cancel, so drop them rather than add noise.
    J_pose[obs.cam_idx == h_idx] = 0.0
    return pix - obs.pixels, J_pose, J_feat
