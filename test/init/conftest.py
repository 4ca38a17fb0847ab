"""Fixtures of the global-initialization tests."""

from __future__ import annotations

import pytest


def pytest_configure(config: pytest.Config) -> None:
    """Register the ``slow`` marker used by the heavier real-data runs."""
    config.addinivalue_line('markers', 'slow: heavier test (deselect with -m "not slow")')
