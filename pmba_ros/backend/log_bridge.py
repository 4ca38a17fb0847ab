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
"""Python ``logging`` of the package forwarded to a ROS logger (no rclpy import)."""

from __future__ import annotations

import logging
from typing import Any

ENGINE_LOGGERS = ('pmba_ros.core', 'pmba_ros.init')
"""Loggers whose INFO lines come with every solve (debug material for a running node)."""


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

    The package logger takes the ROS logger's level and stops propagating (no duplicate
    lines on the console); the engine loggers are held at WARNING unless the level is DEBUG.

    Args:
        ros_logger: An rclpy logger (``node.get_logger()``).
    """

    def __init__(self, ros_logger: Any) -> None:
        """Install the handler and set the levels (the previous ones are kept)."""
        self.handler = RosLogHandler(ros_logger)
        level = int(ros_logger.get_effective_level())
        self._saved = {name: logging.getLogger(name).level
                       for name in ('pmba_ros', *ENGINE_LOGGERS)}
        package_logger = logging.getLogger('pmba_ros')
        package_logger.addHandler(self.handler)
        package_logger.setLevel(level)
        package_logger.propagate = False
        for name in ENGINE_LOGGERS:
            # Their INFO lines come with every solve: debug material for a running node.
            logging.getLogger(name).setLevel(level if level <= logging.DEBUG
                                             else max(level, logging.WARNING))

    def close(self) -> None:
        """Remove the handler and restore the levels and propagation."""
        package_logger = logging.getLogger('pmba_ros')
        package_logger.removeHandler(self.handler)
        package_logger.propagate = True
        for name, level in self._saved.items():
            logging.getLogger(name).setLevel(level)


__all__ = ['ENGINE_LOGGERS', 'LogRoute', 'RosLogHandler']
