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
"""Tests of the trust-region helpers, one at a time (scipy's test_lsq_common style)."""

from __future__ import annotations

import numpy as np
from pmba_ros.core import dogleg


def test_gauss_newton_step_inside_region_is_taken() -> None:
    """A GN step within the radius is returned unchanged."""
    g = np.array([1.0, 0.0])
    b = np.array([-0.5, 0.1])
    step, kind = dogleg.dogleg_step(g, 0.3, b, radius=1.0)
    assert kind == 'gn'
    np.testing.assert_array_equal(step, b)


def test_cauchy_step_when_gradient_step_leaves_region() -> None:
    """If alpha |g| >= radius the step is the scaled steepest descent to the boundary."""
    g = np.array([3.0, 4.0])
    step, kind = dogleg.dogleg_step(g, 1.0, np.array([-10.0, -10.0]), radius=2.0)
    assert kind == 'cauchy'
    np.testing.assert_allclose(step, -2.0 * g / 5.0)


def test_dogleg_blend_lands_on_boundary() -> None:
    """The blend of Cauchy and GN points has norm equal to the radius."""
    g = np.array([1.0, 0.5])
    b = np.array([-3.0, 1.0])
    step, kind = dogleg.dogleg_step(g, 0.5, b, radius=1.5)
    assert kind == 'dogleg'
    assert abs(np.linalg.norm(step) - 1.5) < 1e-12


def test_radius_update_rules() -> None:
    """Halve on poor steps, grow to 3 |step| on very good ones, shrink below a rejected step."""
    assert dogleg.dogleg_radius(8.0, 0.1, 1.0, True) == 4.0
    assert dogleg.dogleg_radius(8.0, 0.9, 4.0, True) == 12.0
    assert dogleg.dogleg_radius(8.0, 0.5, 4.0, True) == 8.0
    assert dogleg.dogleg_radius(100.0, -1.0, 2.0, False) == 1.0
    radius, factor = dogleg.lm_radius(1.0, 2.0, -1.0, False)
    assert (radius, factor) == (0.5, 4.0)
    radius, factor = dogleg.lm_radius(1.0, 4.0, 1.0, True)
    assert radius == 3.0 and factor == 2.0


def test_step_quality() -> None:
    """Step quality is actual over predicted decrease; non-positive prediction gives -inf."""
    assert dogleg.step_quality(10.0, 8.0, 4.0) == 0.5
    assert dogleg.step_quality(10.0, 8.0, 0.0) == -np.inf
