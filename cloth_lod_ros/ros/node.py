"""``cloth_lod_node``: the adaptive cloth simulator as a ROS 2 node (design §6).

Thin by design: declare parameters, build a :class:`~cloth_lod_ros.sim.ClothSim`,
wire topics and services.  Three kinds of thread share the work, and only the
stepping thread touches the simulator:

* the **pose thread** judges each grasp or obstacle pose when it arrives (frame, finite,
  orientation, stamp, workspace: :func:`~cloth_lod_ros.ros.inputs.judge_pose`),
  records it, and leaves the newest target per grasp and per obstacle in the
  input queue;
* the **request thread** answers every service call at once - "queued: applies
  before step N" or a refusal with the reason (a full queue during a burst);
  parameter changes are validated as a whole scene without the simulator;
* the **stepping thread** (a steady-clock timer) takes the queue, applies it in
  arrival order (recording each input with the step it precedes), steps as far
  as the pacing clock allows, and publishes on a fixed schedule.

So an input never waits for a step, and no input can stop the node: anything
a step or an input raises is caught, counted and reported in ``cloth/lod_stats``
and ``/diagnostics``; a failed step stops the simulation (ERROR) until
``cloth/reset``.

Topics (relative names, so a namespace or remap moves them all):
  in:  ``grasp/<name>/pose`` (geometry_msgs/PoseStamped) for each grasp of the scene,
       ``obstacle/<name>/pose`` (geometry_msgs/PoseStamped) for each obstacle: the
       pose its frame moves to (at its speed limits), judged like grasp poses
  out: ``cloth/markers`` (visualization_msgs/MarkerArray), ``cloth/lod_stats``
       (diagnostic_msgs/DiagnosticArray), ``cloth/points`` (sensor_msgs/PointCloud2,
       one point per particle), ``cloth/grid`` (organised PointCloud2 sampled on a
       fixed (u, v) grid: the same points every message, whatever the mesh),
       ``/diagnostics`` (1 Hz, numbers only), ``/clock`` (with ``publish_clock``)
Services: ``grasp/<name>/close`` (std_srvs/SetBool: true holds, false releases),
  ``cloth/reset``, ``cloth/step`` (std_srvs/Trigger), ``cloth/pause`` (std_srvs/SetBool),
  ``cloth/record`` (std_srvs/SetBool: true starts a bag, false finishes it).

Live view without RViz (parameter ``foxglove_port``, e.g. 8765; 0 = off; needs the
``viewer`` extra): a Foxglove WebSocket server on ``foxglove_host`` sends each published
frame, at most 60 per second, to Foxglove (:mod:`cloth_lod_ros.live`).

Recording (parameter ``record`` or the service) writes a rosbag2 MCAP bag of the
session: inputs as applied, outputs as published, and the scene and parameters
(:mod:`cloth_lod_ros.bag.recorder`).  A recording failure is logged and reported in
``cloth/lod_stats``; the simulation goes on.
"""

from __future__ import annotations

import collections
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from ..live.server import LiveViewError
from ..messages.frames import FrameBuilder, standard_diagnostics
from ..sim import ClothSim, SimulationError
from ..sim.scene.config import SceneError, load_scene, scene_to_dict
from . import parameters
from .inputs import ERROR, POSE_REJECTIONS, InputQueue, PoseLimits, health, judge_pose
from .logs import forward_library_logs
from .parameters import LIVE, LIVE_CHOICES
from .recording import NodeRecording

__all__ = ["ClothLodNode", "main"]

TICK_BUDGET = 0.25              # s, longest a tick steps on before the timer's next call
DIAGNOSTICS_PERIOD = 1.0        # s, /diagnostics as diagnostic_updater publishes it
RATE_WINDOW = 2.0               # s, window of the measured real-time factor and publish rate
# Service requests queue in the middleware until the request thread takes them:
# a deep queue, so a burst is answered (with a refusal if need be), not dropped.
SERVICE_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
# Poses wait in the middleware while the pose thread waits for the interpreter
# (a long step holds it in compiled code): deep enough for seconds at 100 Hz.
POSE_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
SWITCH_INTERVAL = 2e-4          # s, see main()


