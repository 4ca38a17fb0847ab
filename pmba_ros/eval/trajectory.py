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
"""Timestamped trajectories and their text formats: TUM, EuRoC CSV and KITTI.

Formats (``/work/shared/data/SOURCES.md`` §4):

==========  ==================================================  ============================
format      one line per pose                                   quaternion order
==========  ==================================================  ============================
TUM         ``t tx ty tz qx qy qz qw`` (space separated, s)     x, y, z, w
EuRoC CSV   ``t_ns, px, py, pz, qw, qx, qy, qz[, ...]`` (>= 8)  **w first**
KITTI       ``r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz``    (rotation matrix, no stamps)
==========  ==================================================  ============================

A header naming the columns decides the quaternion order and, where it gives one, the stamp
unit (:mod:`pmba_ros.eval.layout`). Lines that are empty or start with ``#`` are skipped in
every format, and so is a first line with no number (a header without ``#``). Every reader raises
:class:`~pmba_ros.errors.FormatError` naming the file, the line and the problem; a file that
cannot be opened is reported the same way. Parsing checks the column count per line, then
converts all values in one vectorized call; the slow per-line scan only runs to locate an
error.
"""

from __future__ import annotations

from dataclasses import dataclass
import logging
from pathlib import Path
from typing import NoReturn, TYPE_CHECKING

import numpy as np
from pmba_ros._numbers import is_number, python_only
from pmba_ros._typing import FloatArray
from pmba_ros.core import so3
from pmba_ros.errors import EvaluationError, FormatError
from pmba_ros.eval.layout import data_lines, detect_layout, Layout

if TYPE_CHECKING:
    from collections.abc import Sequence
    import os

logger = logging.getLogger(__name__)

FORMATS = ('auto', 'tum', 'euroc', 'kitti')
"""Values accepted by the ``fmt`` argument of :func:`read_trajectory`."""

_ROTATION_TOL = 1e-3
"""Largest accepted ``|R^T R - I|`` entry of a KITTI rotation before projection onto SO(3)."""

_MIN_QUAT_NORM = 1e-6
"""Smallest quaternion norm accepted: below it the quaternion is a placeholder, not a rotation."""

MAX_TIME_S = 2.0 ** 31
"""Largest KITTI time magnitude accepted, s: the bags written from these times
(``pmba import-tracks``) stamp messages with them, whose seconds are an int32; beyond it the
stamps overflowed and writing failed deep in serialization."""

MAX_COORDINATE = 1e150
"""Largest position coordinate magnitude accepted, m (as ``io.text.MAX_COORDINATE`` for
camera centres): the squares that the alignment and the errors sum stay finite up to it."""


