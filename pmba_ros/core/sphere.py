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
"""The unit sphere S^2 as the manifold of a feature's ray n (PMBA eqs. 3-4).

A feature's direction n is updated as ``n <- Exp(A_n dn) n``, where ``A_n = [a1 a2]`` is a
3x2 basis of the tangent plane at n with ``[a1 a2 n]`` in SO(3) (so a1 x a2 = n).
"""

from __future__ import annotations

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core import so3


def dots(a: FloatArray, b: FloatArray) -> FloatArray:
    """Return a . b of 3-vectors (..., 3), shape (...): ``np.sum(a * b, axis=-1)`` to the bit.

    numpy reduces a last axis of three slowly; this adds the products in its order.
    """
    out: FloatArray = a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]
    return out


def norms(x: FloatArray) -> FloatArray:
    """Return |x| of 3-vectors (..., 3), shape (...): ``np.linalg.norm(x, axis=-1)`` to the bit."""
    out: FloatArray = np.sqrt(dots(x, x))
    return out


def normalize(x: FloatArray) -> FloatArray:
    """Return xi(x) = x / |x| of 3-vectors (..., 3) (zero vectors stay zero)."""
    x = np.asarray(x, dtype=float)
    norm = norms(x)[..., None]
    return x / np.where(norm > 0.0, norm, 1.0)


def tangent_basis(n: FloatArray) -> FloatArray:
    """Tangent basis A_n = [a1 a2] of unit vectors n (..., 3); shape (..., 3, 2).

    a1 = xi(e x n) with e the coordinate axis least aligned with n, a2 = n x a1, so that
    [a1 a2 n] is a rotation (PMBA eq. 3).
    """
    n = np.asarray(n, dtype=float)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    k = np.argmin(np.abs(n), axis=-1)
    zero = np.zeros(x.shape)
    # e_k x n for the three axes, picked per vector (np.cross is slow on short rows).
    a1 = np.stack([np.choose(k, [zero, z, -y]), np.choose(k, [-z, zero, x]),
                   np.choose(k, [y, -x, zero])], axis=-1)
    norm = norms(a1)[..., None]
    a1 /= np.where(norm > 0.0, norm, 1.0)  # n = 0 (a zero baseline's direction) gives A = 0
    return np.stack([a1, so3.cross(n, a1)], axis=-1)


def retract(n: FloatArray, delta: FloatArray, basis: FloatArray | None = None) -> FloatArray:
    """Retraction n' = Exp(A_n delta) n for n (..., 3), delta (..., 2) (PMBA eq. 4).

    Closed form: with phi = |delta|, n' = cos(phi) n + sin(phi)/phi * A_n [delta_2, -delta_1]^T.
    """
    n = np.asarray(n, dtype=float)
    delta = np.asarray(delta, dtype=float)
    A = tangent_basis(n) if basis is None else basis
    phi_sq = np.sum(delta * delta, axis=-1)
    small = phi_sq < 1e-12
    phi = np.sqrt(np.where(small, 1.0, phi_sq))
    sinc = np.where(small, 1.0 - phi_sq / 6.0, np.sin(phi) / phi)
    rotated = np.stack([delta[..., 1], -delta[..., 0]], axis=-1)
    tangent = np.einsum('...ij,...j->...i', A, rotated)
    out = np.cos(np.sqrt(phi_sq))[..., None] * n + sinc[..., None] * tangent
    return normalize(out)
