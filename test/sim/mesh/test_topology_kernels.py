"""The compiled topology kernels equal the numpy reference: bitwise for the
topology (hinges, patterns) and for the rest data made of basic operations
in the reference's order (areas, deformation coefficients); the hinge
weights to a few ULP, as the reference's squared edge lengths are an
``np.einsum`` whose summation (order, fused multiply-adds) depends on the
numpy build (test/tolerances.py)."""

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.runtime import compiled as runtime_compiled
from cloth_lod_ros.sim.solve import pattern as solve_pattern, pattern_kernels as pk
from cloth_lod_ros.sim.mesh import topology_kernels as tk
from cloth_lod_ros.sim.physics import elements_kernels
from cloth_lod_ros.sim.mesh import topology
from cloth_lod_ros.sim.physics import elements as physics_elements
from cloth_lod_ros.sim.scene.config import load_scene
from cloth_lod_ros.sim.mesh.topology import MeshError
from cloth_lod_ros.sim.mesh.mesh48 import RestMesh, base_mesh, refine_uniform
from tolerances import assert_close_ulps

pytestmark = [pytest.mark.skipif(not runtime_compiled.available, reason="numba not installed"),
              pytest.mark.usefixtures("kernels_restored")]



def _fresh(mesh):
    return RestMesh(uv=mesh.uv.copy(), triangles=mesh.triangles.copy(),
                    levels=mesh.levels.copy(), width=mesh.width, height=mesh.height)


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape
    assert a.tobytes() == b.tobytes()


def _same_element(name, a, b):
    """Element rest data: bitwise, but the hinge weights (see the module docstring)."""
    if name == "hinge_weight":
        assert_close_ulps(a, b, err_msg=name)
    else:
        _same(a, b)


def _build(mesh, compiled):
    runtime_compiled.use(compiled)
    first = _fresh(mesh)
    hinges_first = first.hinges()                 # then precompute reads them
    elements_first = elements_kernels.precompute(first)
    mesh = _fresh(mesh)
    elements = elements_kernels.precompute(mesh)  # a new mesh: hinges and all in one call
    hinges = mesh.hinges()
    for name in ("edge", "opposite", "triangles", "is_hypotenuse", "boundary_edges"):
        _same(getattr(hinges_first, name), getattr(hinges, name))
    for name in ("triangles", "area", "coef_u", "coef_v", "hinge_vertices", "hinge_weight",
                 "hinge_triangles", "coef_u_cm", "coef_v_cm", "triangles_cm"):
        _same(getattr(elements_first, name), getattr(elements, name))
    storage = solve_pattern.PatternStorage()
    pattern = solve_pattern.SparsePattern(elements.vertex_count,
                                          [elements.triangles, elements.hinge_vertices], storage)
    # What a solver builds: from the mesh's edge structure when compiled.
    assert (elements.edges is not None) == compiled
    from_edges = solve_pattern.SparsePattern(elements.vertex_count,
                                             [elements.triangles, elements.hinge_vertices],
                                             edges=elements.edges,
                                             hinge_triangles=elements.hinge_triangles)
    return hinges, elements, pattern, from_edges


def _check(mesh):
    (h0, e0, p0, q0), (h1, e1, p1, q1) = _build(mesh, False), _build(mesh, True)
    for name in ("indices", "indptr", "diagonal_block", "_all_slots"):
        _same(getattr(p0, name), getattr(q0, name))
        _same(getattr(p0, name), getattr(q1, name))
    for name in ("edge", "opposite", "triangles", "is_hypotenuse", "boundary_edges"):
        _same(getattr(h0, name), getattr(h1, name))
    for name in ("triangles", "area", "coef_u", "coef_v", "hinge_vertices", "hinge_weight",
                 "hinge_triangles", "coef_u_cm", "coef_v_cm", "triangles_cm"):
        _same_element(name, getattr(e1, name), getattr(e0, name))
    assert e0.vertex_count == e1.vertex_count
    for name in ("indices", "indptr", "diagonal_block", "_all_slots"):
        _same(getattr(p0, name), getattr(p1, name))
    assert p0.block_count == p1.block_count and p0.shape == p1.shape


@pytest.mark.parametrize("blocks", [(1, 1), (2, 1), (1, 3), (4, 4)])
@pytest.mark.parametrize("level", [0, 1, 2, 3, 4])
def test_uniform_meshes(blocks, level):
    _check(refine_uniform(base_mesh(float(blocks[0]), float(blocks[1]), *blocks), level))


@pytest.mark.parametrize("level", [5, 6])
def test_fine_uniform_meshes(level):
    _check(refine_uniform(base_mesh(1.0, 1.0, 4, 4), level))


