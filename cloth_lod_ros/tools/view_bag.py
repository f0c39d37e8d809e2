"""Frames of a recorded session for ``cloth-lod view``, streamed at a chosen frame rate.

A bag of the node or of ``cloth-lod run --bag`` holds, per output frame and at
one log time (:mod:`~cloth_lod_ros.bag.recorder`), a ``cloth/markers``
``visualization_msgs/MarkerArray`` and a ``cloth/lod_stats``
``diagnostic_msgs/DiagnosticArray``.  The marker array carries everything a
picture needs (:class:`~cloth_lod_ros.messages.frames.FrameBuilder`):

* ``surface`` (TRIANGLE_LIST): the triangle corners, and through the colours
  each face's level (:func:`~cloth_lod_ros.messages.markers.surface_levels`);
* ``grasps`` (SPHERE_LIST): the closed grasps' points;
* one marker per obstacle of the scene (``ns`` = its name, ``id`` = 10 + its
  index), at the pose the obstacle had in that frame - scripted waypoints and
  poses driven live over ``obstacle/<name>/pose`` alike, after the speed
  limits.  So obstacles are drawn where they were, frame by frame.

Time: the video's clock is the bag's **log time** (the node: wall-clock time
of publication; ``run --bag``: start + simulated time).  Output frame ``k``
shows the latest recorded frame whose log time is at most
``t0 + k * speed / fps`` (``t0``: the first recorded frame), so a video of
``fps`` frames per second lasts as long as the session did (divided by
``speed``).  The titles give the simulated time (``sim_time_s`` of
``cloth/lod_stats``).

Memory: messages are read one at a time (the MCAP reader decompresses one
chunk at a time); a recorded frame is kept as its raw bytes only until the
next one arrives, and its CDR is parsed only if an output frame shows it.
The CDR is parsed here with numpy (plain little-endian CDR, the layout of
:func:`~cloth_lod_ros.messages.markers.serialize_marker_array` and of the
ROS 2 type definitions), so no rclpy is needed and a 2 000-triangle surface
costs no Python object per point.
"""

from __future__ import annotations

import dataclasses
import json
import struct
from dataclasses import dataclass, field
from typing import Iterator, NamedTuple

import numpy as np

from ..bag.rosbag import BagError, BagReader
from ..messages.markers import (ADD, CUBE, CYLINDER, SPHERE, SPHERE_LIST, TRIANGLE_LIST,
                                surface_levels)
from ..sim.contact.obstacles import quaternion_matrix
from .plotting import ClothFrame
from .scene3d import obstacle_extent

__all__ = ["MarkerView", "parse_marker_array", "parse_diagnostic_values", "parse_string",
           "BagSource", "open_bag", "scan", "select_frames", "bag_frames", "frame_offsets",
           "levels_from_area"]

OBSTACLE_FIRST_ID = 10       # obstacle_markers(first_id=10): marker id = 10 + scene index
_PLANE_OFFSET = 0.005        # obstacle_markers draws a plane's slab 5 mm below its point
_MARKER_TYPE = {"plane": CUBE, "box": CUBE, "sphere": SPHERE, "cylinder": CYLINDER,
                "disc": CYLINDER}


# -- CDR ----------------------------------------------------------------------------
class _Cdr:
    """Plain little-endian CDR (XCDR1): primitives aligned to their size,
    counted from the byte after the 4-byte encapsulation header."""

    _U32 = struct.Struct("<I")

    def __init__(self, data: bytes):
        if len(data) < 4 or data[:2] != b"\x00\x01":
            raise ValueError("not a little-endian CDR message")
        self.buf = memoryview(data)
        self.pos = 4

    def align(self, n: int) -> None:
        self.pos += (-(self.pos - 4)) % n

    def unpack(self, fmt: struct.Struct, align: int):
        self.align(align)
        values = fmt.unpack_from(self.buf, self.pos)
        self.pos += fmt.size
        return values

    def u32(self) -> int:
        return self.unpack(self._U32, 4)[0]

    def string(self) -> str:
        n = self.u32()                          # length including the terminating NUL
        text = bytes(self.buf[self.pos:self.pos + max(n - 1, 0)]).decode("utf-8", "replace")
        self.pos += n
        return text

    def array(self, dtype: str, width: int, align: int) -> np.ndarray:
        """A sequence of fixed-size structs of ``width`` numbers: ``(n, width)``
        (a read-only view into the message, no copy)."""
        n = self.u32()
        if n:
            self.align(align)
        arr = np.frombuffer(self.buf, dtype=dtype, count=n * width, offset=self.pos)
        self.pos += arr.nbytes
        return arr.reshape(n, width)

    def skip_header(self) -> None:
        self.unpack(_STAMP, 4)                   # builtin_interfaces/Time
        self.string()                            # frame_id


