"""Compiled (numba) split and merge for :class:`~cloth_lod_ros.sim.mesh.hierarchy.Hierarchy48`.

A split or merge changes a handful of pool slots (paper §5.2–§5.3), but in
Python each cost ~70 µs of interpreter overhead.  These kernels do the same
operations on the same pool arrays; one call carries out a whole
:class:`~cloth_lod_ros.sim.lod.policy.LodDecision` with the re-checks of
:meth:`~cloth_lod_ros.sim.lod.policy.LodPolicy.apply`.

The Python methods of ``Hierarchy48`` stay the reference, and the results
here are *bitwise* equal: every pool array, the free-list order (so new ids
are the same), the midpoint map, ``version`` and the operation log.  The
floating-point operations are the reference's, in its order (numba contracts
nothing into FMAs without fastmath).  The switch is
:mod:`~cloth_lod_ros.sim.runtime.compiled`' (``CLOTH_LOD_KERNELS=numpy``);
without numba everything is the reference.

The kernels' form of the index that the reference keeps in Python
containers (:class:`CompiledIndex`):

* the edge index, an :mod:`~cloth_lod_ros.sim.mesh.int_table` hash table from the
  sorted vertex pair packed in one int64 (``lo << 32 | hi``) to its one or
  two active triangles packed the same way (``(t0 + 1) | (t1 + 1) << 32``, 0
  for none), in the order the reference's lists hold them (that order picks
  a split's first parent);
* the midpoint map, a table from the packed split edge to its midpoint
  (both tables' entry counts live in the counters below);
* the free lists, stacks in arrays as long as the pool (a pool never has
  more free slots than its capacity), with their counts.

The pool arrays travel as two tuples, vertices ``(uv, x, v, mass_units,
vertex_active, vertex_edge, vertex_parents, free_vertex_stack)`` and
triangles ``(tri, level, parent, children, tri_active, birth,
free_triangle_stack)``, and the kernels return only a status: a split
that finds its pool full stops before changing anything, the caller doubles
that pool (as the reference would during this split) and calls again, which
resumes where it stopped.  (Returning the fifteen arrays from every call
cost more than the operations; a pool grows a few times per run.)
"""

from __future__ import annotations

import numpy as np

from . import int_table as _table
from ..runtime import compiled as _compiled

__all__ = ["enabled", "CompiledIndex", "execute"]

_jit = _compiled._jit

#: Operation kinds in a kernel's log (``(n, 3)`` rows ``kind, left, right``).
SPLIT, MERGE = 0, 1
#: Statuses: done; a split of an edge that is not the hypotenuse of all its
#: triangles; a split at the maximum level; a merge of an edge not split; a
#: merge whose children are refined further; an edge with a third triangle.
#: NEED_VERTICES / NEED_TRIANGLES: that pool is full; grow it and call again.
#: OUT_OF_RANGE: an id the kernels cannot take (nothing done; use the reference).
#: NEED_INDEX: the edge or midpoint table is half full; grow both and call again.
(OK, NOT_HYPOTENUSE, AT_MAX_LEVEL, NOT_SPLIT, REFINED_FURTHER, INDEX_BROKEN, NEED_VERTICES,
 NEED_TRIANGLES, OUT_OF_RANGE, NEED_INDEX) = range(10)
# Counters shared with the caller: pool high-water marks, free-list sizes,
# the topology version and the entries in the edge and midpoint tables
# (int64 array, written back after the call).
(_VERTEX_END, _TRIANGLE_END, _FREE_VERTICES, _FREE_TRIANGLES, _VERSION, _EDGES,
 _MIDPOINTS) = range(7)
# A split adds at most 4 edges (then 3) and 1 midpoint, a merge at most 1
# edge for a moment: a split first checks there is room for this many of
# each below half of its table (int_table).
_INDEX_ROOM = 8
_LOW = (1 << 32) - 1


def enabled() -> bool:
    """Whether hierarchy operations run the compiled kernels."""
    return _compiled.enabled()


@_jit
def _edge_key(a, b):
    """The sorted vertex pair ``(a, b)`` as one int64 (pool ids are < 2**31)."""
    if a < b:
        return (a << 32) | b
    return (b << 32) | a


