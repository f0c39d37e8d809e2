"""The run-time 4-8 hierarchy: split/merge as invertible, conservative operations.

A hypothesis state machine drives random refine / merge / perturbed-merge / undo
sequences on several bases and maximum levels and checks the mesh, mass,
momentum and topology invariants after every step; deterministic tests cover
forced splits, precondition errors, uniform refinement and pool growth.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.stateful import (
    RuleBasedStateMachine, initialize, invariant, rule,
)

from cloth_lod_ros.sim.mesh import mesh48
from cloth_lod_ros.sim.mesh.hierarchy import Hierarchy48
from cloth_lod_ros.sim.mesh.operations import Merge, Split
from cloth_lod_ros.sim.mesh.topology import MeshError
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, lumped_masses, triangle_rest_areas

# (width, height, blocks_u, blocks_v): all with square blocks.
BASES = [(1.0, 1.0, 4, 4), (2.0, 1.0, 2, 1), (1.0, 1.0, 3, 3)]


# -- helpers ---------------------------------------------------------------------

def make(width=1.0, height=1.0, bu=4, bv=4, max_level=5, density=0.3, seed=0,
         planar=False) -> Hierarchy48:
    base = base_mesh(width, height, bu, bv)
    rng = np.random.default_rng(seed)
    pos = np.column_stack([base.uv, np.zeros(base.vertex_count)])
    if not planar:
        pos = pos + 0.1 * rng.standard_normal(pos.shape)
    h = Hierarchy48(base, pos, density, max_level)
    if not planar:
        h.v[:h.vertex_end] = rng.standard_normal((h.vertex_end, 3))
    return h


def snapshot(h: Hierarchy48) -> dict:
    """Everything a caller sees of the active mesh, copied."""
    mesh, vids, tids = h.active_mesh()
    return dict(tris=mesh.triangles.copy(), levels=mesh.levels.copy(),
                vids=vids.copy(), tids=tids.copy(), uv=h.uv[vids].copy(),
                x=h.x[vids].copy(), v=h.v[vids].copy(), masses=h.masses[vids].copy())


def assert_same(a: dict, b: dict) -> None:
    for key in a:
        assert a[key].shape == b[key].shape, key
        assert np.array_equal(a[key], b[key]), key


def momentum(h: Hierarchy48) -> np.ndarray:
    vids = h.active_vertices()
    return (h.masses[vids, None] * h.v[vids]).sum(axis=0)


def momentum_scale(h: Hierarchy48) -> float:
    vids = h.active_vertices()
    vmax = float(np.abs(h.v[vids]).max()) if len(vids) else 0.0
    return float(h.masses[vids].sum()) * max(vmax, 1.0)


def hyp_is_leg_of_neighbour(h: Hierarchy48, t: int) -> bool:
    """Whether the triangle across ``t``'s hypotenuse is coarser (forced split)."""
    edge = h.hypotenuse(t)
    return any(o != t and h.hypotenuse(o) != edge for o in h.edge_triangles(edge))


