"""Compiled (numba) hinges of a new topology, with its edge structure.

An adaptive mesh changes topology at a fraction of its steps, and every
change rebuilds the interior edges as hinges
(:func:`cloth_lod_ros.sim.mesh.topology.build_hinges`) and, with them, the edge
structure the first solve's sparsity pattern is built from
(:mod:`~cloth_lod_ros.sim.solve.pattern_kernels`); the elements' rest data
follow (:mod:`cloth_lod_ros.sim.physics.elements_kernels`).  At adaptive-mesh
sizes (a few hundred particles) the numpy code is mostly the overhead of some
dozens of small passes; the kernel does it in a few loops.

The numpy code stays the reference: the results here are *bitwise* equal
(same arrays, dtypes and order).  The switch is
:func:`~cloth_lod_ros.sim.runtime.compiled.enabled` (``CLOTH_LOD_KERNELS=numpy``);
without numba everything is the reference.  Inputs the kernels do not expect
(other dtypes, vertex indices outside ``[0, n)``) go to the reference too:
its result or its error, never a write out of bounds.
"""

from __future__ import annotations

import numpy as np

from ..runtime import compiled as _compiled
from . import topology as _topology

__all__ = ["build_hinges"]

_jit = _compiled._jit


@_jit
def _hinges(t, n):
    """Interior and border edges of triangles ``t`` ``(m, 3)`` int64 over ``n``
    vertices, as topology.build_hinges finds them.

    Half-edge 3i + k runs t[i,k] -> t[i,(k+1)%3].  The reference groups them
    by a *stable* sort of the keys ``lo·(n+1) + hi``; here a counting sort by
    ``lo`` (stable) then a stable insertion sort by ``hi`` inside each ``lo``
    bucket (a handful of half-edges) gives the same order.

    Returns ``(status, edge, opposite, triangles, is_hypotenuse, border,
    ends, half_edge, corner)``: Hinges' fields (``(h, 2)`` each, border ``(b,
    2)``), then the edge structure the sparsity pattern is built from
    (pattern_kernels._edge_pattern): every edge's ``(lo, hi)`` in this order
    ``(h + b, 2)``, the edge of each half-edge ``(3m,)`` and the corner k of
    each hinge's two half-edges ``(h, 2)``.  status 0 ok, 1 an index outside
    ``[0, n)``, 2 an edge in more than two triangles, 3 two triangles
    traversing an edge the same way (then the arrays are empty).
    """
    m = t.shape[0]
    empty = np.empty((0, 2), np.int64)
    fail = (empty, empty, empty, np.empty((0, 2), np.bool_), empty, empty,
            np.empty(0, np.int64), empty)
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
    ends = np.empty((n_pairs + n_border, 2), np.int64)
    half_edge = np.empty(3 * m, np.int64)
    corner = np.empty((n_pairs, 2), np.int64)
    w = b = p = e = 0
    while p < 3 * m:
        h = order[p]
        ends[e, 0], ends[e, 1] = lo[p], hi[p]
        if p + 1 < 3 * m and lo[p + 1] == lo[p] and hi[p + 1] == hi[p]:
            edge[w, 0], edge[w, 1] = t[h // 3, h % 3], t[h // 3, (h + 1) % 3]
            for s in range(2):
                hs = order[p + s]
                tris[w, s] = hs // 3
                hyp[w, s] = hs % 3 == 1            # corner 0 is the apex
                opposite[w, s] = t[hs // 3, (hs + 2) % 3]
                corner[w, s] = hs % 3
                half_edge[hs] = e
            w += 1
            p += 2
        else:
            border[b, 0], border[b, 1] = t[h // 3, h % 3], t[h // 3, (h + 1) % 3]
            half_edge[h] = e
            b += 1
            p += 1
        e += 1
    return status, edge, opposite, tris, hyp, border, ends, half_edge, corner


def build_hinges(triangles: np.ndarray, vertex_count: int) -> _topology.Hinges:
    """:func:`cloth_lod_ros.sim.mesh.topology.build_hinges` (the same arrays bitwise,
    the same errors), compiled when :func:`~cloth_lod_ros.sim.runtime.compiled.enabled`."""
    t = np.asarray(triangles)
    if not _compiled.enabled() or t.dtype != np.int64 or t.ndim != 2 or t.shape[1] != 3:
        return _topology.build_hinges(triangles, vertex_count)
    status, edge, opposite, tris, hyp, border, ends, half_edge, corner = _hinges(
        np.ascontiguousarray(t), int(vertex_count))
    if status == 2:
        raise _topology.MeshError(
            "non-manifold mesh: an edge is shared by more than two triangles")
    if status == 3:
        raise _topology.MeshError(
            "inconsistent orientation: two triangles traverse an edge the same way")
    if status != 0:
        return _topology.build_hinges(triangles, vertex_count)
    return _topology.Hinges(edge=edge, opposite=opposite, triangles=tris,
                            is_hypotenuse=hyp, boundary_edges=border,
                            edges=(ends, half_edge, corner))
