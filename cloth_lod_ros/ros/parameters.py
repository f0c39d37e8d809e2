"""The node's parameters: declarations, ranges and validation (design §6).

Validation never touches the simulator: scene parameters are checked as a whole
scene (:func:`~cloth_lod_ros.sim.cloth.live_update`) against the scene as it will
be once the changes already accepted are applied, so a change is answered at
once and applied by the stepping thread before its next step.
"""

from __future__ import annotations

import array

import numpy as np
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)

from ..bag.rosbag import COMPRESSIONS
from ..sim.cloth import live_update
from ..sim.scene.config import SceneConfig, SceneError
from ..sim.integrate.step_control import effective_tolerance

__all__ = ["LIVE", "LIVE_CHOICES", "COLOUR_BY", "declare_parameters", "declare_scene_parameters",
           "validate", "scene_value", "outside_declared_range"]

# Live-tunable scene parameters: name -> (scene path, unit, low, high); low and
# high None: a vector of 3 (m/s for the wind), validated by the scene.
LIVE = {
    "lod.refine_threshold": ("lod.refine_threshold", "m", 1e-6, 1.0),
    "lod.coarsen_threshold": ("lod.coarsen_threshold", "m", 1e-7, 1.0),
    "lod.min_lifetime": ("lod.min_lifetime", "s", 0.0, 60.0),
    "lod.max_hinge_rate": ("lod.max_hinge_rate", "rad/s", 1e-6, 1e3),
    "lod.max_bend_force": ("lod.max_bend_force", "N", 1e-9, 1e3),
    "lod.max_merge_speed": ("lod.max_merge_speed", "m/s", 0.0, 100.0),
    "material.stretch_stiffness": ("material.stretch_stiffness", "N/m", 0.0, 1e7),
    "material.shear_stiffness": ("material.shear_stiffness", "N/m", 0.0, 1e7),
    "material.bend_stiffness": ("material.bend_stiffness", "N*m", 0.0, 10.0),
    "material.air_drag": ("material.air_drag", "1/s", 0.0, 100.0),
    "air.density": ("air.density", "kg/m^3", 0.0, 1000.0),
    "air.drag_coefficient": ("air.drag_coefficient", "", 0.0, 100.0),
    "air.wind": ("air.wind", "m/s", None, None),
    "simulation.error_tolerance": ("simulation.error_tolerance", "m", 0.0, 1.0),
}
# Live scene parameters that are names: parameter -> (scene path, choices).
LIVE_CHOICES = {
    "simulation.integrator": ("simulation.integrator",
                              ("sdirk2", "backward_euler", "baraff_witkin")),
}
COLOUR_BY = ("level", "shading")


def _float_descriptor(text, unit, low, high, read_only=False):
    return ParameterDescriptor(
        description=f"{text} [{unit}]" if unit else text, read_only=read_only,
        floating_point_range=[FloatingPointRange(from_value=float(low), to_value=float(high))])


def declare_parameters(node) -> None:
    """Declare the node's parameters (all but the live scene ones, which take
    their defaults from the scene: :func:`declare_scene_parameters`)."""
    string = ParameterDescriptor
    node.declare_parameter("scene", "hang_two_corners", string(
        description="built-in scene name or path to a scene YAML file", read_only=True))
    node.declare_parameter("frame_id", "world", string(
        description="frame of the cloth; grasp poses must use it", read_only=True))
    node.declare_parameter("time_step", 0.0, _float_descriptor(
        "simulation time step, 0 = the scene's", "s", 0.0, 1.0, read_only=True))
    node.declare_parameter("publish_rate", 30.0, _float_descriptor(
        "rate of cloth/markers, cloth/points, cloth/grid and cloth/lod_stats; "
        "at most one frame per step tick (1/time_step in real time)", "Hz", 0.1, 1000.0))
    node.declare_parameter("realtime", True, string(
        description="pace steps to the clock (false: step as fast as possible)"))
    node.declare_parameter("paused", False, string(
        description="pause (true) or run (false) the simulation; cloth/pause does the same"))
    node.declare_parameter("grid_resolution", 21, ParameterDescriptor(
        description="points per side of the cloth/grid resampling", read_only=True,
        integer_range=[IntegerRange(from_value=2, to_value=257, step=1)]))
    node.declare_parameter("stale_pose_timeout", 1.0, _float_descriptor(
        "reject grasp poses stamped more than this before or after the node's clock, "
        "0 = never", "s", 0.0, 3600.0))
    node.declare_parameter("workspace_min", [-10.0, -10.0, -10.0], string(
        description="[m] x, y, z lower corner of the box grasp targets must lie in"))
    node.declare_parameter("workspace_max", [10.0, 10.0, 10.0], string(
        description="[m] x, y, z upper corner of the box grasp targets must lie in"))
    node.declare_parameter("strain_warn", 0.3, _float_descriptor(
        "WARN above this strain | |w| - 1 | (ERROR above 4x)", "", 1e-3, 100.0))
    node.declare_parameter("speed_warn", 20.0, _float_descriptor(
        "WARN above this particle speed (ERROR above 4x)", "m/s", 1e-3, 1e4))
    node.declare_parameter("auto_reset", 0.0, _float_descriptor(
        "reset the scene by itself (as cloth/reset) once the simulation has stopped, or "
        "its health has been ERROR, for this long; 0 = never", "s", 0.0, 3600.0))
    node.declare_parameter("colour_by", "level", string(
        description="surface colours: 'level' or 'shading'"))
    node.declare_parameter("wireframe", True, string(description="publish the wireframe"))
    node.declare_parameter("publish_clock", False, string(
        description="publish /clock from the simulated time and stamp outputs with it",
        read_only=True))
    node.declare_parameter("record", False, string(
        description="record the session to a bag from the start", read_only=True))
    node.declare_parameter("record_path", "", string(
        description="bag directory; '' = bags/cloth_lod_<date>_<time>_<ms>; a name "
                    "taken gets _2, _3, ... (a bag is never overwritten)",
        read_only=True))
    node.declare_parameter("record_compression", "zstd", string(
        description=f"MCAP chunk compression: {', '.join(COMPRESSIONS)}", read_only=True))
    node.declare_parameter("foxglove_port", 0, ParameterDescriptor(
        description="serve the live view to Foxglove on this WebSocket port (e.g. 8765; "
                    "0 = off; needs the viewer extra)", read_only=True,
        integer_range=[IntegerRange(from_value=0, to_value=65535, step=1)]))
    node.declare_parameter("foxglove_host", "127.0.0.1", string(
        description="address the live view listens on (0.0.0.0: every interface)",
        read_only=True))


