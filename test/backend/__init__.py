"""Tests of pmba_ros.backend."""
