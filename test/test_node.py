"""cloth_lod_node driven by other processes (real rclpy, real processes).

The node runs in its own process; a second process publishes grasp poses; this
test process observes the published topics and calls services and parameters.
Every run uses its own ROS_DOMAIN_ID and localhost-only discovery.  These tests
need rclpy (installed by the test extras) and must run, not skip, in CI.
"""

import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

DOMAIN = str(random.Random(os.getpid() ^ int(time.time())).randint(20, 220))
os.environ["ROS_DOMAIN_ID"] = DOMAIN
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

import rclpy  # noqa: E402  (after the environment is set)
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParametersAtomically  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from std_srvs.srv import SetBool, Trigger  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
GRID = 11

SCENE = textwrap.dedent("""
    name: node_test
    cloth: {width: 1.0, height: 1.0, base_blocks: [4, 4], level: 5, origin: [0, 0, 1]}
    material: {air_drag: 1.0}
    grasps:
      - {name: hand, uv: [0.5, 1.0], close_time: 0.0, max_speed: 2.0}
      - {name: other, uv: [0.0, 1.0], close_time: 0.0}
    simulation: {time_step: 0.02, duration: 100.0}
    lod: {enabled: true, initial_level: 2}
""")


def env():
    e = dict(os.environ)
    e["PYTHONPATH"] = os.pathsep.join([str(REPO), e.get("PYTHONPATH", "")])
    return e


@pytest.fixture(scope="module")
def observer():
    rclpy.init()
    node = Node("test_observer")
    yield node
    node.destroy_node()
    rclpy.shutdown()


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "node_test.yaml"
    path.write_text(SCENE)
    return path


@pytest.fixture(autouse=True)
def no_node_outlives_its_test():
    """A test that fails before stopping its node would leave the process
    running (and loading the machine) for the rest of the session."""
    yield
    while Running.started:
        proc = Running.started.pop()
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)


