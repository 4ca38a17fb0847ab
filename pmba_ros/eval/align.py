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
"""Least-squares SE(3) / Sim(3) alignment of trajectories (Umeyama's method).

Notation (Umeyama 1991):

========  ===============  =======  =================================================
paper     code             shape    meaning
========  ===============  =======  =================================================
x_i       x[i]             (N, m)   points to be mapped (the estimate)
y_i       y[i]             (N, m)   target points (the reference)
mu_x      mean_x           (m,)     eq. (34)
mu_y      mean_y           (m,)     eq. (35)
sigma_x²  var_x            ()       eq. (36)
Sigma_xy  cov_xy           (m, m)   eq. (38)
U D V^T   U, d, Vt         (m, m)   SVD of Sigma_xy
S         S                (m, m)   eq. (43), reflection fix
R, t, c   rotation, ...             eq. (40), (41), (42): y ≈ c R x + t
========  ===============  =======  =================================================

Points are rows, ``(N, m)``, like every other array in pmba_ros (evo's
``umeyama_alignment`` takes the transpose, ``(m, N)``).

References:
    S. Umeyama, "Least-squares estimation of transformation parameters between two point
    patterns", IEEE PAMI 13(4), 1991.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.errors import DegenerateGeometryError, EvaluationError
from pmba_ros.eval.trajectory import Trajectory

logger = logging.getLogger(__name__)

_RANK_RTOL = 1e-12
"""Singular values of Sigma_xy below this fraction of the largest count as zero."""

_COINCIDENT_RTOL = 1e3 * float(np.finfo(float).eps)
"""A point set whose RMS spread about its mean is at most this fraction of its largest
coordinate coincides: the spread is what rounding the mean leaves."""

_SCALE_P_MAX = 1e-3
"""Largest p-value of a determined Sim(3) scale: the chance that positions unrelated to the
reference explain as much of its spread (:func:`align_sim3`)."""


def spread_over_rounding(points: FloatArray, centred: FloatArray) -> bool:
    """Return whether points spread beyond the rounding of their largest coordinate."""
    spread = float(np.sqrt(np.sum(centred * centred) / points.shape[0]))
    return spread > _COINCIDENT_RTOL * float(np.max(np.abs(points)))


class UmeyamaResult(NamedTuple):
    """A similarity transform ``y = scale * rotation @ x + translation``.

    Attributes:
        rotation: Rotation matrix R, shape (m, m).
        translation: Translation t, shape (m,).
        scale: Scale factor c (1.0 for a rigid alignment).
    """

    rotation: FloatArray
    translation: FloatArray
    scale: float

    def as_matrix(self) -> FloatArray:
        """Return the homogeneous Sim(m) matrix ``[[c R, t], [0, 1]]``, shape (m+1, m+1)."""
        m = self.rotation.shape[0]
        out = np.eye(m + 1)
        out[:m, :m] = self.scale * self.rotation
        out[:m, m] = self.translation
        return out

    def apply(self, points: FloatArray) -> FloatArray:
        """Map points of shape (..., m) with the transform; returns a new array."""
        return self.scale * (np.asarray(points, dtype=float) @ self.rotation.T) + self.translation


def umeyama_alignment(x: FloatArray, y: FloatArray, with_scale: bool = False) -> UmeyamaResult:
    """Find R, t (and c) minimizing ``sum_i ||y_i - (c R x_i + t)||^2``.

    Args:
        x: Source points (the estimate), shape (N, m).
        y: Target points (the reference), shape (N, m).
        with_scale: Also estimate the scale c (Sim(m)); otherwise c = 1 (SE(m)).

    Returns:
        The transform mapping ``x`` onto ``y``; R is a proper rotation (det = +1).

    Raises:
        EvaluationError: If ``x`` and ``y`` do not have the same (N, m) shape.
        DegenerateGeometryError: If the points do not span at least m - 1 dimensions (for
            example fewer than 3 distinct, or collinear, points in 3-D).

    References:
        Umeyama 1991, eqs. (34)-(43).
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[0] == 0:
        msg = (f'Umeyama alignment needs two (N, m) point arrays of equal shape; '
               f'got {x.shape} and {y.shape}')
        raise EvaluationError(msg)
    n, m = x.shape

    # means, eq. 34 and 35
    mean_x = x.mean(axis=0)
    mean_y = y.mean(axis=0)
    xc = x - mean_x
    yc = y - mean_y

    # variance, eq. 36
    var_x = float(np.sum(xc * xc)) / n

    # covariance matrix, eq. 38 (one product instead of a sum of outer products)
    cov_xy = yc.T @ xc / n

    # SVD (text between eq. 38 and 39): Sigma_xy = U D V^T
    U, d, Vt = np.linalg.svd(cov_xy)
    rank = int(np.count_nonzero(d > _RANK_RTOL * max(float(d[0]), np.finfo(float).tiny)))
    # Points that coincide away from the origin (a static trajectory at 1000 m) keep a spread
    # of rounding noise, and the rank above is relative to the largest singular value, itself
    # noise: the noise was taken for a shape, and a Sim(3) scale of 1e-29 mapped any estimate
    # onto the one point (ATE 0).
    if not (spread_over_rounding(x, xc) and spread_over_rounding(y, yc)):
        rank = 0
    if rank < m - 1:
        msg = (f'degenerate point set for Umeyama alignment: covariance rank {rank} < {m - 1} '
               f'({n} points; they must not be collinear or coincident)')
        raise DegenerateGeometryError(msg)

    # S matrix, eq. 43: flip the last axis if U V^T is a reflection
    S = np.eye(m)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:
        S[m - 1, m - 1] = -1.0

    # rotation, eq. 40
    rotation = U @ S @ Vt

    # scale and translation, eq. 42 and 41
    scale = float(np.sum(d * np.diag(S)) / var_x) if with_scale else 1.0
    translation = mean_y - scale * (rotation @ mean_x)
    logger.debug('Umeyama alignment over %d points: scale %.9g', n, scale)
    return UmeyamaResult(rotation, translation, scale)