def _readonly(arr: np.ndarray) -> np.ndarray:
    """Return a C-contiguous float64 copy of ``arr`` that cannot be written to."""
    out = np.array(arr, dtype=np.float64, order='C', copy=True)
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A sequence of timestamped poses (body or camera -> world); N = number of poses.

    The arrays are copied on construction and made read-only, so a trajectory can be shared
    freely: every operation returns a new object.

    Attributes:
        stamps_s: Timestamps in seconds, shape (N,).
        positions_xyz: Positions of the body in the world frame, shape (N, 3).
        R_wc: Body -> world rotations, shape (N, 3, 3).
        index_stamps: The stamps are pose numbers 0, 1, 2, ..., not times (a KITTI file read
            without its times): they match another trajectory's stamps only if those are
            pose numbers too (:func:`pmba_ros.eval.metrics.associate` checks this).
        stamps_note: How the stamps were read from a file, for messages about them, e.g.
            ``'read as nanoseconds (EuRoC CSV)'`` ('' if not read from a TUM or EuRoC file).
    """

    stamps_s: FloatArray
    positions_xyz: FloatArray
    R_wc: FloatArray
    index_stamps: bool = False
    stamps_note: str = ''

    def __post_init__(self) -> None:
        """Validate shapes and finiteness and freeze copies of the arrays.

        Raises:
            EvaluationError: If the shapes disagree or a value is not finite.
        """
        stamps = np.asarray(self.stamps_s, dtype=np.float64)
        positions = np.asarray(self.positions_xyz, dtype=np.float64)
        rotations = np.asarray(self.R_wc, dtype=np.float64)
        n = stamps.shape[0] if stamps.ndim == 1 else -1
        if (stamps.ndim != 1 or positions.shape != (n, 3) or rotations.shape != (n, 3, 3)):
            msg = (f'Trajectory needs stamps_s (N,), positions_xyz (N, 3) and R_wc (N, 3, 3); '
                   f'got {stamps.shape}, {positions.shape} and {rotations.shape}')
            raise EvaluationError(msg)
        for name, arr in (('stamps_s', stamps), ('positions_xyz', positions),
                          ('R_wc', rotations)):
            if not np.all(np.isfinite(arr)):
                msg = f'Trajectory {name} contains non-finite values'
                raise EvaluationError(msg)
        object.__setattr__(self, 'stamps_s', _readonly(stamps))
        object.__setattr__(self, 'positions_xyz', _readonly(positions))
        object.__setattr__(self, 'R_wc', _readonly(rotations))

    def __len__(self) -> int:
        """Return the number of poses."""
        return int(self.stamps_s.shape[0])

    @property
    def quat_xyzw(self) -> FloatArray:
        """Unit quaternions of :attr:`R_wc` in (x, y, z, w) order with w >= 0, shape (N, 4)."""
        return so3.to_quat_xyzw(self.R_wc)

    def take(self, index: np.ndarray | Sequence[int]) -> Trajectory:
        """Return the poses selected by an integer or boolean index, as a new trajectory."""
        idx = np.asarray(index)
        return Trajectory(self.stamps_s[idx], self.positions_xyz[idx], self.R_wc[idx],
                          self.index_stamps, self.stamps_note)


# --------------------------------------------------------------------------------------------
# Parsing helpers
# --------------------------------------------------------------------------------------------

def _read_text(path: str | os.PathLike[str]) -> str:
    """Return the text of ``path`` (a leading UTF-8 BOM is dropped).

    Raises:
        FormatError: If the file cannot be opened or decoded.
    """
    try:
        return Path(path).read_text(encoding='utf-8-sig')
    except (OSError, UnicodeDecodeError) as err:
        msg = f'{path}: cannot read trajectory file: {err}'
        raise FormatError(msg) from err


def _parse_matrix(path: str | os.PathLike[str], text: str, *, delimiter: str | None,
                  n_cols: int, exact: bool, what: str) -> tuple[FloatArray, list[int]]:
    """Parse the data lines of ``text`` into a float matrix with ``n_cols`` columns.

    Args:
        path: File name used in error messages.
        text: File contents.
        delimiter: Column separator; None splits on any whitespace.
        n_cols: Number of columns kept (and required, at least).
        exact: Require exactly ``n_cols`` columns instead of at least ``n_cols``.
        what: Format name used in error messages, e.g. ``'TUM'``.

    Returns:
        The matrix, shape (N, n_cols), and the file line number of each row.

    Raises:
        FormatError: If there is no data line, a line has the wrong number of columns, or a
            value is not a finite number.
    """
    lines = data_lines(text)
    if not lines:
        msg = f'{path}: no {what} poses found (the file is empty or only has comments)'
        raise FormatError(msg)
    rows = [[tok.strip() for tok in line.split(delimiter)] if delimiter else line.split()
            for _, line in lines]
    counts = np.fromiter((len(row) for row in rows), dtype=np.int64, count=len(rows))
    bad = np.flatnonzero(counts != n_cols if exact else counts < n_cols)
    if bad.size:
        k = int(bad[0])
        need = f'{n_cols}' if exact else f'at least {n_cols}'
        sep = f'{delimiter!r}' if delimiter else 'whitespace'
        msg = (f'{path}:{lines[k][0]}: {what} lines need {need} values '
               f'separated by {sep}, got {counts[k]}')
        raise FormatError(msg)
    flat = [tok for row in rows for tok in row[:n_cols]]
    if python_only(''.join(flat)):
        _raise_bad_value(path, lines, rows, n_cols, what)
    try:
        mat = np.array(flat, dtype=np.float64).reshape(len(rows), n_cols)
    except ValueError:
        _raise_bad_value(path, lines, rows, n_cols, what)
    if not np.all(np.isfinite(mat)):
        _raise_bad_value(path, lines, rows, n_cols, what)
    return mat, [lineno for lineno, _ in lines]


def _raise_bad_value(path: str | os.PathLike[str], lines: list[tuple[int, str]],
                     rows: list[list[str]], n_cols: int, what: str) -> NoReturn:
    """Find the first value that is not a finite number and raise a FormatError naming it."""
    for (lineno, _), row in zip(lines, rows, strict=True):
        for col, tok in enumerate(row[:n_cols], start=1):
            if not (is_number(tok) and np.isfinite(float(tok))):
                msg = f'{path}:{lineno}: {what} column {col} is not a finite number: {tok!r}'
                raise FormatError(msg)
    msg = f'{path}: {what} values are not finite numbers'  # pragma: no cover
    raise FormatError(msg)  # pragma: no cover


def _rotations_from_quat(path: str | os.PathLike[str], quat_xyzw: FloatArray,
                         linenos: list[int], what: str) -> FloatArray:
    """Return rotation matrices of (not necessarily unit) quaternions, rejecting zero ones.

    Raises:
        FormatError: If a quaternion has (near) zero norm.
    """
    with np.errstate(over='ignore', under='ignore'):
        norms = np.linalg.norm(quat_xyzw, axis=1)
    bad = np.flatnonzero(norms < _MIN_QUAT_NORM)
    if bad.size:
        k = int(bad[0])
        # Its squares underflow below 1e-154: the norm is taken of the quaternion scaled up.
        largest = float(np.max(np.abs(quat_xyzw[k])))
        norm = largest * float(np.linalg.norm(quat_xyzw[k] / largest)) if largest else 0.0
        problem = (f'has norm {norm:.3g}, too small to normalize (below {_MIN_QUAT_NORM:g})'
                   if norm else 'is zero')
        msg = f'{path}:{linenos[k]}: {what} quaternion {problem}'
        raise FormatError(msg)
    # A quaternion with components beyond ~1e154 is a rotation, but its norm overflowed to
    # inf and normalizing it gave zeros: a wrong rotation, silently. Scaled down first.
    huge = ~np.isfinite(norms)
    if huge.any():
        quat_xyzw = quat_xyzw.copy()
        quat_xyzw[huge] /= np.max(np.abs(quat_xyzw[huge]), axis=1, keepdims=True)
    return so3.from_quat_xyzw(quat_xyzw)


def _check_positions(path: str | os.PathLike[str], positions: FloatArray,
                     linenos: list[int], what: str) -> None:
    """Refuse the first pose with a position coordinate beyond :data:`MAX_COORDINATE`.

    Such a coordinate is finite, but the squares of the alignment and of the errors
    overflowed: ATE / RPE were printed as inf / nan and the evaluation passed.

    Raises:
        FormatError: Naming the file, the line and the coordinate.
    """
    bad = np.flatnonzero(np.any(np.abs(positions) > MAX_COORDINATE, axis=1))
    if bad.size:
        k = int(bad[0])
        value = positions[k][int(np.argmax(np.abs(positions[k])))]
        msg = (f'{path}:{linenos[k]}: {what} position coordinate {value:g} is beyond '
               f'{MAX_COORDINATE:g} m')
        raise FormatError(msg)


# --------------------------------------------------------------------------------------------
# Readers and writers
# --------------------------------------------------------------------------------------------

def _poses_from_text(path: str | os.PathLike[str], text: str, layout: Layout) -> Trajectory:
    """Parse TUM or EuRoC CSV text: stamp, position, quaternion in ``layout``'s order."""
    what = layout.name
    if layout.fmt == 'tum':   # a TUM file with commas for spaces reads the same
        mat, linenos = _parse_matrix(path, text.replace(',', ' '), delimiter=None, n_cols=8,
                                     exact=True, what=what)
    else:
        mat, linenos = _parse_matrix(path, text, delimiter=',', n_cols=8, exact=False,
                                     what=what)
    _check_positions(path, mat[:, 1:4], linenos, what)
    quat_xyzw = mat[:, [5, 6, 7, 4]] if layout.w_first else mat[:, 4:8]
    rotations = _rotations_from_quat(path, quat_xyzw, linenos, what)
    logger.debug('Read %d %s poses from %s', mat.shape[0], what, path)
    # Same conversion as evo's read_euroc_csv_trajectory: float(t_ns) / 1e9.
    stamps = mat[:, 0] / 1e9 if layout.stamps_ns else mat[:, 0]
    return Trajectory(stamps, mat[:, 1:4], rotations, stamps_note=layout.stamps_note())


