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

"""The ROS 2 node ``pmba_node``: the only module that imports rclpy (lazily, in functions).

Wiring only: parameters (with descriptors; run-time ones applied by an on-set callback) ->
:class:`~pmba_ros.backend.config.BackendConfig`; subscriptions (tracks, keyframe poses,
CameraInfo, the front-end's extrinsic, TF; QoS per input, ``qos_overrides`` honoured; type
and QoS mismatches reported);
publishers (path, keyframes, transient-local landmarks, odometry, ``pmba/map_to_odom``,
``/diagnostics``); map -> odom on TF (tf2_ros, else a plain ``/tf`` publisher, else off with a
warning); services ``~/reset``, ``~/save`` (std_srvs/Trigger) and ``~/pause`` (SetBool).

Callbacks only enqueue into a bounded queue (drops are counted); a worker thread feeds
:class:`~pmba_ros.backend.logic.BackendLogic` and publishes its outputs, so solving never
blocks the executor. A keyframe pose is published on ``odometry_topic`` as it arrives (through
the newest map <- odom) and again when optimized; map -> odom is re-sent at ``tf_rate_hz``,
diagnostics at 1 Hz. Back-end ``logging`` goes to the node's logger (and /rosout), the
engine's per-solve lines only at ``--log-level debug``. Run with ``ros2 run pmba_ros
pmba_node --ros-args --params-file config/pmba.yaml``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import fields, replace
import importlib
import sys
import time
from typing import Any

from pmba_ros._process import tune_process
from pmba_ros.backend import config as settings
from pmba_ros.backend import outputs as out
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.input_check import InputCheck
from pmba_ros.backend.log_bridge import LogRoute
from pmba_ros.backend.logic import BackendLogic, DIAGNOSTICS_TOPIC, TF_TOPIC
from pmba_ros.backend.msg_backend import NodeMsgBackend, RclpyBackend
from pmba_ros.backend.parameters import declare_config
from pmba_ros.backend.status import node_level_and_message, received_values
from pmba_ros.backend.tracks import KEYFRAME_MSGTYPES, parse_keyframe, tracks_msgtype
from pmba_ros.backend.worker import LogicWorker
from pmba_ros.core import warmup
from pmba_ros.errors import MessageError, PmbaError
from pmba_ros.init import import_initialization
from pmba_ros.io.playback import ACK_TIMEOUT_S, CLOCK_PERIOD_S, MATCH_SETTLE_S, paced, wait_until

MAP_TO_ODOM_TOPIC = 'pmba/map_to_odom'
"""geometry_msgs/TransformStamped copy of every map -> odom sent (for users without tf2)."""

_DIAGNOSTICS_PERIOD_S = 1.0


def _msg_type(name: str) -> Any:
    """Return the rclpy message/service class 'pkg/msg/Name' (imported lazily)."""
    pkg, kind, cls = name.split('/')
    return getattr(importlib.import_module(f'{pkg}.{kind}'), cls)


# --- input QoS ----------------------------------------------------------------------------


def input_qos(preset: str, config: BackendConfig) -> Any:
    """Return the subscription QoS of a per-input preset (see :data:`INPUT_QOS`)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    if preset == 'sensor_data':
        from rclpy.qos import qos_profile_sensor_data
        return qos_profile_sensor_data
    reliable = (preset in ('reliable', 'transient_local')
                or (preset == '' and config.qos_reliability == 'reliable'))
    durability = (DurabilityPolicy.TRANSIENT_LOCAL if preset == 'transient_local'
                  else DurabilityPolicy.VOLATILE)
    return QoSProfile(depth=config.qos_depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=(ReliabilityPolicy.RELIABLE if reliable
                                   else ReliabilityPolicy.BEST_EFFORT),
                      durability=durability)


# --- the node -----------------------------------------------------------------------------


