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
"""pmba_node against a strict fake rclpy: only what real rclpy cannot check here.

test/test_node_rclpy.py runs the node on real rclpy. tf2_msgs is not on PyPI, so the
``/tf`` publisher fallback (tf2_msgs present, tf2_ros absent) is checked here, with message
modules filled with rosbags Jazzy classes; so are main()'s exits, without a process.
The fakes copy rclpy Jazzy's signatures (keyword-only arguments included) and check types:
publishers accept only their declared message class.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import Enum
import sys
import types
from typing import Any

import numpy as np
from pmba_ros.sim.sequence import SimSequence, simulate_sequence
import pytest

from .test_logic import BACKEND, camera_info_msg, keyframe_msg, tracks_msg

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


class ClockType(Enum):
    """rclpy.clock.ClockType."""

    UNINITIALIZED = 0
    ROS_TIME = 1
    SYSTEM_TIME = 2
    STEADY_TIME = 3


@dataclass
class Clock:
    """rclpy.clock.Clock (keyword-only, as rclpy's)."""

    clock_type: ClockType = ClockType.SYSTEM_TIME

    def __post_init__(self) -> None:
        """Check the type, as rclpy's does."""
        if not isinstance(self.clock_type, ClockType):
            raise TypeError('Clock type must be a ClockType enum')


class ExternalShutdownException(Exception):
    """Fake ExternalShutdownException."""

    pass


class ParameterException(Exception):
    """Fake ParameterException."""


@dataclass
class ParameterDescriptor:
    """Fake ParameterDescriptor (rosbags classes want every field)."""

    name: str = ''
    description: str = ''
    additional_constraints: str = ''
    read_only: bool = False
    dynamic_typing: bool = False
    integer_range: list[Any] = field(default_factory=list)
    floating_point_range: list[Any] = field(default_factory=list)


@dataclass
class IntegerRange:
    """Fake IntegerRange."""

    from_value: int
    to_value: int
    step: int


@dataclass
class FloatingPointRange:
    """Fake FloatingPointRange."""

    from_value: float
    to_value: float
    step: float


@dataclass
class SetParametersResult:
    """Fake SetParametersResult."""

    successful: bool
    reason: str = ''


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
    events: Any = None

    @property
    def topic_name(self) -> str:
        """Return the topic resolved in the root namespace."""
        return self.topic if self.topic.startswith('/') else f'/{self.topic}'


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

    def get_effective_level(self) -> int:
        """Return INFO (rclpy's LoggingSeverity values equal logging's)."""
        return 20

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
        self.timers: list[Any] = []
        self.logger = Logger()
        self.destroyed = False
        self.graph: dict[str, list[str]] = {}
        self.context = types.SimpleNamespace(ok=lambda: not self.destroyed)

    def declare_parameter(self, name: str, value: Any = None, descriptor: Any = None,
                          ignore_override: bool = False) -> Parameter:
        """Declare parameter."""
        assert name not in self.parameters, f'parameter {name} declared twice'
        if name in self.overrides and not ignore_override:
            override = self.overrides[name]
            if type(override) is not type(value) and not descriptor.dynamic_typing:
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
        sub = Subscription(msg_type, topic, callback, qos_profile,  # type: ignore[arg-type]
                           event_callbacks)
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

    def get_publishers_info_by_topic(self, topic_name: str) -> list[Any]:
        """Return the publishers of ``graph`` (topic -> message types)."""
        return [types.SimpleNamespace(topic_type=t) for t in self.graph.get(topic_name, [])]

    def get_logger(self) -> Logger:
        """Get logger."""
        return self.logger

    def get_fully_qualified_name(self) -> str:
        """Return '/' + the name (no namespace here)."""
        return '/' + self.name

    def get_name(self) -> str:
        """Get name."""
        return self.name

    def get_clock(self) -> Any:
        """Get a clock at a fixed time."""
        return types.SimpleNamespace(now=lambda: types.SimpleNamespace(nanoseconds=5 * 10**9))

    def add_on_set_parameters_callback(self, callback: Callable[[Any], Any]) -> None:
        """Add on set parameters callback."""
        self.on_set = callback

    def add_post_set_parameters_callback(self, callback: Callable[[Any], None]) -> None:
        """Add post set parameters callback."""
        self.post_set = callback

    def create_timer(self, timer_period_sec: float, callback: Callable[[], None], *,
                     callback_group: Any = None, clock: Any = None,
                     autostart: bool = True) -> Any:
        """Create timer (fired by tests)."""
        timer = types.SimpleNamespace(period=timer_period_sec, callback=callback)
        self.timers.append(timer)
        return timer

    def destroy_timer(self, timer: Any) -> bool:
        """Destroy timer."""
        self.timers.remove(timer)
        return True

    def destroy_node(self) -> None:
        """Destroy node."""
        self.destroyed = True


def _trigger() -> type:
    """Return a stand-in for std_srvs/srv/Trigger."""

    @dataclass
    class Request:
        """Fake Request."""

    @dataclass
    class Response:
        """Fake Response."""

        success: bool = False
        message: str = ''

    return type('Trigger', (), {'Request': Request, 'Response': Response})


def _set_bool() -> type:
    """Return a stand-in for std_srvs/srv/SetBool."""

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
    wrappers: list[Any] = field(default_factory=list)   # closed at the end (log routes)


@pytest.fixture
def fake_ros(monkeypatch: pytest.MonkeyPatch) -> Iterator[FakeRclpy]:
    """Put fake rclpy, QoS, service and message modules in sys.modules."""
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
    clock_mod = types.ModuleType('rclpy.clock')
    clock_mod.Clock, clock_mod.ClockType = Clock, ClockType  # type: ignore[attr-defined]
    exec_mod = types.ModuleType('rclpy.executors')
    exec_mod.ExternalShutdownException = ExternalShutdownException  # type: ignore[attr-defined]
    qos_mod.qos_profile_sensor_data = QoSProfile(  # type: ignore[attr-defined]
        depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    overriding_mod = types.ModuleType('rclpy.qos_overriding_options')
    overriding_mod.QoSOverridingOptions = types.SimpleNamespace(  # type: ignore[attr-defined]
        with_default_policies=lambda: 'default policies')
    events_mod = types.ModuleType('rclpy.event_handler')
    events_mod.SubscriptionEventCallbacks = types.SimpleNamespace  # type: ignore[attr-defined]
    exc_mod = types.ModuleType('rclpy.exceptions')
    exc_mod.ParameterException = ParameterException  # type: ignore[attr-defined]
    rcl_mod = types.ModuleType('rcl_interfaces.msg')
    for cls in (ParameterDescriptor, IntegerRange, FloatingPointRange, SetParametersResult):
        setattr(rcl_mod, cls.__name__, cls)
    srv_mod = types.ModuleType('std_srvs.srv')
    srv_mod.Trigger = _trigger()  # type: ignore[attr-defined]
    srv_mod.SetBool = _set_bool()  # type: ignore[attr-defined]
    modules |= {'rclpy.node': node_mod, 'rclpy.qos': qos_mod, 'rclpy.executors': exec_mod,
                'rclpy.clock': clock_mod,
                'rclpy.qos_overriding_options': overriding_mod, 'rclpy.exceptions': exc_mod,
                'rclpy.event_handler': events_mod,
                'rcl_interfaces': types.ModuleType('rcl_interfaces'),
                'rcl_interfaces.msg': rcl_mod,
                'tf2_ros': None, 'std_srvs': types.ModuleType('std_srvs'),
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
    for wrapper in state.wrappers:
        wrapper.close()


@pytest.fixture(scope='module')
def seq() -> SimSequence:
    """Simulate a 16-keyframe street once for the module."""
    return simulate_sequence('street', n_keyframes=16, seed=1)


def make(fake: FakeRclpy, **overrides: Any) -> Any:
    """Create a PmbaNode on a fake node with parameter overrides, no worker thread."""
    from pmba_ros.node import PmbaNode
    import rclpy as fake_rclpy
    node = fake_rclpy.create_node('pmba_node', parameter_overrides=overrides)
    wrapper = PmbaNode(node, start_worker=False)
    fake.wrappers.append(wrapper)
    return wrapper


def by_topic(node: Node) -> dict[str, Publisher]:
    """Return a node's publishers by topic."""
    return {p.topic: p for p in node.publishers}


# --- tests ----------------------------------------------------------------------------------


def test_tf_topic_fallback_without_tf2_ros(fake_ros: FakeRclpy, seq: SimSequence) -> None:
    """tf2_msgs but no tf2_ros: map -> odom on a plain /tf publisher, also re-sent by timer."""
    wrapper = make(fake_ros, init_batch_size=10, deterministic=True)
    node = fake_ros.created[0]
    assert wrapper.tf_mode.startswith('/tf publisher') and wrapper.tf_broadcaster is None
    subs = {s.topic: s.callback for s in node.subscriptions}
    subs['camera_info'](camera_info_msg(seq))
    for i in range(len(seq)):
        subs['features'](tracks_msg(seq, i))
        subs['keyframe_pose'](keyframe_msg(seq, i))
    assert wrapper.process_pending() == 1 + 2 * len(seq)
    pubs = by_topic(node)
    tf = pubs['/tf'].published
    assert tf and tf[-1].__msgtype__ == 'tf2_msgs/msg/TFMessage'
    assert tf[-1].transforms[0].child_frame_id == 'odom'
    assert len(pubs['pmba/map_to_odom'].published) == len(tf)
    n = len(tf)
    resend = next(t for t in node.timers if t.period == 0.1)   # tf_rate_hz 10
    resend.callback()
    assert len(tf) == n + 1 and tf[-1].transforms[0].header.stamp.sec == 5
    diag = pubs['/diagnostics'].published[-1]
    node_status = next(st for st in diag.status if st.name == 'pmba_node: node')
    assert {kv.key: kv.value for kv in node_status.values}['tf'].startswith('/tf publisher')


@pytest.mark.parametrize('exc', [KeyboardInterrupt, ExternalShutdownException])
def test_main_shuts_down_cleanly(fake_ros: FakeRclpy, exc: type[BaseException]) -> None:
    """An interrupt or external shutdown while spinning destroys the node and shuts down once."""
    from pmba_ros.node import main

    def interrupt(node: Node) -> None:
        """Raise the exception under test while spinning."""
        raise exc

    fake_ros.spin.append(interrupt)
    main([])
    assert fake_ros.created[0].destroyed and fake_ros.shutdowns == [True]


def test_main_exits_on_invalid_parameters(fake_ros: FakeRclpy,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """An invalid parameter is one fatal log line, a clean shutdown and SystemExit."""
    import pmba_ros.node as node_mod

    def bad_config(node: Any) -> Any:
        """Fail like an invalid parameter."""
        msg = 'parameter window_size=1: expected an integer >= 2'
        raise ValueError(msg)

    monkeypatch.setattr(node_mod, 'declare_config', bad_config)
    with pytest.raises(SystemExit):
        node_mod.main([])
    assert fake_ros.created[0].destroyed and fake_ros.shutdowns == [True]
    assert fake_ros.created[0].logger.lines[-1][0] == 'fatal'


def test_main_compiles_in_the_background_and_says_so(
        fake_ros: FakeRclpy, monkeypatch: pytest.MonkeyPatch) -> None:
    """A cold cache: the node subscribes without waiting for the compilation, and says so.

    One line with the expected time when it starts, one when it is done.
    """
    from pmba_ros.core import warmup
    from pmba_ros.node import main

    started: list[Callable[[float | None], None]] = []

    def waited() -> float:
        pytest.fail('the node waited for the compilation')

    def spin(node: Any) -> None:
        del node
        assert fake_ros.created[0].subscriptions, 'not subscribed while compiling'
        started[0](20.0)
        raise KeyboardInterrupt

    monkeypatch.setattr(warmup, 'is_warm', lambda: False)
    monkeypatch.setattr(warmup, 'warm_up', waited)
    monkeypatch.setattr(warmup, 'warm_up_in_background', started.append)
    fake_ros.spin.append(spin)
    main([])
    assert len(started) == 1
    lines = [text for _, text in fake_ros.created[0].logger.lines]
    assert any(f'expected {warmup.expected_compile_text()}' in t and 'background' in t
               for t in lines), lines
    assert any('compiled in 20.0 s' in t for t in lines), lines


def test_tf_static_reaches_the_back_end(fake_ros: FakeRclpy) -> None:
    """With tf2_msgs, /tf_static and /tf feed the extrinsic's transform tree, not the staleness."""
    from pmba_ros.backend.outputs import make_odometry, make_tf

    wrapper = make(fake_ros, deterministic=True)
    subs = {s.topic: s.callback for s in fake_ros.created[0].subscriptions}
    assert {'/tf_static', '/tf'} <= subs.keys()
    last_input = wrapper.worker.last_input
    subs['/tf_static'](make_tf(0, 'base_link', 'camera', [0.1, 0.0, 0.0], [0, 0, 0, 1], BACKEND))
    assert wrapper.worker.last_input == last_input
    assert wrapper.process_pending() == 1
    assert len(wrapper.logic.cameras.tf_tree) == 1
    # The front-end's own extrinsic (VINS, OpenVINS) is an input beside them.
    subs[wrapper.config.extrinsic_topic](make_odometry(0, 'world', '', [0.1, 0.0, 0.0],
                                                       [0, 0, 0, 1], np.eye(6), BACKEND))
    assert wrapper.process_pending() == 1
    assert wrapper.logic.cameras.topic_extrinsic is not None
    np.testing.assert_allclose(wrapper.logic.cameras.topic_extrinsic.translation, [0.1, 0, 0])


def test_no_tf_subscription_with_extrinsics_given(fake_ros: FakeRclpy) -> None:
    """camera_extrinsics set: the node listens neither to TF nor to the extrinsic topic."""
    wrapper = make(fake_ros, camera_extrinsics=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    topics = {s.topic for s in fake_ros.created[0].subscriptions}
    assert wrapper.config.camera_extrinsics
    assert not topics & {'/tf_static', '/tf', wrapper.config.extrinsic_topic}


def test_a_rig_s_lists_declare_num_cams(fake_ros: FakeRclpy) -> None:
    """Two cameras' extrinsics and no num_cams: the parameter is declared 2, not refused.

    Before, ``num_cams`` was declared 1 and the 14 values failed the start; one set
    explicitly still wins and is checked against them, with the value to set.
    """
    stereo = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.11, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    wrapper = make(fake_ros, camera_extrinsics=stereo)
    assert wrapper.config.num_cams == 2
    assert fake_ros.created[0].get_parameter('num_cams').value == 2
    assert make(fake_ros, camera_info_topics=['/a', '/b', '/c']).config.num_cams == 3
    with pytest.raises(ValueError, match='per camera for num_cams=1, got 14: set num_cams: 2'):
        make(fake_ros, camera_extrinsics=stereo, num_cams=1)


def test_silent_inputs_name_their_mismatch(fake_ros: FakeRclpy, seq: SimSequence) -> None:
    """A publisher of another type or with incompatible QoS: one WARN naming the parameter."""
    wrapper = make(fake_ros, deterministic=True)
    node = fake_ros.created[0]
    node.graph = {'/keyframe_pose': ['geometry_msgs/msg/PoseStamped'],
                  '/features': ['sensor_msgs/msg/PointCloud']}
    features = next(s for s in node.subscriptions if s.topic == 'features')
    features.events.incompatible_qos(types.SimpleNamespace(
        total_count=1, last_policy_kind=types.SimpleNamespace(name='RMW_QOS_POLICY_RELIABILITY')))
    status = wrapper.node_status()
    assert status.level == status.WARN
    assert ('/keyframe_pose is published as geometry_msgs/msg/PoseStamped, read as '
            'nav_msgs/msg/Odometry (set keyframe_type)') in status.message
    assert '/features: a publisher offers QoS' in status.message
    assert 'reliability; set features_qos' in status.message
    warned = [line for level, line in node.logger.lines if level == 'warning']
    wrapper.node_status()
    assert [line for level, line in node.logger.lines if level == 'warning'] == warned
    assert len(warned) == 2   # each problem logged once
    # Once an input receives, its mismatch is no longer the reason it is silent.
    features.callback(tracks_msg(seq, 0))
    assert wrapper.process_pending() == 1
    assert '/features' not in wrapper.node_status().message
