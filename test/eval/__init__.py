"""Tests of pmba_ros.eval."""
