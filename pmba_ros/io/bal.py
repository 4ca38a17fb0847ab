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
"""Read and write "Bundle Adjustment in the Large" (BAL) problem files.

File layout (SOURCES.md §1): a header ``nc np no``; ``no`` observation lines ``cam pt x y``;
then ``9 nc`` camera values ``rx ry rz tx ty tz f k1 k2`` and ``3 np`` point values, whitespace
separated (one value per line in the published files). Blank lines are ignored.

BAL model: ``P = R_bal X + t``, ``p = -P / P_z``, ``p' = f (1 + k1 |p|^2 + k2 |p|^4) p``. The
camera looks down -z, pixels are centred with +y up. Conversion to this package's convention
(camera x right, y down, z forward; see :mod:`pmba_ros.core.camera`):

=============  ======================================  ==================================
BAL            pmba_ros                                note
=============  ======================================  ==================================
R_bal (rx..)   R_wc = (diag(1,-1,-1) R_bal)^T          Rodrigues vector, world -> camera
t_bal          centers_w = -R_bal^T t_bal              camera centre
(x, y)         pixels = (x, -y)                        origin stays at the image centre
f, k1, k2      fx = fy = f, cx = cy = 0, k1, k2        held fixed by the solvers
=============  ======================================  ==================================

The radial model is symmetric, so ``project(R_wc^T (X - C))`` in this convention reproduces the
BAL projection exactly (including points behind the camera, which BAL projects too).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pmba_ros._numbers import python_only
from pmba_ros.core import so3
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.problem import make_problem
from pmba_ros.errors import FormatError, ProblemError
from pmba_ros.io.text import (
    check_bounded,
    check_numeric,
    check_pixels,
    float_values,
    integer_indices,
    MAX_COORDINATE,
    MAX_FOCAL,
    nonblank_lines,
)

if TYPE_CHECKING:
    from collections.abc import Callable
    from os import PathLike

    from pmba_ros._typing import FloatArray
    from pmba_ros.core.problem import BAProblem

logger = logging.getLogger(__name__)

__all__ = ['read_bal', 'write_bal']

_FLIP = np.diag([1.0, -1.0, -1.0])
"""BAL camera frame (x right, y up, z backward) -> ours (x right, y down, z forward)."""


def read_bal(path: str | PathLike[str]) -> BAProblem:
    """Read a BAL problem file and convert it to this package's conventions.

    Args:
        path: The BAL text file (``problem-*.txt``).

    Returns:
        The problem with the file's poses, intrinsics (fixed by convention), observations and
        points. Unobserved points and points seen only once are dropped by
        :func:`~pmba_ros.core.problem.make_problem`; ``feature_ids`` holds the BAL point index.

    Raises:
        FormatError: If the file is not a well-formed BAL file (the message names file, line
            and problem): bad header, truncated file, wrong value counts, non-numeric tokens,
            out-of-range or non-integer indices, non-finite values, a focal length not positive
            or beyond :data:`~pmba_ros.io.text.MAX_FOCAL`, a rotation or translation coordinate
            beyond :data:`~pmba_ros.io.text.MAX_COORDINATE`.
        OSError: If the file cannot be read.
    """
    path = Path(path)
    lines, line_no = nonblank_lines(path)
    if not lines:
        msg = f'{path}: empty file, expected a BAL header "n_cams n_points n_obs"'
        raise FormatError(msg)
    n_cams, n_points, n_obs = _parse_header(path, lines[0], line_no[0])
    if len(lines) - 1 < n_obs:
        last = line_no[-1]
        msg = (f'{path}:{last}: truncated file: header announces {n_obs} observation lines, '
               f'found {len(lines) - 1}')
        raise FormatError(msg)
    obs = _parse_observations(path, lines[1:1 + n_obs], line_no[1:1 + n_obs])
    obs_lines = line_no[1:1 + n_obs]
    cam_idx = integer_indices(path, obs[:, 0], n_cams, 'camera', obs_lines)
    pt_idx = integer_indices(path, obs[:, 1], n_points, 'point', obs_lines)
    check_pixels(path, obs[:, 2:], obs_lines)

    n_params = 9 * n_cams + 3 * n_points
    params = _parse_parameters(path, lines[1 + n_obs:], line_no[1 + n_obs:], n_params,
                               last_line=line_no[-1])
    cams = params[:9 * n_cams].reshape(n_cams, 9)
    points = params[9 * n_cams:].reshape(n_points, 3)
    _check_parameters(path, params, cams, lines[1 + n_obs:], line_no[1 + n_obs:])

    R_bal = so3.exp(cams[:, 0:3])
    R_wc = np.swapaxes(_FLIP @ R_bal, 1, 2)
    centers_w = -np.einsum('mji,mj->mi', R_bal, cams[:, 3:6])
    f = cams[:, 6]
    intrinsics = Intrinsics(f.copy(), f.copy(), np.zeros(n_cams), np.zeros(n_cams),
                            cams[:, 7].copy(), cams[:, 8].copy())
    pixels = np.stack([obs[:, 2], -obs[:, 3]], axis=1)
    try:
        problem = make_problem(R_wc, centers_w, intrinsics, cam_idx, pt_idx, pixels,
                               points_w=points, n_feats=n_points,
                               feature_ids=np.arange(n_points, dtype=np.int64))
    except ProblemError as err:
        msg = f'{path}: {err}'
        raise FormatError(msg) from err
    logger.info('read_bal %s: %d cameras, %d points, %d observations', path, problem.n_cams,
                problem.n_feats, problem.n_obs)
    return problem


def write_bal(path: str | PathLike[str], problem: BAProblem, R_wc: FloatArray | None = None,
              centers_w: FloatArray | None = None, points_w: FloatArray | None = None) -> None:
    """Write a problem (optionally with other poses / points) as a BAL file.

    Pixels are written relative to the principal point with +y up; when ``fy != fx`` the
    y coordinate is scaled by ``fx / fy`` so that the single BAL focal length ``f = fx`` stays
    exact (the radial model acts on normalized coordinates, so this holds with distortion too).
    Features are written in the problem's order (BAL point j is feature j).

    Args:
        path: Output file.
        problem: Supplies observations and intrinsics (and default poses / points).
        R_wc: Camera -> world rotations, shape (M, 3, 3); default ``problem.R_wc``.
        centers_w: Camera centres in the world frame, shape (M, 3); default
            ``problem.centers_w``.
        points_w: World points, shape (N, 3); default ``problem.points_w``.

    Raises:
        ProblemError: If the arrays have wrong shapes, or there are no points to write.
        OSError: If the file cannot be written.
    """
    R_wc = np.asarray(problem.R_wc if R_wc is None else R_wc, dtype=float)
    centers_w = np.asarray(problem.centers_w if centers_w is None else centers_w, dtype=float)
    if points_w is None:
        points_w = problem.points_w
    if points_w is None:
        msg = 'write_bal: the problem has no points; pass points_w (e.g. triangulated points)'
        raise ProblemError(msg)
    points_w = np.asarray(points_w, dtype=float)
    M, N = problem.n_cams, problem.n_feats
    if R_wc.shape != (M, 3, 3) or centers_w.shape != (M, 3) or points_w.shape != (N, 3):
        msg = (f'write_bal: expected R_wc ({M},3,3), centers_w ({M},3), points_w ({N},3); got '
               f'{R_wc.shape}, {centers_w.shape}, {points_w.shape}')
        raise ProblemError(msg)
    intr = problem.intrinsics
    R_bal = _FLIP @ np.swapaxes(R_wc, 1, 2)
    t_bal = -np.einsum('mij,mj->mi', R_bal, centers_w)
    cams = np.column_stack([so3.log(R_bal), t_bal, intr.fx, intr.k1, intr.k2])
    obs = problem.obs
    c = obs.cam_idx
    x_bal = obs.pixels[:, 0] - intr.cx[c]
    y_bal = -(obs.pixels[:, 1] - intr.cy[c]) * (intr.fx[c] / intr.fy[c])
    path = Path(path)
    with path.open('w', encoding='ascii') as fh:
        fh.write(f'{M} {N} {len(obs)}\n')
        table = np.empty(len(obs), dtype=[('c', np.int64), ('p', np.int64),
                                          ('x', float), ('y', float)])
        table['c'], table['p'], table['x'], table['y'] = c, obs.feat_idx, x_bal, y_bal
        np.savetxt(fh, table, fmt='%d %d %.17g %.17g')
        np.savetxt(fh, np.concatenate([cams.ravel(), points_w.ravel()]), fmt='%.17g')
    logger.info('write_bal %s: %d cameras, %d points, %d observations', path, M, N, len(obs))


def _parse_header(path: Path, line: str, line_no: int) -> tuple[int, int, int]:
    """Parse ``n_cams n_points n_obs``."""
    tokens = line.split()
    try:
        counts = [] if python_only(line) else [int(t) for t in tokens]
    except ValueError:
        counts = []
    if len(tokens) != 3 or len(counts) != 3 or min(counts) < 0 or counts[0] == 0:
        shown = ' '.join(tokens[:6]) + (f' ... ({len(tokens)} values)' if len(tokens) > 6 else '')
        msg = (f'{path}:{line_no}: bad header {shown!r}, expected three non-negative '
               f'integers "n_cams n_points n_obs" with n_cams > 0')
        raise FormatError(msg)
    return counts[0], counts[1], counts[2]


def _parse_observations(path: Path, lines: list[str], line_no: list[int]) -> FloatArray:
    """Parse observation lines ``cam pt x y`` into an (n_obs, 4) array."""
    if not lines:
        return np.zeros((0, 4))
    try:
        obs = np.loadtxt(lines, dtype=float, ndmin=2, comments=None)
    except ValueError:
        obs = None
    if obs is None or obs.shape != (len(lines), 4):
        for s, n in zip(lines, line_no, strict=True):
            tokens = s.split()
            check_numeric(path, tokens, n)
            if len(tokens) != 4:
                msg = (f'{path}:{n}: observation line has {len(tokens)} values, '
                       f'expected 4 (cam pt x y)')
                raise FormatError(msg)
        msg = f'{path}: cannot parse the observation lines'  # pragma: no cover
        raise FormatError(msg)  # pragma: no cover
    return obs


def _parse_parameters(path: Path, lines: list[str], line_no: list[int], n_params: int,
                      last_line: int) -> FloatArray:
    """Parse the camera and point values that follow the observations (exactly n_params)."""
    values = float_values(path, lines, line_no)
    if values.size < n_params:
        msg = (f'{path}:{last_line}: truncated file: expected {n_params} camera and point '
               f'values after the observations, found {values.size}')
        raise FormatError(msg)
    if values.size > n_params:
        where = _value_lines(lines, line_no)[n_params]
        msg = (f'{path}:{where}: unexpected extra values: expected {n_params} camera and point '
               f'values after the observations, found {values.size}')
        raise FormatError(msg)
    return values


def _check_parameters(path: Path, params: FloatArray, cams: FloatArray, lines: list[str],
                      line_no: list[int]) -> None:
    """Refuse non-finite values, and absurd cameras (focal length, distortion, pose) and points.

    The translation's norm is the camera centre's distance from the origin; beyond
    :data:`~pmba_ros.io.text.MAX_COORDINATE` the residuals of an XYZ or IDP solve stay finite
    but meaningless (such a solve reported a converged answer), while PMBA's overflow: refused
    here, every parameterization fails alike, naming the camera and line. A rotation vector
    beyond the same bound has an angle whose square overflows (numpy warnings, then a pose
    refused without its line).
    """
    f = cams[:, 6]
    far = np.any(np.abs(cams[:, 0:6]) > MAX_COORDINATE, axis=1)

    def where(first: int, size: int, what: str) -> Callable[[int, int], str]:
        return lambda k, j: (f'{path}:{_value_lines(lines, line_no)[first + size * k + j]}: '
                             f'{what} {k}')

    if np.all(np.isfinite(params)) and np.all((f > 0) & (f <= MAX_FOCAL)) and not far.any():
        # Distortion and points overflowed as a focal length does, or the XYZ solve of a
        # point of 1e300 reported a converged answer with the point where it was.
        check_bounded(cams[:, 7:9], MAX_FOCAL, 'distortion coefficient', where(7, 9, 'camera'))
        check_bounded(params[cams.size:].reshape(-1, 3), MAX_COORDINATE, 'coordinate',
                      where(cams.size, 3, 'point'))
        return
    param_lines = _value_lines(lines, line_no)
    bad = np.flatnonzero(~np.isfinite(params))
    if bad.size:
        msg = f'{path}:{param_lines[bad[0]]}: non-finite parameter value'
        raise FormatError(msg)
    i = int(np.flatnonzero((f <= 0) | (f > MAX_FOCAL) | far)[0])
    if far[i]:
        j = int(np.argmax(np.abs(cams[i, 0:6])))
        what = 'rotation vector' if j < 3 else 'translation'
        msg = (f'{path}:{param_lines[9 * i + j]}: camera {i} has {what} coordinate '
               f'{cams[i, j]:g} beyond {MAX_COORDINATE:g}')
    elif f[i] <= 0:
        msg = (f'{path}:{param_lines[9 * i + 6]}: camera {i} has non-positive focal length '
               f'{f[i]:g}')
    else:
        msg = (f'{path}:{param_lines[9 * i + 6]}: camera {i} has focal length {f[i]:g} beyond '
               f'{MAX_FOCAL:g} px')
    raise FormatError(msg)


def _value_lines(lines: list[str], line_no: list[int]) -> list[int]:
    """Return the line number of every whitespace-separated value in ``lines``."""
    out: list[int] = []
    for s, n in zip(lines, line_no, strict=True):
        out.extend([n] * len(s.split()))
    return out