@_jit
def _add_user(edges, counters, key, t):
    """Append triangle ``t`` to the edge's users (False: it had two already)."""
    packed = _table.get(edges, key, 0)
    if packed == 0:
        counters[_EDGES] += _table.put(edges, key, t + 1)
        return True
    if (packed >> 32) != 0:
        return False
    _table.put(edges, key, packed | ((t + 1) << 32))
    return True


@_jit
def _remove_user(edges, counters, key, t):
    """Remove ``t`` from the edge's users, keeping the other's place
    (``list.remove``); drop an edge left without users.  False: not a user."""
    packed = _table.get(edges, key, 0)
    first, second = (packed & _LOW) - 1, (packed >> 32) - 1
    if packed == 0:
        return False
    if first == t:
        if second < 0:
            counters[_EDGES] -= _table.remove(edges, key)
        else:
            _table.put(edges, key, second + 1)
    elif second == t:
        _table.put(edges, key, first + 1)
    else:
        return False
    return True


@_jit
def _link(edges, counters, mass_units, tri_active, t, a, b, c, units):
    """Hierarchy48._link: index triangle ``t`` = ``(a, b, c)`` under its edges
    and give each corner ``units`` mass units, in the reference's order."""
    ok = _add_user(edges, counters, _edge_key(a, b), t)
    ok &= _add_user(edges, counters, _edge_key(b, c), t)
    ok &= _add_user(edges, counters, _edge_key(c, a), t)
    mass_units[a] = mass_units[a] + units
    mass_units[b] = mass_units[b] + units
    mass_units[c] = mass_units[c] + units
    tri_active[t] = True
    return ok


@_jit
def _unlink(edges, counters, mass_units, tri_active, t, a, b, c, units):
    """Hierarchy48._unlink, the inverse of :func:`_link`."""
    ok = _remove_user(edges, counters, _edge_key(a, b), t)
    ok &= _remove_user(edges, counters, _edge_key(b, c), t)
    ok &= _remove_user(edges, counters, _edge_key(c, a), t)
    mass_units[a] = mass_units[a] - units
    mass_units[b] = mass_units[b] - units
    mass_units[c] = mass_units[c] - units
    tri_active[t] = False
    return ok


@_jit
def _new_vertex(vp, counters):
    """A free vertex slot: the last freed one, else the next (room checked)."""
    if counters[_FREE_VERTICES] > 0:
        counters[_FREE_VERTICES] -= 1
        return vp[7][counters[_FREE_VERTICES]]
    counters[_VERTEX_END] += 1
    return counters[_VERTEX_END] - 1


@_jit
def _new_triangle(tp, counters):
    """A free triangle slot: the last freed one, else the next (room checked)."""
    if counters[_FREE_TRIANGLES] > 0:
        counters[_FREE_TRIANGLES] -= 1
        return tp[6][counters[_FREE_TRIANGLES]]
    counters[_TRIANGLE_END] += 1
    return counters[_TRIANGLE_END] - 1