_STAMP = struct.Struct("<iI")
_MARKER_HEAD = struct.Struct("<iii")            # id, type, action
_POSE_SCALE = struct.Struct("<10d")             # position, orientation (x y z w), scale
_COLOR = struct.Struct("<4f")
_BOOL = struct.Struct("<?")


class MarkerView(NamedTuple):
    """The fields of one ``visualization_msgs/Marker`` that a picture uses.

    position ``(3,)`` m, orientation ``(4,)`` quaternion [x, y, z, w], scale
    ``(3,)``; points ``(k, 3)`` m (float64) and colors ``(k, 4)`` RGBA (float32)
    are read-only views into the message bytes.
    """

    ns: str
    id: int
    type: int
    action: int
    position: np.ndarray
    orientation: np.ndarray
    scale: np.ndarray
    points: np.ndarray
    colors: np.ndarray


def parse_marker_array(data: bytes) -> list[MarkerView]:
    """The markers of a CDR ``visualization_msgs/MarkerArray`` (ROS 2 Jazzy layout).

    Field order from ``visualization_msgs/msg/Marker.msg``: header, ns, id,
    type, action, pose, scale, color, lifetime, frame_locked, points, colors,
    texture_resource, texture (sensor_msgs/CompressedImage), uv_coordinates,
    text, mesh_resource, mesh_file (MeshFile), mesh_use_embedded_materials.

    Raises:
        ValueError: not little-endian CDR, or shorter than its own counts say.
    """
    try:
        r = _Cdr(data)
        markers = []
        for _ in range(r.u32()):
            r.skip_header()
            ns = r.string()
            mid, mtype, action = r.unpack(_MARKER_HEAD, 4)
            pose = np.array(r.unpack(_POSE_SCALE, 8))
            r.unpack(_COLOR, 4)
            r.unpack(_STAMP, 4)                  # lifetime
            r.unpack(_BOOL, 1)                   # frame_locked
            points = r.array("<f8", 3, 8)
            colors = r.array("<f4", 4, 4)
            r.string()                           # texture_resource
            r.skip_header()                      # texture.header
            r.string()                           # texture.format
            r.array("u1", 1, 1)                  # texture.data
            r.array("<f4", 2, 4)                 # uv_coordinates
            r.string()                           # text
            r.string()                           # mesh_resource
            r.string()                           # mesh_file.filename
            r.array("u1", 1, 1)                  # mesh_file.data
            r.unpack(_BOOL, 1)                   # mesh_use_embedded_materials
            markers.append(MarkerView(ns, mid, mtype, action, pose[:3], pose[3:7], pose[7:10],
                                      points, colors))
    except (struct.error, ValueError, UnicodeError) as exc:
        raise ValueError(f"unreadable MarkerArray ({exc})") from None
    return markers


def parse_diagnostic_values(data: bytes) -> dict[str, str]:
    """Key/values of the first status of a CDR ``diagnostic_msgs/DiagnosticArray``.

    Raises:
        ValueError: not little-endian CDR, or truncated.
    """
    try:
        r = _Cdr(data)
        r.skip_header()
        if not r.u32():
            return {}
        r.unpack(_BOOL, 1)                       # level (byte)
        for _ in range(3):                       # name, message, hardware_id
            r.string()
        return {r.string(): r.string() for _ in range(r.u32())}
    except (struct.error, ValueError, UnicodeError) as exc:
        raise ValueError(f"unreadable DiagnosticArray ({exc})") from None


