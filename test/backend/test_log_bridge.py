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
"""The package's logging routed to ROS loggers, one route per node of the process (no ROS)."""

from __future__ import annotations

import contextvars
import logging
import threading

from pmba_ros.backend.log_bridge import LogRoute


class RosLogger:
    """Record what an rclpy logger at ``level`` would print (it drops lines below its level)."""

    def __init__(self, level: int) -> None:
        """Start with no line."""
        self.level = level
        self.lines: list[tuple[str, str]] = []

    def get_effective_level(self) -> int:
        """Return the level."""
        return self.level

    def _log(self, severity: str, level: int, text: str) -> None:
        if level >= self.level:
            self.lines.append((severity, text))

    def debug(self, text: str) -> None:
        """Log at DEBUG."""
        self._log('debug', logging.DEBUG, text)

    def info(self, text: str) -> None:
        """Log at INFO."""
        self._log('info', logging.INFO, text)

    def warning(self, text: str) -> None:
        """Log at WARN."""
        self._log('warning', logging.WARNING, text)


def test_each_context_logs_to_its_own_route_and_the_last_close_restores() -> None:
    """Lines go to the route active where they are logged (a thread started in it, too).

    Elsewhere they go to the oldest open route. The engine's INFO lines reach only a route
    at DEBUG; the levels and propagation come back with the last route closed.
    """
    package, engine = logging.getLogger('pmba_ros'), logging.getLogger('pmba_ros.core')
    saved = (package.level, engine.level, package.propagate)
    a, b = RosLogger(logging.INFO), RosLogger(logging.DEBUG)
    route_a, route_b = LogRoute(a), LogRoute(b)
    log = logging.getLogger('pmba_ros.backend.logic')
    try:
        with route_b.active():   # as LogicWorker.start() starts the solver thread
            thread = threading.Thread(target=contextvars.copy_context().run,
                                      args=(log.warning, 'from the thread of b'))
        thread.start()
        thread.join()
        with route_b.active():
            engine.info('an engine line of b')
        with route_a.active():
            engine.info('an engine line of a')
        log.warning('no context')
        assert a.lines == [('warning', 'pmba_ros.backend.logic: no context')]
        assert b.lines == [('warning', 'pmba_ros.backend.logic: from the thread of b'),
                           ('info', 'pmba_ros.core: an engine line of b')]
        route_a.close()
        log.warning('a closed')
        assert b.lines[-1] == ('warning', 'pmba_ros.backend.logic: a closed')
        assert not package.propagate
    finally:
        route_a.close()
        route_b.close()
    assert (package.level, engine.level, package.propagate) == saved
