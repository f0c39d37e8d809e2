"""The simulator's Python log records on the node's ROS logger.

rclpy keys a logging call by its call site and refuses (ValueError) a second
severity from the same site; the records forwarded from the library come at
every severity - the kernels' warm-up at INFO, a grasp catching up with a jumped
target at WARNING - and a refusal raised inside the step that logged, which then
stopped the simulation (the README's grasp example did: INFO at start-up, then
WARNING when the first pose arrived).
"""

import logging

import pytest

import rclpy.logging as rclpy_logging  # noqa: E402  (the ROS tests run in CI: fail, never skip)

from cloth_lod_ros.ros.logs import forward_library_logs  # noqa: E402


def test_records_of_every_severity_reach_the_ros_logger_in_any_order(capfd):
    library = logging.getLogger("cloth_lod_ros")
    saved = library.handlers[:], library.propagate, library.level
    forward_library_logs(rclpy_logging.get_logger("test_node_logs"))
    library.setLevel(logging.INFO)
    source = logging.getLogger("cloth_lod_ros.sim.test_source")
    try:
        for level in (logging.INFO, logging.WARNING, logging.ERROR, logging.INFO,
                      logging.ERROR, logging.WARNING):
            source.log(level, "record at %s", logging.getLevelName(level))
    finally:
        library.handlers, library.propagate = saved[0], saved[1]
        library.setLevel(saved[2])
    err = capfd.readouterr().err
    for name, ros in (("INFO", "INFO"), ("WARNING", "WARN"), ("ERROR", "ERROR")):
        assert f"[{ros}]" in err and f"record at {name}" in err, err
    assert err.count("[test_node_logs]: record at") == 6, err