class Running:
    """A cloth_lod_node process and the latest messages it published."""

    started: list = []      # every process started, for no_node_outlives_its_test

    def __init__(self, observer, scene, *params):
        args = [sys.executable, "-m", "cloth_lod_ros.ros.node", "--ros-args",
                "-p", f"scene:={scene}", "-p", f"grid_resolution:={GRID}",
                "-p", "publish_rate:=25.0"]
        for p in params:
            args += ["-p", p]
        self.proc = subprocess.Popen(args, env=env(), stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
        Running.started.append(self.proc)
        self.observer = observer
        self.grid, self.stats, self.markers = [], [], []
        self.subs = [
            observer.create_subscription(PointCloud2, "cloth/grid", self.grid.append, 10),
            observer.create_subscription(DiagnosticArray, "cloth/lod_stats", self.stats.append, 10),
            observer.create_subscription(MarkerArray, "cloth/markers", self.markers.append, 10)]
        self.spin_until(lambda: self.grid and self.stats and self.markers, 20.0)

    def spin_until(self, condition, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            rclpy.spin_once(self.observer, timeout_sec=0.05)
            if condition():
                return True
            assert self.proc.poll() is None, self.proc.stdout.read()
        return False

    def spin_for(self, seconds):
        self.spin_until(lambda: False, seconds)

    def grid_point(self, u_index, v_index):
        msg = self.grid[-1]
        pts = np.frombuffer(bytes(msg.data), dtype="<f4").reshape(msg.height, msg.width, 3)
        return pts[v_index, u_index].astype(float)

    def grid_time(self) -> float:
        """The stamp of the latest grid message (s): simulated time when the node
        runs with ``publish_clock``."""
        stamp = self.grid[-1].header.stamp
        return stamp.sec + 1e-9 * stamp.nanosec

    def stat(self, key):
        values = {kv.key: kv.value for kv in self.stats[-1].status[0].values}
        return values[key]

    def call(self, srv_type, name, request, timeout=10.0):
        client = self.observer.create_client(srv_type, name)
        assert client.wait_for_service(timeout_sec=timeout), name
        future = client.call_async(request)
        self.spin_until(future.done, timeout)
        self.observer.destroy_client(client)
        return future.result()

    def stop(self, sig=signal.SIGINT):
        for sub in self.subs:
            self.observer.destroy_subscription(sub)
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                return self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                raise
        return self.proc.returncode


@pytest.fixture
def running(observer, scene_file):
    nodes = []

    def start(*params):
        nodes.append(Running(observer, scene_file, *params))
        return nodes[-1]
    yield start
    for n in nodes:
        n.stop()


def driver(script: str) -> subprocess.Popen:
    """A separate process publishing with rclpy (the 'other node')."""
    code = textwrap.dedent("""
        import math, sys, time
        import rclpy
        from geometry_msgs.msg import PoseStamped
        rclpy.init()
        node = rclpy.create_node("test_driver")
        pubs = {}
        def send(name, x, y, z, frame="world", stamp_now=True, qw=1.0):
            if name not in pubs:
                pubs[name] = node.create_publisher(PoseStamped, f"grasp/{name}/pose", 10)
                end = time.monotonic() + (10.0 if name != "nobody" else 0.0)   # discovery
                while pubs[name].get_subscription_count() == 0 and time.monotonic() < end:
                    rclpy.spin_once(node, timeout_sec=0.05)
            msg = PoseStamped()
            msg.header.frame_id = frame
            if stamp_now:
                msg.header.stamp = node.get_clock().now().to_msg()
            else:
                msg.header.stamp.sec = 1
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, z
            msg.pose.orientation.w = qw
            pubs[name].publish(msg)
    """) + textwrap.dedent(script) + "\nnode.destroy_node()\nrclpy.shutdown()\n"
    return subprocess.Popen([sys.executable, "-c", code], env=env())


def test_a_grasp_follows_poses_published_by_another_process(running):
    node = running()
    top_middle = (GRID // 2, GRID - 1)               # (u, v) = (0.5, 1.0): the grasp point
    start = node.grid_point(*top_middle)
    target = start + np.array([0.0, 0.3, 0.4])
    proc = driver(f"""
        for _ in range(150):
            send("hand", {target[0]}, {target[1]}, {target[2]})
            time.sleep(0.02)
    """)
    reached = node.spin_until(
        lambda: np.linalg.norm(node.grid_point(*top_middle) - target) < 0.01, 20.0)
    proc.wait(timeout=20)
    assert reached, (node.grid_point(*top_middle), target)
    # The other grasp held still meanwhile.
    np.testing.assert_allclose(node.grid_point(0, GRID - 1), [0.0, 1.0, 1.0], atol=1e-3)
    assert node.stat("rejected_poses") == "0"


def test_opening_and_closing_a_grasp(running):
    # With publish_clock every output is stamped with simulated time, so the grid
    # read below is known to come from a frame after the close (the statistics
    # topic can run ahead of the grid topic on a loaded machine).
    node = running("publish_clock:=true")
    corner = (0, GRID - 1)
    assert node.call(SetBool, "grasp/other/close", SetBool.Request(data=False)).success
    # Released: the corner swings down (waiting on simulated, not wall, time).
    assert node.spin_until(lambda: node.grid_point(*corner)[2] < 0.9, 20.0)
    assert node.call(SetBool, "grasp/other/close", SetBool.Request(data=True)).success
    # The close is applied at the node's next tick: read the corner from a frame
    # simulated well after it (a fixed wall-time wait is too short under load).
    # The statistics can lag the simulation under load, so "after the close"
    # is also told by the corner itself: it has stopped (within 0.5 mm over
    # 0.1 s of simulated time, where the swinging corner moves centimetres).
    closed = float(node.stat("sim_time_s"))
    last = []

    def stopped():
        now, point = node.grid_time(), node.grid_point(*corner)
        if now <= closed + 0.2:
            return False
        if last and now > last[0][0] + 0.1:
            still = np.linalg.norm(point - last[0][1]) < 5e-4
            last[0] = (now, point)
            return still
        if not last:
            last.append((now, point))
        return False

    assert node.spin_until(stopped, 20.0)
    held = node.grid_point(*corner)
    time_held = node.grid_time()
    assert node.spin_until(lambda: node.grid_time() > time_held + 0.5, 20.0)
    np.testing.assert_allclose(node.grid_point(*corner), held, atol=2e-3)   # held again


def _parameter_value(v) -> ParameterValue:
    if isinstance(v, bool):
        return ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=v)
    if isinstance(v, str):
        return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=v)
    return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(v))


def set_params(node, **values):
    """Set parameters atomically (bool, str or a number as a double); the result."""
    request = SetParametersAtomically.Request(parameters=[
        Parameter(name=k, value=_parameter_value(v)) for k, v in values.items()])
    return node.call(SetParametersAtomically, "cloth_lod_node/set_parameters_atomically",
                     request).result


def test_parameters_from_another_process_change_the_lod(running):
    node = running()
    node.spin_for(1.0)
    before = int(node.stat("triangles"))
    assert before > 200                              # the hanging cloth is refined
    # Coarsen wherever possible: thresholds far above any curvature, motion or
    # energy a merge adds.
    result = set_params(node, **{"lod.refine_threshold": 0.5, "lod.coarsen_threshold": 0.4,
                                 "lod.max_hinge_rate": 1000.0, "lod.max_bend_force": 1000.0,
                                 "lod.max_merge_speed": 100.0, "lod.min_lifetime": 0.0})
    assert result.successful, result.reason
    assert node.spin_until(lambda: int(node.stat("triangles")) < 0.5 * before, 15.0), \
        (before, node.stat("triangles"))


def test_invalid_parameters_are_refused_with_a_reason(running):
    node = running()
    result = set_params(node, **{"lod.coarsen_threshold": 0.5})      # above refine_threshold
    assert not result.successful and "lod.coarsen_threshold" in result.reason
    result = set_params(node, **{"material.bend_stiffness": -1.0})   # outside its range
    assert not result.successful
    node.spin_for(0.5)
    assert node.proc.poll() is None


