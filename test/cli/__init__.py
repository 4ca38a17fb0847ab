"""Tests of pmba_ros.cli."""