class ClothLodNode(Node):
    """Runs a cloth scene, driven by grasp poses, publishing its mesh and statistics."""

    def __init__(self, started: float | None = None, **kwargs):
        """``started``: ``time.monotonic()`` when the process started (the
        first frame's log line counts from it; default: now)."""
        self._started = time.monotonic() if started is None else started
        self._first_frame_logged = False
        super().__init__("cloth_lod_node", **kwargs)
        parameters.declare_parameters(self)
        scene = load_scene(self.get_parameter("scene").value)   # SceneError: main() exits 2
        parameters.declare_scene_parameters(self, scene)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._parameters_set)

        self.frame_id = self.get_parameter("frame_id").value
        self.publish_clock = bool(self.get_parameter("publish_clock").value)
        forward_library_logs(self.get_logger())     # INFO: the kernels' warm-up, in _build_sim
        self.queue = InputQueue()
        self.rejected = dict.fromkeys(POSE_REJECTIONS, 0)
        self.rejected.update(invalid=0, requests=0, parameters=0)
        self.poses_received = 0
        self.internal_errors = 0
        self.auto_resets = 0                        # resets by auto_reset
        self._error_since: float | None = None      # monotonic s when the health became ERROR
        self.error: str | None = None
        self.paused = bool(self.get_parameter("paused").value)
        self._limits = self._pose_limits()
        self._build_sim()
        self.live = self._start_live_view()         # before anything that needs closing
        self.recording = NodeRecording(self.get_namespace(),
                                       self.get_parameter("record_compression").value,
                                       [g.name for g in self.sim.grasps], self.get_logger(),
                                       self.context.ok,
                                       [o.name for o in self.sim.obstacle_motions])
        self._param_scene = self.sim.scene          # what live changes are validated against
        self._sim_time = 0.0                        # read by the input threads

        self._poses = MutuallyExclusiveCallbackGroup()
        self._requests = MutuallyExclusiveCallbackGroup()
        self._stepping = MutuallyExclusiveCallbackGroup()
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.markers_pub = self.create_publisher(MarkerArray, "cloth/markers", latched)
        self.points_pub = self.create_publisher(PointCloud2, "cloth/points", 10)
        self.grid_pub = self.create_publisher(PointCloud2, "cloth/grid", 10)
        self.stats_pub = self.create_publisher(DiagnosticArray, "cloth/lod_stats", 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.clock_pub = (self.create_publisher(ClockMsg, "/clock", 10)
                          if self.publish_clock else None)
        for g in self.sim.grasps:
            self.create_subscription(PoseStamped, f"grasp/{g.name}/pose",
                                     lambda msg, info, name=g.name: self._on_pose(
                                         name, msg, info=info),
                                     POSE_QOS, callback_group=self._poses)
            self._service(SetBool, f"grasp/{g.name}/close",
                          lambda req, res, name=g.name: self._on_close(name, req, res))
        # Every obstacle can be driven live (one that has not been is static).
        for o in self.sim.obstacle_motions:
            self.create_subscription(
                PoseStamped, f"obstacle/{o.name}/pose",
                lambda msg, info, name=o.name: self._on_pose(name, msg, "obstacle", info),
                POSE_QOS, callback_group=self._poses)
        self._service(Trigger, "cloth/reset", self._on_reset)
        self._service(Trigger, "cloth/step", self._on_step)
        self._service(SetBool, "cloth/pause", self._on_pause)
        self._service(SetBool, "cloth/record", self._on_record)
        if self.get_parameter("record").value:
            self._start_recording(self.get_parameter("record_path").value)

        # Timers run on the steady clock: with use_sim_time and no /clock yet the
        # node still ticks, reports that it waits, and answers inputs.
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._session_wall_start = time.monotonic()     # wall_time_s origin (moves on reset)
        self._reset_pacing()
        self._next_publish = time.monotonic()
        self._next_diagnostics = time.monotonic()
        self._publishes: collections.deque = collections.deque()
        self._progress: collections.deque = collections.deque()
        self._last_level = 0
        self._last_values: dict = {}
        self._last_message = "starting"
        self._waiting_for_clock = False
        self.timer = None
        self._make_timer()
        self._log_start()

    # -- set-up ----------------------------------------------------------------
    def _service(self, srv_type, name: str, callback) -> None:
        def answer(request, response):
            try:
                return callback(request, response)
            except Exception as exc:            # a refusal is an answer; never an exception
                self.internal_errors += 1
                response.success, response.message = False, f"internal error: {exc!r}"
                return response
        self.create_service(srv_type, name, answer, qos_profile=SERVICE_QOS,
                            callback_group=self._requests)

    def _make_timer(self) -> None:
        if self.timer is not None:
            self.destroy_timer(self.timer)
        period = self.sim.time_step if self.get_parameter("realtime").value else 1e-4
        self.timer = self.create_timer(period, self._on_timer, callback_group=self._stepping,
                                       clock=self._steady)

    def _log_start(self) -> None:
        rate = self.get_parameter("publish_rate").value
        step_rate = 1.0 / self.sim.time_step
        topics = ", ".join(self.resolve_topic_name(t) for t in (
            "cloth/markers", "cloth/points", "cloth/grid", "cloth/lod_stats"))
        self.get_logger().info(
            f"scene {self.sim.scene.name}: {self.sim.mesh.vertex_count} particles, grasps "
            f"{[g.name for g in self.sim.grasps]}, h = {self.sim.time_step:.4g} s; publishing "
            f"{topics} and /diagnostics in frame '{self.frame_id}' at "
            f"{min(rate, step_rate):g} Hz" + (" (capped at the step rate)" if rate > step_rate
                                             else "")
            + ("; /clock from simulated time" if self.publish_clock else ""))

    def _start_live_view(self):
        """The Foxglove live view with ``foxglove_port`` > 0 (else None); raises
        :class:`~cloth_lod_ros.live.server.LiveViewError` (main: exit code 2)."""
        port = self.get_parameter("foxglove_port").value
        if not port:
            return None
        from ..live.server import LiveView
        live = LiveView(self.get_parameter("foxglove_host").value, port, self.frame_id)
        for line in live.instructions().splitlines():
            self.get_logger().info(line.strip())
        return live

    def _pose_limits(self) -> PoseLimits:
        return PoseLimits(self.frame_id, float(self.get_parameter("stale_pose_timeout").value),
                          tuple(self.get_parameter("workspace_min").value),
                          tuple(self.get_parameter("workspace_max").value))

    def _build_sim(self) -> None:
        overrides = {path: parameters.scene_value(self.get_parameter(name).value)
                     for name, (path, *_) in [*LIVE.items(), *LIVE_CHOICES.items()]}
        if self.get_parameter("time_step").value > 0:
            overrides["simulation.time_step"] = self.get_parameter("time_step").value
        # Only recent step statistics are kept: the node may run for days.
        self.sim = ClothSim(load_scene(self.get_parameter("scene").value, overrides),
                            keep_stats=1000)
        self.frames = FrameBuilder(self.frame_id, self.get_parameter("grid_resolution").value,
                                   self.get_parameter("colour_by").value,
                                   self.get_parameter("wireframe").value)
        self.error = None

    # -- parameters (any thread; never the simulator) --------------------------
    def _validate_parameters(self, params) -> SetParametersResult:
        """Validate a set of changes as a whole; refuse with the reason, keep old values."""
        result, scene, changes = parameters.validate(
            params, lambda name: self.get_parameter(name).value, self._param_scene,
            self._descriptor)
        if result.successful and changes:
            if not self.queue.put_command("parameters", changes):
                return SetParametersResult(successful=False, reason=self._busy())
            self._param_scene = scene
        return result

    def _descriptor(self, name: str):
        """The declared descriptor of ``name`` (None while it is being declared)."""
        try:
            return self.describe_parameter(name)
        except ParameterNotDeclaredException:
            return None

    def set_parameters_atomically(self, parameter_list):
        """rclpy's, counting a refused set in ``rejected_parameters`` wherever it
        is refused: by rclpy before :meth:`_validate_parameters` runs (an
        undeclared name - raised -, a read-only parameter, a wrong type, a value
        outside the declared range, unsetting a declared parameter) or by it.
        Both parameter services (``set_parameters`` once per parameter,
        ``set_parameters_atomically``) call this method."""
        try:
            result = super().set_parameters_atomically(parameter_list)
        except ParameterNotDeclaredException:
            self.rejected["parameters"] += 1
            raise
        if not result.successful:
            self.rejected["parameters"] += 1
        return result

    def set_parameters(self, parameter_list):
        """rclpy's (each parameter set on its own), counting each refusal like
        :meth:`set_parameters_atomically`."""
        try:
            results = super().set_parameters(parameter_list)
        except ParameterNotDeclaredException:
            self.rejected["parameters"] += 1
            raise
        self.rejected["parameters"] += sum(not r.successful for r in results)
        return results

    def _parameters_set(self, params) -> None:
        """After a change took effect: refresh what the input threads read, and
        queue what the stepping thread must apply."""
        names = {p.name for p in params}
        if names & {"stale_pose_timeout", "workspace_min", "workspace_max"}:
            self._limits = self._pose_limits()
        if names & {"colour_by", "wireframe"}:
            self.queue.put_command("frames", self.get_parameter("colour_by").value,
                                   bool(self.get_parameter("wireframe").value))
        if "paused" in names:
            self.queue.put_command("pause", bool(self.get_parameter("paused").value))
        if "realtime" in names:
            self.queue.put_command("realtime")

    def _busy(self) -> str:
        self.rejected["requests"] += 1
        return (f"refused: {self.queue.max_commands} requests are waiting for the simulator; "
                "try again")

    # -- inputs (input threads; never wait for a step) --------------------------
    def _on_pose(self, name: str, msg: PoseStamped, kind: str = "grasp",
                 info: dict | None = None) -> None:
        """A pose on ``<kind>/<name>/pose`` (kind ``grasp`` or ``obstacle``); ``info``:
        rclpy's message info (``received_timestamp``: ns, system clock, when the
        middleware received it)."""
        self.poses_received += 1
        topic = f"{kind}/{name}/pose"
        try:
            p, q = msg.pose.position, msg.pose.orientation
            reason, position, orientation = judge_pose(
                msg.header.frame_id, [p.x, p.y, p.z], [q.x, q.y, q.z, q.w],
                msg.header.stamp.sec, msg.header.stamp.nanosec, self._arrival_s(info),
                self._limits)
            # The bag takes accepted poses as received and rejected ones in a
            # bounded form, both within the recording's input budget (bag/recorder.py).
            if self.recording.recorder is not None:
                if reason is None:
                    self.recording.message(topic, serialize_message(msg))
                else:
                    self.recording.rejected(
                        topic, reason, frame_id=msg.header.frame_id,
                        stamp=[msg.header.stamp.sec, msg.header.stamp.nanosec],
                        position=[p.x, p.y, p.z], orientation=[q.x, q.y, q.z, q.w])
        except Exception as exc:
            self.internal_errors += 1
            reason = "invalid"
            self.get_logger().error(f"{topic}: {exc!r}", throttle_duration_sec=5.0)
        if reason is not None:
            self.rejected[reason] += 1
            self.get_logger().warning(
                f"{kind}/{name}/pose rejected ({reason}); {self._rejected_poses()} "
                "rejected so far", throttle_duration_sec=2.0)
            return
        self.queue.put_target(name, position, orientation,
                              "target" if kind == "grasp" else "obstacle_target")

    def _rejected_poses(self) -> int:
        return sum(self.rejected[k] for k in POSE_REJECTIONS) + self.rejected["invalid"]

    def _queued(self, response, *command, what: str):
        if self.queue.put_command(*command):
            response.success = True
            response.message = f"{what}: queued, applies before step {self.sim.step_count + 1}"
        else:
            response.success, response.message = False, self._busy()
        return response

    def _on_close(self, name: str, request, response):
        return self._queued(response, "close", name, bool(request.data),
                            what=f"grasp {name} {'close' if request.data else 'open'}")

    def _on_reset(self, request, response):
        return self._queued(response, "reset", what="reset to the scene's initial state")

    def _on_step(self, request, response):
        return self._queued(response, "step", what="one step")

    def _on_pause(self, request, response):
        return self._queued(response, "pause", bool(request.data),
                            what="pause" if request.data else "resume")

    def _on_record(self, request, response):
        """``true``: start a bag unless one is being written (a failed one is finished
        first); ``false``: finish the bag, or (not recording) clear a failure shown.
        The answers, state by state, are in docs/recording.md."""
        recording = self.recording
        if request.data and recording.recorder is not None and recording.failed is None:
            response.success = True
            response.message = f"already recording to {recording.recorder.path}"
        elif request.data:
            prefix = ""
            if recording.recorder is not None:          # failed while writing: finish it
                prefix = recording.stop()[1] + "; "
            started, text = self._start_recording(self.get_parameter("record_path").value)
            response.success, response.message = started, prefix + text
        else:
            response.success, response.message = recording.stop()
        return response

    # -- the stepping thread -----------------------------------------------------
    def _on_timer(self) -> None:
        try:
            self._tick()
        except Exception as exc:            # never let a tick end the node
            if not self.context.ok():
                return                      # shutting down: publishing may fail
            self.internal_errors += 1
            self.get_logger().error(f"internal error in a tick: {exc!r}",
                                    throttle_duration_sec=5.0)

    def _tick(self) -> None:
        self._apply_inputs()
        waiting = False
        published = False
        if not self.paused and self.error is None:
            now = self._pace_now()
            realtime = self.get_parameter("realtime").value
            waiting = now is None and realtime      # unpaced, the clock is not waited for
            if now is not None and self._pace_start is None:     # /clock has started
                self._pace_start, self._sim_start = now, self.sim.time
            # A simulation slower than real time steps on within the tick, with
            # frames published on schedule between steps: a tick that returned
            # behind would wait for the timer's next period (half of one on
            # average, 3.7 ms per tick measured on a driven grasp_lift).
            budget_end = time.monotonic() + TICK_BUDGET
            stepped = 0
            while self._step_due(realtime, stepped):
                if stepped:
                    self._apply_inputs()    # what arrived during a step comes before the next
                    if self.paused or self.error is not None:
                        break
                if not self._step_once():
                    break
                stepped += 1
                if time.monotonic() >= self._next_publish:
                    self._publish_on_schedule()
                    published = True
                if time.monotonic() >= budget_end:
                    break
                realtime = self.get_parameter("realtime").value
        self._waiting_for_clock = waiting
        now = time.monotonic()
        if not published and now >= self._next_publish:
            self._publish_on_schedule()
        if now >= self._next_diagnostics:
            self._publish_diagnostics()
            self._next_diagnostics = max(self._next_diagnostics + DIAGNOSTICS_PERIOD, now)

    def _step_due(self, realtime: bool, stepped: int) -> bool:
        """Whether the tick steps (again): unpaced, once per tick; paced, while
        the simulation is a step or more behind the pacing clock."""
        if not realtime:
            return stepped == 0
        now = self._pace_now()
        if now is None or self._pace_start is None:
            return False
        behind = (now - self._pace_start) - (self.sim.time - self._sim_start)
        return behind >= self.sim.time_step

    def _publish_on_schedule(self) -> None:
        self._publish()
        if not self._first_frame_logged:
            self._first_frame_logged = True
            self.get_logger().info(
                f"first frame published {time.monotonic() - self._started:.1f} s after start")
        now = time.monotonic()
        period = 1.0 / self.get_parameter("publish_rate").value
        # A fixed schedule: the rate is exact on average whatever the tick
        # jitter; after a stall, restart it instead of bursting.
        self._next_publish = max(self._next_publish + period, now - period)

    def _apply_inputs(self) -> None:
        for command in self.queue.take():
            kind = command[0]
            try:
                if kind == "target":
                    _, name, position, orientation = command
                    self.sim.set_grasp_target(name, position, orientation)
                    self._record_input("grasp_target", grasp=name, position=position.tolist(),
                                       orientation=orientation.tolist())
                elif kind == "obstacle_target":
                    _, name, position, orientation = command
                    self.sim.set_obstacle_target(name, position, orientation)
                    self._record_input("obstacle_target", obstacle=name,
                                       position=position.tolist(),
                                       orientation=orientation.tolist())
                elif kind == "close":
                    _, name, close = command
                    (self.sim.close_grasp if close else self.sim.open_grasp)(name)
                    self._record_input("grasp_close" if close else "grasp_open", grasp=name)
                elif kind == "parameters":
                    self.sim.update_parameters(command[1])
                    self._record_input("parameters", changes=command[1])
                elif kind == "reset":
                    self._build_sim()
                    self._param_scene = self.sim.scene
                    self._record_input("reset", scene=scene_to_dict(self.sim.scene))
                    self._session_wall_start = time.monotonic()
                    self._reset_pacing()
                    self._next_publish = time.monotonic()
                elif kind == "step":
                    self._step_once()
                    self._next_publish = time.monotonic()
                elif kind == "pause":
                    if self.paused != command[1]:
                        self._record_input("pause" if command[1] else "resume")
                    self.paused = command[1]
                    if not self.paused:
                        self._reset_pacing()
                elif kind == "frames":
                    self.frames.colour_by, self.frames.wireframe = command[1], command[2]
                elif kind == "realtime":
                    self._reset_pacing()
                    self._make_timer()
            except (KeyError, ValueError, SceneError) as exc:
                self.rejected["invalid"] += 1
                self.get_logger().warning(f"input {kind} refused: {exc}",
                                          throttle_duration_sec=2.0)

    def _step_once(self) -> bool:
        try:
            self.sim.step()
        except SimulationError as exc:
            self._stop_simulation(str(exc))
            return False
        except Exception as exc:            # a defect, not an input: still never fatal
            self.internal_errors += 1
            self._stop_simulation(f"{type(exc).__name__}: {exc}")
            return False
        self._sim_time = self.sim.time
        if self.clock_pub is not None:
            self.clock_pub.publish(ClockMsg(clock=_time_msg(self.sim.time)))
        return True

    def _stop_simulation(self, reason: str) -> None:
        self.error = reason
        self.get_logger().error(f"simulation stopped: {reason}; call cloth/reset")

    # -- clocks ------------------------------------------------------------------
    def _uses_ros_clock(self) -> bool:
        """Pace to the ROS clock: use_sim_time with /clock from another node."""
        return bool(self.get_parameter("use_sim_time").value) and not self.publish_clock

    def _pace_now(self) -> float | None:
        """Seconds on the pacing clock, or None while /clock has not started."""
        if self._uses_ros_clock():
            ns = self.get_clock().now().nanoseconds
            return ns * 1e-9 if ns > 0 else None
        return time.monotonic()

    def _reset_pacing(self) -> None:
        self._pace_start = self._pace_now()     # None until /clock starts
        self._sim_start = self.sim.time
        self._progress = collections.deque()

    def _arrival_s(self, info: dict | None) -> float:
        """When a message arrived, on the clock outputs are stamped with (s).

        A step holds the interpreter (compiled code) for as long as it takes, so a
        pose may wait in the middleware's queue for seconds on a node behind real
        time; judged against the time its callback runs, a well-formed pose would be
        ``stale``.  On the system clock the middleware's reception time is used; on
        simulated time (``publish_clock``, ``use_sim_time``) the wait is not known
        in that clock's seconds, and the callback's time stands."""
        now = self._now_s()
        received = (info or {}).get("received_timestamp") or 0
        if received > 0 and not self.publish_clock and not self._uses_ros_clock():
            waited = (time.time_ns() - received) * 1e-9
            if 0.0 < waited < 3600.0:       # a clock step: the callback's time
                now -= waited
        return now

    def _now_s(self) -> float:
        """The clock outputs are stamped with (s): simulated time with publish_clock."""
        if self.publish_clock:
            return self._sim_time
        return self.get_clock().now().nanoseconds * 1e-9

    def _stamp(self) -> tuple[int, int]:
        if self.publish_clock:
            t = _time_msg(self.sim.time)
            return t.sec, t.nanosec
        return self.get_clock().now().seconds_nanoseconds()

    # -- recording -----------------------------------------------------------------
    def _record_input(self, kind: str, **payload) -> None:
        self.recording.input(self.sim, kind, self._now_ns(), **payload)

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _start_recording(self, path: str) -> tuple[bool, str]:
        params = {n: parameters.scene_value(self.get_parameter(n).value)    # JSON: no arrays
                  for n in self.list_parameters([], 0).names}
        return self.recording.start(path, self.sim, params,
                                    self.get_parameter("grid_resolution").value, self._now_ns())

    def destroy_node(self):
        self.recording.stop()
        if getattr(self, "live", None) is not None:
            self.live.close()
        return super().destroy_node()

    # -- outputs -------------------------------------------------------------------
    def _rates(self, now: float) -> tuple[float | None, float | None]:
        """Real-time factor and publish rate over the last RATE_WINDOW seconds."""
        self._progress.append((now, self.sim.time))
        self._publishes.append(now)
        while self._progress and now - self._progress[0][0] > RATE_WINDOW:
            self._progress.popleft()
        while self._publishes and now - self._publishes[0] > RATE_WINDOW:
            self._publishes.popleft()
        rtf = None
        if len(self._progress) > 1 and now - self._progress[0][0] > 0.5 * RATE_WINDOW:
            rtf = (self.sim.time - self._progress[0][1]) / (now - self._progress[0][0])
        rate = None
        if len(self._publishes) > 1:
            rate = (len(self._publishes) - 1) / (self._publishes[-1] - self._publishes[0])
        return rtf, rate

    def _health(self, rtf):
        measured = (rtf if self.get_parameter("realtime").value and not self._uses_ros_clock()
                    else None)
        return health(error=self.error, stats=self.sim.stats[-1] if self.sim.stats else None,
                      strain_warn=self.get_parameter("strain_warn").value,
                      speed_warn=self.get_parameter("speed_warn").value,
                      real_time_factor=measured,
                      waiting_for_clock=self._waiting_for_clock,
                      recording_failed=self.recording.failed is not None,
                      paused=self.paused)

    def _publish(self) -> None:
        now = time.monotonic()
        sim = self.sim
        rtf, rate = self._rates(now)
        if self.paused or self.error is not None:
            self._progress.clear()
        wall = (self._pace_now() or 0.0) - (self._pace_start or 0.0)
        recording = self.recording.status()
        level, message = self._health(rtf)
        self._last_level = level
        self._auto_reset(level, message, now)
        values = {"paused": str(self.paused).lower(),
                  "wall_time_s": f"{now - self._session_wall_start:.6f}",
                  "real_time_factor": f"{(sim.time - self._sim_start) / max(wall, 1e-9):.3f}",
                  "recent_real_time_factor": "" if rtf is None else f"{rtf:.3f}",
                  "publish_rate_hz": "" if rate is None else f"{rate:.2f}",
                  "poses_received": str(self.poses_received),
                  "rejected_poses": str(self._rejected_poses()),
                  "internal_errors": str(self.internal_errors),
                  "auto_resets": str(self.auto_resets),
                  "recording": recording}
        values.update({f"rejected_{k}": str(v) for k, v in self.rejected.items()})
        stamp = self._stamp()
        frames = self.frames.build(sim, stamp, values, bytes([level]), message)
        self.markers_pub.publish(frames["cloth/markers"])
        self.points_pub.publish(frames["cloth/points"])
        self.grid_pub.publish(frames["cloth/grid"])
        self.stats_pub.publish(frames["cloth/lod_stats"])
        self._last_values, self._last_message = values, message
        self.recording.frame(frames, self._now_ns())
        if self.live is not None:
            try:            # a viewer's trouble never stops the node
                self.live.publish(sim, stamp[0] * 1_000_000_000 + stamp[1], values)
            except Exception as exc:
                self.get_logger().error(f"live view: {exc!r}", throttle_duration_sec=5.0)

    def _auto_reset(self, level: int, message: str, now: float) -> None:
        """With ``auto_reset`` > 0: queue a reset once the health has been ERROR (a
        stopped simulation, unphysical motion) for that many seconds."""
        if level < ERROR:
            self._error_since = None
            return
        if self._error_since is None:
            self._error_since = now
        after = float(self.get_parameter("auto_reset").value)
        if after > 0 and now - self._error_since >= after:
            if self.queue.put_command("reset"):
                self.auto_resets += 1
                self._error_since = None
                self.get_logger().warning(f"auto_reset: {message}; ERROR for {after:g} s, "
                                          "resetting the scene")

    def _publish_diagnostics(self) -> None:
        """``/diagnostics``: one status with numbers a tool can plot."""
        sim, last = self.sim, (self.sim.stats[-1] if self.sim.stats else None)
        values = {"sim_time_s": sim.time, "step_count": sim.step_count,
                  "particles": sim.mesh.vertex_count, "triangles": sim.mesh.triangle_count,
                  "poses_received": self.poses_received,
                  "rejected_poses": self._rejected_poses(),
                  "rejected_requests": self.rejected["requests"],
                  "rejected_parameters": self.rejected["parameters"],
                  "internal_errors": self.internal_errors}
        for key in ("recent_real_time_factor", "publish_rate_hz"):
            if self._last_values.get(key):
                values[key] = float(self._last_values[key])
        if last is not None:
            for key in ("step_ms", "lod_ms", "solve_ms", "cg_iterations", "max_strain",
                        "max_speed", "kinetic_energy", "contact_count"):
                values[key] = getattr(last, key)
        self.diagnostics_pub.publish(standard_diagnostics(
            f"{self.get_name()}: simulation", sim.scene.name, self._last_level, self._last_message,
            values, self._stamp()))


def _time_msg(seconds: float):
    """builtin_interfaces/Time of a non-negative time in s."""
    msg = ClockMsg().clock
    ns = int(round(seconds * 1e9))
    msg.sec, msg.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
    return msg


def main(args=None, started: float | None = None) -> None:
    """Run the node (``cloth_lod_node`` runs :func:`~cloth_lod_ros.ros.startup.node_main`,
    which prints the kernels' line first); Ctrl-C and SIGTERM end it with code 0, a bad
    ``scene`` with one line on stderr and code 2.  ``started``: ``time.monotonic()`` at
    the process's start."""
    started = time.monotonic() if started is None else started
    # Input threads must get the interpreter within a fraction of a millisecond
    # while the stepping thread computes (the default 5 ms switch interval let a
    # 100 Hz pose stream fall seconds behind on a busy step).
    sys.setswitchinterval(SWITCH_INTERVAL)
    rclpy.init(args=args)
    node = None
    try:
        try:
            node = ClothLodNode(started=started)
        except SceneError as exc:       # a bad `scene`: one line, as the CLI says it
            print(f"cloth_lod_node: scene error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        except LiveViewError as exc:    # foxglove_port set: no foxglove-sdk, or the port is taken
            print(f"cloth_lod_node: live view: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        # Threads: stepping and publishing; poses; service calls; parameters.
        executor = MultiThreadedExecutor(num_threads=4)
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