def test_every_refused_parameter_set_is_counted(running):
    """rclpy refuses some sets before the node's callback sees them (read-only,
    wrong type, outside the declared range, undeclared name, unsetting a declared
    parameter), the node others (an invalid scene); rejected_parameters counts
    every refusal, through either parameter service, and no accepted set."""
    from rcl_interfaces.srv import SetParameters
    node = running()
    unset = Parameter(name="publish_rate",
                      value=ParameterValue(type=ParameterType.PARAMETER_NOT_SET))
    refused = [
        {"scene": "grasp_lift"},                        # read-only (rclpy)
        {"publish_rate": "fast"},                       # a string for a double (rclpy)
        {"material.bend_stiffness": -1.0},              # outside its declared range (rclpy)
        {"no_such_parameter": 1.0},                     # not declared (rclpy raises)
        {"lod.coarsen_threshold": 0.5},                 # above refine_threshold (the node)
        # rclpy lets a value within 1e-6 (relative) of a range's end pass; the node
        # enforces the declared maximum exactly (issue 34).
        {"material.stretch_stiffness": 1e7 + 1},
    ]
    for values in refused:
        result = set_params(node, **values)
        assert not result.successful and result.reason, values
    result = node.call(SetParametersAtomically, "cloth_lod_node/set_parameters_atomically",
                       SetParametersAtomically.Request(parameters=[unset])).result
    assert not result.successful                        # a static parameter stays declared
    # set_parameters: each parameter on its own, one refused of two.
    results = node.call(SetParameters, "cloth_lod_node/set_parameters", SetParameters.Request(
        parameters=[Parameter(name="grid_resolution", value=ParameterValue(
                        type=ParameterType.PARAMETER_INTEGER, integer_value=5)),  # read-only
                    Parameter(name="publish_rate", value=_parameter_value(20.0))])).results
    assert [r.successful for r in results] == [False, True]
    assert set_params(node, **{"strain_warn": 0.5}).successful
    count = len(refused) + 2
    assert node.spin_until(lambda: int(node.stat("rejected_parameters")) == count, 10.0), \
        node.stat("rejected_parameters")
    node.spin_for(0.3)
    assert int(node.stat("rejected_parameters")) == count


