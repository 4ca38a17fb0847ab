"""Tests of pmba_ros.sim."""
