"""Analytic obstacles: exact signed distances, normals, poses and contact detection.

Every distance is checked against an independent reference: the plane and the
sphere analytically, the cylinder and the box by projecting onto the solid in a
local frame built here (a convex product set, so the nearest point of an
outside point is the coordinate-wise clamp) and, inside, by the nearest face.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from cloth_lod_ros.sim.scene.config import scene_from_dict
from cloth_lod_ros.sim.contact.obstacles import (Box, Cylinder, Plane, Sphere, make_obstacle,
                                                 quaternion_matrix)
from cloth_lod_ros.sim.contact.contacts import ContactSet, find_contacts

EXAMPLES = settings(max_examples=40, deadline=None)

coord = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False, allow_subnormal=False)
vec3 = st.tuples(coord, coord, coord).map(np.array)
points = st.lists(st.tuples(coord, coord, coord), min_size=1, max_size=40).map(
    lambda p: np.array(p, dtype=float))
length = st.floats(0.05, 1.0, allow_nan=False)
friction = st.floats(0.0, 2.0, allow_nan=False)


def _nonzero(dim: int):
    comp = st.floats(-1.0, 1.0, allow_nan=False, allow_subnormal=False)
    return st.tuples(*[comp] * dim).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.1)


unit3 = _nonzero(3).map(lambda v: v / np.linalg.norm(v))
quaternion = _nonzero(4).map(lambda q: q / np.linalg.norm(q))


# -- obstacle strategies -------------------------------------------------------

planes = st.builds(lambda p, n, s, mu: Plane("plane", mu, p, n * s),
                   vec3, unit3, st.floats(0.2, 5.0), friction)
spheres = st.builds(lambda c, r, mu: Sphere("sphere", mu, c, r), vec3, length, friction)
cylinders = st.builds(lambda c, a, r, hh, mu: Cylinder("cyl", mu, c, a, r, hh),
                      vec3, unit3, length, st.floats(0.005, 1.0), friction)
boxes = st.builds(lambda c, he, q, mu: Box("box", mu, c, np.array(he), q),
                  vec3, st.tuples(length, length, length), quaternion, friction)
any_obstacle = st.one_of(planes, spheres, cylinders, boxes)


# -- independent references ----------------------------------------------------

def _frame(axis: np.ndarray) -> np.ndarray:
    """Columns (e1, e2, axis): an orthonormal right-handed frame (via QR)."""
    helper = np.array([0.3, -0.7, 0.2]) if abs(axis @ [0.3, -0.7, 0.2]) < 0.7 else np.array(
        [0.9, 0.1, 0.4])
    q, _ = np.linalg.qr(np.column_stack([axis, helper, np.cross(axis, helper)]))
    e3 = q[:, 0] * np.sign(q[:, 0] @ axis)
    e1 = q[:, 1]
    e2 = np.cross(e3, e1)
    return np.column_stack([e1, e2, e3])


def ref_plane(ob: Plane, x):
    n = np.asarray(ob.normal) / np.sqrt(np.sum(np.square(ob.normal)))
    phi = np.array([float(np.dot(p - ob.point, n)) for p in x])
    return phi, x - phi[:, None] * n


def ref_sphere(ob: Sphere, x):
    d = x - ob.centre
    r = np.sqrt(np.sum(d * d, axis=1))
    return r - ob.radius


def ref_cylinder(ob: Cylinder, x):
    """Signed distance and (for outside points) nearest surface point."""
    frame = _frame(np.asarray(ob.axis) / np.linalg.norm(ob.axis))
    local = (x - ob.centre) @ frame                       # (e1, e2, axial) coordinates
    rad = np.hypot(local[:, 0], local[:, 1])
    scale = np.where(rad > ob.radius, ob.radius / np.maximum(rad, 1e-300), 1.0)
    clamped = np.column_stack([local[:, 0] * scale, local[:, 1] * scale,
                               np.clip(local[:, 2], -ob.half_height, ob.half_height)])
    out_dist = np.linalg.norm(local - clamped, axis=1)
    in_dist = np.minimum(ob.radius - rad, ob.half_height - np.abs(local[:, 2]))
    phi = np.where(out_dist > 0, out_dist, -in_dist)
    return phi, clamped @ frame.T + ob.centre


def ref_box(ob: Box, x):
    rot = Rotation.from_quat(ob.orientation).as_matrix()
    local = (x - ob.centre) @ rot
    he = np.asarray(ob.half_extents)
    clamped = np.clip(local, -he, he)
    out_dist = np.linalg.norm(local - clamped, axis=1)
    in_dist = np.min(he - np.abs(local), axis=1)
    phi = np.where(out_dist > 0, out_dist, -in_dist)
    return phi, clamped @ rot.T + ob.centre


# -- 1. exact signed distance --------------------------------------------------

@EXAMPLES
@given(ob=planes, x=points)
def test_plane_distance_is_exact(ob, x):
    phi, normal = ob.distance(x)
    ref, _ = ref_plane(ob, x)
    np.testing.assert_allclose(phi, ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(normal, np.broadcast_to(ob.normal / np.linalg.norm(ob.normal),
                                                       x.shape), atol=1e-12)


@EXAMPLES
@given(ob=spheres, x=points)
def test_sphere_distance_is_exact(ob, x):
    phi, _ = ob.distance(x)
    np.testing.assert_allclose(phi, ref_sphere(ob, x), rtol=0, atol=1e-9)


@EXAMPLES
@given(ob=cylinders, x=points)
def test_cylinder_distance_is_exact(ob, x):
    phi, _ = ob.distance(x)
    ref, _ = ref_cylinder(ob, x)
    np.testing.assert_allclose(phi, ref, rtol=0, atol=1e-9)


@EXAMPLES
@given(ob=boxes, x=points)
def test_box_distance_is_exact(ob, x):
    phi, _ = ob.distance(x)
    ref, _ = ref_box(ob, x)
    np.testing.assert_allclose(phi, ref, rtol=0, atol=1e-9)


@EXAMPLES
@given(ob=st.one_of(cylinders, boxes), x=points)
def test_points_on_the_surface_of_cylinder_and_box_are_found_as_such(ob, x):
    """Project random points onto the surface (reference) and query there: φ = 0."""
    ref_phi, foot = (ref_cylinder if isinstance(ob, Cylinder) else ref_box)(ob, x)
    outside = ref_phi > 1e-6
    assume(outside.any())
    phi, _ = ob.distance(foot[outside])
    np.testing.assert_allclose(phi, 0.0, atol=1e-9)


def test_simple_known_values():
    """Hand-computed distances (catch a reference and code sharing a mistake)."""
    box = Box("b", 0.0, np.zeros(3), np.array([1.0, 2.0, 3.0]), np.array([0, 0, 0, 1.0]))
    x = np.array([[0.0, 0, 0], [2.0, 0, 0], [2.0, 3.0, 0], [0.5, 1.9, 0], [4.0, 6.0, 7.0]])
    phi, n = box.distance(x)
    np.testing.assert_allclose(phi, [-1.0, 1.0, np.sqrt(2), -0.1, np.sqrt(9 + 16 + 16)])
    np.testing.assert_allclose(n[1], [1, 0, 0])
    np.testing.assert_allclose(n[2], [np.sqrt(0.5), np.sqrt(0.5), 0])
    np.testing.assert_allclose(n[3], [0, 1, 0])
    # Disc of radius 0.3, half height 0.02, axis x.
    disc = Cylinder("d", 0.0, np.array([1.0, 0, 0]), np.array([2.0, 0, 0]), 0.3, 0.02)
    x = np.array([[1.5, 0, 0], [1.0, 0.5, 0], [1.1, 0, 0.4], [1.0, 0.1, 0], [1.0, 0, 0.29]])
    phi, n = disc.distance(x)
    np.testing.assert_allclose(phi, [0.48, 0.2, np.hypot(0.08, 0.1), -0.02, -0.01])
    np.testing.assert_allclose(n[0], [1, 0, 0])
    np.testing.assert_allclose(n[1], [0, 1, 0])
    np.testing.assert_allclose(n[2], np.array([0.08, 0, 0.1]) / np.hypot(0.08, 0.1))
    np.testing.assert_allclose(np.abs(n[3]), [1, 0, 0], atol=1e-15)  # along == 0: either cap
    np.testing.assert_allclose(n[4], [0, 0, 1])


# -- 2. normals: unit, gradient of φ, and projection onto the surface ----------

def _fd_gradient(ob, x, eps=1e-6):
    grad = np.empty_like(x)
    for k in range(3):
        e = np.zeros(3)
        e[k] = eps
        grad[:, k] = (ob.distance(x + e)[0] - ob.distance(x - e)[0]) / (2 * eps)
    return grad


def _gradient_well_defined(ob, x, margin=1e-3):
    """Points where φ is smooth with a clear margin: away from the surface, the
    medial set inside (two faces equally near) and the cylinder axis."""
    if isinstance(ob, Plane):
        return np.ones(len(x), bool)
    if isinstance(ob, Sphere):
        return np.linalg.norm(x - ob.centre, axis=1) > margin
    if isinstance(ob, Cylinder):
        phi, _ = ref_cylinder(ob, x)
        frame = _frame(np.asarray(ob.axis) / np.linalg.norm(ob.axis))
        local = (x - ob.centre) @ frame
        rad = np.hypot(local[:, 0], local[:, 1])
        q_r, q_a = rad - ob.radius, np.abs(local[:, 2]) - ob.half_height
        inside_ok = (np.abs(q_r - q_a) > margin) & (rad > margin) & (
            np.abs(local[:, 2]) > margin)
        # Outside, φ is C¹ but not C² where the nearest point moves from a face
        # onto the rim (q_r or q_a = 0): a central difference errs by ~ε/|q| there.
        outside_ok = (np.abs(q_r) > margin) & (np.abs(q_a) > margin)
        return (np.abs(phi) > margin) & (((phi > 0) & outside_ok) | ((phi < 0) & inside_ok))
    phi, _ = ref_box(ob, x)
    local = (x - ob.centre) @ Rotation.from_quat(ob.orientation).as_matrix()
    q = np.sort(np.abs(local) - ob.half_extents, axis=1)
    inside_ok = (q[:, 2] - q[:, 1] > margin) & (np.abs(local) > margin).all(axis=1)
    # Outside, φ is C¹ but not C² where the nearest point moves from a face onto
    # an edge (a coordinate at its half extent): a central difference errs there.
    outside_ok = (np.abs(q) > margin).all(axis=1)
    return (np.abs(phi) > margin) & (((phi > 0) & outside_ok) | ((phi < 0) & inside_ok))


@EXAMPLES
@given(ob=any_obstacle, x=points)
def test_normal_is_unit_and_the_gradient_of_phi(ob, x):
    phi, normal = ob.distance(x)
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-12)
    ok = _gradient_well_defined(ob, x)
    assume(ok.any())
    np.testing.assert_allclose(normal[ok], _fd_gradient(ob, x[ok]), atol=1e-5)


@EXAMPLES
@given(ob=any_obstacle, x=points)
def test_stepping_back_along_the_normal_lands_on_the_surface(ob, x):
    phi, normal = ob.distance(x)
    foot = x - phi[:, None] * normal
    np.testing.assert_allclose(ob.distance(foot)[0], 0.0, atol=1e-9)
    if isinstance(ob, (Cylinder, Box)):
        # Outside a convex solid the nearest surface point is unique: the clamp.
        ref_phi, ref_foot = (ref_cylinder if isinstance(ob, Cylinder) else ref_box)(ob, x)
        out = ref_phi > 1e-9
        np.testing.assert_allclose(foot[out], ref_foot[out], atol=1e-9)


# -- 3. box orientation and quaternion_matrix ----------------------------------

@EXAMPLES
@given(he=st.tuples(length, length, length), q=quaternion, c=vec3, p=points)
def test_rotated_box_equals_unrotated_box_on_rotated_points(he, q, c, p):
    rot = Rotation.from_quat(q).as_matrix()
    posed = Box("b", 0.3, c, np.array(he), q)
    straight = Box("b", 0.3, c, np.array(he), np.array([0.0, 0.0, 0.0, 1.0]))
    phi_posed, n_posed = posed.distance(c + p @ rot.T)
    phi_straight, n_straight = straight.distance(c + p)
    np.testing.assert_allclose(phi_posed, phi_straight, atol=1e-9)
    ok = _gradient_well_defined(straight, c + p)   # the normal is unique there
    np.testing.assert_allclose(n_posed[ok], n_straight[ok] @ rot.T, atol=1e-9)


@EXAMPLES
@given(q=_nonzero(4), scale=st.floats(0.2, 10.0))
def test_quaternion_matrix_is_a_rotation_matching_scipy(q, scale):
    m = quaternion_matrix(q * scale)                   # also normalises
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(m, Rotation.from_quat(q).as_matrix(), atol=1e-12)


def test_quaternion_matrix_known_rotation():
    # 90 degrees about z, [x, y, z, w] order: x -> y.
    m = quaternion_matrix([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])
    np.testing.assert_allclose(m @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-15)
    np.testing.assert_allclose(quaternion_matrix([0, 0, 0, 1]), np.eye(3))


def test_box_orientation_is_used_in_the_right_direction():
    """A long box (x half extent 1) turned 90 degrees about z lies along y."""
    q = [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)]
    box = Box("b", 0.0, np.zeros(3), np.array([1.0, 0.1, 0.1]), np.array(q))
    phi, n = box.distance(np.array([[0.0, 0.9, 0.0], [0.9, 0.0, 0.0]]))
    np.testing.assert_allclose(phi, [-0.1, 0.8], atol=1e-12)
    np.testing.assert_allclose(n[1], [1.0, 0, 0], atol=1e-12)


# -- 4. find_contacts ----------------------------------------------------------

THICK = 0.01
FLOOR = Plane("floor", 0.2, np.zeros(3), np.array([0.0, 0.0, 1.0]))


def test_band_and_moving_away():
    z = np.array([-0.05, 0.0, 0.005, 0.0199, 0.0201, 0.05, 1.0])
    x = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    for v in (None, np.tile([0.3, -0.2, 1.0], (len(z), 1))):   # at rest / moving away
        cs = find_contacts([FLOOR], x, THICK, velocities=v, h=0.01)
        assert isinstance(cs, ContactSet)
        np.testing.assert_array_equal(cs.indices, [0, 1, 2, 3])
        np.testing.assert_allclose(cs.normals, np.tile([0, 0, 1.0], (4, 1)))
        np.testing.assert_allclose(cs.distance, z[:4] - THICK)
        np.testing.assert_allclose(cs.friction, 0.2)
        assert len(cs) == 4


def test_speculative_contact_for_a_fast_particle():
    x = np.array([[0.0, 0, 0.10], [1.0, 0, 0.10], [2.0, 0, 0.10], [3.0, 0, 0.10]])
    v = np.array([[0.0, 0, -10.0],      # h|v.n| = 0.1: crosses the band -> found
                  [0.0, 0, -7.0],       # 0.1 - 0.07 = 0.03 > 2 thickness -> not yet
                  [50.0, 0, 0.0],       # fast but parallel -> not found
                  [0.0, 0, 10.0]])      # fast away -> not found
    cs = find_contacts([FLOOR], x, THICK, velocities=v, h=0.01)
    np.testing.assert_array_equal(cs.indices, [0])
    np.testing.assert_allclose(cs.distance, [0.10 - THICK])
    assert len(find_contacts([FLOOR], x, THICK, velocities=v, h=0.0)) == 0
    assert len(find_contacts([FLOOR], x, THICK)) == 0


def test_closer_obstacle_wins_normal_and_friction():
    ball = Sphere("ball", 0.9, np.array([0.0, 0, 0.5]), 0.2)
    x = np.array([[0.0, 0.0, 0.295],     # just below the ball, far above the floor
                  [0.0, 0.0, 0.005],     # on the floor
                  [0.0, 0.0, 0.715]])    # on top of the ball
    for order in ([FLOOR, ball], [ball, FLOOR]):
        cs = find_contacts(order, x, THICK)
        np.testing.assert_array_equal(cs.indices, [0, 1, 2])
        np.testing.assert_allclose(cs.normals, [[0, 0, -1.0], [0, 0, 1.0], [0, 0, 1.0]],
                                   atol=1e-12)
        np.testing.assert_allclose(cs.friction, [0.9, 0.2, 0.9])
        np.testing.assert_allclose(cs.distance, [0.005 - THICK, 0.005 - THICK,
                                                 0.015 - THICK], atol=1e-12)


def test_empty_obstacle_list_gives_no_contacts():
    x = np.zeros((5, 3))
    for kwargs in ({}, dict(velocities=np.full((5, 3), -100.0), h=1.0)):
        cs = find_contacts([], x, THICK, **kwargs)
        assert len(cs) == 0
        assert cs.normals.shape == (0, 3)


def _reference_contacts(obstacles, x, thickness, v, h):
    """Per particle: the nearest obstacle (first on a tie), its φ, normal and μ, and
    how near the particle gets this step along that normal."""
    phis, normals = zip(*(ob.distance(x) for ob in obstacles))
    j = np.argmin(np.array(phis), axis=0)
    rows = np.arange(len(x))
    phi = np.array(phis)[j, rows]
    normal = np.array(normals)[j, rows]
    mu = np.array([ob.friction for ob in obstacles])[j]
    reach = phi + h * np.minimum([float(a @ b) for a, b in zip(v, normal)], 0.0)
    return phi, normal, mu, reach


@EXAMPLES
@given(obstacles=st.lists(any_obstacle, min_size=1, max_size=3), x=points,
       data=st.data(), thickness=st.floats(0.001, 0.2), h=st.floats(0.0, 0.1))
def test_find_contacts_matches_a_per_particle_reference(obstacles, x, data, thickness, h):
    n = len(x)
    v = np.array(data.draw(st.lists(st.tuples(*[st.floats(-30, 30)] * 3),
                                    min_size=n, max_size=n)), dtype=float).reshape(n, 3)
    exclude = np.array(sorted(data.draw(st.sets(st.integers(0, n - 1)))), dtype=int)
    cs = find_contacts(obstacles, x, thickness, exclude=exclude, velocities=v, h=h)
    found = set(cs.indices.tolist())
    excluded = set(exclude.tolist())
    assert not found & excluded
    assert np.all(np.diff(cs.indices) > 0)
    phi, normal, mu, reach = _reference_contacts(obstacles, x, thickness, v, h)
    # A particle within rounding of the band's edge may go either way.
    inside = set(np.flatnonzero(reach < 2 * thickness - 1e-9).tolist()) - excluded
    outside = set(np.flatnonzero(reach > 2 * thickness + 1e-9).tolist())
    assert inside <= found
    assert not found & outside
    idx = cs.indices
    np.testing.assert_allclose(cs.normals, normal[idx], atol=1e-12)
    np.testing.assert_allclose(cs.distance, phi[idx] - thickness, atol=1e-12)
    np.testing.assert_allclose(cs.friction, mu[idx])
    # The exclusion removes exactly the excluded particles.
    full = find_contacts(obstacles, x, thickness, velocities=v, h=h)
    assert found == set(full.indices.tolist()) - excluded


def test_excluded_particles_never_returned():
    x = np.array([[0.0, 0, 0.0], [1.0, 0, 0.0], [2.0, 0, -0.5], [3.0, 0, 0.001]])
    cs = find_contacts([FLOOR], x, THICK, exclude=np.array([0, 2]))
    np.testing.assert_array_equal(cs.indices, [1, 3])
    cs = find_contacts([FLOOR], x, THICK, exclude=np.array([], dtype=int))
    np.testing.assert_array_equal(cs.indices, [0, 1, 2, 3])


def test_contact_set_subset_keeps_rows_together():
    x = np.array([[0.0, 0, 0.001], [1.0, 0, 0.002], [2.0, 0, 0.003]])
    cs = find_contacts([FLOOR], x, THICK)
    sub = cs.subset(np.array([True, False, True]))
    np.testing.assert_array_equal(sub.indices, [0, 2])
    np.testing.assert_allclose(sub.distance, [0.001 - THICK, 0.003 - THICK])
    assert sub.normals.shape == (2, 3) and sub.friction.shape == (2,)


# -- 5. make_obstacle from scene configuration ---------------------------------

def _scene(obstacles):
    return scene_from_dict({
        "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [2, 2]},
        "simulation": {"time_step": 0.01, "duration": 0.1},
        "obstacles": obstacles})


def test_make_obstacle_builds_the_right_class_with_the_configured_values():
    scene = _scene([
        {"type": "plane", "centre": [0, 0, 0.1], "normal": [0, 0, 2], "friction": 0.1},
        {"type": "sphere", "centre": [1, 2, 3], "radius": 0.25, "friction": 0.2},
        {"type": "cylinder", "centre": [0, 0, 1], "axis": [1, 0, 0], "radius": 0.3,
         "half_height": 0.5},
        {"type": "disc", "name": "table", "radius": 0.32, "half_height": 0.02},
        {"type": "box", "centre": [0, 0, -0.4], "half_extents": [0.5, 0.6, 0.4],
         "orientation": [0, 0, 1, 1]},
    ])
    built = [make_obstacle(cfg) for cfg in scene.obstacles]
    assert [type(b) for b in built] == [Plane, Sphere, Cylinder, Cylinder, Box]
    assert [b.name for b in built] == ["plane0", "sphere1", "cylinder2", "table", "box4"]
    assert [b.friction for b in built] == [0.1, 0.2, 0.3, 0.3, 0.3]
    probe = np.array([[0.0, 0.0, 2.0]])
    phis = [float(b.distance(probe)[0][0]) for b in built]
    expected = [1.9, np.sqrt(1 + 4 + 1) - 0.25, np.hypot(0.0, 1.0) - 0.3, 2.0 - 0.02, 2.0]
    np.testing.assert_allclose(phis, expected, atol=1e-12)
    np.testing.assert_allclose(built[0].distance(probe)[1][0], [0, 0, 1])
    np.testing.assert_allclose(built[2].axis, [1, 0, 0])
    np.testing.assert_allclose(quaternion_matrix(built[4].orientation),
                               Rotation.from_quat([0, 0, 1, 1]).as_matrix(), atol=1e-12)


def test_make_obstacle_refuses_an_unknown_type():
    cfg = _scene([{"type": "sphere"}]).obstacles[0]
    with pytest.raises(ValueError, match="torus"):
        make_obstacle(dataclasses.replace(cfg, type="torus"))


def test_rounded_box_edges_are_arcs():
    """A box with rounded edges: points off an edge are at (distance to the edge
    axis − rounding), and the normal turns smoothly from the top to the side."""
    from cloth_lod_ros.sim.contact.obstacles import Box
    box = Box("t", 0.2, np.array([0.0, 0.0, -0.4]), np.array([0.5, 0.6, 0.4]),
              np.array([0.0, 0.0, 0.0, 1.0]), rounding=0.03)
    axis_point = np.array([0.47, 0.0, -0.03])            # centre of the edge's arc
    angles = np.linspace(0.0, np.pi / 2, 7)
    pts = axis_point + 0.05 * np.column_stack([np.sin(angles), np.zeros(7), np.cos(angles)])
    phi, normal = box.distance(pts)
    np.testing.assert_allclose(phi, 0.05 - 0.03, atol=1e-12)
    np.testing.assert_allclose(normal, (pts - axis_point) / 0.05, atol=1e-12)
    # Far from the edges it is the plain box.
    phi_top, n_top = box.distance(np.array([[0.0, 0.0, 0.01]]))
    np.testing.assert_allclose(phi_top, [0.01])
    np.testing.assert_allclose(n_top, [[0, 0, 1]])
