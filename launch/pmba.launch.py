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

Pairings (parameters and remappings per front-end, the topics as each publishes them):
``pmba_ros.backend.frontends.PAIRINGS``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from pmba_ros.backend.frontends import PAIRINGS


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
