"""Tests of pmba_ros, mirroring the package layout."""
