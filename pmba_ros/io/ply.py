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
"""Point clouds as PLY files (binary little-endian, float32 x, y, z [, uint32 id]).

The writer is deterministic: the same points give the same bytes. The reader understands
the files :func:`write_ply` writes (and ASCII PLY with the same vertex properties), which is
enough for tests and for loading the landmarks into MeshLab, CloudCompare or Open3D.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pmba_ros.errors import FormatError

if TYPE_CHECKING:
    from os import PathLike

    from numpy.typing import ArrayLike
    from pmba_ros._typing import FloatArray, IntArray

logger = logging.getLogger(__name__)

_PLY_TYPES = {'float': 'f4', 'float32': 'f4', 'double': 'f8', 'float64': 'f8',
              'uint': 'u4', 'uint32': 'u4', 'int': 'i4', 'int32': 'i4',
              'uchar': 'u1', 'uint8': 'u1', 'char': 'i1', 'int8': 'i1',
              'ushort': 'u2', 'uint16': 'u2', 'short': 'i2', 'int16': 'i2'}


def write_ply(path: str | PathLike[str], points: ArrayLike, ids: ArrayLike | None = None,
              *, comment: str = 'pmba_ros landmarks') -> None:
    """Write points as a binary little-endian PLY file.

    Args:
        path: Output file (overwritten).
        points: Points, shape (N, 3), m (stored as float32).
        ids: Optional feature ids, shape (N,) (stored as uint32 property ``id``).
        comment: One header comment line.

    Raises:
        FormatError: On wrong shapes or if the file cannot be written.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        msg = f'{path}: PLY points must have shape (N, 3), got {pts.shape}'
        raise FormatError(msg)
    fields = [('x', '<f4'), ('y', '<f4'), ('z', '<f4')]
    if ids is not None:
        id_arr = np.asarray(ids).reshape(-1)
        if id_arr.shape[0] != pts.shape[0]:
            msg = f'{path}: {id_arr.shape[0]} ids for {pts.shape[0]} points'
            raise FormatError(msg)
        fields.append(('id', '<u4'))
    rec = np.empty(pts.shape[0], dtype=fields)
    rec['x'], rec['y'], rec['z'] = pts[:, 0], pts[:, 1], pts[:, 2]
    header = ['ply', 'format binary_little_endian 1.0', f'comment {comment}',
              f'element vertex {pts.shape[0]}', 'property float x', 'property float y',
              'property float z']
    if ids is not None:
        rec['id'] = id_arr
        header.append('property uint id')
    header.append('end_header')
    try:
        with Path(path).open('wb') as stream:
            stream.write(('\n'.join(header) + '\n').encode('ascii'))
            stream.write(rec.tobytes())
    except OSError as err:
        msg = f'{path}: cannot write PLY file: {err}'
        raise FormatError(msg) from err
    logger.debug('Wrote %d points to %s', pts.shape[0], path)


def read_ply(path: str | PathLike[str]) -> tuple[FloatArray, IntArray | None]:
    """Read the vertices of a PLY file (binary little-endian or ASCII).

    Args:
        path: File to read.

    Returns:
        ``(points, ids)``: points of shape (N, 3) and ids of shape (N,) (None if the file
        has no ``id`` property).

    Raises:
        FormatError: If the file cannot be read or is not a vertex PLY this reader supports.
    """
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        msg = f'{path}: cannot read PLY file: {err}'
        raise FormatError(msg) from err
    end = data.find(b'end_header\n')
    if not data.startswith(b'ply\n') or end < 0:
        msg = f'{path}: not a PLY file (no "ply" / "end_header" lines)'
        raise FormatError(msg)
    header = data[:end].decode('ascii', errors='replace').splitlines()
    body = data[end + len(b'end_header\n'):]
    fmt, count, props = '', -1, []
    for line in header:
        words = line.split()
        if words[:1] == ['format']:
            fmt = words[1]
        elif words[:2] == ['element', 'vertex']:
            count = int(words[2])
        elif words[:1] == ['property'] and count >= 0 and len(words) == 3:
            if words[1] not in _PLY_TYPES:
                msg = f'{path}: unsupported PLY property type {words[1]!r}'
                raise FormatError(msg)
            props.append((words[2], '<' + _PLY_TYPES[words[1]]))
    if count < 0 or not {'x', 'y', 'z'} <= {p[0] for p in props}:
        msg = f'{path}: PLY file has no vertex element with x, y, z'
        raise FormatError(msg)
    dtype = np.dtype(props)
    if fmt == 'binary_little_endian':
        if len(body) < count * dtype.itemsize:
            msg = f'{path}: PLY file is truncated ({len(body)} bytes for {count} vertices)'
            raise FormatError(msg)
        rec = np.frombuffer(body, dtype=dtype, count=count)
        columns = {name: rec[name] for name in dtype.names or ()}
    elif fmt == 'ascii':
        table = np.loadtxt(body.decode('ascii').splitlines()[:count], ndmin=2)
        columns = {name: table[:, i] for i, (name, _) in enumerate(props)}
    else:
        msg = f'{path}: unsupported PLY format {fmt!r}'
        raise FormatError(msg)
    points = np.column_stack([columns[k].astype(np.float64) for k in 'xyz']).reshape(-1, 3)
    ids = columns['id'].astype(np.int64) if 'id' in columns else None
    return points, ids


__all__ = ['read_ply', 'write_ply']
