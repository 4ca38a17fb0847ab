"""pmba_ros: Parallax Bundle Adjustment on Manifold (PMBA) back-end for visual front-ends.

The package imports without ROS: only :mod:`pmba_ros.node` needs rclpy, and it is never
imported from here.
"""

import logging

__version__ = '0.1.0'

logging.getLogger(__name__).addHandler(logging.NullHandler())
