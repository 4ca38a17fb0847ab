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
"""Residuals and Jacobians of all observations in the one layout the normal equations read.

Every parameterization's observation (i, j) depends on its observer pose i, its feature j and
*anchor* poses that are the same for all observations of the feature (PMBA: the main
anchor, and the associate anchor's centre; IDP: the anchor pose; XYZ: none). One row block
per observation, shape (d, 10 + A), holds:

=========  ======================================================
columns    meaning
=========  ======================================================
0:3, 3:6   d e / d phi_i, d e / d P_i (R_i <- R_i Exp(d phi))
6          the residual e
7:10       d e / d feature (3 local coordinates)
10:        the anchors' columns, anchor slot by slot (``anchor_cols``)
=========  ======================================================

The jacobian functions of each parameterization write straight into this array, so the
assembly neither copies nor gathers it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pmba_ros._typing import FloatArray

#: First column of the anchors' blocks.
ANCHOR_START = 10


@dataclass(frozen=True, eq=False)
class Linearization:
    """Residuals and Jacobian blocks of K observations (see the module table).

    Attributes:
        rows: Shape (K, d, 10 + A).
        anchor_cols: Pose columns (start, stop) of each anchor slot, in order; A is the sum
            of their widths.
    """

    rows: FloatArray
    anchor_cols: tuple[tuple[int, int], ...] = ()

    @classmethod
    def empty(cls, n_obs: int, dim: int, anchor_cols: tuple[tuple[int, int], ...] = (),
              ) -> Linearization:
        """Return an uninitialized linearization of n_obs observations of dimension dim."""
        width = ANCHOR_START + sum(hi - lo for lo, hi in anchor_cols)
        return cls(np.empty((n_obs, dim, width)), anchor_cols)

    @property
    def residuals(self) -> FloatArray:
        """Return the residuals, shape (K, d) (a view)."""
        return self.rows[:, :, 6]

    @property
    def J_feat(self) -> FloatArray:
        """Return the feature blocks, shape (K, d, 3) (a view)."""
        return self.rows[:, :, 7:10]

    @property
    def J_obs(self) -> FloatArray:
        """Return the observer pose blocks, shape (K, d, 6) (a view)."""
        return self.rows[:, :, :6]

    def anchor_offsets(self) -> list[int]:
        """Return the first column of each anchor slot in ``rows`` and the end column."""
        offs = [ANCHOR_START]
        for lo, hi in self.anchor_cols:
            offs.append(offs[-1] + hi - lo)
        return offs

    def anchor(self, slot: int) -> FloatArray:
        """Return the columns of anchor slot ``slot`` (0-based), shape (K, d, width) (a view)."""
        offs = self.anchor_offsets()
        return self.rows[:, :, offs[slot]:offs[slot + 1]]

    def J_pose(self) -> FloatArray:
        """Return full 6-column pose blocks per slot (observer, anchors...), (K, 1 + S_a, d, 6).

        A copy with zero columns where an anchor touches part of a pose (for tests and
        readers that want the textbook layout).
        """
        K, d, _ = self.rows.shape
        out = np.zeros((K, 1 + len(self.anchor_cols), d, 6))
        out[:, 0] = self.J_obs
        for s, (lo, hi) in enumerate(self.anchor_cols):
            out[:, s + 1, :, lo:hi] = self.anchor(s)
        return out

    def scaled(self, weights: FloatArray) -> Linearization:
        """Return the rows multiplied by per-observation weights (K,) (robust losses)."""
        return Linearization(self.rows * weights[:, None, None], self.anchor_cols)
