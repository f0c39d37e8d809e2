"""Declared parameter ranges, enforced exactly (ros/parameters.py; issue 34)."""

from __future__ import annotations

import math

import pytest

import rclpy  # noqa: E402,F401  (the test extra installs it: without it these fail, never skip)

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from cloth_lod_ros.ros.parameters import LIVE, outside_declared_range, validate  # noqa: E402
from cloth_lod_ros.sim.scene.config import load_scene  # noqa: E402


def descriptor(low, high):
    return ParameterDescriptor(floating_point_range=[
        FloatingPointRange(from_value=low, to_value=high)])


def test_rclpy_alone_lets_a_value_just_past_the_maximum_through():
    """The outside truth this guards against: rclpy's own check has a relative
    tolerance, so 1e7 + 1 passes a declared maximum of 1e7."""
    assert Node.PARAM_REL_TOL > 0
    assert math.isclose(1e7 + 1, 1e7, rel_tol=Node.PARAM_REL_TOL)


@pytest.mark.parametrize("value,inside", [
    (1e7, True), (0.0, True), (5e6, True), (1e7 + 1, False), (math.nextafter(1e7, 2e7), False),
    (-1e-300, False), (float("nan"), False)])
def test_a_declared_range_is_exact(value, inside):
    reason = outside_declared_range("material.stretch_stiffness", value, descriptor(0.0, 1e7))
    assert (reason is None) == inside, reason
    if not inside:
        assert "declared range [0.0, 10000000.0]" in reason


def test_validate_refuses_past_the_maximum_of_every_live_parameter():
    scene = load_scene("hang_two_corners")
    for name, (_, _, low, high) in LIVE.items():
        if low is None:
            continue
        just_over = high * (1 + 1e-7) if high > 0 else high + 1e-300
        result, after, changes = validate([Parameter(name, value=just_over)], lambda n: None,
                                          scene, lambda n: descriptor(low, high))
        assert not result.successful and "declared range" in result.reason, name
        assert after is scene and changes == {}
    # Without descriptors (as before), only the scene's own checks apply.
    result, _, _ = validate([Parameter("material.stretch_stiffness", value=1e7 + 1)],
                            lambda n: None, scene)
    assert result.successful
