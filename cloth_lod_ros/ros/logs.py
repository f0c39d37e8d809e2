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
        level = {logging.WARNING: "warning", logging.ERROR: "error"}.get(record.levelno, "info")
        getattr(self.ros_logger, level)(record.getMessage())


def forward_library_logs(ros_logger) -> None:
    library = logging.getLogger("cloth_lod_ros")
    library.handlers = [h for h in library.handlers if not isinstance(h, _RosLogHandler)]
    library.addHandler(_RosLogHandler(ros_logger))
    library.propagate = False
