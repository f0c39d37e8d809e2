"""Material-point sampling (PointLocator) and distances between point sets."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform
from cloth_lod_ros.sim.mesh.sampling import PointLocator, rms_and_max_distance

SHAPES = {
    "square": (1.0, 1.0, 4, 4),
    "wide": (2.0, 1.0, 4, 2),
    "odd": (0.3, 0.7, 3, 7),          # non-dyadic sizes
}


def make(shape="square", level=3):
    width, height, bu, bv = SHAPES[shape]
    mesh = refine_uniform(base_mesh(width, height, bu, bv), level)
    return mesh, PointLocator(mesh.uv, mesh.triangles, width, height)


def random_positions(n, seed=0):
    return np.random.default_rng(seed).normal(scale=3.0, size=(n, 3))


# -- at vertices ---------------------------------------------------------------

@pytest.mark.parametrize("shape", ["square", "wide"])
@pytest.mark.parametrize("level", [0, 3, 6])
def test_sample_at_vertices_is_exact_for_dyadic_cloths(shape, level):
    mesh, loc = make(shape, level)
    x = random_positions(mesh.vertex_count)
    np.testing.assert_array_equal(loc.sample(x, mesh.uv), x)


@pytest.mark.parametrize("level", [0, 3, 5])
def test_sample_at_vertices_reproduces_positions(level):
    mesh, loc = make("odd", level)
    x = random_positions(mesh.vertex_count, seed=level)
    np.testing.assert_allclose(loc.sample(x, mesh.uv), x, rtol=0, atol=1e-13)
    tri, bary = loc.locate(mesh.uv)
    # The chosen triangle has the vertex as a corner with weight ~1.
    corner = mesh.triangles[tri] == np.arange(mesh.vertex_count)[:, None]
    assert corner.sum(axis=1).tolist() == [1] * mesh.vertex_count
    np.testing.assert_allclose(bary[corner], 1.0, atol=1e-12)


# -- affine maps are reproduced everywhere ----------------------------------------

coord = st.floats(min_value=-5.0, max_value=5.0, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(shape=st.sampled_from(sorted(SHAPES)), level=st.integers(0, 5),
       A=st.lists(coord, min_size=6, max_size=6), c=st.lists(coord, min_size=3, max_size=3),
       fractions=st.lists(st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0)),
                          min_size=1, max_size=20))
def test_affine_map_is_interpolated_exactly(shape, level, A, c, fractions):
    mesh, loc = make(shape, level)
    A = np.array(A).reshape(3, 2)
    c = np.array(c)
    x = mesh.uv @ A.T + c
    points = np.array(fractions) * [mesh.width, mesh.height]
    got = loc.sample(x, points)
    assert got.shape == (len(points), 3)
    np.testing.assert_allclose(got, points @ A.T + c, rtol=0, atol=1e-12)
    tri, bary = loc.locate(points)
    assert np.all(bary >= -1e-9) and np.allclose(bary.sum(axis=1), 1.0, atol=1e-12)
    # The located triangle really contains the point (in the rest plane).
    np.testing.assert_allclose(np.einsum("mk,mkd->md", bary, mesh.uv[mesh.triangles[tri]]),
                               points, atol=1e-12)


def test_nonlinear_field_is_piecewise_linear_between_vertices():
    """Midpoint of an edge samples to the average of its end vertices."""
    mesh, loc = make("square", 2)
    x = random_positions(mesh.vertex_count, seed=3)
    h = mesh.hinges()
    a, b = h.edge[:, 0], h.edge[:, 1]
    mid = 0.5 * (mesh.uv[a] + mesh.uv[b])
    np.testing.assert_allclose(loc.sample(x, mid), 0.5 * (x[a] + x[b]), atol=1e-12)


# -- edges, corners, border ----------------------------------------------------------

@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_border_and_corner_points(shape):
    mesh, loc = make(shape, 2)
    w, h = mesh.width, mesh.height
    A = np.array([[1.0, 2.0], [-0.5, 0.25], [3.0, -1.0]])
    c = np.array([0.1, -0.2, 0.3])
    x = mesh.uv @ A.T + c
    s = np.linspace(0.0, 1.0, 17)
    points = np.vstack([
        [[0, 0], [w, 0], [0, h], [w, h]],                          # corners
        np.column_stack([s * w, np.zeros_like(s)]),                 # bottom
        np.column_stack([s * w, np.full_like(s, h)]),               # top
        np.column_stack([np.zeros_like(s), s * h]),                 # left
        np.column_stack([np.full_like(s, w), s * h]),               # right
        np.column_stack([s * w, s * h]),                            # diagonal
    ])
    np.testing.assert_allclose(loc.sample(x, points), points @ A.T + c, atol=1e-12)


def test_single_point_accepts_1d_input():
    mesh, loc = make("square", 1)
    x = np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)])
    np.testing.assert_allclose(loc.sample(x, [0.25, 0.75]), [[0.25, 0.75, 0.0]], atol=1e-15)


def test_points_within_rounding_of_the_border_are_accepted():
    mesh, loc = make("square", 2)
    x = np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)])
    got = loc.sample(x, [[-1e-12, 0.5], [1.0 + 1e-12, 1.0 + 1e-12]])
    np.testing.assert_allclose(got[:, :2], [[0.0, 0.5], [1.0, 1.0]], atol=1e-11)


# -- refusals ------------------------------------------------------------------------

@pytest.mark.parametrize("point", [[1.5, 0.5], [-0.01, 0.5], [0.5, 1.001], [0.5, -3.0],
                                   [2.0, 2.0]])
def test_point_outside_cloth_is_refused(point):
    mesh, loc = make("square", 2)
    x = random_positions(mesh.vertex_count)
    with pytest.raises(ValueError, match="outside the 1.0 x 1.0 m cloth") as info:
        loc.sample(x, [[0.5, 0.5], point])
    assert str(point[0]) in str(info.value)               # names the bad point


@pytest.mark.parametrize("point", [[np.nan, 0.5], [0.5, np.nan], [np.inf, 0.0],
                                   [0.2, -np.inf]])
def test_non_finite_point_is_refused(point):
    mesh, loc = make("square", 2)
    x = random_positions(mesh.vertex_count)
    with pytest.raises(ValueError, match="finite"):
        loc.sample(x, [point])


def test_wrong_point_shape_is_refused():
    mesh, loc = make("square", 1)
    x = random_positions(mesh.vertex_count)
    with pytest.raises(ValueError, match="shape"):
        loc.sample(x, [[0.1, 0.2, 0.3]])


# -- distances -----------------------------------------------------------------------

def test_rms_and_max_distance_known_values():
    a = np.zeros((4, 3))
    b = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 2.0, 2.0]])
    rms, mx = rms_and_max_distance(a, b)
    # distances 5, 0, 1, 3 -> rms = sqrt((25 + 0 + 1 + 9) / 4)
    assert rms == pytest.approx(np.sqrt(35 / 4), rel=1e-15)
    assert mx == 5.0
    assert isinstance(rms, float) and isinstance(mx, float)
    assert rms_and_max_distance(b, a) == (rms, mx)                  # symmetric
    assert rms_and_max_distance(b, b) == (0.0, 0.0)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(coord, coord, coord), min_size=1, max_size=30),
       st.tuples(coord, coord, coord))
def test_rms_and_max_distance_of_a_translation(points, shift):
    a = np.array(points)
    rms, mx = rms_and_max_distance(a, a + np.array(shift))
    norm = float(np.linalg.norm(shift))
    assert rms == pytest.approx(norm, rel=1e-12, abs=1e-12)
    assert mx == pytest.approx(norm, rel=1e-12, abs=1e-12)
    assert rms <= mx + 1e-15


def test_material_grid_is_row_major_in_v_then_u_and_spans_the_cloth():
    from cloth_lod_ros.sim.mesh.sampling import material_grid
    grid = material_grid(2.0, 1.0, 3).reshape(3, 3, 2)       # [row v, column u]
    np.testing.assert_array_equal(grid[0, :, 0], [0.0, 1.0, 2.0])
    np.testing.assert_array_equal(grid[:, 0, 1], [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(grid[2, 2], [2.0, 1.0])


def test_repeated_queries_follow_the_positions_and_the_points():
    """The located triangles of the last query are kept: sampling the same
    points again follows new positions exactly, a query mutated in place or
    with other points is located anew."""
    mesh, loc = make("odd", 4)
    rng = np.random.default_rng(3)
    points = rng.uniform([0.0, 0.0], [0.3, 0.7], size=(25, 2))
    fresh = PointLocator(mesh.uv, mesh.triangles, 0.3, 0.7)
    for seed in range(3):
        x = random_positions(mesh.vertex_count, seed=seed)
        np.testing.assert_array_equal(loc.sample(x, points), fresh.sample(x, points.copy()))
        fresh = PointLocator(mesh.uv, mesh.triangles, 0.3, 0.7)
    x = random_positions(mesh.vertex_count)
    points[0] = (0.01, 0.02)                       # the caller's array, changed in place
    other = rng.uniform([0.0, 0.0], [0.3, 0.7], size=(7, 2))
    for query in (points, other):
        expected = PointLocator(mesh.uv, mesh.triangles, 0.3, 0.7).sample(x, query)
        np.testing.assert_array_equal(loc.sample(x, query), expected)
