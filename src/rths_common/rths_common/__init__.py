"""Shared ROS-side helpers of the rths nodes: topics, QoS, parameters, status, spin loops, CDR."""
