"""Wiring test of pmba_ros.node against a strict fake rclpy (ros2_notes.md §5.3).

The fakes copy rclpy Jazzy's signatures (keyword-only arguments included) and check types:
publishers accept only their declared message class, parameters keep the type of their
default. Message modules are filled with rosbags Jazzy classes. The test skips itself where
real rclpy is importable (test/test_node_rclpy.py runs there instead).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from enum import Enum
import sys
import time
import types
from typing import Any

import pytest

try:
    import rclpy  # noqa: F401
    HAVE_RCLPY = True
except ImportError:
    HAVE_RCLPY = False

from pmba_ros.sim.sequence import SimSequence, simulate_sequence
from test.backend.test_logic import BACKEND, camera_info_msg, keyframe_msg, tracks_msg

pytestmark = pytest.mark.skipif(HAVE_RCLPY, reason='real rclpy present: see test_node_rclpy.py')

MSG_PACKAGES = ('builtin_interfaces', 'std_msgs', 'geometry_msgs', 'nav_msgs', 'sensor_msgs',
                'diagnostic_msgs', 'tf2_msgs')


# --- the fakes ------------------------------------------------------------------------------


class ReliabilityPolicy(Enum):
    """Fake ReliabilityPolicy."""
    RELIABLE = 1
    BEST_EFFORT = 2


class DurabilityPolicy(Enum):
    """Fake DurabilityPolicy."""
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


class HistoryPolicy(Enum):
    """Fake HistoryPolicy."""
    KEEP_LAST = 1
    KEEP_ALL = 2


class QoSProfile:
    """Fake QoSProfile."""
    def __init__(self, *, depth: int | None = None, history: HistoryPolicy | None = None,
                 reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE,
                 durability: DurabilityPolicy = DurabilityPolicy.VOLATILE, **kwargs: Any) -> None:
        """Initialize."""
        if depth is None and history is None:
            msg = 'QoSProfile needs depth or history'
            raise ValueError(msg)
        assert not kwargs, kwargs
        self.depth, self.history = depth, history
        self.reliability, self.durability = reliability, durability


class ExternalShutdownException(Exception):
    """Fake ExternalShutdownException."""
    pass


@dataclass
class Parameter:
    """Fake Parameter."""
    name: str
    value: Any


class Publisher:
    """Fake Publisher."""
    def __init__(self, msg_type: type, topic: str, qos: QoSProfile) -> None:
        """Initialize."""
        self.msg_type, self.topic, self.qos = msg_type, topic, qos
        self.published: list[Any] = []

    def publish(self, msg: Any) -> None:
        """Publish."""
        assert isinstance(msg, self.msg_type), (type(msg), self.msg_type)
        self.published.append(msg)


@dataclass
class Subscription:
    """Fake Subscription."""
    msg_type: type
    topic: str
    callback: Callable[[Any], None]
    qos: QoSProfile


@dataclass
class Service:
    """Fake Service."""
    srv_type: type
    name: str
    callback: Callable[[Any, Any], Any]


class Logger:
    """Fake Logger."""
    def __init__(self) -> None:
        """Initialize."""
        self.lines: list[tuple[str, str]] = []

    def __getattr__(self, level: str) -> Callable[[str], None]:
        """Implement __getattr__."""
        assert level in ('debug', 'info', 'warning', 'warn', 'error', 'fatal'), level
        return lambda text: self.lines.append((level, text))


class Node:
    """Fake Node."""
    def __init__(self, node_name: str, *, parameter_overrides: dict[str, Any] | None = None,
                 **kwargs: Any) -> None:
        """Initialize."""
        assert set(kwargs) <= {'context', 'cli_args', 'namespace', 'use_global_arguments',
                               'enable_rosout', 'start_parameter_services',
                               'allow_undeclared_parameters',
                               'automatically_declare_parameters_from_overrides'}
        self.name = node_name
        self.overrides = dict(parameter_overrides or {})
        self.parameters: dict[str, Parameter] = {}
        self.publishers: list[Publisher] = []
        self.subscriptions: list[Subscription] = []
        self.services: list[Service] = []
        self.logger = Logger()
        self.destroyed = False

    def declare_parameter(self, name: str, value: Any = None, descriptor: Any = None,
                          ignore_override: bool = False) -> Parameter:
        """Declare parameter."""
        assert name not in self.parameters, f'parameter {name} declared twice'
        if name in self.overrides and not ignore_override:
            override = self.overrides[name]
            if type(override) is not type(value):
                msg = f'{name}: override type {type(override)} != default type {type(value)}'
                raise TypeError(msg)
            value = override
        self.parameters[name] = Parameter(name, value)
        return self.parameters[name]

    def get_parameter(self, name: str) -> Parameter:
        """Get parameter."""
        return self.parameters[name]

    def create_subscription(self, msg_type: type, topic: str, callback: Callable[[Any], None],
                            qos_profile: QoSProfile | int, *, callback_group: Any = None,
                            event_callbacks: Any = None, qos_overriding_options: Any = None,
                            raw: bool = False) -> Subscription:
        """Create subscription."""
        assert isinstance(qos_profile, QoSProfile | int)
        sub = Subscription(msg_type, topic, callback, qos_profile)  # type: ignore[arg-type]
        self.subscriptions.append(sub)
        return sub

    def create_publisher(self, msg_type: type, topic: str, qos_profile: QoSProfile | int, *,
                         callback_group: Any = None, event_callbacks: Any = None,
                         qos_overriding_options: Any = None,
                         publisher_class: Any = None) -> Publisher:
        """Create publisher."""
        assert isinstance(qos_profile, QoSProfile | int)
        pub = Publisher(msg_type, topic, qos_profile)  # type: ignore[arg-type]
        self.publishers.append(pub)
        return pub

    def create_service(self, srv_type: type, srv_name: str,
                       callback: Callable[[Any, Any], Any], *, qos_profile: Any = None,
                       callback_group: Any = None) -> Service:
        """Create service."""
        assert hasattr(srv_type, 'Request') and hasattr(srv_type, 'Response')
        srv = Service(srv_type, srv_name, callback)
        self.services.append(srv)
        return srv

    def get_logger(self) -> Logger:
        """Get logger."""
        return self.logger

    def destroy_node(self) -> None:
        """Destroy node."""
        self.destroyed = True


class TransformBroadcaster:
    """Fake TransformBroadcaster."""
    def __init__(self, node: Node, qos: Any = None) -> None:
        """Initialize."""
        assert isinstance(node, Node)
        self.sent: list[Any] = []

    def sendTransform(self, transform: Any) -> None:
        """SendTransform."""
        items = transform if isinstance(transform, list) else [transform]
        for t in items:
            assert t.__msgtype__ == 'geometry_msgs/msg/TransformStamped'
        self.sent.extend(items)


def _trigger() -> type:
    """Trigger."""

    @dataclass
    class Request:
        """Fake Request."""
        pass

    @dataclass
    class Response:
        """Fake Response."""
        success: bool = False
        message: str = ''

    return type('Trigger', (), {'Request': Request, 'Response': Response})


def _set_bool() -> type:
    """Set bool."""

    @dataclass
    class Request:
        """Fake Request."""
        data: bool = False

    @dataclass
    class Response:
        """Fake Response."""
        success: bool = False
        message: str = ''

    return type('SetBool', (), {'Request': Request, 'Response': Response})


@dataclass
class FakeRclpy:
    """Fake FakeRclpy."""
    created: list[Node]
    shutdowns: list[bool]
    spin: list[Callable[[Node], None]]


@pytest.fixture
def fake_ros(monkeypatch: pytest.MonkeyPatch) -> Iterator[FakeRclpy]:
    """Fake ros."""
    state = FakeRclpy([], [], [])
    rclpy_mod = types.ModuleType('rclpy')

    def init(*, args: Any = None, context: Any = None, domain_id: Any = None,
             signal_handler_options: Any = None) -> None:
        """Init."""
        return None

    def create_node(node_name: str, **kwargs: Any) -> Node:
        """Create node."""
        node = Node(node_name, **kwargs)
        state.created.append(node)
        return node

    def spin(node: Node, executor: Any = None) -> None:
        """Spin."""
        for fn in state.spin:
            fn(node)

    def try_shutdown(*, context: Any = None, uninstall_handlers: Any = None) -> None:
        """Try shutdown."""
        state.shutdowns.append(True)

    rclpy_mod.init = init  # type: ignore[attr-defined]
    rclpy_mod.create_node = create_node  # type: ignore[attr-defined]
    rclpy_mod.spin = spin  # type: ignore[attr-defined]
    rclpy_mod.try_shutdown = try_shutdown  # type: ignore[attr-defined]
    modules = {'rclpy': rclpy_mod}
    node_mod = types.ModuleType('rclpy.node')
    node_mod.Node = Node  # type: ignore[attr-defined]
    qos_mod = types.ModuleType('rclpy.qos')
    for cls in (QoSProfile, ReliabilityPolicy, DurabilityPolicy, HistoryPolicy):
        setattr(qos_mod, cls.__name__, cls)
    exec_mod = types.ModuleType('rclpy.executors')
    exec_mod.ExternalShutdownException = ExternalShutdownException  # type: ignore[attr-defined]
    tf_mod = types.ModuleType('tf2_ros')
    tf_mod.TransformBroadcaster = TransformBroadcaster  # type: ignore[attr-defined]
    srv_mod = types.ModuleType('std_srvs.srv')
    srv_mod.Trigger = _trigger()  # type: ignore[attr-defined]
    srv_mod.SetBool = _set_bool()  # type: ignore[attr-defined]
    modules |= {'rclpy.node': node_mod, 'rclpy.qos': qos_mod, 'rclpy.executors': exec_mod,
                'tf2_ros': tf_mod, 'std_srvs': types.ModuleType('std_srvs'),
                'std_srvs.srv': srv_mod}
    for pkg in MSG_PACKAGES:
        mod = types.ModuleType(f'{pkg}.msg')
        for name, cls in BACKEND.typestore.types.items():
            p, kind, short = name.split('/')
            if p == pkg and kind == 'msg':
                setattr(mod, short, cls)
        modules[pkg] = types.ModuleType(pkg)
        modules[f'{pkg}.msg'] = mod
    for name, mod in modules.items():
        monkeypatch.setitem(sys.modules, name, mod)
    yield state


@pytest.fixture(scope='module')
def seq() -> SimSequence:
    """Seq."""
    return simulate_sequence('street', n_keyframes=16, seed=1)


def make(fake: FakeRclpy, **overrides: Any) -> Any:
    """Make."""
    import rclpy as fake_rclpy

    from pmba_ros.node import PmbaNode
    node = fake_rclpy.create_node('pmba_node', parameter_overrides=overrides)
    return PmbaNode(node, start_worker=False)


def by_topic(node: Node) -> dict[str, Publisher]:
    """By topic."""
    return {p.topic: p for p in node.publishers}


# --- tests ----------------------------------------------------------------------------------


def test_parameters_topics_types_and_qos(fake_ros: FakeRclpy) -> None:
    """Test: parameters topics types and qos."""
    wrapper = make(fake_ros, features_topic='vins/feature', qos_reliability='best_effort',
                   qos_depth=7)
    node = fake_ros.created[0]
    assert wrapper.config.features_topic == 'vins/feature'
    assert {p for p in node.parameters} >= {'mode', 'window_size', 'publish_tf', 'map_frame'}
    subs = {s.topic: s for s in node.subscriptions}
    assert subs['vins/feature'].msg_type.__msgtype__ == 'sensor_msgs/msg/PointCloud'
    assert subs['keyframe_pose'].msg_type.__msgtype__ == 'nav_msgs/msg/Odometry'
    assert subs['camera_info'].msg_type.__msgtype__ == 'sensor_msgs/msg/CameraInfo'
    assert all(s.qos.reliability is ReliabilityPolicy.BEST_EFFORT and s.qos.depth == 7
               for s in subs.values())
    pubs = by_topic(node)
    assert {t: p.msg_type.__msgtype__ for t, p in pubs.items()} == {
        'pmba/path': 'nav_msgs/msg/Path', 'pmba/keyframes': 'geometry_msgs/msg/PoseArray',
        'pmba/landmarks': 'sensor_msgs/msg/PointCloud2', 'pmba/odometry': 'nav_msgs/msg/Odometry',
        '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray'}
    assert pubs['pmba/landmarks'].qos.durability is DurabilityPolicy.TRANSIENT_LOCAL
    assert {s.name: s.srv_type.__name__ for s in node.services} == {
        '~/reset': 'Trigger', '~/pause': 'SetBool', '~/save': 'Trigger'}


def test_named_layout_and_pose_stamped_types(fake_ros: FakeRclpy) -> None:
    """Test: named layout and pose stamped types."""
    make(fake_ros, feature_layout='named', keyframe_type='pose_stamped')
    subs = {s.topic: s.msg_type.__msgtype__ for s in fake_ros.created[0].subscriptions}
    assert subs['features'] == 'sensor_msgs/msg/PointCloud2'
    assert subs['keyframe_pose'] == 'geometry_msgs/msg/PoseStamped'


def test_invalid_parameters_raise(fake_ros: FakeRclpy) -> None:
    """Test: invalid parameters raise."""
    with pytest.raises(ValueError, match='window_size'):
        make(fake_ros, window_size=1)
    with pytest.raises(TypeError):
        make(fake_ros, max_time_s=1)  # rclpy types parameters by their default


def test_callbacks_to_published_outputs(fake_ros: FakeRclpy, seq: SimSequence) -> None:
    """Test: callbacks to published outputs."""
    wrapper = make(fake_ros, init_batch_size=10, deterministic=True)
    node = fake_ros.created[0]
    subs = {s.topic: s.callback for s in node.subscriptions}
    subs['camera_info'](camera_info_msg(seq))
    for i in range(len(seq)):
        subs['features'](tracks_msg(seq, i))
        subs['keyframe_pose'](keyframe_msg(seq, i))
    assert wrapper.process_pending() == 1 + 2 * len(seq)
    pubs = by_topic(node)
    path = pubs['pmba/path'].published[-1]
    assert len(path.poses) == len(seq) and path.header.frame_id == 'map'
    assert len(pubs['pmba/keyframes'].published) == len(pubs['pmba/path'].published) == 7
    assert pubs['pmba/landmarks'].published[-1].width > 0
    assert pubs['pmba/odometry'].published[-1].child_frame_id == 'camera'
    sent = wrapper.tf_broadcaster.sent
    assert len(sent) == 7 and sent[-1].child_frame_id == 'odom'
    diag = pubs['/diagnostics'].published[-1]
    assert {kv.key: kv.value for kv in diag.status[0].values}['state'] == 'tracking'


def test_queue_overflow_is_counted(fake_ros: FakeRclpy, seq: SimSequence) -> None:
    """Test: queue overflow is counted."""
    wrapper = make(fake_ros, queue_size=2)
    subs = {s.topic: s.callback for s in fake_ros.created[0].subscriptions}
    for i in range(5):
        subs['features'](tracks_msg(seq, i))
    wrapper.process_pending()
    diag = by_topic(fake_ros.created[0])['/diagnostics'].published[-1]
    values = {kv.key: kv.value for kv in diag.status[0].values}
    assert values['count.queue_full_tracks'] == '3'


def test_services(fake_ros: FakeRclpy, seq: SimSequence, tmp_path: Any) -> None:
    """Test: services."""
    wrapper = make(fake_ros, save_directory=str(tmp_path / 'saved'), init_batch_size=10)
    services = {s.name: s for s in fake_ros.created[0].services}
    pause = services['~/pause']
    res = pause.callback(pause.srv_type.Request(data=True), pause.srv_type.Response())
    assert res.success and wrapper.logic.paused
    res = pause.callback(pause.srv_type.Request(data=False), pause.srv_type.Response())
    assert res.success and not wrapper.logic.paused
    reset = services['~/reset']
    assert reset.callback(reset.srv_type.Request(), reset.srv_type.Response()).success
    assert wrapper.logic.stats.counters['resets'] == 1
    save = services['~/save']
    res = save.callback(save.srv_type.Request(), save.srv_type.Response())
    assert res.success and (tmp_path / 'saved' / 'pmba_keyframes.tum').exists()


def test_worker_thread_and_close(fake_ros: FakeRclpy, seq: SimSequence) -> None:
    """Test: worker thread and close."""
    import rclpy as fake_rclpy

    from pmba_ros.node import PmbaNode
    node = fake_rclpy.create_node('pmba_node')
    wrapper = PmbaNode(node)
    subs = {s.topic: s.callback for s in node.subscriptions}
    subs['camera_info'](camera_info_msg(seq))
    subs['features'](tracks_msg(seq, 0))
    deadline = time.monotonic() + 5.0
    while wrapper.logic.camera is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert wrapper.logic.camera is not None
    wrapper.close()
    assert node.destroyed and not wrapper._worker.is_alive()


@pytest.mark.parametrize('exc', [KeyboardInterrupt, ExternalShutdownException])
def test_main_shuts_down_cleanly(fake_ros: FakeRclpy, exc: type[BaseException]) -> None:
    """Test: main shuts down cleanly."""
    from pmba_ros.node import main

    def interrupt(node: Node) -> None:
        """Interrupt."""
        raise exc

    fake_ros.spin.append(interrupt)
    main([])
    assert fake_ros.created[0].destroyed and fake_ros.shutdowns == [True]


def test_main_exits_on_invalid_parameters(fake_ros: FakeRclpy,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Test: main exits on invalid parameters."""
    import pmba_ros.node as node_mod

    def bad_config(node: Any) -> Any:
        """Bad config."""
        msg = 'parameter window_size=1: expected an integer >= 2'
        raise ValueError(msg)

    monkeypatch.setattr(node_mod, 'declare_config', bad_config)
    with pytest.raises(SystemExit):
        node_mod.main([])
    assert fake_ros.created[0].destroyed and fake_ros.shutdowns == [True]
    assert fake_ros.created[0].logger.lines[-1][0] == 'fatal'


def test_main_compiles_before_subscribing_and_says_so(
        fake_ros: FakeRclpy, monkeypatch: pytest.MonkeyPatch) -> None:
    """A cold cache: one log line with the expected time, the loops ready before subscribing."""
    from pmba_ros.core import warmup
    from pmba_ros.node import main

    subscribed_at_warm_up: list[int] = []

    def fake_warm_up() -> float:
        subscribed_at_warm_up.append(len(fake_ros.created[0].subscriptions))
        return 20.0

    monkeypatch.setattr(warmup, 'is_warm', lambda: False)
    monkeypatch.setattr(warmup, 'warm_up', fake_warm_up)
    fake_ros.spin.append(lambda node: (_ for _ in ()).throw(KeyboardInterrupt))
    main([])
    assert subscribed_at_warm_up == [0]
    lines = [text for _, text in fake_ros.created[0].logger.lines]
    assert any(f'expected {warmup.expected_compile_text()}' in t for t in lines), lines
    assert any('ready in 20.0 s' in t for t in lines), lines
    assert fake_ros.created[0].subscriptions, 'the node never subscribed'
