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
"""Fixtures shared by the back-end tests: the pinned Jazzy typestore and a message backend."""

from __future__ import annotations

from typing import Any

from pmba_ros.backend.msg_backend import RosbagsBackend
import pytest
from rosbags.typesys import get_typestore, Stores


@pytest.fixture(scope='module')
def ts() -> Any:
    """Return the pinned Jazzy typestore."""
    return get_typestore(Stores.ROS2_JAZZY)


@pytest.fixture(scope='module')
def backend(ts: Any) -> RosbagsBackend:
    """Return a rosbags message backend on the Jazzy store."""
    return RosbagsBackend(ts)
