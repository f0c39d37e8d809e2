"""The Foxglove live view, checked as a viewer sees it.

A client written here from the Foxglove WebSocket protocol specification
(https://github.com/foxglove/ws-protocol/blob/main/docs/spec.md: JSON
``serverInfo``/``advertise`` from the server, ``subscribe`` from the client,
binary ``messageData`` = opcode 0x01, uint32 subscription id, uint64 log time,
payload, little-endian) connects to ``cloth-lod run --foxglove`` and to
``cloth_lod_node`` running in their own processes.  Protobuf payloads are
decoded by ``google.protobuf`` with the schema the server advertises (a
``FileDescriptorSet``), not by our encoder's code.  What the messages must show
comes from outside the code under test: the scene files (where the cloth
starts, where it is pinned, where the scripted box is at a given time), the
4-8 mesh (2 triangles per base block at level 0, doubling with each level),
matplotlib's viridis for the level colours, and the statistics topic sent with
the same log time.
"""

from __future__ import annotations

import base64
import json
import math
import os
import random
import re
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

foxglove = pytest.importorskip("foxglove")      # the viewer extra (part of the test extra)

import matplotlib  # noqa: E402
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402
from websockets.sync.client import connect  # noqa: E402

from cloth_lod_ros.live import protobuf, scene as live_scene  # noqa: E402
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
# The SDK's server speaks the v1 framing under the subprotocol name
# foxglove.sdk.v1; older servers use foxglove.websocket.v1.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01
STARTUP = 600.0             # s: a first start compiles the kernels (minutes on a loaded machine)


# -- a protocol client ---------------------------------------------------------------
def _protobuf_class(schema_b64: str, name: str):
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


