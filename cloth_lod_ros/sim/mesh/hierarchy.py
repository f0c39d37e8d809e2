"""The 4-8 hierarchy at run time: split and merge as invertible operations.

Mechanism only (paper §3, §5.2–§5.3, §5.5; design §4); *when* to split or merge
is decided by :mod:`cloth_lod_ros.sim.lod.policy`.

Storage is a pool of numpy arrays with capacity growth and free lists, not one
Python object per element:

* vertices: rest ``uv``, state ``x``/``v``, ``mass_units``, active flag, and for
  a vertex made by a split the hypotenuse it bisected;
* triangles: ``(apex, left, right)`` as in :mod:`cloth_lod_ros.sim.mesh.mesh48`, level,
  parent, two children, active flag and the time it was (re)activated.

A split keeps its parents in memory (inactive); a merge frees the children and
re-activates the parents (paper §5.3).  Active edges are indexed in a dict from
the sorted vertex pair to its one or two active triangles, which is what finds
the neighbour across a hypotenuse.

**Compiled operations.**  With numba (and ``CLOTH_LOD_KERNELS`` not ``numpy``)
``apply``, ``refine``, ``refine_uniform`` and :meth:`Hierarchy48.carry_out` (a
whole LOD decision) run :mod:`cloth_lod_ros.sim.mesh.hierarchy_kernels` on the same
arrays, with the edge index, midpoint map and free lists in the kernels' form;
the Python methods here are their reference, with bitwise equal results.  The
Python containers are rebuilt from the kernels' form when read.

**Operations are values** (:mod:`.operations`).  ``Split(edge)`` bisects the
hypotenuse ``edge`` shared by its one or two triangles; ``Merge(edge)`` removes that edge's midpoint and
restores the two triangles.  ``Split(e).inverse() == Merge(e)`` and vice versa;
:meth:`Hierarchy48.refine` returns the list of splits it performed (forced ones
first) so ``for op in reversed(ops): h.apply(op.inverse())`` undoes it exactly.

**Conservation** (paper §5.5).  Each triangle gives a third of its mass to each
corner.  Masses are kept as exact dyadic *units* (a level-L triangle gives
``2**-L`` units to each corner) times ``base_triangle_area * density / 3``, so a
split followed by a merge restores every mass bit for bit and the total is
``3 × base triangle count`` units exactly.  A split moves mass from the edge ends
to the new midpoint particle, which takes the average velocity, so momentum is
unchanged.  A merge gives the removed particle's mass back to the edge ends and
adds the same velocity change to both so that momentum is unchanged (zero when
the midpoint still moves with the average of the ends, so split-then-merge
restores velocities exactly).
"""

from __future__ import annotations

import numpy as np

from . import compact_kernels as _compact
from . import hierarchy_kernels as _compiled
from .topology import MeshError
from .mesh48 import RestMesh
from .operations import Merge, OperationLog, Split

__all__ = ["Hierarchy48", "merge_velocity_change", "warm_up"]


def merge_velocity_change(mass_mid, mass_ends, v_mid: np.ndarray, v_left: np.ndarray,
                          v_right: np.ndarray) -> np.ndarray:
    """Velocity change, m/s, that a merge gives both ends of the edge (design §2).

    The removed particle's mass goes to the two ends equally; adding the same
    ``Δv = m_mid (v_mid − ½(v_left + v_right)) / (m_left' + m_right')`` to both
    keeps the momentum.  Zero when the midpoint moves with the ends' average.

    Args:
        mass_mid: ``()`` or ``(k,)`` mass of the removed particle.
        mass_ends: ``()`` or ``(k,)`` the ends' total mass *after* the merge
            (same unit as ``mass_mid``: kg or mass units).
        v_mid, v_left, v_right: ``(3,)`` or ``(k, 3)`` velocities, m/s.

    Returns:
        ``(3,)`` or ``(k, 3)``.
    """
    mass_mid = np.asarray(mass_mid, dtype=float)[..., None]
    mass_ends = np.asarray(mass_ends, dtype=float)[..., None]
    return mass_mid * (v_mid - 0.5 * (v_left + v_right)) / mass_ends