def test_pattern_beyond_the_dense_key_table():
    # n > 2048: the reference takes np.unique instead of its key table.
    mesh = refine_uniform(base_mesh(1.0, 1.0, 4, 4), 7)
    assert mesh.vertex_count ** 2 > solve_pattern._DENSE_KEYS
    _check(mesh)


@pytest.mark.parametrize("scene", ["hang_two_corners", "grasp_lift"])
def test_graded_meshes_of_an_adaptive_run(scene):
    sim = ClothSim(load_scene(scene, []))
    meshes = [sim.mesh]
    adopt = sim._adopt_hierarchy

    def hook():
        adopt()
        meshes.append(sim.mesh)
    sim._adopt_hierarchy = hook
    for _ in range(40):
        sim.step()
    assert any(m.levels.min() != m.levels.max() for m in meshes)
    for mesh in meshes[::3]:
        _check(mesh)


def test_pattern_of_other_element_kinds():
    rng = np.random.default_rng(3)
    kinds = [rng.integers(0, 9, (7, 2)), rng.integers(0, 9, (5, 3)), np.zeros((0, 4), np.int64)]
    out = []
    for compiled in (False, True):
        runtime_compiled.use(compiled)
        out.append(solve_pattern.SparsePattern(9, kinds))
    for name in ("indices", "indptr", "diagonal_block", "_all_slots"):
        _same(getattr(out[0], name), getattr(out[1], name))


def test_errors_and_fallbacks_are_the_reference_ones():
    runtime_compiled.use(True)
    bad = np.array([[0, 1, 2], [0, 1, 2]])        # the same orientation twice
    with pytest.raises(MeshError, match="orientation"):
        tk.build_hinges(bad, 3)
    with pytest.raises(MeshError, match="non-manifold"):
        tk.build_hinges(np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [1, 0, 5]]), 6)
    with pytest.raises(IndexError):                # an index outside [0, n): the reference's
        solve_pattern.SparsePattern(3, [np.array([[0, 1, 5]])])
    hinges = tk.build_hinges(np.array([[0, 1, 2]], dtype=np.int32), 3)   # other dtype
    reference = topology.build_hinges(np.array([[0, 1, 2]]), 3)
    _same(hinges.boundary_edges, reference.boundary_edges)


def test_pattern_from_edges_falls_back_when_the_structure_does_not_fit():
    runtime_compiled.use(True)
    elements = elements_kernels.precompute(refine_uniform(base_mesh(1.0, 1.0, 2, 2), 2))
    kinds = [elements.triangles, elements.hinge_vertices]
    reference = solve_pattern.SparsePattern(elements.vertex_count, kinds)
    ends, half_edge, corner = elements.edges
    slots = np.empty(len(reference._owned), np.int64)
    assert pk._edge_pattern(elements.vertex_count, kinds[0], kinds[1],
                            elements.hinge_triangles, ends, half_edge, corner, slots)[0]
    extra = np.vstack([ends, [[0, elements.vertex_count - 1]]])   # an edge no triangle has
    for edges, triangles in (
            ((ends, half_edge, corner), elements.hinge_triangles[:, ::-1]),
            ((ends, half_edge, corner), elements.hinge_triangles + 10**6),
            ((ends, half_edge, corner), np.zeros_like(elements.hinge_triangles)),
            ((ends[::-1].copy(), half_edge, corner), elements.hinge_triangles),
            ((ends + 1, half_edge, corner), elements.hinge_triangles),
            ((extra, half_edge, corner), elements.hinge_triangles),
            ((ends, np.roll(half_edge, 1), corner), elements.hinge_triangles),
            ((ends, half_edge, (corner + 1) % 3), elements.hinge_triangles)):
        assert not pk._edge_pattern(elements.vertex_count, kinds[0], kinds[1],
                                    np.ascontiguousarray(triangles), *edges, slots)[0]
        pattern = solve_pattern.SparsePattern(elements.vertex_count, kinds, edges=edges,
                                              hinge_triangles=triangles)
        for name in ("indices", "indptr", "diagonal_block", "_all_slots"):
            _same(getattr(reference, name), getattr(pattern, name))


def test_numpy_switch_uses_the_reference(monkeypatch):
    runtime_compiled.use(False)
    mesh = base_mesh(1.0, 1.0, 1, 1)
    monkeypatch.setattr(elements_kernels, "_element_data", None)
    monkeypatch.setattr(tk, "_hinges", None)
    monkeypatch.setattr(pk, "_pattern", None)
    monkeypatch.setattr(pk, "_edge_pattern", None)
    elements = elements_kernels.precompute(mesh)
    _same(elements.area, physics_elements.precompute(_fresh(mesh)).area)
    assert pk.sparse_pattern(4, [elements.triangles], np.empty(81, np.int64)) is None