class PmbaNode:
    """The node's wiring around a :class:`BackendLogic` (composition over ``rclpy.node.Node``).

    Args:
        node: An ``rclpy.node.Node`` (``rclpy.create_node('pmba_node')`` in :func:`main`).
        start_worker: Start the solver thread (tests may drive :meth:`process_pending`).
    """

    def __init__(self, node: Any, *, start_worker: bool = True) -> None:
        """Declare parameters, create the interfaces and start the worker."""
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.qos_overriding_options import QoSOverridingOptions

        self.node = node
        self.config = cfg = declare_config(node)
        self.backend = NodeMsgBackend()
        # The logic always emits map -> odom: the node needs it for the provisional poses
        # and decides itself whether it goes to TF.
        self.logic = BackendLogic(replace(cfg, publish_tf=True), self.backend)
        self._log_route = LogRoute(node.get_logger())
        self.worker = LogicWorker(self.logic, self.publish, cfg.queue_size,
                                  closing=lambda: not node.context.ok())
        self._started = time.monotonic()
        self._map_to_odom: out.MapToOdom | None = None
        self._newest_provisional = -1
        self._restarts = 0   # the back-end's input restarts the provisional poses followed
        self._backend_status: list[Any] = []
        self._sent = Counter[str]()
        # Status names 'NODE: back-end' and 'NODE: node' (diagnostic_updater's 'node: task'),
        # namespace included: two nodes' statuses must not take each other's place.
        self.diagnostics_prefix = node.get_fully_qualified_name().lstrip('/')

        overrides = QoSOverridingOptions.with_default_policies()
        pub_qos = QoSProfile(depth=cfg.qos_depth, reliability=ReliabilityPolicy.RELIABLE,
                             history=HistoryPolicy.KEEP_LAST)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             history=HistoryPolicy.KEEP_LAST)
        self.inputs = InputCheck()
        self.subscriptions = [
            self._subscribe('tracks', tracks_msgtype(cfg.feature_layout), cfg.features_topic,
                            self._enqueuer('tracks'), cfg.features_qos, overrides),
            *self._subscribe_camera_infos(overrides),
            # With keyframe_source 'tracks' the poses are an optional stream, sampled there.
            self._subscribe('keyframe', KEYFRAME_MSGTYPES[cfg.keyframe_type], cfg.keyframe_topic,
                            self._on_keyframe, cfg.keyframe_qos, overrides)]
        if not cfg.camera_extrinsics:   # the front-end's own (it publishes it beside its poses)
            self.subscriptions.append(self._subscribe(
                'extrinsic', 'nav_msgs/msg/Odometry', cfg.extrinsic_topic,
                self._enqueuer('extrinsic'), cfg.keyframe_qos, overrides))
        self.subscriptions.extend(self._subscribe_tf())
        self.publishers: dict[str, Any] = {
            cfg.path_topic: node.create_publisher(_msg_type('nav_msgs/msg/Path'),
                                                  cfg.path_topic, pub_qos),
            cfg.keyframes_topic: node.create_publisher(_msg_type('geometry_msgs/msg/PoseArray'),
                                                       cfg.keyframes_topic, pub_qos),
            cfg.landmarks_topic: node.create_publisher(_msg_type('sensor_msgs/msg/PointCloud2'),
                                                       cfg.landmarks_topic, latched),
            cfg.odometry_topic: node.create_publisher(_msg_type('nav_msgs/msg/Odometry'),
                                                      cfg.odometry_topic, pub_qos),
            MAP_TO_ODOM_TOPIC: node.create_publisher(
                _msg_type('geometry_msgs/msg/TransformStamped'), MAP_TO_ODOM_TOPIC, pub_qos),
            DIAGNOSTICS_TOPIC: node.create_publisher(
                _msg_type('diagnostic_msgs/msg/DiagnosticArray'), DIAGNOSTICS_TOPIC, pub_qos),
        }
        self.tf_broadcaster: Any = None
        self.tf_mode = self._make_tf()
        trigger = _msg_type('std_srvs/srv/Trigger')
        self.services = [
            node.create_service(trigger, '~/reset', self._log_route.routed(self._on_reset)),
            node.create_service(_msg_type('std_srvs/srv/SetBool'), '~/pause',
                                self._log_route.routed(self._on_pause)),
            node.create_service(trigger, '~/save', self._log_route.routed(self._on_save)),
        ]
        node.add_on_set_parameters_callback(self._check_parameters)
        node.add_post_set_parameters_callback(self._apply_parameters)
        self._tf_timer: Any = None
        self._reset_tf_timer()
        # Steady: with use_sim_time and no /clock, a timer on the node's clock never fires.
        from rclpy.clock import Clock, ClockType
        self._diag_timer = node.create_timer(_DIAGNOSTICS_PERIOD_S, self.publish_diagnostics,
                                             clock=Clock(clock_type=ClockType.STEADY_TIME))
        if start_worker:
            with self._log_route.active():   # the thread logs under this node's name
                self.worker.start()
        node.get_logger().info(
            f'pmba_node: mode {cfg.mode}, window {cfg.window_size}, layout '
            f'{cfg.feature_layout}, tracks on {cfg.features_topic!r}, keyframes on '
            f'{cfg.keyframe_topic!r}, TF: {self.tf_mode}')

    def _make_tf(self) -> str:
        """Create the TF output and return how map -> odom is sent."""
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        if not self.config.publish_tf:
            return 'disabled (publish_tf false)'
        try:
            from tf2_ros import TransformBroadcaster
        except ImportError:
            pass
        else:
            self.tf_broadcaster = TransformBroadcaster(self.node)
            return 'tf2_ros'
        try:
            tf_type = _msg_type('tf2_msgs/msg/TFMessage')
        except ImportError:
            self.node.get_logger().warning(
                'neither tf2_ros nor tf2_msgs is importable: map -> odom is not sent on TF, '
                f'only on {MAP_TO_ODOM_TOPIC!r} (geometry_msgs/TransformStamped)')
            return 'off: neither tf2_ros nor tf2_msgs installed'
        self.publishers[TF_TOPIC] = self.node.create_publisher(
            tf_type, TF_TOPIC, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        return f'{TF_TOPIC} publisher (tf2_ros not installed)'

    def _subscribe_tf(self) -> list[Any]:
        """Subscribe to /tf_static and /tf for the body -> camera extrinsic, where it can.

        Not needed when ``camera_extrinsics`` is set; without tf2_msgs (a pip install) the
        back-end resolves the extrinsic from the parameter or the frames alone.
        """
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        if self.config.camera_extrinsics:
            return []
        try:
            tf_type = _msg_type('tf2_msgs/msg/TFMessage')
        except ImportError:
            return []
        static = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
        dynamic = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        return [self.node.create_subscription(tf_type, '/tf_static', self._enqueuer('tf'),
                                              static),
                self.node.create_subscription(tf_type, '/tf', self._enqueuer('tf'), dynamic)]

    # --- parameters at run time -----------------------------------------------------------

    def _changes(self, params: list[Any]) -> dict[str, Any]:
        known = {f.name for f in fields(BackendConfig)}
        return {p.name: p.value for p in params if p.name in known}

    def _check_parameters(self, params: list[Any]) -> Any:
        """Refuse (with the reason) parameter values the config does not accept."""
        from rcl_interfaces.msg import SetParametersResult

        try:
            replace(self.config, **self._changes(params))
        except (ValueError, TypeError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Any]) -> None:
        """Apply accepted run-time parameters (the worker takes them at its next message)."""
        changes = self._changes(params)
        if not changes:
            return
        old = self.config
        self.config = replace(old, **changes)
        self.worker.stage_config(self.config)
        if self.config.publish_tf and self.tf_mode.startswith('disabled'):
            self.tf_mode = self._make_tf()
        if (old.tf_rate_hz, old.publish_tf) != (self.config.tf_rate_hz, self.config.publish_tf):
            self._reset_tf_timer()
        self.node.get_logger().info(
            'parameters set: ' + ', '.join(f'{k}={v!r}' for k, v in changes.items()))

    def _reset_tf_timer(self) -> None:
        if self._tf_timer is not None:
            self.node.destroy_timer(self._tf_timer)
            self._tf_timer = None
        if self.config.tf_rate_hz > 0 and self.config.publish_tf:
            self._tf_timer = self.node.create_timer(1.0 / self.config.tf_rate_hz,
                                                    self._resend_map_to_odom)

    # --- callbacks (executor thread): enqueue only ------------------------------------------

    def _subscribe_camera_infos(self, overrides: Any) -> list[Any]:
        """Subscribe to ``camera_info_topic``, or to each of ``camera_info_topics`` (a rig).

        The reference camera's messages are queued as ``camera_info``, camera c's as
        ``camera_info.c``.
        """
        cfg = self.config
        topics = cfg.camera_info_topics or (cfg.camera_info_topic,)
        kinds = [('camera_info' if not cfg.camera_info_topics or cam == cfg.camera_id
                  else f'camera_info.{cam}') for cam in range(len(topics))]
        return [self._subscribe(kind, 'sensor_msgs/msg/CameraInfo', topic, self._enqueuer(kind),
                                cfg.camera_info_qos, overrides)
                for kind, topic in zip(kinds, topics, strict=True)]

    def _subscribe(self, kind: str, msgtype: str, topic: str, callback: Any, preset: str,
                   overrides: Any) -> Any:
        """Subscribe to an input, watched by :attr:`inputs` for type and QoS mismatches."""
        from rclpy.event_handler import SubscriptionEventCallbacks

        events = SubscriptionEventCallbacks(incompatible_qos=self.inputs.incompatible_qos(kind))
        sub = self.node.create_subscription(
            _msg_type(msgtype), topic, callback, input_qos(preset, self.config),
            qos_overriding_options=overrides, event_callbacks=events)
        self.inputs.watch(kind, sub.topic_name, msgtype)
        return sub

    def _enqueuer(self, kind: str) -> Any:
        def callback(msg: Any) -> None:
            self.worker.enqueue(kind, msg)
        return callback

    def _on_keyframe(self, msg: Any) -> None:
        self.worker.enqueue('keyframe', msg)
        if not self.worker.paused:
            self._publish_provisional(msg)

    def _publish_provisional(self, msg: Any) -> None:
        """Publish the keyframe's front-end pose mapped through the newest map <- odom."""
        cfg = self.config
        try:
            pose = parse_keyframe(msg, cfg.keyframe_type)
        except Exception:  # the worker counts and reports it
            return
        if (restarts := self.logic.stats.counters['input_restarts']) != self._restarts:
            # The input started again (a bag played in a loop), and the back-end with it.
            self._restarts, self._map_to_odom, self._newest_provisional = restarts, None, -1
        if pose.stamp_ns <= self._newest_provisional:
            return
        self._newest_provisional = pose.stamp_ns
        link = None if self._map_to_odom is None else self._map_to_odom.link
        try:
            odom = out.provisional_odometry(pose, link, cfg.map_frame, cfg.base_frame,
                                            cfg.odometry_covariance(optimized=False),
                                            self.backend)
            self.publishers[cfg.odometry_topic].publish(odom)
        except Exception as err:
            self.node.get_logger().error(f'publishing the provisional pose failed: {err}')
            return
        self._sent['provisional_odometry'] += 1

    def _on_reset(self, request: Any, response: Any) -> Any:
        del request

        def reset() -> None:
            self.logic.reset()
            self._map_to_odom, self._newest_provisional = None, -1

        discarded = self.worker.reset(reset)
        response.success = True
        response.message = f'back-end reset ({discarded} queued messages discarded)'
        return response

    def _on_pause(self, request: Any, response: Any) -> Any:
        self.worker.stage_pause(bool(request.data))   # not waiting for a solve in progress
        response.success = True
        response.message = 'paused' if request.data else 'resumed'
        return response

    def _on_save(self, request: Any, response: Any) -> Any:
        del request
        try:
            with self.worker.lock:
                if self.worker.cancelled:   # an update abandoned half-way: nothing to save
                    msg = 'the back-end is being reset or the node shut down'
                    raise PmbaError(msg)
                paths = self.logic.save(self.config.save_directory)
        except Exception as err:
            response.success = False
            response.message = f'save failed: {err}'
            return response
        response.success = True
        response.message = 'wrote ' + ', '.join(str(p) for p in paths)
        return response

    # --- worker thread ----------------------------------------------------------------------

    def process_pending(self) -> int:
        """Handle every queued message now (see :meth:`LogicWorker.process_pending`)."""
        return self.worker.process_pending()

    def publish(self, outputs: list[tuple[str, Any]]) -> None:
        """Publish ``(topic, msg)`` outputs of the logic."""
        for topic, msg in outputs:
            try:
                if topic == TF_TOPIC:
                    for transform in msg.transforms:
                        self._send_map_to_odom(transform)
                elif topic == DIAGNOSTICS_TOPIC:
                    for status in msg.status:
                        status.name = f'{self.diagnostics_prefix}: back-end'
                    self._backend_status = list(msg.status)
                    self.publish_diagnostics()
                elif topic in self.publishers:
                    self.publishers[topic].publish(msg)
            except Exception as err:
                if self.node.context.ok():   # else the process is shutting down
                    self.node.get_logger().error(f'publishing on {topic} failed: {err}')

    def _send_map_to_odom(self, transform: Any) -> None:
        """Remember map -> odom (for the provisional poses) and send it on TF and the topic."""
        self._map_to_odom = out.MapToOdom.of(transform)
        if not self.config.publish_tf:
            return
        self.publishers[MAP_TO_ODOM_TOPIC].publish(transform)
        if self.tf_broadcaster is not None:
            self.tf_broadcaster.sendTransform(transform)
        elif TF_TOPIC in self.publishers:
            self.publishers[TF_TOPIC].publish(self.backend.new('tf2_msgs/msg/TFMessage',
                                                               transforms=[transform]))
        self._sent['map_to_odom'] += 1

    def _resend_map_to_odom(self) -> None:
        """Timer: re-send the newest map -> odom stamped now (+ the tolerance)."""
        link = self._map_to_odom
        now_ns = self.node.get_clock().now().nanoseconds
        if link is None or now_ns <= 0:
            return
        stamp = now_ns + round(self.config.transform_tolerance_s * 1e9)
        try:
            self._send_map_to_odom(out.restamped(link.transform, stamp, self.backend))
        except Exception as err:
            self.node.get_logger().error(f're-sending map -> odom failed: {err}')

    def node_status(self) -> Any:
        """Return the node's own DiagnosticStatus (TF mode, input age, queue, counts)."""
        now = time.monotonic()
        last_input = self.worker.last_input
        age = now - (last_input if last_input >= 0 else self._started)
        received = self.worker.received()
        tf_off = (self.tf_mode if self.config.publish_tf and self.tf_mode.startswith('off')
                  else None)
        problems = self.inputs.problems(received, lambda topic: [
            i.topic_type for i in self.node.get_publishers_info_by_topic(topic)])
        if self.node.get_clock().now().nanoseconds == 0 and \
                now - self._started > self.config.stale_input_s:
            problems.append('use_sim_time is true and no /clock has arrived (play the recording '
                            'with --clock)')
        for problem in self.inputs.new(problems):
            self.node.get_logger().warning(problem)
        level, message = node_level_and_message(age, last_input >= 0, self.config.stale_input_s,
                                                tf_off, MAP_TO_ODOM_TOPIC, problems)
        values: dict[str, str | float] = {
            'tf': self.tf_mode if self.config.publish_tf else 'disabled (publish_tf false)',
            'input_age_s': round(age, 3),
            'queue_length': self.worker.queue_length(),
            'provisional_odometry': self._sent['provisional_odometry'],
            'map_to_odom_sent': self._sent['map_to_odom'], **received_values(received)}
        array = out.make_diagnostics(self.node.get_clock().now().nanoseconds,
                                     f'{self.diagnostics_prefix}: node', level, message, values,
                                     self.backend)
        return array.status[0]

    def publish_diagnostics(self) -> None:
        """Publish the newest back-end status with the node's status (also a 1 Hz timer)."""
        try:
            status = [*self._backend_status, self.node_status()]
            header = out.header_msg(self.node.get_clock().now().nanoseconds, '', self.backend)
            self.publishers[DIAGNOSTICS_TOPIC].publish(self.backend.new(
                'diagnostic_msgs/msg/DiagnosticArray', header=header, status=status))
        except Exception as err:
            if self.node.context.ok():   # else the process is shutting down
                self.node.get_logger().error(f'publishing diagnostics failed: {err}')

    def close(self) -> None:
        """Stop the worker (pending messages are discarded) and destroy the node."""
        self.worker.stop()
        self._log_route.close()
        self.node.destroy_node()