def apply_alignment(traj: Trajectory, alignment: UmeyamaResult) -> Trajectory:
    """Return ``traj`` moved by a similarity transform (the input is not modified).

    Positions become ``c R p + t`` and orientations ``R R_wc``, as evo's
    ``traj.scale(c); traj.transform(se3(R, t))`` does in place.

    Args:
        traj: Trajectory to transform.
        alignment: Transform, for example from :func:`umeyama_alignment`.

    Returns:
        A new trajectory with the same stamps.
    """
    positions = alignment.apply(traj.positions_xyz)
    rotations = np.einsum('ij,njk->nik', alignment.rotation, traj.R_wc)
    return Trajectory(traj.stamps_s, positions, rotations)


def _align(est: Trajectory, ref: Trajectory,
           with_scale: bool) -> tuple[Trajectory, UmeyamaResult]:
    """Umeyama-align the positions of ``est`` onto those of ``ref`` (pose i with pose i)."""
    if len(est) != len(ref):
        msg = (f'aligning trajectories needs associated poses: the estimate has {len(est)} and '
               f'the reference {len(ref)}; associate them first')
        raise EvaluationError(msg)
    alignment = umeyama_alignment(est.positions_xyz, ref.positions_xyz, with_scale)
    return apply_alignment(est, alignment), alignment


def align_se3(est: Trajectory, ref: Trajectory) -> tuple[Trajectory, UmeyamaResult]:
    """Rigidly align ``est`` onto ``ref`` (like ``evo_ape ... -a``).

    Args:
        est: Estimated trajectory, already associated with ``ref`` (same length).
        ref: Reference trajectory.

    Returns:
        The aligned copy of ``est`` and the transform (scale 1).

    Raises:
        EvaluationError: If the lengths differ.
        DegenerateGeometryError: If the positions are collinear or coincident.
    """
    return _align(est, ref, with_scale=False)


def align_sim3(est: Trajectory, ref: Trajectory) -> tuple[Trajectory, UmeyamaResult]:
    """Align ``est`` onto ``ref`` with rotation, translation and scale (``evo_ape ... -as``).

    The scale must be determined by the positions: the fit has to explain the reference's
    spread better than positions unrelated to it would, at p <= :data:`_SCALE_P_MAX`
    (:func:`scale_p_value`). An estimate that stands still but for its noise (sub-micrometre
    jitter about one point) was scaled by 1e6 to the reference's size, and its ATE printed.

    Args:
        est: Estimated trajectory, already associated with ``ref`` (same length).
        ref: Reference trajectory.

    Returns:
        The aligned copy of ``est`` and the transform.

    Raises:
        EvaluationError: If the lengths differ.
        DegenerateGeometryError: If the positions are collinear or coincident, or do not
            determine the scale.
    """
    aligned, fit = _align(est, ref, with_scale=True)
    unexplained, p_value = scale_p_value(aligned.positions_xyz, ref.positions_xyz)
    if p_value > _SCALE_P_MAX:
        msg = (f'the scale {fit.scale:.3g} is not determined by the positions: the fit leaves '
               f"{100 * unexplained:.1f} % of the reference's spread unexplained, no better "
               f'than positions unrelated to it (F test p = {p_value:.2g} > {_SCALE_P_MAX:g})')
        raise DegenerateGeometryError(msg)
    return aligned, fit


def scale_p_value(aligned: FloatArray, ref: FloatArray) -> tuple[float, float]:
    """Return the share of the reference's spread a Sim(m) fit leaves, and its p-value.

    F test of the fit (rotation, translation, scale) against the model in which the
    estimate says nothing of the reference (scale 0: only the mean fits), on the squared
    residuals of N m coordinates. p is the probability of the fit doing at least as well
    by chance. The test takes the residuals as independent: it refuses noise about a point,
    not an estimate that wanders (a random walk fits a reference's path spuriously well).

    Args:
        aligned: Estimated points after the fit, shape (N, m).
        ref: Reference points, shape (N, m), not all coincident.

    Returns:
        The residual sum of squares over the reference's about its mean, in [0, 1], and the
        p-value (0.0 when no degree of freedom is left to judge the fit by).
    """
    from scipy.special import betainc

    n, m = ref.shape
    extra = m * (m - 1) // 2 + 1          # rotation and scale, beyond the translation
    dof = n * m - (extra + m)
    centred = ref - ref.mean(axis=0)
    unexplained = float(np.clip(np.sum((ref - aligned) ** 2) / np.sum(centred * centred),
                                0.0, 1.0))
    if dof <= 0:
        return unexplained, 0.0
    # P(F > f) for F(extra, dof) is I_x(dof / 2, extra / 2) at x = dof / (dof + extra f),
    # which for f = ((1 - u) / extra) / (u / dof) is the unexplained share u itself.
    return unexplained, float(betainc(dof / 2, extra / 2, unexplained))