def parse_string(data: bytes) -> str:
    """The text of a CDR ``std_msgs/String``."""
    try:
        return _Cdr(data).string()
    except (struct.error, ValueError) as exc:
        raise ValueError(f"unreadable String ({exc})") from None


# -- what a recorded frame shows -------------------------------------------------------
def levels_from_area(corners: np.ndarray, scene) -> np.ndarray:
    """``(t,)`` levels implied by the areas of triangles ``corners`` ``(t, 3, 3)``
    (m): each bisection halves a base triangle's area (half a square block);
    right for strains well below 40 %."""
    cloth = scene.cloth
    base_area = 0.5 * (cloth.width / cloth.base_blocks[0]) ** 2
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                         corners[:, 2] - corners[:, 0]), axis=1)
    levels = np.round(np.log2(base_area / np.maximum(area, 1e-300)))
    return np.clip(levels, 0, cloth.level).astype(np.int64)


def _posed(o, marker: MarkerView):
    """Obstacle config ``o`` moved to the pose of its marker (the inverse of
    :func:`~cloth_lod_ros.messages.markers.obstacle_markers`)."""
    centre = marker.position.astype(float)
    z_axis = quaternion_matrix(marker.orientation)[:, 2]
    if o.type == "plane":
        return dataclasses.replace(o, centre=tuple(centre + _PLANE_OFFSET * z_axis),
                                   normal=tuple(z_axis))
    if o.type == "sphere":
        return dataclasses.replace(o, centre=tuple(centre))
    if o.type in ("cylinder", "disc"):
        return dataclasses.replace(o, centre=tuple(centre), axis=tuple(z_axis))
    return dataclasses.replace(o, centre=tuple(centre),
                               orientation=tuple(marker.orientation.astype(float)))


@dataclass
class _Shown:
    """A recorded frame, parsed: the surface, grasps and obstacles."""

    corners: np.ndarray                 # (t, 3, 3) m
    colours: np.ndarray | None          # (t, 3) RGB of each face, or None
    grasps: np.ndarray                  # (g, 3) m
    obstacles: tuple                    # configs at this frame's poses, scene order


def _parse_frame(data: bytes, scene) -> _Shown | None:
    """A recorded ``cloth/markers`` message (None: no surface marker in it)."""
    surface, grasps = None, np.zeros((0, 3))
    poses = {}
    for m in parse_marker_array(data):
        if m.action != ADD:
            continue
        if m.ns == "surface" and m.type == TRIANGLE_LIST:
            surface = m
        elif m.ns == "grasps" and m.type == SPHERE_LIST:
            grasps = m.points
        elif m.id >= OBSTACLE_FIRST_ID:
            poses[(m.ns, m.id)] = m
    if surface is None:
        return None
    obstacles = []
    for k, o in enumerate(scene.obstacles):
        marker = poses.get((o.name, OBSTACLE_FIRST_ID + k))
        same_shape = marker is not None and marker.type == _MARKER_TYPE[o.type]
        obstacles.append(_posed(o, marker) if same_shape else o)
    corners = np.array(surface.points).reshape(-1, 3, 3)   # aligned copy: faster maths
    colours = None
    if len(surface.colors) == len(surface.points):
        colours = surface.colors[::3, :3].astype(float)
    return _Shown(corners, colours, np.array(grasps, float).reshape(-1, 3), tuple(obstacles))


# -- a bag ----------------------------------------------------------------------------
@dataclass
class BagSource:
    """A recorded session to show.

    Attributes:
        path: the bag; scene: its ``/cloth/session`` scene (names, colour scale).
        markers_topic, stats_topic: the recorded topics (stats may be None).
        recorded: recorded marker messages.
        start_ns: log time of the first recorded frame, ns; end_ns: of the
            last recorded frame (within ``--duration``); last_shown_ns: of the
            last recorded frame shown (all filled by :func:`scan`).
        box_points: ``(2, 3)`` lowest and highest surface corner over the
            frames shown, m; obstacle_extents: per non-plane obstacle, ``(2, 3)``
            bounds over its poses; planes: the last poses of the planes
            (all filled by :func:`scan`).
    """

    path: object
    scene: object
    markers_topic: str
    stats_topic: str | None
    recorded: int
    start_ns: int | None = None
    end_ns: int | None = None
    last_shown_ns: int | None = None
    box_points: np.ndarray | None = None
    obstacle_extents: list = field(default_factory=list)
    planes: tuple = ()


