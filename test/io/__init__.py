"""Tests of pmba_ros.io."""
