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
"""Vectorized CDR decoding of the feature tracks of the VINS layouts.

A ``sensor_msgs/PointCloud`` of a few hundred tracks arrives with every camera frame, and
rosbags' generated deserializer builds one ``Point32`` object per point (a few microseconds
each). Here the points become one ``(N, 3)`` float32 array read straight from the buffer; the
header and the channels are the typestore's own classes. :func:`parse_tracks
<pmba_ros.backend.tracks.parse_tracks>` reads either form. Anything that does not fit the
layout exactly (a short buffer, counts past the end, bytes left over) returns None, so that
rosbags decodes it and reports what is wrong in its own words.
"""

from __future__ import annotations

from collections.abc import Callable
import struct
from typing import Any

import numpy as np

POINT_CLOUD = 'sensor_msgs/msg/PointCloud'
"""The message type :func:`decode_point_cloud` reads."""

#: The types whose definitions the decoder assumes.
_LAYOUT_TYPES = (POINT_CLOUD, 'std_msgs/msg/Header', 'builtin_interfaces/msg/Time',
                 'geometry_msgs/msg/Point32', 'sensor_msgs/msg/ChannelFloat32')

#: Bytes rosbags accepts after a message (padding up to the next 4-byte boundary and more).
_SLACK = 7


class _Cursor:
    """Reads 4-byte-aligned CDR fields from a buffer; offsets count from the body."""

    def __init__(self, raw: memoryview, order: str) -> None:
        self.raw, self.order, self.pos = raw, order, 4
        self._u32 = struct.Struct(order + 'I')

    def align(self) -> None:
        """Skip to the next 4-byte boundary of the body."""
        self.pos += -(self.pos - 4) % 4

    def i32(self) -> int:
        """Read an aligned int32."""
        value = self.u32()
        return value - (1 << 32) if value >= 1 << 31 else value

    def u32(self) -> int:
        """Read an aligned uint32."""
        self.align()
        if self.pos + 4 > len(self.raw):
            raise _Misfit
        (value,) = self._u32.unpack_from(self.raw, self.pos)
        self.pos += 4
        return int(value)

    def string(self) -> str:
        """Read a CDR text field (length with its terminating NUL, bytes, NUL)."""
        size = self.u32()
        end = self.pos + size
        if size < 1 or end > len(self.raw) or self.raw[end - 1] != 0:
            raise _Misfit
        text = bytes(self.raw[self.pos:end - 1]).decode()
        self.pos = end
        return text

    def floats(self, count: int) -> np.ndarray:
        """Read ``count`` aligned float32 values (a read-only view of the buffer)."""
        self.align()
        end = self.pos + 4 * count
        if end > len(self.raw):
            raise _Misfit
        values = np.frombuffer(self.raw, dtype=self.order + 'f4', count=count, offset=self.pos)
        self.pos = end
        return values


class _Misfit(Exception):
    """The buffer is not a well-formed PointCloud: rosbags should decode and judge it."""


def decode_point_cloud(raw: bytes | memoryview, typestore: Any) -> Any | None:
    """Return a ``sensor_msgs/PointCloud`` with its points as an ``(N, 3)`` float32 array.

    Args:
        raw: The serialized message (CDR with its 4-byte encapsulation header).
        typestore: A rosbags typestore with the sensor_msgs and std_msgs types.

    Returns:
        The message (the typestore's class; ``points`` an array, channel values arrays in
        native byte order), or None if ``raw`` does not fit the layout.
    """
    view = memoryview(raw).cast('B')
    if len(view) < 4 or bytes(view[:2]) not in (b'\x00\x00', b'\x00\x01'):
        return None
    cur = _Cursor(view, '<' if view[1] else '>')
    try:
        sec, nanosec = cur.i32(), cur.u32()
        frame_id = cur.string()
        points = cur.floats(3 * cur.u32()).reshape(-1, 3)
        channels = []
        for _ in range(cur.u32()):
            name = cur.string()
            channels.append((name, cur.floats(cur.u32())))
    except (_Misfit, UnicodeDecodeError):
        return None
    if cur.pos + _SLACK < len(view):
        return None
    types = typestore.types
    header = types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
        frame_id=frame_id)
    channel = types['sensor_msgs/msg/ChannelFloat32']
    return types[POINT_CLOUD](
        header=header, points=points.astype(np.float32),
        channels=[channel(name=name, values=values.astype(np.float32))
                  for name, values in channels])


def fast_decoder(typestore: Any, msgtype: str,
                 reference: Any) -> Callable[[bytes | memoryview], Any | None] | None:
    """Return a vectorized decoder of ``msgtype`` for a reader's typestore, if there is one.

    Args:
        typestore: The typestore the reader decodes with (built from the bag's definitions).
        msgtype: The connection's message type.
        reference: A typestore with the standard definitions (Jazzy's).

    Returns:
        ``raw -> message or None``; None if ``msgtype`` has no vectorized decoder or the bag
        defines it (or a type inside it) differently from ``reference``.
    """
    if msgtype != POINT_CLOUD:
        return None
    for name in _LAYOUT_TYPES:
        if name not in typestore.fielddefs or \
                typestore.fielddefs[name] != reference.fielddefs.get(name):
            return None
    return lambda raw: decode_point_cloud(raw, typestore)
