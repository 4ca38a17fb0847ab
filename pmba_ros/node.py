"""The ROS 2 node ``pmba_node``: the only module that imports rclpy (lazily, in functions).

Wiring only: parameters -> :class:`~pmba_ros.backend.config.BackendConfig`, subscriptions
(tracks, keyframe poses, CameraInfo), publishers (path, keyframes, landmarks with a
transient-local QoS, odometry, ``/diagnostics``), the map -> odom broadcaster (tf2_ros, or a
plain ``/tf`` publisher if tf2_ros is missing) and the services ``~/reset``
(std_srvs/Trigger), ``~/pause`` (std_srvs/SetBool) and ``~/save`` (std_srvs/Trigger). The
callbacks only enqueue messages into a bounded queue (drops are counted and reported in the
diagnostics); a worker thread feeds :class:`~pmba_ros.backend.logic.BackendLogic` and
publishes its outputs, so solving never blocks the executor. Run with
``ros2 run pmba_ros pmba_node --ros-args --params-file config/pmba.yaml``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import fields
import importlib
import logging
import queue
import threading
from typing import Any

from pmba_ros._process import tune_process
from pmba_ros.backend.config import NODE_NAME, BackendConfig
from pmba_ros.backend.logic import DIAGNOSTICS_TOPIC, TF_TOPIC, BackendLogic
from pmba_ros.backend.outputs import RclpyBackend
from pmba_ros.core import warmup

logger = logging.getLogger(__name__)

_STOP = object()
_WORKER_POLL_S = 0.1
_JOIN_TIMEOUT_S = 5.0


def _msg_type(name: str) -> Any:
    """Return the rclpy message/service class 'pkg/msg/Name' (imported lazily)."""
    pkg, kind, cls = name.split('/')
    return getattr(importlib.import_module(f'{pkg}.{kind}'), cls)


def declare_config(node: Any) -> BackendConfig:
    """Declare every :class:`BackendConfig` field as a parameter and build the config.

    Raises:
        ValueError: If a parameter value is invalid.
    """
    defaults = BackendConfig()
    values = {}
    for f in fields(BackendConfig):
        values[f.name] = node.declare_parameter(f.name, getattr(defaults, f.name)).value
    return BackendConfig.from_params(values)


class PmbaNode:
    """The node's wiring around a :class:`BackendLogic` (composition over ``rclpy.node.Node``).

    Args:
        node: An ``rclpy.node.Node`` (``rclpy.create_node('pmba_node')`` in :func:`main`).
        start_worker: Start the solver thread (tests may drive :meth:`process_pending`).
    """

    def __init__(self, node: Any, *, start_worker: bool = True) -> None:
        """Declare parameters, create the interfaces and start the worker."""
        from rclpy.qos import (
            DurabilityPolicy,
            HistoryPolicy,
            QoSProfile,
            ReliabilityPolicy,
        )

        self.node = node
        self.config = cfg = declare_config(node)
        self.logic = BackendLogic(cfg, RclpyBackend())
        self._lock = threading.Lock()
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=cfg.queue_size)
        self._drops: Counter[str] = Counter()
        self._drops_lock = threading.Lock()
        self._stop = threading.Event()

        reliability = (ReliabilityPolicy.RELIABLE if cfg.qos_reliability == 'reliable'
                       else ReliabilityPolicy.BEST_EFFORT)
        sub_qos = QoSProfile(depth=cfg.qos_depth, reliability=reliability,
                             history=HistoryPolicy.KEEP_LAST)
        pub_qos = QoSProfile(depth=cfg.qos_depth, reliability=ReliabilityPolicy.RELIABLE,
                             history=HistoryPolicy.KEEP_LAST)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             history=HistoryPolicy.KEEP_LAST)
        tracks_type = ('sensor_msgs/msg/PointCloud2' if cfg.feature_layout == 'named'
                       else 'sensor_msgs/msg/PointCloud')
        kf_type = ('nav_msgs/msg/Odometry' if cfg.keyframe_type == 'odometry'
                   else 'geometry_msgs/msg/PoseStamped')
        self.subscriptions = [
            node.create_subscription(_msg_type(tracks_type), cfg.features_topic,
                                     self._enqueuer('tracks'), sub_qos),
            node.create_subscription(_msg_type('sensor_msgs/msg/CameraInfo'),
                                     cfg.camera_info_topic, self._enqueuer('camera_info'),
                                     sub_qos),
        ]
        if cfg.keyframe_source == 'keyframe_topic':
            self.subscriptions.append(node.create_subscription(
                _msg_type(kf_type), cfg.keyframe_topic, self._enqueuer('keyframe'), sub_qos))
        self.publishers: dict[str, Any] = {
            cfg.path_topic: node.create_publisher(_msg_type('nav_msgs/msg/Path'),
                                                  cfg.path_topic, pub_qos),
            cfg.keyframes_topic: node.create_publisher(_msg_type('geometry_msgs/msg/PoseArray'),
                                                       cfg.keyframes_topic, pub_qos),
            cfg.landmarks_topic: node.create_publisher(_msg_type('sensor_msgs/msg/PointCloud2'),
                                                       cfg.landmarks_topic, latched),
            cfg.odometry_topic: node.create_publisher(_msg_type('nav_msgs/msg/Odometry'),
                                                      cfg.odometry_topic, pub_qos),
            DIAGNOSTICS_TOPIC: node.create_publisher(
                _msg_type('diagnostic_msgs/msg/DiagnosticArray'), DIAGNOSTICS_TOPIC, pub_qos),
        }
        self.tf_broadcaster: Any = None
        if cfg.publish_tf:
            try:
                from tf2_ros import TransformBroadcaster

                self.tf_broadcaster = TransformBroadcaster(node)
            except ImportError:
                node.get_logger().warning('tf2_ros not found: publishing map->odom on /tf')
                self.publishers[TF_TOPIC] = node.create_publisher(
                    _msg_type('tf2_msgs/msg/TFMessage'), TF_TOPIC, pub_qos)
        trigger = _msg_type('std_srvs/srv/Trigger')
        self.services = [
            node.create_service(trigger, '~/reset', self._on_reset),
            node.create_service(_msg_type('std_srvs/srv/SetBool'), '~/pause', self._on_pause),
            node.create_service(trigger, '~/save', self._on_save),
        ]
        self._worker: threading.Thread | None = None
        if start_worker:
            self._worker = threading.Thread(target=self._run, name='pmba_solver', daemon=True)
            self._worker.start()
        node.get_logger().info(
            f'pmba_node: mode {cfg.mode}, window {cfg.window_size}, layout '
            f'{cfg.feature_layout}, tracks on {cfg.features_topic!r}, keyframes on '
            f'{cfg.keyframe_topic!r}')

    # --- callbacks (executor thread): enqueue only ------------------------------------------

    def _enqueuer(self, kind: str) -> Any:
        def callback(msg: Any) -> None:
            try:
                self._queue.put_nowait((kind, msg))
            except queue.Full:
                with self._drops_lock:
                    self._drops[f'queue_full_{kind}'] += 1
        return callback

    def _on_reset(self, request: Any, response: Any) -> Any:
        del request
        with self._lock:
            self.logic.reset()
        response.success = True
        response.message = 'back-end reset'
        return response

    def _on_pause(self, request: Any, response: Any) -> Any:
        with self._lock:
            self.logic.set_paused(bool(request.data))
        response.success = True
        response.message = 'paused' if request.data else 'resumed'
        return response

    def _on_save(self, request: Any, response: Any) -> Any:
        del request
        try:
            with self._lock:
                paths = self.logic.save(self.config.save_directory)
        except Exception as err:
            response.success = False
            response.message = f'save failed: {err}'
            return response
        response.success = True
        response.message = 'wrote ' + ', '.join(str(p) for p in paths)
        return response

    # --- worker thread ----------------------------------------------------------------------

    def _dispatch(self, kind: str, msg: Any) -> None:
        if kind == 'tracks':
            self.logic.on_tracks(msg)
        elif kind == 'keyframe':
            self.logic.on_keyframe(msg)
        else:
            self.logic.on_camera_info(msg)

    def process_pending(self) -> int:
        """Handle every queued message (worker body; tests call it directly).

        Returns:
            The number of messages handled.
        """
        handled = 0
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return handled
            if item is _STOP:
                self._stop.set()
                return handled
            self._handle(*item)
            handled += 1

    def _handle(self, kind: str, msg: Any) -> None:
        with self._drops_lock:
            drops = dict(self._drops)
            self._drops.clear()
        with self._lock:
            for reason, n in drops.items():
                self.logic.count(reason, n)
            self._dispatch(kind, msg)
            outputs = self.logic.step()
        self.publish(outputs)

    def publish(self, outputs: list[tuple[str, Any]]) -> None:
        """Publish ``(topic, msg)`` outputs of the logic."""
        for topic, msg in outputs:
            try:
                if topic == TF_TOPIC and self.tf_broadcaster is not None:
                    self.tf_broadcaster.sendTransform(list(msg.transforms))
                elif topic in self.publishers:
                    self.publishers[topic].publish(msg)
            except Exception as err:
                self.node.get_logger().error(f'publishing on {topic} failed: {err}')

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                item = self._queue.get(timeout=_WORKER_POLL_S)
            except queue.Empty:
                continue
            if item is _STOP:
                break
            try:
                self._handle(*item)
            except Exception:
                logger.exception('pmba worker: unexpected error')

    def close(self) -> None:
        """Stop the worker (pending messages are discarded) and destroy the node."""
        self._stop.set()
        try:
            self._queue.put_nowait(_STOP)
        except queue.Full:
            pass
        if self._worker is not None:
            self._worker.join(timeout=_JOIN_TIMEOUT_S)
        self.node.destroy_node()


def main(args: list[str] | None = None) -> None:
    """Entry point ``pmba_node`` (Jazzy idiom: init, spin, destroy, try_shutdown)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException

    tune_process()
    rclpy.init(args=args)
    node = rclpy.create_node(NODE_NAME)
    # Before subscribing, so that no message queues behind a first compilation.
    if not warmup.is_warm():
        node.get_logger().info('compiling the solver loops before subscribing (once per '
                               f'install; expected {warmup.expected_compile_text()})')
    seconds = warmup.warm_up()
    if seconds > 1.0:
        node.get_logger().info(f'solver loops ready in {seconds:.1f} s')
    try:
        wrapper = PmbaNode(node)
    except ValueError as err:
        node.get_logger().fatal(f'invalid parameters: {err}')
        node.destroy_node()
        rclpy.try_shutdown()
        raise SystemExit(1) from err
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        wrapper.close()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
