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
"""Vectorized CDR encoding of the two outputs that grow with the trajectory.

``nav_msgs/Path`` and ``geometry_msgs/PoseArray`` carry every keyframe pose and are written
once per keyframe, so a replay serializes O(n^2) poses. rosbags' generated serializer visits
each pose in Python; here each pose is packed by one ``struct`` call into a buffer in the
exact little-endian CDR layout (XCDR1, the layout rosbags and ROS 2 write), which the tests
compare byte for byte with ``serialize_cdr`` of the Jazzy typestore. Messages outside that
shape (a Path whose poses carry different frames) return None and take rosbags' path.

Successive messages of one topic repeat most of their poses: the back-end keeps the message
objects of keyframes that no longer move. An :class:`Encoder` (one per topic, as the replay's
writer keeps them) keeps its buffer and packs only the poses that are not the same object at
the same place as in the previous message, so a keyframe's output costs the same early and
late in a long run (apart from copying the bytes out).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
import operator
import struct
from typing import Any

import numpy as np

#: CDR encapsulation header: little-endian plain CDR.
_CDR_LE = b'\x00\x01\x00\x00'


def _align(n: int, to: int) -> int:
    """Return n rounded up to a multiple of ``to``."""
    return -(-n // to) * to


@lru_cache(maxsize=16)   # one frame name per topic
def _prefix_layout(name_size: int) -> struct.Struct:
    """Return the layout of a std_msgs/Header and a sequence length after it.

    stamp (int32, uint32), the frame name's length, the name (name_size bytes, NUL too), zero
    padding to 4 and the uint32 sequence length; offsets count from the body.
    """
    return struct.Struct(f'<iII{name_size}s{_align(12 + name_size, 4) - 12 - name_size}xI')


def _prefix(header: Any, count: int) -> bytes:
    """Return the CDR body of ``header`` followed by a sequence length ``count``."""
    name = header.frame_id.encode() + b'\x00'
    return _prefix_layout(len(name)).pack(header.stamp.sec, header.stamp.nanosec, len(name),
                                          name, count)


#: A geometry_msgs/Pose: seven float64 (8-aligned in every message that holds one).
_POSE = struct.Struct('<7d')


@lru_cache(maxsize=16)   # one frame name per topic: the same layout at every message
def _stamped_layout(name_size: int) -> struct.Struct:
    """Return the layout of an 8-aligned PoseStamped whose frame name takes name_size bytes.

    stamp (int32, uint32), the name's length (uint32), the name (NUL too), zero padding to 8,
    then the pose's seven float64.
    """
    return struct.Struct(f'<iII{name_size}s{_align(12 + name_size, 8) - 12 - name_size}x7d')


class _Packed:
    """The elements of a sequence in their CDR layout, kept from message to message.

    Only the objects that are not the same object at the same place as in the previous
    message (packed with the same key) are packed again.
    """

    def __init__(self) -> None:
        """Start with nothing packed."""
        self._objs: list[Any] = []
        self._key: object = None
        self._buf = bytearray()

    def fresh(self, objs: list[Any], key: object) -> list[int]:
        """Return the places of ``objs`` to pack (all of them for another key)."""
        old = self._objs if key == self._key else []
        m = min(len(objs), len(old))
        same = np.fromiter(map(operator.is_, old[:m], objs[:m]), dtype=bool, count=m)
        return [*np.flatnonzero(~same).tolist(), *range(m, len(objs))]

    def pack(self, objs: list[Any], key: object, fresh: list[int], size: int,
             pack: Callable[[bytearray, int, Any], None]) -> memoryview:
        """Pack the objects at the places ``fresh``, each into ``size`` bytes by ``pack``.

        ``pack`` is called with the buffer, the element's byte offset and the object.

        Returns:
            The bytes of all ``objs``' elements (a view, valid until the next call).
        """
        self._objs, self._key = [], key   # a failure below leaves nothing to reuse
        total = size * len(objs)
        if len(self._buf) < total:   # a new buffer: the last one's views may still be held
            self._buf = self._buf + bytes(max(total, 2 * len(self._buf)) - len(self._buf))
        for i in fresh:
            pack(self._buf, i * size, objs[i])
        self._objs = list(objs)
        return memoryview(self._buf)[:total]


def _pack_pose(buf: bytearray, at: int, p: Any) -> None:
    """Pack a geometry_msgs/Pose at byte ``at`` of ``buf``."""
    pos, q = p.position, p.orientation
    _POSE.pack_into(buf, at, pos.x, pos.y, pos.z, q.x, q.y, q.z, q.w)


class _MixedFrames(Exception):
    """A Path's poses carry different frame names (their elements differ in layout)."""


class Encoder:
    """Encodes the Paths and PoseArrays of one topic, packing only the poses that changed."""

    def __init__(self) -> None:
        """Start with nothing remembered."""
        self._path = _Packed()
        self._array = _Packed()

    def encode(self, msg: Any, msgtype: str) -> bytes | None:
        """Return the CDR bytes of a Path or PoseArray, or None for other messages."""
        if msgtype == 'nav_msgs/msg/Path':
            return self._encode_path(msg)
        if msgtype == 'geometry_msgs/msg/PoseArray':
            return self._encode_pose_array(msg)
        return None

    def _encode_pose_array(self, msg: Any) -> bytes:
        """Return the CDR bytes of a geometry_msgs/msg/PoseArray."""
        poses = msg.poses
        prefix = _prefix(msg.header, len(poses))
        if not poses:
            return _CDR_LE + prefix
        fresh = self._array.fresh(poses, None)
        packed = self._array.pack(poses, None, fresh, _POSE.size, _pack_pose)
        return b''.join((_CDR_LE, prefix, bytes(_align(len(prefix), 8) - len(prefix)), packed))

    def _encode_path(self, msg: Any) -> bytes | None:
        """Return the CDR bytes of a nav_msgs/msg/Path, or None if its poses' frames differ."""
        poses = msg.poses
        prefix = _prefix(msg.header, len(poses))
        if not poses:
            return _CDR_LE + prefix
        frame = str(poses[0].header.frame_id)
        name = frame.encode() + b'\x00'
        layout = _stamped_layout(len(name))

        def pack(buf: bytearray, at: int, p: Any) -> None:
            header, pose = p.header, p.pose
            if str(header.frame_id) != frame:   # the others were packed with this frame
                raise _MixedFrames
            pos, q = pose.position, pose.orientation
            layout.pack_into(buf, at, header.stamp.sec, header.stamp.nanosec, len(name), name,
                             pos.x, pos.y, pos.z, q.x, q.y, q.z, q.w)

        try:
            packed = self._path.pack(poses, frame, self._path.fresh(poses, frame), layout.size,
                                     pack)
        except _MixedFrames:
            return None
        # Every element but the first starts 8-aligned (each ends with a float64); the first
        # starts where the sequence length left off, its padding before the pose differs.
        head = 12 + len(name)
        pad = _align(len(prefix) + head, 8) - len(prefix) - head
        return b''.join((_CDR_LE, prefix, packed[:head], bytes(pad),
                         packed[layout.size - _POSE.size:]))


def encode(msg: Any, msgtype: str) -> bytes | None:
    """Return the CDR bytes of a Path or PoseArray, or None for other messages (no memory)."""
    return Encoder().encode(msg, msgtype)
