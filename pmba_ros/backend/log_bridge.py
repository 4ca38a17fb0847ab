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
"""Python ``logging`` of the package forwarded to a ROS logger (no rclpy import).

The package logger ``pmba_ros`` is one per process; the nodes of a process (two
``PmbaNode``s in a component-container-like script) each open a :class:`LogRoute`. A record
goes to the route active in the context that logs it (:meth:`LogRoute.active`: a node's
solver thread runs in it, its service callbacks enter it), else to the oldest open route: a
node's warning shows under that node's name, once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import contextlib
from contextvars import ContextVar
import logging
import threading
from typing import Any, TypeVar

ENGINE_LOGGERS = ('pmba_ros.core', 'pmba_ros.init')
"""Loggers whose INFO lines come with every solve (debug material for a running node)."""

_PACKAGE = 'pmba_ros'
_T = TypeVar('_T')


class RosLogHandler(logging.Handler):
    """Forward Python ``logging`` records to an rclpy logger (and so to /rosout)."""

    def __init__(self, ros_logger: Any) -> None:
        """Wrap ``ros_logger`` (``node.get_logger()``)."""
        super().__init__()
        self._ros = ros_logger
        self.setFormatter(logging.Formatter('%(name)s: %(message)s'))

    def emit(self, record: logging.LogRecord) -> None:
        """Log ``record`` at the matching rclpy severity."""
        try:
            text = self.format(record)
            if record.levelno >= logging.CRITICAL:
                self._ros.fatal(text)
            elif record.levelno >= logging.ERROR:
                self._ros.error(text)
            elif record.levelno >= logging.WARNING:
                self._ros.warning(text)
            elif record.levelno >= logging.INFO:
                self._ros.info(text)
            else:
                self._ros.debug(text)
        except Exception:
            self.handleError(record)


class LogRoute:
    """The package's ``logging`` routed to a ROS logger, until :meth:`close`.

    While routes are open, the package logger has one handler that hands each record to its
    route and stops propagating (no duplicate lines on the console). Its level is the lowest
    of the routes' ROS loggers', the engine loggers are held at WARNING unless one is at
    DEBUG, and each route drops the engine's INFO lines unless its own is.

    Args:
        ros_logger: An rclpy logger (``node.get_logger()``).
    """

    def __init__(self, ros_logger: Any) -> None:
        """Open the route (the first one installs the handler and sets the levels)."""
        self.level = int(ros_logger.get_effective_level())
        self.handler = RosLogHandler(ros_logger)
        self.handler.addFilter(self._engine_filter)
        _DISPATCH.add(self)

    def _engine_filter(self, record: logging.LogRecord) -> bool:
        return (record.levelno >= logging.WARNING or self.level <= logging.DEBUG
                or not record.name.startswith(ENGINE_LOGGERS))

    def routed(self, callback: Callable[..., _T]) -> Callable[..., _T]:
        """Return ``callback`` run with this route :meth:`active` (a service's callback)."""
        def call(*args: Any) -> _T:
            with self.active():
                return callback(*args)
        return call

    @contextlib.contextmanager
    def active(self) -> Iterator[None]:
        """Send the records logged in this context (and threads started in a copy of it) here."""
        token = _ACTIVE.set(self)
        try:
            yield
        finally:
            _ACTIVE.reset(token)

    def close(self) -> None:
        """Close the route (the last one restores the handlers, levels and propagation)."""
        _DISPATCH.remove(self)


_ACTIVE: ContextVar[LogRoute | None] = ContextVar('pmba_ros_log_route', default=None)


class _Dispatch(logging.Handler):
    """The package logger's handler while routes are open: each record to its route."""

    def __init__(self) -> None:
        super().__init__()
        self.routes: list[LogRoute] = []
        self._routes_lock = threading.Lock()
        self._saved: dict[str, int] = {}

    def emit(self, record: logging.LogRecord) -> None:
        routes = self.routes
        route = _ACTIVE.get()
        if route not in routes:   # none active here, or closed since: the oldest open one
            route = routes[0] if routes else None
        if route is not None:
            route.handler.handle(record)

    def add(self, route: LogRoute) -> None:
        with self._routes_lock:
            if not self.routes:
                self._saved = {name: logging.getLogger(name).level
                               for name in (_PACKAGE, *ENGINE_LOGGERS)}
                package_logger = logging.getLogger(_PACKAGE)
                package_logger.addHandler(self)
                package_logger.propagate = False
            self.routes = [*self.routes, route]
            self._set_levels()

    def remove(self, route: LogRoute) -> None:
        with self._routes_lock:
            if route not in self.routes:
                return
            self.routes = [r for r in self.routes if r is not route]
            if self.routes:
                self._set_levels()
                return
            package_logger = logging.getLogger(_PACKAGE)
            package_logger.removeHandler(self)
            package_logger.propagate = True
            for name, level in self._saved.items():
                logging.getLogger(name).setLevel(level)

    def _set_levels(self) -> None:
        logging.getLogger(_PACKAGE).setLevel(min(r.level for r in self.routes))
        engine = min(r.level if r.level <= logging.DEBUG else max(r.level, logging.WARNING)
                     for r in self.routes)
        for name in ENGINE_LOGGERS:
            logging.getLogger(name).setLevel(engine)


_DISPATCH = _Dispatch()


__all__ = ['ENGINE_LOGGERS', 'LogRoute', 'RosLogHandler']
