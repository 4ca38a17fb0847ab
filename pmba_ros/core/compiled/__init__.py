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
"""Compiled loops (numba) for the solver's per-observation work, one module per concept.

The numpy engine forms rays, Jacobian rows, J^T J and the Schur complement from batched
products and 0/1 scatter matrices: a few dozen numpy calls per step whatever the size, which
on a sliding window (a few thousand observations) take more time than the arithmetic. These
loops visit each observation, feature or observation pair once and write in place:

- PMBA rays, camera rays and errors (eqs. 6-8), Jacobian rows (pmba.md §1.6), pixel errors,
  the pixel weights' projection Jacobians and the sphere retraction (eq. 4);
- the robust cost and row weights (loss.py);
- J^T J (U, W, V, g), its Jacobi scaling, V^-1 with the Schur complement and right-hand side,
  the back-substitution and x^T H x (normal_equations.py), and the covisible pose pairs;
- the widest-pair anchor search (conversions.select_anchors), and with it the PMBA features
  of points in one pass (conversions.xyz_to_parallax).

On large problems the rows, J^T J and the Schur complement run on every core, features split
between threads (chunks.py).

They are the compiled engine (:mod:`pmba_ros.core.engine`), the default when numba is
installed (the ``fast`` extra), and give the numpy code's results to rounding: the tests run
both. ``PMBA_NUMBA=0`` turns them off (:mod:`pmba_ros.core.jit`). Each module mirrors a numpy
module of the same concept, which stays the reference; each jitted loop has a typed wrapper
without the underscore.

Block addressing: ``pair_index[a, b]`` (a <= b) is the row of the upper pair block (a, b) in
``U``; a pair (a, b) with a > b is stored transposed at ``pair_index[b, a]``.
"""
