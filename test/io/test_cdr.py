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
"""The vectorized Path / PoseArray encoder writes rosbags' CDR bytes exactly."""

from __future__ import annotations

import numpy as np
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.backend.outputs import header_msg, pose_stamped_msgs
from pmba_ros.io import cdr
from pmba_ros.io.bags import jazzy_typestore
import pytest


def _poses(n: int, frame: str, backend: RosbagsBackend, seed: int) -> list:
    rng = np.random.default_rng(seed)
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    stamps = np.sort(rng.integers(0, 2**40, n))
    return list(pose_stamped_msgs(stamps, frame, rng.normal(size=(n, 3)) * 100, quats,
                                  backend))


@pytest.mark.parametrize('n', [0, 1, 2, 7])
@pytest.mark.parametrize('frame', ['', 'm', 'map', 'odom', 'world_ned', 'a' * 13])
def test_path_and_pose_array_bytes_equal_rosbags(n: int, frame: str) -> None:
    """Every frame-name length (all paddings of the first and later poses) and sizes 0-7."""
    store = jazzy_typestore()
    backend = RosbagsBackend(store)
    header = header_msg(-5 * 10**9 + 3, frame[::-1], backend)   # negative sec too
    stamped = _poses(n, frame, backend, seed=n + len(frame))
    path = backend.new('nav_msgs/msg/Path', header=header, poses=stamped)
    array = backend.new('geometry_msgs/msg/PoseArray', header=header,
                        poses=[p.pose for p in stamped])
    for msg, msgtype in ((path, 'nav_msgs/msg/Path'), (array, 'geometry_msgs/msg/PoseArray')):
        raw = cdr.encode(msg, msgtype)
        assert raw == bytes(store.serialize_cdr(msg, msgtype))
        back = store.deserialize_cdr(raw, msgtype)
        assert len(back.poses) == n


def test_path_with_mixed_frames_falls_back() -> None:
    """Poses in different frames have different element sizes: rosbags serializes them."""
    backend = RosbagsBackend(jazzy_typestore())
    poses = _poses(2, 'map', backend, 0) + _poses(1, 'odom', backend, 1)
    path = backend.new('nav_msgs/msg/Path', header=header_msg(0, 'map', backend), poses=poses)
    assert cdr.encode(path, 'nav_msgs/msg/Path') is None
    assert cdr.encode(path.header, 'std_msgs/msg/Header') is None


def test_encoder_reuses_unchanged_poses_and_reads_the_rest() -> None:
    """A growing trajectory whose tail moves: each message's bytes equal rosbags' bytes."""
    store = jazzy_typestore()
    backend = RosbagsBackend(store)
    encoder = cdr.Encoder()
    stamped = _poses(5, 'map', backend, seed=0)
    for step in range(6):
        # Two new keyframes, and the last three poses replaced by new objects (they moved).
        stamped = stamped[:-3] + _poses(5, 'map', backend, seed=100 + step)
        if step == 3:
            stamped = stamped[::-1]   # objects at other places are read again
        header = header_msg(step * 10**8, 'map', backend)
        path = backend.new('nav_msgs/msg/Path', header=header, poses=stamped)
        array = backend.new('geometry_msgs/msg/PoseArray', header=header,
                            poses=[p.pose for p in stamped])
        for msg, msgtype in ((path, 'nav_msgs/msg/Path'),
                             (array, 'geometry_msgs/msg/PoseArray')):
            assert encoder.encode(msg, msgtype) == bytes(store.serialize_cdr(msg, msgtype))
    shorter = backend.new('nav_msgs/msg/Path', header=header, poses=stamped[:4])
    assert encoder.encode(shorter, 'nav_msgs/msg/Path') == bytes(
        store.serialize_cdr(shorter, 'nav_msgs/msg/Path'))
    odd = stamped[:4] + _poses(1, 'odom', backend, seed=7)
    mixed = backend.new('nav_msgs/msg/Path', header=header, poses=odd)
    assert encoder.encode(mixed, 'nav_msgs/msg/Path') is None


def test_encoder_keeps_its_buffer_right_through_any_sequence_of_messages() -> None:
    """Every message's bytes equal rosbags' bytes, whatever came before.

    Random growth, shrinking, moved and replaced poses, other frames, mixed frames (rosbags'
    path) and a message that fails to encode.
    """
    store = jazzy_typestore()
    backend = RosbagsBackend(store)
    rng = np.random.default_rng(3)
    encoder = cdr.Encoder()
    frames = ['map', 'odo', 'world', 'm']
    frame = 'map'
    stamped = _poses(3, frame, backend, seed=0)
    for step in range(120):
        op = rng.integers(0, 8)
        if op == 0:
            frame = frames[rng.integers(0, len(frames))]
            stamped = _poses(int(rng.integers(0, 40)), frame, backend, seed=step)
        elif op == 1:
            stamped = stamped[:int(rng.integers(0, len(stamped) + 1))]
        elif op == 2 and len(stamped) > 1:
            i, j = rng.choice(len(stamped), 2, replace=False)
            stamped[i], stamped[j] = stamped[j], stamped[i]
        else:
            stamped = list(stamped)
            for i in rng.choice(len(stamped), min(len(stamped), 3), replace=False):
                stamped[i] = _poses(1, frame, backend, seed=1000 + step)[0]
            stamped += _poses(int(rng.integers(0, 30)), frame, backend, seed=2000 + step)
        header = header_msg(step * 10**8, frames[step % len(frames)] * (step % 3), backend)
        array = backend.new('geometry_msgs/msg/PoseArray', header=header,
                            poses=[p.pose for p in stamped])
        assert encoder.encode(array, 'geometry_msgs/msg/PoseArray') == bytes(
            store.serialize_cdr(array, 'geometry_msgs/msg/PoseArray'))
        if step % 23 == 7 and stamped:   # a pose that cannot be read: nothing half-written
            unreadable = [*_poses(len(stamped), frame, backend, step), object()]
            broken = backend.new('nav_msgs/msg/Path', header=header, poses=unreadable)
            with pytest.raises(AttributeError):
                encoder.encode(broken, 'nav_msgs/msg/Path')
        path = backend.new('nav_msgs/msg/Path', header=header, poses=stamped)
        assert encoder.encode(path, 'nav_msgs/msg/Path') == bytes(
            store.serialize_cdr(path, 'nav_msgs/msg/Path'))
        if step % 17 == 5 and stamped:   # another frame: rosbags' path
            other = _poses(1, 'map' if frame != 'map' else 'odo', backend, step)
            for odd in (other + stamped[1:], stamped[:-1] + other):
                mixed = backend.new('nav_msgs/msg/Path', header=header, poses=odd)
                assert encoder.encode(mixed, 'nav_msgs/msg/Path') is None
