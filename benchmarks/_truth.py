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
"""A global initialization's cameras against the simulated truth (for the init benchmarks)."""

from __future__ import annotations

import numpy as np
from pmba_ros.backend.window import estimate_similarity
from pmba_ros.core.problem import BAProblem
from pmba_ros.init.options import InitResult


def largest_centre_error(truth: BAProblem, result: InitResult) -> float:
    """Return the largest camera centre error over the extent, after a similarity alignment.

    The extent is the largest side of the true centres' bounding box.
    """
    ci = result.camera_index
    true_c = truth.centers_w[ci]
    sim = estimate_similarity(truth.R_wc[ci], true_c, result.solve.R_wc,
                              result.solve.centers_w)
    _, centers = sim.apply_poses(result.solve.R_wc, result.solve.centers_w)
    error = float(np.max(np.linalg.norm(centers - true_c, axis=1)))
    return error / float(np.ptp(true_c, axis=0).max())
