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
"""Read and write Bundler ``bundle.out`` files (v0.3).

Layout: an optional ``# Bundle file v0.3`` line, ``num_cameras num_points``, then per camera
``f k1 k2``, three rows of R and ``t``; then per point its position ``x y z``, colour
``r g b`` and view list ``n  cam key x y  cam key x y ...``. Whitespace and line breaks are
free. A camera with f = 0 was not registered by Bundler: it and its observations are left out
of the problem and written back unchanged.

Bundler's camera model is BAL's (:mod:`pmba_ros.io.bal`): ``P = R X + t``, ``p = -P / P_z``,
``p' = f (1 + k1 |p|^2 + k2 |p|^4) p``, the camera looks down -z, image coordinates are
relative to the image centre with +y up. The conversion is the same:

=============  ======================================  ==================================
Bundler        pmba_ros                                note
=============  ======================================  ==================================
R, t           R_wc = (diag(1,-1,-1) R)^T, C = -R^T t
(x, y)         pixels = (x, -y)                        origin stays at the image centre
f, k1, k2      fx = fy = f, cx = cy = 0, k1, k2        held fixed by the solvers
=============  ======================================  ==================================

Format reference: the Bundler v0.3 manual ("Output format").
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pmba_ros.core import so3
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.problem import make_problem
from pmba_ros.errors import FormatError, ProblemError
from pmba_ros.io.text import (
    check_bounded,
    float_values,
    MAX_COORDINATE,
    MAX_FOCAL,
    MAX_PIXEL,
    utf8_text,
    value_line,
)

if TYPE_CHECKING:
    from collections.abc import Callable
    from os import PathLike

    from pmba_ros._typing import BoolArray, FloatArray, IntArray
    from pmba_ros.core.problem import BAProblem

logger = logging.getLogger(__name__)

__all__ = ['BundlerModel', 'read_bundler', 'to_problem', 'updated', 'write_bundler']

_FLIP = np.diag([1.0, -1.0, -1.0])
_HEADER = '# Bundle file v0.3'


@dataclass(frozen=True, eq=False)
class BundlerModel:
    """The contents of a bundle file.

    Attributes:
        cameras: Per camera ``f k1 k2``, R (row-major) and t: shape (C, 15).
        xyz: Point positions (N, 3).
        rgb: Point colours (N, 3) (integers as stored).
        view_offsets: CSR offsets (N+1,) into the view arrays.
        view_cam: Camera of each view (V,).
        view_key: Feature (SIFT key) index of each view in its image (V,).
        view_xy: Image coordinates of each view (V, 2), centred, +y up.
    """

    cameras: FloatArray
    xyz: FloatArray
    rgb: IntArray
    view_offsets: IntArray
    view_cam: IntArray
    view_key: IntArray
    view_xy: FloatArray


def read_bundler(path: str | PathLike[str]) -> BundlerModel:
    """Read a Bundler v0.3 file.

    Raises:
        FormatError: On a malformed file (the file, and what was expected where).
    """
    path = Path(path)
    text = utf8_text(path)
    first, _, rest = text.partition('\n')
    first_line = 2
    if not first.lstrip().startswith('#'):
        rest, first_line = text, 1
    elif 'v0.3' not in first:
        msg = f'{path}:1: unsupported header {first.strip()!r}, expected {_HEADER!r}'
        raise FormatError(msg)
    lines = rest.splitlines()
    values = float_values(path, lines, range(first_line, first_line + len(lines)))
    if values.size < 2 or not np.all(_whole(values[:2])):
        msg = f'{path}: expected "num_cameras num_points" after the header'
        raise FormatError(msg)
    n_cams, n_points = int(values[0]), int(values[1])
    if n_cams < 0 or n_points < 0:
        msg = f'{path}: negative count in "num_cameras num_points" = "{n_cams} {n_points}"'
        raise FormatError(msg)
    pos = 2 + 15 * n_cams
    if values.size < pos:
        msg = f'{path}: truncated file: {n_cams} cameras need {15 * n_cams} values'
        raise FormatError(msg)
    # Every point takes at least 7 values: a damaged count is refused before the point
    # arrays are allocated (1e10 points asked for 224 GiB).
    if values.size - pos < 7 * n_points:
        msg = (f'{path}: truncated file: {n_points} points need at least {7 * n_points} '
               f'values after the cameras, found {values.size - pos}')
        raise FormatError(msg)
    cameras = values[2:pos].reshape(n_cams, 15)
    xyz = np.empty((n_points, 3))
    rgb = np.empty((n_points, 3))   # as read: made integers once checked
    counts = np.empty(n_points, dtype=np.int64)
    starts = np.empty(n_points, dtype=np.int64)
    views = []
    for j in range(n_points):
        if values.size < pos + 7:
            msg = f'{path}: truncated file in point {j} of {n_points}'
            raise FormatError(msg)
        starts[j] = pos
        xyz[j] = values[pos:pos + 3]
        rgb[j] = values[pos + 3:pos + 6]
        count = values[pos + 6]
        # A fractional count read as its integer part misaligned every later point (the
        # error then named the wrong point); NaN or inf would not convert at all.
        if not _whole(count):
            msg = f'{path}: point {j}: view count {count:g} is not a whole number'
            raise FormatError(msg)
        n = int(count)
        end = pos + 7 + 4 * n
        if n < 0 or values.size < end:
            msg = f'{path}: point {j}: view list of {n} views is truncated or invalid'
            raise FormatError(msg)
        views.append(values[pos + 7:end].reshape(n, 4))
        counts[j] = n
        pos = end
    if values.size != pos:
        msg = f'{path}: {values.size - pos} unexpected values after the last point'
        raise FormatError(msg)
    _check_magnitudes(path, lambda index: value_line(rest, index, first_line), cameras, xyz,
                      starts)
    v = np.concatenate(views) if views else np.zeros((0, 4))
    # Checked before the cast: casting a NaN or huge index warned (numpy) before the error.
    if not np.all((v[:, 0] >= 0) & (v[:, 0] < n_cams) & _whole(v[:, 0])):
        msg = f'{path}: a view refers to a camera outside 0..{n_cams - 1}'
        raise FormatError(msg)
    cam = v[:, 0].astype(np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    _check_colours(path, rgb)
    _check_views(path, v, offsets)
    return BundlerModel(cameras, xyz, rgb.astype(np.int64), offsets, cam,
                        v[:, 1].astype(np.int64), v[:, 2:4].copy())


def _check_magnitudes(path: Path, line: Callable[[int], int], cameras: FloatArray,
                      xyz: FloatArray, starts: IntArray) -> None:
    """Refuse absurd focal lengths, distortion, translations and points, naming their line.

    Bounded as BAL's are (:data:`~pmba_ros.io.text.MAX_FOCAL`,
    :data:`~pmba_ros.io.text.MAX_COORDINATE`): beyond them the solve stopped at non-finite
    residuals of a camera index, or the XYZ solve reported a converged answer.

    Args:
        path: The file (for the message).
        line: The line of a value, by its index among the file's values.
        cameras: The cameras (C, 15), values 2 + 15 i on.
        xyz: The points (N, 3).
        starts: Index of each point's first value (N,).
    """
    def camera(i: int, j: int, first: int) -> str:
        return f'{path}:{line(2 + 15 * i + first + j)}: camera {i}'

    check_bounded(cameras[:, 0], MAX_FOCAL, 'focal length', lambda i, j: camera(i, j, 0))
    check_bounded(cameras[:, 1:3], MAX_FOCAL, 'distortion coefficient',
                  lambda i, j: camera(i, j, 1))
    check_bounded(cameras[:, 12:15], MAX_COORDINATE, 'translation coordinate',
                  lambda i, j: camera(i, j, 12))
    check_bounded(xyz, MAX_COORDINATE, 'coordinate',
                  lambda k, j: f'{path}:{line(int(starts[k]) + j)}: point {k}')


_MAX_KEY = 2 ** 31
"""Bound on a key's magnitude: Bundler's keys are C ints (indices into an image's keys)."""


def _check_colours(path: Path, rgb: FloatArray) -> None:
    """Refuse the first point whose colour is not three whole numbers in 0..255.

    As the COLMAP reader does: a damaged colour (NaN, negative, huge) was read as an
    arbitrary integer and written back with ``--out``.
    """
    bad = np.flatnonzero(~np.all((rgb >= 0) & (rgb <= 255) & _whole(rgb), axis=1))
    if bad.size:
        j = int(bad[0])
        msg = f'{path}: point {j}: colour {" ".join(f"{c:g}" for c in rgb[j])} is not in 0..255'
        raise FormatError(msg)


def _check_views(path: Path, views: FloatArray, offsets: IntArray) -> None:
    """Refuse the first view (camera, key, x, y) whose key or image coordinates are absurd.

    Keys must be C ints as Bundler writes them; a NaN or huge key was cast to an arbitrary
    integer and written back with ``--out``. Image coordinates are bounded as BAL's and
    COLMAP's pixels are (:data:`~pmba_ros.io.text.MAX_PIXEL`).
    """
    key, xy = views[:, 1], views[:, 2:4]
    bad_key = ~((np.abs(key) < _MAX_KEY) & _whole(key))
    bad_xy = ~np.all(np.abs(xy) <= MAX_PIXEL, axis=1)
    bad = np.flatnonzero(bad_key | bad_xy)
    if bad.size:
        k = int(bad[0])
        j = int(np.searchsorted(offsets, k, side='right')) - 1
        where = f'{path}: point {j}: view {k - int(offsets[j])} (camera {int(views[k, 0])})'
        what = (f'key {key[k]:g} is not a whole number of magnitude below 2^31' if bad_key[k]
                else f'image coordinates ({xy[k, 0]:g}, {xy[k, 1]:g}) are not finite or beyond '
                f'{MAX_PIXEL:g}')
        msg = f'{where}: {what}'
        raise FormatError(msg)


def _whole(values: FloatArray | float) -> BoolArray:
    """Return where ``values`` are finite whole numbers (counts, indices read as floats)."""
    return np.asarray(np.isfinite(values) & (np.floor(values) == values))


def to_problem(model: BundlerModel) -> tuple[BAProblem, IntArray]:
    """Return the BA problem of the registered cameras (f > 0) and their file indices.

    ``feature_ids`` are the point indices in the file.

    Raises:
        FormatError: If no camera is registered, a focal length is negative or not finite, a
            registered camera's R is not a rotation, or the data are inconsistent.
    """
    f_all = model.cameras[:, 0]
    # Bundler marks an unregistered camera by f = 0; a negative or non-finite f is no camera
    # at all, and leaving it out as unregistered would hide a damaged file.
    bad_f = np.flatnonzero(~(f_all >= 0))
    if bad_f.size:
        msg = (f'Bundler file: camera {int(bad_f[0])} has focal length {f_all[bad_f[0]]:g}; '
               'expected f > 0 (registered) or f = 0 (not registered)')
        raise FormatError(msg)
    registered = np.flatnonzero(f_all > 0)
    if registered.size == 0:
        msg = 'Bundler file: no registered camera (every focal length is 0)'
        raise FormatError(msg)
    new = np.full(model.cameras.shape[0], -1, dtype=np.int64)
    new[registered] = np.arange(registered.size)
    cams = model.cameras[registered]
    R = _rotations(cams[:, 3:12].reshape(-1, 3, 3), registered)
    t = cams[:, 12:15]
    R_wc = np.swapaxes(_FLIP @ R, 1, 2)
    centers = -np.einsum('mji,mj->mi', R, t)
    f = cams[:, 0]
    zero = np.zeros(registered.size)
    intr = Intrinsics(f.copy(), f.copy(), zero, zero.copy(), cams[:, 1].copy(),
                      cams[:, 2].copy())
    counts = np.diff(model.view_offsets)
    feat = np.repeat(np.arange(counts.size), counts)
    keep = new[model.view_cam] >= 0
    pixels = np.stack([model.view_xy[:, 0], -model.view_xy[:, 1]], axis=1)
    try:
        problem = make_problem(R_wc, centers, intr, new[model.view_cam[keep]], feat[keep],
                               pixels[keep], points_w=model.xyz, n_feats=counts.size)
    except ProblemError as err:
        msg = f'Bundler file: {err}'
        raise FormatError(msg) from err
    return problem, registered


_ROTATION_TOL = 1e-3
"""Largest accepted ``|R^T R - I|`` entry (or ``|det R - 1|``) of a stored rotation."""


def _rotations(R: FloatArray, file_cams: IntArray) -> FloatArray:
    """Return the stored rotations (C, 3, 3) projected onto SO(3), after checking them.

    The file stores R as nine printed numbers: orthonormal to their digits, which the
    projection restores. The solvers take R as a rotation and never re-orthonormalize it, so
    a matrix far from one (zeros, a scaled or mirrored matrix) would be solved as a wrong
    camera without a word: it is refused instead.

    Raises:
        FormatError: Naming the first registered camera whose R is not a (finite) rotation.
    """
    finite = np.all(np.isfinite(R), axis=(1, 2))
    safe = np.where(finite[:, None, None], R, 0.0)
    ortho_err = np.abs(np.swapaxes(safe, 1, 2) @ safe - np.eye(3)).max(axis=(1, 2))
    det_err = np.abs(np.linalg.det(safe) - 1.0)
    bad = np.flatnonzero(~finite | (ortho_err > _ROTATION_TOL) | (det_err > _ROTATION_TOL))
    if bad.size:
        k = int(bad[0])
        msg = (f'Bundler file: camera {int(file_cams[k])} has a rotation that is not a '
               f'rotation matrix (|R^T R - I| = {ortho_err[k]:.3g}, det R = '
               f'{np.linalg.det(safe[k]):.3g})' if finite[k] else
               f'Bundler file: camera {int(file_cams[k])} has a non-finite rotation')
        raise FormatError(msg)
    out: FloatArray = so3.project(R)
    return out


def updated(model: BundlerModel, cameras: IntArray, R_wc: FloatArray, centers_w: FloatArray,
            point_ids: IntArray, points_w: FloatArray) -> BundlerModel:
    """Return the model with new poses for file cameras ``cameras`` and new point positions.

    Non-finite points (PMBA points at infinity) keep their stored position.
    """
    R = _FLIP @ np.swapaxes(np.asarray(R_wc, dtype=float), 1, 2)
    t = -np.einsum('mij,mj->mi', R, centers_w)
    cams = model.cameras.copy()
    cams[cameras, 3:12] = R.reshape(-1, 9)
    cams[cameras, 12:15] = t
    xyz = model.xyz.copy()
    finite = np.all(np.isfinite(points_w), axis=1)
    xyz[np.asarray(point_ids)[finite]] = np.asarray(points_w)[finite]
    return replace(model, cameras=cams, xyz=xyz)


def write_bundler(path: str | PathLike[str], model: BundlerModel) -> None:
    """Write a model as a Bundler v0.3 file."""
    lines = [_HEADER, f'{model.cameras.shape[0]} {model.xyz.shape[0]}']
    for c in model.cameras:
        lines.append(' '.join(f'{v:.17g}' for v in c[0:3]))
        lines += [' '.join(f'{v:.17g}' for v in c[3 + 3 * r:6 + 3 * r]) for r in range(4)]
    for j in range(model.xyz.shape[0]):
        a, b = model.view_offsets[j], model.view_offsets[j + 1]
        lines.append(' '.join(f'{v:.17g}' for v in model.xyz[j]))
        lines.append(' '.join(str(int(v)) for v in model.rgb[j]))
        views = ' '.join(f'{int(c)} {int(k)} {x:.17g} {y:.17g}' for c, k, (x, y) in zip(
            model.view_cam[a:b], model.view_key[a:b], model.view_xy[a:b], strict=True))
        lines.append(f'{b - a} {views}'.rstrip())
    Path(path).write_text('\n'.join(lines) + '\n', encoding='utf-8')