def open_bag(reader: BagReader) -> BagSource:
    """The session and topics of an open bag.

    Raises:
        BagError: no session, an unreadable scene, or no recorded markers.
    """
    from ..bag.analysis import topic_named
    from ..sim.scene.config import SceneError, scene_from_dict
    path = reader.path
    session_topic = topic_named(reader, "cloth/session")
    session = None
    if session_topic is not None:
        for m in reader.messages([session_topic]):
            try:
                session = json.loads(parse_string(m.data))
            except ValueError as exc:
                raise BagError(f"{path}: unreadable session message ({exc})") from None
            break
    if session is None:
        raise BagError(f"{path}: no cloth/session message; not a cloth_lod_ros recording")
    try:
        scene = scene_from_dict(session["scene"])
    except (SceneError, KeyError, TypeError) as exc:
        raise BagError(f"{path}: the session's scene is unreadable ({exc})") from None
    markers_topic = topic_named(reader, "cloth/markers")
    if markers_topic is None or not reader.topics[markers_topic].message_count:
        raise BagError(f"{path}: no cloth/markers messages to show")
    return BagSource(path, scene, markers_topic, topic_named(reader, "cloth/lod_stats"),
                     reader.topics[markers_topic].message_count)


def frame_offsets(fps: float, speed: float = 1.0) -> Iterator[int]:
    """Bag-time offsets from the first frame of output frames 0, 1, 2, ...: ``k
    speed / fps`` seconds, in ns (rounded, not accumulated)."""
    step = 1e9 * speed / fps
    k = 0
    while True:
        yield int(round(k * step))
        k += 1


def select_frames(messages, markers_topic: str, stats_topic: str | None, offsets,
                  duration_ns: int | None = None) -> Iterator[tuple]:
    """Pick the recorded frame each output frame shows, without parsing any.

    Args:
        messages: :class:`~cloth_lod_ros.bag.rosbag.BagMessage` iterator in
            log-time order (at least the markers and stats topics).
        offsets: nondecreasing output times after the first recorded frame, ns
            (e.g. :func:`frame_offsets`); the frames end when it does, or at
            the last recorded frame, or after ``duration_ns``.

    Yields:
        ``(output offset ns, recorded log time ns, markers bytes, stats bytes
        or None)``: the latest recorded frame at or before each output time.
        Consecutive output frames showing the same recorded frame yield the same
        objects.  Only the current recorded frame is held.
    """
    offsets = iter(offsets)
    target = next(offsets, None)
    pending = None                     # [log time, markers bytes, stats bytes]
    first = None
    for m in messages:
        if target is None:
            return
        if m.topic == markers_topic:
            if first is None:
                first = m.time_ns
            while pending is not None and target is not None and first + target < m.time_ns \
                    and (duration_ns is None or target <= duration_ns):
                yield target, pending[0], pending[1], pending[2]
                target = next(offsets, None)
            if duration_ns is not None and m.time_ns - first > duration_ns:
                return
            pending = [m.time_ns, m.data, None]
        elif m.topic == stats_topic and pending is not None and m.time_ns == pending[0]:
            pending[2] = m.data                # the same frame's statistics
    while pending is not None and target is not None and first + target <= pending[0] \
            and (duration_ns is None or target <= duration_ns):
        yield target, pending[0], pending[1], pending[2]
        target = next(offsets, None)


def _title(name: str, t: float, triangles: int) -> str:
    return f"{name}   t = {t:.2f} s   {triangles} triangles"


