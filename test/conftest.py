"""Test set-up shared by all tests.

ROS 2 from PyPI wheels: nothing sets ``AMENT_PREFIX_PATH``, which rclpy needs
to find message type support.  Append this interpreter's prefix (colcon sets
the variable to the workspace; appending keeps that first).
"""

import os
import sys

import pytest

_prefix = sys.prefix
_paths = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
if _prefix not in _paths:
    os.environ["AMENT_PREFIX_PATH"] = os.pathsep.join(_paths + [_prefix])


@pytest.fixture
def kernels_restored():
    """For tests that switch between the compiled kernels and the numpy
    reference (``compiled.use``): the switch is left as it was found."""
    from cloth_lod_ros.sim.runtime import compiled
    previous = compiled.enabled()
    yield
    compiled.use(previous)
