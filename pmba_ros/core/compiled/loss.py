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
"""Compiled robust cost and row weights (mirrors :mod:`pmba_ros.core.loss`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core import jit

_jit = jit.jit


#: Loss codes of the compiled robust loops (loss.Loss order: none, huber, cauchy).
LOSS_CODES = {'none': 0, 'huber': 1, 'cauchy': 2}


@_jit
def _rho(z: float, code: int) -> tuple[float, float]:
    """Return rho(z) and rho'(z) of a unit-scale loss (loss.rho)."""
    if code == 1:
        if z <= 1.0:
            return z, 1.0
        root = np.sqrt(z)
        return 2.0 * root - 1.0, 1.0 / root
    if code == 2:
        return np.log1p(z), 1.0 / (1.0 + z)
    return z, 1.0


@_jit
def _robust_cost(res: Any, code: int, scale: float) -> float:
    """1/2 sum a^2 rho(|e|^2 / a^2), or inf if a residual is not finite."""
    a2 = scale * scale
    total = 0.0
    for k in range(res.shape[0]):
        sq = 0.0
        for r in range(res.shape[1]):
            sq += res[k, r] * res[k, r]
        if not np.isfinite(sq):
            return np.inf
        total += _rho(sq / a2, code)[0] * a2
    return 0.5 * total


@_jit
def _robust_scale_rows(E: Any, code: int, scale: float) -> None:
    """Scale each observation's rows (residual column 6 included) by sqrt(rho'(|e|^2))."""
    a2 = scale * scale
    for k in range(E.shape[0]):
        sq = 0.0
        for r in range(E.shape[1]):
            sq += E[k, r, 6] * E[k, r, 6]
        w = np.sqrt(_rho(sq / a2, code)[1])
        for r in range(E.shape[1]):
            for c in range(E.shape[2]):
                E[k, r, c] *= w


def robust_cost(residuals: FloatArray, loss: str, scale: float) -> float:
    """Return loss.robust_cost of residuals (K, d), inf if one is not finite."""
    return float(_robust_cost(residuals, LOSS_CODES[loss], scale))


def robust_scale_rows(E: FloatArray, loss: str, scale: float) -> None:
    """Scale Jacobian rows E (K, d, w) in place by loss.robust_weights of their residuals."""
    _robust_scale_rows(E, LOSS_CODES[loss], scale)
