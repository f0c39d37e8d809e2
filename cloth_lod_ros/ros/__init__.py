"""Processes on a ROS 2 graph: ``cloth_lod_node`` and the bag player (design §6, §9)."""
