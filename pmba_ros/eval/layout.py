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
"""Column layout of a trajectory file: its format, quaternion order and stamp unit.

A header line that names the columns decides the quaternion order (EuRoC's
``#timestamp [ns],p_RS_R_x [m],...,q_RS_w [],...``, TUM's ``# timestamp tx ty tz qx qy qz
qw``, short names such as ``p_x``, ``q_w``) and, where it gives one (``[ns]``, ``[s]``), the
stamp unit. It is the last comment line before the first data line that has as many
columns as the data, or a first line with no number in it (a header without ``#``).
Without a header the first data line decides, as :func:`detect_layout` describes.
"""

from __future__ import annotations

from dataclasses import dataclass
import logging
from pathlib import Path
import re
from typing import TYPE_CHECKING

import numpy as np
from pmba_ros._numbers import is_number
from pmba_ros.errors import FormatError

if TYPE_CHECKING:
    import os

logger = logging.getLogger(__name__)

_NAMES = {'tum': 'TUM', 'euroc': 'EuRoC CSV', 'kitti': 'KITTI'}
"""Format names for messages."""

_UNIT = re.compile(r'\[([^\]]*)\]')
"""A unit in a header's column name, ``[ns]``."""

_NAME = re.compile(r'[A-Za-z_]')
"""How a column name in a header starts."""

_STAMP_UNITS = {'ns': True, 's': False, 'sec': False}
"""Stamp units a header may give: True for nanoseconds."""

_ORDERS: dict[tuple[str, ...], bool] = {('qw', 'qx', 'qy', 'qz'): True,
                                        ('qx', 'qy', 'qz', 'qw'): False}
"""Quaternion column orders a reader takes: True for w first."""


@dataclass(frozen=True)
class Layout:
    """How the lines of a trajectory file are read.

    Attributes:
        fmt: ``'tum'`` (8 columns, spaces or commas), ``'euroc'`` (at least 8, commas) or
            ``'kitti'`` (12, a 3x4 pose).
        w_first: The quaternion columns are w, x, y, z (EuRoC's order), not x, y, z, w.
        stamps_ns: The stamps are nanoseconds, not seconds.
        header_line: Line number of a header without ``#``, to be skipped (0: none).
        seconds_like: The stamps are written as seconds (a decimal fraction).
    """

    fmt: str
    w_first: bool
    stamps_ns: bool
    header_line: int = 0
    seconds_like: bool = False

    @property
    def name(self) -> str:
        """The format's name for messages, e.g. ``'EuRoC CSV'``."""
        return _NAMES[self.fmt]

    def stamps_note(self) -> str:
        """Describe how the stamps were read, for messages about them."""
        unit = 'nanoseconds' if self.stamps_ns else 'seconds'
        hint = '; these look like seconds' if self.stamps_ns and self.seconds_like else ''
        return f'read as {unit} ({self.name}){hint}'


def data_lines(text: str) -> list[tuple[int, str]]:
    """Return ``(line number, stripped line)`` of every non-empty, non-comment line."""
    return [(lineno, stripped) for lineno, line in enumerate(text.splitlines(), start=1)
            if (stripped := line.strip()) and not stripped.startswith('#')]


def _fields(line: str) -> list[str]:
    """Split a line into its columns: at commas if it has one, else at whitespace."""
    return [tok.strip() for tok in line.split(',')] if ',' in line else line.split()


def _first_field(line: str) -> str:
    """Return the first column of a data line (see :func:`_fields`)."""
    return line.split(',', 1)[0].strip() if ',' in line else line.split(None, 1)[0]


def _seconds_like(tokens: list[str]) -> bool:
    """Return True if stamps are written as seconds: a decimal fraction, or not whole.

    ``1.5`` and ``1.000000`` are seconds; ``1403715524907143168`` and ``1.0e+09`` (whole,
    in exponent form) may be nanoseconds.
    """
    if any('.' in tok and not ('e' in tok or 'E' in tok) for tok in tokens):
        return True
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError:
        return False  # the reader names the bad value
    return bool(np.any(values != np.round(values)))


def _header_names(line: str) -> list[str]:
    """Return the column names of a header line, each with its unit (``timestamp [ns]``)."""
    return _fields(re.sub(r'\s+\[', '[', line.lstrip('#').strip()))


def _column_key(name: str) -> str:
    """Return ``'t'``, ``'px'``... or ``'qw'``... for a column name, '' if not one of them."""
    key = re.sub(r'[^a-z0-9]', '', _UNIT.sub('', name).lower())
    if 'time' in key or 'stamp' in key or key == 't':
        return 't'
    if not key or key[-1] not in 'wxyz':
        return ''
    if key[0] == 'q' or 'quat' in key or 'orient' in key:
        return 'q' + key[-1]
    return 'p' + key[-1] if key[-1] != 'w' else ''


