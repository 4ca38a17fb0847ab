"""pmba_node with real rclpy (isolated context, executor, spin until a condition).

Runs under ``colcon test`` on a ROS 2 Jazzy machine; skips where rclpy is missing (our CI:
see ros2_notes.md §2 and §7, this module has not been run there).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import time
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402

from pmba_ros.backend import outputs as out  # noqa: E402
from pmba_ros.core import so3  # noqa: E402
from pmba_ros.node import PmbaNode  # noqa: E402
from pmba_ros.sim.sequence import simulate_sequence  # noqa: E402


@pytest.fixture
def ros() -> Iterator[tuple[Context, SingleThreadedExecutor]]:
    """Ros."""
    context = Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    yield context, executor
    executor.shutdown()
    rclpy.shutdown(context=context)


def spin_until(executor: SingleThreadedExecutor, condition: Callable[[], bool],
               timeout_s: float = 30.0) -> bool:
    """Spin until."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
        if condition():
            return True
    return False


def test_node_publishes_path_tf_and_diagnostics(
        ros: tuple[Context, SingleThreadedExecutor]) -> None:
    """Test: node publishes path tf and diagnostics."""
    context, executor = ros
    seq = simulate_sequence('street', n_keyframes=16, seed=1)
    node = rclpy.create_node('pmba_node', context=context, parameter_overrides=[
        Parameter('init_batch_size', value=10), Parameter('deterministic', value=True)])
    wrapper = PmbaNode(node)
    driver = rclpy.create_node('pmba_test_driver', context=context)
    executor.add_node(node)
    executor.add_node(driver)
    backend = out.RclpyBackend()
    from nav_msgs.msg import Odometry, Path
    from sensor_msgs.msg import CameraInfo, PointCloud, PointCloud2
    from tf2_msgs.msg import TFMessage

    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    pub_tracks = driver.create_publisher(PointCloud, 'features', qos)
    pub_kf = driver.create_publisher(Odometry, 'keyframe_pose', qos)
    pub_info = driver.create_publisher(CameraInfo, 'camera_info', qos)
    got: dict[str, list[Any]] = {'path': [], 'tf': [], 'landmarks': []}
    driver.create_subscription(Path, 'pmba/path', got['path'].append, qos)
    driver.create_subscription(TFMessage, '/tf', got['tf'].append, qos)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    driver.create_subscription(PointCloud2, 'pmba/landmarks', got['landmarks'].append, latched)
    try:
        assert spin_until(executor, lambda: pub_tracks.get_subscription_count() > 0
                          and pub_kf.get_subscription_count() > 0)
        pub_info.publish(out.make_camera_info(int(seq.stamps_ns[0]), 'camera', seq.camera,
                                              backend))
        for i in range(len(seq)):
            pub_tracks.publish(out.make_tracks(seq.frames[i], 'vins_fusion', backend))
            pub_kf.publish(out.make_odometry(
                int(seq.stamps_ns[i]), 'odom', 'camera', seq.centers_odom[i],
                so3.to_quat_xyzw(seq.R_wc_odom[i]), np.eye(6) * 1e-3, backend))
            executor.spin_once(timeout_sec=0.01)
        assert spin_until(executor, lambda: bool(got['path'])
                          and len(got['path'][-1].poses) == len(seq), timeout_s=60.0)
        assert got['path'][-1].header.frame_id == 'map'
        assert spin_until(executor, lambda: bool(got['tf']) and bool(got['landmarks']))
        tf = got['tf'][-1].transforms[0]
        assert (tf.header.frame_id, tf.child_frame_id) == ('map', 'odom')
    finally:
        wrapper.close()
        driver.destroy_node()


def test_services_respond(ros: tuple[Context, SingleThreadedExecutor], tmp_path: Any) -> None:
    """Test: services respond."""
    context, executor = ros
    node = rclpy.create_node('pmba_node', context=context, parameter_overrides=[
        Parameter('save_directory', value=str(tmp_path))])
    wrapper = PmbaNode(node)
    client_node = rclpy.create_node('pmba_test_client', context=context)
    executor.add_node(node)
    executor.add_node(client_node)
    from std_srvs.srv import SetBool, Trigger
    try:
        for srv_type, name, request in ((SetBool, '/pmba_node/pause', SetBool.Request(data=True)),
                                        (Trigger, '/pmba_node/reset', Trigger.Request()),
                                        (Trigger, '/pmba_node/save', Trigger.Request())):
            client = client_node.create_client(srv_type, name)
            assert spin_until(executor, client.service_is_ready)
            future = client.call_async(request)
            assert spin_until(executor, future.done)
            assert future.result().success, future.result().message
        assert (tmp_path / 'pmba_keyframes.tum').exists()
    finally:
        wrapper.close()
        client_node.destroy_node()