def check_invariants(h: Hierarchy48, density: float, n_base_vertices: int) -> None:
    h.check()
    mesh, vids, tids = h.active_mesh()
    W, H = h.width, h.height
    # Mass: exact total, and equal to area lumping of the active mesh.
    masses = h.masses[vids]
    assert masses.sum() == pytest.approx(density * W * H, rel=1e-12, abs=0)
    np.testing.assert_allclose(
        masses, lumped_masses(mesh.uv, mesh.triangles, density), rtol=1e-12, atol=0)
    assert np.all(masses > 0)
    # Inactive vertex slots carry no mass.
    inactive = ~h.vertex_active[:h.vertex_end]
    assert np.all(h.mass_units[:h.vertex_end][inactive] == 0)
    # Rest area.
    areas = triangle_rest_areas(mesh.uv, mesh.triangles)
    assert np.all(areas > 0)
    assert areas.sum() == pytest.approx(W * H, rel=1e-12, abs=0)
    # Levels.
    assert np.all(mesh.levels >= 0)
    assert np.all(mesh.levels <= h.max_level)
    assert np.array_equal(mesh.levels, h.level[tids])
    # Rest coordinates inside the rectangle (midpoints of inside points: exact).
    uv = mesh.uv
    assert np.all((uv[:, 0] >= 0) & (uv[:, 0] <= W) & (uv[:, 1] >= 0) & (uv[:, 1] <= H))
    # Euler characteristic of a disc.
    t = mesh.triangles
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    n_edges = len(np.unique(edges, axis=0))
    assert mesh.vertex_count - n_edges + mesh.triangle_count == 1
    # Every active vertex is a base vertex or the midpoint of a split edge.
    assert len(vids) == n_base_vertices + len(h.midpoint)
    mids = np.array(sorted(h.midpoint.values()), dtype=np.int64)
    assert np.all(h.vertex_active[mids])
    for edge, m in h.midpoint.items():
        assert tuple(h.vertex_edge[m]) == edge
        assert np.array_equal(h.uv[m], 0.5 * (h.uv[edge[0]] + h.uv[edge[1]]))
    # mergeable_edges is exactly the split edges whose children are all leaves.
    expect = {e for e, parents in h.diamond.items()
              if h.tri_active[h.children[list(parents)]].all()}
    assert set(h.mergeable_edges()) == expect


# -- the state machine -------------------------------------------------------------

