"""Tests of pmba_ros.core."""