@_jit
def _split(vp, tp, counters, edges, midpoints, left, right, time, max_level):
    """Hierarchy48._split of the sorted edge ``(left, right)``; the status.

    A full pool is not grown here (returning new arrays from a kernel costs
    more than the split): the split returns NEED_VERTICES or NEED_TRIANGLES
    before changing anything, the caller doubles that pool, as the reference
    would in this split, and calls again.
    """
    key = _edge_key(left, right)
    packed = _table.get(edges, key, 0)
    if packed == 0:
        return NOT_HYPOTENUSE
    first, second = (packed & _LOW) - 1, (packed >> 32) - 1
    count = 1 if second < 0 else 2
    tri = tp[0]
    for i in range(count):
        t = first if i == 0 else second
        if _edge_key(tri[t, 1], tri[t, 2]) != key:
            return NOT_HYPOTENUSE
    level = tp[1][first]
    if level >= max_level:
        return AT_MAX_LEVEL
    if counters[_FREE_VERTICES] == 0 and counters[_VERTEX_END] == vp[0].shape[0]:
        return NEED_VERTICES
    if counters[_FREE_TRIANGLES] + tp[0].shape[0] - counters[_TRIANGLE_END] < 2 * count:
        return NEED_TRIANGLES
    if (2 * (counters[_EDGES] + _INDEX_ROOM) > edges.shape[0]
            or 2 * (counters[_MIDPOINTS] + _INDEX_ROOM) > midpoints.shape[0]):
        return NEED_INDEX
    m = _new_vertex(vp, counters)
    uv, x, v = vp[0], vp[1], vp[2]
    # The face rule: nothing moves, and the midpoint takes the ends' average
    # velocity (momentum kept); 0.5 * (a + b) per component as the reference.
    for k in range(2):
        uv[m, k] = 0.5 * (uv[left, k] + uv[right, k])
    for k in range(3):
        x[m, k] = 0.5 * (x[left, k] + x[right, k])
    for k in range(3):
        v[m, k] = 0.5 * (v[left, k] + v[right, k])
    mass_units = vp[3]
    mass_units[m] = 0.0
    vp[4][m] = True
    vp[5][m, 0], vp[5][m, 1] = left, right
    vp[6][m, 0], vp[6][m, 1] = first, second if count == 2 else -1
    units, kid_units = 2.0 ** -level, 2.0 ** -(level + 1)
    ok = True
    for i in range(count):
        t = first if i == 0 else second
        tri = tp[0]
        apex, leg_end, hyp_end = tri[t, 0], tri[t, 1], tri[t, 2]
        ok &= _unlink(edges, counters, mass_units, tp[4], t, apex, leg_end, hyp_end, units)
        kid0 = _new_triangle(tp, counters)
        kid1 = _new_triangle(tp, counters)
        tri, kid_level, parent, children, birth = tp[0], tp[1], tp[2], tp[3], tp[5]
        for j in range(2):
            kid = kid0 if j == 0 else kid1
            b = apex if j == 0 else hyp_end
            c = leg_end if j == 0 else apex
            tri[kid, 0], tri[kid, 1], tri[kid, 2] = m, b, c
            kid_level[kid] = level + 1
            parent[kid] = t
            children[kid, 0] = children[kid, 1] = -1
            ok &= _link(edges, counters, mass_units, tp[4], kid, m, b, c, kid_units)
            birth[kid] = time
        children[t, 0], children[t, 1] = kid0, kid1
    counters[_MIDPOINTS] += _table.put(midpoints, key, m)
    counters[_VERSION] += 1
    return OK if ok else INDEX_BROKEN


@_jit
def _merge(vp, tp, counters, edges, midpoints, left, right, time):
    """Hierarchy48._merge of the sorted edge ``(left, right)``; the status."""
    key = _edge_key(left, right)
    m = _table.get(midpoints, key, -1)
    if m < 0:
        return NOT_SPLIT
    tri, level, children, active, birth = tp[0], tp[1], tp[3], tp[4], tp[5]
    parents = vp[6]
    for i in range(2):
        t = parents[m, i]
        if t >= 0 and not (active[children[t, 0]] and active[children[t, 1]]):
            return REFINED_FURTHER
    mass_units, v = vp[3], vp[2]
    mass_m = mass_units[m]
    ok = True
    for i in range(2):
        t = parents[m, i]
        if t < 0:
            continue
        for j in range(2):
            kid = children[t, j]
            ok &= _unlink(edges, counters, mass_units, active, kid, tri[kid, 0], tri[kid, 1],
                          tri[kid, 2], 2.0 ** -level[kid])
            tp[6][counters[_FREE_TRIANGLES]] = kid
            counters[_FREE_TRIANGLES] += 1
        children[t, 0] = children[t, 1] = -1
        ok &= _link(edges, counters, mass_units, active, t, tri[t, 0], tri[t, 1], tri[t, 2],
                    2.0 ** -level[t])
        birth[t] = time
    # Momentum (merge_velocity_change written out): m's mass went back to the
    # ends equally; both get the same velocity change, in the reference's
    # operation order, and only a nonzero one is added (as the reference).
    ends = mass_units[left] + mass_units[right]
    c0 = mass_m * (v[m, 0] - 0.5 * (v[left, 0] + v[right, 0])) / ends
    c1 = mass_m * (v[m, 1] - 0.5 * (v[left, 1] + v[right, 1])) / ends
    c2 = mass_m * (v[m, 2] - 0.5 * (v[left, 2] + v[right, 2])) / ends
    if c0 != 0.0 or c1 != 0.0 or c2 != 0.0:          # NaN counts as nonzero, as any()
        v[left, 0], v[left, 1], v[left, 2] = v[left, 0] + c0, v[left, 1] + c1, v[left, 2] + c2
        v[right, 0], v[right, 1], v[right, 2] = (v[right, 0] + c0, v[right, 1] + c1,
                                                 v[right, 2] + c2)
    vp[4][m] = False
    mass_units[m] = 0.0
    vp[5][m, 0] = vp[5][m, 1] = -1
    parents[m, 0] = parents[m, 1] = -1
    for k in range(3):
        vp[1][m, k] = 0.0
        v[m, k] = 0.0
    vp[7][counters[_FREE_VERTICES]] = m
    counters[_FREE_VERTICES] += 1
    counters[_MIDPOINTS] -= _table.remove(midpoints, key)
    counters[_VERSION] += 1
    return OK if ok else INDEX_BROKEN


