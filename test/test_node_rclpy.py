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

"""pmba_node in-process with real rclpy (the ``ros`` extra): own context and DDS domain each.

The rclpy wheels of PyPI run here, so these tests run in CI; tf2_ros and tf2_msgs are not on
PyPI, so the TF-less path is the real one here and tf2_ros is a recording stand-in.
"""

from __future__ import annotations

from collections.abc import Iterator
import logging
import sys
import threading
import time
import types
from typing import Any

import numpy as np
from pmba_ros.backend import outputs as out
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.extrinsics import Rigid
from pmba_ros.backend.input_restart import InputRestarts
from pmba_ros.backend.msg_backend import RclpyBackend
from pmba_ros.backend.parameters import RUNTIME_PARAMETERS
from pmba_ros.core import so3
from pmba_ros.node import MAP_TO_ODOM_TOPIC, PmbaNode
from pmba_ros.sim.bag import EUROC_CAM0
from pmba_ros.sim.inputs import make_camera_info, make_tracks
from pmba_ros.sim.rig import add_camera, EUROC_CAM1
from pmba_ros.sim.sequence import SimSequence, simulate_sequence
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from .ros_helpers import domain_id, isolate, spin_until, transient_local_qos

RELIABLE = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture
def ros(monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[Context, SingleThreadedExecutor]]:
    """Return an initialized context on its own localhost-only domain and an executor."""
    domain = domain_id()
    isolate(monkeypatch, domain)
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    executor = SingleThreadedExecutor(context=context)
    yield context, executor
    executor.shutdown()
    rclpy.shutdown(context=context)


@pytest.fixture(scope='module')
def seq() -> SimSequence:
    """Return a short simulated street."""
    return simulate_sequence('street', n_keyframes=16, seed=1)


def start(context: Context, executor: SingleThreadedExecutor, *, start_worker: bool = True,
          **params: Any) -> tuple[PmbaNode, Any]:
    """Start a PmbaNode with parameter overrides and a driver node on one executor.

    ``start_worker`` False: the test steps the worker itself.
    """
    node = rclpy.create_node('pmba_node', context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()])
    wrapper = PmbaNode(node, start_worker=start_worker)
    driver = rclpy.create_node('pmba_test_driver', context=context)
    executor.add_node(node)
    executor.add_node(driver)
    return wrapper, driver


def feed(executor: SingleThreadedExecutor, driver: Any, seq: SimSequence,
         period_s: float = 0.005) -> None:
    """Publish the sequence's CameraInfo, tracks and keyframe poses from ``driver``.

    One keyframe each ``period_s`` of spinning (the default: as fast as the test runs).
    """
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import CameraInfo, PointCloud

    backend = RclpyBackend()
    pub_tracks = driver.create_publisher(PointCloud, 'features', RELIABLE)
    pub_kf = driver.create_publisher(Odometry, 'keyframe_pose', RELIABLE)
    pub_info = driver.create_publisher(CameraInfo, 'camera_info', RELIABLE)
    assert spin_until(executor, lambda: min(p.get_subscription_count() for p in
                                            (pub_tracks, pub_kf, pub_info)) > 0)
    pub_info.publish(make_camera_info(int(seq.stamps_ns[0]), 'camera', seq.camera, backend))
    for i in range(len(seq)):
        pub_tracks.publish(make_tracks(seq.frames[i], 'vins_fusion', backend))
        pub_kf.publish(out.make_odometry(
            int(seq.stamps_ns[i]), 'odom', 'camera', seq.centers_odom[i],
            so3.to_quat_xyzw(seq.R_wc_odom[i]), np.eye(6) * 1e-3, backend))
        if period_s > 0.005:
            spin_until(executor, lambda: False, timeout_s=period_s)
        else:
            executor.spin_once(timeout_sec=period_s)


def statuses(arrays: list[Any], name: str) -> list[Any]:
    """Return the DiagnosticStatus entries called ``name`` of DiagnosticArrays."""
    return [s for a in arrays for s in a.status if s.name == name]


