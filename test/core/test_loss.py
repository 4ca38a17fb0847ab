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
"""Robust losses: the compiled loops against numpy, and numpy against scipy's least_squares."""

from __future__ import annotations

import math

import numpy as np
from pmba_ros.core.engine import COMPILED
from pmba_ros.core.jacobian import Linearization
from pmba_ros.core.loss import Loss, median, robust_cost, robust_weights
import pytest


@pytest.mark.parametrize('loss', list(Loss))
def test_compiled_robust_cost_and_weights_equal_numpy(loss: Loss) -> None:
    """The compiled engine's robust_cost / robust_rows equal loss.robust_cost / robust_weights."""
    pytest.importorskip('numba')
    rng = np.random.default_rng(3)
    rows = rng.normal(size=(500, 2, 19)) * np.logspace(-2, 1.5, 500)[:, None, None]
    lin = Linearization(rows.copy(), ((0, 6), (3, 6)))
    assert COMPILED.robust_cost(lin.residuals, loss, 2.0) == pytest.approx(
        robust_cost(lin.residuals, loss, 2.0), rel=1e-12)
    expected = lin.scaled(robust_weights(lin.residuals, loss, 2.0)).rows
    np.testing.assert_allclose(COMPILED.robust_rows(lin, loss, 2.0).rows, expected, rtol=1e-14,
                               atol=0)
    lin.rows[7, 1, 6] = np.nan
    assert COMPILED.robust_cost(lin.residuals, loss, 2.0) == np.inf


def _scipy_cost(residuals: np.ndarray, loss: Loss, scale: float) -> float:
    """Return least_squares' robust cost 1/2 sum C^2 rho(f^2 / C^2) of fixed scalar residuals."""
    from scipy.optimize import least_squares
    name = 'linear' if loss is Loss.NONE else loss.value
    # A zero Jacobian ends least_squares at its start, so its cost is the oracle's value there.
    zero_jac = np.zeros((residuals.size, 1))
    result = least_squares(lambda x: residuals, np.zeros(1), jac=lambda x: zero_jac, loss=name,
                           f_scale=scale)
    assert np.array_equal(result.x, np.zeros(1))
    return float(result.cost)


@pytest.mark.parametrize('loss', list(Loss))
def test_robust_cost_equals_scipy_least_squares(loss: Loss) -> None:
    """The cost of one-dimensional residuals is scipy least_squares' cost for the same loss."""
    residuals = np.logspace(-3, 3, 61) * np.where(np.arange(61) % 2, 1.0, -1.0)
    ours = robust_cost(residuals[:, None], loss, 2.5)
    assert ours == pytest.approx(_scipy_cost(residuals, loss, 2.5), rel=1e-12)


@pytest.mark.parametrize('loss', list(Loss))
def test_robust_weights_are_the_derivative_of_scipys_cost(loss: Loss) -> None:
    """rho'(z) = weights^2 matches a central difference of scipy's cost in z = f^2."""
    z = np.logspace(-2, 2, 9) * 6.25
    step = 1e-6 * z
    d_cost = np.array([(_scipy_cost(np.sqrt([zi + h]), loss, 2.5)
                        - _scipy_cost(np.sqrt([zi - h]), loss, 2.5)) / (2 * h)
                       for zi, h in zip(z, step, strict=True)])
    weights = robust_weights(np.sqrt(z)[:, None], loss, 2.5)
    # cost = 1/2 rho(z), so d cost / dz = rho'(z) / 2.
    np.testing.assert_allclose(weights ** 2, 2.0 * d_cost, rtol=1e-6)


@pytest.mark.parametrize('n', [1, 2, 7, 2500, 2501])
def test_median_is_numpys(n: int) -> None:
    """loss.median gives np.median's number, NaN included, without changing its input."""
    values = np.random.default_rng(n).lognormal(size=n)
    kept = values.copy()
    assert median(values) == np.median(values)
    np.testing.assert_array_equal(values, kept)
    values[n // 3] = np.nan
    assert math.isnan(median(values))