@_jit
def _refine(vp, tp, counters, edges, midpoints, t, time, max_level, log, logged):
    """Hierarchy48.refine(t) with its forced splits, logged from ``log[logged]``.

    The reference recurses into the coarser neighbour across the hypotenuse
    before splitting; the neighbours form a chain of strictly coarser
    triangles, so walking it first and splitting its hypotenuses from the far
    end is the same sequence.  Nothing is split if a link is inactive or at
    the maximum level.  Returns ``(status, left, right, logged)`` (the edge
    whose split failed or lacked room, else -1).  After a NEED_* status and
    the growth, the same call again walks only what is left of the chain
    (the links split already are conforming now), so it resumes exactly.
    """
    chain = np.empty((max_level + 2, 2), np.int64)
    length = 0
    current = t
    while True:
        tri = tp[0]
        if not tp[4][current] or tp[1][current] >= max_level or length == chain.shape[0]:
            return OK, -1, -1, logged
        a, b = min(tri[current, 1], tri[current, 2]), max(tri[current, 1], tri[current, 2])
        chain[length, 0], chain[length, 1] = a, b
        length += 1
        key = _edge_key(a, b)
        packed = _table.get(edges, key, 0)
        coarser = -1
        for user in ((packed & _LOW) - 1, (packed >> 32) - 1):
            if (coarser < 0 and user >= 0 and user != current
                    and _edge_key(tri[user, 1], tri[user, 2]) != key):
                coarser = user
        if coarser < 0:
            break
        current = coarser
    for i in range(length - 1, -1, -1):
        status = _split(vp, tp, counters, edges, midpoints, chain[i, 0], chain[i, 1], time,
                        max_level)
        if status != OK:
            return status, chain[i, 0], chain[i, 1], logged
        log[logged, 0], log[logged, 1], log[logged, 2] = SPLIT, chain[i, 0], chain[i, 1]
        logged += 1
    return OK, -1, -1, logged


@_jit
def _squared_norm(a0, a1, a2):
    """``einsum('kd,kd->k')`` of one row, in its summation order (0, 2, then 1)."""
    return (a0 * a0 + a2 * a2) + a1 * a1


