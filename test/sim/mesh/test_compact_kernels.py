"""The compiled compact-mesh and holding-patch kernels equal the numpy reference bitwise.

:mod:`cloth_lod_ros.sim.mesh.compact_kernels` replaces
:meth:`~cloth_lod_ros.sim.mesh.hierarchy.Hierarchy48.active_mesh`'s numpy passes and
:func:`cloth_lod_ros.sim.inputs.holding.patch_refresh` at every topology change; both must
give the same arrays (values, dtypes, shapes) as the reference, over random
sequences of refinements and merges and over random patches.  Bitwise on
every CPU: the results are ids, flags and copies of pool values, and the one
float test (a particle within the patch radius) is ``sqrt(du² + dv²)`` in the
reference's order, basic operations that are correctly rounded everywhere
(test/tolerances.py), so the same particles are inside on both paths, even
exactly at the radius.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim.mesh import compact_kernels
from cloth_lod_ros.sim.inputs import holding_kernels
from cloth_lod_ros.sim.runtime import compiled as runtime_compiled
from cloth_lod_ros.sim.inputs.holding import patch_refresh
from cloth_lod_ros.sim.mesh.hierarchy import Hierarchy48
from cloth_lod_ros.sim.mesh.operations import Merge
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh

pytestmark = [pytest.mark.skipif(not runtime_compiled.available, reason="numba not installed"),
              pytest.mark.usefixtures("kernels_restored")]


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape
    assert a.tobytes() == b.tobytes()


def _both_active_meshes(h):
    runtime_compiled.use(False)
    reference = h.active_mesh()
    runtime_compiled.use(True)
    compiled = compact_kernels.active_mesh(h)
    assert compiled is not None
    assert h.active_mesh()[0].triangles.tobytes() == compiled[0].triangles.tobytes()
    return reference, compiled


def _check_active_mesh(h):
    (m0, v0, t0), (m1, v1, t1) = _both_active_meshes(h)
    _same(v0, v1)
    _same(t0, t1)
    for name in ("uv", "triangles", "levels"):
        _same(getattr(m0, name), getattr(m1, name))
    assert (m0.width, m0.height) == (m1.width, m1.height)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), steps=st.integers(1, 40))
def test_active_mesh_through_random_refines_and_merges(seed, steps):
    runtime_compiled.use(True)
    base = base_mesh(2.0, 1.0, 2, 1)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(base.vertex_count)]), 0.2, 5)
    rng = np.random.default_rng(seed)
    _check_active_mesh(h)
    for _ in range(steps):
        mergeable = h.mergeable_edges()
        if mergeable and rng.random() < 0.4:
            h.apply(Merge(mergeable[rng.integers(len(mergeable))]))
        else:
            tids = h.active_triangles()
            h.refine(int(tids[rng.integers(len(tids))]))
        _check_active_mesh(h)


def test_active_mesh_falls_back_on_a_broken_pool():
    base = base_mesh(1.0, 1.0, 1, 1)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(base.vertex_count)]), 0.2, 3)
    runtime_compiled.use(True)
    h.tri[0, 0] = h.vertex_end + 5          # a corner outside the used pool
    assert compact_kernels.active_mesh(h) is None
    with pytest.raises(IndexError):
        h.active_mesh()                     # the reference's error
    runtime_compiled.use(False)
    assert compact_kernels.active_mesh(h) is None


def _check_patch(ids, uv, centre, radius, nodes, node):
    runtime_compiled.use(False)
    assert holding_kernels.patch_refresh(ids, uv, centre, radius, nodes, node) is None
    reference = patch_refresh(ids, uv, centre, radius, nodes, node)
    runtime_compiled.use(True)
    compiled = holding_kernels.patch_refresh(ids, uv, centre, radius, nodes, node)
    for a, b in zip(reference, compiled):
        if a is None or b is None:
            assert a is None and b is None
        else:
            _same(a, b)
    # The definition: what stays, what is new, and the pin's compact indices.
    keep, new, vertices, vertex = reference
    inside = ids[np.linalg.norm(uv - centre, axis=1) <= radius + 1e-12]
    stays = np.ones(len(nodes), bool) if node is None else (
        np.isin(nodes, inside) | (nodes == node))
    np.testing.assert_array_equal(keep if keep is not None else np.ones(len(nodes), bool),
                                  stays)
    np.testing.assert_array_equal(ids[new], np.setdiff1d(inside, nodes[np.isin(nodes, ids)]))
    if node is not None:
        held = np.concatenate([nodes[stays], ids[new]])
        np.testing.assert_array_equal(vertices, np.searchsorted(ids, held))
        assert vertex == np.searchsorted(ids, node)
    else:
        assert vertices is None and vertex == -1


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**16), n=st.integers(1, 60), held=st.integers(0, 20),
       radius=st.floats(0.0, 0.8), grasp=st.booleans())
def test_patch_refresh_matches_the_reference(seed, n, held, radius, grasp):
    rng = np.random.default_rng(seed)
    ids = np.sort(rng.choice(3 * n, n, replace=False)).astype(np.int64)
    # A lattice (distances exactly at the radius happen) and random points.
    uv = np.where(rng.random((n, 1)) < 0.5, np.round(rng.random((n, 2)) * 8) / 8,
                  rng.random((n, 2)))
    centre = np.round(rng.random(2) * 4) / 4
    # Held nodes: active ones, inactive ones, duplicates, in any order.
    nodes = rng.integers(0, 3 * n, held).astype(np.int64)
    if held and n:
        nodes[: held // 2] = rng.choice(ids, held // 2)
    node = None if grasp else int(nodes[0] if held else ids[0])
    _check_patch(ids, uv, centre, radius, nodes, node)


def test_patch_refresh_edge_cases():
    ids = np.array([2, 5, 9], dtype=np.int64)
    uv = np.array([[0.0, 0.0], [0.1, 0.0], [1.0, 1.0]])
    for nodes, node in (([], 2), ([9], 9), ([5, 5, 2], 2), ([11, 0], 11), ([2], None)):
        _check_patch(ids, uv, np.zeros(2), 0.1, np.array(nodes, dtype=np.int64), node)
    runtime_compiled.use(True)
    # Inputs the kernel does not take go to the reference.
    assert holding_kernels.patch_refresh(ids, uv, np.zeros(2), 0.1,
                                         np.array([2], dtype=np.int32), 2) is None
    assert holding_kernels.patch_refresh(ids[:0], uv[:0], np.zeros(2), 0.1,
                                         np.zeros(0, dtype=np.int64), None) is None