def declare_scene_parameters(node, scene: SceneConfig) -> None:
    """Declare the live scene parameters with the scene's values as defaults."""
    for name, (path, unit, low, high) in LIVE.items():
        section, key = path.split(".")
        value = getattr(getattr(scene, section), key)
        if path == "simulation.error_tolerance":
            value = effective_tolerance(scene.simulation)     # unset: what it means
        if low is None:
            node.declare_parameter(name, [float(c) for c in value], ParameterDescriptor(
                description=f"{name} [{unit}] x, y, z"))
        else:
            node.declare_parameter(name, float(value), _float_descriptor(name, unit, low, high))
    for name, (path, choices) in LIVE_CHOICES.items():
        section, key = path.split(".")
        node.declare_parameter(name, getattr(getattr(scene, section), key), ParameterDescriptor(
            description=f"{name}: one of {', '.join(choices)}"))


def scene_value(value):
    """A parameter's value as a scene field takes it: an array (rclpy gives
    ``array.array`` for double arrays) as a list, anything else unchanged."""
    return list(value) if isinstance(value, (array.array, list, tuple)) else value


def outside_declared_range(name: str, value, descriptor) -> str | None:
    """Why ``value`` lies outside ``descriptor``'s floating-point range, or None.

    rclpy accepts a value within a relative 1e-6 of either end
    (``Node.PARAM_REL_TOL``: ``material.stretch_stiffness`` 1e7 + 1 passed a declared
    maximum of 1e7); a declared range is meant exactly, so this checks it again."""
    ranges = getattr(descriptor, "floating_point_range", None) or []
    if not ranges or isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    low, high = sorted((ranges[0].from_value, ranges[0].to_value))
    if low <= value <= high:
        return None
    return f"{name} must be within its declared range [{low!r}, {high!r}], got {value!r}"


def validate(params, current, scene: SceneConfig, describe=None):
    """Check a set of parameter changes as a whole.

    Args:
        params: the rclpy ``Parameter`` objects being set.
        current: ``name -> value`` of the node's parameters now.
        scene: the scene the live scene changes apply to.
        describe: ``name -> ParameterDescriptor`` (``Node.describe_parameter``):
            declared floating-point ranges are enforced exactly.

    Returns:
        ``(SetParametersResult, scene after the changes, {scene path: value})``;
        on refusal the scene is the one given and the changes are empty.
    """
    changes = {}
    for p in params:
        reason = describe is not None and outside_declared_range(p.name, p.value,
                                                                 describe(p.name))
        if reason:
            return SetParametersResult(successful=False, reason=reason), scene, {}
        if p.name == "use_sim_time" and p.value != current("use_sim_time"):
            # Switching it live makes rclpy create or destroy its /clock
            # subscription while the multi-threaded executor may be using it
            # (InvalidHandle: the node dies).  The clock source is chosen at start.
            return SetParametersResult(successful=False, reason=(
                "use_sim_time is read-only while the node runs; start the node with "
                "--ros-args -p use_sim_time:=true (or false)")), scene, {}
        if p.name in LIVE:
            changes[LIVE[p.name][0]] = scene_value(p.value)
        elif p.name in LIVE_CHOICES:
            changes[LIVE_CHOICES[p.name][0]] = p.value
        elif p.name == "colour_by" and p.value not in COLOUR_BY:
            return SetParametersResult(successful=False, reason=(
                f"colour_by must be one of {', '.join(COLOUR_BY)}, got {p.value!r}")), scene, {}
        elif p.name in ("workspace_min", "workspace_max"):
            values = np.asarray(p.value, dtype=float) if p.value is not None else None
            if values is None or values.shape != (3,) or not np.all(np.isfinite(values)):
                return SetParametersResult(successful=False, reason=(
                    f"{p.name} must be 3 finite numbers [m], got {p.value!r}")), scene, {}
    names = {p.name: p.value for p in params}
    low = np.asarray(names.get("workspace_min", current("workspace_min")), dtype=float)
    high = np.asarray(names.get("workspace_max", current("workspace_max")), dtype=float)
    if np.any(low >= high):
        return SetParametersResult(successful=False,
                                   reason="workspace_min must be below workspace_max"), scene, {}
    if changes:
        try:
            scene = live_update(scene, changes)
        except SceneError as exc:
            return SetParametersResult(successful=False, reason=str(exc)), scene, {}
    return SetParametersResult(successful=True), scene, changes
