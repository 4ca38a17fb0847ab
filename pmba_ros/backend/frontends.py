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
"""How the front-ends pmba_node pairs with publish their tracks and keyframe poses.

Plain data, read by ``launch/pmba.launch.py`` (parameters and remappings of the node) and by
``pmba replay`` (a recording's topics, where the configured ones were not recorded). Topics
as the front-ends publish them (``docs/ros_node.md``, front-end pairings):

``vins_mono``
    VINS-Mono's tracker output ``/feature_tracker/feature`` (layout ``vins_mono``: five
    unnamed channels, id*NUM_OF_CAM+cam first) and ``/vins_estimator/keyframe_pose``
    (Odometry). Tracks carry normalized coordinates: no CameraInfo needed. The body ->
    camera extrinsic on ``/vins_estimator/extrinsic`` (the keyframe poses name no body
    frame for TF), as for VINS-Fusion.
``vins_fusion``
    VINS-Fusion runs its tracker inside the estimator, so the tracks come from
    ``/vins_estimator/keyframe_point`` (layout ``per_point``: one channel
    ``[x_n, y_n, u, v, id]`` per point, same stamp as the keyframe pose) and
    ``/vins_estimator/keyframe_pose`` (Odometry).
``vins_fusion_ros2``
    The ROS 2 port (zinuok/VINS-Fusion-ROS2) publishes the same without a namespace:
    ``/keyframe_point``, ``/keyframe_pose``, ``/extrinsic``.
``openvins``
    ``/ov_msckf/loop_feats`` (layout ``per_point``, raw pixels only: needs the intrinsics),
    ``/ov_msckf/loop_pose`` (Odometry), ``/ov_msckf/loop_intrinsics`` (CameraInfo) and
    ``/ov_msckf/loop_extrinsic`` (camera 0 in the IMU frame).
    OpenVINS publishes these only while something subscribes.
"""

from __future__ import annotations

from typing import Any

__all__ = ['PAIRINGS']

PAIRINGS: dict[str, dict[str, Any]] = {
    'vins_mono': {
        'parameters': {'feature_layout': 'vins_mono', 'keyframe_type': 'odometry',
                       'num_cams': 1},
        'remappings': [('features', '/feature_tracker/feature'),
                       ('keyframe_pose', '/vins_estimator/keyframe_pose'),
                       ('extrinsic', '/vins_estimator/extrinsic')],
    },
    'vins_fusion': {
        'parameters': {'feature_layout': 'per_point', 'keyframe_type': 'odometry'},
        'remappings': [('features', '/vins_estimator/keyframe_point'),
                       ('keyframe_pose', '/vins_estimator/keyframe_pose'),
                       ('extrinsic', '/vins_estimator/extrinsic')],
    },
    'vins_fusion_ros2': {
        'parameters': {'feature_layout': 'per_point', 'keyframe_type': 'odometry'},
        'remappings': [('features', '/keyframe_point'),
                       ('keyframe_pose', '/keyframe_pose'),
                       ('extrinsic', '/extrinsic')],
    },
    'openvins': {
        'parameters': {'feature_layout': 'per_point', 'keyframe_type': 'odometry',
                       'camera_info_qos': 'reliable'},
        'remappings': [('features', '/ov_msckf/loop_feats'),
                       ('keyframe_pose', '/ov_msckf/loop_pose'),
                       ('camera_info', '/ov_msckf/loop_intrinsics'),
                       ('extrinsic', '/ov_msckf/loop_extrinsic')],
    },
}
"""Front-end -> the node's ``parameters`` and the ``remappings`` of its input topics."""
