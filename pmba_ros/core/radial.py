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
"""Radial distortion polynomials, inverted on the branch where they grow.

Radial distortion scales a point's radius r (or its ray's angle) by a polynomial,
r (1 + k1 r^2 + k2 r^4 + ...). A calibration fits it to the image it saw; past the radius where
it stops growing (its fold) a distorted radius has no undistorted one, or two. The inverses
here search below the fold only and return NaN where no radius there fits.
"""

from __future__ import annotations

from collections.abc import Callable
import functools
import math

import numpy as np
from pmba_ros._typing import FloatArray

__all__ = ['NEWTON_ITERATIONS', 'NEWTON_TOL', 'first_positive_root', 'fold',
           'increasing_inverse', 'theta_d', 'theta_d_slope']

NEWTON_ITERATIONS = 30
NEWTON_TOL = 1e-14


def theta_d(theta: FloatArray, d: FloatArray) -> FloatArray:
    """Return the equidistant distorted angle theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)."""
    t2 = theta * theta
    out: FloatArray = theta * (1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))
    return out


def theta_d_slope(theta: FloatArray, d: FloatArray) -> FloatArray:
    """Return d(theta_d) / d(theta) of :func:`theta_d`."""
    t2 = theta * theta
    k1, k2, k3, k4 = d
    out: FloatArray = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    return out


def fold(d: tuple[float, float, float, float]) -> float:
    """Return where :func:`theta_d` of ``d`` stops growing (inf if it grows everywhere).

    The first positive root of its slope 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3 + 9 k4 s^4,
    s = t^2.
    """
    k1, k2, k3, k4 = d
    return math.sqrt(first_positive_root((9.0 * k4, 7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0)))


def increasing_inverse(f: Callable[[FloatArray], FloatArray],
                       slope: Callable[[FloatArray], FloatArray], target: FloatArray,
                       end: float | FloatArray) -> FloatArray:
    """Return t in [0, end) with f(t) = target, for f growing there from f(0) = 0; NaN if none.

    Newton's method kept inside a bracket that bisection narrows (safeguarded Newton), on
    all points at once; ``end`` is finite (a fold, or 90 degrees), one for all points or one
    each.
    """
    lo = np.zeros_like(target)
    hi = np.full_like(target, end)
    has = (target >= 0.0) & (f(hi) >= target)
    t = np.minimum(target, hi)
    for _ in range(4 * NEWTON_ITERATIONS):
        value = f(t) - target
        lo, hi = np.where(value < 0.0, t, lo), np.where(value > 0.0, t, hi)
        with np.errstate(divide='ignore', invalid='ignore'):
            t_new = t - value / slope(t)
        outside = ~((t_new > lo) & (t_new < hi))
        t_new = np.where(outside, 0.5 * (lo + hi), t_new)
        done = np.abs(t_new - t) <= NEWTON_TOL * np.maximum(1.0, t)
        t = t_new
        if np.all(done | ~has):
            break
    return np.where(has, t, np.nan)


@functools.lru_cache(maxsize=64)   # a few cameras, asked at each message of their pixels
def first_positive_root(coefficients: tuple[float, ...]) -> float:
    """Return a polynomial's smallest positive real root (highest power first), or inf."""
    roots = np.roots(np.asarray(coefficients, dtype=float))   # leading zeros dropped
    real = roots.real[(np.abs(roots.imag) <= 1e-9 * np.maximum(1.0, np.abs(roots))) &
                      (roots.real > 0.0)]
    return float(real.min()) if real.size else float('inf')
