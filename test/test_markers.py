"""Vectorised ROS messages: the CDR bytes decode to the field-by-field message.

These tests need rclpy and the message packages (installed by the test extras);
they fail, never skip, when those are missing.
"""

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from geometry_msgs.msg import Point
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from cloth_lod_ros.messages.markers import (DELETEALL, LINE_LIST, SPHERE_LIST, TRIANGLE_LIST,
                                   MarkerSpec, cloth_markers, level_colours,
                                   marker_array_message, serialize_marker_array,
                                   serialize_point_cloud, surface_levels, unique_edges)
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform


def assert_same_message(raw: bytes, reference, msg_type):
    """``raw`` encodes exactly ``reference``.  (Byte equality with rclpy's own
    serialisation is not a usable test: it leaves alignment padding
    uninitialised, so one message serialised twice can differ.)"""
    assert len(raw) == len(serialize_message(reference))
    assert deserialize_message(raw, msg_type) == reference


def reference_marker(spec: MarkerSpec) -> Marker:
    """The same marker built field by field with rclpy objects."""
    m = Marker()
    m.header.frame_id = spec.frame_id
    m.header.stamp.sec, m.header.stamp.nanosec = spec.stamp
    m.ns, m.id, m.type, m.action = spec.ns, spec.id, spec.type, spec.action
    p, q = m.pose.position, m.pose.orientation
    p.x, p.y, p.z = map(float, spec.position)
    q.x, q.y, q.z, q.w = map(float, spec.orientation)
    m.scale.x, m.scale.y, m.scale.z = map(float, spec.scale)
    # float32 fields hold Python floats until serialised: round like the wire does.
    r, g, b, a = map(float, np.asarray(spec.color, np.float32))
    m.color = ColorRGBA(r=r, g=g, b=b, a=a)
    m.frame_locked = spec.frame_locked
    m.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in spec.points]
    m.colors = [ColorRGBA(r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3]))
                for c in np.asarray(spec.colors, np.float32)]
    return m


def small_cloth(level=2, seed=0):
    mesh = refine_uniform(base_mesh(1.0, 1.0, 4, 4), level)
    rng = np.random.default_rng(seed)
    x = np.column_stack([mesh.uv, rng.normal(scale=0.05, size=mesh.vertex_count)])
    return mesh, x


@pytest.mark.parametrize("level,delete_all,grasps", [(0, False, None), (2, True, 2),
                                                      (3, False, 1)])
def test_marker_array_bytes_encode_the_reference_message(level, delete_all, grasps):
    mesh, x = small_cloth(level)
    specs = cloth_markers(x, mesh.triangles, mesh.levels, 6, "cloth_frame", (17, 123456),
                          grasp_points=None if grasps is None else x[:grasps],
                          delete_all_first=delete_all)
    reference = MarkerArray(markers=[reference_marker(s) for s in specs])
    assert_same_message(serialize_marker_array(specs), reference, MarkerArray)


def test_empty_and_odd_strings_round_trip():
    specs = [MarkerSpec("", 0, DELETEALL, ""), MarkerSpec("näme with ünicode", -3, 1, "x/y",
                                                           (-1, 5), frame_locked=True)]
    assert_same_message(serialize_marker_array(specs),
                        MarkerArray(markers=[reference_marker(s) for s in specs]), MarkerArray)
    assert_same_message(serialize_marker_array([]), MarkerArray(), MarkerArray)


def test_cloth_markers_describe_a_valid_mesh():
    mesh, x = small_cloth(4)
    msg = marker_array_message(cloth_markers(x, mesh.triangles, mesh.levels, 6, "world",
                                             grasp_points=x[[0, 5]]))
    surface, wire, grasps = msg.markers
    assert surface.type == TRIANGLE_LIST and len(surface.points) == 3 * mesh.triangle_count
    assert len(surface.colors) == len(surface.points)
    pts = np.array([[p.x, p.y, p.z] for p in surface.points])
    np.testing.assert_allclose(pts, x[mesh.triangles].reshape(-1, 3))
    assert np.all(np.isfinite(pts))
    assert wire.type == LINE_LIST and len(wire.points) % 2 == 0
    # Each mesh edge exactly once: V - E + F = 1 for a disc.
    assert mesh.vertex_count - len(wire.points) // 2 + mesh.triangle_count == 1
    assert grasps.type == SPHERE_LIST and len(grasps.points) == 2
    assert all(m.header.frame_id == "world" for m in msg.markers)