class Viewer:
    """A Foxglove WebSocket client: subscribes to topics and keeps their messages
    decoded, as ``(log_time_ns, message)`` per topic."""

    def __init__(self, url: str, timeout: float = 30.0):
        self._connection = connect(url, subprotocols=SUBPROTOCOLS, open_timeout=timeout,
                                   max_size=None)
        self.ws = self._connection.__enter__()       # what ``with connect(...) as ws`` does
        assert self.ws.subprotocol in SUBPROTOCOLS
        self.server_info = None
        self.channels: dict[int, dict] = {}
        self.subscriptions: dict[int, dict] = {}
        self.decoders: dict[int, object] = {}
        self.messages: dict[str, list] = {}
        self.statuses: list = []
        end = time.monotonic() + timeout
        while (self.server_info is None or not self.channels) and time.monotonic() < end:
            self._handle(self.ws.recv(timeout=max(end - time.monotonic(), 0.01)))
        assert self.server_info is not None, "no serverInfo"
        assert self.channels, "no advertise"

    def _handle(self, frame) -> None:
        if isinstance(frame, str):
            msg = json.loads(frame)
            if msg["op"] == "serverInfo":
                self.server_info = msg
            elif msg["op"] == "advertise":
                for ch in msg["channels"]:
                    self.channels[ch["id"]] = ch
            elif msg["op"] == "unadvertise":
                for cid in msg["channelIds"]:
                    self.channels.pop(cid, None)
            elif msg["op"] == "status":
                self.statuses.append(msg)
            return
        opcode = frame[0]
        if opcode != MESSAGE_DATA:
            return
        sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
        payload = bytes(frame[13:])
        channel = self.subscriptions[sub_id]
        self.messages.setdefault(channel["topic"], []).append(
            (log_time, self.decoders[sub_id](payload)))

    def topics(self) -> dict[str, dict]:
        return {ch["topic"]: ch for ch in self.channels.values()}

    def subscribe(self, topics) -> None:
        subs = []
        for topic in topics:
            ch = self.topics()[topic]
            sub_id = len(self.subscriptions) + 1
            self.subscriptions[sub_id] = ch
            if ch["encoding"] == "protobuf":
                assert ch["schemaEncoding"] == "protobuf"
                cls = _protobuf_class(ch["schema"], ch["schemaName"])
                self.decoders[sub_id] = cls.FromString
            else:
                assert ch["encoding"] == "json"
                self.decoders[sub_id] = lambda b: json.loads(b.decode())
            subs.append({"id": sub_id, "channelId": ch["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def pump_until(self, condition, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if condition():
                return True
            try:
                self._handle(self.ws.recv(timeout=0.2))
            except TimeoutError:
                pass
        return condition()

    def frames(self, *topics):
        """``{log_time: {topic: message}}`` of the log times every topic has."""
        by_time: dict[int, dict] = {}
        for topic in topics:
            for t, msg in self.messages.get(topic, []):
                by_time.setdefault(t, {})[topic] = msg
        return {t: m for t, m in sorted(by_time.items()) if len(m) == len(topics)}

    def close(self) -> None:
        self._connection.__exit__(None, None, None)


# -- reading the messages ------------------------------------------------------------
def cloth_of(update):
    """``[(rgba, corners (t, 3, 3))]`` of the ``cloth`` entity, one per primitive."""
    (entity,) = [e for e in update.entities if e.id == "cloth"]
    out = []
    for prim in entity.triangles:
        points = np.array([[p.x, p.y, p.z] for p in prim.points]).reshape(-1, 3)
        indices = np.array(prim.indices, dtype=np.int64)
        assert len(indices) % 3 == 0 and len(prim.colors) == 0
        assert indices.min() >= 0 and indices.max() < len(points)
        c = prim.color
        out.append(((c.r, c.g, c.b, c.a), points[indices].reshape(-1, 3, 3)))
    return entity, out


def level_of(rgb, max_level: int) -> int:
    """The level whose viridis colour (matplotlib's table) ``rgb`` is, within 0.02."""
    palette = matplotlib.colormaps["viridis"](np.arange(max_level + 1) / max(max_level, 1))[:, :3]
    distance = np.linalg.norm(palette - np.asarray(rgb)[None, :3], axis=1)
    level = int(distance.argmin())
    assert distance[level] < 0.02, (rgb, distance)
    return level


def check_mesh_against_stats(update, stats: dict, size: float) -> np.ndarray:
    """The invariants of one cloth message; returns its vertices ``(k, 3)``."""
    entity, prims = cloth_of(update)
    levels = [level_of(rgba[:3], stats["max_level"]) for rgba, _ in prims]
    assert len(set(levels)) == len(levels)                  # one primitive per level
    assert all(rgba[3] == 1.0 for rgba, _ in prims)
    per_level = np.zeros(stats["max_level"] + 1, dtype=int)
    for level, (_, corners) in zip(levels, prims):
        per_level[level] = len(corners)
    assert per_level.tolist() == stats["triangles_per_level"]
    assert per_level.sum() == stats["triangles"]
    corners = np.concatenate([c for _, c in prims])
    assert np.all(np.isfinite(corners))
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    assert edges.max() <= size                              # a triangle lies within the cloth
    assert entity.frame_id == "world"
    return corners.reshape(-1, 3)


def check_stats(stats: dict, schema: dict) -> None:
    """Every field a number (or a list of integers), as the advertised JSON Schema says."""
    props = schema["properties"]
    for key, value in stats.items():
        if isinstance(value, list):
            assert props[key]["type"] == "array" and all(isinstance(v, int) for v in value), key
        else:
            assert isinstance(value, (int, float)) and not isinstance(value, bool), key
            assert math.isfinite(value), key


# -- processes -------------------------------------------------------------------------
def env(**extra):
    e = dict(os.environ)
    e["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), e.get("PYTHONPATH", "")) if p)
    e["MPLBACKEND"] = "Agg"
    e.update(extra)
    return e


class Process:
    """A subprocess whose output lines are collected by a thread."""

    def __init__(self, args, **kw):
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, **kw)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line)

    def output(self) -> str:
        return "".join(self.lines)

    def wait_for(self, pattern: str, timeout: float) -> re.Match:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for line in list(self.lines):
                match = re.search(pattern, line)
                if match:
                    return match
            assert self.proc.poll() is None, self.output()
            time.sleep(0.05)
        raise AssertionError(f"no line matching {pattern!r}:\n{self.output()}")

    def stop(self, sig=signal.SIGINT, timeout: float = 30.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                raise
        self._reader.join(timeout=5)
        return self.proc.returncode


@pytest.fixture
def processes():
    started = []
    yield started.append
    for p in started:
        if p.proc.poll() is None:
            p.proc.kill()
            p.proc.wait()


def cli_run(tmp_path, scene: str, duration: float, *extra) -> Process:
    return Process([sys.executable, "-m", "cloth_lod_ros.tools.cli", "run", scene,
                    "--duration", str(duration), "--no-png", "--quiet",
                    "--out", str(tmp_path / "state.npz"), "--foxglove", "0", *extra],
                   cwd=tmp_path, env=env())


def watch(proc: Process, topics, until, timeout=STARTUP) -> Viewer:
    port = int(proc.wait_for(r"ws://localhost:(\d+)", 60.0).group(1))
    viewer = Viewer(f"ws://127.0.0.1:{port}")
    viewer.subscribe(topics)
    assert viewer.pump_until(lambda: until(viewer) or proc.proc.poll() is not None, timeout)
    assert proc.proc.poll() is None, proc.output()
    return viewer


def last_stats(viewer: Viewer) -> dict:
    msgs = viewer.messages.get("/cloth/lod_stats", [])
    return msgs[-1][1] if msgs else {}


# -- tests ---------------------------------------------------------------------------------
def test_varints_are_those_of_the_protobuf_encoding_guide():
    # https://protobuf.dev/programming-guides/encoding/: 1 -> 01, 150 -> 96 01.
    assert protobuf.varint(1) == b"\x01"
    assert protobuf.varint(150) == b"\x96\x01"
    assert protobuf.varint(0) == b"\x00"
    assert protobuf.varint(2**32) == bytes([0x80, 0x80, 0x80, 0x80, 0x10])
    assert protobuf.field_key(1, 0) == b"\x08"           # "08 96 01" = field 1, 150
    with pytest.raises(ValueError):
        protobuf.varint(-1)


def test_an_encoded_mesh_decodes_to_its_triangles_with_the_sdk_schema():
    """Our appended fields, read by an independent protobuf parser with the
    schema the SDK publishes, give back every triangle at its level."""
    from foxglove.messages import SceneUpdate
    schema = SceneUpdate.get_schema()
    cls = _protobuf_class(base64.b64encode(schema.data).decode(), schema.name)
    mesh = refine_uniform(base_mesh(1.0, 1.0, 4, 4), 3)
    rng = np.random.default_rng(7)
    levels = rng.integers(0, 4, size=mesh.triangle_count)
    x = np.column_stack([mesh.uv, rng.normal(size=len(mesh.uv))])
    payload = live_scene.scene_update(encoded=[live_scene.cloth_entity(
        x, mesh.triangles, levels, 3, "world", 1_500_000_007)])
    update = cls.FromString(payload)
    entity, prims = cloth_of(update)
    assert (entity.timestamp.seconds, entity.timestamp.nanos) == (1, 500_000_007)
    assert entity.frame_id == "world" and entity.frame_locked
    seen = 0
    for rgba, corners in prims:
        level = level_of(rgba[:3], 3)
        expected = x[mesh.triangles[levels == level]]
        assert corners.shape == expected.shape
        assert np.array_equal(corners, expected)               # same triangles, same order
        seen += len(corners)
    assert seen == mesh.triangle_count


def test_the_live_layer_imports_without_rclpy_or_mcap():
    code = ("import importlib.abc, sys\n"
            "class Block(importlib.abc.MetaPathFinder):\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name.split('.')[0] in ('rclpy', 'mcap'):\n"
            "            raise ImportError(name + ' is blocked')\n"
            "sys.meta_path.insert(0, Block())\n"
            "import cloth_lod_ros.live.server, cloth_lod_ros.live.scene, cloth_lod_ros.live.run\n"
            "from cloth_lod_ros.live.server import LiveView\n"
            "view = LiveView('127.0.0.1', 0)\n"
            "print(view.url)\n"
            "view.close()\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env(),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert re.fullmatch(r"ws://localhost:\d+", proc.stdout.strip())


def test_without_foxglove_the_run_says_how_to_install_it(tmp_path):
    code = ("import importlib.abc, sys\n"
            "class Block(importlib.abc.MetaPathFinder):\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name.split('.')[0] == 'foxglove':\n"
            "            raise ImportError(name + ' is blocked')\n"
            "sys.meta_path.insert(0, Block())\n"
            "from cloth_lod_ros.tools import cli\n"
            "sys.exit(cli.main(sys.argv[1:]))\n")
    proc = subprocess.run([sys.executable, "-c", code, "run", "hang_two_corners",
                           "--foxglove", "--duration", "0.1", "--no-png",
                           "--out", str(tmp_path / "s.npz")],
                          cwd=tmp_path, env=env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "pip install '.[viewer]'" in proc.stderr and "Traceback" not in proc.stderr


def test_a_port_in_use_is_an_error_naming_it(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = subprocess.run([sys.executable, "-m", "cloth_lod_ros.tools.cli", "run",
                               "hang_two_corners", "--foxglove", str(port), "--no-png",
                               "--out", str(tmp_path / "s.npz")],
                              cwd=tmp_path, env=env(), capture_output=True, text=True,
                              timeout=120)
    assert proc.returncode == 2
    assert f"127.0.0.1:{port}" in proc.stderr and "Traceback" not in proc.stderr


def test_a_headless_run_is_served_live_from_its_first_frame_to_its_last(tmp_path, processes):
    """hang_two_corners: a 1 m cloth, 4 x 4 blocks, level 6, starting flat at z = 1
    m over [0, 1]², pinned at material corners (0, 1) and (1, 1)."""
    duration = 0.5
    run = cli_run(tmp_path, "hang_two_corners", duration)
    processes(run)
    topics = ["/cloth/mesh", "/cloth/lod_stats", "/cloth/grasps", "/cloth/obstacles",
              "/cloth/wireframe"]
    viewer = watch(run, topics,
                   lambda v: last_stats(v).get("sim_time_s", -1) >= duration - 1e-9
                   and len(v.frames("/cloth/mesh", "/cloth/lod_stats")) >= 3)
    schema = json.loads(viewer.topics()["/cloth/lod_stats"]["schema"])
    assert viewer.topics()["/cloth/mesh"]["schemaName"] == "foxglove.SceneUpdate"
    frames = viewer.frames("/cloth/mesh", "/cloth/lod_stats")
    times = [f["/cloth/lod_stats"]["sim_time_s"] for f in frames.values()]
    assert times[0] == 0.0                  # the run waited for the viewer: nothing missed
    assert times == sorted(times) and times[-1] == pytest.approx(duration, abs=1e-9)
    base, finest = 2 * 4 * 4, 2 * 4 * 4 * 2**6
    pins = np.array([[0.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
    for frame in frames.values():
        stats = frame["/cloth/lod_stats"]
        check_stats(stats, schema)
        assert stats["max_level"] == 6 and base <= stats["triangles"] <= finest
        vertices = check_mesh_against_stats(frame["/cloth/mesh"], stats, size=math.sqrt(2))
        if stats["sim_time_s"] == 0.0:      # the start: flat at z = 1 m over the unit square
            assert np.all(vertices[:, 2] == 1.0)
            assert vertices[:, :2].min() >= 0.0 and vertices[:, :2].max() <= 1.0
        # The pinned corners stay; no point is farther from either than the
        # cloth's diagonal (plus 10 % stretch).
        for pin in pins:
            gaps = np.linalg.norm(vertices - pin, axis=1)
            assert gaps.min() < 1e-6
            assert gaps.max() <= 1.1 * math.sqrt(2)
    # No grasps and no obstacles in this scene: both topics carry empty updates.
    assert all(len(m.entities) == 0 for _, m in viewer.messages["/cloth/grasps"])
    assert all(len(m.entities) == 0 for _, m in viewer.messages["/cloth/obstacles"])
    wire = viewer.messages["/cloth/wireframe"][-1][1].entities[0]
    assert wire.id == "wireframe" and all(p.type == 2 for p in wire.lines)   # LINE_LIST
    viewer.close()
    run.wait_for("keeps showing the final state", STARTUP)     # outputs written: the hold
    assert run.stop() == 0, run.output()                # Ctrl-C ends the hold cleanly
    with np.load(tmp_path / "state.npz") as state:
        assert float(state["time"]) == pytest.approx(duration, abs=1e-9)


def test_a_scripted_box_is_drawn_where_the_scene_has_it_at_each_moment(tmp_path, processes):
    """push_with_box: the box 'pusher' (half extents 0.05, 0.4, 0.08 m) waits at
    x = -0.5 m until 0.2 s, then moves to x = +0.5 m at 2.7 s turning 30° about z
    (0.4 m/s, within its 1 m/s limit); the table is the plane z = 0."""
    duration = 0.8
    run = cli_run(tmp_path, "push_with_box", duration)
    processes(run)
    topics = ["/cloth/obstacles", "/cloth/lod_stats", "/tf"]
    viewer = watch(run, topics,
                   lambda v: last_stats(v).get("sim_time_s", -1) >= duration - 1e-9)
    frames = viewer.frames(*topics)
    assert len(frames) >= 5
    moved = 0
    for frame in frames.values():
        t = frame["/cloth/lod_stats"]["sim_time_s"]
        entities = {e.id: e for e in frame["/cloth/obstacles"].entities}
        assert set(entities) == {"obstacle/table", "obstacle/pusher"}
        (box,) = entities["obstacle/pusher"].cubes
        s = min(max((t - 0.2) / 2.5, 0.0), 1.0)
        p, q = box.pose.position, box.pose.orientation
        assert p.x == pytest.approx(-0.5 + s, abs=0.01)
        assert (p.y, p.z) == pytest.approx((0.0, 0.03), abs=1e-9)
        yaw = 2 * math.atan2(q.z, q.w)
        assert math.degrees(yaw) == pytest.approx(30.0 * s, abs=0.5)
        assert (box.size.x, box.size.y, box.size.z) == pytest.approx((0.1, 0.8, 0.16))
        (table,) = entities["obstacle/table"].cubes               # a thin slab under z = 0
        assert table.pose.position.z + table.size.z / 2 == pytest.approx(0.0, abs=1e-9)
        moved += p.x > -0.5 + 0.05
        # Its frame on /tf: the box's centre and orientation.
        tf = {f.child_frame_id: f for f in frame["/tf"].transforms}["obstacle/pusher"]
        assert tf.parent_frame_id == "world"
        assert (tf.translation.x, tf.rotation.z) == pytest.approx((p.x, q.z), abs=1e-12)
    assert moved >= 1                                             # it was seen moving
    viewer.close()
    run.wait_for("keeps showing the final state", STARTUP)     # outputs written: the hold
    assert run.stop() == 0, run.output()


def test_the_node_serves_the_live_view(tmp_path, processes):
    with socket.socket() as s:                  # a free port (released for the node)
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    domain = str(random.Random(os.getpid() ^ int(time.time())).randint(20, 220))
    node = Process([sys.executable, "-m", "cloth_lod_ros.ros.node", "--ros-args",
                    "-p", "scene:=hang_two_corners", "-p", f"foxglove_port:={port}"],
                   cwd=tmp_path, env=env(ROS_DOMAIN_ID=domain,
                                         ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"))
    processes(node)
    node.wait_for(rf"ws://localhost:{port}", STARTUP)
    viewer = Viewer(f"ws://127.0.0.1:{port}")
    viewer.subscribe(["/cloth/mesh", "/cloth/lod_stats"])
    assert viewer.pump_until(lambda: len(viewer.frames("/cloth/mesh", "/cloth/lod_stats")) >= 2,
                             STARTUP), node.output()
    schema = json.loads(viewer.topics()["/cloth/lod_stats"]["schema"])
    for frame in viewer.frames("/cloth/mesh", "/cloth/lod_stats").values():
        stats = frame["/cloth/lod_stats"]
        check_stats(stats, schema)
        assert 2 * 4 * 4 <= stats["triangles"] <= 2 * 4 * 4 * 2**6
        check_mesh_against_stats(frame["/cloth/mesh"], stats, size=math.sqrt(2))
        # The node's own figures come along as numbers (it has them as strings).
        assert isinstance(stats["real_time_factor"], float)
        assert stats["internal_errors"] == 0.0
    viewer.close()
    assert node.stop() == 0, node.output()