class HierarchyMachine(RuleBasedStateMachine):
    """Random refine / merge / perturbed merge / undo on a random hierarchy."""

    @initialize(base=st.sampled_from(BASES), max_level=st.integers(2, 7),
                density=st.floats(0.05, 2.0), seed=st.integers(0, 2**32 - 1))
    def setup(self, base, max_level, density, seed):
        W, H, bu, bv = base
        self.density = density
        self.h = make(W, H, bu, bv, max_level=max_level, density=density, seed=seed)
        self.n0 = self.h.vertex_end
        self.rng = np.random.default_rng(seed)
        self.p0 = momentum(self.h)
        self.undo_stack: list[tuple[list[Split], dict]] = []
        self.deepest = 0
        self.clock = 0.0

    # -- rules --------------------------------------------------------------
    @rule(data=st.data())
    def refine(self, data):
        self._refine(data.draw(st.sampled_from(self.h.active_triangles().tolist()),
                               label="triangle"))

    @rule(data=st.data())
    def refine_finest(self, data):
        """Refine one of the finest active triangles: drives depth and forcing."""
        h = self.h
        tids = h.active_triangles()
        finest = tids[h.level[tids] == h.level[tids].max()].tolist()
        self._refine(data.draw(st.sampled_from(finest), label="finest triangle"))

    def _refine(self, t):
        h = self.h
        before = snapshot(h)
        level, edge = int(h.level[t]), h.hypotenuse(t)
        forced = level < h.max_level and hyp_is_leg_of_neighbour(h, t)
        version = h.version
        self.clock += 1.0
        birth = h.birth[before["tids"]].copy()
        ops = h.refine(t, time=self.clock)
        if level >= h.max_level:
            assert ops == []
            assert h.version == version
            assert_same(before, snapshot(h))
            return
        assert ops and all(isinstance(op, Split) for op in ops)
        assert ops[-1] == Split(edge)                 # the requested split comes last
        assert (len(ops) > 1) == forced
        event(f"refine: {'forced' if forced else 'single'} split")
        self.deepest = max(self.deepest, int(h.level[h.active_triangles()].max()))
        assert not h.tri_active[t]
        assert h.version == version + len(ops)
        # Face rule: nothing that existed moves or changes velocity.
        vids = before["vids"]
        assert np.all(h.vertex_active[vids])
        assert np.array_equal(h.x[vids], before["x"])
        assert np.array_equal(h.v[vids], before["v"])
        assert np.array_equal(h.uv[vids], before["uv"])
        # New particles sit at the edge midpoints with the average velocity.
        new = []
        for op in ops:
            a, b = op.edge
            m = h.midpoint[op.edge]
            new.append(m)
            assert np.array_equal(h.uv[m], 0.5 * (h.uv[a] + h.uv[b]))
            assert np.array_equal(h.x[m], 0.5 * (h.x[a] + h.x[b]))
            assert np.array_equal(h.v[m], 0.5 * (h.v[a] + h.v[b]))
        assert len(set(new)) == len(ops)
        # New triangles are born now; surviving ones keep their birth time.
        tids = h.active_triangles()
        old = np.isin(before["tids"], tids)
        assert np.array_equal(h.birth[before["tids"][old]], birth[old])
        fresh = tids[~np.isin(tids, before["tids"])]
        assert len(tids) == len(before["tids"]) + sum(len(h.diamond[op.edge]) for op in ops)
        assert np.all(h.birth[fresh] == self.clock)
        assert set(h.active_vertices().tolist()) == set(vids.tolist()) | set(new)
        self.undo_stack.append((ops, before))

    @rule()
    def undo(self):
        if not self.undo_stack:
            return
        h = self.h
        ops, before = self.undo_stack.pop()
        event(f"undo of {len(ops)} split(s)")
        for op in reversed(ops):
            h.apply(op.inverse())
        assert_same(before, snapshot(h))

    @rule(data=st.data())
    def merge(self, data):
        h = self.h
        edges = sorted(h.mergeable_edges())
        if not edges:
            return
        self._merge(data.draw(st.sampled_from(edges), label="edge"), perturb=False)

    @rule(data=st.data())
    def perturbed_merge(self, data):
        h = self.h
        edges = sorted(h.mergeable_edges())
        if not edges:
            return
        self._merge(data.draw(st.sampled_from(edges), label="edge"), perturb=True)

    def _merge(self, edge, perturb):
        h = self.h
        event("merge (perturbed)" if perturb else "merge")
        m = h.midpoint[edge]
        if perturb:
            h.v[m] += self.rng.standard_normal(3)
            self.p0 = momentum(h)               # the new momentum to conserve
        a, b = edge
        before = snapshot(h)
        vids = before["vids"]
        mass_m = h.masses[m]
        v_m, v_a, v_b = h.v[m].copy(), h.v[a].copy(), h.v[b].copy()
        self.clock += 1.0
        parents = list(h.diamond[edge])
        h.apply(Merge(edge), time=self.clock)
        assert np.all(h.tri_active[parents])
        assert np.all(h.birth[parents] == self.clock)      # re-activated now
        self.undo_stack.clear()                  # earlier refines may be gone
        assert edge not in h.midpoint and edge not in h.diamond
        assert not h.vertex_active[m] and h.mass_units[m] == 0
        keep = vids[vids != m]
        assert set(h.active_vertices().tolist()) == set(keep.tolist())
        # Only the two edge ends change velocity, both by the same vector.
        others = (keep != a) & (keep != b)
        old_v = before["v"][vids != m]
        assert np.array_equal(h.v[keep][others], old_v[others])
        assert np.array_equal(h.x[keep], before["x"][vids != m])
        da, db = h.v[a] - v_a, h.v[b] - v_b
        scale = float(np.abs(h.v[keep]).max()) + np.abs(v_m).max()
        np.testing.assert_allclose(da, db, rtol=0, atol=1e-14 * scale)
        expected = mass_m * (v_m - 0.5 * (v_a + v_b)) / (h.masses[a] + h.masses[b])
        np.testing.assert_allclose(da, expected, rtol=1e-10, atol=1e-14 * scale)
        if perturb:
            assert np.any(da != 0)
        if not perturb and np.array_equal(v_m, 0.5 * (v_a + v_b)):
            assert np.array_equal(da, np.zeros(3)) and np.array_equal(db, np.zeros(3))
        # The edge ends took the removed particle's mass in equal halves.
        old_masses = dict(zip(vids.tolist(), before["masses"]))
        assert h.masses[a] - old_masses[a] == pytest.approx(0.5 * mass_m, rel=1e-12)
        assert h.masses[b] - old_masses[b] == pytest.approx(0.5 * mass_m, rel=1e-12)

    @rule(data=st.data())
    def invalid_operations_raise(self, data):
        """Illegal ops raise MeshError and leave the hierarchy untouched."""
        h = self.h
        before, version = snapshot(h), h.version
        t = data.draw(st.sampled_from(h.active_triangles().tolist()), label="triangle")
        apex, left, right = (int(i) for i in h.tri[t])
        leg = data.draw(st.sampled_from([(apex, left), (left, apex), (right, apex)]),
                        label="leg")
        with pytest.raises(MeshError):
            h.apply(Split(leg))                    # a leg is never a hypotenuse of all
        with pytest.raises(MeshError):
            h.apply(Merge(leg))                    # an active edge is not split
        hyp = h.hypotenuse(t)
        if h.level[t] >= h.max_level:
            with pytest.raises(MeshError):
                h.apply(Split(hyp))
        if hyp not in h.diamond:
            with pytest.raises(MeshError):
                h.apply(Merge(hyp))
        blocked = sorted(set(h.diamond) - set(h.mergeable_edges()))
        if blocked:
            with pytest.raises(MeshError):
                h.apply(Merge(data.draw(st.sampled_from(blocked), label="blocked")))
        inactive = np.flatnonzero(~h.tri_active[:h.tri_end]).tolist()
        if inactive:
            assert h.refine(data.draw(st.sampled_from(inactive), label="inactive")) == []
        assert h.version == version
        assert_same(before, snapshot(h))

    def teardown(self):
        if hasattr(self, "h"):
            event(f"deepest level reached: {self.deepest} of {self.h.max_level}")

    # -- invariants ----------------------------------------------------------
    @invariant()
    def mesh_is_valid(self):
        check_invariants(self.h, self.density, self.n0)

    @invariant()
    def momentum_is_conserved(self):
        h = self.h
        np.testing.assert_allclose(momentum(h), self.p0, rtol=0,
                                   atol=1e-13 * momentum_scale(h))