def _kitti_from_text(path: str | os.PathLike[str], text: str,
                     stamps: FloatArray | Sequence[float] | None,
                     project_to_so3: bool = False) -> Trajectory:
    """Parse KITTI text (see :func:`read_kitti`)."""
    mat, linenos = _parse_matrix(path, text, delimiter=None, n_cols=12, exact=True,
                                 what='KITTI')
    pose = mat.reshape(-1, 3, 4)
    _check_positions(path, pose[:, :, 3], linenos, 'KITTI')
    rotations = pose[:, :, :3]
    ortho_err = np.abs(np.einsum('nji,njk->nik', rotations, rotations) - np.eye(3))
    bad = np.flatnonzero(ortho_err.reshape(-1, 9).max(axis=1) > _ROTATION_TOL)
    if bad.size:
        msg = (f'{path}:{linenos[int(bad[0])]}: KITTI rotation block is not a rotation '
               f'matrix (|R^T R - I| > {_ROTATION_TOL:g})')
        raise FormatError(msg)
    n = pose.shape[0]
    if stamps is None:
        stamps_s = np.arange(n, dtype=np.float64)
    else:
        stamps_s = np.asarray(stamps, dtype=np.float64).reshape(-1)
        if stamps_s.shape[0] != n:
            msg = f'{path}: {n} KITTI poses but {stamps_s.shape[0]} stamps were given'
            raise FormatError(msg)
    logger.debug('Read %d KITTI poses from %s', n, path)
    if project_to_so3:
        rotations = so3.project(rotations)
    return Trajectory(stamps_s, pose[:, :, 3], rotations, index_stamps=stamps is None)


