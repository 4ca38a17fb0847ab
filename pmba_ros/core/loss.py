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
"""Robust losses rho(z) of squared residual norms z = |e|^2 (scipy's and Ceres' contract).

The cost of an observation is ``1/2 a^2 rho(z / a^2)`` for a scale a (in residual units). Both
losses here have rho'' <= 0 wherever they down-weight, where Ceres' ``Corrector`` reduces to
scaling residual and Jacobian by sqrt(rho'), the form used by :func:`robust_weights`.
:func:`noise_scale_px` estimates the noise those scales are compared with.
"""

from __future__ import annotations

from enum import Enum
import math

import numpy as np
from pmba_ros._typing import FloatArray


class Loss(str, Enum):
    """Available robust losses."""

    NONE = 'none'
    HUBER = 'huber'
    CAUCHY = 'cauchy'


def rho(sq_norm: FloatArray, loss: Loss, scale: float) -> tuple[FloatArray, FloatArray]:
    """Return the loss value (residual units squared) and its derivative at z = sq_norm.

    Args:
        sq_norm: Squared residual norms, shape (K,).
        loss: The loss.
        scale: Scale a > 0 beyond which residuals are down-weighted (residual units).
    """
    if loss is Loss.NONE:
        return sq_norm, np.ones_like(sq_norm)
    a2 = scale * scale
    z = sq_norm / a2
    if loss is Loss.HUBER:
        root = np.sqrt(np.maximum(z, 1.0))
        return np.where(z <= 1.0, z, 2.0 * root - 1.0) * a2, np.where(z <= 1.0, 1.0, 1.0 / root)
    return np.log1p(z) * a2, 1.0 / (1.0 + z)


def robust_cost(residuals: FloatArray, loss: Loss, scale: float) -> float:
    """Return the cost 1/2 sum rho(|e_k|^2) of residuals (K, d)."""
    value, _ = rho(np.sum(residuals * residuals, axis=1), loss, scale)
    return 0.5 * float(np.sum(value))


def robust_weights(residuals: FloatArray, loss: Loss, scale: float) -> FloatArray:
    """Return sqrt(rho'(|e_k|^2)), shape (K,), to scale residuals and Jacobian rows by."""
    _, d_rho = rho(np.sum(residuals * residuals, axis=1), loss, scale)
    return np.sqrt(d_rho)


def noise_scale_px(errors_px: FloatArray, n_params: int) -> float:
    """Return a robust per-axis pixel noise estimate from reprojection error norms.

    The median norm of 2-D Gaussian errors is sigma sqrt(2 ln 2); the redundancy factor
    sqrt(2K / (2K - n_params)) adds back what the fitted parameters absorbed. NaN when the
    K errors do not outnumber the parameters.
    """
    k = errors_px.shape[0]
    redundancy = 2 * k - n_params
    if k == 0 or redundancy <= 0:
        return math.nan
    return (median(errors_px) / math.sqrt(2.0 * math.log(2.0))
            * math.sqrt(2.0 * k / redundancy))


def median(values: FloatArray) -> float:
    """Return ``np.median`` of a 1-D array (NaN if one is NaN), without its generic wrapper.

    The same partition and mean of the middle pair, so the same number.
    """
    n = values.shape[0]
    half = n // 2
    part = np.partition(values, [half - 1, half, n - 1] if n % 2 == 0 else [half, n - 1])
    if np.isnan(part[-1]):
        return math.nan
    return float(part[half] if n % 2 else (part[half - 1] + part[half]) / 2.0)