HierarchyMachine.TestCase.settings = settings(
    max_examples=40, stateful_step_count=40, deadline=None,
    suppress_health_check=[HealthCheck.too_slow])
TestHierarchyMachine = HierarchyMachine.TestCase


# -- operation values ----------------------------------------------------------------

def test_operation_values_are_inverse_pairs():
    s, m = Split((3, 7)), Merge((3, 7))
    assert s.inverse() == m and m.inverse() == s
    assert s.inverse().inverse() == s
    assert s != m and len({s, Split((3, 7)), m}) == 2
    h = make()
    with pytest.raises(TypeError):
        h.apply((3, 7))


def test_hierarchy_needs_level_zero_base():
    with pytest.raises(MeshError):
        Hierarchy48(mesh48.refine_uniform(base_mesh(1.0, 1.0, 2, 2), 1),
                    np.zeros((13, 3)), 1.0, 4)


# -- refine then undo ------------------------------------------------------------------

@settings(max_examples=25, deadline=None)
@given(base=st.sampled_from(BASES), seed=st.integers(0, 2**32 - 1), data=st.data())
def test_refine_then_undo_is_exact_after_random_prefix(base, seed, data):
    W, H, bu, bv = base
    h = make(W, H, bu, bv, max_level=6, density=0.7, seed=seed)
    # A random prefix of refines and merges, so that free lists are in use.
    for _ in range(data.draw(st.integers(0, 12), label="prefix")):
        edges = sorted(h.mergeable_edges())
        if edges and data.draw(st.booleans(), label="merge?"):
            h.apply(Merge(data.draw(st.sampled_from(edges))))
        else:
            h.refine(data.draw(st.sampled_from(h.active_triangles().tolist())))
    before = snapshot(h)
    t = data.draw(st.sampled_from(h.active_triangles().tolist()), label="triangle")
    ops = h.refine(t)
    if h.level[t] < h.max_level:
        assert ops
    ends = h.vertex_end, h.tri_end
    for op in reversed(ops):
        h.apply(op.inverse())
    assert_same(before, snapshot(h))
    h.check()
    # Redoing it recycles the freed pool slots instead of growing the pool.
    assert h.refine(t) == ops
    assert (h.vertex_end, h.tri_end) == ends
    h.check()


# -- errors ------------------------------------------------------------------------------

