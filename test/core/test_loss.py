"""Robust losses: the compiled loops against numpy."""

from __future__ import annotations

import numpy as np
import pytest

from pmba_ros.core import kernels
from pmba_ros.core.jacobian import Linearization
from pmba_ros.core.loss import Loss, robust_cost, robust_weights


@pytest.mark.parametrize('loss', list(Loss))
def test_compiled_robust_cost_and_weights_equal_numpy(loss: Loss) -> None:
    """kernels.robust_cost / robust_scale_rows equal loss.robust_cost / robust_weights."""
    pytest.importorskip('numba')
    rng = np.random.default_rng(3)
    rows = rng.normal(size=(500, 2, 19)) * np.logspace(-2, 1.5, 500)[:, None, None]
    lin = Linearization(rows.copy(), ((0, 6), (3, 6)))
    assert kernels.robust_cost(lin.residuals, loss.value, 2.0) == pytest.approx(
        robust_cost(lin.residuals, loss, 2.0), rel=1e-12)
    expected = lin.scaled(robust_weights(lin.residuals, loss, 2.0)).rows
    kernels.robust_scale_rows(lin.rows, loss.value, 2.0)
    np.testing.assert_allclose(lin.rows, expected, rtol=1e-14, atol=0)
    lin.rows[7, 1, 6] = np.nan
    assert kernels.robust_cost(lin.residuals, loss.value, 2.0) == np.inf
