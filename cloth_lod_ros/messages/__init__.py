"""The node's outputs as ROS 2 messages, built with numpy (design §6, §9).

May import the simulator and rclpy's message types and serialisation; creates no
node and never imports mcap.
"""
