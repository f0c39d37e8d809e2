"""Session recording, shared by the node and the headless runner.

:class:`SessionRecorder` writes a session to a rosbag2 bag (design §7):

* ``/cloth/session`` (std_msgs/String, JSON, first message): the resolved scene,
  the node parameters, the grid resolution and the package version - what
  ``cloth-lod replay`` rebuilds the simulator from;
* ``/cloth/inputs`` (std_msgs/String, JSON): every input *as the simulator
  applied it*, with the step count it was applied before: grasp targets,
  open/close, parameter changes, resets, pause/resume;
* ``/grasp/<name>/pose``, ``/obstacle/<name>/pose`` (geometry_msgs/PoseStamped): the
  poses the node accepted, as received;
* ``/cloth/rejected`` (std_msgs/String, JSON): inputs the node rejected, in a bounded
  form: where, why, and a truncated copy (:meth:`SessionRecorder.record_rejected`);
* the node's four outputs (:class:`~cloth_lod_ros.messages.frames.FrameBuilder`),
  exactly as published.

Received messages (accepted poses, rejected inputs) share a budget of
:data:`INPUT_BYTES_PER_S` (a token bucket holding at most :data:`INPUT_BURST_BYTES`):
a remote participant cannot make the bag grow faster, whatever it sends; what is over
the budget is counted (:attr:`SessionRecorder.unrecorded`), not written, and the next
rejected record says how many were left out before it.  Inputs as applied
(``/cloth/inputs``) are bounded by the step rate (the newest target per grasp and
obstacle, a bounded queue of commands) and never budgeted: replay needs each one.  The
writer's queue holds at most :data:`MAX_QUEUED_BYTES`; beyond it messages are
dropped and counted, and a warning says so.

Log times never decrease (a clock step backwards is clamped), and MCAP readers
break ties by file position, so log-time order is the order in which things
happened to the simulator; the four messages of one frame share a log time.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time as _time
from importlib import metadata as _metadata

import numpy as np
from rclpy.serialization import serialize_message
from std_msgs.msg import String

from ..messages.frames import FrameBuilder
from ..sim.scene.config import scene_to_dict
from .rosbag import BagError, BagWriter, qos_profiles_yaml

__all__ = ["SessionRecorder", "OUTPUT_TYPES", "SESSION_FORMAT"]

log = logging.getLogger(__name__)

SESSION_FORMAT = 1
#: Bytes per second of received messages (accepted poses as received, records of
#: rejected inputs) a bag takes, on average; a burst may take :data:`INPUT_BURST_BYTES`.
#: A pose is about 100 bytes: a grasp driven at 100 Hz takes half of it.
INPUT_BYTES_PER_S = 20_000
INPUT_BURST_BYTES = 80_000
#: Characters of a rejected input's text (its frame id) kept in its record.
REJECTED_TEXT_CHARS = 64
#: Most bytes waiting for the writer thread (a disk that stalls): beyond, dropped.
MAX_QUEUED_BYTES = 64_000_000
# Relative output topic -> (type, QoS as offered by the node's publishers).
OUTPUT_TYPES = {
    "cloth/markers": ("visualization_msgs/msg/MarkerArray",
                      qos_profiles_yaml(durability="transient_local", depth=1)),
    "cloth/points": ("sensor_msgs/msg/PointCloud2", qos_profiles_yaml()),
    "cloth/grid": ("sensor_msgs/msg/PointCloud2", qos_profiles_yaml()),
    "cloth/lod_stats": ("diagnostic_msgs/msg/DiagnosticArray", qos_profiles_yaml()),
}


def package_version() -> str:
    try:
        return _metadata.version("cloth_lod_ros")
    except _metadata.PackageNotFoundError:       # running from a source tree
        return "source"


class ByteBudget:
    """A token bucket: ``rate`` bytes per second, at most ``burst`` at once.

    Thread-safe; ``clock`` (s, monotonic) is injectable for tests."""

    def __init__(self, rate: float, burst: float, clock=_time.monotonic):
        self.rate, self.burst, self.clock = float(rate), float(burst), clock
        self._tokens, self._last = float(burst), clock()
        self._lock = threading.Lock()

    def take(self, size: int) -> bool:
        """Whether ``size`` bytes fit now (and take them if they do)."""
        with self._lock:
            now = self.clock()
            self._tokens = min(self.burst, self._tokens + (now - self._last) * self.rate)
            self._last = now
            if size > self._tokens:
                return False
            self._tokens -= size
            return True


def _short(text: str, limit: int = REJECTED_TEXT_CHARS) -> str:
    """``text`` cut to ``limit`` characters, saying how long it was."""
    text = str(text)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} chars)"


def _plain_number(value):
    """A float JSON can carry (NaN and infinities as their names)."""
    value = float(value)
    return value if np.isfinite(value) else repr(value)


class SessionRecorder:
    """Records a session to a bag; a failure stops recording, never the caller.

    Compression and file writes run on a background thread (zstandard and file
    I/O release the GIL), so the simulating thread only queues bytes.  If the
    disk cannot keep up and ``max_queued`` messages wait, further *output*
    frames are dropped and counted in :attr:`dropped_frames`; if
    :data:`MAX_QUEUED_BYTES` wait, any message but the session's is dropped and
    counted in :attr:`dropped_messages` (replay then reports what is missing).
    Received messages are written within :data:`INPUT_BYTES_PER_S`
    (:attr:`unrecorded` counts the rest).

    Args:
        path: bag directory (must not exist).
        namespace: prefix of the recorded topic names (the node's namespace).
        compression: ``"none"``, ``"zstd"`` or ``"lz4"`` chunk compression.
        flush_interval: s, see :class:`~cloth_lod_ros.bag.rosbag.BagWriter`.
        grasp_names, obstacle_names: whose received pose topics are recorded.

    Raises:
        BagError: the bag cannot be created (unwritable or existing path).
    """

    def __init__(self, path, namespace: str = "/", compression: str = "zstd",
                 flush_interval: float = 1.0, grasp_names=(), max_queued: int = 512,
                 obstacle_names=()):
        self.namespace = "/" + namespace.strip("/") if namespace.strip("/") else ""
        self.writer = BagWriter(path, compression=compression, flush_interval=flush_interval)
        self.path = self.writer.path
        self.failed: str | None = None
        self.dropped_frames = 0
        self.dropped_messages = 0       # the queue was over MAX_QUEUED_BYTES
        self.unrecorded = 0             # received messages over the input budget
        self._unrecorded_reported = 0   # of those, already said in a rejected record
        self.input_budget = ByteBudget(INPUT_BYTES_PER_S, INPUT_BURST_BYTES)
        self._queued_bytes = 0
        self._bytes_lock = threading.Lock()
        self._last_ns = 0
        # Inputs are recorded from the node's input threads, frames from its
        # stepping thread: log times and queue order are taken under one lock.
        self._order_lock = threading.Lock()
        self._max_queued = max_queued
        self._queue: queue.Queue = queue.Queue()
        self._thread = threading.Thread(target=self._drain, name="bag-writer", daemon=True)
        try:
            for topic, (type_name, qos) in OUTPUT_TYPES.items():
                self.writer.add_topic(self.topic(topic), type_name, qos)
            self.writer.add_topic(self.topic("cloth/session"), "std_msgs/msg/String",
                                  qos_profiles_yaml(durability="transient_local", depth=1))
            self.writer.add_topic(self.topic("cloth/inputs"), "std_msgs/msg/String",
                                  qos_profiles_yaml(depth=100))
            self.writer.add_topic(self.topic("cloth/rejected"), "std_msgs/msg/String",
                                  qos_profiles_yaml(depth=100))
            for kind, names in (("grasp", grasp_names), ("obstacle", obstacle_names)):
                for name in names:
                    self.writer.add_topic(self.topic(f"{kind}/{name}/pose"),
                                          "geometry_msgs/msg/PoseStamped")
        except BagError:
            self.writer.close()
            raise
        self._thread.start()

    def _drain(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            topic, data, time_ns, flush = item
            with self._bytes_lock:
                self._queued_bytes -= len(data)
            if self.failed is not None:
                continue
            try:
                self.writer.write(topic, data, time_ns)
                if flush:
                    self.writer.flush()
            except BagError as exc:
                self.failed = str(exc)
                log.error("recording failed: %s; the simulation goes on without it", exc)

    def topic(self, relative: str) -> str:
        return f"{self.namespace}/{relative}"

    @property
    def active(self) -> bool:
        return self.failed is None and not self.writer.closed

    def _time(self, time_ns: int | None) -> int:
        t = _time.time_ns() if time_ns is None else int(time_ns)
        t = max(t, self._last_ns)
        self._last_ns = t
        return t

    def _write(self, relative: str, data: bytes, time_ns: int | None,
               flush: bool = False) -> None:
        if self.active:
            with self._bytes_lock:
                if (self._queued_bytes + len(data) > MAX_QUEUED_BYTES
                        and relative != "cloth/session"):
                    self.dropped_messages += 1
                    if self.dropped_messages == 1 or self.dropped_messages % 1000 == 0:
                        log.warning("recording: %d messages dropped, %d bytes wait for the "
                                    "disk", self.dropped_messages, self._queued_bytes)
                    return
                self._queued_bytes += len(data)
            with self._order_lock:
                self._queue.put((self.topic(relative), data, self._time(time_ns), flush))

    def start(self, sim, parameters: dict | None = None, grid_resolution: int = 21,
              time_ns: int | None = None) -> None:
        """Write ``/cloth/session`` and flush it, so even a killed session has it."""
        session = {"format": SESSION_FORMAT, "package_version": package_version(),
                   "scene": scene_to_dict(sim.scene), "parameters": parameters or {},
                   "grid_resolution": int(grid_resolution),
                   # Replay needs the simulation's start; a later start is marked.
                   "start_step_count": int(sim.step_count), "start_sim_time": float(sim.time)}
        self._write("cloth/session", serialize_message(String(data=json.dumps(session))),
                    time_ns, flush=True)

    def record_frame(self, frames: dict, time_ns: int | None = None) -> None:
        """Write one frame of :meth:`FrameBuilder.build` (all at the same log time)."""
        if self._queue.qsize() > self._max_queued:
            self.dropped_frames += 1             # the disk is behind: keep inputs, skip a frame
            return
        with self._order_lock:
            t = self._time(time_ns)
        for relative, data in frames.items():
            self._write(relative, data, t)

    def record_input(self, sim, kind: str, time_ns: int | None = None, **payload) -> None:
        """Write one applied input: ``kind`` plus its payload, with the step count
        it applies before and the simulated time."""
        event = {"kind": kind, "step_count": int(sim.step_count), "sim_time": float(sim.time)}
        event.update(payload)
        self._write("cloth/inputs", serialize_message(String(data=json.dumps(event))), time_ns)

    def record_message(self, relative: str, data: bytes, time_ns: int | None = None) -> bool:
        """Write a raw input message (e.g. an accepted grasp pose) within the input
        budget; returns whether it was written (else it is counted in :attr:`unrecorded`)."""
        if self.topic(relative) not in self.writer.topics:
            return False
        if not self.input_budget.take(len(data)):
            self.unrecorded += 1
            return False
        self._write(relative, data, time_ns)
        return True

    def record_rejected(self, relative: str, reason: str, time_ns: int | None = None,
                        **copy) -> bool:
        """Record a rejected input on ``/cloth/rejected`` within the input budget:
        ``{"topic", "reason", "unrecorded_before", ...copy}`` with text cut to
        :data:`REJECTED_TEXT_CHARS` and floats made JSON-safe (``copy``: e.g. the
        pose's ``frame_id``, ``stamp``, ``position``, ``orientation``).  Returns
        whether it was written (else counted in :attr:`unrecorded`)."""
        event = {"topic": self.topic(relative), "reason": _short(reason),
                 "unrecorded_before": self.unrecorded - self._unrecorded_reported}
        for key, value in copy.items():
            if isinstance(value, str):
                value = _short(value)
            elif isinstance(value, (list, tuple, np.ndarray)):
                value = [_plain_number(v) for v in list(value)[:8]]
            elif isinstance(value, (int, float)) and not isinstance(value, bool):
                value = _plain_number(value) if isinstance(value, float) else int(value)
            else:
                value = _short(repr(value))
            event[key] = value
        data = serialize_message(String(data=json.dumps(event)))
        if not self.input_budget.take(len(data)):
            self.unrecorded += 1
            return False
        self._unrecorded_reported = self.unrecorded
        self._write("cloth/rejected", data, time_ns)
        return True

    def close(self) -> None:
        """Write what is queued, then finish the bag (summary and metadata.yaml)."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        try:
            self.writer.close()
        except BagError as exc:
            self.failed = self.failed or str(exc)
            log.error("closing the recording failed: %s", exc)


def _benchmark(levels=(6, 8), frames: int = 30) -> None:
    """Print frame build time, recording cost and bag size per simulated second
    (``python -m cloth_lod_ros.bag.recorder [OUT_DIR]``).

    For each level, the uniform ``hang_two_corners`` cloth is stepped ``frames``
    times from its start and a frame is built after every other step (30 frames
    per simulated second at h = 1/60 s; distinct frames, so compression sees real
    data).  Each compression then records those frames: the caller's cost
    (queueing) and the background thread's (compress + write, measured as the
    drain after queueing), per frame, and the bag's size per simulated second.
    """
    import os
    import sys
    import tempfile
    from pathlib import Path

    from ..sim.scene.config import load_scene
    from ..sim import ClothSim
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="cloth_bag_"))
    for level in levels:
        sim = ClothSim(load_scene("hang_two_corners", ["lod.enabled=false", f"cloth.level={level}"]))
        builder = FrameBuilder("world", 21)
        built, build_ms = [], []
        for k in range(2 * frames):
            sim.step()
            if k % 2:
                start = _time.perf_counter()
                built.append(builder.build(sim, (k, 0)))
                build_ms.append(1e3 * (_time.perf_counter() - start))
        print(f"level {level}: {sim.mesh.triangle_count} triangles, frame built in "
              f"{np.median(build_ms):.1f} ms (median)")
        simulated = len(built) / 30.0
        for compression in ("none", "zstd", "lz4"):
            recorder = SessionRecorder(out / f"level{level}_{compression}", "/", compression)
            recorder.start(sim)
            start = _time.perf_counter()
            for k, frame in enumerate(built):
                recorder.record_frame(frame, 10**9 + k * 10**9 // 30)
            queue_ms = 1e3 * (_time.perf_counter() - start) / len(built)
            start = _time.perf_counter()
            recorder.close()                   # waits for the writer thread
            write_ms = 1e3 * (_time.perf_counter() - start) / len(built)
            size = os.path.getsize(recorder.writer.mcap_path)
            print(f"  {compression:5s} queue {queue_ms:.3f} ms/frame, compress + write "
                  f"{write_ms:.2f} ms/frame (background), {size / len(built) / 1e3:.0f} "
                  f"kB/frame, {size / simulated / 1e6:.1f} MB per simulated s")
    print(f"bags in {out}")


if __name__ == "__main__":  # pragma: no cover
    _benchmark()
