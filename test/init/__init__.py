"""Tests of pmba_ros.init."""
