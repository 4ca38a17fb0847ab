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
"""Vectorized decoding of the feature tracks of the VINS layouts (ROS 2 CDR and ROS 1).

A ``sensor_msgs/PointCloud`` of a few hundred tracks arrives with every camera frame, and
rosbags' generated deserializers build one ``Point32`` object per point. Here the points
become one ``(N, 3)`` float32 array read straight from the buffer; the header and the
channels are the typestore's own classes. :func:`parse_tracks
<pmba_ros.backend.tracks.parse_tracks>` reads either form. Anything that does not fit the
layout exactly (a short buffer, counts past the end, bytes left over) returns None, so that
rosbags decodes it and reports what is wrong in its own words.

The two serializations differ in three ways: CDR starts with a 4-byte encapsulation header
(its byte order) and aligns 4-byte fields to 4 bytes of the body, and its strings end with a
NUL that their length counts; ROS 1 is little-endian, packed, and its ``Header`` starts with
a ``seq`` counter.
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

#: Bytes rosbags accepts after a CDR message (padding up to the next 4-byte boundary and more).
_CDR_SLACK = 7


class _Misfit(Exception):
    """The buffer is not a well-formed PointCloud: rosbags should decode and judge it."""


class _Cursor:
    """Reads the fields of one serialized message in order."""

    def __init__(self, raw: memoryview, *, ros1: bool) -> None:
        self.raw, self.ros1 = raw, ros1
        self.order = '<' if ros1 or raw[1] else '>'
        self.pos = 0 if ros1 else 4   # after CDR's encapsulation header
        self._u32 = struct.Struct(self.order + 'I')

    def align(self) -> None:
        """Skip CDR's padding to the next 4-byte boundary of the body (none in ROS 1)."""
        if not self.ros1:
            self.pos += -(self.pos - 4) % 4

    def u32(self) -> int:
        """Read a uint32."""
        self.align()
        if self.pos + 4 > len(self.raw):
            raise _Misfit
        (value,) = self._u32.unpack_from(self.raw, self.pos)
        self.pos += 4
        return int(value)

    def i32(self) -> int:
        """Read an int32."""
        value = self.u32()
        return value - (1 << 32) if value >= 1 << 31 else value

    def text(self) -> str:
        """Read a string field (CDR: its length counts a terminating NUL)."""
        size = self.u32()
        end = self.pos + size
        if end > len(self.raw):
            raise _Misfit
        stop = end
        if not self.ros1:
            if size < 1 or self.raw[end - 1] != 0:
                raise _Misfit
            stop = end - 1
        value = bytes(self.raw[self.pos:stop]).decode()
        self.pos = end
        return value

    def floats(self, count: int) -> np.ndarray:
        """Read ``count`` float32 values, as a native-order copy."""
        self.align()
        end = self.pos + 4 * count
        if end > len(self.raw):
            raise _Misfit
        values = np.frombuffer(self.raw, dtype=self.order + 'f4', count=count, offset=self.pos)
        self.pos = end
        return values.astype(np.float32)

    def finished(self) -> bool:
        """Return whether the message ended where the buffer does (CDR: up to its slack)."""
        if self.ros1:
            return self.pos == len(self.raw)
        return self.pos + _CDR_SLACK >= len(self.raw)


def decode_point_cloud(raw: bytes | memoryview, typestore: Any, *,
                       ros1: bool = False) -> Any | None:
    """Return a ``sensor_msgs/PointCloud`` with its points as an ``(N, 3)`` float32 array.

    Args:
        raw: The serialized message (CDR with its 4-byte encapsulation header, or ROS 1).
        typestore: The rosbags typestore of the recording (its classes are used).
        ros1: Whether ``raw`` is a ROS 1 serialization.

    Returns:
        The message (the typestore's class; ``points`` an array, channel values arrays in
        native byte order), or None if ``raw`` does not fit the layout.
    """
    view = memoryview(raw).cast('B')
    if not ros1 and (len(view) < 4 or bytes(view[:2]) not in (b'\x00\x00', b'\x00\x01')):
        return None
    cur = _Cursor(view, ros1=ros1)
    try:
        seq = {'seq': cur.u32()} if ros1 else {}
        sec, nanosec = cur.i32(), cur.u32()
        frame_id = cur.text()
        points = cur.floats(3 * cur.u32()).reshape(-1, 3)
        channels = [(cur.text(), cur.floats(cur.u32())) for _ in range(cur.u32())]
    except (_Misfit, UnicodeDecodeError):
        return None
    if not cur.finished():
        return None
    types = typestore.types
    header = types['std_msgs/msg/Header'](
        **seq, stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
        frame_id=frame_id)
    channel = types['sensor_msgs/msg/ChannelFloat32']
    return types[POINT_CLOUD](header=header, points=points,
                              channels=[channel(name=name, values=values)
                                        for name, values in channels])


def fast_decoder(typestore: Any, msgtype: str, reference: Any, *, ros1: bool = False,
                 ) -> Callable[[bytes | memoryview], Any | None] | None:
    """Return a vectorized decoder of ``msgtype`` for a reader's typestore, if there is one.

    Args:
        typestore: The typestore the reader decodes with (built from the bag's definitions).
        msgtype: The connection's message type.
        reference: A typestore with the standard definitions (Jazzy's; Noetic's for ROS 1).
        ros1: Whether the recording is a ROS 1 bag.

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
    return lambda raw: decode_point_cloud(raw, typestore, ros1=ros1)
