"""``cloth_lod_node``: the adaptive cloth simulator as a ROS 2 node (design §6).

Thin by design: declare parameters, build a :class:`~cloth_lod_ros.sim.ClothSim`,
wire topics and services.  Inputs (grasp poses, open/close) go straight into the
simulator; outputs are built vectorised by :mod:`cloth_lod_ros.messages.markers`.

Topics (relative names, so a namespace or remap moves them all):
  in:  ``grasp/<name>/pose`` (geometry_msgs/PoseStamped) for each grasp of the scene
  out: ``cloth/markers`` (visualization_msgs/MarkerArray), ``cloth/lod_stats``
       (diagnostic_msgs/DiagnosticArray), ``cloth/points`` (sensor_msgs/PointCloud2,
       one point per particle), ``cloth/grid`` (organised PointCloud2 sampled on a
       fixed (u, v) grid: the same points every message, whatever the mesh)
Services: ``grasp/<name>/close`` (std_srvs/SetBool: true holds, false releases),
  ``cloth/reset``, ``cloth/step`` (std_srvs/Trigger), ``cloth/pause`` (std_srvs/SetBool),
  ``cloth/record`` (std_srvs/SetBool: true starts a bag, false finishes it).

Recording (parameter ``record`` or the service) writes a rosbag2 MCAP bag of the
session: inputs as applied, outputs as published, and the scene and parameters
(:mod:`cloth_lod_ros.bag.recorder`).  A recording failure is logged and reported in
``cloth/lod_stats``; the simulation goes on.
"""

from __future__ import annotations

import logging
import math
import threading
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from rclpy.serialization import serialize_message

from ..bag.rosbag import COMPRESSIONS, BagError
from ..sim.config import SceneError, load_scene, scene_to_dict
from ..bag.recorder import SessionRecorder
from ..messages.frames import FrameBuilder
from ..sim import ClothSim, SimulationError

__all__ = ["ClothLodNode", "main"]

# Live-tunable parameters: name -> (scene path, unit, low, high).
LIVE = {
    "lod.refine_threshold": ("lod.refine_threshold", "m", 1e-6, 1.0),
    "lod.coarsen_threshold": ("lod.coarsen_threshold", "m", 1e-7, 1.0),
    "lod.min_lifetime": ("lod.min_lifetime", "s", 0.0, 60.0),
    "lod.max_hinge_rate": ("lod.max_hinge_rate", "rad/s", 1e-6, 1e3),
    "lod.max_bend_force": ("lod.max_bend_force", "N", 1e-9, 1e3),
    "material.stretch_stiffness": ("material.stretch_stiffness", "N/m", 0.0, 1e7),
    "material.shear_stiffness": ("material.shear_stiffness", "N/m", 0.0, 1e7),
    "material.bend_stiffness": ("material.bend_stiffness", "N*m", 0.0, 10.0),
    "material.air_drag": ("material.air_drag", "1/s", 0.0, 100.0),
}


def _float_descriptor(text, unit, low, high, read_only=False):
    return ParameterDescriptor(
        description=f"{text} [{unit}]" if unit else text, read_only=read_only,
        floating_point_range=[FloatingPointRange(from_value=float(low), to_value=float(high))])