def test_unique_edges_keep_the_finest_level():
    tri = np.array([[0, 1, 2], [2, 1, 3]])
    edges, level = unique_edges(tri, np.array([1, 2]))
    assert len(edges) == 5
    shared = np.flatnonzero((edges == [1, 2]).all(axis=1))
    assert level[shared[0]] == 2


def test_level_colours_span_the_scale():
    c = level_colours(np.arange(7), 6)
    assert c.shape == (7, 3) and np.all((c >= 0) & (c <= 1))
    assert np.all(np.diff(c.sum(axis=1)) > 0)        # dark to bright


@pytest.mark.parametrize("max_level", [2, 6, 12])
def test_surface_levels_decode_the_level_colours_of_a_recorded_surface(max_level):
    """``cloth-lod view`` reads the levels back from a recorded surface marker:
    the float32 colours on the wire, divided by the shading, give them exactly."""
    mesh, x = small_cloth(2, seed=max_level)
    levels = np.random.default_rng(max_level).integers(0, max_level + 1, mesh.triangle_count)
    msg = marker_array_message(cloth_markers(x, mesh.triangles, levels, max_level, "world"))
    surface = msg.markers[0]
    corners = np.array([[p.x, p.y, p.z] for p in surface.points]).reshape(-1, 3, 3)
    colours = np.array([[c.r, c.g, c.b] for c in surface.colors[::3]])
    np.testing.assert_array_equal(surface_levels(corners, colours, max_level), levels)
    shaded = cloth_markers(x, mesh.triangles, levels, max_level, "world", colour_by="shading")
    assert surface_levels(corners, shaded[0].colors[::3], max_level) is None


@pytest.mark.parametrize("height", [1, 4])
def test_point_cloud_bytes_encode_the_reference_message(height):
    rng = np.random.default_rng(height)
    points = rng.normal(size=(12, 3))
    raw = serialize_point_cloud(points, "world", (3, 4), height=height)
    msg = PointCloud2()
    msg.header.frame_id = "world"
    msg.header.stamp.sec, msg.header.stamp.nanosec = 3, 4
    msg.height, msg.width = height, 12 // height
    msg.fields = [PointField(name=n, offset=o, datatype=PointField.FLOAT32, count=1)
                  for n, o in (("x", 0), ("y", 4), ("z", 8))]
    msg.is_bigendian = False
    msg.point_step, msg.row_step = 12, 12 * (12 // height)
    msg.data = points.astype("<f4").tobytes()
    msg.is_dense = True
    assert_same_message(raw, msg, PointCloud2)
    back = deserialize_message(raw, PointCloud2)
    decoded = np.frombuffer(bytes(back.data), dtype="<f4").reshape(-1, 3)
    np.testing.assert_allclose(decoded, points.astype(np.float32))
    with pytest.raises(ValueError):
        serialize_point_cloud(points, "world", height=5)


def test_obstacle_markers_match_the_obstacles():
    from scipy.spatial.transform import Rotation

    from cloth_lod_ros.sim.scene.config import load_scene
    from cloth_lod_ros.messages.markers import CUBE, CYLINDER, SPHERE, obstacle_markers
    scene = load_scene("drop_on_sphere")           # sphere + floor plane
    disc = load_scene("drop_on_disc").obstacles[0]
    specs = obstacle_markers(list(scene.obstacles) + [disc], "world")
    msg = marker_array_message(specs)
    ball, floor, table = msg.markers
    assert ball.type == SPHERE and ball.scale.x == pytest.approx(0.5)
    assert floor.type == CUBE and floor.pose.position.z == pytest.approx(-0.255)
    assert table.type == CYLINDER and table.scale.z == pytest.approx(0.04)
    assert len({m.id for m in msg.markers}) == 3
    # A cylinder along x: the marker's +z must map onto the axis.
    from cloth_lod_ros.sim.scene.config import ObstacleConfig
    tilted = ObstacleConfig(type="cylinder", name="c", axis=(1.0, 0.0, 0.0))
    q = obstacle_markers([tilted], "world")[0].orientation
    np.testing.assert_allclose(Rotation.from_quat(q).apply([0, 0, 1]), [1, 0, 0], atol=1e-12)