def test_split_of_a_leg_raises():
    h = make()
    apex, left, right = (int(i) for i in h.tri[0])
    before, version = snapshot(h), h.version
    for leg in ((apex, left), (right, apex)):
        with pytest.raises(MeshError, match="hypotenuse"):
            h.apply(Split(leg))
    # Not an edge at all: two opposite corners of the cloth.
    with pytest.raises(MeshError):
        h.apply(Split((0, h.vertex_end - 1)))
    assert h.version == version
    assert_same(before, snapshot(h))


def test_split_beyond_max_level_raises_and_refine_is_a_no_op():
    h = make(max_level=2)
    h.refine_uniform(2)
    assert np.all(h.level[h.active_triangles()] == 2)
    before, version = snapshot(h), h.version
    for t in h.active_triangles()[:10]:
        with pytest.raises(MeshError, match="maximum level"):
            h.apply(Split(h.hypotenuse(int(t))))
        assert h.refine(int(t)) == []
    h.refine_uniform(3)                         # nothing is left to do
    assert h.version == version
    assert_same(before, snapshot(h))


def test_merge_preconditions():
    h = make(max_level=5)
    before_all = snapshot(h)
    # Never split.
    with pytest.raises(MeshError, match="not split"):
        h.apply(Merge(h.hypotenuse(0)))
    # Children refined further.
    ops = h.refine(0)
    assert ops == [Split(h.hypotenuse(0))]
    edge = ops[0].edge
    kids = h.children[0]
    assert np.all(h.tri_active[kids]) and not h.tri_active[0]
    assert h.refine(0) == []                    # inactive triangle: nothing happens
    more = h.refine(int(kids[0]))
    assert more and not h.tri_active[kids[0]]
    assert edge not in h.mergeable_edges()
    state, version = snapshot(h), h.version
    with pytest.raises(MeshError, match="refined further"):
        h.apply(Merge(edge))
    assert h.version == version
    assert_same(state, snapshot(h))
    # Undo the inner refinement; then the merge is legal again.
    for op in reversed(more):
        h.apply(op.inverse())
    assert edge in h.mergeable_edges()
    h.apply(Merge(edge))
    assert_same(before_all, snapshot(h))
    # Already merged.
    with pytest.raises(MeshError, match="not split"):
        h.apply(Merge(edge))


# -- forced splits ---------------------------------------------------------------------------

def test_refining_into_children_forces_coarser_neighbours():
    density = 0.4
    h = make(1.0, 1.0, 4, 4, max_level=7, density=density, seed=3)
    n0 = h.vertex_end
    p0 = momentum(h)
    # Triangle 0 sits in the corner block; after one split, the child whose
    # hypotenuse is an interior block edge has a level-0 neighbour across it.
    ops = h.refine(0)
    assert len(ops) == 1
    lengths = []
    t = 0
    for _ in range(h.max_level - 1):
        interior = [int(k) for k in h.children[t]
                    if len(h.edge_triangles(h.hypotenuse(int(k)))) == 2]
        assert interior
        t = interior[0]
        assert hyp_is_leg_of_neighbour(h, t)
        before, hyp = snapshot(h), h.hypotenuse(t)
        ops = h.refine(t)
        lengths.append(len(ops))
        assert len(ops) > 1                             # at least one forced split
        assert ops[-1] == Split(hyp)                    # the requested split is last
        check_invariants(h, density, n0)
        np.testing.assert_allclose(momentum(h), p0, rtol=0, atol=1e-13 * momentum_scale(h))
        # Every split is of a hypotenuse shared only by hypotenuses: levels of
        # the split triangles never exceed the requested one.
        assert max(h.level[h.children[t]]) == h.level[t] + 1
        # The whole forced chain undoes exactly, and redoing it gives the same
        # mesh (pool slots may be reused in another order, so compare by uv).
        mesh, vids, _ = h.active_mesh()
        state = _triangle_sets(mesh.uv, mesh.triangles), h.masses[vids], h.uv[vids]
        for op in reversed(ops):
            h.apply(op.inverse())
        assert_same(before, snapshot(h))
        for op in ops:
            h.apply(op)
        mesh, vids, _ = h.active_mesh()
        assert _triangle_sets(mesh.uv, mesh.triangles) == state[0]
        order_old = np.lexsort(state[2].T)
        order_new = np.lexsort(h.uv[vids].T)
        assert np.array_equal(state[2][order_old], h.uv[vids][order_new])
        assert np.array_equal(state[1][order_old], h.masses[vids][order_new])
    # Deeper chains force more than one coarser neighbour (recursion).
    assert max(lengths) > 2


