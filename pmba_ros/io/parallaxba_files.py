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
"""Read the text formats of the ParallaxBA datasets, and triangulate their features.

Formats (``Documentation_ParallaxBA.pdf`` §III; SOURCES.md §2):

- **Cam file**: one row per camera, ``alpha beta gamma Cx Cy Cz`` (Euler angles in radians and
  the camera centre). ``R = RX(gamma) RY(beta) RZ(alpha)`` maps world to camera (PDF eqs. 3-4)
  and ``[u v 1]^T ∝ K R (F - C)`` with the pixel origin at the top-left corner. Rows with 8
  values append ``fx fy`` of that camera; their pixels are relative to the principal point.
- **Feature file** (SBA style, ``*.pmba`` / ``Feature*.txt``): one line per feature,
  ``n  cam u v  cam u v ...`` with ``n`` observations and 0-based camera indices.
- **Calibration file** (``intrinsic*`` / ``cal*``): a 3x3 K (no skew, no distortion).
- **XYZ file** (optional): one initial world point ``X Y Z`` per feature line.

The element rotations (PDF eq. 4)::

    RZ(a) = [[ cos a, sin a, 0], [-sin a, cos a, 0], [0, 0, 1]]
    RY(b) = [[cos b, 0, -sin b], [0, 1, 0], [sin b, 0, cos b]]
    RX(g) = [[1, 0, 0], [0, cos g, sin g], [0, -sin g, cos g]]

The camera frame of the format is x right, y down, z forward, as in :mod:`pmba_ros.core.camera`,
so ``R_wc = R^T`` and ``centers_w = C`` directly.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
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
    plain_name,
)

if TYPE_CHECKING:
    from os import PathLike

    from pmba_ros._typing import FloatArray, IntArray
    from pmba_ros.core.problem import BAProblem

logger = logging.getLogger(__name__)

__all__ = ['euler_to_R_cw', 'read_parallaxba', 'triangulate_points']

_CAM_PATTERNS = ('cam*',)
_FEATURE_PATTERNS = ('*.pmba', 'feature*')
_K_PATTERNS = ('intrinsic*', 'cal*')
_XYZ_PATTERNS = ('xyz*',)


def euler_to_R_cw(angles_rad: FloatArray) -> FloatArray:
    """Return world -> camera rotations ``R = RX(gamma) RY(beta) RZ(alpha)``.

    Args:
        angles_rad: ``[alpha, beta, gamma]`` per camera (radians), shape (..., 3), in the Cam
            file's column order (alpha is the Z angle).

    Returns:
        Rotation matrices, shape (..., 3, 3).

    Raises:
        ValueError: If the last axis does not have length 3.

    References:
        ParallaxBA documentation, eqs. (3)-(4).
    """
    angles_rad = np.asarray(angles_rad, dtype=float)
    if angles_rad.shape[-1:] != (3,):
        msg = f'euler_to_R_cw: expected shape (..., 3), got {angles_rad.shape}'
        raise ValueError(msg)
    ca, sa = np.cos(angles_rad[..., 0]), np.sin(angles_rad[..., 0])
    cb, sb = np.cos(angles_rad[..., 1]), np.sin(angles_rad[..., 1])
    cg, sg = np.cos(angles_rad[..., 2]), np.sin(angles_rad[..., 2])
    one, zero = np.ones_like(ca), np.zeros_like(ca)

    def mat(rows: list[list[np.ndarray]]) -> FloatArray:
        return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)

    RZ = mat([[ca, sa, zero], [-sa, ca, zero], [zero, zero, one]])  # eq. (4)
    RY = mat([[cb, zero, -sb], [zero, one, zero], [sb, zero, cb]])  # eq. (4)
    RX = mat([[one, zero, zero], [zero, cg, sg], [zero, -sg, cg]])  # eq. (4)
    return RX @ RY @ RZ  # eq. (3)


def read_parallaxba(directory_or_cam_file: str | PathLike[str],
                    feature_file: str | PathLike[str] | None = None,
                    k_file: str | PathLike[str] | None = None, *,
                    xyz_file: str | PathLike[str] | None = None) -> BAProblem:
    """Read a ParallaxBA dataset (Cam, feature, calibration and optional XYZ files).

    Files not given are looked for in the directory (or the Cam file's directory), by
    case-insensitive name: ``Cam*`` (Cam file), ``*.pmba`` or ``Feature*`` (features),
    ``intrinsic*`` or ``cal*`` (K), ``XYZ*`` (points, optional).

    Args:
        directory_or_cam_file: The dataset directory, or the Cam file.
        feature_file: The feature file; default: found in the directory.
        k_file: The 3x3 calibration file; default: found in the directory. Not needed when
            the Cam file has 8 columns (per-camera ``fx fy``).
        xyz_file: Initial points, one per feature line; default: an ``XYZ*`` file in the
            directory if there is one, else none.

    Returns:
        The problem (no distortion). ``points_w`` is None without an XYZ file (use
        :func:`triangulate_points`). ``feature_ids`` holds the 0-based feature line index.

    Raises:
        FormatError: If a file is missing, ambiguous or malformed (naming file and line).
        OSError: If a file cannot be read.
    """
    given = Path(directory_or_cam_file)
    if given.is_dir():
        directory = given
        cam_path = _find_required(directory, _CAM_PATTERNS, 'Cam')
    else:
        directory = given.parent
        cam_path = given
    feat_path = (Path(feature_file) if feature_file is not None
                 else _find_required(directory, _FEATURE_PATTERNS, 'feature'))
    cams, cam_lines = _read_table(cam_path, (6, 8), 'alpha beta gamma Cx Cy Cz [fx fy]')
    n_cams = cams.shape[0]
    if n_cams == 0:
        msg = f'{cam_path}: no cameras'
        raise FormatError(msg)
    if cams.shape[1] == 8:
        fx, fy = cams[:, 6].copy(), cams[:, 7].copy()
        bad = np.flatnonzero(~((fx > 0) & (fy > 0)))
        if bad.size:
            msg = f'{cam_path}:{cam_lines[bad[0]]}: focal lengths must be positive'
            raise FormatError(msg)
        # Beyond it the squared residuals overflow: the solve stopped at non-finite residuals
        # naming a camera index, not the line.
        check_bounded(cams[:, 6:8], MAX_FOCAL, 'focal length',
                      lambda k, _j: f'{cam_path}:{cam_lines[k]}: camera {k}')
        intrinsics = Intrinsics(fx, fy, np.zeros(n_cams), np.zeros(n_cams),
                                np.zeros(n_cams), np.zeros(n_cams))
        if k_file is not None:
            logger.info('read_parallaxba: %s has per-camera focal lengths; ignoring %s',
                        cam_path, k_file)
    else:
        k_path = (Path(k_file) if k_file is not None
                  else _find_required(directory, _K_PATTERNS, 'calibration (K)'))
        K = _read_k(k_path)
        intrinsics = Intrinsics.uniform(n_cams, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    R_cw = euler_to_R_cw(cams[:, 0:3])
    centers_w = cams[:, 3:6].copy()
    # Beyond it the triangulation's squared spreads overflow: a LinAlgError from eigh before.
    far = np.flatnonzero(np.any(np.abs(centers_w) > MAX_COORDINATE, axis=1))
    if far.size:
        msg = (f'{cam_path}:{cam_lines[far[0]]}: camera centre coordinate '
               f'{np.max(np.abs(centers_w[far[0]])):g} beyond {MAX_COORDINATE:g}')
        raise FormatError(msg)

    cam_idx, feat_idx, pixels, n_feats = _read_features(feat_path, n_cams)
    if xyz_file is not None:
        xyz_path: Path | None = Path(xyz_file)
    elif feature_file is None:  # fully automatic: an XYZ file beside the others is used
        xyz_path = _find(directory, _XYZ_PATTERNS, 'XYZ')
    else:
        xyz_path = None
    points_w = None
    if xyz_path is not None:
        points_w, xyz_lines = _read_table(xyz_path, (3,), 'X Y Z')
        # The XYZ solve of a point of 1e300 reported a converged answer with it where it was.
        check_bounded(points_w, MAX_COORDINATE, 'coordinate',
                      lambda k, _j: f'{xyz_path}:{xyz_lines[k]}: point {k}')
        if points_w.shape[0] != n_feats:
            msg = (f'{xyz_path}: {points_w.shape[0]} points for {n_feats} features in '
                   f'{feat_path}')
            raise FormatError(msg)
    try:
        problem = make_problem(np.swapaxes(R_cw, 1, 2), centers_w, intrinsics, cam_idx,
                               feat_idx, pixels, points_w=points_w, n_feats=n_feats)
    except ProblemError as err:
        msg = f'{feat_path}: {err}'
        raise FormatError(msg) from err
    logger.info('read_parallaxba %s: %d cameras, %d features, %d observations', directory,
                problem.n_cams, problem.n_feats, problem.n_obs)
    return problem


def triangulate_points(problem: BAProblem, *, max_range_rel: float = 1e8) -> FloatArray:
    """Triangulate every feature from all its observations (linear DLT on unit bearings).

    For each feature j the points are normalized by the mean ``c_j`` and RMS spread ``s_j`` of
    its observing camera centres, then the smallest eigenvector of
    ``A_j = sum_k P_k^T (I - v_k v_k^T) P_k`` with ``P_k = [R_k | R_k (c_j - C_k) / s_j]``
    (``R_k`` world -> camera, ``v_k`` the unit bearing) is the homogeneous point. All features
    are solved at once (batched 4x4 eigen-decompositions).

    Points at or near infinity (no parallax) are placed along the mean observed ray at
    ``max_range_rel * s_j`` from ``c_j``; features whose observing cameras share one centre
    (no baseline, ``s_j = 0``) are placed at ``max_range_rel`` (world units) along that ray.

    Args:
        problem: Poses and observations (the bearings are used, so distortion is removed).
        max_range_rel: Largest distance of a point from ``c_j``, in units of ``s_j``.

    Returns:
        World points, shape (N, 3), in the problem's feature order.

    Raises:
        ValueError: If ``max_range_rel`` is not positive.
    """
    if not max_range_rel > 0:
        msg = f'triangulate_points: max_range_rel must be positive, got {max_range_rel}'
        raise ValueError(msg)
    obs = problem.obs
    N = problem.n_feats
    if N == 0:
        return np.zeros((0, 3))
    offsets = problem.feature_offsets()[:-1]
    counts = np.diff(problem.feature_offsets()).astype(float)
    R_cw = np.swapaxes(problem.R_wc, 1, 2)[obs.cam_idx]  # (K, 3, 3)
    C = problem.centers_w[obs.cam_idx]  # (K, 3)
    c = np.add.reduceat(C, offsets, axis=0) / counts[:, None]  # (N, 3)
    d = C - c[obs.feat_idx]
    s = np.sqrt(np.add.reduceat(np.sum(d * d, axis=1), offsets) / counts)
    no_baseline = s <= 1e-12 * (1.0 + np.linalg.norm(c, axis=1))
    s = np.where(no_baseline, 1.0, s)
    P = np.empty((len(obs), 3, 4))
    P[:, :, :3] = R_cw
    P[:, :, 3] = np.einsum('kij,kj->ki', R_cw, -d / s[obs.feat_idx][:, None])
    v = obs.bearings_c
    proj = np.eye(3) - v[:, :, None] * v[:, None, :]  # (K, 3, 3)
    A = np.add.reduceat(np.swapaxes(P, 1, 2) @ proj @ P, offsets, axis=0)  # (N, 4, 4)
    _, vecs = np.linalg.eigh(A)
    X = vecs[:, :, 0]
    # Orient the direction part along the mean observed world ray (fixes the eigenvector sign).
    rays_w = np.einsum('kji,kj->ki', R_cw, v)
    mean_ray = np.add.reduceat(rays_w, offsets, axis=0)
    X = X * np.where(np.sum(X[:, :3] * mean_ray, axis=1) < 0, -1.0, 1.0)[:, None]
    w = X[:, 3]
    limit = np.linalg.norm(X[:, :3], axis=1) / max_range_rel
    far = np.abs(w) < limit
    w = np.where(far, np.maximum(limit, 1e-300), w)
    points: FloatArray = c + s[:, None] * X[:, :3] / w[:, None]
    # All observing centres coincide: any depth fits (and X = c is a spurious DLT solution).
    far |= no_baseline
    ray_dir = mean_ray / np.maximum(np.linalg.norm(mean_ray, axis=1, keepdims=True), 1e-300)
    points = np.where(no_baseline[:, None], c + max_range_rel * ray_dir, points)
    depth = np.einsum('ki,ki->k', R_cw[:, 2], points[obs.feat_idx] - C)
    n_behind = int(np.count_nonzero(np.bincount(obs.feat_idx, weights=depth <= 0,
                                                minlength=N)))
    logger.info('triangulate_points: %d features, %d at infinity (clamped), %d behind a camera',
                N, int(np.sum(far)), n_behind)
    return points


def _find_required(directory: Path, patterns: tuple[str, ...], what: str) -> Path:
    """Return the one file in ``directory`` matching a pattern; FormatError if there is none."""
    found = _find(directory, patterns, what)
    if found is None:
        msg = f'{directory}: no {what} file (expected a name like {" or ".join(patterns)})'
        raise FormatError(msg)
    return found


def _find(directory: Path, patterns: tuple[str, ...], what: str) -> Path | None:
    """Return the one file in ``directory`` whose lower-case name matches a pattern, or None."""
    if not directory.is_dir():
        msg = f'{directory}: not a directory (looking for the {what} file)'
        raise FormatError(msg)
    found: set[Path] = set()
    for entry in directory.iterdir():
        name = plain_name(entry).lower()
        if entry.is_file() and any(Path(name).match(p) for p in patterns):
            found.add(entry)
    if len(found) > 1:
        names = ', '.join(sorted(p.name for p in found))
        msg = f'{directory}: several {what} files ({names}); pass the one to use'
        raise FormatError(msg)
    return found.pop() if found else None


def _read_table(path: Path, n_cols: tuple[int, ...],
                layout: str) -> tuple[FloatArray, list[int]]:
    """Read a table of finite numbers with one of ``n_cols`` columns (same on every row)."""
    lines, numbers = nonblank_lines(path)
    if not lines:
        msg = f'{path}: empty file, expected rows "{layout}"'
        raise FormatError(msg)
    try:
        table = np.loadtxt(lines, dtype=float, ndmin=2, comments=None)
    except ValueError:
        table = None
    width = len(lines[0].split())
    if table is None or table.shape[1] not in n_cols:
        for s, n in zip(lines, numbers, strict=True):
            tokens = s.split()
            check_numeric(path, tokens, n)
            if len(tokens) not in n_cols or len(tokens) != width:
                expected = ' or '.join(str(k) for k in n_cols)
                msg = f'{path}:{n}: row has {len(tokens)} values, expected {expected} ({layout})'
                raise FormatError(msg)
        expected = ' or '.join(str(k) for k in n_cols)
        msg = f'{path}:{numbers[0]}: rows have {width} values, expected {expected} ({layout})'
        raise FormatError(msg)
    bad = np.flatnonzero(~np.all(np.isfinite(table), axis=1))
    if bad.size:
        msg = f'{path}:{numbers[bad[0]]}: non-finite value'
        raise FormatError(msg)
    return table, numbers


def _read_k(path: Path) -> FloatArray:
    """Read a 3x3 calibration matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``."""
    lines, numbers = nonblank_lines(path)
    values = float_values(path, lines, numbers)
    if values.size != 9:
        bad_rows = [n for s, n in zip(lines, numbers, strict=True) if len(s.split()) != 3]
        where = bad_rows[0] if bad_rows else (numbers[-1] if numbers else 1)
        msg = f'{path}:{where}: expected 9 values (a 3x3 K), found {values.size}'
        raise FormatError(msg)
    K = values.reshape(3, 3)
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        msg = f'{path}: K must be finite with positive focal lengths, got {K.tolist()}'
        raise FormatError(msg)
    if not np.allclose(K[2], [0.0, 0.0, 1.0]) or K[1, 0] != 0.0:
        msg = f'{path}: K must be upper triangular with last row 0 0 1, got {K.tolist()}'
        raise FormatError(msg)
    if abs(K[0, 1]) > 1e-9 * K[0, 0]:
        msg = f'{path}: skew K[0,1] = {K[0, 1]:g} is not supported'
        raise FormatError(msg)
    # Bounded as the Cam file's focal lengths are; the values may share or split lines.
    value_lines = np.repeat(numbers, [len(s.split()) for s in lines])
    check_bounded(np.diag(K)[:2], MAX_FOCAL, 'focal length',
                  lambda k, _j: f'{path}:{value_lines[4 * k]}: K')
    check_bounded(K[:2, 2], MAX_FOCAL, 'principal point coordinate',
                  lambda k, _j: f'{path}:{value_lines[3 * k + 2]}: K')
    return K


def _read_features(path: Path, n_cams: int) -> tuple[IntArray, IntArray, FloatArray, int]:
    """Parse a feature file; return cam_idx (K,), feat_idx (K,), pixels (K, 2), n_feats."""
    lines, numbers = nonblank_lines(path)
    if not lines:
        msg = f'{path}: empty feature file'
        raise FormatError(msg)
    counts = np.array([len(s.split()) for s in lines], dtype=np.int64)
    values = float_values(path, lines, numbers)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    n_obs = values[starts]
    bad = ~np.isfinite(n_obs) | (n_obs != np.round(n_obs)) | (n_obs < 0) | (
        counts != 1 + 3 * np.where(np.isfinite(n_obs), n_obs, 0))
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        msg = (f'{path}:{numbers[i]}: feature line "n cam u v ..." announces {n_obs[i]:g} '
               f'observations but has {counts[i]} values (expected 1 + 3 n)')
        raise FormatError(msg)
    n_per = n_obs.astype(np.int64)
    triples = np.delete(values, starts).reshape(-1, 3)
    line_of = np.repeat(np.arange(len(lines)), n_per)
    cam_idx = integer_indices(path, triples[:, 0], n_cams, 'camera',
                              np.asarray(numbers)[line_of].tolist())
    check_pixels(path, triples[:, 1:], np.asarray(numbers)[line_of].tolist())
    return cam_idx, line_of.astype(np.int64), triples[:, 1:].copy(), len(lines)