def _key(a: int, b: int) -> tuple[int, int]:
    return (a, b) if a < b else (b, a)


def _fits(edge) -> bool:
    """Whether the kernels can take the edge's ids (packed in 32 bits each)."""
    return all(0 <= int(i) < 2**31 for i in edge)


#: The reference's error messages, by kernel status.
_FAILURES = {
    _compiled.NOT_HYPOTENUSE: "cannot split {edge}: not the hypotenuse of all its triangles",
    _compiled.AT_MAX_LEVEL: "cannot split {edge}: triangles already at the maximum level",
    _compiled.NOT_SPLIT: "cannot merge {edge}: it is not split",
    _compiled.REFINED_FURTHER: "cannot merge {edge}: its children are refined further",
    _compiled.INDEX_BROKEN: "edge index broken at {edge}: an edge with three triangles",
}


class Hierarchy48:
    """A 4-8 mesh that can be refined and simplified locally.

    Args:
        base: level-0 mesh from :func:`cloth_lod_ros.sim.mesh.mesh48.base_mesh`.
        positions: ``(n0, 3)`` initial positions of the base vertices, m.
        density: areal density, kg/m².
        max_level: deepest level a triangle may reach.
    """

    def __init__(self, base: RestMesh, positions: np.ndarray, density: float,
                 max_level: int):
        if np.any(base.levels != 0):
            raise MeshError("a hierarchy starts from a level-0 mesh")
        self.width, self.height = base.width, base.height
        self.max_level = int(max_level)
        n, t = base.vertex_count, base.triangle_count
        # All base triangles are halves of equal square blocks.
        base_area = 0.5 * (base.width * base.height) / (t / 2)
        self.unit_mass = base_area * density / 3.0          # kg per mass unit
        self.base_triangle_count = t
        vcap, tcap = max(2 * n, 16), max(2 * t, 16)
        self.uv = np.zeros((vcap, 2))
        self.x = np.zeros((vcap, 3))
        self.v = np.zeros((vcap, 3))
        self.mass_units = np.zeros(vcap)
        self.vertex_active = np.zeros(vcap, dtype=bool)
        self.vertex_edge = np.full((vcap, 2), -1, dtype=np.int64)
        self.vertex_parents = np.full((vcap, 2), -1, dtype=np.int64)
        self.tri = np.zeros((tcap, 3), dtype=np.int64)
        self.level = np.zeros(tcap, dtype=np.int64)
        self.parent = np.full(tcap, -1, dtype=np.int64)
        self.children = np.full((tcap, 2), -1, dtype=np.int64)
        self.tri_active = np.zeros(tcap, dtype=bool)
        self.birth = np.zeros(tcap)
        self.vertex_end, self.tri_end = n, t          # high-water marks
        # The index in Python containers (the reference's form); with the
        # kernels on, a CompiledIndex holds it instead and these are rebuilt
        # from it only when read (_python_index).
        self._py_free_vertices: list[int] = []
        self._py_free_triangles: list[int] = []
        self.uv[:n] = base.uv
        self.x[:n] = positions
        self.vertex_active[:n] = True
        self.tri[:t] = base.triangles
        self._py_edges: dict[tuple[int, int], list[int]] = {}
        self._py_midpoint: dict[tuple[int, int], int] = {}
        self._python_current = True           # the containers above are up to date
        self._compiled: _compiled.CompiledIndex | None = None   # None: stale
        for k in range(t):
            self._activate(k, 0.0)
        self.version = 0            # bumped on every topology change

    # -- the index's two forms ----------------------------------------------
    # Exactly one of them is changed by an operation: the reference's Python
    # containers (kernels off) or the CompiledIndex.  Reading the other
    # rebuilds it (O(size), in order, so the results are the same either way).
    def _python_index(self) -> None:
        if not self._python_current:
            (self._py_edges, self._py_midpoint, self._py_free_vertices,
             self._py_free_triangles) = self._compiled.to_python()
            self._python_current = True

    def _kernel_index(self) -> "_compiled.CompiledIndex":
        if self._compiled is None:
            self._compiled = _compiled.CompiledIndex(
                self._py_edges, self._py_midpoint, self._py_free_vertices,
                self._py_free_triangles, len(self.uv), len(self.tri))
        return self._compiled

    def _for_reference(self) -> None:
        """Before the Python code changes the index: make it current, and
        drop the compiled one it is about to outdate."""
        self._python_index()
        self._compiled = None

    @property
    def midpoint(self) -> dict[tuple[int, int], int]:
        """Split edge (sorted pool vertex pair) -> its midpoint particle."""
        self._python_index()
        return self._py_midpoint

    @property
    def _edges(self) -> dict[tuple[int, int], list[int]]:
        self._python_index()
        return self._py_edges

    @property
    def _free_vertices(self) -> list[int]:
        self._python_index()
        return self._py_free_vertices

    @property
    def _free_triangles(self) -> list[int]:
        self._python_index()
        return self._py_free_triangles

    def __getstate__(self) -> dict:
        """Copies and pickles carry the Python form of the index, the reference's
        (the kernels' tables are rebuilt from it when next needed)."""
        self._python_index()
        state = dict(self.__dict__)
        state["_compiled"] = None
        return state

    # -- pool management ----------------------------------------------------
    def _new_vertex(self) -> int:
        if self._py_free_vertices:
            return self._py_free_vertices.pop()
        if self.vertex_end == len(self.uv):
            self._grow_vertices()
        self.vertex_end += 1
        return self.vertex_end - 1

    def _grow_vertices(self) -> None:
        cap = 2 * len(self.uv)
        for name in ("uv", "x", "v", "mass_units", "vertex_active", "vertex_edge",
                     "vertex_parents"):
            old = getattr(self, name)
            new = np.zeros((cap,) + old.shape[1:], dtype=old.dtype)
            if name in ("vertex_edge", "vertex_parents"):
                new[:] = -1
            new[:len(old)] = old
            setattr(self, name, new)

    def _new_triangle(self) -> int:
        if self._py_free_triangles:
            return self._py_free_triangles.pop()
        if self.tri_end == len(self.tri):
            self._grow_triangles()
        self.tri_end += 1
        return self.tri_end - 1

    def _grow_triangles(self) -> None:
        cap = 2 * len(self.tri)
        for name, fill in (("tri", 0), ("level", 0), ("parent", -1), ("children", -1),
                           ("tri_active", False), ("birth", 0.0)):
            old = getattr(self, name)
            new = np.full((cap,) + old.shape[1:], fill, dtype=old.dtype)
            new[:len(old)] = old
            setattr(self, name, new)

    # Every split and merge calls these a few times.  Scalar Python on
    # ``tolist``/``item`` values, not numpy scalars or fancy indexing: numpy's
    # per-call overhead (~0.1-1 µs) would dominate these few-element updates.
    def _activate(self, t: int, time: float) -> None:
        a, b, c = self.tri[t].tolist()
        self._link(t, a, b, c, 2.0 ** -self.level.item(t))
        self.birth[t] = time

    def _deactivate(self, t: int) -> None:
        a, b, c = self.tri[t].tolist()
        self._unlink(t, a, b, c, 2.0 ** -self.level.item(t))

    def _link(self, t: int, a: int, b: int, c: int, units: float) -> None:
        """Make triangle ``t`` with corners ``(a, b, c)`` active: index its edges
        and give each corner ``units`` mass units (``2**-level``; exact)."""
        edges = self._py_edges
        for e in ((a, b) if a < b else (b, a), (b, c) if b < c else (c, b),
                  (c, a) if c < a else (a, c)):
            users = edges.get(e)
            if users is None:
                edges[e] = [t]
            else:
                users.append(t)
        mass_units = self.mass_units
        mass_units[a] = mass_units.item(a) + units
        mass_units[b] = mass_units.item(b) + units
        mass_units[c] = mass_units.item(c) + units
        self.tri_active[t] = True

    def _unlink(self, t: int, a: int, b: int, c: int, units: float) -> None:
        """Inverse of :meth:`_link`."""
        edges = self._py_edges
        for e in ((a, b) if a < b else (b, a), (b, c) if b < c else (c, b),
                  (c, a) if c < a else (a, c)):
            users = edges[e]
            users.remove(t)
            if not users:
                del edges[e]
        mass_units = self.mass_units
        mass_units[a] = mass_units.item(a) - units
        mass_units[b] = mass_units.item(b) - units
        mass_units[c] = mass_units.item(c) - units
        self.tri_active[t] = False

    # -- queries ------------------------------------------------------------
    def hypotenuse(self, t: int) -> tuple[int, int]:
        return _key(self.tri.item(t, 1), self.tri.item(t, 2))

    def edge_triangles(self, edge: tuple[int, int]) -> list[int]:
        """Active triangles on an edge (sorted vertex pair); empty if not an edge."""
        edge = _key(*edge)
        if not self._python_current:
            return self._compiled.edge_triangles(*edge)
        return list(self._py_edges.get(edge, ()))

    @property
    def masses(self) -> np.ndarray:
        """Masses of all pool slots (kg); inactive slots hold 0."""
        return self.mass_units * self.unit_mass

    def active_vertices(self) -> np.ndarray:
        return np.flatnonzero(self.vertex_active[:self.vertex_end])

    def active_triangles(self) -> np.ndarray:
        return np.flatnonzero(self.tri_active[:self.tri_end])

    def active_mesh(self) -> tuple[RestMesh, np.ndarray, np.ndarray]:
        """Compact mesh of the active elements.

        Returns:
            ``(mesh, vertex_ids, triangle_ids)``: compact vertex ``i`` is pool
            vertex ``vertex_ids[i]``, compact triangle ``k`` is pool triangle
            ``triangle_ids[k]`` (both increasing).
        """
        compiled = _compact.active_mesh(self)      # one pass, the same arrays
        if compiled is not None:
            return compiled
        vids = self.active_vertices()
        tids = self.active_triangles()
        remap = np.full(self.vertex_end, -1, dtype=np.int64)
        remap[vids] = np.arange(len(vids))
        mesh = RestMesh(uv=self.uv[vids].copy(), triangles=remap[self.tri[tids]],
                        levels=self.level[tids].copy(), width=self.width,
                        height=self.height)
        return mesh, vids, tids

    def _parents(self, vertex: int) -> tuple[int, ...]:
        return tuple(int(t) for t in self.vertex_parents[vertex] if t >= 0)

    @property
    def diamond(self) -> dict[tuple[int, int], tuple[int, ...]]:
        """Split edges and the one or two triangles each split (derived view)."""
        return {edge: self._parents(m) for edge, m in self.midpoint.items()}

    def split_vertices(self) -> tuple[np.ndarray, np.ndarray]:
        """Particles made by a split whose merge is valid now (vectorised).

        Returns:
            ``(vertices (k,), children (k, 4))``: pool ids of midpoints whose
            children are all active leaves, and those children (``-1`` padding
            for a border diamond, which has 2).
        """
        vids = self.active_vertices()
        vids = vids[self.vertex_parents[vids, 0] >= 0]
        parents = self.vertex_parents[vids]                       # (k, 2)
        kids = self.children[np.maximum(parents, 0)].reshape(len(vids), 4)
        kids[np.repeat(parents < 0, 2, axis=1)] = -1
        leaf = np.where(kids >= 0, self.tri_active[np.maximum(kids, 0)], True)
        ok = leaf[:, 0] & leaf[:, 1] & leaf[:, 2] & leaf[:, 3]    # all(axis=1), cheaper
        return vids[ok], kids[ok]

    def mergeable_edges(self) -> list[tuple[int, int]]:
        """Split edges whose children are all active (their merge is valid)."""
        vids, _ = self.split_vertices()
        return [(int(a), int(b)) for a, b in self.vertex_edge[vids]]

    # -- operations ---------------------------------------------------------
    def apply(self, op, time: float = 0.0) -> None:
        """Apply one :class:`Split` or :class:`Merge`.

        Raises:
            MeshError: the operation's precondition does not hold (a split of an
                edge that is not the hypotenuse of all its triangles, or beyond
                the maximum level; a merge of an edge that is not split or
                whose children are not all leaves).
        """
        if isinstance(op, (Split, Merge)) and _compiled.enabled() and _fits(op.edge):
            kind = _compiled.SPLIT if isinstance(op, Split) else _compiled.MERGE
            self._run_compiled(time, direct=np.array([(kind, *_key(*op.edge))], np.int64))
            return
        self._for_reference()
        if isinstance(op, Split):
            self._split(op.edge, time)
        elif isinstance(op, Merge):
            self._merge(op.edge, time)
        else:
            raise TypeError(f"not a mesh operation: {op!r}")
        self.version += 1

    def _split(self, edge: tuple[int, int], time: float) -> None:
        edge = _key(*edge)
        left, right = edge
        tris = list(self._py_edges.get(edge, ()))
        corners = [self.tri[t].tolist() for t in tris]
        if not tris or any(_key(c[1], c[2]) != edge for c in corners):
            raise MeshError(f"cannot split {edge}: not the hypotenuse of all its triangles")
        level = self.level.item(tris[0])
        if level >= self.max_level:
            raise MeshError(f"cannot split {edge}: triangles already at the maximum level")
        m = self._new_vertex()
        # Midpoints in Python floats: the same IEEE sums and halvings as the
        # numpy row expression 0.5 * (a + b), at half its per-call cost.
        for rows in (self.uv, self.x, self.v):   # face rule: nothing moves; v keeps momentum
            a, b = rows[left].tolist(), rows[right].tolist()
            rows[m] = [0.5 * (p + q) for p, q in zip(a, b)]
        self.mass_units[m] = 0.0
        self.vertex_active[m] = True
        self.vertex_edge[m, 0], self.vertex_edge[m, 1] = left, right
        self.vertex_parents[m, 0] = tris[0]
        self.vertex_parents[m, 1] = tris[1] if len(tris) == 2 else -1
        units, kid_units = 2.0 ** -level, 2.0 ** -(level + 1)
        for t, (apex, l, r) in zip(tris, corners):
            self._unlink(t, apex, l, r, units)
            kids = (self._new_triangle(), self._new_triangle())
            tri, kid_level, parent = self.tri, self.level, self.parent   # after any growth
            children, birth = self.children, self.birth
            for kid, (a, b, c) in zip(kids, ((m, apex, l), (m, r, apex))):
                tri[kid, 0], tri[kid, 1], tri[kid, 2] = a, b, c
                kid_level[kid] = level + 1
                parent[kid] = t
                children[kid, 0] = children[kid, 1] = -1
                self._link(kid, a, b, c, kid_units)
                birth[kid] = time
            children[t, 0], children[t, 1] = kids
        self._py_midpoint[edge] = m

    def _merge(self, edge: tuple[int, int], time: float) -> None:
        edge = _key(*edge)
        m = self._py_midpoint.get(edge)
        if m is None:
            raise MeshError(f"cannot merge {edge}: it is not split")
        parents = [t for t in self.vertex_parents[m].tolist() if t >= 0]
        kids = [self.children[t].tolist() for t in parents]
        active = self.tri_active
        if not all(active[k] for pair in kids for k in pair):
            raise MeshError(f"cannot merge {edge}: its children are refined further")
        left, right = edge
        mass_units = self.mass_units
        mass_m = mass_units.item(m)
        for t, pair in zip(parents, kids):
            for kid in pair:
                self._deactivate(kid)
                self._py_free_triangles.append(kid)
            self.children[t, 0] = self.children[t, 1] = -1
            self._activate(t, time)
        # Momentum: m's mass went back to the edge ends (equally); give both the
        # same velocity change so that Σ m v is unchanged
        # (merge_velocity_change, written out for one merge).
        # In Python floats, each component with the same operations in the
        # same order as the numpy row expression (identical results, fewer calls).
        v = self.v
        ends = mass_units.item(left) + mass_units.item(right)
        v_l, v_r = v[left].tolist(), v[right].tolist()
        change = [mass_m * (c - 0.5 * (p + q)) / ends
                  for c, p, q in zip(v[m].tolist(), v_l, v_r)]
        if any(change):
            v[left] = [p + d for p, d in zip(v_l, change)]
            v[right] = [q + d for q, d in zip(v_r, change)]
        self.vertex_active[m] = False
        mass_units[m] = 0.0
        self.vertex_edge[m] = -1
        self.vertex_parents[m] = -1
        self.x[m] = 0.0
        v[m] = 0.0
        self._py_free_vertices.append(m)
        del self._py_midpoint[edge]

    def refine(self, t: int, time: float = 0.0) -> list[Split]:
        """Bisect active triangle ``t`` (paper's ``Subdivide48``), forcing splits.

        If the triangle across ``t``'s hypotenuse is coarser, it is refined first
        (recursively), so levels across any edge differ by at most one.  Returns
        the splits performed, forced ones first; empty if ``t`` is inactive or at
        the maximum level.
        """
        t = int(t)
        if _compiled.enabled() and 0 <= t < len(self.tri):
            ops, _ = self._run_compiled(time, refine=np.array([t], np.int64))
            return [Split((a, b)) for a, b in ops[:, 1:].tolist()]
        self._for_reference()
        ops: list[Split] = []
        self._refine(t, time, ops)
        return ops

    def _refine(self, t: int, time: float, ops: list[Split]) -> bool:
        if not self.tri_active[t] or self.level.item(t) >= self.max_level:
            return False
        edge = self.hypotenuse(t)
        for other in self.edge_triangles(edge):
            if other != t and self.hypotenuse(other) != edge:
                # Coarser neighbour (its leg is our hypotenuse): refine it first.
                if not self._refine(other, time, ops):
                    return False
        op = Split(edge)
        self.apply(op, time)
        ops.append(op)
        return True

    def refine_uniform(self, levels: int, time: float = 0.0) -> None:
        """Split every active triangle ``levels`` times (set-up, not the time step)."""
        for _ in range(int(levels)):
            if _compiled.enabled():
                # One call: a refinement of a triangle split meanwhile does
                # nothing, as the reference's tri_active test.
                self._run_compiled(time, refine=self.active_triangles().astype(np.int64))
                continue
            for t in self.active_triangles():
                if self.tri_active[t]:
                    self.refine(int(t), time)

    def carry_out(self, refine, merge, time: float, energy=None, kinetic=None, bound=None,
                  log: list | None = None) -> tuple[int, int] | None:
        """:meth:`cloth_lod_ros.sim.lod.policy.LodPolicy.apply`'s work in one compiled call.

        Args:
            refine: pool triangles to refine, in order; merge: split edges
                (sorted pairs) to merge after them, with that method's checks
                (``energy``, ``kinetic``, ``bound``: ``(len(merge),)`` J, the
                decision's, or None for no kinetic re-test).
            log: list the operations performed are appended to.

        Returns:
            ``(splits, merges)``, or None (nothing done) when the kernels are
            off, an id is out of their range, or ``apply`` is replaced on this
            instance (an instrument that must see every operation, as tests
            do): the caller runs the reference, which calls ``apply``.
        """
        if not _compiled.enabled() or "apply" in vars(self) or "refine" in vars(self):
            return None
        refine = np.asarray(refine, dtype=np.int64).reshape(-1)
        merge = np.asarray(merge, dtype=np.int64).reshape(-1, 2)
        if energy is not None:
            energy, kinetic, bound = (np.asarray(a, dtype=np.float64) for a in (energy, kinetic,
                                                                                bound))
        done = self._run_compiled(time, refine=refine, merge=merge, energy=energy,
                                  kinetic=kinetic, bound=bound, log=log)
        if done is None:
            return None
        ops, splits = done
        return splits, len(ops) - splits

    def _run_compiled(self, time: float, log: list | None = None, **work):
        """:func:`hierarchy_kernels.execute` on this hierarchy: ``(ops, splits)``,
        the ``(n, 3)`` log of what it did (also appended to ``log`` as
        Split/Merge values) and how many of them precede the merges; None if
        an id was out of the kernels' range (nothing done).

        Raises:
            MeshError: as the reference for the operation that failed (the
                operations of the whole requests before it stay done and logged).
        """
        index = self._kernel_index()
        self._python_current = False
        status, edge, ops, complete, splits = _compiled.execute(self, index, time, **work)
        if status == _compiled.OUT_OF_RANGE:
            return None
        if log is not None:
            if isinstance(log, OperationLog):       # made into values only if read
                log.add_raw(ops[:complete])
            else:
                log.extend(Split((a, b)) if kind == _compiled.SPLIT else Merge((a, b))
                           for kind, a, b in ops[:complete].tolist())
        if status != _compiled.OK:
            raise MeshError(_FAILURES[status].format(edge=edge))
        return ops, splits

    # -- checks -------------------------------------------------------------
    def check(self) -> None:
        """Raise :class:`MeshError` unless the active mesh satisfies the 4-8 invariants.

        Conforming and right isosceles (:func:`cloth_lod_ros.sim.mesh.mesh48.check_mesh`),
        levels across every edge differ by at most one, mass units match the
        active triangles exactly, and the total is ``3 × base triangles``.
        """
        from .topology import build_hinges
        from .mesh48 import check_mesh
        mesh, vids, tids = self.active_mesh()
        check_mesh(mesh)
        hinges = build_hinges(mesh.triangles, mesh.vertex_count)
        lev = mesh.levels[hinges.triangles]
        if np.any(np.abs(lev[:, 0] - lev[:, 1]) > 1):
            raise MeshError("levels across an edge differ by more than one")
        units = np.bincount(mesh.triangles.ravel(),
                            weights=np.repeat(2.0 ** -mesh.levels, 3),
                            minlength=mesh.vertex_count)
        if not np.array_equal(units, self.mass_units[vids]):
            raise MeshError("mass units do not match the active triangles")
        if self.mass_units[vids].sum() != 3 * self.base_triangle_count:
            raise MeshError("total mass is not conserved")


def warm_up() -> None:
    """Compile or load these kernels on a one-block hierarchy (a refine with
    forced splits, a direct split and merge, a decision with a kinetic
    re-test, the index tables' growth and export), so no timed step pays
    for it.  Nothing without numba."""
    if not _compiled.enabled():
        return
    from .mesh48 import base_mesh
    base = base_mesh(2.0, 1.0, 2, 1)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(len(base.uv))]), 0.1, 4)
    ops = h.refine(0)
    h.apply(Merge(ops[-1].edge))
    h.apply(Split(ops[-1].edge))
    index = h._kernel_index()
    index.edge_count += 10**4       # as if nearly full: the tables grow (int_table's rehash)
    index.grow()
    index.edge_count -= 10**4
    index.to_python()
    _compiled.execute(h, index, 0.0, refine=np.zeros(1, np.int64),
                      merge=np.array([ops[0].edge], np.int64), energy=np.zeros(1),
                      kinetic=np.zeros(1), bound=np.ones(1))
