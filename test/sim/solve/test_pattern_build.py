"""Topology-change builds equal their straightforward definitions.

:class:`~cloth_lod_ros.sim.solve.pattern.SparsePattern` computes pair keys and entry
slots by row gathers and :func:`~cloth_lod_ros.sim.mesh.topology.build_hinges` groups
sorted keys without ``np.unique``; both must give what the plain broadcast /
``np.unique`` formulation gives, on random meshes and element lists.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim.physics.elements import precompute
from cloth_lod_ros.sim.mesh.hierarchy import Hierarchy48
from cloth_lod_ros.sim.solve.pattern import PatternStorage, SparsePattern
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh
from cloth_lod_ros.sim.mesh.topology import build_hinges


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 40), counts=st.lists(st.integers(0, 30), min_size=1, max_size=3),
       seed=st.integers(0, 2**16))
def test_pattern_slots_match_definition(n, counts, seed):
    rng = np.random.default_rng(seed)
    elements = [rng.integers(0, n, (c, k)) for c, k in zip(counts, (3, 4, 2))]
    p = SparsePattern(n, elements)
    rows = np.repeat(np.arange(n), np.diff(p.indptr))
    block_of = {(r, c): b for b, (r, c) in enumerate(zip(rows.tolist(), p.indices.tolist()))}
    expect = [9 * block_of[(v[i], v[j])] + 3 * a + b
              for v in elements for v in v.tolist()
              for i in range(len(v)) for a in range(3) for j in range(len(v)) for b in range(3)]
    np.testing.assert_array_equal(p._all_slots, np.array(expect, dtype=np.int64))
    np.testing.assert_array_equal(p.diagonal_block, [block_of[(i, i)] for i in range(n)])
    pairs = {(i, i) for i in range(n)} | {(v[i], v[j]) for e in elements for v in e.tolist()
                                          for i in range(len(v)) for j in range(len(v))}
    assert set(block_of) == pairs


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16), refinements=st.integers(0, 30))
def test_build_hinges_matches_unique_grouping(seed, refinements):
    base = base_mesh(1.0, 1.0, 2, 2)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(base.vertex_count)]), 1.0, 6)
    rng = np.random.default_rng(seed)
    for _ in range(refinements):
        tids = h.active_triangles()
        h.refine(int(tids[rng.integers(len(tids))]))
    mesh = h.active_mesh()[0]
    hinges = build_hinges(mesh.triangles, mesh.vertex_count)
    # Reference: np.unique's groups of the sorted half-edge keys.
    t = mesh.triangles
    start, end = t.ravel(), np.roll(t, -1, axis=1).ravel()
    keys = np.minimum(start, end) * (mesh.vertex_count + 1) + np.maximum(start, end)
    order = np.argsort(keys, kind="stable")
    _, first, counts = np.unique(keys[order], return_index=True, return_counts=True)
    np.testing.assert_array_equal(hinges.edge, np.column_stack(
        [start[order[first[counts == 2]]], end[order[first[counts == 2]]]]))
    np.testing.assert_array_equal(hinges.triangles[:, 1], order[first[counts == 2] + 1] // 3)
    assert len(hinges.boundary_edges) == np.count_nonzero(counts == 1)
    assert len(precompute(mesh).hinge_vertices) == len(hinges.edge)


def test_build_hinges_of_no_triangles():
    hinges = build_hinges(np.zeros((0, 3), dtype=np.int64), 0)
    assert hinges.edge.shape == (0, 2) and hinges.boundary_edges.shape == (0, 2)


@settings(max_examples=30, deadline=None)
@given(sizes=st.lists(st.tuples(st.integers(1, 30), st.integers(1, 25), st.integers(0, 25)),
                      min_size=2, max_size=6),
       seed=st.integers(0, 2**16))
def test_pattern_on_retired_storage_equals_fresh(sizes, seed):
    """A chain of patterns sharing one PatternStorage (each built on its
    predecessor's retired slots and the shared rank table, as the solver does
    at topology changes) equals patterns built fresh, and a retired pattern
    refuses to assemble."""
    rng = np.random.default_rng(seed)
    storage, previous = PatternStorage(), None
    for n, tris, hinges in sizes:
        elements = [rng.integers(0, n, (tris, 3)), rng.integers(0, n, (hinges, 4))]
        fresh = SparsePattern(n, elements)
        if previous is not None:
            previous.retire(storage)
        reused = SparsePattern(n, elements, storage=storage)
        np.testing.assert_array_equal(reused._all_slots, fresh._all_slots)
        np.testing.assert_array_equal(reused.indices, fresh.indices)
        np.testing.assert_array_equal(reused.indptr, fresh.indptr)
        np.testing.assert_array_equal(reused.diagonal_block, fresh.diagonal_block)
        blocks = [rng.random((tris, 3, 3, 3, 3)), rng.random((hinges, 4, 3, 4, 3))]
        diagonal = rng.random(n)
        a, b = fresh.assemble(blocks, diagonal), reused.assemble(blocks, diagonal)
        np.testing.assert_array_equal(a.toarray(), b.toarray())
        if previous is not None:
            with pytest.raises(RuntimeError):
                previous.assemble(blocks, diagonal)
        previous = reused