# --- pmba play -----------------------------------------------------------------------------


_CLOCK_BACKEND = RclpyBackend()


def play_messages(messages: Iterable[tuple[str, int, bytes]], types: dict[str, str], *,
                  rate: float = 1.0, clock: bool = False, delay_s: float = 0.0,
                  wait_for_subscribers_s: float = 0.0, ros_args: list[str] | None = None,
                  ) -> int:
    """Publish serialized messages with their recorded timing (``pmba play``).

    Args:
        messages: ``(topic, log_time_ns, CDR bytes)`` in log-time order.
        types: Message type of every topic, e.g. ``{'/features': 'sensor_msgs/msg/PointCloud'}``.
        rate: Playback speed factor (2.0: twice as fast).
        clock: Also publish ``/clock`` (rosgraph_msgs/Clock, every 25 ms and with each
            message) for nodes with ``use_sim_time``.
        delay_s: Wait this long after creating the publishers (discovery) before playing.
        wait_for_subscribers_s: Then wait up to this long until every topic has a
            subscriber. A volatile subscriber may still lose the first messages (its side of
            the match can come later); a transient-local one gets the last 100 per topic.
        ros_args: rclpy arguments (``--ros-args -r FROM:=TO ...``).

    Returns:
        The number of messages published (playback stops early on Ctrl-C), once every
        reliable subscriber acknowledged them (or ``ACK_TIMEOUT_S`` passed).

    Raises:
        MessageError: If a message type cannot be imported in this ROS environment.
        PmbaError: If rclpy is not installed.
    """
    try:
        import rclpy
    except ImportError as err:
        msg = ("this needs rclpy: pip install 'pmba_ros[ros]' (Python 3.11) or source a ROS 2 "
               f'Jazzy installation ({err})')
        raise PmbaError(msg) from err
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    classes: dict[str, Any] = {}
    for topic, type_name in sorted(types.items()):
        try:
            classes[topic] = _msg_type(type_name)
        except (ImportError, AttributeError, ValueError) as err:
            msg = (f'topic {topic!r}: message type {type_name} is not available to rclpy here '
                   f'({err}); install its package or leave the topic out with --topics')
            raise MessageError(msg) from err
    rclpy.init(args=ros_args)
    node = rclpy.create_node('pmba_play')
    count = 0
    try:
        # Transient local suits every reader: a volatile one sees no difference, and a
        # transient-local one also gets what was published before it matched the writer.
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        publishers = {topic: node.create_publisher(cls, topic, qos)
                      for topic, cls in classes.items()}
        clock_cls = _msg_type('rosgraph_msgs/msg/Clock')
        clock_pub = node.create_publisher(clock_cls, '/clock', qos) if clock else None
        time.sleep(delay_s)
        if wait_for_subscribers_s > 0:
            wait_until(lambda: all(p.get_subscription_count() for p in publishers.values()),
                       wait_for_subscribers_s, settle_s=MATCH_SETTLE_S)
        clock_period_s = CLOCK_PERIOD_S if clock_pub is not None else None
        for tick in paced(messages, rate, clock_period_s=clock_period_s):
            if clock_pub is not None:
                clock_pub.publish(clock_cls(clock=out.time_msg(tick.stamp_ns, _CLOCK_BACKEND)))
            if tick.topic is not None:
                publishers[tick.topic].publish(tick.raw)
                count += 1
        _wait_for_acks([*publishers.values(), *([clock_pub] if clock_pub else [])], node)
    except KeyboardInterrupt:
        pass
    except Exception:
        if rclpy.ok():   # else a SIGTERM shut the context down under a publish: stop there
            raise
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return count


