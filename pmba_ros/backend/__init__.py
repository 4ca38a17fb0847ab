"""The ROS-free back-end: message adapters, state machine and outputs."""
