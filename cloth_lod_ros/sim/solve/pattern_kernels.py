"""Compiled (numba) kernels for a new topology's sparsity pattern.

The first solve on a new topology builds the block pattern of the system
(:class:`cloth_lod_ros.sim.solve.pattern.SparsePattern`): the blocks are the distinct
vertex pairs of every element plus each ``(i, i)``, in rows sorted by column,
and every element pair gets its block's slot.  Two builds here, with the
same results bitwise as the numpy reference:

* :func:`_pattern`, any element lists: every pair to its row's bucket, the
  distinct columns of each row by marks, sorted;
* :func:`_edge_pattern`, a mesh's ``[triangles, hinges]`` with the edge
  structure its compiled hinge build found
  (:func:`cloth_lod_ros.sim.mesh.topology_kernels.build_hinges`: every edge in
  ``(lo, hi)`` order, each half-edge's edge, each hinge's corners).  The
  mesh's pairs are its edges both ways, the diagonal and each hinge's
  opposite vertices ``(o0, o1)``, so the upper triangle is the sorted edges
  merged with the sorted ``(o0, o1)`` pairs, and the lower its transpose;
  rows and slots then follow by arithmetic, without a per-row search.  In
  ``hang_two_corners`` it took 0.63-0.65 of the time of the build from
  the triangles it replaces (47 against 73 µs at 343 particles, 102 against 161
  at 701).

The switch is :mod:`~cloth_lod_ros.sim.runtime.compiled`' (``CLOTH_LOD_KERNELS=numpy``);
without numba, or for inputs the kernels do not expect (other dtypes, an index
outside ``[0, n)``, an edge structure that does not describe the elements),
the reference builds it.
"""

from __future__ import annotations

import numpy as np

from ..runtime import compiled as _compiled

__all__ = ["sparse_pattern", "warm_up"]

_jit = _compiled._jit