@_jit
def merge_kinetic(v, m, left, right, m_mid, m_left, m_right):
    """``merge_energy.merge_kinetic_change`` of one merge, J, bitwise: ``v`` ``(n, 3)``
    m/s, ``m`` the midpoint, ``left``/``right`` the edge ends, masses in kg (the
    LOD criterion's merge energies use it too, lod_kernels)."""
    ends = m_left + m_right + m_mid
    c0 = m_mid * (v[m, 0] - 0.5 * (v[left, 0] + v[right, 0])) / ends
    c1 = m_mid * (v[m, 1] - 0.5 * (v[left, 1] + v[right, 1])) / ends
    c2 = m_mid * (v[m, 2] - 0.5 * (v[left, 2] + v[right, 2])) / ends
    before = (m_left * _squared_norm(v[left, 0], v[left, 1], v[left, 2])
              + m_right * _squared_norm(v[right, 0], v[right, 1], v[right, 2])
              + m_mid * _squared_norm(v[m, 0], v[m, 1], v[m, 2]))
    after = ((m_left + 0.5 * m_mid) * _squared_norm(v[left, 0] + c0, v[left, 1] + c1,
                                                    v[left, 2] + c2)
             + (m_right + 0.5 * m_mid) * _squared_norm(v[right, 0] + c0, v[right, 1] + c1,
                                                       v[right, 2] + c2))
    return 0.5 * (after - before)


@_jit
def _add_triangle_edges(changed, tri, t, legs_only):
    """Put triangle ``t``'s edges (or its two legs) in the set ``changed``."""
    changed.add(_edge_key(tri[t, 0], tri[t, 1]))
    changed.add(_edge_key(tri[t, 2], tri[t, 0]))
    if not legs_only:
        changed.add(_edge_key(tri[t, 1], tri[t, 2]))


@_jit
def _execute(vp, tp, counters, edges, midpoints, direct, refine, merge, energy, kinetic,
             bound, check_energy, time, max_level, unit_mass, log, resume):
    """Carry out ``direct`` operations (``(p, 3)`` rows kind, left, right), then
    the refinements ``refine`` ``(r,)`` and the merges ``merge`` ``(k, 2)`` of a
    decision with LodPolicy.apply's re-checks (its docstring says why).

    Operations are logged in ``log`` (rows kind, left, right).  ``resume``
    ``(5,)`` int64 is where to start and is updated in place: the next direct
    operation, the next refinement, the log rows written, the rows of whole
    requests (a refinement that failed half way is not one) and the rows
    before the merges.  Returns ``(status, left, right)``: OK, or the failure
    (or NEED_* to grow a pool and call again) and its edge.
    """
    if resume[2] == 0:          # first call: ids the reference would index otherwise
        for i in range(refine.shape[0]):
            if refine[i] < 0 or refine[i] >= tp[0].shape[0]:
                return OUT_OF_RANGE, -1, -1
        for i in range(merge.shape[0]):
            if min(merge[i, 0], merge[i, 1]) < 0 or max(merge[i, 0], merge[i, 1]) >= 2**31:
                return OUT_OF_RANGE, -1, -1
    for i in range(resume[0], direct.shape[0]):
        kind, a, b = direct[i, 0], direct[i, 1], direct[i, 2]
        if kind == SPLIT:
            status = _split(vp, tp, counters, edges, midpoints, a, b, time, max_level)
        else:
            status = _merge(vp, tp, counters, edges, midpoints, a, b, time)
        if status != OK:
            return status, a, b
        log[resume[2], 0], log[resume[2], 1], log[resume[2], 2] = kind, a, b
        resume[0], resume[2], resume[3] = i + 1, resume[2] + 1, resume[2] + 1
    for i in range(resume[1], refine.shape[0]):
        status, a, b, logged = _refine(vp, tp, counters, edges, midpoints, refine[i], time,
                                       max_level, log, resume[2])
        resume[2] = logged
        if status != OK:
            return status, a, b
        resume[1], resume[3] = i + 1, logged
    resume[4] = resume[2]
    if merge.shape[0] == 0:
        return OK, -1, -1
    # What the refinements changed: the ends of every split edge (mass and
    # velocity) and every edge of the triangles they split.
    moved = {np.int64(-1)}           # particles whose mass or velocity changed
    changed = {np.int64(-1)}         # packed edges whose triangles were replaced
    for j in range(direct.shape[0], resume[2]):
        a, b = log[j, 1], log[j, 2]
        moved.add(a)
        moved.add(b)
        m = _table.get(midpoints, _edge_key(a, b), -1)
        for p in range(2):
            if vp[6][m, p] >= 0:
                _add_triangle_edges(changed, tp[0], vp[6][m, p], False)
    for i in range(merge.shape[0]):
        a, b = merge[i, 0], merge[i, 1]
        key = _edge_key(a, b)
        m = _table.get(midpoints, key, -1)
        if a >= b or m < 0:    # (an unsorted pair is not a key there either)
            continue
        if check_energy and (a in moved or b in moved):
            again = merge_kinetic(vp[2], m, a, b, vp[3][m] * unit_mass, vp[3][a] * unit_mass,
                                  vp[3][b] * unit_mass)
            if energy[i] - kinetic[i] + again > bound[i]:
                continue
        tri, children, active = tp[0], tp[3], tp[4]
        mergeable = True
        for p in range(2):
            t = vp[6][m, p]
            if t < 0:
                continue
            mergeable &= active[children[t, 0]] and active[children[t, 1]]
            for outer in (_edge_key(tri[t, 0], tri[t, 1]), _edge_key(tri[t, 2], tri[t, 0])):
                mergeable &= outer not in changed
        if not mergeable:
            continue
        first, second = vp[6][m, 0], vp[6][m, 1]       # the merge clears them
        status = _merge(vp, tp, counters, edges, midpoints, a, b, time)
        if status != OK:
            return status, a, b
        log[resume[2], 0], log[resume[2], 1], log[resume[2], 2] = MERGE, a, b
        resume[2] += 1
        resume[3] = resume[2]
        moved.add(a)
        moved.add(b)
        for t in (first, second):
            if t >= 0:
                _add_triangle_edges(changed, tp[0], t, True)
    return OK, -1, -1


