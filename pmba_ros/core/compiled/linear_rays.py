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
"""Compiled normal matrix of the linearised rays (mirrors ``init.cls.LinearRays``).

The position steps of the global initialization (CLS, eq. 14, and NLS, eq. 13) assemble
sum_k G_k^T A_k G_k over all observations at every iteration, with G_k = dN-bar_k / dP: the
blocks -sin(theta_j) I on the observer P_i and C_a, C_m on the anchors P_a, P_m of feature j.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import jit

_jit = jit.jit


@_jit
def _ray_normal_matrix(cam: Any, feat: Any, assoc: Any, main: Any, coeff: Any, sin_t: Any,
                       A: Any, H: Any) -> None:
    """Add sum_k G_k^T A_k G_k to the dense (3M, 3M) H.

    The observer's blocks are added per observation, the anchors' once per feature from the
    sum B_j of its observations' A_k.
    """
    B = np.zeros((coeff.shape[0], 3, 3))
    for k in range(cam.shape[0]):
        j, i = feat[k], cam[k]
        s = sin_t[j]
        for r in range(3):
            for c in range(3):
                B[j, r, c] += A[k, r, c]
                H[3 * i + r, 3 * i + c] += s * s * A[k, r, c]
        for t in range(2):
            a = assoc[j] if t == 0 else main[j]
            for r in range(3):
                for c in range(3):
                    v = -s * (A[k, r, 0] * coeff[j, t, 0, c] + A[k, r, 1] * coeff[j, t, 1, c]
                              + A[k, r, 2] * coeff[j, t, 2, c])
                    H[3 * i + r, 3 * a + c] += v
                    H[3 * a + c, 3 * i + r] += v
    for j in range(coeff.shape[0]):
        for t in range(2):
            a = assoc[j] if t == 0 else main[j]
            for u in range(2):
                b = assoc[j] if u == 0 else main[j]
                for r in range(3):
                    for c in range(3):
                        v = 0.0
                        for p in range(3):
                            for q in range(3):
                                v += coeff[j, t, p, r] * B[j, p, q] * coeff[j, u, q, c]
                        H[3 * a + r, 3 * b + c] += v


def ray_normal_matrix(cam: IntArray, feat: IntArray, assoc: IntArray, main: IntArray,
                      coeff: FloatArray, sin_t: FloatArray, A: FloatArray,
                      n_cams: int) -> FloatArray:
    """Return sum_k G_k^T A_k G_k, shape (3M, 3M) (``init.cls.LinearRays.normal_matrix``)."""
    H = np.zeros((3 * n_cams, 3 * n_cams))
    _ray_normal_matrix(cam, feat, assoc, main, np.ascontiguousarray(coeff), sin_t,
                       np.ascontiguousarray(A), H)
    return H
