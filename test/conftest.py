"""Test set-up shared by all tests.

ROS 2 from PyPI wheels: nothing sets ``AMENT_PREFIX_PATH``, which rclpy needs
to find message type support.  Append this interpreter's prefix (colcon sets
the variable to the workspace; appending keeps that first).
"""

import os
import sys

_prefix = sys.prefix
_paths = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
if _prefix not in _paths:
    os.environ["AMENT_PREFIX_PATH"] = os.pathsep.join(_paths + [_prefix])
