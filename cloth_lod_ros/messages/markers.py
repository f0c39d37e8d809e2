"""Cloth state to ROS messages, vectorised (numpy → CDR bytes).

rclpy stores ``geometry_msgs/Point[]`` as a Python list of Point objects, so a
30 000-triangle ``TRIANGLE_LIST`` built field by field means 90 000 Python
objects, which takes seconds.  Here a ``visualization_msgs/MarkerArray`` is
written directly as its CDR serialisation (what rosbag2 and the middleware
carry) with numpy arrays for the bulk fields; ``Publisher.publish`` accepts
those bytes as they are, and :func:`marker_array_message` turns them into a
message object when one is wanted.  The tests check that the bytes decode, with
``rclpy.serialization``, to exactly the message built field by field (byte
equality is not a usable test: rclpy leaves alignment padding uninitialised).

This module imports no ROS package at import time, except in
:func:`marker_array_message` (and the tests).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from ..sim.contact.obstacles import quaternion_from_z

__all__ = ["MarkerSpec", "serialize_marker_array", "marker_array_message",
           "cloth_markers", "obstacle_markers", "level_colours", "unique_edges",
           "surface_shade", "surface_levels",
           "serialize_point_cloud", "TRIANGLE_LIST", "LINE_LIST", "SPHERE_LIST",
           "CUBE", "SPHERE", "CYLINDER", "ADD", "DELETEALL"]

# visualization_msgs/Marker constants (Jazzy).
CUBE, SPHERE, CYLINDER, LINE_LIST, SPHERE_LIST, TRIANGLE_LIST = 1, 2, 3, 5, 7, 11
ADD, DELETEALL = 0, 3


@dataclass
class MarkerSpec:
    """One ``visualization_msgs/Marker`` with numpy bulk fields (SI units).

    Attributes:
        ns, id, type, action: as in the message.
        frame_id: header frame; stamp: ``(sec, nanosec)``.
        position: ``(3,)`` m; orientation: ``(4,)`` quaternion [x, y, z, w].
        scale: ``(3,)``; color: ``(4,)`` RGBA in [0, 1].
        points: ``(k, 3)`` m (float64); colors: ``(k, 4)`` RGBA (float32) or empty.
    """

    ns: str
    id: int
    type: int
    frame_id: str
    stamp: tuple = (0, 0)
    action: int = ADD
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    orientation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    color: np.ndarray = field(default_factory=lambda: np.array([1.0, 1.0, 1.0, 1.0]))
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.float32))
    frame_locked: bool = False


class _CdrWriter:
    """Little-endian plain CDR (XCDR1) with alignment relative to the payload."""

    def __init__(self):
        self.parts = [b"\x00\x01\x00\x00"]          # encapsulation: CDR_LE
        self.pos = 0

    def _align(self, n: int) -> None:
        pad = (-self.pos) % n
        if pad:
            self.parts.append(b"\x00" * pad)
            self.pos += pad

    def _put(self, data: bytes) -> None:
        self.parts.append(data)
        self.pos += len(data)

    def prim(self, fmt: str, *values) -> None:
        size = struct.calcsize("<" + fmt.lstrip("0123456789")[0])   # align to the first item
        self._align(size)
        self._put(struct.pack("<" + fmt, *values))

    def string(self, text: str) -> None:
        data = text.encode() + b"\x00"
        self.prim("I", len(data))
        self._put(data)

    def array(self, values: np.ndarray, dtype, align: int) -> None:
        """A sequence of fixed-size structs given as a contiguous numeric array."""
        arr = np.ascontiguousarray(values, dtype=dtype)
        self.prim("I", len(arr))
        if len(arr):
            self._align(align)
            self._put(arr.tobytes())

    def getvalue(self) -> bytes:
        return b"".join(self.parts)


def _write_header(w: _CdrWriter, stamp: tuple, frame_id: str) -> None:
    w.prim("iI", int(stamp[0]), int(stamp[1]))
    w.string(frame_id)


def _write_marker(w: _CdrWriter, m: MarkerSpec) -> None:
    _write_header(w, m.stamp, m.frame_id)
    w.string(m.ns)
    w.prim("iii", int(m.id), int(m.type), int(m.action))
    w.prim("7d", *np.asarray(m.position, float), *np.asarray(m.orientation, float))
    w.prim("3d", *np.asarray(m.scale, float))
    w.prim("4f", *np.asarray(m.color, float))
    w.prim("iI", 0, 0)                                   # lifetime: forever
    w.prim("?", bool(m.frame_locked))
    w.array(np.asarray(m.points, float).reshape(-1, 3), "<f8", 8)     # Point[]
    w.array(np.asarray(m.colors, float).reshape(-1, 4), "<f4", 4)     # ColorRGBA[]
    w.string("")                                         # texture_resource
    _write_header(w, (0, 0), "")                         # texture: CompressedImage
    w.string("")                                         #   format
    w.prim("I", 0)                                       #   data
    w.prim("I", 0)                                       # uv_coordinates
    w.string("")                                         # text
    w.string("")                                         # mesh_resource
    w.string("")                                         # mesh_file.filename
    w.prim("I", 0)                                       # mesh_file.data
    w.prim("?", False)                                   # mesh_use_embedded_materials


def serialize_marker_array(markers: list[MarkerSpec]) -> bytes:
    """CDR bytes of a ``visualization_msgs/MarkerArray`` (publishable as is)."""
    w = _CdrWriter()
    w.prim("I", len(markers))
    for m in markers:
        _write_marker(w, m)
    return w.getvalue()


def marker_array_message(markers: list[MarkerSpec]):
    """The ``visualization_msgs.msg.MarkerArray`` object (needs rclpy)."""
    from rclpy.serialization import deserialize_message
    from visualization_msgs.msg import MarkerArray
    return deserialize_message(serialize_marker_array(markers), MarkerArray)


# -- colours -------------------------------------------------------------------
# Viridis, sampled at 9 points (matplotlib's table), so no plotting library is
# needed at run time; levels interpolate between them.
_VIRIDIS = np.array([[0.267, 0.005, 0.329], [0.283, 0.141, 0.458], [0.254, 0.265, 0.530],
                     [0.207, 0.372, 0.553], [0.164, 0.471, 0.558], [0.128, 0.567, 0.551],
                     [0.135, 0.659, 0.518], [0.267, 0.749, 0.441], [0.478, 0.821, 0.318],
                     [0.741, 0.873, 0.150], [0.993, 0.906, 0.144]])


def level_colours(levels: np.ndarray, max_level: int) -> np.ndarray:
    """``(t, 3)`` RGB in [0, 1] for bisection levels on a 0..max_level viridis scale."""
    s = np.clip(np.asarray(levels, float) / max(max_level, 1), 0.0, 1.0) * (len(_VIRIDIS) - 1)
    lo = np.floor(s).astype(int)
    hi = np.minimum(lo + 1, len(_VIRIDIS) - 1)
    frac = (s - lo)[:, None]
    return (1 - frac) * _VIRIDIS[lo] + frac * _VIRIDIS[hi]


_LIGHT = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])


def surface_shade(corners: np.ndarray) -> np.ndarray:
    """``(t,)`` brightness in [0.45, 1] of triangles ``corners`` ``(t, 3, 3)``: the
    face normal against a fixed light (the ``surface`` marker's shading)."""
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    return 0.45 + 0.55 * np.abs(normals @ _LIGHT)


def surface_levels(corners: np.ndarray, colours: np.ndarray, max_level: int,
                   tolerance: float = 1e-3) -> np.ndarray | None:
    """The bisection levels a ``surface`` marker coloured by level encodes.

    The inverse of :func:`cloth_markers` with ``colour_by="level"``: each face's
    colour divided by its shade (:func:`surface_shade` of its corners) is one of
    the ``level_colours`` of 0..``max_level``.

    Args:
        corners: ``(t, 3, 3)`` triangle corners, m (the marker's points).
        colours: ``(t, 3)`` RGB of each face (the colour of its first corner).

    Returns:
        ``(t,)`` levels, or None when some face matches no level colour within
        ``tolerance`` (the marker was coloured by shading, or by another palette).
    """
    if not len(corners):
        return np.zeros(0, dtype=np.int64)
    base = np.asarray(colours, float)[:, :3] / surface_shade(np.asarray(corners, float))[:, None]
    palette = level_colours(np.arange(max_level + 1), max_level)
    distance = np.linalg.norm(base[:, None, :] - palette[None, :, :], axis=2)
    levels = distance.argmin(axis=1)
    if distance[np.arange(len(levels)), levels].max() > tolerance:
        return None
    return levels


def unique_edges(triangles: np.ndarray, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each edge once, ``(e, 2)``, with the finest level of its triangles ``(e,)``.

    Depends on the topology only: cache it while the mesh does not change.
    """
    tri = np.asarray(triangles)
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    edge_level = np.tile(levels, 3)
    order = np.lexsort((-edge_level, edges[:, 1], edges[:, 0]))      # finest first
    edges, edge_level = edges[order], edge_level[order]
    first = np.ones(len(edges), dtype=bool)
    first[1:] = np.any(edges[1:] != edges[:-1], axis=1)
    return edges[first], edge_level[first]


def cloth_markers(positions: np.ndarray, triangles: np.ndarray, levels: np.ndarray,
                  max_level: int, frame_id: str, stamp: tuple = (0, 0),
                  grasp_points: np.ndarray | None = None, colour_by: str = "level",
                  wireframe: bool = True, line_width: float = 0.002,
                  delete_all_first: bool = False,
                  edges: tuple | None = None) -> list[MarkerSpec]:
    """Markers of the cloth: surface, wireframe coloured by level, grasp points.

    Args:
        positions: ``(n, 3)`` m; triangles: ``(t, 3)``; levels: ``(t,)``.
        colour_by: ``"level"`` (viridis by level, shaded by the face normal) or
            ``"shading"`` (one cloth colour shaded by the normal).
        delete_all_first: prepend a DELETEALL marker (use when markers may have
            disappeared since the last publish, e.g. grasp points).
        edges: ``unique_edges(triangles, levels)`` if the caller caches it.

    Returns:
        Specs for :func:`serialize_marker_array`: ``surface`` (TRIANGLE_LIST),
        ``wireframe`` (LINE_LIST, optional), ``grasps`` (SPHERE_LIST, optional).
    """
    x = np.asarray(positions, float)
    tri = np.asarray(triangles)
    corners = x[tri]                                            # (t, 3, 3)
    shade = surface_shade(corners)
    if colour_by == "level":
        base = level_colours(levels, max_level)
    else:
        base = np.tile([0.85, 0.45, 0.25], (len(tri), 1))
    face_rgba = np.column_stack([base * shade[:, None], np.ones(len(tri))]).astype(np.float32)
    specs = []
    if delete_all_first:
        specs.append(MarkerSpec("", 0, CUBE, frame_id, stamp, action=DELETEALL))
    specs.append(MarkerSpec("surface", 0, TRIANGLE_LIST, frame_id, stamp,
                            points=corners.reshape(-1, 3),
                            colors=np.repeat(face_rgba, 3, axis=0)))
    if wireframe:
        key, edge_level = edges if edges is not None else unique_edges(tri, levels)
        line_rgba = np.column_stack([level_colours(edge_level, max_level) * 0.6,
                                     np.ones(len(key))]).astype(np.float32)
        specs.append(MarkerSpec("wireframe", 1, LINE_LIST, frame_id, stamp,
                                scale=np.array([line_width, 0.0, 0.0]),
                                points=x[key].reshape(-1, 3),
                                colors=np.repeat(line_rgba, 2, axis=0)))
    if grasp_points is not None and len(grasp_points):
        specs.append(MarkerSpec("grasps", 2, SPHERE_LIST, frame_id, stamp,
                                scale=np.full(3, 0.03),
                                color=np.array([0.85, 0.1, 0.2, 1.0]),
                                points=np.asarray(grasp_points, float).reshape(-1, 3)))
    return specs


def obstacle_markers(obstacles, frame_id: str, stamp: tuple = (0, 0),
                     first_id: int = 10) -> list[MarkerSpec]:
    """One marker per obstacle config (:class:`~cloth_lod_ros.sim.scene.config.ObstacleConfig`;
    for a running simulator, ``ClothSim.obstacle_configs()``: the configs at the
    obstacles' current poses, so the markers follow kinematic obstacles).

    Planes are drawn as a thin 2 m square around their point; cylinders and discs
    as CYLINDER, spheres as SPHERE, boxes as CUBE (rounding not drawn).
    """
    grey = np.array([0.55, 0.58, 0.62, 0.6])
    specs = []
    for k, o in enumerate(obstacles):
        centre = np.asarray(o.centre, float)
        if o.type == "plane":
            q = quaternion_from_z(o.normal)
            normal = np.asarray(o.normal, float) / np.linalg.norm(o.normal)
            spec = MarkerSpec(o.name, first_id + k, CUBE, frame_id, stamp,
                              position=centre - 0.005 * normal, orientation=q,
                              scale=np.array([2.0, 2.0, 0.01]), color=grey)
        elif o.type == "sphere":
            spec = MarkerSpec(o.name, first_id + k, SPHERE, frame_id, stamp, position=centre,
                              scale=np.full(3, 2 * o.radius), color=grey)
        elif o.type in ("cylinder", "disc"):
            spec = MarkerSpec(o.name, first_id + k, CYLINDER, frame_id, stamp,
                              position=centre, orientation=quaternion_from_z(o.axis),
                              scale=np.array([2 * o.radius, 2 * o.radius, 2 * o.half_height]),
                              color=grey)
        else:                                       # box
            spec = MarkerSpec(o.name, first_id + k, CUBE, frame_id, stamp, position=centre,
                              orientation=np.asarray(o.orientation, float),
                              scale=2 * np.asarray(o.half_extents, float), color=grey)
        specs.append(spec)
    return specs


FLOAT32 = 7          # sensor_msgs/PointField.FLOAT32


def serialize_point_cloud(points: np.ndarray, frame_id: str, stamp: tuple = (0, 0),
                          height: int = 1) -> bytes:
    """CDR bytes of a ``sensor_msgs/PointCloud2`` with float32 fields x, y, z.

    Args:
        points: ``(n, 3)`` m.  With ``height`` > 1 the cloud is *organised*:
            ``n = height × width`` points in row-major order (a (u, v) grid).
    """
    pts = np.ascontiguousarray(np.asarray(points, float).reshape(-1, 3), dtype="<f4")
    if len(pts) % height:
        raise ValueError(f"{len(pts)} points do not make {height} rows")
    width = len(pts) // height
    w = _CdrWriter()
    _write_header(w, stamp, frame_id)
    w.prim("II", height, width)
    w.prim("I", 3)                                         # fields
    for offset, name in ((0, "x"), (4, "y"), (8, "z")):
        w.string(name)
        w.prim("I", offset)
        w.prim("B", FLOAT32)
        w.prim("I", 1)
    w.prim("?", False)                                     # is_bigendian
    w.prim("II", 12, 12 * width)                           # point_step, row_step
    w.array(pts.view(np.uint8).reshape(-1), np.uint8, 1)   # data
    w.prim("?", bool(np.all(np.isfinite(pts))))            # is_dense
    return w.getvalue()


def _benchmark(levels=(6, 8), repeats: int = 10) -> None:
    """Print marker and point-cloud build times (``python -m cloth_lod_ros.messages.markers``)."""
    import time

    from ..sim.mesh.mesh48 import base_mesh, refine_uniform
    for level in levels:
        mesh = refine_uniform(base_mesh(1.0, 1.0, 4, 4), level)
        x = np.column_stack([mesh.uv, 0.1 * np.sin(3 * mesh.uv[:, 0])])
        start = time.perf_counter()
        for _ in range(repeats):
            edges = unique_edges(mesh.triangles, mesh.levels)
        edge_ms = 1e3 * (time.perf_counter() - start) / repeats
        start = time.perf_counter()
        for _ in range(repeats):
            raw = serialize_marker_array(cloth_markers(x, mesh.triangles, mesh.levels, level,
                                                       "world", edges=edges))
        marker_ms = 1e3 * (time.perf_counter() - start) / repeats
        start = time.perf_counter()
        for _ in range(repeats):
            cloud = serialize_point_cloud(x, "world")
        cloud_ms = 1e3 * (time.perf_counter() - start) / repeats
        print(f"level {level}: {mesh.triangle_count} triangles: markers {marker_ms:.1f} ms "
              f"({len(raw) / 1e6:.2f} MB), wireframe edges on a topology change "
              f"{edge_ms:.1f} ms, points {cloud_ms:.2f} ms ({len(cloud) / 1e3:.1f} kB)")


if __name__ == "__main__":  # pragma: no cover
    _benchmark()
