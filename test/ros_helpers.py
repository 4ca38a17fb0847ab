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

"""Helpers of the real-rclpy tests: isolated DDS domains and spinning until a condition."""

from __future__ import annotations

from collections.abc import Callable, Iterator
import contextlib
import itertools
import os
import time
from typing import Any

_COUNTER = itertools.count()


def domain_id() -> int:
    """Return a ROS_DOMAIN_ID in 1..100 for one test (per process and call: no cross-talk).

    Test runs of other checkouts may share the machine, hence the process id in it.
    """
    return (os.getpid() * 7 + next(_COUNTER) * 13) % 100 + 1


def isolated_env(domain: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """Return the environment of a child process on its own localhost-only DDS domain.

    ``base``: the environment to start from (this process's by default).
    """
    env = dict(os.environ if base is None else base)
    env['ROS_DOMAIN_ID'] = str(domain)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('ROS_LOCALHOST_ONLY', None)
    return env


def isolate(monkeypatch: Any, domain: int) -> None:
    """Set this process's ROS variables as :func:`isolated_env` sets its children's."""
    for name, value in isolated_env(domain).items():
        if name.startswith('ROS_'):
            monkeypatch.setenv(name, value)
    monkeypatch.delenv('ROS_LOCALHOST_ONLY', raising=False)


def transient_local_qos(depth: int) -> Any:
    """Return a reliable, transient-local QoS, as ``pmba play`` publishes.

    A volatile reader drops what a writer sends before the reader's side of the match
    (eProsima/Fast-DDS#2641), which no wait rules out on a loaded machine; transient local
    on both sides delivers those too.
    """
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def spin_until(executor: Any, condition: Callable[[], bool], timeout_s: float = 30.0) -> bool:
    """Spin ``executor`` until ``condition()`` holds; return whether it did in time."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
        if condition():
            return True
    return False


@contextlib.contextmanager
def isolated_node(monkeypatch: Any, name: str) -> Iterator[tuple[int, Any, Any]]:
    """Yield ``(domain, executor, node)``: a node in its own context on a fresh domain."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    domain = domain_id()
    isolate(monkeypatch, domain)
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    executor = SingleThreadedExecutor(context=context)
    node = rclpy.create_node(name, context=context)
    executor.add_node(node)
    try:
        yield domain, executor, node
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
