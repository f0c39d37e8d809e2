"""Compiled (numba) kernels for what a topology change builds from the new mesh.

An adaptive mesh changes topology at a fraction of its steps, and every
change rebuilds the same pure functions of the new triangles: the interior
edges as hinges (:func:`cloth_lod_ros.sim.mesh48.build_hinges`), the rest
coefficients of every element (:func:`cloth_lod_ros.sim.forces.precompute`)
and the first solve's sparsity pattern with its block slots
(:class:`cloth_lod_ros.sim.linear.SparsePattern`).  At adaptive-mesh sizes
(a few hundred particles) their numpy code is mostly the overhead of some
dozens of small passes; these kernels do each in a few loops.

The numpy code stays the reference: the results here are *bitwise* equal
(same arrays, dtypes and order; the floating-point operations are the
reference's, in its order, and numba contracts nothing into FMAs without
fastmath).  The switch is :mod:`~cloth_lod_ros.sim.kernels`'
(:func:`~cloth_lod_ros.sim.kernels.enabled`, ``CLOTH_LOD_KERNELS=numpy``);
without numba everything is the reference.  Inputs the kernels do not expect
(other dtypes, vertex indices outside ``[0, n)``) go to the reference too:
its result or its error, never a write out of bounds.
"""

from __future__ import annotations

import numpy as np

from . import forces as _forces
from . import kernels as _kernels
from . import mesh48 as _mesh48

__all__ = ["build_hinges", "precompute", "sparse_pattern", "warm_up"]

_jit = _kernels._jit


