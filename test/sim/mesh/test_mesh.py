"""4-8 meshes: construction, uniform refinement, invariants, hinges, masses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim.mesh.topology import MeshError, build_hinges
from cloth_lod_ros.sim.mesh.mesh48 import (RestMesh, base_mesh, check_mesh, lumped_masses,
                                           refine_uniform, triangle_rest_areas)


def mesh_at(level, width=1.0, height=1.0, bu=4, bv=4) -> RestMesh:
    return refine_uniform(base_mesh(width, height, bu, bv), level)


def interior_mask(mesh: RestMesh) -> np.ndarray:
    u, v = mesh.uv[:, 0], mesh.uv[:, 1]
    return (u > 0) & (u < mesh.width) & (v > 0) & (v < mesh.height)


def corrupt(mesh: RestMesh, **changes) -> RestMesh:
    return dataclasses.replace(mesh, _cache={}, **changes)


# -- counts --------------------------------------------------------------------

def test_base_mesh_counts_and_grid():
    mesh = base_mesh(1.0, 1.0, 4, 4)
    assert mesh.vertex_count == 25
    assert mesh.triangle_count == 32
    assert np.all(mesh.levels == 0)
    grid = np.linspace(0.0, 1.0, 5)
    assert sorted(set(mesh.uv[:, 0])) == list(grid)
    assert sorted(set(mesh.uv[:, 1])) == list(grid)
    assert len({tuple(p) for p in mesh.uv}) == 25           # no duplicates


@pytest.mark.parametrize("level", range(0, 9))
def test_refine_uniform_counts(level):
    base = base_mesh(1.0, 1.0, 4, 4)
    mesh = refine_uniform(base, level)
    assert mesh.triangle_count == 32 * 2**level
    assert np.all(mesh.levels == level)
    assert len({tuple(p) for p in mesh.uv}) == mesh.vertex_count   # midpoints shared
    if level % 2 == 0:
        n = 4 * 2 ** (level // 2) + 1
        assert mesh.vertex_count == n * n
        # It is exactly the regular n x n grid.
        grid = np.linspace(0.0, 1.0, n)
        expected = {(a, b) for a in grid for b in grid}
        assert {tuple(p) for p in np.round(mesh.uv, 12)} == \
            {tuple(p) for p in np.round(np.array(sorted(expected)), 12)}


def test_level_6_is_33_by_33():
    assert mesh_at(6).vertex_count == 33 * 33 == 1089


def test_refine_zero_levels_is_identity_and_refinement_composes():
    base = base_mesh(2.0, 1.0, 4, 2)
    same = refine_uniform(base, 0)
    np.testing.assert_array_equal(same.triangles, base.triangles)
    np.testing.assert_array_equal(same.uv, base.uv)
    two_then_one = refine_uniform(refine_uniform(base, 2), 1)
    three = refine_uniform(base, 3)
    np.testing.assert_array_equal(two_then_one.triangles, three.triangles)
    np.testing.assert_array_equal(two_then_one.uv, three.uv)


# -- check_mesh on valid meshes -------------------------------------------------

@pytest.mark.parametrize("level", range(0, 8))
def test_check_mesh_passes_square(level):
    check_mesh(mesh_at(level))


@pytest.mark.parametrize("width, height, bu, bv", [
    (2.0, 1.0, 4, 2), (1.0, 3.0, 1, 3), (0.3, 0.7, 3, 7), (5.0, 1.0, 5, 1),
    (1.0, 1.0, 1, 1), (1.5, 1.0, 3, 2),
])
@pytest.mark.parametrize("level", [0, 1, 2, 5])
def test_check_mesh_passes_rectangles(width, height, bu, bv, level):
    mesh = mesh_at(level, width, height, bu, bv)
    check_mesh(mesh)
    assert mesh.uv[:, 0].min() == 0.0 and mesh.uv[:, 0].max() == width
    assert mesh.uv[:, 1].min() == 0.0 and mesh.uv[:, 1].max() == height


# -- check_mesh on corrupted meshes ---------------------------------------------

@pytest.mark.parametrize("level", [0, 3])
def test_check_mesh_refuses_flipped_triangle(level):
    mesh = mesh_at(level)
    tris = mesh.triangles.copy()
    tris[5, [1, 2]] = tris[5, [2, 1]]                        # clockwise now
    with pytest.raises(MeshError, match="clockwise"):
        check_mesh(corrupt(mesh, triangles=tris))


@pytest.mark.parametrize("level", [0, 3])
@pytest.mark.parametrize("which", ["first", "middle", "last"])
def test_check_mesh_refuses_removed_triangle(level, which):
    mesh = mesh_at(level)
    i = {"first": 0, "middle": mesh.triangle_count // 2, "last": -1}[which]
    keep = np.ones(mesh.triangle_count, dtype=bool)
    keep[i] = False
    with pytest.raises(MeshError):
        check_mesh(corrupt(mesh, triangles=mesh.triangles[keep], levels=mesh.levels[keep]))


def test_check_mesh_refuses_t_junction():
    """Bisect one triangle but not its hypotenuse neighbour: a hanging vertex."""
    mesh = mesh_at(2)
    hinges = mesh.hinges()
    # An interior hypotenuse shared by two triangles (a refinement pair).
    k = np.flatnonzero(hinges.is_hypotenuse.all(axis=1))[0]
    t0 = hinges.triangles[k, 0]
    apex, left, right = mesh.triangles[t0]
    uv = np.vstack([mesh.uv, 0.5 * (mesh.uv[left] + mesh.uv[right])])
    m = len(mesh.uv)
    keep = np.arange(mesh.triangle_count) != t0
    tris = np.vstack([mesh.triangles[keep], [[m, apex, left], [m, right, apex]]])
    levels = np.concatenate([mesh.levels[keep], [3, 3]])
    broken = corrupt(mesh, uv=uv, triangles=tris, levels=levels)
    with pytest.raises(MeshError, match="T-junction"):
        check_mesh(broken)
    # Bisecting the neighbour as well makes it conforming again.
    t1 = hinges.triangles[k, 1]
    a1, l1, r1 = mesh.triangles[t1]
    keep = ~np.isin(np.arange(mesh.triangle_count), [t0, t1])
    tris = np.vstack([mesh.triangles[keep], [[m, apex, left], [m, right, apex]],
                      [[m, a1, l1], [m, r1, a1]]])
    levels = np.concatenate([mesh.levels[keep], [3, 3, 3, 3]])
    check_mesh(corrupt(mesh, uv=uv, triangles=tris, levels=levels))


@pytest.mark.parametrize("delta", [(0.01, 0.0), (0.0, -0.003), (1e-6, 1e-6)])
def test_check_mesh_refuses_moved_vertex(delta):
    mesh = mesh_at(2)
    uv = mesh.uv.copy()
    v = int(np.flatnonzero(interior_mask(mesh))[0])
    uv[v] += delta
    with pytest.raises(MeshError, match="right angle|isosceles"):
        check_mesh(corrupt(mesh, uv=uv))


def test_check_mesh_refuses_wrong_levels():
    mesh = mesh_at(3)
    levels = mesh.levels.copy()
    levels[7] += 1
    with pytest.raises(MeshError, match="2\\*\\*-level"):
        check_mesh(corrupt(mesh, levels=levels))
    with pytest.raises(MeshError):
        check_mesh(corrupt(mesh, levels=mesh.levels[:-1]))


def test_check_mesh_refuses_duplicate_triangle_and_unused_vertex():
    mesh = mesh_at(1)
    with pytest.raises(MeshError):
        check_mesh(corrupt(mesh, triangles=np.vstack([mesh.triangles, mesh.triangles[:1]]),
                           levels=np.concatenate([mesh.levels, [1]])))
    with pytest.raises(MeshError, match="no triangle"):
        check_mesh(corrupt(mesh, uv=np.vstack([mesh.uv, [[0.5, 0.5]]])))


# -- areas and masses ------------------------------------------------------------

@settings(max_examples=40, deadline=None)
@given(side=st.floats(min_value=1e-2, max_value=10.0),
       bu=st.integers(1, 6), bv=st.integers(1, 6), level=st.integers(0, 5),
       density=st.floats(min_value=1e-3, max_value=1e3))
def test_area_and_mass_conservation(side, bu, bv, level, density):
    width, height = side * bu, side * bv
    mesh = refine_uniform(base_mesh(width, height, bu, bv), level)
    areas = triangle_rest_areas(mesh.uv, mesh.triangles)
    assert areas.sum() == pytest.approx(width * height, rel=1e-12, abs=0)
    mass = lumped_masses(mesh.uv, mesh.triangles, density)
    assert mass.shape == (mesh.vertex_count,)
    assert np.all(mass > 0)
    assert mass.sum() == pytest.approx(density * width * height, rel=1e-12, abs=0)
    # Every triangle has 2**-level of a base triangle's area (side**2 / 2).
    np.testing.assert_allclose(areas, 0.5 * side**2 * 2.0**-mesh.levels, rtol=1e-9)
    check_mesh(mesh)


def test_lumped_masses_are_a_third_of_incident_areas():
    mesh = base_mesh(1.0, 1.0, 1, 1)                 # two triangles of 0.5 m^2
    mass = lumped_masses(mesh.uv, mesh.triangles, 3.0)
    # Diagonal corners touch both triangles, the others one.
    counts = np.bincount(mesh.triangles.ravel(), minlength=4)
    np.testing.assert_allclose(mass, counts * 0.5 * 3.0 / 3.0, rtol=1e-15)
    padded = lumped_masses(mesh.uv, mesh.triangles, 3.0, vertex_count=6)
    assert padded.shape == (6,) and np.all(padded[4:] == 0)


def test_rest_areas_are_signed():
    mesh = base_mesh(1.0, 1.0, 2, 2)
    areas = triangle_rest_areas(mesh.uv, mesh.triangles)
    assert np.all(areas > 0)
    flipped = triangle_rest_areas(mesh.uv, mesh.triangles[:, [0, 2, 1]])
    np.testing.assert_array_equal(flipped, -areas)


# -- 4-8 structure ----------------------------------------------------------------

def vertex_degrees(mesh: RestMesh) -> np.ndarray:
    h = build_hinges(mesh.triangles, mesh.vertex_count)
    edges = np.vstack([h.edge, h.boundary_edges])
    return np.bincount(edges.ravel(), minlength=mesh.vertex_count)


@pytest.mark.parametrize("level", range(0, 8))
@pytest.mark.parametrize("shape", [(1.0, 1.0, 4, 4), (2.0, 1.0, 4, 2), (3.0, 1.0, 3, 1)])
def test_interior_valence_is_4_or_8(level, shape):
    mesh = mesh_at(level, *shape)
    deg = vertex_degrees(mesh)[interior_mask(mesh)]
    if len(deg):
        assert set(deg.tolist()) <= {4, 8}
    # Valence (edges) equals the number of incident triangles at interior vertices.
    incident = np.bincount(mesh.triangles.ravel(), minlength=mesh.vertex_count)
    np.testing.assert_array_equal(incident[interior_mask(mesh)], deg)


@pytest.mark.parametrize("level", [0, 1, 2, 3, 6])
def test_hinges_cover_each_interior_edge_once(level):
    mesh = mesh_at(level, 2.0, 1.0, 4, 2)
    h = mesh.hinges()
    assert h is mesh.hinges()                                  # cached
    nv = mesh.vertex_count
    tris = mesh.triangles

    # All undirected edges from the triangles, with how many triangles use them.
    half = np.stack([tris, np.roll(tris, -1, axis=1)], axis=-1).reshape(-1, 2)
    und = np.sort(half, axis=1)
    keys, counts = np.unique(und[:, 0] * nv + und[:, 1], return_counts=True)
    assert set(counts.tolist()) <= {1, 2}
    interior_keys = set(keys[counts == 2].tolist())
    boundary_keys = set(keys[counts == 1].tolist())

    he = np.sort(h.edge, axis=1)
    hinge_keys = (he[:, 0] * nv + he[:, 1]).tolist()
    assert len(hinge_keys) == len(set(hinge_keys))              # each at most once
    assert set(hinge_keys) == interior_keys                     # and all of them
    be = np.sort(h.boundary_edges, axis=1)
    assert set((be[:, 0] * nv + be[:, 1]).tolist()) == boundary_keys
    # Euler: E = 3T/2 + B/2 for a disc.
    assert 2 * len(hinge_keys) + len(boundary_keys) == 3 * mesh.triangle_count

    # Opposite vertices: opposite[:,0] is in triangles[:,0], which traverses
    # edge[0] -> edge[1] counter-clockwise; triangles[:,1] the other way.
    for side, (a, b) in ((0, (0, 1)), (1, (1, 0))):
        t = tris[h.triangles[:, side]]
        e0, e1, opp = h.edge[:, a], h.edge[:, b], h.opposite[:, side]
        # The triangle is (e0, e1, opp) up to rotation.
        rot = [t, np.roll(t, 1, axis=1), np.roll(t, 2, axis=1)]
        target = np.column_stack([e0, e1, opp])
        match = np.zeros(len(t), dtype=bool)
        for r in rot:
            match |= (r == target).all(axis=1)
        assert match.all()
    assert np.all(h.opposite[:, 0] != h.opposite[:, 1])
    assert np.all(h.triangles[:, 0] != h.triangles[:, 1])
    # The opposite vertices lie on opposite sides of the edge in (u, v).
    p0, p1 = mesh.uv[h.edge[:, 0]], mesh.uv[h.edge[:, 1]]
    d = p1 - p0

    def side_of(q):
        w = mesh.uv[q] - p0
        return d[:, 0] * w[:, 1] - d[:, 1] * w[:, 0]
    assert np.all(side_of(h.opposite[:, 0]) > 0)
    assert np.all(side_of(h.opposite[:, 1]) < 0)
    # is_hypotenuse agrees with geometry: the hypotenuse is a triangle's longest edge.
    length = np.linalg.norm(d, axis=1)
    for side in (0, 1):
        t = tris[h.triangles[:, side]]
        legs = np.linalg.norm(mesh.uv[t[:, 1]] - mesh.uv[t[:, 0]], axis=1)
        longest = length > legs * 1.2
        np.testing.assert_array_equal(h.is_hypotenuse[:, side], longest)


def test_build_hinges_refuses_non_manifold_and_inconsistent_orientation():
    tris = np.array([[0, 1, 2], [0, 3, 1], [1, 0, 4]])      # edge 0-1 used three times
    with pytest.raises(MeshError, match="non-manifold"):
        build_hinges(tris, 5)
    tris = np.array([[0, 1, 2], [0, 1, 3]])                  # both run 0 -> 1
    with pytest.raises(MeshError, match="orientation"):
        build_hinges(tris, 4)


# -- base_mesh arguments --------------------------------------------------------

@pytest.mark.parametrize("width, height, bu, bv", [
    (1.0, 1.0, 4, 2), (2.0, 1.0, 4, 4), (1.0, 1.0001, 3, 3),
])
def test_base_mesh_refuses_non_square_blocks(width, height, bu, bv):
    with pytest.raises(MeshError, match="square"):
        base_mesh(width, height, bu, bv)


@pytest.mark.parametrize("bu, bv", [(0, 1), (1, 0), (-1, 2)])
def test_base_mesh_refuses_empty_grid(bu, bv):
    with pytest.raises(MeshError):
        base_mesh(1.0, 1.0, bu, bv)