class CompiledIndex:
    """The edge index, midpoint map and free lists of a hierarchy in the
    kernels' form (module docstring), built from the reference's containers.

    Args:
        edges: sorted vertex pair -> list of its one or two active triangles.
        midpoint: split edge -> its midpoint's pool id.
        free_vertices, free_triangles: the free lists (the last is reused first).
        vertex_capacity, triangle_capacity: pool sizes (the stacks' lengths).
    """

    def __init__(self, edges: dict, midpoint: dict, free_vertices: list,
                 free_triangles: list, vertex_capacity: int, triangle_capacity: int):
        if any(len(u) > 2 for u in edges.values()):
            raise ValueError("an edge with more than two triangles")
        pairs = np.array(list(edges), dtype=np.int64).reshape(-1, 2)
        users = np.array([(u[0], u[1] if len(u) > 1 else -1) for u in edges.values()],
                         dtype=np.int64).reshape(-1, 2) + 1
        self.edges = _table.build(_packed(pairs), users[:, 0] | (users[:, 1] << 32))
        split = np.array(list(midpoint), dtype=np.int64).reshape(-1, 2)
        self.midpoints = _table.build(_packed(split),
                                      np.array(list(midpoint.values()), dtype=np.int64))
        self.edge_count, self.midpoint_count = len(pairs), len(split)
        self.free_vertex_stack = np.zeros(vertex_capacity, np.int64)
        self.free_vertex_stack[:len(free_vertices)] = free_vertices
        self.free_triangle_stack = np.zeros(triangle_capacity, np.int64)
        self.free_triangle_stack[:len(free_triangles)] = free_triangles
        self.free_vertex_count, self.free_triangle_count = len(free_vertices), len(free_triangles)

    def to_python(self) -> tuple[dict, dict, list, list]:
        """The reference's ``(edges, midpoint, free_vertices, free_triangles)``
        (the dicts in the order of their keys: their order means nothing)."""
        keys, packed = _table.items(self.edges)
        edges = {(a, b): [t - 1 for t in pair if t]
                 for a, b, *pair in zip((keys >> 32).tolist(), (keys & _LOW).tolist(),
                                        (packed & _LOW).tolist(), (packed >> 32).tolist())}
        keys, mids = _table.items(self.midpoints)
        midpoint = {(a, b): m for a, b, m in zip((keys >> 32).tolist(), (keys & _LOW).tolist(),
                                                 mids.tolist())}
        return (edges, midpoint, self.free_vertex_stack[:self.free_vertex_count].tolist(),
                self.free_triangle_stack[:self.free_triangle_count].tolist())

    def edge_triangles(self, a: int, b: int) -> list[int]:
        """Active triangles on the edge ``(a, b)`` in the reference's list order."""
        if not (0 <= a < 2**31 and 0 <= b < 2**31):
            return []
        packed = int(_table.get(self.edges, int(_edge_key(int(a), int(b))), 0))
        return [t - 1 for t in (packed & _LOW, packed >> 32) if t]

    def grow(self) -> None:
        """Both tables rehashed to at most a third full (a kernel found one half full)."""
        self.edges = _table.grown(self.edges, self.edge_count)
        self.midpoints = _table.grown(self.midpoints, self.midpoint_count)