def test_outputs_without_tf2(ros: tuple[Context, SingleThreadedExecutor],
                             seq: SimSequence) -> None:
    """Every keyframe in the path, odometry at once, map -> odom re-sent, TF-off diagnostics."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import TransformStamped
    from nav_msgs.msg import Odometry, Path
    from sensor_msgs.msg import PointCloud2

    context, executor = ros
    wrapper, driver = start(context, executor, init_batch_size=10, deterministic=True,
                            tf_rate_hz=20)
    assert wrapper.tf_mode.startswith('off')
    got: dict[str, list[Any]] = {'path': [], 'odom': [], 'm2o': [], 'diag': [], 'lm': []}
    driver.create_subscription(Path, 'pmba/path', got['path'].append, RELIABLE)
    driver.create_subscription(Odometry, 'pmba/odometry', got['odom'].append, RELIABLE)
    driver.create_subscription(TransformStamped, MAP_TO_ODOM_TOPIC, got['m2o'].append, RELIABLE)
    driver.create_subscription(DiagnosticArray, '/diagnostics', got['diag'].append, RELIABLE)
    driver.create_subscription(PointCloud2, 'pmba/landmarks', got['lm'].append, QoSProfile(
        depth=1, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    try:
        feed(executor, driver, seq)
        assert spin_until(executor, lambda: bool(got['path'])
                          and len(got['path'][-1].poses) == len(seq), timeout_s=60.0)
        assert got['path'][-1].header.frame_id == 'map'
        stamps = {(o.header.stamp.sec, o.header.stamp.nanosec) for o in got['odom']}
        assert len(stamps) == len(seq)          # provisional and corrected poses
        assert len(got['odom']) > len(seq)
        assert spin_until(executor, lambda: len(got['m2o']) >= 5 and bool(got['lm']))
        m2o = got['m2o'][-1]
        assert (m2o.header.frame_id, m2o.child_frame_id) == ('map', 'odom')
        sent = len(got['m2o'])
        assert spin_until(executor, lambda: len(got['m2o']) >= sent + 4, timeout_s=5.0)
        node_diag = statuses(got['diag'], 'pmba_node: node')
        assert node_diag and 'TF off' in node_diag[-1].message
        assert node_diag[-1].level == node_diag[-1].WARN
        backend_diag = statuses(got['diag'], 'pmba_node: back-end')
        assert {kv.key: kv.value for kv in backend_diag[-1].values}['state'] == 'tracking'
    finally:
        wrapper.close()
        driver.destroy_node()


def test_provisional_odometry_before_the_solve(ros: tuple[Context, SingleThreadedExecutor],
                                               seq: SimSequence) -> None:
    """A keyframe's odometry is out before the worker has handled it (front-end pose)."""
    from nav_msgs.msg import Odometry

    context, executor = ros
    wrapper, driver = start(context, executor, start_worker=False)
    got: list[Any] = []
    driver.create_subscription(Odometry, 'pmba/odometry', got.append, RELIABLE)
    try:
        feed(executor, driver, seq)
        assert spin_until(executor, lambda: len(got) == len(seq))
        first = got[0].pose.pose.position
        np.testing.assert_allclose([first.x, first.y, first.z], seq.centers_odom[0], atol=1e-9)
        assert got[0].header.frame_id == 'map' and got[0].child_frame_id == 'camera'
        assert wrapper.process_pending() > 0     # the worker had not run before
    finally:
        wrapper.close()
        driver.destroy_node()


def test_provisional_odometry_again_after_the_input_starts_over(
        ros: tuple[Context, SingleThreadedExecutor], seq: SimSequence) -> None:
    """A recording played again (``pmba play --loop``): its keyframes' odometry at once again.

    Once the back-end has seen the restart (five keyframes stamped back in a row), the
    provisional poses follow it. Before, they waited for stamps past the first pass's
    newest: none of the second pass's keyframes had its odometry at once.
    """
    context, executor = ros
    wrapper, driver = start(context, executor)
    try:
        feed(executor, driver, seq)
        assert spin_until(executor, lambda: wrapper.logic.stats.keyframes == len(seq))
        assert wrapper._sent['provisional_odometry'] == len(seq)
        feed(executor, driver, seq, period_s=0.05)   # at 20 Hz
        assert spin_until(executor, lambda: wrapper.logic.stats.counters['input_restarts'] == 1)
        spin_until(executor, lambda: False, timeout_s=0.5)
        again = wrapper._sent['provisional_odometry'] - len(seq)
        assert len(seq) - 2 * InputRestarts.RUN <= again < len(seq), again
    finally:
        wrapper.close()
        driver.destroy_node()