def read_tum(path: str | os.PathLike[str]) -> Trajectory:
    """Read a TUM trajectory file (``t tx ty tz qx qy qz qw`` per line).

    Args:
        path: File to read.

    Returns:
        The trajectory; quaternions are normalized.

    Raises:
        FormatError: If the file cannot be read, a line does not have exactly 8 numbers, a
            quaternion is zero, or a header names other columns.
    """
    return read_trajectory(path, 'tum')


def read_euroc_csv(path: str | os.PathLike[str]) -> Trajectory:
    """Read a EuRoC ground-truth CSV (``t_ns, p_xyz, q_wxyz, ...``, at least 8 columns).

    Columns after the eighth (velocity, biases) are ignored. Stamps are converted from
    nanoseconds to seconds as evo does, ``float(t_ns) / 1e9``.

    Args:
        path: File to read.

    Returns:
        The trajectory of the body (IMU) frame.

    Raises:
        FormatError: If the file cannot be read, a line has fewer than 8 numbers, a
            quaternion is zero, or a header names other columns.
    """
    return read_trajectory(path, 'euroc')


def read_kitti(path: str | os.PathLike[str],
               stamps: FloatArray | Sequence[float] | None = None, *,
               project_to_so3: bool = False) -> Trajectory:
    """Read a KITTI pose file (a row-major 3x4 ``[R|t]`` of cam0 -> world per line).

    KITTI files print about 7 significant digits, so the rotation blocks are orthonormal only
    to about 1e-6. By default they are kept as printed, which is what evo does and keeps ATE
    and RPE identical to evo's; ``project_to_so3=True`` replaces them by the nearest rotation
    (this changes per-pair RPE values by about 1e-6 relative).

    Args:
        path: File to read.
        stamps: Timestamps in seconds, shape (N,); None uses the pose index 0, 1, 2, ...
            (and marks the trajectory's ``index_stamps``).
        project_to_so3: Project each rotation block onto SO(3) (SVD).

    Returns:
        The trajectory.

    Raises:
        FormatError: If the file cannot be read, a line does not have exactly 12 numbers, a
            rotation block is far from orthonormal, or ``stamps`` has the wrong length.
    """
    return _kitti_from_text(path, _read_text(path), stamps, project_to_so3)


def detect_format(path: str | os.PathLike[str], text: str | None = None) -> str:
    """Guess the format of a trajectory file: ``'tum'``, ``'euroc'`` or ``'kitti'``.

    A header naming the columns decides between TUM and EuRoC CSV by the quaternion order.
    Without one, a comma in the first data line means EuRoC CSV, unless the file is named
    ``.tum`` or its stamps are written as seconds (a decimal fraction; EuRoC stamps are
    whole nanoseconds: TUM written with commas); otherwise 8 values mean TUM and 12 KITTI
    (:func:`pmba_ros.eval.layout.detect_layout`).

    Args:
        path: File name (read only if ``text`` is None).
        text: File contents, if already read.

    Returns:
        The format name.

    Raises:
        FormatError: If the file cannot be read, its first data line fits no format, or its
            header cannot be read.
    """
    if text is None:
        text = _read_text(path)
    return detect_layout(path, text).fmt


