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
"""The compiled engine's Schur plan: the covisible pose pairs and the loops that fill them.

Block addressing: ``pair_index[a, b]`` (a <= b) is the row of the upper pair block (a, b) in
``U`` and ``S``; a pair (a, b) with a > b is stored transposed at ``pair_index[b, a]``. The
pose pairs are the covisible ones: two free poses that observe one feature (the anchors
observe their features, so they are among the observers).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core.compiled import assembly, schur
from pmba_ros.core.jacobian import Linearization
from pmba_ros.core.normal_equations import NormalEquations, SchurLayout
from pmba_ros.errors import ReducedSystemError


@dataclass(frozen=True, eq=False)
class CompiledSchurPlan:
    """The pair index that the compiled loops read (a :class:`SchurPlan`).

    Attributes:
        layout: The structure's common part.
        pair_rows, pair_cols: Covisible block pairs, upper triangle incl. the diagonal.
        pair_index: (n_blocks, n_blocks) number of the upper pair (a, b), a <= b, or -1.
    """

    layout: SchurLayout
    pair_rows: IntArray
    pair_cols: IntArray
    pair_index: IntArray

    @classmethod
    def build(cls, layout: SchurLayout) -> CompiledSchurPlan:
        """Find the covisible pose pairs of a layout."""
        pair_index = assembly.covisible_pairs(layout.starts, layout.obs_block, layout.n_blocks)
        pair_rows, pair_cols = np.nonzero(pair_index >= 0)
        return cls(layout, pair_rows, pair_cols, pair_index)

    def assemble(self, lin: Linearization) -> NormalEquations:
        """Return U, W, V and the gradient of rows ``lin``, one observation at a time."""
        lt = self.layout
        return NormalEquations(*assembly.assemble(
            lin.rows, lt.starts, lt.obs_block, lt.anchor_block, lt.anchor_obs,
            lt.anchor_cols, self.pair_index, self.pair_rows.shape[0]))

    def scale_w(self, W: FloatArray, c_pose: FloatArray, c_feat: FloatArray) -> None:
        """Scale the W blocks in place by their pose and feature column scales."""
        assembly.scale_w(W, self.layout.feat_idx, self.layout.obs_block, c_pose, c_feat)

    def reduce(self, eqs: NormalEquations, damp_feat: FloatArray,
               ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Return S (upper pair blocks), -g_T + W V^-1 g_F and V^-1 of the damped V.

        Raises:
            ReducedSystemError: If a damped feature block is singular.
        """
        lt = self.layout
        S_blocks, rhs, V_inv, bad = schur.reduce(eqs.U, eqs.W, eqs.V, damp_feat, eqs.g_pose,
                                                 eqs.g_feat, lt.starts, lt.obs_block,
                                                 self.pair_index)
        if bad >= 0:
            msg = f'singular feature block (feature {bad})'
            raise ReducedSystemError(msg)
        return S_blocks, rhs, V_inv

    def back_substitute(self, eqs: NormalEquations, V_inv: FloatArray,
                        x_pose: FloatArray) -> FloatArray:
        """Return x_F = V^-1 (-g_F - W^T x_T), feature by feature."""
        return schur.back_substitute(eqs.W, V_inv, eqs.g_feat, x_pose, self.layout.starts,
                                     self.layout.obs_block)

    def quadratic_form(self, eqs: NormalEquations, x_pose: FloatArray,
                       x_feat: FloatArray) -> float:
        """Return x^T H x for H held as (upper) U, W and V blocks."""
        return assembly.quadratic_form(eqs.U, self.pair_rows, self.pair_cols, eqs.W, eqs.V,
                                       x_pose, x_feat, self.layout.feat_idx,
                                       self.layout.obs_block)