def bag_frames(reader: BagReader, source: BagSource, offsets,
               duration_ns: int | None = None) -> Iterator[tuple[int, int, ClothFrame]]:
    """The frames a bag shows at output times ``offsets`` (see :func:`select_frames`).

    Yields:
        ``(output offset ns, recorded log time ns, ClothFrame)``; the frame's
        time is the simulated time (``sim_time_s``; the log time since the
        first frame when the statistics are missing), its obstacles are at
        their recorded poses.  A recorded frame shown by several output frames
        is parsed once and yielded as the same object.  Frames without a
        surface marker are skipped.
    """
    scene = source.scene
    topics = [t for t in (source.markers_topic, source.stats_topic) if t]
    last_time, last_frame, first = None, None, None
    for offset, time_ns, markers, stats in select_frames(
            reader.messages(topics), source.markers_topic, source.stats_topic, offsets,
            duration_ns):
        if first is None:
            first = time_ns - offset
        if time_ns != last_time:
            last_time, last_frame = time_ns, None
            try:
                shown = _parse_frame(markers, scene)
                values = parse_diagnostic_values(stats) if stats is not None else {}
            except ValueError as exc:
                raise BagError(f"{source.path}: recorded frame at log time {time_ns} ns: "
                               f"{exc}") from None
            if shown is not None:
                t = float(values.get("sim_time_s", (time_ns - first) * 1e-9))
                levels = (surface_levels(shown.corners, shown.colours, scene.cloth.level)
                          if shown.colours is not None else None)
                if levels is None:
                    levels = levels_from_area(shown.corners, scene)
                n = len(shown.corners)
                last_frame = ClothFrame(shown.corners.reshape(-1, 3),
                                        np.arange(3 * n).reshape(-1, 3), levels, t,
                                        shown.grasps, title=_title(scene.name, t, n),
                                        obstacles=shown.obstacles)
        if last_frame is not None:
            yield offset, time_ns, last_frame


def scan(reader: BagReader, source: BagSource, offsets,
         duration_ns: int | None = None) -> int:
    """First pass: the time span, the cloth's and obstacles' reach over the
    frames to show (for fixed axes), without building frames.

    Returns:
        The number of output frames (fills ``source``'s span and bounds).

    Raises:
        BagError: no recorded frame has a cloth surface.
    """
    scene = source.scene
    topics = [t for t in (source.markers_topic, source.stats_topic) if t]
    lo = np.full(3, np.inf)
    hi = -lo
    solid = [k for k, o in enumerate(scene.obstacles) if o.type != "plane"]
    extents = {k: [np.full(3, np.inf), np.full(3, -np.inf)] for k in solid}
    planes = tuple(o for o in scene.obstacles if o.type == "plane")
    count, last_time, start, shown = 0, None, None, None
    span = [None, None]                        # first and last recorded frame in range

    def noted(messages):
        for m in messages:
            if m.topic == source.markers_topic:
                if span[0] is None:
                    span[0] = m.time_ns
                if duration_ns is None or m.time_ns - span[0] <= duration_ns:
                    span[1] = m.time_ns
            yield m

    for offset, time_ns, markers, _ in select_frames(
            noted(reader.messages(topics)), source.markers_topic, None, offsets, duration_ns):
        if start is None:
            start = time_ns - offset
        if time_ns != last_time:
            last_time = time_ns
            try:
                shown = _parse_frame(markers, scene)
            except ValueError as exc:
                raise BagError(f"{source.path}: recorded frame at log time {time_ns} ns: "
                               f"{exc}") from None
            if shown is not None and len(shown.corners):
                points = shown.corners.reshape(-1, 3)
                lo = np.minimum(lo, points.min(axis=0))
                hi = np.maximum(hi, points.max(axis=0))
                for k in solid:
                    e = obstacle_extent(shown.obstacles[k], lo, hi)
                    extents[k][0] = np.minimum(extents[k][0], e.min(axis=0))
                    extents[k][1] = np.maximum(extents[k][1], e.max(axis=0))
                planes = tuple(o for o in shown.obstacles if o.type == "plane")
        if shown is None:
            continue                           # as bag_frames: nothing to draw
        source.last_shown_ns = time_ns
        count += 1
    if not count or not np.all(np.isfinite(lo)):
        raise BagError(f"{source.path}: no cloth surface in the recorded cloth/markers")
    source.start_ns, source.end_ns = span
    source.box_points = np.array([lo, hi])
    source.obstacle_extents = [np.array(e) for e in extents.values()]
    source.planes = planes
    return count
