"""Fixtures shared by the back-end tests: the pinned Jazzy typestore and a message backend."""

from __future__ import annotations

from typing import Any

from pmba_ros.backend import outputs
import pytest
from rosbags.typesys import get_typestore, Stores


@pytest.fixture(scope='module')
def ts() -> Any:
    """Return the pinned Jazzy typestore."""
    return get_typestore(Stores.ROS2_JAZZY)


@pytest.fixture(scope='module')
def backend(ts: Any) -> outputs.RosbagsBackend:
    """Return a rosbags message backend on the Jazzy store."""
    return outputs.RosbagsBackend(ts)
