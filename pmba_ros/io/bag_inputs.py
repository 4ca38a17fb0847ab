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
"""The recorded topics a replay feeds to the back-end, and their header-stamp order."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
import heapq
import logging
from pathlib import Path
from typing import Any, TYPE_CHECKING

from pmba_ros.backend.tracks import KEYFRAME_MSGTYPES, stamp_of, tracks_msgtype
from pmba_ros.errors import BagError, MessageError
from pmba_ros.io.bags import (
    BagMessage,
    iter_messages,
    list_topics,
    OpenBags,
    ReadStats,
    TopicInfo,
)

if TYPE_CHECKING:
    from pmba_ros.backend.config import BackendConfig

logger = logging.getLogger(__name__)

CAMERA_INFO_TYPES = ('sensor_msgs/msg/CameraInfo',)
TF_TOPICS = ('/tf_static', '/tf')
"""Transform topics read when recorded (body -> camera extrinsic, see BackendLogic.on_tf)."""
TF_TYPES = ('tf2_msgs/msg/TFMessage',)
STATIC_TF_TOPIC = '/tf_static'

EXTRINSIC_TYPES = ('nav_msgs/msg/Odometry', 'geometry_msgs/msg/PoseStamped')
"""Types of ``extrinsic_topic`` (the reference camera's pose in the body frame)."""

REORDER_BUFFER = 256
"""Messages held back to sort the log-time stream into header-stamp order."""

_KIND_ORDER = {'tf': 0, 'extrinsic': 0, 'camera_info': 1, 'tracks': 2, 'keyframe': 3}


def resolve_topic(name: str, namespace: str = '/') -> str:
    """Resolve a (relative) ROS topic name in a namespace, as rclpy does for a plain node.

    Args:
        name: Absolute ('/a/b') or relative ('a/b') name; '~' is not supported.
        namespace: Node namespace.

    Returns:
        The absolute name.
    """
    if name.startswith('/'):
        return name
    ns = '/' + namespace.strip('/')
    return f'{ns.rstrip("/")}/{name}'


def find_topic(wanted: str, recorded: Iterable[str]) -> str | None:
    """Return the recorded topic matching ``wanted`` (ROS 1 bags may lack the '/')."""
    names = list(recorded)
    if wanted in names:
        return wanted
    bare = wanted.lstrip('/')
    return next((n for n in names if n.lstrip('/') == bare), None)


@dataclass(frozen=True)
class ReplayInputs:
    """Input topics of a replay."""

    tracks: str
    keyframes: str | None
    camera_info: str | None
    tf: tuple[str, ...] = ()
    extrinsic: str | None = None


def select_inputs(bags: Sequence[Path], config: BackendConfig, camera_given: bool,
                  warnings: list[str], recorded: dict[str, TopicInfo] | None = None,
                  ) -> tuple[ReplayInputs, dict[str, int]]:
    """Check the recorded topics against the configuration; return topics and counts.

    ``recorded``: the bags' topics if they were listed already (default: list them).

    Raises:
        BagError: If a needed topic is missing.
        MessageError: If the tracks / keyframe topic has a type the layout cannot read.
    """
    topics = list_topics(bags) if recorded is None else recorded
    names = ', '.join(f'{t} [{i.msgtype}]' for t, i in sorted(topics.items())) or 'none'
    where = ', '.join(str(b) for b in bags)

    def need(option: str, name: str) -> str:
        found = find_topic(resolve_topic(name), topics)
        if found is None:
            msg = (f'{where}: {option} topic {resolve_topic(name)!r} is not in the bag '
                   f'(recorded: {names})')
            raise BagError(msg)
        return found

    tracks = need('tracks', config.features_topic)
    layout = config.feature_layout
    accepted = tracks_msgtype(layout)
    if topics[tracks].msgtype != accepted:
        msg = (f'{where}: tracks topic {tracks!r} has type {topics[tracks].msgtype}, but layout '
               f'{layout!r} reads {accepted} (wrong --tracks-layout?)')
        raise MessageError(msg)
    if config.keyframe_source == 'keyframe_topic':
        keyframes: str | None = need('keyframes', config.keyframe_topic)
    else:   # keyframes from the tracks; their poses from this stream where it was recorded
        keyframes = find_topic(resolve_topic(config.keyframe_topic), topics)
    if keyframes is not None:
        accepted = KEYFRAME_MSGTYPES[config.keyframe_type]
        if topics[keyframes].msgtype != accepted:
            msg = (f'{where}: keyframes topic {keyframes!r} has type '
                   f'{topics[keyframes].msgtype}, but --keyframes-type '
                   f'{config.keyframe_type!r} reads {accepted}')
            raise MessageError(msg)
    camera_info = find_topic(resolve_topic(config.camera_info_topic), topics)
    if camera_info is not None and topics[camera_info].msgtype not in CAMERA_INFO_TYPES:
        msg = (f'{where}: camera info topic {camera_info!r} has type '
               f'{topics[camera_info].msgtype}, expected {CAMERA_INFO_TYPES[0]}')
        raise BagError(msg)
    if camera_given:
        camera_info = None
    elif camera_info is None:
        text = (f'camera info topic {resolve_topic(config.camera_info_topic)!r} is not in the '
                f'bag and no intrinsics were given; using normalized coordinates from the tracks')
        logger.warning(text)
        warnings.append(text)
    tf = tuple(t for t in (find_topic(name, topics) for name in TF_TOPICS)
               if t is not None and topics[t].msgtype in TF_TYPES)
    extrinsic = None if config.camera_extrinsics else find_topic(
        resolve_topic(config.extrinsic_topic), topics)
    if extrinsic is not None and topics[extrinsic].msgtype not in EXTRINSIC_TYPES:
        text = (f'extrinsic topic {extrinsic!r} has type {topics[extrinsic].msgtype}, not '
                f'{" or ".join(EXTRINSIC_TYPES)}: not read')
        logger.warning(text)
        warnings.append(text)
        extrinsic = None
    counts = {t: topics[t].count for t in (tracks, keyframes, camera_info, *tf, extrinsic)
              if t is not None}
    return ReplayInputs(tracks, keyframes, camera_info, tf, extrinsic), counts


def rig_camera_infos(bags: Sequence[Path], config: BackendConfig, warnings: list[str],
                     counts: dict[str, int], recorded: dict[str, TopicInfo] | None = None,
                     ) -> dict[str, int]:
    """Return the recorded ``camera_info_topics`` of a rig: topic -> camera id.

    A missing topic leaves its camera unused (its observations are counted as
    ``other_camera_observations``), with a warning. ``counts`` gets each topic's message
    count; ``recorded`` as for :func:`select_inputs`.
    """
    if not config.camera_info_topics:
        return {}
    topics = list_topics(bags) if recorded is None else recorded
    found: dict[str, int] = {}
    for cam, name in enumerate(config.camera_info_topics):
        topic = find_topic(resolve_topic(name), topics)
        if topic is not None and topics[topic].msgtype in CAMERA_INFO_TYPES:
            found[topic] = cam
            counts[topic] = topics[topic].count
        else:
            text = (f'camera info topic {resolve_topic(name)!r} of camera {cam} is not in the '
                    'bag: that camera is not used')
            logger.warning(text)
            warnings.append(text)
    return found


def static_transforms(bags: OpenBags, tf_topics: Sequence[str]) -> Iterator[Any]:
    """Yield the recorded static transform messages (``/tf_static``), in log-time order.

    A static transform holds at every time (tf2 keeps it forever), but the extrinsic is
    fixed at the first keyframe pose: a ``/tf_static`` recorded after it (a recording
    started before the robot's state publisher, a static publisher started late) left a
    whole run with the identity as its body -> camera transform, silently. Damage is read
    past here; the replay's pass reports it.
    """
    static = [t for t in tf_topics if t.lstrip('/') == STATIC_TF_TOPIC.lstrip('/')]
    if not static:
        return
    for message in iter_messages(bags, topics=static, damage=ReadStats()):
        yield message.msg


def header_stamp_ns(msg: Any, fallback: int) -> int:
    """Return a message's header stamp in ns (``fallback`` if it has no usable header)."""
    stamp = stamp_of(msg)
    return fallback if stamp is None else stamp


def stamp_ordered(messages: Iterable[BagMessage], kinds: dict[str, str],
                  window: int = REORDER_BUFFER) -> Iterator[tuple[int, str, BagMessage]]:
    """Reorder a log-time message stream into header-stamp order with a bounded buffer.

    At equal stamps transforms come first, then camera info, tracks and keyframe poses (a
    keyframe then finds its tracks and extrinsic). Messages more than ``window`` positions
    out of order are passed on late rather than held indefinitely.

    Args:
        messages: Messages in log-time order.
        kinds: Topic -> 'tf' | 'extrinsic' | 'camera_info' | 'tracks' | 'keyframe'.
        window: Messages held back.

    Yields:
        ``(stamp_ns, kind, message)`` in (almost) stamp order.
    """
    heap: list[tuple[int, int, int, str, BagMessage]] = []
    for seq, message in enumerate(messages):
        kind = kinds[message.topic]
        stamp = header_stamp_ns(message.msg, message.log_time_ns)
        heapq.heappush(heap, (stamp, _KIND_ORDER[kind], seq, kind, message))
        if len(heap) > window:
            stamp, _, _, kind, message = heapq.heappop(heap)
            yield stamp, kind, message
    while heap:
        stamp, _, _, kind, message = heapq.heappop(heap)
        yield stamp, kind, message