def test_tf2_ros_broadcaster_when_importable(ros: tuple[Context, SingleThreadedExecutor],
                                             seq: SimSequence,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """With tf2_ros importable, map -> odom goes through its TransformBroadcaster."""
    sent: list[Any] = []

    class TransformBroadcaster:
        """Record what is sent."""

        def __init__(self, node: Any) -> None:
            """Take the node like tf2_ros does."""
            assert node.get_name() == 'pmba_node'

        def sendTransform(self, transform: Any) -> None:
            """Record."""
            sent.append(transform)

    monkeypatch.setitem(sys.modules, 'tf2_ros', types.SimpleNamespace(
        TransformBroadcaster=TransformBroadcaster))
    context, executor = ros
    wrapper, driver = start(context, executor, init_batch_size=10, deterministic=True,
                            tf_rate_hz=0)
    try:
        assert wrapper.tf_mode == 'tf2_ros'
        feed(executor, driver, seq)
        assert spin_until(executor, lambda: wrapper.logic.stats.keyframes == len(seq),
                          timeout_s=60.0)
        assert sent and sent[-1].child_frame_id == 'odom'
        assert sent[-1].header.frame_id == 'map'
    finally:
        wrapper.close()
        driver.destroy_node()


def test_parameters_descriptors_and_runtime_changes(
        ros: tuple[Context, SingleThreadedExecutor]) -> None:
    """Ints for floats, read-only descriptors, refusals with a reason, applied changes."""
    context, executor = ros
    wrapper, driver = start(context, executor, max_time_s=1, covariance_position_m2=2)
    node = wrapper.node
    try:
        assert wrapper.config.max_time_s == 1.0 and isinstance(wrapper.config.max_time_s, float)
        window = node.describe_parameter('window_size')
        assert window.read_only and window.integer_range[0].from_value == 2
        assert 'Free keyframes' in window.description
        assert 'one of' in node.describe_parameter('loss').additional_constraints
        assert not node.describe_parameter('max_iterations').read_only
        refused = node.set_parameters([Parameter('window_size', value=30)])[0]
        assert not refused.successful and 'read-only' in refused.reason
        refused = node.set_parameters([Parameter('loss', value='squared')])[0]
        assert not refused.successful and 'loss' in refused.reason
        refused = node.set_parameters([Parameter('max_iterations', value='three')])[0]
        assert not refused.successful and 'max_iterations' in refused.reason
        assert wrapper.config.loss == 'cauchy'
        ok = node.set_parameters([Parameter('max_iterations', value=5),
                                  Parameter('loss_scale_px', value=3)])
        assert all(r.successful for r in ok)
        assert wrapper.config.max_iterations == 5 and wrapper.config.loss_scale_px == 3.0
        wrapper.worker.enqueue('tracks', object())  # the worker applies it at its next message
        assert spin_until(executor, lambda: wrapper.logic.config.max_iterations == 5, 5.0)
        assert wrapper.logic.estimator.config.loss_scale_px == 3.0
        assert RUNTIME_PARAMETERS <= set(BackendConfig().to_params())
    finally:
        wrapper.close()
        driver.destroy_node()


def test_invalid_parameter_raises_naming_it(ros: tuple[Context, SingleThreadedExecutor]) -> None:
    """A wrong type or value raises with the parameter's name (main() makes it [FATAL])."""
    context, _ = ros
    for name, value in (('window_size', 1), ('max_time_s', 'fast'), ('mode', 'batch')):
        node = rclpy.create_node('pmba_node', context=context, parameter_overrides=[
            Parameter(name, value=value)])
        with pytest.raises(Exception, match=name):
            PmbaNode(node)
        node.destroy_node()


def test_qos_per_input_and_overrides(ros: tuple[Context, SingleThreadedExecutor]) -> None:
    """camera_info best effort by default, presets per input, qos_overrides win."""
    context, executor = ros
    wrapper, driver = start(context, executor, keyframe_qos='transient_local', **{
        'qos_overrides./features.subscription.reliability': 'best_effort'})
    try:
        subs = {s.topic_name: s.qos_profile for s in wrapper.subscriptions}
        assert subs['/camera_info'].reliability == ReliabilityPolicy.BEST_EFFORT
        assert subs['/keyframe_pose'].durability == DurabilityPolicy.TRANSIENT_LOCAL
        assert subs['/keyframe_pose'].reliability == ReliabilityPolicy.RELIABLE
        assert subs['/features'].reliability == ReliabilityPolicy.BEST_EFFORT
    finally:
        wrapper.close()
        driver.destroy_node()


def test_backend_logging_reaches_rosout(ros: tuple[Context, SingleThreadedExecutor]) -> None:
    """Back-end ``logging`` records come out of the node's logger on /rosout."""
    from rcl_interfaces.msg import Log

    context, executor = ros
    wrapper, driver = start(context, executor)
    got: list[Any] = []
    driver.create_subscription(Log, '/rosout', got.append, QoSProfile(
        depth=100, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    try:
        time.sleep(0.2)
        logging.getLogger('pmba_ros.backend.logic').warning('solver note %d', 42)
        assert spin_until(executor, lambda: any('solver note 42' in m.msg for m in got), 10.0)
        line = next(m for m in got if 'solver note 42' in m.msg)
        assert line.name == 'pmba_node' and line.level == Log.WARN
    finally:
        wrapper.close()
        driver.destroy_node()
    assert logging.getLogger('pmba_ros').propagate


def test_stale_input_warning(ros: tuple[Context, SingleThreadedExecutor]) -> None:
    """The 1 Hz diagnostics warn when no input arrives."""
    from diagnostic_msgs.msg import DiagnosticArray

    context, executor = ros
    wrapper, driver = start(context, executor, stale_input_s=0.5, publish_tf=False)
    got: list[Any] = []
    driver.create_subscription(DiagnosticArray, '/diagnostics', got.append, RELIABLE)
    try:
        assert spin_until(executor, lambda: any(
            'no input received' in s.message for s in statuses(got, 'pmba_node: node')), 5.0)
        status = statuses(got, 'pmba_node: node')[-1]
        assert status.level == status.WARN and 'TF off' not in status.message
        assert wrapper.tf_mode.startswith('disabled') and wrapper._tf_timer is None
        assert wrapper.node.set_parameters([Parameter('publish_tf', value=True)])[0].successful
        assert wrapper.tf_mode.startswith('off') and wrapper._tf_timer is not None
        # Switched off again: the diagnostics say so, not the mode it had.
        assert wrapper.node.set_parameters([Parameter('publish_tf', value=False)])[0].successful
        got.clear()
        assert spin_until(executor, lambda: any(
            {kv.key: kv.value for kv in s.values}.get('tf', '').startswith('disabled')
            for s in statuses(got, 'pmba_node: node')), 3.0)
    finally:
        wrapper.close()
        driver.destroy_node()


def test_use_sim_time_without_a_clock_is_named(
        ros: tuple[Context, SingleThreadedExecutor], seq: SimSequence) -> None:
    """With use_sim_time and no /clock (a bag played without --clock), input still arriving.

    The 1 Hz diagnostics run on the steady clock and name the missing clock. Before, their
    timer was on the node's clock, which stood at 0: no diagnostics at all, and nothing said
    why.
    """
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    context, executor = ros
    wrapper, driver = start(context, executor, stale_input_s=0.5, use_sim_time=True)
    got: list[Any] = []
    driver.create_subscription(DiagnosticArray, '/diagnostics', got.append, RELIABLE)
    try:
        feed(executor, driver, seq, period_s=0.1)
        assert spin_until(executor, lambda: any(
            'no /clock has arrived' in s.message for s in statuses(got, 'pmba_node: node')),
            5.0)
        assert statuses(got, 'pmba_node: node')[-1].level == DiagnosticStatus.WARN
    finally:
        wrapper.close()
        driver.destroy_node()


def test_services_respond(ros: tuple[Context, SingleThreadedExecutor], tmp_path: Any) -> None:
    """~/pause, ~/reset and ~/save through real service clients."""
    from std_srvs.srv import SetBool, Trigger

    context, executor = ros
    wrapper, client_node = start(context, executor, save_directory=str(tmp_path))
    try:
        for srv_type, name, request in ((SetBool, '/pmba_node/pause', SetBool.Request(data=True)),
                                        (Trigger, '/pmba_node/reset', Trigger.Request()),
                                        (Trigger, '/pmba_node/save', Trigger.Request())):
            client = client_node.create_client(srv_type, name)
            assert spin_until(executor, client.service_is_ready)
            future = client.call_async(request)
            assert spin_until(executor, future.done)
            assert future.result().success, future.result().message
        assert wrapper.worker.paused   # the logic takes it at the worker's next step
        assert (tmp_path / 'pmba_keyframes.tum').exists()
    finally:
        wrapper.close()
        client_node.destroy_node()


def test_two_cameras(ros: tuple[Context, SingleThreadedExecutor], seq: SimSequence) -> None:
    """camera_info_topics: one subscription per camera id; camera 1's observations are used."""
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import CameraInfo, PointCloud

    T_c0c1 = EUROC_CAM0.inverse() @ EUROC_CAM1
    stereo = add_camera(seq, T_c0c1, camera_id=1)
    context, executor = ros
    node = rclpy.create_node('pmba_node', context=context, parameter_overrides=[
        Parameter('num_cams', value=2), Parameter('init_batch_size', value=10),
        Parameter('camera_info_topics', value=['camera_info', 'cam1/camera_info']),
        Parameter('camera_extrinsics', value=Rigid.identity().to_flat() + T_c0c1.to_flat())])
    wrapper = PmbaNode(node, start_worker=False)
    driver = rclpy.create_node('pmba_test_driver', context=context)
    executor.add_node(node)
    executor.add_node(driver)
    assert wrapper.config.camera_info_topics == ('camera_info', 'cam1/camera_info')
    backend = RclpyBackend()
    pubs = [driver.create_publisher(PointCloud, 'features', RELIABLE),
            driver.create_publisher(Odometry, 'keyframe_pose', RELIABLE),
            driver.create_publisher(CameraInfo, 'camera_info', RELIABLE),
            driver.create_publisher(CameraInfo, 'cam1/camera_info', RELIABLE)]
    try:
        assert spin_until(executor, lambda: min(p.get_subscription_count() for p in pubs) > 0)
        stamp = int(seq.stamps_ns[0])
        pubs[2].publish(make_camera_info(stamp, 'camera', seq.camera, backend))
        pubs[3].publish(make_camera_info(stamp, 'camera1', seq.camera, backend))
        assert spin_until(executor, lambda: wrapper.process_pending() >= 0
                          and 1 in wrapper.logic.cameras.others)
        for i in range(len(stereo)):
            pubs[0].publish(make_tracks(stereo.frames[i], 'vins_fusion', backend))
            pubs[1].publish(out.make_odometry(
                int(seq.stamps_ns[i]), 'odom', 'camera', seq.centers_odom[i],
                so3.to_quat_xyzw(seq.R_wc_odom[i]), np.eye(6) * 1e-3, backend))
            executor.spin_once(timeout_sec=0.005)
        logic = wrapper.logic
        assert spin_until(executor, lambda: wrapper.process_pending() >= 0
                          and logic.stats.keyframes == len(seq), timeout_s=60.0)
        assert logic.state == 'tracking'
        assert 1 in logic.cameras.rig and logic.cameras.rig[1][1] == 'parameters'
        assert logic.stats.counters['other_camera_observations'] == 0
        status = wrapper.node_status()
        values = {kv.key: kv.value for kv in status.values}
        assert int(values['received.camera_info']) >= 1
        assert int(values['received.camera_info.1']) >= 1
    finally:
        wrapper.close()
        driver.destroy_node()


def test_a_vins_extrinsic_on_its_topic_gives_body_poses(
        ros: tuple[Context, SingleThreadedExecutor], seq: SimSequence) -> None:
    """VINS-style input: body poses without a child frame, the extrinsic on its own topic."""
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import CameraInfo, PointCloud

    context, executor = ros
    topic = '/vins_estimator/extrinsic'
    wrapper, driver = start(context, executor, start_worker=False, init_batch_size=10,
                            extrinsic_topic=topic)
    backend = RclpyBackend()
    T = EUROC_CAM0
    R_b, C_b = T.inverse().apply_to_poses(seq.R_wc_odom, seq.centers_odom)
    pubs = [driver.create_publisher(PointCloud, 'features', RELIABLE),
            driver.create_publisher(Odometry, 'keyframe_pose', RELIABLE),
            driver.create_publisher(CameraInfo, 'camera_info', RELIABLE),
            driver.create_publisher(Odometry, topic, RELIABLE)]
    try:
        assert spin_until(executor, lambda: min(p.get_subscription_count() for p in pubs) > 0)
        pubs[2].publish(make_camera_info(int(seq.stamps_ns[0]), 'camera', seq.camera, backend))
        for i in range(len(seq)):
            stamp = int(seq.stamps_ns[i])
            pubs[3].publish(out.make_odometry(stamp, 'world', '', T.translation,
                                              so3.to_quat_xyzw(T.rotation), np.eye(6) * 1e-6,
                                              backend))
            pubs[0].publish(make_tracks(seq.frames[i], 'vins_fusion', backend))
            pubs[1].publish(out.make_odometry(stamp, 'world', '', C_b[i],
                                              so3.to_quat_xyzw(R_b[i]), np.eye(6) * 1e-3,
                                              backend))
            executor.spin_once(timeout_sec=0.005)
        logic = wrapper.logic
        assert spin_until(executor, lambda: wrapper.process_pending() >= 0
                          and logic.stats.keyframes == len(seq), timeout_s=60.0)
        assert logic.cameras.extrinsic_source == 'extrinsic_topic'
        assert logic.cameras.extrinsic is not None
        np.testing.assert_allclose(logic.cameras.extrinsic.to_flat(), T.to_flat(), atol=1e-12)
        assert logic.stats.counters['extrinsic_unknown'] == 0
        np.testing.assert_allclose(logic.frontend_trajectory().positions_xyz, C_b, atol=1e-9)
    finally:
        wrapper.close()
        driver.destroy_node()


def test_keyframes_from_tracks_take_their_poses_from_a_faster_stream(
        ros: tuple[Context, SingleThreadedExecutor], seq: SimSequence) -> None:
    """keyframe_source 'tracks': the pose topic, at 5x the tracks' rate, is sampled at them.

    Every tracks message is a keyframe with the stream's pose at its stamp (map -> odom is
    sent, as it is only with front-end poses); the poses between them are no keyframes.
    """
    from geometry_msgs.msg import TransformStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import CameraInfo, PointCloud

    context, executor = ros
    # Published far faster than real time, the two topics may arrive more than the default
    # association_timeout_s of stamps apart.
    node = rclpy.create_node('pmba_node', context=context, parameter_overrides=[
        Parameter('keyframe_source', value='tracks'), Parameter('init_batch_size', value=10),
        Parameter('deterministic', value=True), Parameter('association_timeout_s', value=30.0)])
    wrapper = PmbaNode(node, start_worker=False)
    driver = rclpy.create_node('pmba_test_driver', context=context)
    executor.add_node(node)
    executor.add_node(driver)
    backend = RclpyBackend()
    pubs = [driver.create_publisher(PointCloud, 'features', RELIABLE),
            driver.create_publisher(Odometry, 'keyframe_pose', RELIABLE),
            driver.create_publisher(CameraInfo, 'camera_info', RELIABLE)]
    got: list[Any] = []
    driver.create_subscription(TransformStamped, MAP_TO_ODOM_TOPIC, got.append, RELIABLE)
    try:
        assert spin_until(executor, lambda: min(p.get_subscription_count() for p in pubs) > 0)
        pubs[2].publish(make_camera_info(int(seq.stamps_ns[0]), 'camera', seq.camera, backend))
        for i in range(len(seq)):
            pubs[0].publish(make_tracks(seq.frames[i], 'vins_fusion', backend))
            j = min(i + 1, len(seq) - 1)
            for k in range(5 if j > i else 1):   # straight between keyframes, 5 per interval
                a = k / 5
                R = seq.R_wc_odom[i] @ so3.exp(a * so3.log(seq.R_wc_odom[i].T @ seq.R_wc_odom[j]))
                stamp = int(seq.stamps_ns[i] + a * (seq.stamps_ns[j] - seq.stamps_ns[i]))
                pubs[1].publish(out.make_odometry(
                    stamp, 'odom', 'camera', (1 - a) * seq.centers_odom[i]
                    + a * seq.centers_odom[j], so3.to_quat_xyzw(R), np.eye(6) * 1e-3, backend))
            executor.spin_once(timeout_sec=0.005)
        logic = wrapper.logic
        assert spin_until(executor, lambda: wrapper.process_pending() >= 0
                          and logic.stats.keyframes == len(seq), timeout_s=60.0)
        assert logic.state == 'tracking' and len(logic.optimized_trajectory()) == len(seq)
        np.testing.assert_allclose(logic.frontend_trajectory().positions_xyz,
                                   seq.centers_odom, atol=1e-9)
        assert not logic.stats.counters.get('keyframes_without_tracks')
        assert spin_until(executor, lambda: bool(got))   # only with front-end poses
    finally:
        wrapper.close()
        driver.destroy_node()


def test_publishers_the_inputs_cannot_match_are_named(
        ros: tuple[Context, SingleThreadedExecutor]) -> None:
    """A best-effort tracks publisher and a PoseStamped keyframe publisher, over DDS: one WARN.

    The keyframe publisher lives in a second context (its own DDS participant), as a front-end
    process would: one participant refuses a second type on a topic.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import PointCloud

    context, executor = ros
    wrapper, driver = start(context, executor, publish_tf=False)
    got: list[Any] = []
    driver.create_subscription(DiagnosticArray, '/diagnostics', got.append, RELIABLE)
    driver.create_publisher(PointCloud, 'features', QoSProfile(
        depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    other = Context()
    rclpy.init(context=other, domain_id=context.get_domain_id())
    front_end = rclpy.create_node('front_end', context=other)
    front_end.create_publisher(PoseStamped, 'keyframe_pose', RELIABLE)

    def warned() -> bool:
        return any('keyframe_pose is published as geometry_msgs/msg/PoseStamped' in s.message
                   and 'reliability; set features_qos' in s.message
                   for s in statuses(got, 'pmba_node: node'))
    try:
        assert spin_until(executor, warned, 10.0)
        status = next(s for s in statuses(got, 'pmba_node: node') if 'PoseStamped' in s.message)
        assert status.level == status.WARN
    finally:
        front_end.destroy_node()
        rclpy.shutdown(context=other)
        wrapper.close()
        driver.destroy_node()


def test_pause_and_reset_show_without_input(
        ros: tuple[Context, SingleThreadedExecutor]) -> None:
    """~/pause and ~/reset reach the diagnostics while the front-end sends nothing.

    The back-end's status came only with steps, which inputs trigger: a pause said nothing
    until the next message. A reset discards the queued messages (they belong to what it
    forgets) and says how many.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import SetBool, Trigger

    context, executor = ros
    wrapper, driver = start(context, executor, start_worker=False, publish_tf=False)
    got: list[Any] = []
    driver.create_subscription(DiagnosticArray, '/diagnostics', got.append, RELIABLE)
    try:
        pause = driver.create_client(SetBool, '/pmba_node/pause')
        assert spin_until(executor, pause.service_is_ready)
        future = pause.call_async(SetBool.Request(data=True))
        assert spin_until(executor, future.done) and future.result().success
        wrapper.process_pending()
        assert spin_until(executor, lambda: any(
            s.message == 'paused' for s in statuses(got, 'pmba_node: back-end')), 5.0)
        for _ in range(3):
            wrapper.worker.enqueue('tracks', object())
        reset = driver.create_client(Trigger, '/pmba_node/reset')
        assert spin_until(executor, reset.service_is_ready)
        future = reset.call_async(Trigger.Request())
        assert spin_until(executor, future.done)
        assert future.result().success and '3 queued messages discarded' in \
            future.result().message
        wrapper.process_pending()
        assert wrapper.logic.stats.counters['bad_tracks'] == 0
    finally:
        wrapper.close()
        driver.destroy_node()


def test_pause_and_reset_during_a_solve(ros: tuple[Context, SingleThreadedExecutor],
                                        seq: SimSequence,
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """~/pause answers while the initialization's BA runs; ~/reset abandons it, unpublished.

    The BA here takes a minute unless stopped (it checks in as the solver's iterations do).
    Both services waited for it, the executor blocked meanwhile (no diagnostics, no
    provisional poses), and the reset then published the forgotten initialization.
    """
    from nav_msgs.msg import Path
    from pmba_ros.init import pipeline
    from std_srvs.srv import SetBool, Trigger

    solving, ended = threading.Event(), threading.Event()
    real_solve = pipeline.solve

    def slow_solve(*args: Any, callback: Any = None, **kwargs: Any) -> Any:
        solving.set()
        try:
            for _ in range(6000):
                callback(None)
                time.sleep(0.01)
        finally:
            ended.set()
        return real_solve(*args, callback=callback, **kwargs)

    monkeypatch.setattr(pipeline, 'solve', slow_solve)
    context, executor = ros
    wrapper, driver = start(context, executor, init_batch_size=10, deterministic=True,
                            publish_tf=False)
    paths: list[Any] = []
    driver.create_subscription(Path, 'pmba/path', paths.append, RELIABLE)
    try:
        feed(executor, driver, seq)
        assert spin_until(executor, solving.is_set)
        for srv_type, name, request in ((SetBool, '/pmba_node/pause', SetBool.Request(data=True)),
                                        (Trigger, '/pmba_node/reset', Trigger.Request())):
            client = driver.create_client(srv_type, name)
            assert spin_until(executor, client.service_is_ready)
            future = client.call_async(request)
            assert spin_until(executor, future.done, 10.0), name
            assert future.result().success
            assert ended.is_set() == (name.endswith('reset'))
        spin_until(executor, lambda: False, 0.5)
        assert all(len(p.poses) < 10 for p in paths)   # the initialization's never came
        assert wrapper.logic.paused and wrapper.logic.state == 'paused'
    finally:
        wrapper.close()
        driver.destroy_node()


def test_two_nodes_in_one_process_log_and_report_as_themselves(
        ros: tuple[Context, SingleThreadedExecutor]) -> None:
    """Two PmbaNodes in one process (a component container): each one's lines are its own.

    The package logger is one per process: every node's back-end warning came out of both
    nodes' loggers, and both published their statuses under the same names.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.msg import Log
    from sensor_msgs.msg import CameraInfo
    from std_srvs.srv import Trigger

    context, executor = ros
    latched = [Parameter('camera_info_qos', value='transient_local')]   # none lost at match
    nodes = [PmbaNode(rclpy.create_node('pmba_a', context=context,
                                        parameter_overrides=latched)),
             PmbaNode(rclpy.create_node('pmba_node', namespace='robot2', context=context,
                                        parameter_overrides=latched))]
    driver = rclpy.create_node('pmba_test_driver', context=context)
    for node in (*[n.node for n in nodes], driver):
        executor.add_node(node)
    lines: list[Any] = []
    diagnostics: list[Any] = []
    driver.create_subscription(Log, '/rosout', lines.append, QoSProfile(
        depth=100, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    driver.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, RELIABLE)
    pubs = [driver.create_publisher(CameraInfo, topic, transient_local_qos(10))
            for topic in ('/camera_info', '/robot2/camera_info')]
    try:
        assert spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs))
        for pub, fx in zip(pubs, (-1.0, -2.0), strict=True):   # refused with a warning
            info = CameraInfo()
            info.k[0] = fx
            pub.publish(info)

        def said(text: str) -> list[str]:
            return [m.name for m in lines if text in m.msg]
        assert spin_until(executor, lambda: bool(said('got [-1.0') and said('got [-2.0')), 10.0)
        reset = driver.create_client(Trigger, '/robot2/pmba_node/reset')   # on the executor
        assert spin_until(executor, reset.service_is_ready)
        future = reset.call_async(Trigger.Request())
        assert spin_until(executor, future.done)
        assert spin_until(executor, lambda: bool(said('back-end reset')), 10.0)
        spin_until(executor, lambda: False, 0.3)   # a line under the other name would be here
        assert said('got [-1.0') == ['pmba_a']
        assert said('got [-2.0') == ['robot2.pmba_node']
        assert said('back-end reset') == ['robot2.pmba_node']
        names = {s.name for a in diagnostics for s in a.status}
        assert {'pmba_a: back-end', 'pmba_a: node', 'robot2/pmba_node: back-end',
                'robot2/pmba_node: node'} <= names
        nodes.pop().close()
        assert not logging.getLogger('pmba_ros').propagate   # pmba_a still routes its lines
    finally:
        for wrapper in nodes:
            wrapper.close()
        driver.destroy_node()
    assert logging.getLogger('pmba_ros').propagate
