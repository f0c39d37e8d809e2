"""cloth_lod_node with obstacles driven live by another process.

As in test_node.py: the node in its own process, a second process publishing
``obstacle/<name>/pose``, this process observing; its own ROS_DOMAIN_ID and
localhost-only discovery (importing test_node sets them).
"""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from test_node import (Running, env, no_node_outlives_its_test,  # noqa: F401  (sets the ROS environment)
                       observer)

from std_srvs.srv import SetBool  # noqa: E402

from cloth_lod_ros.bag.replay import replay  # noqa: E402
from cloth_lod_ros.bag.rosbag import BagReader  # noqa: E402

SCENE = textwrap.dedent("""
    name: node_obstacles
    cloth: {width: 0.5, height: 0.5, base_blocks: [2, 2], level: 4, origin: [-0.25, -0.25, 0.004]}
    obstacles:
      - {type: plane, name: table, friction: 0.4}
      - {type: box, name: pusher, centre: [-0.4, 0.0, 0.03], half_extents: [0.05, 0.3, 0.08],
         friction: 0.3, max_speed: 1.0}
    contact: {friction_rounds: 40}
    simulation: {time_step: 0.02, duration: 100.0}
    lod: {enabled: true, initial_level: 2}
""")


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "node_obstacles.yaml"
    path.write_text(SCENE)
    return path


def publisher(script: str) -> subprocess.Popen:
    """A separate process that publishes obstacle poses with rclpy."""
    code = textwrap.dedent("""
        import math, time
        import rclpy
        from geometry_msgs.msg import PoseStamped
        rclpy.init()
        node = rclpy.create_node("obstacle_driver")
        pub = node.create_publisher(PoseStamped, "obstacle/pusher/pose", 10)
        end = time.monotonic() + 10.0                       # discovery
        while pub.get_subscription_count() == 0 and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        def send(x, y, z, q=(0.0, 0.0, 0.0, 1.0), frame="world", stamp=True):
            msg = PoseStamped()
            msg.header.frame_id = frame
            if stamp:
                msg.header.stamp = node.get_clock().now().to_msg()
            else:
                msg.header.stamp.sec = 1                    # 1970: stale
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, z
            (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
             msg.pose.orientation.w) = q
            pub.publish(msg)
    """) + textwrap.dedent(script) + "\nnode.destroy_node()\nrclpy.shutdown()\n"
    return subprocess.Popen([sys.executable, "-c", code], env=env())


def _pusher_marker(node):
    markers = [m for m in node.markers[-1].markers if m.ns == "pusher"]
    assert len(markers) == 1
    p, q = markers[0].pose.position, markers[0].pose.orientation
    return np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w])


def test_an_obstacle_follows_poses_published_by_another_process(observer, scene_file):
    node = Running(observer, scene_file)
    try:
        start, _ = _pusher_marker(node)
        np.testing.assert_allclose(start, [-0.4, 0.0, 0.03])
        # Sweep the box across the cloth at 0.5 m/s, turning it 20 degrees.
        proc = publisher("""
            for k in range(60):
                x = -0.4 + 0.5 * 0.02 * k
                a = math.radians(20) * k / 59
                send(x, 0.0, 0.03, (0.0, 0.0, math.sin(a / 2), math.cos(a / 2)))
                time.sleep(0.02)
        """)
        target = np.array([-0.4 + 0.5 * 0.02 * 59, 0.0, 0.03])
        reached = node.spin_until(
            lambda: np.linalg.norm(_pusher_marker(node)[0] - target) < 1e-6, 30.0)
        proc.wait(timeout=30)
        assert reached, _pusher_marker(node)
        _, q = _pusher_marker(node)
        assert 2 * np.degrees(np.arctan2(q[2], q[3])) == pytest.approx(20.0, abs=1e-6)
        # It pushed the cloth (whose left edge started at x = -0.25) ahead of it.
        assert node.spin_until(lambda: node.grid_point(0, 5)[0] > 0.25 - 0.05 + 0.004, 10.0), \
            node.grid_point(0, 5)
        assert node.stat("rejected_poses") == "0"
        assert int(node.stat("poses_received")) >= 50
    finally:
        assert node.stop() == 0


def test_malformed_obstacle_poses_are_rejected_counted_and_the_node_runs_on(
        observer, scene_file):
    node = Running(observer, scene_file)
    try:
        proc = publisher("""
            for _ in range(3):
                send(0.0, 0.0, 0.03, frame="elsewhere")      # frame
                send(float("nan"), 0.0, 0.03)                # not_finite
                send(0.0, 0.0, 0.03, q=(0.0, 0.0, 0.0, 0.0))  # orientation
                send(0.0, 0.0, 0.03, stamp=False)            # stale
                send(50.0, 0.0, 0.03)                        # workspace
                time.sleep(0.05)
            time.sleep(0.5)
        """)
        proc.wait(timeout=30)

        def counted():
            return all(node.stat(f"rejected_{r}") == "3" for r in
                       ("frame", "not_finite", "orientation", "stale", "workspace"))
        assert node.spin_until(counted, 10.0), {k.key: k.value for k in
                                                node.stats[-1].status[0].values}
        assert node.stat("rejected_poses") == "15"
        # Nothing moved the box, and the simulation runs on.
        np.testing.assert_allclose(_pusher_marker(node)[0], [-0.4, 0.0, 0.03])
        before = float(node.stat("sim_time_s"))
        assert node.spin_until(lambda: float(node.stat("sim_time_s")) > before + 0.2, 10.0)
        assert node.stats[-1].status[0].level == b"\x00"
    finally:
        assert node.stop() == 0


def test_a_session_with_obstacle_poses_replays_bit_for_bit(observer, scene_file, tmp_path):
    bag = tmp_path / "obstacle_session"
    node = Running(observer, scene_file, f"record_path:={bag}", "record:=true",
                   "realtime:=false")
    try:
        proc = publisher("""
            for k in range(40):
                send(-0.4 + 0.01 * k, 0.002 * k, 0.03)
                time.sleep(0.02)
        """)
        proc.wait(timeout=30)
        node.spin_for(0.5)
        assert node.call(SetBool, "cloth/record", SetBool.Request(data=False)).success
    finally:
        assert node.stop() == 0
    with BagReader(bag) as reader:
        events = [json.loads(_string(m.data)) for m in reader.messages(["/cloth/inputs"])]
        poses = list(reader.messages(["/obstacle/pusher/pose"]))
    targets = [e for e in events if e["kind"] == "obstacle_target"]
    assert targets and all(e["obstacle"] == "pusher" for e in targets)
    assert len(poses) >= len(targets)          # received poses are recorded as they came
    result = replay(bag)
    assert result["inputs_applied"] > 0 and result["frame_count"] > 10
    assert result["identical"], {k: v for k, v in result.items() if k != "frames"}


def _string(data):
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import String
    return deserialize_message(data, String).data
