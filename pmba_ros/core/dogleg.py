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
"""Trust-region helpers of Ceres' TRADITIONAL_DOGLEG and Levenberg-Marquardt (pmba.md §5).

All vectors live in the Jacobi-scaled space z = D delta, where the trust region is the ball
|z| <= Delta. ``g`` is the scaled gradient D^-1 J^T r, ``alpha g`` the Cauchy step length
and ``b`` the (damped) Gauss-Newton step D y with (J^T J + mu D^2) y = -J^T r.

References:
    Ceres Solver, internal/ceres/dogleg_strategy.cc, trust_region_minimizer.cc,
    levenberg_marquardt_strategy.cc; Madsen, Nielsen, Tingleff, "Methods for non-linear least
    squares problems", 2004, §3.3.
"""

from __future__ import annotations

import math

from pmba_ros._typing import FloatArray

#: Ceres defaults (include/ceres/solver.h).
MIN_RELATIVE_DECREASE = 1e-3
MIN_MU = 1e-8
MAX_MU = 1.0
MU_INCREASE_FACTOR = 10.0


def cauchy_alpha(g: FloatArray, Jg_sq_norm: float) -> float:
    """Return alpha = |g|^2 / |J D^-1 g|^2, the step length along -g minimizing the model."""
    g_sq = float(g @ g)
    return g_sq / Jg_sq_norm if Jg_sq_norm > 0.0 else 0.0


def dogleg_step(g: FloatArray, alpha: float, b: FloatArray, radius: float,
                ) -> tuple[FloatArray, str]:
    """Return the traditional dogleg step and which branch made it ('gn', 'cauchy', 'dogleg').

    Args:
        g: Scaled gradient.
        alpha: Cauchy step length (:func:`cauchy_alpha`).
        b: Scaled Gauss-Newton step.
        radius: Trust-region radius Delta.
    """
    b_norm = math.sqrt(float(b.dot(b)))   # np.linalg.norm, unwrapped
    if b_norm <= radius:
        return b.copy(), 'gn'
    g_norm = math.sqrt(float(g.dot(g)))
    if alpha * g_norm >= radius:
        return -(radius / g_norm) * g, 'cauchy'
    a = -alpha * g
    b_minus_a = b - a
    c = float(a @ b_minus_a)
    bma_sq = float(b_minus_a @ b_minus_a)
    a_sq = float(a @ a)
    d = math.sqrt(c * c + bma_sq * (radius * radius - a_sq))
    beta = (d - c) / bma_sq if c <= 0.0 else (radius * radius - a_sq) / (d + c)
    return a + beta * b_minus_a, 'dogleg'


def step_quality(cost: float, new_cost: float, model_change: float) -> float:
    """Return rho = (actual cost reduction) / (model's predicted reduction)."""
    if model_change <= 0.0:
        return -math.inf
    return (cost - new_cost) / model_change


def dogleg_radius(radius: float, rho: float, step_norm: float, accepted: bool) -> float:
    """Update the dogleg radius: halve below rho 0.25 or on rejection, grow above 0.75.

    A rejected step halves the smaller of the radius and the step's length: when the
    Gauss-Newton step lies well inside the region, halving the radius alone would propose the
    same rejected step again (Madsen, Nielsen, Tingleff use Delta := |h_dl| / 2 likewise).
    """
    if not accepted:
        return min(radius, step_norm) * 0.5
    if rho < 0.25:
        return radius * 0.5
    if rho > 0.75:
        return max(radius, 3.0 * step_norm)
    return radius


def lm_radius(radius: float, decrease_factor: float, rho: float, accepted: bool,
              ) -> tuple[float, float]:
    """Update Ceres' LM radius (1/mu) and its decrease factor (Nielsen's rule).

    Returns:
        The new radius and decrease factor.
    """
    if accepted:
        return radius / max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 2.0
    return radius / decrease_factor, decrease_factor * 2.0
