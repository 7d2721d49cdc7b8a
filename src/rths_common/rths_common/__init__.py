"""Shared ROS-side helpers of the rths nodes: topic names, QoS profiles, parameters, status, spin loop."""