def test_wind_set_from_another_process_blows_the_cloth(running):
    """air.wind is live (a double array): the hanging cloth, swinging about
    y = 1 m, is blown back to y ~ 0 within half a second by -8 m/s along y."""
    node = running()
    node.spin_until(lambda: node.stats and float(node.stat("sim_time_s")) > 1.0, 20.0)
    assert node.grid_point(GRID // 2, 0)[1] > 0.6             # the free edge's middle
    wind = [Parameter(name="air.wind", value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[0.0, -8.0, 0.0]))]
    result = node.call(SetParametersAtomically, "cloth_lod_node/set_parameters_atomically",
                       SetParametersAtomically.Request(parameters=wind)).result
    assert result.successful, result.reason
    assert node.spin_until(lambda: node.grid_point(GRID // 2, 0)[1] < 0.3, 20.0)
    short = [Parameter(name="air.wind", value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[1.0, 2.0]))]
    result = node.call(SetParametersAtomically, "cloth_lod_node/set_parameters_atomically",
                       SetParametersAtomically.Request(parameters=short)).result
    assert not result.successful and "air.wind" in result.reason


def test_a_flood_of_bad_poses_is_rejected_and_the_node_keeps_running(running):
    node = running()
    proc = driver("""
        nan = float("nan")
        for _ in range(100):
            send("hand", nan, 0.0, 1.0)                   # not finite
            send("hand", 0.0, math.inf, 1.0)
            send("hand", 0.5, 1.0, 1.2, frame="map")      # wrong frame
            send("hand", 0.5, 1.0, 1.2, stamp_now=False)  # stale stamp
            send("hand", 0.5, 1.0, 1.2, qw=0.0)           # no orientation
            send("nobody", 0.5, 1.0, 1.2)                 # unknown grasp: nobody listens
            time.sleep(0.005)
    """)
    proc.wait(timeout=30)
    count = len(node.grid)
    # (A busy node's keep-last-10 queue drops part of a flood: count kinds, not all.)
    assert node.spin_until(lambda: all(int(node.stat(f"rejected_{k}")) > 0
                                       for k in ("not_finite", "frame", "stale")), 10.0)
    node.spin_until(lambda: len(node.grid) > count + 10, 10.0)
    assert len(node.grid) > count + 10                   # still publishing
    assert int(node.stat("rejected_poses")) >= 3
    assert np.all(np.isfinite(node.grid_point(GRID // 2, GRID - 1)))


def test_markers_seen_by_another_process_describe_a_valid_mesh(running):
    node = running()
    node.spin_for(1.0)

    def pair():
        """The newest markers whose statistics (published right after them with
        the same stamp) were received too: the observer's keep-last-10 queues
        may drop a message while it deserialises large marker arrays."""
        stats = {(s.header.stamp.sec, s.header.stamp.nanosec): s for s in node.stats}
        for msg in reversed(node.markers):
            surface = next(m for m in msg.markers if m.ns == "surface")
            key = (surface.header.stamp.sec, surface.header.stamp.nanosec)
            if key in stats:
                return msg, surface, stats[key]
        return None
    assert node.spin_until(lambda: pair() is not None, 5.0), "no lod_stats with a markers' stamp"
    msg, surface, same = pair()
    assert len(surface.points) % 3 == 0 and len(surface.points) > 0
    pts = np.array([[p.x, p.y, p.z] for p in surface.points])
    assert np.all(np.isfinite(pts))
    # The statistics published with these markers (same stamp) count the same mesh.
    triangles = {kv.key: kv.value for kv in same.status[0].values}["triangles"]
    assert len(surface.points) == 3 * int(triangles)
    assert all(m.header.frame_id == "world" for m in msg.markers)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signals_end_the_node_cleanly(running, sig):
    """A signal ends the node with exit 0 without waiting for a step or a
    writer to drain.  The bound is a hang detector, not a speed figure (no
    timing assertions: a loaded CI machine took 1.4 s where a quiet one takes
    well under a second)."""
    node = running()
    node.proc.send_signal(sig)
    assert node.proc.wait(timeout=15) == 0


# -- robustness: inputs judged, never fatal, never waiting (issue: the node under real use) --
def pose_script(body: str) -> subprocess.Popen:
    """A driver process with a raw publisher per grasp (``pub(name)``) and ``pose()``."""
    return driver(textwrap.dedent("""
        def pub(name):
            send(name, 0.5, 1.0, 1.0, stamp_now=True)      # creates and discovers it
            return pubs[name]
        def pose(x, y, z, qx=0.0, qy=0.0, qz=0.0, qw=1.0, sec=None, nanosec=0):
            msg = PoseStamped()
            msg.header.frame_id = "world"
            if sec is None:
                msg.header.stamp = node.get_clock().now().to_msg()
            else:
                msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, z
            q = msg.pose.orientation
            q.x, q.y, q.z, q.w = qx, qy, qz, qw
            return msg
    """) + textwrap.dedent(body))


def light_scene(tmp_path):
    """The test scene at level 3 with the paper's one solve per step: it keeps
    real time with room to spare on a loaded machine (the second-order default
    left only 1.2x), so rates and clocks are the node's, not the machine's."""
    scene = tmp_path / "light.yaml"
    scene.write_text(SCENE.replace("level: 5", "level: 3").replace(
        "simulation: {time_step: 0.02, duration: 100.0}",
        "simulation: {time_step: 0.02, duration: 100.0, integrator: baraff_witkin}"))
    return scene


def level(node):
    return node.stats[-1].status[0].level[0]


def test_hostile_poses_are_judged_and_none_stops_the_node(running):
    node = running()
    proc = pose_script("""
        p = pub("hand")
        now = node.get_clock().now().to_msg().sec
        for _ in range(20):
            p.publish(pose(0.5, 1.0, 1.0, qx=1e200, qy=1e200, qw=0.0))   # norm overflows
            p.publish(pose(0.5, 1.0, 1.0, sec=now + 3600))               # future
            p.publish(pose(0.5, 1.0, 1.0, sec=-5))                       # negative
            p.publish(pose(0.5, 1.0, 1.0, sec=now, nanosec=1_500_000_000))
            p.publish(pose(1e6, 0.0, 0.0))                               # outside the workspace
            time.sleep(0.05)
        # Reliable samples not yet acknowledged are dropped with their writer: let
        # them arrive before the process ends (the burst was lost once under load).
        time.sleep(1.0)
    """)
    proc.wait(timeout=30)
    assert node.spin_until(lambda: all(int(node.stat(f"rejected_{k}")) > 0 for k in
                                       ("future", "bad_stamp", "workspace")), 10.0)
    count = len(node.grid)
    assert node.spin_until(lambda: len(node.grid) > count + 10, 10.0)   # still publishing
    assert node.proc.poll() is None
    assert int(node.stat("internal_errors")) == 0
    assert level(node) < 2                           # WARN at most (a loaded machine is slow)
    assert np.all(np.abs(node.grid_point(GRID // 2, GRID - 1)) < 5.0)  # far target never applied


def test_a_failing_step_stops_the_simulation_not_the_node(observer, tmp_path):
    scene = tmp_path / "heavy.yaml"
    scene.write_text(SCENE.replace("simulation: {time_step: 0.02, duration: 100.0}",
                                   "simulation: {time_step: 0.02, duration: 100.0, "
                                   "gravity: [0, 0, -1.0e12]}"))
    node = Running(observer, scene)
    try:
        # Unphysical motion (ERROR) comes first; then a step fails outright.
        assert node.spin_until(lambda: level(node) == 2 and "simulation stopped"
                               in node.stats[-1].status[0].message, 15.0), \
            node.stats[-1].status[0].message
        response = node.call(Trigger, "cloth/reset", Trigger.Request())
        assert response.success
        count = len(node.stats)
        assert node.spin_until(lambda: len(node.stats) > count + 5, 10.0)
        assert node.proc.poll() is None
    finally:
        assert node.stop() == 0


def test_auto_reset_resets_a_stopped_simulation_by_itself(observer, tmp_path):
    """Issue 34: a simulation driven into ERROR waited for cloth/reset; with
    auto_reset the node says how to recover and resets itself after that long."""
    scene = tmp_path / "heavy.yaml"
    scene.write_text(SCENE.replace("simulation: {time_step: 0.02, duration: 100.0}",
                                   "simulation: {time_step: 0.02, duration: 100.0, "
                                   "gravity: [0, 0, -1.0e12]}"))
    node = Running(observer, scene, "auto_reset:=0.5")
    try:
        assert node.spin_until(lambda: level(node) == 2, 15.0)
        assert "auto_reset" in node.stats[-1].status[0].message
        # The scene fails again after each reset: the node keeps resetting, never stuck.
        assert node.spin_until(lambda: int(node.stat("auto_resets")) >= 2, 60.0), \
            node.stats[-1].status[0].message
        assert node.proc.poll() is None and int(node.stat("internal_errors")) == 0
    finally:
        assert node.stop() == 0


def test_a_burst_of_service_calls_is_answered_every_one(running):
    node = running()
    kinds = [(SetBool, "grasp/other/close", lambda k: SetBool.Request(data=bool(k % 2))),
             (Trigger, "cloth/step", lambda k: Trigger.Request()),
             (SetBool, "cloth/pause", lambda k: SetBool.Request(data=bool(k % 2))),
             (Trigger, "cloth/reset", lambda k: Trigger.Request())]
    clients = []
    # A burst's answers arrive together: the caller needs a response queue as
    # deep as its burst (the default keeps the last 10).
    deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    for srv, name, _ in kinds:
        client = node.observer.create_client(srv, name, qos_profile=deep)
        assert client.wait_for_service(timeout_sec=10.0)
        clients.append(client)
    futures = [clients[k % 4].call_async(kinds[k % 4][2](k)) for k in range(200)]
    node.spin_until(lambda: all(f.done() for f in futures), 30.0)
    for client in clients:
        node.observer.destroy_client(client)
    answered = [f.result() for f in futures if f.done()]
    assert len(answered) == 200
    assert all(r.success or "refused" in r.message for r in answered)
    assert node.proc.poll() is None


def test_run_time_parameters_do_what_they_say(running):
    node = running()
    bad = node.call(SetParametersAtomically, "cloth_lod_node/set_parameters_atomically",
                    SetParametersAtomically.Request(parameters=[Parameter(
                        name="colour_by", value=ParameterValue(
                            type=ParameterType.PARAMETER_STRING, string_value="purple"))])).result
    assert not bad.successful and "colour_by" in bad.reason

    def set_bool(name, value):
        return node.call(SetParametersAtomically, "cloth_lod_node/set_parameters_atomically",
                         SetParametersAtomically.Request(parameters=[Parameter(
                             name=name, value=ParameterValue(
                                 type=ParameterType.PARAMETER_BOOL, bool_value=value))])).result

    assert set_bool("wireframe", False).successful
    assert node.spin_until(lambda: not any(m.ns == "wireframe" for m in node.markers[-1].markers),
                           10.0)
    assert set_bool("paused", True).successful
    assert node.spin_until(lambda: node.stat("paused") == "true", 10.0)
    frozen = node.stat("sim_time_s")
    node.spin_for(0.5)
    assert node.stat("sim_time_s") == frozen
    assert set_bool("paused", False).successful
    assert node.spin_until(lambda: node.stat("sim_time_s") != frozen, 10.0)


def test_publish_rate_follows_the_parameter(observer, tmp_path):
    """Measured on the node's own stamps, so the observer's delays do not count
    (a light scene, so the simulation keeps real time on a loaded machine)."""
    node = Running(observer, light_scene(tmp_path), "publish_rate:=30.0")
    # Only lod_stats: decoding big MarkerArrays in Python would slow the observer.
    for sub in node.subs[:1] + node.subs[2:]:
        node.observer.destroy_subscription(sub)
    node.subs = node.subs[1:2]
    node.spin_for(1.0)
    first = len(node.stats)
    node.spin_for(3.0)
    stamps = [s.header.stamp.sec + 1e-9 * s.header.stamp.nanosec for s in node.stats[first:]]
    rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    assert node.stop() == 0
    assert 28.5 < rate < 31.5, rate                  # within 5 %


def test_simulated_time_on_clock_and_on_every_stamp(running, observer):
    from rosgraph_msgs.msg import Clock
    clocks = []
    sub = observer.create_subscription(Clock, "/clock", clocks.append, 10)
    try:
        node = running("publish_clock:=true")
        assert node.spin_until(lambda: len(clocks) > 5, 10.0)
        stamp = node.stats[-1].header.stamp
        assert abs(stamp.sec + 1e-9 * stamp.nanosec - float(node.stat("sim_time_s"))) < 1e-6
        assert clocks[-1].clock.sec < 1000        # simulated seconds, not the epoch
    finally:
        observer.destroy_subscription(sub)


def test_use_sim_time_without_clock_waits_and_says_so(running):
    node = running("use_sim_time:=true")
    assert node.spin_until(lambda: "/clock" in node.stats[-1].status[0].message, 10.0)
    assert float(node.stat("sim_time_s")) == 0.0
    assert level(node) == 1


def test_switching_use_sim_time_live_is_refused_and_the_node_lives(running):
    """rclpy would tear down its /clock subscription under the executor (the node
    died with InvalidHandle); the clock source is chosen at start."""
    node = running("use_sim_time:=true")
    for value in (False, True, False):
        result = set_params(node, use_sim_time=value)
        assert result.successful == value        # true is the start value: accepted
        if not value:
            assert "read-only while the node runs" in result.reason
    node.spin_for(0.5)
    assert node.proc.poll() is None
    assert "/clock" in node.stats[-1].status[0].message      # still waiting for /clock
    assert int(node.stat("rejected_parameters")) == 2


def test_the_integrator_and_its_tolerance_are_live(running):
    """A user who needs real time more than accuracy switches to the paper's step."""
    node = running()
    assert node.spin_until(lambda: node.stats and node.stat("integrator") == "sdirk2", 10.0)
    result = set_params(node, **{"simulation.integrator": "baraff_witkin",
                                 "simulation.error_tolerance": 0.0})
    assert result.successful, result.reason
    assert node.spin_until(lambda: node.stat("integrator") == "baraff_witkin", 10.0)
    assert float(node.stat("error_tolerance_m")) == 0.0
    bad = set_params(node, **{"simulation.integrator": "rk4"})
    assert not bad.successful and "integrator" in bad.reason


def test_standard_diagnostics_carry_numbers(running, observer):
    seen = []
    sub = observer.create_subscription(DiagnosticArray, "/diagnostics", seen.append, 10)
    try:
        node = running()
        assert node.spin_until(lambda: len(seen) >= 2, 10.0)
        values = {kv.key: kv.value for kv in seen[-1].status[0].values}
        assert seen[-1].status[0].name == "cloth_lod_node: simulation"
        for key in ("sim_time_s", "triangles", "step_ms", "max_strain", "rejected_poses"):
            float(values[key])                       # a number a plotting tool can read
    finally:
        observer.destroy_subscription(sub)


def test_stopping_logs_what_the_recording_holds(observer, scene_file, tmp_path):
    bag = tmp_path / "stop_bag"
    node = Running(observer, scene_file, "record:=true", f"record_path:={bag}")
    node.spin_for(1.0)
    assert node.stop() == 0
    out = node.proc.stdout.read()
    assert "publishing" in out and "cloth/markers" in out        # the start-up line
    assert "recording finished:" in out and str(bag) in out and "messages" in out
    assert "never retrieved" not in out and "Traceback" not in out


def test_poses_at_100_hz_with_recording_are_all_received(observer, tmp_path):
    """1,500 poses at 100 Hz on grasp_lift while recording: every one is taken
    and judged (none waits for a step, so none is dropped or judged late)."""
    node = Running(observer, "grasp_lift", "record:=true", f"record_path:={tmp_path / 'b'}")
    try:
        proc = pose_script("""
            p = pub("left")
            start = time.monotonic()
            for k in range(1500):
                p.publish(pose(-0.4, 0.5 + 0.1 * math.sin(0.01 * k), 0.6))
                time.sleep(max(0.0, start + 0.01 * (k + 1) - time.monotonic()))
        """)
        proc.wait(timeout=60)
        assert node.spin_until(lambda: int(node.stat("poses_received")) >= 1501, 15.0), \
            node.stat("poses_received")
        judged = int(node.stat("poses_received"))
        stale = int(node.stat("rejected_stale")) + int(node.stat("rejected_future"))
        assert judged >= 0.99 * 1501 and stale <= 0.01 * judged
    finally:
        assert node.stop() == 0


def test_poses_are_judged_on_arrival_on_a_node_behind_real_time(observer, tmp_path):
    """Issue 34: a node behind real time judged poses when their callback ran, so
    well-formed poses that waited in the middleware were `stale`.  They are judged
    at their reception time: on a uniform level-8 mesh (a real-time factor near
    0.01 here), 1,000 poses at 100 Hz are all accepted.  (Measured with a timeout of
    0.05 s and 2,000 poses: 1,858 stale before, 5 after - the middleware's own delay
    on a machine at load 13; at 0.25 s and load 17, 1 of 1,000: so the default 1 s.)"""
    scene = tmp_path / "slow.yaml"
    scene.write_text(SCENE.replace("level: 5", "level: 8").replace(
        "lod: {enabled: true, initial_level: 2}", "lod: {enabled: false}"))
    node = Running(observer, scene)
    try:
        proc = pose_script("""
            p = pub("hand")
            start = time.monotonic()
            for k in range(1000):
                p.publish(pose(0.5, 1.0 + 0.05 * math.sin(0.01 * k), 1.0))
                time.sleep(max(0.0, start + 0.01 * (k + 1) - time.monotonic()))
        """)
        proc.wait(timeout=60)
        assert node.spin_until(lambda: int(node.stat("poses_received")) >= 1001, 60.0), \
            node.stat("poses_received")
        assert float(node.stat("real_time_factor")) < 0.9          # behind real time
        assert int(node.stat("rejected_stale")) == 0 and int(node.stat("rejected_future")) == 0
    finally:
        assert node.stop() == 0


def test_fuzzed_poses_parameters_and_service_calls_never_stop_the_node(observer, scene_file):
    """Property-based: random poses (any float, frame, stamp), parameter sets (any
    declared name, any type) and service calls from this process; after every
    batch the node is alive; at the end it still publishes and has counted
    every pose it was sent."""
    from geometry_msgs.msg import PoseStamped
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
    from rcl_interfaces.srv import SetParameters

    node = Running(observer, scene_file)
    deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {g: observer.create_publisher(PoseStamped, f"grasp/{g}/pose", deep)
            for g in ("hand", "other")}
    node.spin_until(lambda: all(p.get_subscription_count() for p in pubs.values()), 10.0)
    clients = {name: observer.create_client(srv, name, qos_profile=deep) for name, srv in (
        ("cloth_lod_node/set_parameters", SetParameters), ("cloth/reset", Trigger),
        ("cloth/step", Trigger), ("cloth/pause", SetBool), ("grasp/hand/close", SetBool))}
    for client in clients.values():
        assert client.wait_for_service(timeout_sec=10.0)
    sent = {"poses": 0, "parameters": 0, "services": 0}
    futures = []
    number = st.floats(allow_nan=True, allow_infinity=True) | st.floats(-2.0, 2.0)
    pose = st.tuples(st.just("pose"), st.sampled_from(sorted(pubs)),
                     st.lists(number, min_size=7, max_size=7),
                     st.sampled_from(["world", "", "map"]),
                     st.none() | st.integers(-2**31, 2**31 - 1), st.integers(0, 2**32 - 1))
    names = ["publish_rate", "realtime", "paused", "stale_pose_timeout", "colour_by",
             "wireframe", "workspace_min", "workspace_max", "strain_warn", "scene",
             "lod.refine_threshold", "lod.coarsen_threshold", "material.bend_stiffness",
             "material.air_drag", "use_sim_time", "no_such_parameter"]
    value = st.one_of(
        st.builds(lambda v: ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=v),
                  number),
        st.builds(lambda v: ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=v),
                  st.booleans()),
        st.builds(lambda v: ParameterValue(type=ParameterType.PARAMETER_STRING,
                                           string_value=v), st.text(max_size=20)),
        st.builds(lambda v: ParameterValue(type=ParameterType.PARAMETER_INTEGER,
                                           integer_value=v), st.integers(-2**63, 2**63 - 1)),
        st.builds(lambda v: ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                                           double_array_value=v),
                  st.lists(number, max_size=4)))
    double = st.builds(lambda v: ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                                 double_value=v),
                       st.floats(-1.0, 100.0) | st.floats(1e-6, 1e-2) | number)
    boolean = st.builds(lambda v: ParameterValue(type=ParameterType.PARAMETER_BOOL,
                                                 bool_value=v), st.booleans())
    typed = {"realtime": boolean, "paused": boolean, "wireframe": boolean,
             "use_sim_time": boolean,
             "colour_by": st.builds(lambda v: ParameterValue(
                 type=ParameterType.PARAMETER_STRING, string_value=v),
                 st.sampled_from(["level", "shading", "Level", ""])),
             "workspace_min": st.builds(lambda v: ParameterValue(
                 type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=v),
                 st.lists(st.floats(-20.0, 0.0), min_size=3, max_size=3)),
             "workspace_max": st.builds(lambda v: ParameterValue(
                 type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=v),
                 st.lists(st.floats(0.0, 20.0), min_size=3, max_size=3))}
    # Half of the values have the parameter's type (mostly plausible), half anything.
    parameter = st.sampled_from(names).flatmap(lambda name: st.tuples(
        st.just("parameter"), st.just(name), typed.get(name, double) | value))
    service = st.tuples(st.just("service"), st.sampled_from(sorted(clients)[1:]),
                        st.booleans())

    @settings(max_examples=80, deadline=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(st.lists(st.one_of(pose, pose, parameter, service), min_size=1, max_size=25))
    def batch(actions):
        for action in actions:
            if action[0] == "pose":
                _, grasp, v, frame, sec, nanosec = action
                msg = PoseStamped()
                msg.header.frame_id = frame
                if sec is None:
                    msg.header.stamp = observer.get_clock().now().to_msg()
                else:
                    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
                p, q = msg.pose.position, msg.pose.orientation
                p.x, p.y, p.z, q.x, q.y, q.z, q.w = v
                pubs[grasp].publish(msg)
                sent["poses"] += 1
            elif action[0] == "parameter":
                request = SetParameters.Request(parameters=[Parameter(name=action[1],
                                                                      value=action[2])])
                futures.append(clients["cloth_lod_node/set_parameters"].call_async(request))
                sent["parameters"] += 1
            else:
                _, name, data = action
                srv = clients[name].srv_type
                request = srv.Request(data=data) if srv is SetBool else srv.Request()
                futures.append(clients[name].call_async(request))
                sent["services"] += 1
        node.spin_for(0.05)
        assert node.proc.poll() is None

    try:
        batch()
        assert node.spin_until(lambda: all(f.done() for f in futures), 30.0), \
            f"{sum(not f.done() for f in futures)} of {len(futures)} calls unanswered"
        # Let the node settle on sane settings, then check it still publishes and
        # counted every pose.
        reset = [Parameter(name=n, value=ParameterValue(type=ParameterType.PARAMETER_BOOL,
                                                        bool_value=b))
                 for n, b in (("paused", False), ("use_sim_time", False), ("realtime", True))]
        node.call(SetParameters, "cloth_lod_node/set_parameters",
                  SetParameters.Request(parameters=reset))
        assert node.spin_until(lambda: int(node.stat("poses_received")) >= sent["poses"], 20.0)
        count = len(node.stats)
        assert node.spin_until(lambda: len(node.stats) > count + 5, 10.0)
        stats = {kv.key: kv.value for kv in node.stats[-1].status[0].values}
        rejected = {k[len("rejected_"):]: int(v) for k, v in stats.items()
                    if k.startswith("rejected_") and k != "rejected_poses"}
        print(f"\nfuzz: sent {sent}; node received {stats['poses_received']} poses, "
              f"rejected {rejected}; internal errors {stats['internal_errors']}; "
              f"{sum(r.successful for f in futures for r in getattr(f.result(), 'results', []))}"
              f" of {sent['parameters']} parameter sets accepted; node alive")
        assert int(stats["poses_received"]) == sent["poses"]
    finally:
        for client in clients.values():
            observer.destroy_client(client)
        for pub in pubs.values():
            observer.destroy_publisher(pub)
        assert node.stop() == 0


def test_the_physics_follows_an_external_clock_at_half_speed(observer, tmp_path):
    """use_sim_time with /clock from another process running at half speed: the
    simulated time advances with /clock, not with the wall clock."""
    clock = subprocess.Popen([sys.executable, "-c", textwrap.dedent("""
        import time
        import rclpy
        from rosgraph_msgs.msg import Clock
        rclpy.init()
        node = rclpy.create_node("test_half_speed_clock")
        pub = node.create_publisher(Clock, "/clock", 10)
        start = time.monotonic()
        while time.monotonic() - start < 25.0:
            msg = Clock()
            ns = int(0.5 * (time.monotonic() - start) * 1e9) + 1_000_000_000
            msg.clock.sec, msg.clock.nanosec = ns // 10**9, ns % 10**9
            pub.publish(msg)
            time.sleep(0.01)
        rclpy.shutdown()
    """)], env=env())
    node = Running(observer, light_scene(tmp_path), "use_sim_time:=true")

    def sim_and_clock(msg):
        """Simulated time and the /clock time the node stamped it with: both
        from the node's own message, so a slow observer cannot skew them."""
        values = {kv.key: kv.value for kv in msg.status[0].values}
        return float(values["sim_time_s"]), msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec

    try:
        assert node.spin_until(lambda: float(node.stat("sim_time_s")) > 0.2, 15.0)
        first = len(node.stats) - 1
        node.spin_for(3.0)
        sim0, clock0 = sim_and_clock(node.stats[first])
        sim1, clock1 = sim_and_clock(node.stats[-1])
        # The simulated time follows /clock, not the wall clock (which runs
        # twice as fast as this clock: a ratio of 2).
        assert clock1 - clock0 > 0.3
        ratio = (sim1 - sim0) / (clock1 - clock0)
        assert 0.7 < ratio < 1.3, ratio
        assert clock1 < 1000                      # stamped with /clock, not the epoch
    finally:
        node.stop()
        clock.kill()
        clock.wait()


def test_realtime_can_be_switched_off_while_running(observer, tmp_path):
    # Behaviour, not speed: paced by a /clock that never comes, the node
    # waits; with real-time pacing switched off it steps as fast as it can,
    # whatever the clock.
    node = Running(observer, light_scene(tmp_path), "publish_rate:=10.0", "use_sim_time:=true")
    assert node.spin_until(lambda: node.stats and "/clock" in node.stats[-1].status[0].message,
                           15.0)
    assert float(node.stat("sim_time_s")) == 0.0
    result = node.call(SetParametersAtomically, "cloth_lod_node/set_parameters_atomically",
                       SetParametersAtomically.Request(parameters=[Parameter(
                           name="realtime", value=ParameterValue(
                               type=ParameterType.PARAMETER_BOOL, bool_value=False))])).result
    assert result.successful
    assert node.spin_until(lambda: float(node.stat("sim_time_s")) > 0.2, 30.0)
    assert "/clock" not in node.stats[-1].status[0].message
    node.stop()
