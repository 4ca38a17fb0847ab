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

"""Launch pmba_node paired with a visual front-end.

    ros2 launch pmba_ros pmba.launch.py frontend:=vins_fusion
    ros2 launch pmba_ros pmba.launch.py frontend:=openvins use_sim_time:=true
    ros2 launch pmba_ros pmba.launch.py frontend:=vins_mono params_file:=/path/my.yaml

Pairings (topics as the front-ends publish them; see docs/ros2_notes.md §3.1):

``vins_mono``
    VINS-Mono's tracker output ``/feature_tracker/feature`` (layout ``vins_mono``: five
    unnamed channels, id*NUM_OF_CAM+cam first) and ``/vins_estimator/keyframe_pose``
    (Odometry). Tracks carry normalized coordinates: no CameraInfo needed.
``vins_fusion``
    VINS-Fusion runs its tracker inside the estimator, so the tracks come from
    ``/vins_estimator/keyframe_point`` (layout ``per_point``: one channel
    ``[x_n, y_n, u, v, id]`` per point, same stamp as the keyframe pose) and
    ``/vins_estimator/keyframe_pose`` (Odometry).
``vins_fusion_ros2``
    The ROS 2 port (zinuok/VINS-Fusion-ROS2) publishes the same without a namespace:
    ``/keyframe_point``, ``/keyframe_pose``.
``openvins``
    ``/ov_msckf/loop_feats`` (layout ``per_point``, raw pixels only: needs the intrinsics),
    ``/ov_msckf/loop_pose`` (Odometry) and ``/ov_msckf/loop_intrinsics`` (CameraInfo).
    OpenVINS publishes these only while something subscribes.

``PAIRINGS`` below is plain data (the test suite checks it without ROS installed).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PAIRINGS = {
    'vins_mono': {
        'parameters': {'feature_layout': 'vins_mono', 'keyframe_type': 'odometry',
                       'num_cams': 1},
        'remappings': [('features', '/feature_tracker/feature'),
                       ('keyframe_pose', '/vins_estimator/keyframe_pose')],
    },
    'vins_fusion': {
        'parameters': {'feature_layout': 'per_point', 'keyframe_type': 'odometry'},
        'remappings': [('features', '/vins_estimator/keyframe_point'),
                       ('keyframe_pose', '/vins_estimator/keyframe_pose')],
    },
    'vins_fusion_ros2': {
        'parameters': {'feature_layout': 'per_point', 'keyframe_type': 'odometry'},
        'remappings': [('features', '/keyframe_point'),
                       ('keyframe_pose', '/keyframe_pose')],
    },
    'openvins': {
        'parameters': {'feature_layout': 'per_point', 'keyframe_type': 'odometry',
                       'camera_info_qos': 'reliable'},
        'remappings': [('features', '/ov_msckf/loop_feats'),
                       ('keyframe_pose', '/ov_msckf/loop_pose'),
                       ('camera_info', '/ov_msckf/loop_intrinsics')],
    },
}


def _node(context, *args, **kwargs):
    frontend = LaunchConfiguration('frontend').perform(context)
    if frontend not in PAIRINGS:
        raise RuntimeError(f'frontend:={frontend}: expected one of {", ".join(PAIRINGS)}')
    pairing = PAIRINGS[frontend]
    use_sim_time = LaunchConfiguration('use_sim_time').perform(context).lower() == 'true'
    return [Node(
        package='pmba_ros', executable='pmba_node', name='pmba_node', output='screen',
        parameters=[LaunchConfiguration('params_file').perform(context),
                    {**pairing['parameters'], 'use_sim_time': use_sim_time}],
        remappings=pairing['remappings'])]


def generate_launch_description():
    """Return the launch description (arguments frontend, params_file, use_sim_time)."""
    default_params = os.path.join(get_package_share_directory('pmba_ros'), 'config',
                                  'pmba.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('frontend', default_value='vins_fusion',
                              description='one of ' + ', '.join(PAIRINGS)),
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='pmba_node parameter file'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='true when replaying with ros2 bag play --clock'),
        OpaqueFunction(function=_node),
    ])
