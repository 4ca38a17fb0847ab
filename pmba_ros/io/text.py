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
"""Shared helpers of the text-file readers."""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
from pathlib import Path
from typing import TYPE_CHECKING
import zlib

import numpy as np
from pmba_ros._numbers import is_number, python_only
from pmba_ros.errors import FormatError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from pmba_ros._typing import FloatArray, IntArray


_COMPRESSIONS = ((b'BZh', 'bzip2'), (b'\x1f\x8b', 'gzip'), (b'\xfd7zXZ\x00', 'xz'))
"""Magic bytes and name of each compression a problem file may come in (the BAL collections
are published as ``.bz2``)."""

COMPRESSED_SUFFIXES = ('.bz2', '.gz', '.xz')
"""File name endings of those compressions (dropped where a name is written back)."""


def plain_name(path: Path) -> str:
    """Return the name of ``path`` without a compression suffix: ``b.out.gz`` -> ``b.out``."""
    return path.stem if path.suffix.lower() in COMPRESSED_SUFFIXES else path.name


def file_bytes(path: Path, limit: int = -1) -> bytes:
    """Return the bytes of ``path`` (at most ``limit``), decompressed when bzip2, gzip or xz.

    The compression is told by the file's first bytes, not its name.

    Raises:
        FormatError: If a compressed file is damaged or cut short.
        OSError: If the file cannot be read.
    """
    with path.open('rb') as fh:
        magic = fh.read(6)
        kind = next((name for head, name in _COMPRESSIONS if magic.startswith(head)), None)
        if kind is None:
            fh.seek(0)
            return fh.read(limit)
    stream: io.BufferedIOBase = (bz2.BZ2File(path) if kind == 'bzip2' else
                                 gzip.GzipFile(path) if kind == 'gzip' else lzma.LZMAFile(path))
    try:
        with stream:
            return stream.read(limit)
    except (EOFError, OSError, lzma.LZMAError, zlib.error) as err:
        msg = f'{path}: damaged {kind} file ({err})'
        raise FormatError(msg) from err


def utf8_text(path: Path) -> str:
    """Return the text of ``path``, decompressed when bzip2, gzip or xz (:func:`file_bytes`).

    Raises:
        FormatError: If the file is not UTF-8 text, or a damaged compressed file.
    """
    try:
        return file_bytes(path).decode('utf-8')
    except UnicodeDecodeError as err:
        msg = f'{path}: not a text file ({err})'
        raise FormatError(msg) from err


def nonblank_lines(path: Path) -> tuple[list[str], list[int]]:
    """Return the non-blank lines of ``path`` and their 1-based line numbers.

    Raises:
        FormatError: If the file is not UTF-8 text.
    """
    lines = utf8_text(path).splitlines()
    numbers = [i for i, s in enumerate(lines, start=1) if s.strip()]
    return [lines[i - 1] for i in numbers], numbers


def integer_indices(path: Path, values: FloatArray, n: int, what: str,
                    line_numbers: Sequence[int]) -> IntArray:
    """Check that ``values`` are integers in [0, n) and return them as int64.

    Args:
        path: The file (for the message).
        values: Parsed values, shape (K,).
        n: Exclusive upper bound.
        what: What the index is, e.g. 'camera'.
        line_numbers: 1-based line of each value, shape (K,).

    Raises:
        FormatError: Naming the file, line and value of the first bad index.
    """
    finite = np.isfinite(values)
    idx = np.clip(np.where(finite, values, -1.0), -1.0, float(n)).astype(np.int64)
    bad = ~finite | (idx != values) | (idx < 0) | (idx >= n)
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        msg = (f'{path}:{line_numbers[k]}: {what} index {values[k]:g} is not an integer in '
               f'[0, {n})')
        raise FormatError(msg)
    return idx


MAX_PIXEL = 1e9
"""Largest pixel coordinate magnitude accepted: far beyond any sensor, and small enough that
squared residuals of a whole problem stay finite."""


MAX_COORDINATE = 1e150
"""Largest world coordinate magnitude accepted for a camera centre (or a translation, whose
norm is the centre's) or a point: squared distances between centres (a triangulation's spread
of its cameras) stay finite up to it."""


