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
"""Relative-motion priors between pose pairs, added to the reduced camera system.

A front-end's keyframe-to-keyframe motion is precise locally (and metric for a VIO), where a
monocular window is weakest: its scale and, with distant structure, its positions along the
image plane. :class:`RelativePosePrior` holds weighted factors between poses a and b of a
problem (camera -> world rotations ``R`` and centres ``P``), with the residual

    r_rot   = w_rot   * log(R_ab^T R_a^T R_b)
    r_trans = W_trans (R_a^T (P_b - P_a) - t_ab)

for the measured relative rotation ``R_ab`` and translation ``t_ab`` (in the frame of a).
They touch only pose columns, so they enter the normal equations after the observations:
H_aa, H_bb, H_ab and the pose gradient of the covisible pairs (the Schur complement then
reduces the features as before). The pose increment is the solver's: ``R <- R Exp(dphi)``,
``P <- P + dP``, columns [dphi, dP].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import so3
from pmba_ros.core.normal_equations import NormalEquations, SchurStructure
from pmba_ros.errors import ProblemError


def right_jacobian_inverse(omega: FloatArray) -> FloatArray:
    """Return J_r^-1 of SO(3) at rotation vectors ``omega`` (M, 3), shape (M, 3, 3)."""
    theta = np.linalg.norm(omega, axis=1)
    K = so3.hat(omega)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    coef = np.where(small, 1.0 / 12.0,
                    1.0 / t ** 2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(np.where(small, 1.0, t))))
    return np.eye(3) + 0.5 * K + coef[:, None, None] * (K @ K)


@dataclass(frozen=True, eq=False)
class RelativePosePrior:
    """Weighted relative-motion factors between poses of one problem.

    Attributes:
        a: First pose of each factor, shape (M,).
        b: Second pose, shape (M,).
        R_ab: Measured relative rotation R_a^T R_b, shape (M, 3, 3).
        t_ab: Measured relative translation R_a^T (P_b - P_a), shape (M, 3).
        w_rot: Rotation weight (1 / sigma, rad^-1), shape (M,).
        W_trans: Translation weight (square-root information, in the frame of a),
            shape (M, 3, 3).
    """

    a: IntArray
    b: IntArray
    R_ab: FloatArray
    t_ab: FloatArray
    w_rot: FloatArray
    W_trans: FloatArray

    def __post_init__(self) -> None:
        """Check shapes and weights.

        Raises:
            ProblemError: On mismatched shapes, a factor of a pose with itself or weights
                that are negative or not finite.
        """
        M = self.a.shape[0]
        shapes = (self.b.shape == (M,) and self.R_ab.shape == (M, 3, 3)
                  and self.t_ab.shape == (M, 3) and self.w_rot.shape == (M,)
                  and self.W_trans.shape == (M, 3, 3))
        if not shapes:
            msg = ('pose prior: a, b, R_ab, t_ab, w_rot, W_trans need shapes M, M, (M, 3, 3), '
                   '(M, 3), M, (M, 3, 3)')
            raise ProblemError(msg)
        if np.any(self.a == self.b):
            msg = 'pose prior: a factor between a pose and itself'
            raise ProblemError(msg)
        if not (np.all(np.isfinite(self.w_rot)) and np.all(np.isfinite(self.W_trans))
                and np.all(self.w_rot >= 0)):
            msg = 'pose prior: weights must be finite (and w_rot >= 0)'
            raise ProblemError(msg)

    def __len__(self) -> int:
        """Return the number of factors."""
        return int(self.a.shape[0])

    def residuals(self, R: FloatArray, P: FloatArray) -> FloatArray:
        """Return the weighted residuals, shape (M, 6): rotation, then translation."""
        Ra, Rb = R[self.a], R[self.b]
        E = np.einsum('mji,mkj,mkl->mil', self.R_ab, Ra, Rb)  # R_ab^T R_a^T R_b
        rel_t = np.einsum('mji,mj->mi', Ra, P[self.b] - P[self.a])
        return np.concatenate([self.w_rot[:, None] * so3.log(E),
                               np.einsum('mij,mj->mi', self.W_trans, rel_t - self.t_ab)],
                              axis=1)

    def cost(self, R: FloatArray, P: FloatArray) -> float:
        """Return 1/2 |r|^2 (the solver's cost convention)."""
        if len(self) == 0:
            return 0.0
        r = self.residuals(R, P)
        return 0.5 * float(np.sum(r * r))

    def jacobians(self, R: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Return d r / d [dphi_a, dP_a] and d r / d [dphi_b, dP_b], each (M, 6, 6)."""
        Ra, Rb = R[self.a], R[self.b]
        E = np.einsum('mji,mkj,mkl->mil', self.R_ab, Ra, Rb)
        Jinv = right_jacobian_inverse(so3.log(E))
        rel_t = np.einsum('mji,mj->mi', Ra, P[self.b] - P[self.a])
        RaT = np.swapaxes(Ra, 1, 2)
        M = len(self)
        Ja = np.zeros((M, 6, 6))
        Jb = np.zeros((M, 6, 6))
        Ja[:, :3, :3] = -Jinv @ np.swapaxes(Rb, 1, 2) @ Ra
        Jb[:, :3, :3] = Jinv
        Ja[:, 3:, :3] = so3.hat(rel_t)
        Ja[:, 3:, 3:] = -RaT
        Jb[:, 3:, 3:] = RaT
        Ja[:, :3] *= self.w_rot[:, None, None]
        Jb[:, :3] *= self.w_rot[:, None, None]
        Ja[:, 3:] = self.W_trans @ Ja[:, 3:]
        Jb[:, 3:] = self.W_trans @ Jb[:, 3:]
        return Ja, Jb

    def add_to(self, structure: SchurStructure, eqs: NormalEquations, R: FloatArray,
               P: FloatArray, free_block: IntArray) -> NormalEquations:
        """Return ``eqs`` (unscaled) with the factors' J^T J and J^T r added.

        Fixed poses contribute no columns. A cross block H_ab is added where (a, b) is a
        covisible pair of the structure (consecutive keyframes of a window are); elsewhere
        only the diagonal blocks are (a block-Jacobi approximation of the factor).

        Args:
            structure: The problem's Schur structure.
            eqs: Normal equations of the observations.
            R: Rotations of the problem's poses, (n_cams, 3, 3).
            P: Centres, (n_cams, 3).
            free_block: Pose -> block index (-1 for fixed poses).
        """
        if len(self) == 0:
            return eqs
        r = self.residuals(R, P)
        Ja, Jb = self.jacobians(R, P)
        ba, bb = free_block[self.a], free_block[self.b]
        U = eqs.U.copy()
        g = eqs.g_pose.copy()
        nb = structure.n_blocks
        keys = structure.pair_rows.astype(np.int64) * nb + structure.pair_cols
        order = np.argsort(keys)
        sorted_keys = keys[order]

        def pair_of(x: IntArray, y: IntArray) -> IntArray:
            """Upper pair index of blocks (x, y), -1 if not a pair."""
            lo, hi = np.minimum(x, y), np.maximum(x, y)
            want = lo.astype(np.int64) * nb + hi
            pos = np.minimum(np.searchsorted(sorted_keys, want), max(len(sorted_keys) - 1, 0))
            found = (len(sorted_keys) > 0) & (sorted_keys[pos] == want) & (lo >= 0)
            return np.where(found, order[pos], -1)

        for blocks, J in ((ba, Ja), (bb, Jb)):
            free = blocks >= 0
            diag = pair_of(blocks[free], blocks[free])
            np.add.at(U, diag, np.swapaxes(J[free], 1, 2) @ J[free])
            np.add.at(g, blocks[free], np.einsum('mji,mj->mi', J[free], r[free]))
        both = (ba >= 0) & (bb >= 0)
        cross = pair_of(ba[both], bb[both])
        has = cross >= 0
        H_ab = np.swapaxes(Ja[both][has], 1, 2) @ Jb[both][has]   # rows a, columns b
        upper = (ba[both] <= bb[both])[has]
        np.add.at(U, cross[has], np.where(upper[:, None, None], H_ab,
                                          np.swapaxes(H_ab, 1, 2)))
        return NormalEquations(U, eqs.W, eqs.V, g, eqs.g_feat)
