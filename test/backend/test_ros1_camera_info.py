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

"""ROS 1 CameraInfo (upper-case ``K``, ``D``, ``R``, ``P``) from a ROS 1 bag, as ROS 2's."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.backend.tracks import parse_camera_info
from pmba_ros.backend.types import CameraModel
from pmba_ros.io.bags import iter_messages
from pmba_ros.sim.inputs import make_camera_info
from rosbags.rosbag1 import Writer
from rosbags.typesys import get_typestore, Stores

CAMERA = CameraModel(fx=458.654, fy=457.296, cx=367.215, cy=248.375,
                     distortion_model='plumb_bob',
                     d=np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]),
                     width=752, height=480)


def ros1_camera_info(ts1: Any, camera: CameraModel, stamp_ns: int) -> Any:
    """Return a ROS 1 (Noetic) sensor_msgs/CameraInfo of ``camera``."""
    types = ts1.types
    k = np.array([camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0])
    p = np.column_stack([k.reshape(3, 3), np.zeros(3)]).reshape(-1)
    stamp = types['builtin_interfaces/msg/Time'](sec=stamp_ns // 10**9,
                                                 nanosec=stamp_ns % 10**9)
    return types['sensor_msgs/msg/CameraInfo'](
        header=types['std_msgs/msg/Header'](seq=7, stamp=stamp, frame_id='cam0'),
        height=camera.height, width=camera.width, distortion_model=camera.distortion_model,
        D=np.asarray(camera.d, dtype=np.float64), K=k, R=np.eye(3).reshape(-1), P=p,
        binning_x=0, binning_y=0,
        roi=types['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0,
                                                      width=0, do_rectify=False))


def test_ros1_camera_info_from_a_ros1_bag_reads_like_ros2(tmp_path: Path) -> None:
    """A CameraInfo read back from a ROS 1 bag gives the model its ROS 2 twin gives."""
    ts1 = get_typestore(Stores.ROS1_NOETIC)
    bag = tmp_path / 'euroc.bag'
    msg = ros1_camera_info(ts1, CAMERA, 1_403_636_579_763_555_584)
    with Writer(bag) as writer:
        conn = writer.add_connection('/cam0/camera_info', 'sensor_msgs/msg/CameraInfo',
                                     typestore=ts1)
        writer.write(conn, 1_403_636_579_763_555_584,
                     ts1.serialize_ros1(msg, 'sensor_msgs/msg/CameraInfo'))
    (read,) = list(iter_messages([bag]))
    assert hasattr(read.msg, 'K') and not hasattr(read.msg, 'k')
    from_ros1 = parse_camera_info(read.msg)
    ros2 = make_camera_info(1, 'cam0', CAMERA, RosbagsBackend())
    from_ros2 = parse_camera_info(ros2)
    for model in (from_ros1, from_ros2):
        assert (model.fx, model.fy, model.cx, model.cy) == (CAMERA.fx, CAMERA.fy, CAMERA.cx,
                                                            CAMERA.cy)
        assert model.distortion_model == 'plumb_bob'
        np.testing.assert_array_equal(model.d, CAMERA.d)
    pixels = np.array([[100.0, 50.0], [700.0, 400.0]])
    np.testing.assert_array_equal(from_ros1.normalize(pixels), from_ros2.normalize(pixels))
