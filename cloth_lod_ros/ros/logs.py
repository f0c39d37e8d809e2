"""The simulator's Python log records on the node's ROS logger (design §6)."""

from __future__ import annotations

import logging

__all__ = ["forward_library_logs"]


class _RosLogHandler(logging.Handler):
    """Send the simulator's Python log records (e.g. a grasp catching up with a
    jumped target) to the node's ROS logger."""

    def __init__(self, ros_logger):
        super().__init__(level=logging.INFO)
        self.ros_logger = ros_logger

    def emit(self, record):
        # One call per severity, each on its own line: rclpy keys a logging call
        # by its call site and raises ValueError ("Logger severity cannot be
        # changed between calls") when one site logs at two severities - inside
        # the step that logged, which then failed and stopped the simulation.
        message = record.getMessage()
        if record.levelno >= logging.ERROR:
            self.ros_logger.error(message)
        elif record.levelno >= logging.WARNING:
            self.ros_logger.warning(message)
        else:
            self.ros_logger.info(message)


def forward_library_logs(ros_logger) -> None:
    library = logging.getLogger("cloth_lod_ros")
    library.handlers = [h for h in library.handlers if not isinstance(h, _RosLogHandler)]
    library.addHandler(_RosLogHandler(ros_logger))
    library.setLevel(logging.INFO)      # the kernels' warm-up, a grasp catching up
    library.propagate = False