@_jit
def _hinges(t, n):
    """Interior and border edges of triangles ``t`` ``(m, 3)`` int64 over ``n``
    vertices, as mesh48.build_hinges finds them.

    Half-edge 3i + k runs t[i,k] -> t[i,(k+1)%3].  The reference groups them
    by a *stable* sort of the keys ``lo·(n+1) + hi``; here a counting sort by
    ``lo`` (stable) then a stable insertion sort by ``hi`` inside each ``lo``
    bucket (a handful of half-edges) gives the same order.

    Returns ``(status, edge, opposite, triangles, is_hypotenuse, border)``
    (``(h, 2)`` each, the last ``(b, 2)``; Hinges' fields); status 0 ok, 1 an
    index outside ``[0, n)``, 2 an edge in more than two triangles, 3 two
    triangles traversing an edge the same way (then the arrays are empty).
    """
    m = t.shape[0]
    empty = np.empty((0, 2), np.int64)
    fail = (empty, empty, empty, np.empty((0, 2), np.bool_), empty)
    count = np.zeros(n + 1, np.int64)
    for i in range(m):
        for k in range(3):
            a, b = t[i, k], t[i, (k + 1) % 3]
            if a < 0 or a >= n or b < 0 or b >= n:
                return (1,) + fail
            count[min(a, b) + 1] += 1
    for v in range(n):
        count[v + 1] += count[v]
    fill = count[:n].copy()
    order = np.empty(3 * m, np.int64)
    lo = np.empty(3 * m, np.int64)
    hi = np.empty(3 * m, np.int64)
    for h in range(3 * m):
        a, b = t[h // 3, h % 3], t[h // 3, (h + 1) % 3]
        p = fill[min(a, b)]
        order[p], lo[p], hi[p] = h, min(a, b), max(a, b)
        fill[min(a, b)] += 1
    for v in range(n):
        for p in range(count[v] + 1, count[v + 1]):
            key, h = hi[p], order[p]
            q = p - 1
            while q >= count[v] and hi[q] > key:        # strict: equal keys keep order
                hi[q + 1], order[q + 1] = hi[q], order[q]
                q -= 1
            hi[q + 1], order[q + 1] = key, h
    # Group sizes: a first pass counts, so the outputs are allocated exactly.
    n_pairs = n_border = 0
    status = 0
    p = 0
    while p < 3 * m:
        q = p + 1
        while q < 3 * m and lo[q] == lo[p] and hi[q] == hi[p]:
            q += 1
        if q - p > 2:
            status = 2
        elif q - p == 2:
            first, second = order[p], order[p + 1]
            if t[first // 3, first % 3] == t[second // 3, second % 3] and status == 0:
                status = 3
            n_pairs += 1
        else:
            n_border += 1
        p = q
    if status != 0:
        return (status,) + fail
    edge = np.empty((n_pairs, 2), np.int64)
    opposite = np.empty((n_pairs, 2), np.int64)
    tris = np.empty((n_pairs, 2), np.int64)
    hyp = np.empty((n_pairs, 2), np.bool_)
    border = np.empty((n_border, 2), np.int64)
    w = b = p = 0
    while p < 3 * m:
        h = order[p]
        if p + 1 < 3 * m and lo[p + 1] == lo[p] and hi[p + 1] == hi[p]:
            edge[w, 0], edge[w, 1] = t[h // 3, h % 3], t[h // 3, (h + 1) % 3]
            for s in range(2):
                hs = order[p + s]
                tris[w, s] = hs // 3
                hyp[w, s] = hs % 3 == 1            # corner 0 is the apex
                opposite[w, s] = t[hs // 3, (hs + 2) % 3]
            w += 1
            p += 2
        else:
            border[b, 0], border[b, 1] = t[h // 3, h % 3], t[h // 3, (h + 1) % 3]
            b += 1
            p += 1
    return status, edge, opposite, tris, hyp, border


def build_hinges(triangles: np.ndarray, vertex_count: int) -> _mesh48.Hinges:
    """:func:`cloth_lod_ros.sim.mesh48.build_hinges` (the same arrays bitwise,
    the same errors), compiled when :func:`~cloth_lod_ros.sim.kernels.enabled`."""
    t = np.asarray(triangles)
    if not _kernels.enabled() or t.dtype != np.int64 or t.ndim != 2 or t.shape[1] != 3:
        return _mesh48.build_hinges(triangles, vertex_count)
    status, edge, opposite, tris, hyp, border = _hinges(np.ascontiguousarray(t),
                                                        int(vertex_count))
    if status == 2:
        raise _mesh48.MeshError("non-manifold mesh: an edge is shared by more than two triangles")
    if status == 3:
        raise _mesh48.MeshError(
            "inconsistent orientation: two triangles traverse an edge the same way")
    if status != 0:
        return _mesh48.build_hinges(triangles, vertex_count)
    return _mesh48.Hinges(edge=edge, opposite=opposite, triangles=tris,
                          is_hypotenuse=hyp, boundary_edges=border)


@_jit
def _element_data(uv, tri, edge, opposite, hinge_tri, hyp):
    """forces.triangle_maps and hinge_weights in one pass each, the same
    operations in the same order.

    Args: uv ``(n, 2)`` m; tri ``(t, 3)``; edge, opposite, hinge_tri, hyp
    ``(h, 2)`` (mesh48.Hinges).  Returns ``(ok, area (t,), coef_u (t, 3),
    coef_v (t, 3), hinge_vertices (h, 4), weight (h,))``; ok False (and
    empty arrays) when an index is outside its array.
    """
    n, t_count, h_count = uv.shape[0], tri.shape[0], edge.shape[0]
    area = np.empty(t_count)
    coef_u = np.empty((t_count, 3))
    coef_v = np.empty((t_count, 3))
    hv = np.empty((h_count, 4), np.int64)
    weight = np.empty(h_count)
    fail = (False, area[:0], coef_u[:0], coef_v[:0], hv[:0], weight[:0])
    for i in range(t_count):
        p, q, r = tri[i, 0], tri[i, 1], tri[i, 2]
        if min(p, q, r) < 0 or max(p, q, r) >= n:
            return fail
        d1u, d1v = uv[q, 0] - uv[p, 0], uv[q, 1] - uv[p, 1]
        d2u, d2v = uv[r, 0] - uv[p, 0], uv[r, 1] - uv[p, 1]
        det = d1u * d2v - d2u * d1v
        a1, a2 = d2v / det, -d1v / det
        b1, b2 = -d2u / det, d1u / det
        coef_u[i, 0], coef_u[i, 1], coef_u[i, 2] = -(a1 + a2), a1, a2
        coef_v[i, 0], coef_v[i, 1], coef_v[i, 2] = -(b1 + b2), b1, b2
        area[i] = 0.5 * det
    for h in range(h_count):
        e0, e1, s0, s1 = edge[h, 0], edge[h, 1], hinge_tri[h, 0], hinge_tri[h, 1]
        if (min(e0, e1) < 0 or max(e0, e1) >= n or min(s0, s1) < 0
                or max(s0, s1) >= t_count):
            return fail
        hv[h, 0], hv[h, 1], hv[h, 2], hv[h, 3] = e0, e1, opposite[h, 0], opposite[h, 1]
        eu, ev = uv[e1, 0] - uv[e0, 0], uv[e1, 1] - uv[e0, 1]
        # einsum's sum of products starts from 0 (exact: 0 + x == x).
        length2 = eu * eu + ev * ev
        count = (1.0 if hyp[h, 0] else 0.0) + (1.0 if hyp[h, 1] else 0.0)
        gamma = 1.0 - 0.25 * count
        weight[h] = gamma * length2 / (area[s0] + area[s1])
    return True, area, coef_u, coef_v, hv, weight


@_jit
def _mesh_elements(uv, tri, n):
    """:func:`_hinges` and :func:`_element_data` of a mesh in one call (a new
    topology's whole precompute: one dispatch, no arrays through Python in
    between).  Returns ``(status, edge, opposite, triangles, is_hypotenuse,
    border, ok, area, coef_u, coef_v, hinge_vertices, weight)``: _hinges'
    status and arrays, then _element_data's (``ok`` False and empty arrays
    when status is not 0)."""
    status, edge, opposite, tris, hyp, border = _hinges(tri, n)
    if status != 0:
        e = np.empty(0)
        return (status, edge, opposite, tris, hyp, border, False, e, np.empty((0, 3)),
                np.empty((0, 3)), np.empty((0, 4), np.int64), e)
    ok, area, coef_u, coef_v, hv, weight = _element_data(uv, tri, edge, opposite, tris, hyp)
    return status, edge, opposite, tris, hyp, border, ok, area, coef_u, coef_v, hv, weight


def precompute(mesh: _mesh48.RestMesh) -> _forces.Elements:
    """:func:`cloth_lod_ros.sim.forces.precompute` (the same arrays bitwise),
    compiled when :func:`~cloth_lod_ros.sim.kernels.enabled`."""
    uv, tri = mesh.uv, mesh.triangles
    if (not _kernels.enabled() or uv.dtype != np.float64 or tri.dtype != np.int64
            or uv.ndim != 2 or uv.shape[1] != 2 or tri.ndim != 2 or tri.shape[1] != 3):
        return _forces.precompute(mesh)
    if "hinges" not in mesh._cache:
        # A new mesh (every topology change): hinges and element data in one call.
        (status, edge, opposite, tris, hyp, border, ok, area, coef_u, coef_v, hv,
         weight) = _mesh_elements(_kernels._as_float(uv), _kernels._as_index(tri),
                                  mesh.vertex_count)
        if status == 0 and ok:
            mesh._cache["hinges"] = _mesh48.Hinges(edge=edge, opposite=opposite,
                                                   triangles=tris, is_hypotenuse=hyp,
                                                   boundary_edges=border)
            return _forces.Elements(
                triangles=tri.copy(), area=area, coef_u=coef_u, coef_v=coef_v,
                hinge_vertices=hv, hinge_weight=weight, hinge_triangles=tris,
                vertex_count=mesh.vertex_count)
    hinges = mesh.hinges()          # the errors of build_hinges, or its cached arrays
    ok, area, coef_u, coef_v, hv, weight = _element_data(
        np.ascontiguousarray(uv), np.ascontiguousarray(tri),
        *(np.ascontiguousarray(a) for a in (hinges.edge, hinges.opposite,
                                            hinges.triangles, hinges.is_hypotenuse)))
    if not ok:
        return _forces.precompute(mesh)
    return _forces.Elements(
        triangles=tri.copy(), area=area, coef_u=coef_u, coef_v=coef_v,
        hinge_vertices=hv, hinge_weight=weight, hinge_triangles=hinges.triangles,
        vertex_count=mesh.vertex_count)


@_jit
def _pattern(n, kinds, slots, scratch):
    """linear.SparsePattern's block pattern and block slots.

    Args: n vertices; kinds a tuple of ``(e, k)`` int64 element vertex
    arrays; slots ``(Σ e k²,)`` int64, written: each vertex pair's block
    slot (``9 · block``); scratch int64 of at least
    ``3 Σ e k² + 2n`` (contents undefined; the large temporaries live there,
    as fresh pages of that size would cost a page fault each).  The blocks are the
    distinct vertex pairs of all elements plus every ``(i, i)``, sorted by
    row then column (the reference's sorted keys ``i·n + j``).  Every pair
    entry goes to its row's bucket (a counting sort); per row, the distinct
    columns (a mark per vertex, no n² table) are sorted (a few: insertion)
    and give each bucket entry its block.

    Returns ``(ok, indices (blocks,) int32, indptr (n + 1,) int32,
    diagonal_block (n,) int64)``; ok False when an index is outside ``[0, n)``.
    """
    count = np.zeros(n + 1, np.int64)
    entries = 0
    for v in kinds:
        for q in range(v.shape[0]):
            for i in range(v.shape[1]):
                if v[q, i] < 0 or v[q, i] >= n:
                    return False, np.empty(0, np.int32), np.empty(0, np.int32), count[:0]
                count[v[q, i] + 1] += v.shape[1]
        entries += v.size * v.shape[1]
    for r in range(n):
        count[r + 1] += count[r] + 1                # + 1: the diagonal block, last
    # Bucket position of every pair entry, in (kind, e, i, j) order.
    fill = count[:n].copy()
    columns = scratch[:count[n]]        # each pair's column, then its block
    position = scratch[count[n]:count[n] + entries]
    found = scratch[count[n] + entries:2 * count[n] + entries]
    g = 0
    for v in kinds:
        for q in range(v.shape[0]):
            for i in range(v.shape[1]):
                r = v[q, i]
                for j in range(v.shape[1]):
                    columns[fill[r]] = v[q, j]
                    position[g] = fill[r]
                    fill[r] += 1
                    g += 1
    for r in range(n):
        columns[fill[r]] = r
    indptr = np.empty(n + 1, np.int32)
    mark = np.full(n, -1, np.int64)
    where = np.empty(n, np.int64)
    unique = np.empty(n, np.int64)
    diagonal = np.empty(n, np.int64)
    indptr[0] = blocks = 0
    for r in range(n):
        u = 0
        for p in range(count[r], count[r + 1]):
            c = columns[p]
            if mark[c] != r:
                mark[c] = r
                s = u                               # insertion into the sorted few
                while s > 0 and unique[s - 1] > c:
                    unique[s] = unique[s - 1]
                    s -= 1
                unique[s] = c
                u += 1
        for s in range(u):
            found[blocks + s] = unique[s]
            where[unique[s]] = blocks + s
        for p in range(count[r], count[r + 1]):
            columns[p] = where[columns[p]]
        diagonal[r] = where[r]
        blocks += u
        indptr[r + 1] = blocks
    # Pair (e, i, j) of a kind at 9·block(e, i, j): the flat data index of
    # its block's entry (0, 0), in (kind, e, i, j) order (SparsePattern
    # derives the nine entry slots from it when they are asked for).
    for g in range(entries):
        slots[g] = 9 * columns[position[g]]
    indices = np.empty(blocks, np.int32)
    for s in range(blocks):
        indices[s] = found[s]
    return True, indices, indptr, diagonal


@_jit
def _mesh_pattern(n, tri, hv, ht, slots, scratch):
    """:func:`_pattern` of a mesh's ``[triangles, hinges]``, from the triangles.

    Args: n vertices; tri ``(t, 3)`` and hv ``(h, 4)`` int64 (the kinds of
    _pattern, in that order); ht ``(h, 2)`` int64 each hinge's two
    triangles (forces.Elements.hinge_triangles: the first holds e0, e1, o0,
    the second e0, e1, o1); slots ``(9 t + 16 h,)`` written as _pattern
    writes them; scratch int64 of at least ``12 t + 4 h + n``.

    A hinge's pairs are its triangles' pairs and (o0, o1), (o1, o0): so the
    blocks are the triangles' pairs, those two per hinge and the diagonal
    (the same set as _pattern's), and a hinge's 16 slots are copies of its
    triangles' 9 + 5 and two of its own.  Rows take their columns from ~3
    corners per incident triangle and one per hinge across, not the ~4 x 4
    of every element at them: a third of _pattern's marking and lookups.

    Returns _pattern's ``(ok, indices, indptr, diagonal_block)``, the same
    arrays; ok False when an index is out of range or a hinge's vertices
    are not in its triangles (then _pattern, or the reference, builds it).
    """
    t_count, h_count = tri.shape[0], hv.shape[0]
    fail = (False, np.empty(0, np.int32), np.empty(0, np.int32), np.empty(0, np.int64))
    # Each hinge's corners in its triangles: e0, e1, o0 in the first, e0, e1, o1 in the second.
    where_in = np.empty((h_count, 6), np.int64)
    for h in range(h_count):
        first, second = ht[h, 0], ht[h, 1]
        if first < 0 or first >= t_count or second < 0 or second >= t_count:
            return fail
        for k in range(3):
            a0, a1 = hv[h, k], hv[h, k + 1 if k == 2 else k]
            c0 = c1 = -1
            for c in range(2, -1, -1):     # the first matching corner
                if tri[first, c] == a0:
                    c0 = c
                if tri[second, c] == a1:
                    c1 = c
            if c0 < 0 or c1 < 0:
                return fail
            where_in[h, k], where_in[h, 3 + k] = c0, c1
    tri_count = np.zeros(n + 1, np.int64)
    across_count = np.zeros(n + 1, np.int64)
    for t in range(t_count):
        for c in range(3):
            a = tri[t, c]
            if a < 0 or a >= n:
                return fail
            tri_count[a + 1] += 1
    for h in range(h_count):          # o0, o1 are in the triangles: in range
        across_count[hv[h, 2] + 1] += 1
        across_count[hv[h, 3] + 1] += 1
    for r in range(n):
        tri_count[r + 1] += tri_count[r]
        across_count[r + 1] += across_count[r]
    # Buckets: each triangle corner as 4 t + corner, each hinge end across as 2 h + side.
    corners = scratch[:3 * t_count]
    across = scratch[3 * t_count:3 * t_count + 2 * h_count]
    found = scratch[3 * t_count + 2 * h_count:]
    fill = tri_count[:n].copy()
    for t in range(t_count):
        for c in range(3):
            corners[fill[tri[t, c]]] = 4 * t + c
            fill[tri[t, c]] += 1
    fill[:] = across_count[:n]
    for h in range(h_count):
        for side in range(2):
            across[fill[hv[h, 2 + side]]] = 2 * h + side
            fill[hv[h, 2 + side]] += 1
    hinge_base = 9 * t_count
    indptr = np.empty(n + 1, np.int32)
    mark = np.full(n, -1, np.int64)
    where = np.empty(n, np.int64)
    unique = np.empty(n, np.int64)
    diagonal = np.empty(n, np.int64)
    indptr[0] = blocks = 0
    for r in range(n):
        mark[r] = r                          # the diagonal block is always there
        unique[0] = r
        u = 1
        # Columns: the corners of the triangles at r, then the hinge ends
        # across from r (written out twice: a helper call per column would
        # cost its array arguments' reference counts).
        for p in range(tri_count[r], tri_count[r + 1]):
            t = corners[p] >> 2
            for j in range(3):
                col = tri[t, j]
                if mark[col] != r:
                    mark[col] = r
                    s = u                           # insertion into the sorted few
                    while s > 0 and unique[s - 1] > col:
                        unique[s] = unique[s - 1]
                        s -= 1
                    unique[s] = col
                    u += 1
        for p in range(across_count[r], across_count[r + 1]):
            col = hv[across[p] >> 1, 3 - (across[p] & 1)]
            if mark[col] != r:
                mark[col] = r
                s = u
                while s > 0 and unique[s - 1] > col:
                    unique[s] = unique[s - 1]
                    s -= 1
                unique[s] = col
                u += 1
        for s in range(u):
            found[blocks + s] = unique[s]
            where[unique[s]] = blocks + s
        diagonal[r] = where[r]
        # Pair (e, i, j) at 9·block(e, i, j), in _pattern's layout.
        for p in range(tri_count[r], tri_count[r + 1]):
            t, c = corners[p] >> 2, corners[p] & 3
            for j in range(3):
                slots[9 * t + 3 * c + j] = 9 * where[tri[t, j]]
        for p in range(across_count[r], across_count[r + 1]):
            h, side = across[p] >> 1, across[p] & 1
            # Row o0 (side 0): pair (2, 3); row o1: pair (3, 2).
            slots[hinge_base + 16 * h + 4 * (2 + side) + 3 - side] = 9 * where[hv[h, 3 - side]]
        blocks += u
        indptr[r + 1] = blocks
    # The hinges' other pairs from their triangles'.
    for h in range(h_count):
        first, second = 9 * ht[h, 0], 9 * ht[h, 1]
        out = hinge_base + 16 * h
        for i in range(3):
            for j in range(3):
                slots[out + 4 * i + j] = slots[first + 3 * where_in[h, i] + where_in[h, j]]
        o1 = where_in[h, 5]
        for i in range(2):                  # e0, e1 with o1, both ways
            e = where_in[h, 3 + i]
            slots[out + 4 * i + 3] = slots[second + 3 * e + o1]
            slots[out + 12 + i] = slots[second + 3 * o1 + e]
        slots[out + 15] = slots[second + 4 * o1]
    indices = np.empty(blocks, np.int32)
    for s in range(blocks):
        indices[s] = found[s]
    return True, indices, indptr, diagonal


def sparse_pattern(n: int, element_vertices: list[np.ndarray], slots: np.ndarray,
                   storage=None, hinge_triangles: np.ndarray | None = None):
    """The compiled twin of :class:`~cloth_lod_ros.sim.linear.SparsePattern`'s
    build: ``(indices (blocks,) int32, indptr (n + 1,) int32, diagonal_block
    (n,) int64)`` with every vertex pair's block slot written into ``slots``
    (int64, ``Σ e k²``: one per pair, in element order); None when the reference is to build it (kernels off, no
    elements, an index outside ``[0, n)``).

    Args: n vertices; element_vertices ``(e, k)`` int64 arrays; storage the
    :class:`~cloth_lod_ros.sim.linear.PatternStorage` whose scratch table to
    use (None: a fresh one); hinge_triangles ``(h, 2)``: with
    ``element_vertices`` a mesh's ``[triangles (t, 3), hinges (h, 4)]``, each
    hinge's triangles (forces.Elements), for :func:`_mesh_pattern`.
    """
    if not _kernels.enabled() or not element_vertices or slots.dtype != np.int64:
        return None
    kinds = tuple(np.ascontiguousarray(v) for v in element_vertices)
    if any(v.ndim != 2 or v.dtype != np.int64 for v in kinds):
        return None
    if (hinge_triangles is not None and len(kinds) == 2 and kinds[0].shape[1] == 3
            and kinds[1].shape[1] == 4 and hinge_triangles.dtype == np.int64
            and hinge_triangles.shape == (len(kinds[1]), 2)):
        size = 12 * len(kinds[0]) + 4 * len(kinds[1]) + n
        scratch = storage.rank_table(size) if storage is not None else np.empty(size, np.int64)
        ok, indices, indptr, diagonal = _mesh_pattern(
            n, kinds[0], kinds[1], np.ascontiguousarray(hinge_triangles), slots, scratch)
        if ok:
            return indices, indptr, diagonal
    size = 3 * len(slots) + 2 * n
    scratch = storage.rank_table(size) if storage is not None else np.empty(size, np.int64)
    ok, indices, indptr, diagonal = _pattern(n, kinds, slots, scratch)
    return (indices, indptr, diagonal) if ok else None


def warm_up() -> None:
    """Compile or load these kernels (the signatures a simulation calls) on
    a one-block mesh, so no timed step pays for it.  Nothing without numba."""
    if not _kernels.enabled():
        return
    mesh = _mesh48.base_mesh(1.0, 1.0, 1, 1)
    elements = precompute(mesh)                 # a new mesh: _mesh_elements
    precompute(mesh)                            # its hinges known: _element_data
    size = elements.triangles.size * 3 + elements.hinge_vertices.size * 4
    sparse_pattern(mesh.vertex_count, [elements.triangles, elements.hinge_vertices],
                   np.empty(size, np.int64))
    sparse_pattern(mesh.vertex_count, [elements.triangles, elements.hinge_vertices],
                   np.empty(size, np.int64), hinge_triangles=elements.hinge_triangles)