# -- uniform refinement and pool growth ----------------------------------------------------------

def _triangle_sets(uv, triangles):
    pts = np.round(uv[triangles], 12)                          # (T, 3, 2)
    oriented = {tuple(map(tuple, tri)) for tri in pts}
    unordered = {tuple(sorted(map(tuple, tri))) for tri in pts}
    return unordered, oriented


@pytest.mark.parametrize("base", BASES)
@pytest.mark.parametrize("levels", range(6))
def test_refine_uniform_matches_mesh48(base, levels):
    W, H, bu, bv = base
    h = make(W, H, bu, bv, max_level=7, planar=True)
    h.refine_uniform(levels)
    mesh, _, tids = h.active_mesh()
    ref = mesh48.refine_uniform(base_mesh(W, H, bu, bv), levels)
    assert mesh.triangle_count == ref.triangle_count == 2 * bu * bv * 2**levels
    assert mesh.vertex_count == ref.vertex_count
    assert np.all(mesh.levels == levels) and np.all(h.level[tids] == levels)
    got, got_oriented = _triangle_sets(mesh.uv, mesh.triangles)
    want, want_oriented = _triangle_sets(ref.uv, ref.triangles)
    assert len(got) == mesh.triangle_count
    assert got == want
    assert got_oriented == want_oriented                 # same (apex, left, right) too
    h.check()


def test_capacity_growth_far_beyond_initial_pool():
    density = 0.25
    h = make(1.0, 1.0, 1, 1, max_level=7, density=density, planar=True)
    vcap, tcap = len(h.uv), len(h.tri)
    rng = np.random.default_rng(11)
    v0 = rng.standard_normal((h.vertex_end, 3))
    h.v[:h.vertex_end] = v0
    p0 = momentum(h)
    h.refine_uniform(6)
    assert h.vertex_end > 4 * vcap and h.tri_end > 8 * tcap
    assert len(h.uv) >= h.vertex_end and len(h.tri) >= h.tri_end
    for name in ("x", "v", "mass_units", "vertex_active", "vertex_edge"):
        assert len(getattr(h, name)) == len(h.uv), name
    for name in ("level", "parent", "children", "tri_active", "birth"):
        assert len(getattr(h, name)) == len(h.tri), name
    mesh, vids, tids = h.active_mesh()
    assert mesh.triangle_count == 2 * 4**3 and mesh.vertex_count == 9 * 9
    assert np.all(h.level[tids] == 6)
    check_invariants(h, density, 4)
    # Data survived every reallocation: base vertices untouched, and since
    # x = (u, v, 0) initially and every midpoint is computed the same way,
    # x stays equal to (u, v, 0) bit for bit.
    assert np.array_equal(h.v[:4], v0)
    assert np.array_equal(h.x[vids, :2], h.uv[vids])
    assert np.all(h.x[vids, 2] == 0)
    np.testing.assert_allclose(momentum(h), p0, rtol=0, atol=1e-13 * momentum_scale(h))
    # Parents are kept (inactive) with consistent links.
    inner = np.flatnonzero(~h.tri_active[:h.tri_end])
    assert len(inner) == h.tri_end - mesh.triangle_count
    for t in inner:
        kids = h.children[t]
        assert np.all(kids >= 0) and np.all(h.parent[kids] == t)
        assert np.all(h.level[kids] == h.level[t] + 1)
    # Coarsen all the way back to the base.
    while edges := h.mergeable_edges():
        for e in edges:
            if e in h.mergeable_edges():
                h.apply(Merge(e))
    mesh, vids, _ = h.active_mesh()
    assert mesh.triangle_count == 2 and np.array_equal(vids, np.arange(4))
    assert np.array_equal(h.v[:4], v0)
    check_invariants(h, density, 4)