class ClothLodNode(Node):
    """Runs a cloth scene, driven by grasp poses, publishing its mesh and statistics."""

    def __init__(self, **kwargs):
        super().__init__("cloth_lod_node", **kwargs)
        string = ParameterDescriptor
        self.declare_parameter("scene", "hang_two_corners", string(
            description="built-in scene name or path to a scene YAML file", read_only=True))
        self.declare_parameter("frame_id", "world", string(
            description="frame of the cloth; grasp poses must use it", read_only=True))
        self.declare_parameter("time_step", 0.0, _float_descriptor(
            "simulation time step, 0 = the scene's", "s", 0.0, 1.0, read_only=True))
        self.declare_parameter("publish_rate", 30.0, _float_descriptor(
            "rate of cloth/markers, cloth/points, cloth/grid and cloth/lod_stats",
            "Hz", 0.1, 1000.0))
        self.declare_parameter("realtime", True, string(
            description="pace steps to the clock (false: step as fast as possible)"))
        self.declare_parameter("paused", False, string(description="start paused"))
        self.declare_parameter("grid_resolution", 21, ParameterDescriptor(
            description="points per side of the cloth/grid resampling", read_only=True,
            integer_range=[IntegerRange(from_value=2, to_value=257, step=1)]))
        self.declare_parameter("stale_pose_timeout", 1.0, _float_descriptor(
            "reject grasp poses stamped older than this, 0 = never", "s", 0.0, 3600.0))
        self.declare_parameter("colour_by", "level", string(
            description="surface colours: 'level' or 'shading'"))
        self.declare_parameter("wireframe", True, string(description="publish the wireframe"))
        self.declare_parameter("record", False, string(
            description="record the session to a bag from the start", read_only=True))
        self.declare_parameter("record_path", "", string(
            description="bag directory; '' = bags/cloth_lod_<date>_<time>; must not exist",
            read_only=True))
        self.declare_parameter("record_compression", "zstd", string(
            description=f"MCAP chunk compression: {', '.join(COMPRESSIONS)}", read_only=True))
        scene = load_scene(self.get_parameter("scene").value)
        for name, (path, unit, low, high) in LIVE.items():
            section, key = path.split(".")
            value = float(getattr(getattr(scene, section), key))
            self.declare_parameter(name, value, _float_descriptor(name, unit, low, high))
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.frame_id = self.get_parameter("frame_id").value
        _forward_library_logs(self.get_logger())
        # Inputs run beside the (possibly long) step: poses are checked when they
        # arrive, not after the step, and the simulator is shared under a lock.
        self._lock = threading.RLock()
        self._inputs = MutuallyExclusiveCallbackGroup()
        self._stepping = MutuallyExclusiveCallbackGroup()
        self.rejected = {"frame": 0, "not_finite": 0, "stale": 0}
        self._build_sim()
        reliable_latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.markers_pub = self.create_publisher(MarkerArray, "cloth/markers", reliable_latched)
        self.points_pub = self.create_publisher(PointCloud2, "cloth/points", 10)
        self.grid_pub = self.create_publisher(PointCloud2, "cloth/grid", 10)
        self.stats_pub = self.create_publisher(DiagnosticArray, "cloth/lod_stats", 10)
        for g in self.sim.grasps:
            self.create_subscription(PoseStamped, f"grasp/{g.name}/pose",
                                     lambda msg, name=g.name: self._on_pose(name, msg), 10,
                                     callback_group=self._inputs)
            self.create_service(SetBool, f"grasp/{g.name}/close",
                                lambda req, res, name=g.name: self._locked(self._on_close,
                                                                           name, req, res),
                                callback_group=self._inputs)
        self.create_service(Trigger, "cloth/reset",
                            lambda req, res: self._locked(self._on_reset, req, res),
                            callback_group=self._inputs)
        self.create_service(Trigger, "cloth/step",
                            lambda req, res: self._locked(self._on_step, req, res),
                            callback_group=self._inputs)
        self.create_service(SetBool, "cloth/pause",
                            lambda req, res: self._locked(self._on_pause, req, res),
                            callback_group=self._inputs)
        self.create_service(SetBool, "cloth/record",
                            lambda req, res: self._locked(self._on_record, req, res),
                            callback_group=self._inputs)
        self.paused = bool(self.get_parameter("paused").value)
        self.recorder: SessionRecorder | None = None
        self.record_error: str | None = None
        if self.get_parameter("record").value:
            self._start_recording(self.get_parameter("record_path").value)
        self._last_publish = -math.inf
        self._wall_start = time.monotonic()     # pacing origin (moves on resume)
        self._session_wall_start = self._wall_start   # wall_time_s origin (moves on reset)
        self._sim_start = 0.0
        period = self.sim.time_step if self.get_parameter("realtime").value else 1e-4
        self.timer = self.create_timer(period, lambda: self._locked(self._on_timer),
                                       callback_group=self._stepping)
        self.get_logger().info(
            f"scene {self.sim.scene.name}: {self.sim.mesh.vertex_count} particles, "
            f"grasps {[g.name for g in self.sim.grasps]}, h = {self.sim.time_step:.4g} s")

    def _locked(self, function, *args):
        with self._lock:
            return function(*args)

    # -- simulator ---------------------------------------------------------
    def _build_sim(self) -> None:
        overrides = {path: self.get_parameter(name).value
                     for name, (path, *_) in LIVE.items()}
        if self.get_parameter("time_step").value > 0:
            overrides["simulation.time_step"] = self.get_parameter("time_step").value
        # Only recent step statistics are kept: the node may run for days.
        self.sim = ClothSim(load_scene(self.get_parameter("scene").value, overrides),
                            keep_stats=1000)
        self.frames = FrameBuilder(self.frame_id, self.get_parameter("grid_resolution").value,
                                   self.get_parameter("colour_by").value,
                                   self.get_parameter("wireframe").value)
        self.error = None

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Validate live changes as a whole scene; refuse with the reason, keep old values."""
        changes = {LIVE[p.name][0]: p.value for p in params if p.name in LIVE}
        if not changes:
            return SetParametersResult(successful=True)
        with self._lock:
            return self._apply_live(changes)

    def _apply_live(self, changes: dict) -> SetParametersResult:
        try:
            self.sim.update_parameters(changes)
        except SceneError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self._record_input("parameters", changes=changes)
        return SetParametersResult(successful=True)

    def _on_timer(self) -> None:
        if self.paused or self.error is not None:
            self._publish(force=False)
            return
        if self.get_parameter("realtime").value:
            # Catch up with the wall clock, at most a few steps per tick.
            behind = (time.monotonic() - self._wall_start) - (self.sim.time - self._sim_start)
            steps = min(max(int(behind / self.sim.time_step), 0), 3)
        else:
            steps = 1
        for _ in range(steps):
            self._step_once()
        self._publish(force=False)

    def _step_once(self) -> bool:
        try:
            self.sim.step()
            return True
        except SimulationError as exc:
            self.error = str(exc)
            self.get_logger().error(f"simulation stopped: {exc}; call cloth/reset")
            return False

    # -- inputs --------------------------------------------------------------
    def _on_pose(self, name: str, msg: PoseStamped) -> None:
        """Check a pose when it arrives (stamps are judged now, not after a step)."""
        if self.recorder is not None:
            with self._lock:
                self.recorder.record_message(f"grasp/{name}/pose", serialize_message(msg))
        reason = self._check_pose(msg)
        if reason is not None:
            self.rejected[reason] += 1
            self.get_logger().warning(
                f"grasp/{name}/pose rejected ({reason}); {sum(self.rejected.values())} "
                "rejected so far", throttle_duration_sec=2.0)
            return
        p, q = msg.pose.position, msg.pose.orientation
        with self._lock:
            self.sim.set_grasp_target(name, [p.x, p.y, p.z], [q.x, q.y, q.z, q.w])
            self._record_input("grasp_target", grasp=name, position=[p.x, p.y, p.z],
                               orientation=[q.x, q.y, q.z, q.w])

    def _check_pose(self, msg: PoseStamped) -> str | None:
        if msg.header.frame_id not in ("", self.frame_id):
            return "frame"
        p, q = msg.pose.position, msg.pose.orientation
        values = np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w])
        if not np.all(np.isfinite(values)) or np.linalg.norm(values[3:]) < 1e-9:
            return "not_finite"
        timeout = self.get_parameter("stale_pose_timeout").value
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        if timeout > 0 and stamp > 0:
            now = self.get_clock().now().nanoseconds * 1e-9
            if now - stamp > timeout:
                return "stale"
        return None

    def _on_close(self, name: str, request, response):
        try:
            (self.sim.close_grasp if request.data else self.sim.open_grasp)(name)
            self._record_input("grasp_close" if request.data else "grasp_open", grasp=name)
            response.success = True
            response.message = f"grasp {name} {'closed' if request.data else 'opened'}"
        except (KeyError, ValueError) as exc:
            response.success, response.message = False, str(exc)
        return response

    def _on_reset(self, request, response):
        self._build_sim()
        self._record_input("reset", scene=scene_to_dict(self.sim.scene))
        self._sim_start, self._wall_start = 0.0, time.monotonic()
        self._session_wall_start = self._wall_start
        response.success, response.message = True, "reset to the scene's initial state"
        self._publish(force=True)
        return response

    def _on_step(self, request, response):
        ok = self._step_once()
        self._publish(force=True)
        response.success = ok
        response.message = f"t = {self.sim.time:.4f} s" if ok else self.error
        return response

    def _on_pause(self, request, response):
        if self.paused != bool(request.data):
            self._record_input("pause" if request.data else "resume")
        self.paused = bool(request.data)
        if not self.paused:
            self._sim_start, self._wall_start = self.sim.time, time.monotonic()
        response.success, response.message = True, "paused" if self.paused else "running"
        return response

    # -- recording -----------------------------------------------------------
    def _record_input(self, kind: str, **payload) -> None:
        if self.recorder is not None:
            self.recorder.record_input(self.sim, kind, self._now_ns(), **payload)

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _start_recording(self, path: str) -> str:
        """Open a bag; on failure log it, report it in lod_stats and go on."""
        if not path:
            path = time.strftime("bags/cloth_lod_%Y%m%d_%H%M%S")
        try:
            self.recorder = SessionRecorder(
                path, self.get_namespace(), self.get_parameter("record_compression").value,
                grasp_names=[g.name for g in self.sim.grasps])
        except BagError as exc:
            self.record_error = str(exc)
            self.get_logger().error(f"recording not started: {exc}")
            return self.record_error
        self.record_error = None
        if self.sim.step_count:
            self.get_logger().warning(
                f"recording starts at step {self.sim.step_count}: `cloth-lod replay` needs a "
                "recording from the start (record:=true, or call cloth/reset after this)")
        params = {n: self.get_parameter(n).value
                  for n in self.list_parameters([], 0).names}
        self.recorder.start(self.sim, params, self.get_parameter("grid_resolution").value,
                            self._now_ns())
        self.get_logger().info(f"recording to {self.recorder.path}")
        return f"recording to {self.recorder.path}"

    def _stop_recording(self) -> str:
        recorder, self.recorder = self.recorder, None
        if recorder is None:
            return "not recording"
        recorder.close()
        if recorder.failed:
            self.record_error = recorder.failed
            return f"recording failed: {recorder.failed}"
        if self.context.ok():        # no ROS logging once the context is shut down
            self.get_logger().info(f"recording finished: {recorder.path}")
        return f"wrote {recorder.path}"

    def _on_record(self, request, response):
        if request.data and self.recorder is None:
            response.message = self._start_recording(self.get_parameter("record_path").value
                                                     if self.record_error is None else "")
            response.success = self.recorder is not None
        elif request.data:
            response.success, response.message = True, f"already recording to {self.recorder.path}"
        else:
            response.message = self._stop_recording()
            response.success = self.record_error is None
        return response

    def _recording_status(self) -> str:
        if self.recorder is not None and self.recorder.failed:
            self.record_error = self.recorder.failed
        if self.record_error is not None:
            return f"failed: {self.record_error}"
        if self.recorder is None:
            return "off"
        dropped = self.recorder.dropped_frames
        return f"on: {self.recorder.path}" + (f" ({dropped} frames dropped: disk behind)"
                                               if dropped else "")

    def destroy_node(self):
        with self._lock:
            self._stop_recording()
        return super().destroy_node()

    # -- outputs -------------------------------------------------------------
    def _publish(self, force: bool) -> None:
        now = time.monotonic()
        if not force and now - self._last_publish < 1.0 / self.get_parameter("publish_rate").value:
            return
        self._last_publish = now
        sim = self.sim
        stamp = self.get_clock().now()
        wall = now - self._wall_start
        recording = self._recording_status()
        values = {"paused": str(self.paused).lower(),
                  "wall_time_s": f"{now - self._session_wall_start:.6f}",
                  "real_time_factor": f"{(sim.time - self._sim_start) / max(wall, 1e-9):.3f}",
                  "rejected_poses": str(sum(self.rejected.values())),
                  "recording": recording}
        values.update({f"rejected_{k}": str(v) for k, v in self.rejected.items()})
        level, message = None, "paused" if self.paused else "running"
        if self.error is not None:
            level, message = DiagnosticStatus.ERROR, self.error
        elif recording.startswith("failed"):
            level, message = DiagnosticStatus.WARN, "recording failed; simulation running"
        sec, nanosec = stamp.seconds_nanoseconds()
        frames = self.frames.build(sim, (sec, nanosec), values, level, message)
        self.markers_pub.publish(frames["cloth/markers"])
        self.points_pub.publish(frames["cloth/points"])
        self.grid_pub.publish(frames["cloth/grid"])
        self.stats_pub.publish(frames["cloth/lod_stats"])
        if self.recorder is not None:
            self.recorder.record_frame(frames, stamp.nanoseconds)


class _RosLogHandler(logging.Handler):
    """Send the simulator's Python log records (e.g. a grasp catching up with a
    jumped target) to the node's ROS logger."""

    def __init__(self, ros_logger):
        super().__init__(level=logging.INFO)
        self.ros_logger = ros_logger

    def emit(self, record):
        level = {logging.WARNING: "warning", logging.ERROR: "error"}.get(record.levelno, "info")
        getattr(self.ros_logger, level)(record.getMessage())


def _forward_library_logs(ros_logger) -> None:
    library = logging.getLogger("cloth_lod_ros")
    library.handlers = [h for h in library.handlers if not isinstance(h, _RosLogHandler)]
    library.addHandler(_RosLogHandler(ros_logger))
    library.propagate = False


def main(args=None) -> None:
    """Entry point (``cloth_lod_node``); Ctrl-C and SIGTERM end it with code 0, a bad
    ``scene`` with one line on stderr and code 2."""
    import sys
    rclpy.init(args=args)
    node = None
    try:
        try:
            node = ClothLodNode()
        except SceneError as exc:       # a bad `scene`: one line, as the CLI says it
            print(f"cloth_lod_node: scene error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        # Two threads: one steps and publishes, the other takes poses and services.
        executor = MultiThreadedExecutor(num_threads=2)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # A signal can shut the context down in the middle of a step or a
        # publish; what that raises is part of a clean stop, anything else is not.
        if rclpy.ok():
            raise
    finally:
        try:
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
        except KeyboardInterrupt:       # a second Ctrl-C while closing: already stopping
            pass


if __name__ == "__main__":  # pragma: no cover
    main()