def _packed(pairs: np.ndarray) -> np.ndarray:
    """``(k, 2)`` sorted vertex pairs as the kernels' int64 keys ``lo << 32 | hi``."""
    return (pairs[:, 0] << 32) | pairs[:, 1]


_EMPTY_OPS, _EMPTY_EDGES = np.zeros((0, 3), np.int64), np.zeros((0, 2), np.int64)
_EMPTY_IDS, _EMPTY_VALUES = np.zeros(0, np.int64), np.zeros(0)


def execute(hierarchy, index: CompiledIndex, time: float, direct=_EMPTY_OPS, refine=_EMPTY_IDS,
            merge=_EMPTY_EDGES, energy=None, kinetic=None, bound=None):
    """Run :func:`_execute` on ``hierarchy``'s pools and write back what it changed.

    Args:
        hierarchy: the :class:`~cloth_lod_ros.sim.mesh.hierarchy.Hierarchy48`.
        index: its :class:`CompiledIndex` (current).
        time: simulation time, s (birth of new triangles).
        direct: ``(p, 3)`` int64 operations ``kind, left, right`` to apply as given.
        refine: ``(r,)`` int64 pool triangles to refine, in ``[0, capacity)``.
        merge: ``(k, 2)`` int64 edges to merge with LodPolicy.apply's checks.
        energy, kinetic, bound: ``(k,)`` J, the decision's merge energies (None:
            no kinetic re-test).

    Returns:
        ``(status, edge, log, complete, splits)``: status (:data:`OK`, the
        reason an operation failed, for ``edge``, or OUT_OF_RANGE: nothing
        done), the ``(n, 3)`` log of the operations performed, how many of
        them belong to whole requests, and how many precede the merges.
    """
    h = hierarchy
    counters = np.array([h.vertex_end, h.tri_end, index.free_vertex_count,
                         index.free_triangle_count, h.version, index.edge_count,
                         index.midpoint_count], dtype=np.int64)
    check_energy = energy is not None
    if not check_energy:
        energy = kinetic = bound = _EMPTY_VALUES
    # A refinement makes at most one split per level of its chain.
    log = np.empty((len(direct) + len(refine) * (h.max_level + 2) + len(merge), 3), np.int64)
    resume = np.zeros(5, np.int64)
    while True:
        vp = (h.uv, h.x, h.v, h.mass_units, h.vertex_active, h.vertex_edge, h.vertex_parents,
              index.free_vertex_stack)
        tp = (h.tri, h.level, h.parent, h.children, h.tri_active, h.birth,
              index.free_triangle_stack)
        status, left, right = _execute(vp, tp, counters, index.edges, index.midpoints, direct,
                                       refine, merge, energy, kinetic, bound, check_energy,
                                       float(time), h.max_level, h.unit_mass, log, resume)
        if status == NEED_VERTICES:
            h._grow_vertices()
            index.free_vertex_stack = np.resize(index.free_vertex_stack, len(h.uv))
        elif status == NEED_TRIANGLES:
            h._grow_triangles()
            index.free_triangle_stack = np.resize(index.free_triangle_stack, len(h.tri))
        elif status == NEED_INDEX:
            index.edge_count, index.midpoint_count = int(counters[_EDGES]), int(
                counters[_MIDPOINTS])
            index.grow()
        else:
            break
    (h.vertex_end, h.tri_end, index.free_vertex_count, index.free_triangle_count,
     h.version, index.edge_count, index.midpoint_count) = counters.tolist()
    return int(status), (int(left), int(right)), log[:resume[2]], int(resume[3]), int(resume[4])
