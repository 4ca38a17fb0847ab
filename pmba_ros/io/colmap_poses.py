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
"""COLMAP's poses: world -> camera quaternions (w, x, y, z) and translations, and ours."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from pmba_ros.errors import FormatError
from pmba_ros.io.text import check_bounded, MAX_COORDINATE

if TYPE_CHECKING:
    from collections.abc import Sequence

    from pmba_ros._typing import FloatArray

__all__ = ['R_to_quat', 'check_poses', 'check_translation', 'poses_from_colmap',
           'poses_to_colmap', 'quat_to_R']


def check_poses(q: FloatArray, t: FloatArray, names: Sequence[str]) -> None:
    """Refuse the first pose whose quaternion (M, 4) or translation (M, 3) is not one.

    COLMAP normalizes a stored quaternion: any finite one but zero is a rotation.

    Raises:
        FormatError: Naming the pose (``names[k]``, e.g. 'image 12') and its values.
    """
    with np.errstate(over='ignore'):
        norm = np.linalg.norm(q, axis=1)
    bad = ~(np.isfinite(norm) & (norm > 0) & np.isfinite(t).all(axis=1))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        msg = (f'COLMAP {names[k]}: its pose (quaternion {" ".join(f"{v:g}" for v in q[k])}, '
               f'translation {" ".join(f"{v:g}" for v in t[k])}) is not a rotation and a '
               'translation')
        raise FormatError(msg)


def check_translation(where: str, tvec: FloatArray) -> None:
    """Refuse a translation coordinate beyond :data:`~pmba_ros.io.text.MAX_COORDINATE`.

    ``where`` names the file, line and record. The translation's norm is the camera centre's
    distance from the origin (or the offset of a rig's camera): beyond it the solve stopped at
    non-finite residuals, and the XYZ solve reported a converged answer.
    """
    check_bounded(tvec[None], MAX_COORDINATE, 'translation coordinate', lambda _k, _j: where)


def quat_to_R(q: FloatArray) -> FloatArray:
    """Return rotation matrices (M, 3, 3) of unit quaternions (M, 4) in (w, x, y, z)."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def R_to_quat(R: FloatArray) -> FloatArray:
    """Return unit quaternions (M, 4) (w, x, y, z), w >= 0, of rotations (M, 3, 3)."""
    # The largest of the four squared components is computed directly (stable everywhere).
    tr = np.trace(R, axis1=1, axis2=2)
    d = np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1)
    k = np.argmax(d, axis=1)
    q = np.empty((R.shape[0], 4))
    s = np.sqrt(np.maximum(1.0 + 2.0 * d[np.arange(R.shape[0]), k] - tr, 1e-300)) * 2.0
    r = R
    cases = [
        (k == 0, [s / 4, (r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                  (r[:, 1, 0] - r[:, 0, 1]) / s]),
        (k == 1, [(r[:, 2, 1] - r[:, 1, 2]) / s, s / 4, (r[:, 0, 1] + r[:, 1, 0]) / s,
                  (r[:, 0, 2] + r[:, 2, 0]) / s]),
        (k == 2, [(r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 0, 1] + r[:, 1, 0]) / s, s / 4,
                  (r[:, 1, 2] + r[:, 2, 1]) / s]),
        (k == 3, [(r[:, 1, 0] - r[:, 0, 1]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s,
                  (r[:, 1, 2] + r[:, 2, 1]) / s, s / 4]),
    ]
    for mask, comps in cases:
        q[mask] = np.stack(comps, axis=1)[mask]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(q[:, :1] < 0, -q, q)


def poses_from_colmap(q: FloatArray, t: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return (R_wc (M, 3, 3), centres (M, 3)) of COLMAP's world -> camera poses (q, t)."""
    R_wc = np.swapaxes(quat_to_R(np.reshape(q, (-1, 4))), 1, 2)
    return R_wc, -np.einsum('mij,mj->mi', R_wc, np.reshape(t, (-1, 3)))


def poses_to_colmap(R_wc: FloatArray, centers_w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return COLMAP's (q (M, 4), t (M, 3)) of camera -> world rotations and centres."""
    R_cw = np.swapaxes(np.asarray(R_wc, dtype=float), 1, 2)
    q = R_to_quat(R_cw) if R_cw.shape[0] else np.zeros((0, 4))
    return q, -np.einsum('mij,mj->mi', R_cw, centers_w)