def read_times(path: str | os.PathLike[str]) -> FloatArray:
    """Read a KITTI ``times.txt``: one time in seconds per line, one line per pose.

    Args:
        path: File to read.

    Returns:
        The times, shape (N,).

    Raises:
        FormatError: If the file cannot be read, a line is not exactly one finite number, a
            time is beyond :data:`MAX_TIME_S`, or a time is before the one of the line above.
    """
    mat, line_no = _parse_matrix(path, _read_text(path), delimiter=None, n_cols=1,
                                 exact=True, what='times')
    times = mat[:, 0]
    bad = np.flatnonzero(np.abs(times) >= MAX_TIME_S)
    if bad.size:
        msg = (f'{path}:{line_no[bad[0]]}: time {times[bad[0]]:g} s is beyond '
               f'{MAX_TIME_S:g} s (a ROS stamp holds whole seconds in an int32)')
        raise FormatError(msg)
    # Line i is the time of pose i: a file out of order gives poses the stamps of others
    # (sorting them would pair them anew), and was read silently (ATE 2x, RPE 2 m).
    back = np.flatnonzero(np.diff(times) < 0)
    if back.size:
        k = int(back[0]) + 1
        msg = (f'{path}:{line_no[k]}: time {times[k]:g} s is before the {times[k - 1]:g} s of '
               f'line {line_no[k - 1]}: the times of a KITTI file go line by line with its '
               'poses and cannot decrease')
        raise FormatError(msg)
    return times


def read_trajectory(path: str | os.PathLike[str], fmt: str = 'auto', *,
                    times: str | os.PathLike[str] | None = None) -> Trajectory:
    """Read a trajectory in any supported format.

    Args:
        path: File to read.
        fmt: One of :data:`FORMATS`; ``'auto'`` uses :func:`detect_format`.
        times: KITTI ``times.txt`` with the stamps of a KITTI file (:func:`read_times`);
            without it KITTI files get index stamps (``index_stamps``).

    Returns:
        The trajectory.

    Raises:
        FormatError: If ``fmt`` is unknown, the format cannot be detected, the file is
            malformed, its header contradicts ``fmt``, or ``times`` is given for a format
            with stamps of its own or does not have one line per pose.
    """
    if fmt not in FORMATS:
        msg = f'unknown trajectory format {fmt!r}; expected one of {", ".join(FORMATS)}'
        raise FormatError(msg)
    text = _read_text(path)
    layout = detect_layout(path, text, fmt)
    fmt = layout.fmt
    if times is not None and fmt != 'kitti':
        # Silently ignoring them would leave the user believing the times were used.
        msg = (f'{times}: times are for a KITTI file (no stamps), but {path} is '
               f'{"TUM" if fmt == "tum" else "EuRoC CSV"} with stamps of its own')
        raise FormatError(msg)
    if layout.header_line:
        lines = text.splitlines()
        lines[layout.header_line - 1] = ''   # keeps the line numbers of messages
        text = '\n'.join(lines)
    if fmt != 'kitti':
        return _poses_from_text(path, text, layout)
    stamps = read_times(times) if times is not None else None
    return _kitti_from_text(path, text, stamps)


def write_tum(path: str | os.PathLike[str], traj: Trajectory) -> None:
    """Write a trajectory as TUM text, byte-identical for identical input.

    Stamps are printed with ``%.9f`` (nanosecond digits), positions and quaternions with
    ``%.9g``; quaternions have w >= 0.

    Args:
        path: File to write (overwritten).
        traj: Trajectory to write.

    Raises:
        FormatError: If the file cannot be written.
    """
    mat = np.column_stack([traj.stamps_s, traj.positions_xyz, traj.quat_xyzw])
    lines = ['# timestamp tx ty tz qx qy qz qw\n']
    lines.extend(_format_rows(mat, ['%.9f'] + ['%.9g'] * 7))
    try:
        with Path(path).open('w', encoding='utf-8', newline='\n') as stream:
            stream.writelines(lines)
    except OSError as err:
        msg = f'{path}: cannot write trajectory file: {err}'
        raise FormatError(msg) from err
    logger.debug('Wrote %d TUM poses to %s', len(traj), path)


def _format_rows(mat: FloatArray, formats: list[str]) -> list[str]:
    """Format each row of ``mat`` with one printf format per column, space separated."""
    row_fmt = ' '.join(formats) + '\n'
    # Negative zero would print as "-0"; normalize it so the output does not depend on it.
    clean = mat + 0.0
    return [row_fmt % tuple(row) for row in clean.tolist()]
