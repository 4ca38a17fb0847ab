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
"""The text and binary primitives of COLMAP's model files: tokens, numbers, a reader.

Each names the file, and the line or byte, of what it cannot read (a damaged file is a
:class:`~pmba_ros.errors.FormatError`, never a crash in a parser).
"""

from __future__ import annotations

import struct
from typing import Any, TYPE_CHECKING

import numpy as np
from pmba_ros._numbers import python_only
from pmba_ros.errors import FormatError

if TYPE_CHECKING:
    from collections.abc import Mapping
    from pathlib import Path

    from pmba_ros._typing import FloatArray, IntArray

__all__ = ['NAME_ERRORS', 'BinaryReader', 'check_new_id', 'data_lines', 'integers', 'numbers']

NAME_ERRORS = 'surrogateescape'
"""How bytes that are not UTF-8 are read and written: COLMAP stores an image name as the
file system gave it, and a refined model must name the same files; in a number they fail
as any other non-numeric text."""


def data_lines(path: Path) -> list[tuple[int, list[str]]]:
    """Return the (line number, tokens) of a text file's lines that are not comments."""
    out = []
    with path.open(encoding='utf-8', errors=NAME_ERRORS) as fh:
        for n, line in enumerate(fh, 1):
            s = line.strip()
            if s and not s.startswith('#'):
                out.append((n, s.split()))
    return out


def numbers(path: Path, n: int, tokens: list[str], what: str) -> FloatArray:
    """Return tokens as floats; FormatError naming the file, line ``n`` and ``what``."""
    try:
        return np.array(_c_numbers(tokens), dtype=float)
    except ValueError as err:
        msg = f'{path}:{n}: non-numeric value in {what}: {err}'
        raise FormatError(msg) from err


def integers(path: Path, n: int, tokens: list[str], what: str) -> IntArray:
    """Return tokens as int64; FormatError naming the file, line ``n`` and ``what``."""
    try:
        return np.array(_c_numbers(tokens), dtype=np.int64)
    except (ValueError, OverflowError) as err:
        msg = f'{path}:{n}: not an integer in {what}: {err}'
        raise FormatError(msg) from err


def _c_numbers(tokens: list[str]) -> list[str]:
    """Return ``tokens``, or raise ValueError naming the first number only Python reads.

    numpy converts strings with Python's float() and int(), which read '1_000' and the
    digits of other scripts; COLMAP does not (:mod:`pmba_ros._numbers`).
    """
    if python_only(''.join(tokens)):
        bad = next(t for t in tokens if python_only(t))
        raise ValueError(repr(bad))
    return tokens


def check_new_id(where: str, what: str, new_id: int, known: Mapping[int, object]) -> None:
    """Raise FormatError if ``new_id`` is already among the ``known`` ids of a file.

    ``where`` names the file (and line) in the message.

    A model's ids are unique; read into a dictionary, a repeated one silently replaced the
    record before it (an image and its observations were lost from the solve and from a
    written model).
    """
    if new_id in known:
        msg = f'{where}: {what} id {new_id} appears twice'
        raise FormatError(msg)


class BinaryReader:
    """Little-endian binary reader that names the file and offset in its errors."""

    def __init__(self, path: Path) -> None:
        """Read the whole file."""
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def take(self, fmt: str) -> tuple[Any, ...]:
        """Return the values of a struct format at the position, and move past them."""
        size = struct.calcsize('<' + fmt)
        if self.pos + size > len(self.data):
            msg = f'{self.path}: truncated file at byte {self.pos} (need {size} more bytes)'
            raise FormatError(msg)
        out = struct.unpack_from('<' + fmt, self.data, self.pos)
        self.pos += size
        return out

    def array(self, dtype: str, count: int) -> np.ndarray:
        """Return ``count`` values of ``dtype`` (a copy), and move past them."""
        size = np.dtype(dtype).itemsize * count
        if self.pos + size > len(self.data):
            msg = f'{self.path}: truncated file at byte {self.pos} (need {size} more bytes)'
            raise FormatError(msg)
        out = np.frombuffer(self.data, dtype=dtype, count=count, offset=self.pos).copy()
        self.pos += size
        return out

    def count(self, record_bytes: int, what: str) -> int:
        """Read a record count that the rest of the file can hold (records >= record_bytes)."""
        # A damaged count is refused before it sizes an array (2**40 points: 8 TiB).
        (count,) = self.take('Q')
        left = len(self.data) - self.pos
        if count * record_bytes > left:
            msg = (f'{self.path}: truncated file or bad count: {count} {what} need at least '
                   f'{count * record_bytes} bytes, {left} left after byte {self.pos}')
            raise FormatError(msg)
        return int(count)

    def string(self) -> str:
        """Return the NUL-terminated UTF-8 text here (an image name), and move past it."""
        end = self.data.find(b'\0', self.pos)
        if end < 0:
            msg = f'{self.path}: unterminated image name at byte {self.pos}'
            raise FormatError(msg)
        s = self.data[self.pos:end].decode('utf-8', errors=NAME_ERRORS)
        self.pos = end + 1
        return s
