"""The hierarchy's incrementally kept bookkeeping equals a from-scratch rebuild.

``Hierarchy48`` updates its edge index (sorted vertex pair -> active
triangles), mass units, midpoint map and parent/child links one split or merge
at a time on Python scalars.  After random sequences of refinements and merges
each of them must equal what the active triangles define, and a merge's
velocity change must be :func:`~cloth_lod_ros.sim.mesh.hierarchy.merge_velocity_change`
bit for bit (the merge writes it out for one edge).
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim.mesh.hierarchy import Hierarchy48, merge_velocity_change
from cloth_lod_ros.sim.mesh.operations import Merge
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh


def _make(seed: int, max_level: int = 6) -> Hierarchy48:
    base = base_mesh(1.0, 1.0, 2, 2)
    rng = np.random.default_rng(seed)
    pos = np.column_stack([base.uv, 0.05 * rng.standard_normal(base.vertex_count)])
    h = Hierarchy48(base, pos, 0.3, max_level)
    h.v[:h.vertex_end] = rng.standard_normal((h.vertex_end, 3))
    return h


def _rebuilt_edges(h: Hierarchy48) -> dict:
    edges: dict = {}
    for t in h.active_triangles().tolist():
        a, b, c = h.tri[t].tolist()
        for e in ((a, b), (b, c), (c, a)):
            edges.setdefault((min(e), max(e)), set()).add(t)
    return edges


def _check_against_rebuild(h: Hierarchy48) -> None:
    assert {e: set(ts) for e, ts in h._edges.items()} == _rebuilt_edges(h)
    tids = h.active_triangles()
    units = np.bincount(h.tri[tids].ravel(), weights=np.repeat(2.0 ** -h.level[tids], 3),
                        minlength=h.vertex_end)
    np.testing.assert_array_equal(h.mass_units[:h.vertex_end], units)
    used = np.zeros(h.vertex_end, dtype=bool)
    used[h.tri[tids].ravel()] = True
    np.testing.assert_array_equal(h.vertex_active[:h.vertex_end], used)
    for edge, m in h.midpoint.items():
        assert tuple(h.vertex_edge[m].tolist()) == edge
        parents = [t for t in h.vertex_parents[m].tolist() if t >= 0]
        assert len(parents) == len(h._edges.get(edge, ())) or not h.tri_active[parents].any()
        for t in parents:
            kids = h.children[t].tolist()
            assert h.parent[kids].tolist() == [t, t]
            assert not h.tri_active[t]
    h.check()


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), data=st.data())
def test_incremental_bookkeeping_equals_rebuild(seed, data):
    h = _make(seed)
    rng = np.random.default_rng(seed)
    for _ in range(data.draw(st.integers(1, 25), label="operations")):
        if rng.random() < 0.6 or not h.mergeable_edges():
            tids = h.active_triangles()
            h.refine(int(tids[rng.integers(len(tids))]), time=0.1)
        else:
            edges = h.mergeable_edges()
            edge = edges[rng.integers(len(edges))]
            m = h.midpoint[edge]
            left, right = edge
            before = h.v.copy()
            mass_m = h.mass_units[m]
            h.apply(Merge(edge), time=0.2)
            change = merge_velocity_change(mass_m, h.mass_units[left] + h.mass_units[right],
                                           before[m], before[left], before[right])
            np.testing.assert_array_equal(h.v[left], before[left] + change)
            np.testing.assert_array_equal(h.v[right], before[right] + change)
        _check_against_rebuild(h)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_undo_restores_every_pool_array(seed):
    """Refinements undone by their inverses leave every pool array bit for bit."""
    h = _make(seed)
    rng = np.random.default_rng(seed)
    for _ in range(4):
        tids = h.active_triangles()
        h.refine(int(tids[rng.integers(len(tids))]))
    names = ("uv", "x", "v", "mass_units", "vertex_active", "tri", "level", "tri_active",
             "children")
    snapshot = {n: getattr(h, n).copy() for n in names}
    edges = {e: list(ts) for e, ts in h._edges.items()}
    ops = []
    for _ in range(6):
        tids = h.active_triangles()
        ops += h.refine(int(tids[rng.integers(len(tids))]), time=1.0)
    for op in reversed(ops):
        h.apply(op.inverse(), time=2.0)
    np.testing.assert_array_equal(h.vertex_active[:len(snapshot["vertex_active"])],
                                  snapshot["vertex_active"])
    live = np.flatnonzero(snapshot["vertex_active"])     # freed slots keep stale uv
    for n in ("uv", "x", "v", "mass_units"):
        np.testing.assert_array_equal(getattr(h, n)[live], snapshot[n][live], err_msg=n)
    tids = h.active_triangles()
    np.testing.assert_array_equal(tids, np.flatnonzero(snapshot["tri_active"]))
    np.testing.assert_array_equal(h.tri[tids], snapshot["tri"][tids])
    np.testing.assert_array_equal(h.children[tids], snapshot["children"][tids])
    assert {e: set(ts) for e, ts in h._edges.items()} == {e: set(ts) for e, ts in edges.items()}
    _check_against_rebuild(h)