MAX_FOCAL = MAX_COORDINATE
"""Largest focal length accepted, px: up to it a problem's squared pixel residuals stay
finite. Smaller ones that no lens has (focal lengths not in pixels) are solved, with a
warning naming them (:mod:`pmba_ros.cli.solve`)."""


def check_bounded(values: FloatArray, bound: float, what: str,
                  where: Callable[[int, int], str]) -> None:
    """Refuse the first finite value of ``values`` whose magnitude is beyond ``bound``.

    Non-finite values are left to the checks that name them as such.

    Args:
        values: One row per record (camera, image, point), shape (K, d) or (K,).
        bound: E.g. :data:`MAX_COORDINATE` or :data:`MAX_FOCAL`.
        what: What the values are, e.g. 'translation coordinate'.
        where: The file, line and record of row k, column j, e.g. ``f.txt:12: image 3``
            (called only for the message).

    Raises:
        FormatError: ``{where} has {what} {value} beyond {bound}``.
    """
    v = np.asarray(values, dtype=float)
    v = v[:, None] if v.ndim == 1 else v
    big = np.abs(np.where(np.isfinite(v), v, 0.0)) > bound
    if np.any(big):
        k, j = (int(i) for i in np.argwhere(big)[0])
        msg = f'{where(k, j)} has {what} {v[k, j]:g} beyond {bound:g}'
        raise FormatError(msg)


def value_line(text: str, index: int, first_line: int = 1) -> int:
    """Return the line of the ``index``-th whitespace-separated value of ``text``.

    For the messages of readers that take a file's values as one stream (line breaks free),
    counting lines only when one is needed.
    """
    for n, line in enumerate(text.splitlines(), start=first_line):
        index -= len(line.split())
        if index < 0:
            return n
    return first_line + len(text.splitlines())


def check_pixels(path: Path, pixels: FloatArray, line_numbers: Sequence[int]) -> None:
    """Raise FormatError naming the first observation with a non-finite or absurd pixel.

    Args:
        path: The file (for the message).
        pixels: Pixel coordinates, shape (K, 2).
        line_numbers: 1-based line of each observation, shape (K,).
    """
    finite = np.all(np.isfinite(pixels), axis=1)
    bad = ~finite | np.any(np.abs(np.where(np.isfinite(pixels), pixels, 0.0)) > MAX_PIXEL,
                           axis=1)
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        what = ('non-finite pixel coordinate' if not finite[k] else
                f'pixel coordinate {np.max(np.abs(pixels[k])):g} beyond {MAX_PIXEL:g}')
        msg = f'{path}:{line_numbers[k]}: {what}'
        raise FormatError(msg)


def detect_problem_format(path: Path) -> str:
    """Tell a BAL file from a ParallaxBA Cam file by its first line, not by its name.

    A ParallaxBA Cam file's rows hold six or eight numbers; anything else is read as BAL
    (whose reader then names what is wrong). Folders are ParallaxBA datasets.

    Returns:
        'bal' or 'parallaxba'.

    Raises:
        FormatError: If a compressed file is damaged.
        OSError: If the file cannot be read.
    """
    if path.is_dir():
        return 'parallaxba'
    head = file_bytes(path, 4096).decode('utf-8', errors='replace')
    first = next((line for line in head.splitlines() if line.strip()), '')
    return 'parallaxba' if len(first.split()) in (6, 8) else 'bal'


def check_numeric(path: Path, tokens: list[str], line_no: int) -> None:
    """Raise FormatError naming the first token that is not a number.

    Numbers only Python reads ('1_000', :mod:`pmba_ros._numbers`) are not numbers here.
    """
    for tok in tokens:
        if not is_number(tok):
            msg = f'{path}:{line_no}: non-numeric token {tok!r}'
            raise FormatError(msg)


def float_values(path: Path, lines: Sequence[str], line_no: Sequence[int]) -> FloatArray:
    """Return the whitespace-separated numbers of ``lines`` as one array.

    Raises:
        FormatError: Naming the file, line and first token that is not a number.
    """
    text = ' '.join(lines)
    try:
        if not python_only(text):
            return np.array(text.split(), dtype=float)
    except ValueError:
        pass
    for s, n in zip(lines, line_no, strict=True):
        check_numeric(path, s.split(), n)
    # Numbers that only Python reads are named above: what is left is separated by other
    # whitespace (a no-break space), as str.split() takes it.
    return np.array(text.split(), dtype=float)