def _wait_for_acks(publishers: list[Any], node: Any) -> None:
    from rclpy.duration import Duration

    deadline = time.monotonic() + ACK_TIMEOUT_S
    late = [p.topic_name for p in publishers
            if not p.wait_for_all_acked(Duration(seconds=max(deadline - time.monotonic(), 0.0)))]
    if late:
        node.get_logger().warning(f'{", ".join(late)}: not every subscriber acknowledged the '
                                  f'last messages within {ACK_TIMEOUT_S:g} s; some may be lost')


def main(args: list[str] | None = None) -> None:
    """Entry point ``pmba_node`` (Jazzy idiom: init, spin, destroy, try_shutdown).

    Invalid parameters end the process with one ``[FATAL]`` line and exit code 1.
    """
    import rclpy
    from rclpy.exceptions import ParameterException
    from rclpy.executors import ExternalShutdownException

    tune_process()
    try:
        rclpy.init(args=args)
    except Exception as err:
        print(f'[FATAL] [{settings.NODE_NAME}]: cannot initialize rclpy: {err}', file=sys.stderr)
        raise SystemExit(1) from None
    node = rclpy.create_node(settings.NODE_NAME)
    try:
        warmup.warm_up_beside_input(node.get_logger().info)
        import_initialization()
        wrapper = PmbaNode(node)
    except KeyboardInterrupt:
        node.destroy_node()
        rclpy.try_shutdown()
        return
    except (ValueError, ParameterException) as err:
        node.get_logger().fatal(f'invalid parameter: {err}')
        node.destroy_node()
        rclpy.try_shutdown()
        raise SystemExit(1) from None
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # A shutdown signal between two executor iterations surfaces as an RCLError about
        # the invalid context (an rclpy race), not as ExternalShutdownException.
        if rclpy.ok():
            raise
    finally:
        wrapper.close()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
