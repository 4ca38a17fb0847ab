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
"""Why an input of the node receives nothing although its topic has publishers.

Two mismatches leave a subscription silent without an error of its own: a publisher of
another message type (another track layout, PoseStamped keyframe poses) and one whose QoS
the subscription cannot match (a best-effort driver against a reliable subscription).
The middleware reports the second as an event; the first shows in the ROS graph, as the
types of the topic's publishers. The node asks :class:`InputCheck` at each diagnostics
tick, for the inputs that have received nothing yet.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ['InputCheck', 'WatchedInput']

_PARAMETERS = {'tracks': ('feature_layout', 'features_qos'),
               'keyframe': ('keyframe_type', 'keyframe_qos'),
               'extrinsic': (None, 'keyframe_qos')}
"""Input kind -> the parameters that choose its message type and its QoS."""


@dataclass(frozen=True)
class WatchedInput:
    """One subscription of the node.

    Attributes:
        kind: The worker's input kind ('tracks', 'keyframe', 'extrinsic', 'camera_info',
            'camera_info.c').
        topic: The resolved topic name.
        msgtype: The message type it reads, e.g. 'nav_msgs/msg/Odometry'.
    """

    kind: str
    topic: str
    msgtype: str

    def parameters(self) -> tuple[str | None, str]:
        """Return the parameters that set this input's message type (None: fixed) and QoS."""
        return _PARAMETERS.get(self.kind, (None, 'camera_info_qos'))


class InputCheck:
    """The node's inputs, with the QoS events the middleware reported for them."""

    def __init__(self) -> None:
        """Watch nothing yet."""
        self._inputs: dict[str, WatchedInput] = {}
        self._qos: dict[str, str] = {}
        self._reported: set[str] = set()

    def watch(self, kind: str, topic: str, msgtype: str) -> None:
        """Watch the subscription of ``kind`` on ``topic`` reading ``msgtype``."""
        self._inputs[kind] = WatchedInput(kind, topic, msgtype)

    def incompatible_qos(self, kind: str) -> Callable[[Any], None]:
        """Return the middleware's incompatible-QoS event callback for input ``kind``.

        The event's ``last_policy_kind`` names the policy (e.g. ``RMW_QOS_POLICY_RELIABILITY``).
        """
        def callback(status: Any) -> None:
            policy = getattr(status.last_policy_kind, 'name', str(status.last_policy_kind))
            self._qos[kind] = policy.removeprefix('RMW_QOS_POLICY_').lower()
        return callback

    def problems(self, received: Mapping[str, int],
                 publisher_types: Callable[[str], list[str]]) -> list[str]:
        """Return what keeps each silent input from receiving, one sentence per input.

        Args:
            received: Messages received per input kind.
            publisher_types: Topic -> the message types of its publishers (the ROS graph).
        """
        problems = []
        for kind, watched in self._inputs.items():
            if received.get(kind, 0):
                continue
            type_parameter, qos_parameter = watched.parameters()
            types = set(publisher_types(watched.topic))
            if types and watched.msgtype not in types:
                fix = f'set {type_parameter}' if type_parameter else 'check the remapping'
                problems.append(f'{watched.topic} is published as {", ".join(sorted(types))}, '
                                f'read as {watched.msgtype} ({fix})')
            elif kind in self._qos:
                problems.append(f'{watched.topic}: a publisher offers QoS this subscription '
                                f'cannot match ({self._qos[kind]}; set {qos_parameter} or '
                                'qos_reliability to match it)')
        return problems

    def new(self, problems: list[str]) -> list[str]:
        """Return the problems not returned by an earlier call (to log each once)."""
        fresh = [p for p in problems if p not in self._reported]
        self._reported.update(fresh)
        return fresh