def _read_header(path: str | os.PathLike[str], lineno: int,
                 line: str) -> tuple[bool, bool | None] | None:
    """Return (w first, stamps in ns or None if not said) of a header; None if not understood.

    Raises:
        FormatError: If the header names the columns in an order no reader takes, or gives
            a stamp unit other than ns or s.
    """
    names = _header_names(line)[:8]
    keys = tuple(_column_key(name) for name in names)
    if sorted(keys) != ['px', 'py', 'pz', 'qw', 'qx', 'qy', 'qz', 't']:
        return None
    if keys[:4] != ('t', 'px', 'py', 'pz') or keys[4:] not in _ORDERS:
        msg = (f'{path}:{lineno}: the header names the columns {", ".join(names)}; the '
               'readers take a stamp, x, y, z, then the quaternion w, x, y, z (EuRoC) or x, '
               'y, z, w (TUM)')
        raise FormatError(msg)
    unit_match = _UNIT.search(names[0])
    unit = unit_match.group(1).strip().lower() if unit_match else ''
    if unit and unit not in _STAMP_UNITS:
        msg = (f'{path}:{lineno}: the header gives the stamps in [{unit}]; the readers take '
               'ns or s')
        raise FormatError(msg)
    return _ORDERS[keys[4:]], _STAMP_UNITS[unit] if unit else None


def _header(text: str, lines: list[tuple[int, str]]) -> tuple[int, str, bool]:
    """Return the header's line number, text and whether it lacks ``#`` (0, '' if none).

    The first data line is one if its columns are all names (a letter first, no number);
    else the last comment line before it that has as many columns as it (a comment of prose
    is not a header).
    """
    lineno, first = lines[0]
    if all(_NAME.match(tok) and not is_number(tok) for tok in _fields(first)):
        return lineno, first, True
    n_cols = len(_fields(first))
    comments = text.splitlines()[:lineno - 1]
    for k in range(len(comments) - 1, -1, -1):
        line = comments[k].strip()
        if line.startswith('#') and len(_header_names(line)) == n_cols:
            return k + 1, line, False
    return 0, '', False


def _guess(path: str | os.PathLike[str], lineno: int, first: str, seconds: bool) -> str:
    """Return the format of a file without a header, from its first data line."""
    if ',' in first:
        # EuRoC stamps are whole nanoseconds; a fraction is seconds: TUM written with commas.
        tum = Path(path).suffix.lower() == '.tum' or (seconds and len(_fields(first)) == 8)
        return 'tum' if tum else 'euroc'
    n_values = len(first.split())
    if n_values == 8:
        return 'tum'
    if n_values == 12:
        return 'kitti'
    msg = (f'{path}:{lineno}: cannot detect the trajectory format: {n_values} values '
           f'(TUM has 8, KITTI 12, EuRoC CSV is comma separated)')
    raise FormatError(msg)


def detect_layout(path: str | os.PathLike[str], text: str, fmt: str = 'auto') -> Layout:
    """Return how to read a trajectory file, ``fmt`` being the format asked for or 'auto'.

    With 'auto', a header naming the columns decides the quaternion order (then the format:
    EuRoC CSV if w comes first and commas separate, else TUM) and the stamp unit if it gives
    one; else w first means nanoseconds unless the stamps are written as seconds, and x
    first seconds. Without a header, a comma in the first data line means EuRoC CSV unless
    the file is named ``.tum`` or has 8 columns of stamps written as seconds (TUM with
    commas); else 8 values mean TUM and 12 KITTI. A format asked for reads by its own
    order and unit, which a header must not contradict.

    Args:
        path: File name, for messages and its ``.tum`` suffix.
        text: File contents.
        fmt: ``'auto'``, ``'tum'``, ``'euroc'`` or ``'kitti'``.

    Returns:
        The layout.

    Raises:
        FormatError: If the file has no data line or its first fits no format ('auto'), or
            its header contradicts ``fmt``, names an order no reader takes or a stamp unit
            other than ns or s.
    """
    lines = data_lines(text)
    if not lines:
        if fmt != 'auto':   # the reader says there are no poses
            return Layout(fmt, fmt == 'euroc', fmt == 'euroc')
        msg = f'{path}: cannot detect the trajectory format: no data lines'
        raise FormatError(msg)
    header_no, header, bare = _header(text, lines)
    skip = header_no if bare else 0
    body = lines[1:] if bare else lines
    if not body:
        msg = f'{path}: no poses after the header on line {header_no}'
        raise FormatError(msg)
    lineno, first = body[0]
    seconds = _seconds_like([_first_field(line) for _, line in body])
    guessed = fmt if fmt != 'auto' else _guess(path, lineno, first, seconds)
    said = _read_header(path, header_no, header) if header and guessed != 'kitti' else None
    if header and guessed != 'kitti' and said is None:
        logger.warning('%s:%d: the header %r names no columns the readers know (a stamp, '
                       'x, y, z, a quaternion); read as %s by its column order', path,
                       header_no, header, _NAMES[guessed])
    if said is None:
        return Layout(guessed, guessed == 'euroc', guessed == 'euroc', skip, seconds)
    w_first, ns = said
    if fmt == 'auto':
        auto = 'euroc' if w_first and ',' in first else 'tum'
        return Layout(auto, w_first, ns if ns is not None else w_first and not seconds,
                      skip, seconds)
    if w_first != (fmt == 'euroc') or ns not in (None, fmt == 'euroc'):
        order = 'w, x, y, z' if w_first else 'x, y, z, w'
        unit = {None: '', True: ', stamps in ns', False: ', stamps in s'}[ns]
        msg = (f'{path}:{header_no}: the header names the quaternion {order}{unit}, but the '
               f'file is read as {_NAMES[fmt]} (quaternion '
               f'{"w, x, y, z, stamps in ns" if fmt == "euroc" else "x, y, z, w, stamps in s"})'
               '; give the format that fits the file, or auto')
        raise FormatError(msg)
    return Layout(fmt, w_first, fmt == 'euroc', skip, seconds)