@_jit
def _pattern(n, kinds, slots, scratch):
    """pattern.SparsePattern's block pattern and block slots.

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
def _edge_structure_fits(n, tri, hv, ht, ends, half_edge, corner):
    """Whether ``(ends, half_edge, corner)`` describe the mesh ``tri``, ``hv``,
    ``ht`` exactly (:func:`_edge_pattern`'s inputs): every index in range,
    ``ends`` strictly increasing ``(lo, hi)`` pairs each used by a half-edge,
    each half-edge's edge its own, each hinge's corners its vertices."""
    t_count, h_count, e_count = tri.shape[0], hv.shape[0], ends.shape[0]
    if half_edge.shape[0] != 3 * t_count or corner.shape[0] != h_count:
        return False
    for e in range(e_count):
        lo, hi = ends[e, 0], ends[e, 1]
        if lo < 0 or lo >= hi or hi >= n:
            return False
        if e > 0 and (lo < ends[e - 1, 0] or (lo == ends[e - 1, 0] and hi <= ends[e - 1, 1])):
            return False
    used = np.zeros(e_count, np.bool_)
    for t in range(t_count):
        for k in range(3):
            e = half_edge[3 * t + k]
            if e < 0 or e >= e_count:
                return False
            a, b = tri[t, k], tri[t, (k + 1) % 3]
            if ends[e, 0] != min(a, b) or ends[e, 1] != max(a, b):
                return False
            used[e] = True
    for e in range(e_count):
        if not used[e]:
            return False
    for h in range(h_count):
        f, s, c0, c1 = ht[h, 0], ht[h, 1], corner[h, 0], corner[h, 1]
        if min(f, s) < 0 or max(f, s) >= t_count or min(c0, c1) < 0 or max(c0, c1) > 2:
            return False
        if (tri[f, c0] != hv[h, 0] or tri[f, (c0 + 1) % 3] != hv[h, 1]
                or tri[f, (c0 + 2) % 3] != hv[h, 2] or tri[s, c1] != hv[h, 1]
                or tri[s, (c1 + 1) % 3] != hv[h, 0] or tri[s, (c1 + 2) % 3] != hv[h, 3]):
            return False
    return True


@_jit
def _across_sorted(n, hv):
    """Each hinge's ``(min, max)`` of its opposite vertices sorted by that pair
    (a counting sort by min, then insertion by max inside each bucket):
    ``(start (n + 1,), hinge (h,), high (h,))``, the pairs with min r at
    ``start[r]:start[r + 1]``."""
    h_count = hv.shape[0]
    start = np.zeros(n + 1, np.int64)
    for h in range(h_count):
        start[min(hv[h, 2], hv[h, 3]) + 1] += 1
    for r in range(n):
        start[r + 1] += start[r]
    fill = start[:n].copy()
    hinge = np.empty(h_count, np.int64)
    high = np.empty(h_count, np.int64)
    for h in range(h_count):
        lo = min(hv[h, 2], hv[h, 3])
        hinge[fill[lo]], high[fill[lo]] = h, max(hv[h, 2], hv[h, 3])
        fill[lo] += 1
    for r in range(n):
        for p in range(start[r] + 1, start[r + 1]):
            key, h = high[p], hinge[p]
            q = p - 1
            while q >= start[r] and high[q] > key:
                high[q + 1], hinge[q + 1] = high[q], hinge[q]
                q -= 1
            high[q + 1], hinge[q + 1] = key, h
    return start, hinge, high


@_jit
def _edge_pattern(n, tri, hv, ht, ends, half_edge, corner, slots):
    """:func:`_pattern` of a mesh's ``[triangles, hinges]`` from its edge structure.

    Args: n vertices; tri ``(t, 3)``, hv ``(h, 4)``, ht ``(h, 2)`` int64 (the
    mesh's triangles, hinges ``(e0, e1, o0, o1)`` and their triangles); ends
    ``(e, 2)`` every edge's ``(lo, hi)``, increasing; half_edge ``(3t,)`` the
    edge of half-edge ``3i + k`` (``tri[i, k] -> tri[i, k + 1]``); corner
    ``(h, 2)`` the k of each hinge's half-edge in its two triangles (the
    first runs e0 -> e1 with o0 next, the second e1 -> e0 with o1 next);
    slots ``(9 t + 16 h,)`` written as _pattern writes them.

    Returns _pattern's ``(ok, indices, indptr, diagonal_block)``; ok False
    (nothing written) when the structure does not describe the mesh.
    """
    fail = (False, np.empty(0, np.int32), np.empty(0, np.int32), np.empty(0, np.int64))
    if not _edge_structure_fits(n, tri, hv, ht, ends, half_edge, corner):
        return fail
    t_count, h_count, e_count = tri.shape[0], hv.shape[0], ends.shape[0]
    across_start, across_hinge, across_high = _across_sorted(n, hv)
    # The upper triangle U: row by row, the edges (sorted) merged with the
    # across pairs (sorted), without repeats; each edge's and hinge's entry.
    u_lo = np.empty(e_count + h_count, np.int64)
    u_hi = np.empty(e_count + h_count, np.int64)
    edge_u = np.empty(e_count, np.int64)
    across_u = np.empty(h_count, np.int64)      # -1: o0 == o1, the diagonal
    lower = np.zeros(n + 1, np.int64)           # U entries in each column
    upper = np.zeros(n, np.int64)               # and in each row
    u = e = 0
    for r in range(n):
        a, a_end = across_start[r], across_start[r + 1]
        while (e < e_count and ends[e, 0] == r) or a < a_end:
            take_edge = e < e_count and ends[e, 0] == r and (
                a >= a_end or ends[e, 1] <= across_high[a])
            c = ends[e, 1] if take_edge else across_high[a]
            if c != r and (u == 0 or u_lo[u - 1] != r or u_hi[u - 1] != c):
                u_lo[u], u_hi[u] = r, c
                lower[c + 1] += 1
                upper[r] += 1
                u += 1
            if take_edge:
                edge_u[e] = u - 1
                e += 1
            else:
                across_u[across_hinge[a]] = u - 1 if c != r else -1
                a += 1
    # Row r: its lower part (U's column r, transposed, in row order), the
    # diagonal, its upper part.
    indptr = np.empty(n + 1, np.int32)
    diagonal = np.empty(n, np.int64)
    next_lower = np.empty(n, np.int64)
    next_upper = np.empty(n, np.int64)
    indptr[0] = 0
    start = 0
    for r in range(n):
        next_lower[r] = start
        diagonal[r] = start + lower[r + 1]
        next_upper[r] = diagonal[r] + 1
        start += lower[r + 1] + 1 + upper[r]
        indptr[r + 1] = start
    indices = np.empty(start, np.int32)
    for r in range(n):
        indices[diagonal[r]] = r
    up_block = np.empty(u, np.int64)            # block of (lo, hi), in row lo
    down_block = np.empty(u, np.int64)          # block of (hi, lo), in row hi
    for k in range(u):
        lo, hi = u_lo[k], u_hi[k]
        up_block[k], down_block[k] = next_upper[lo], next_lower[hi]
        indices[next_upper[lo]], indices[next_lower[hi]] = hi, lo
        next_upper[lo] += 1
        next_lower[hi] += 1
    # Pair (e, i, j) of a kind at 9·block(e, i, j), in _pattern's layout:
    # a triangle's through its half-edges' edges.
    for t in range(t_count):
        base = 9 * t
        for i in range(3):
            j = (i + 1) % 3
            k = edge_u[half_edge[3 * t + i]]
            forward, backward = ((up_block[k], down_block[k]) if tri[t, i] < tri[t, j]
                                 else (down_block[k], up_block[k]))
            slots[base + 4 * i] = 9 * diagonal[tri[t, i]]
            slots[base + 3 * i + j] = 9 * forward
            slots[base + 3 * j + i] = 9 * backward
    # A hinge's: its triangles' (e0, e1, o0 in the first; o1 with e0, e1 in
    # the second) and (o0, o1) both ways.
    hinge_base = 9 * t_count
    for h in range(h_count):
        f, s = 9 * ht[h, 0], 9 * ht[h, 1]
        e0, e1, o0 = corner[h, 0], (corner[h, 0] + 1) % 3, (corner[h, 0] + 2) % 3
        s1, s0, o1 = corner[h, 1], (corner[h, 1] + 1) % 3, (corner[h, 1] + 2) % 3
        out = hinge_base + 16 * h
        slots[out], slots[out + 1], slots[out + 2] = (
            slots[f + 4 * e0], slots[f + 3 * e0 + e1], slots[f + 3 * e0 + o0])
        slots[out + 4], slots[out + 5], slots[out + 6] = (
            slots[f + 3 * e1 + e0], slots[f + 4 * e1], slots[f + 3 * e1 + o0])
        slots[out + 8], slots[out + 9], slots[out + 10] = (
            slots[f + 3 * o0 + e0], slots[f + 3 * o0 + e1], slots[f + 4 * o0])
        slots[out + 3], slots[out + 7] = slots[s + 3 * s0 + o1], slots[s + 3 * s1 + o1]
        slots[out + 12], slots[out + 13] = slots[s + 3 * o1 + s0], slots[s + 3 * o1 + s1]
        slots[out + 15] = slots[s + 4 * o1]
        k = across_u[h]
        if k < 0:
            slots[out + 11] = slots[out + 14] = slots[out + 10]
        elif hv[h, 2] < hv[h, 3]:
            slots[out + 11], slots[out + 14] = 9 * up_block[k], 9 * down_block[k]
        else:
            slots[out + 11], slots[out + 14] = 9 * down_block[k], 9 * up_block[k]
    return True, indices, indptr, diagonal


def sparse_pattern(n: int, element_vertices: list[np.ndarray], slots: np.ndarray,
                   storage=None, edges=None, hinge_triangles: np.ndarray | None = None):
    """The compiled twin of :class:`~cloth_lod_ros.sim.solve.pattern.SparsePattern`'s
    build: ``(indices (blocks,) int32, indptr (n + 1,) int32, diagonal_block
    (n,) int64)`` with every vertex pair's block slot written into ``slots``
    (int64, ``Σ e k²``: one per pair, in element order); None when the
    reference is to build it (kernels off, no elements, an index outside
    ``[0, n)``).

    Args: n vertices; element_vertices ``(e, k)`` int64 arrays; storage the
    :class:`~cloth_lod_ros.sim.solve.pattern.PatternStorage` whose scratch table to
    use (None: a fresh one); edges, hinge_triangles: with
    ``element_vertices`` a mesh's ``[triangles (t, 3), hinges (h, 4)]``, its
    ``(ends, half_edge, corner)`` and each hinge's triangles
    (elements.Elements' ``edges``, ``hinge_triangles``), for
    :func:`_edge_pattern`.
    """
    if not _compiled.enabled() or not element_vertices or slots.dtype != np.int64:
        return None
    kinds = tuple(np.ascontiguousarray(v) for v in element_vertices)
    if any(v.ndim != 2 or v.dtype != np.int64 for v in kinds):
        return None
    if (edges is not None and hinge_triangles is not None and len(kinds) == 2
            and kinds[0].shape[1] == 3 and kinds[1].shape[1] == 4
            and hinge_triangles.shape == (len(kinds[1]), 2)
            and all(a.dtype == np.int64 for a in (hinge_triangles, *edges))):
        ok, indices, indptr, diagonal = _edge_pattern(
            n, kinds[0], kinds[1], np.ascontiguousarray(hinge_triangles),
            *(np.ascontiguousarray(a) for a in edges), slots)
        if ok:
            return indices, indptr, diagonal
    size = 3 * len(slots) + 2 * n
    scratch = storage.rank_table(size) if storage is not None else np.empty(size, np.int64)
    ok, indices, indptr, diagonal = _pattern(n, kinds, slots, scratch)
    return (indices, indptr, diagonal) if ok else None


def warm_up() -> None:
    """Compile or load these kernels (the signatures a simulation calls) on
    a one-block mesh, so no timed step pays for it.  Nothing without numba."""
    if not _compiled.enabled():
        return
    from ..mesh.mesh48 import base_mesh
    from ..physics.elements_kernels import precompute
    elements = precompute(base_mesh(1.0, 1.0, 1, 1))
    kinds = [elements.triangles, elements.hinge_vertices]
    size = elements.triangles.size * 3 + elements.hinge_vertices.size * 4
    sparse_pattern(elements.vertex_count, kinds, np.empty(size, np.int64))
    sparse_pattern(elements.vertex_count, kinds, np.empty(size, np.int64),
                   edges=elements.edges, hinge_triangles=elements.hinge_triangles)


@_jit
def _scatter_slots(slots, offset, values, data):
    """``data[slots[offset + k]] += values[k]`` in k order (np.bincount's order)."""
    for k in range(values.shape[0]):
        data[slots[offset + k]] += values[k]


@_jit
def _add_diagonal(diagonal_block, diagonal, data):
    """Add ``diagonal[i] I₃`` to vertex i's diagonal block of flat data ``(9 blocks,)``."""
    for i in range(diagonal.shape[0]):
        base = 9 * diagonal_block[i]
        data[base] += diagonal[i]
        data[base + 4] += diagonal[i]
        data[base + 8] += diagonal[i]
