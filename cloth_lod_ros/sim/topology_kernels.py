"""Compiled (numba) kernels for what a topology change builds from the new mesh.

An adaptive mesh changes topology at a fraction of its steps, and every
change rebuilds the same pure functions of the new triangles: the interior
edges as hinges (:func:`cloth_lod_ros.sim.mesh48.build_hinges`), the rest
coefficients of every element (:func:`cloth_lod_ros.sim.forces.precompute`)
and the edge structure the first solve's sparsity pattern is built from
(:mod:`~cloth_lod_ros.sim.pattern_kernels`).  At adaptive-mesh sizes
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
from .compact_kernels import _active_mesh
from . import kernels as _kernels
from . import mesh48 as _mesh48

__all__ = ["adopt", "build_hinges", "precompute", "warm_up"]

_jit = _kernels._jit


@_jit
def _hinges(t, n):
    """Interior and border edges of triangles ``t`` ``(m, 3)`` int64 over ``n``
    vertices, as mesh48.build_hinges finds them.

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


def build_hinges(triangles: np.ndarray, vertex_count: int) -> _mesh48.Hinges:
    """:func:`cloth_lod_ros.sim.mesh48.build_hinges` (the same arrays bitwise,
    the same errors), compiled when :func:`~cloth_lod_ros.sim.kernels.enabled`."""
    t = np.asarray(triangles)
    if not _kernels.enabled() or t.dtype != np.int64 or t.ndim != 2 or t.shape[1] != 3:
        return _mesh48.build_hinges(triangles, vertex_count)
    status, edge, opposite, tris, hyp, border, ends, half_edge, corner = _hinges(
        np.ascontiguousarray(t), int(vertex_count))
    if status == 2:
        raise _mesh48.MeshError("non-manifold mesh: an edge is shared by more than two triangles")
    if status == 3:
        raise _mesh48.MeshError(
            "inconsistent orientation: two triangles traverse an edge the same way")
    if status != 0:
        return _mesh48.build_hinges(triangles, vertex_count)
    return _mesh48.Hinges(edge=edge, opposite=opposite, triangles=tris,
                          is_hypotenuse=hyp, boundary_edges=border,
                          edges=(ends, half_edge, corner))


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
    between).  Returns ``(hinges, ok, area, coef_u, coef_v, hinge_vertices,
    weight)``: _hinges' status and arrays as a tuple, then _element_data's
    (``ok`` False and empty arrays when status is not 0)."""
    hinges = _hinges(tri, n)
    if hinges[0] != 0:
        e = np.empty(0)
        return (hinges, False, e, np.empty((0, 3)), np.empty((0, 3)),
                np.empty((0, 4), np.int64), e)
    ok, area, coef_u, coef_v, hv, weight = _element_data(uv, tri, hinges[1], hinges[2],
                                                         hinges[3], hinges[4])
    return hinges, ok, area, coef_u, coef_v, hv, weight


def precompute(mesh: _mesh48.RestMesh) -> _forces.Elements:
    """:func:`cloth_lod_ros.sim.forces.precompute` (the same arrays bitwise),
    compiled when :func:`~cloth_lod_ros.sim.kernels.enabled`."""
    uv, tri = mesh.uv, mesh.triangles
    if (not _kernels.enabled() or uv.dtype != np.float64 or tri.dtype != np.int64
            or uv.ndim != 2 or uv.shape[1] != 2 or tri.ndim != 2 or tri.shape[1] != 3):
        return _forces.precompute(mesh)
    if "hinges" not in mesh._cache:
        # A new mesh (every topology change): hinges and element data in one call.
        built = _mesh_elements(_kernels._as_float(uv), _kernels._as_index(tri),
                               mesh.vertex_count)
        if built[0][0] == 0 and built[1]:
            return _adopted_elements(mesh, built)
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
        vertex_count=mesh.vertex_count, edges=hinges.edges)


@_jit
def _adopt(vertex_active, vertex_end, tri_active, tri_end, pool_uv, pool_tri, pool_level,
           mass_units, unit_mass, pool_x, pool_v):
    """A topology change's whole refresh from a hierarchy's pools in one call:
    compact_kernels._active_mesh, the compact particles' masses (kg), positions
    and velocities, and :func:`_mesh_elements` of the compact mesh.  Returns
    ``(ok, active_mesh's five arrays, masses, x, v, _mesh_elements' tuple)``;
    ok False when either part declines (then the separate calls run)."""
    ok, vertex_ids, triangle_ids, uv, tri, levels = _active_mesh(
        vertex_active, vertex_end, tri_active, tri_end, pool_uv, pool_tri, pool_level)
    n = vertex_ids.shape[0]
    masses, x, v = np.empty(n), np.empty((n, 3)), np.empty((n, 3))
    for i in range(n):
        p = vertex_ids[i]
        masses[i] = mass_units[p] * unit_mass
        for d in range(3):
            x[i, d], v[i, d] = pool_x[p, d], pool_v[p, d]
    elements = _mesh_elements(uv, tri, n)
    ok = ok and elements[0][0] == 0 and elements[1]
    return ok, vertex_ids, triangle_ids, uv, tri, levels, masses, x, v, elements


def adopt(hierarchy):
    """The compact mesh of a hierarchy with its element data and state:
    ``(mesh, vertex_ids, triangle_ids, elements, masses (n,) kg, x, v (n, 3)
    m, m/s)``, the same arrays bitwise as
    :meth:`~cloth_lod_ros.sim.hierarchy.Hierarchy48.active_mesh`, :func:`precompute`
    and the pools' gathers; None when the kernels are off or decline (then
    make those calls)."""
    h = hierarchy
    if (not _kernels.enabled() or h.uv.dtype != np.float64 or h.tri.dtype != np.int64
            or h.level.dtype != np.int64 or h.vertex_active.dtype != np.bool_
            or h.tri_active.dtype != np.bool_ or h.uv.ndim != 2 or h.uv.shape[1] != 2
            or h.mass_units.dtype != np.float64 or h.x.dtype != np.float64
            or h.v.dtype != np.float64):
        return None
    ok, vertex_ids, triangle_ids, uv, tri, levels, masses, x, v, built = _adopt(
        h.vertex_active, int(h.vertex_end), h.tri_active, int(h.tri_end),
        np.ascontiguousarray(h.uv), np.ascontiguousarray(h.tri), h.level, h.mass_units,
        float(h.unit_mass), np.ascontiguousarray(h.x), np.ascontiguousarray(h.v))
    if not ok:
        return None
    mesh = _mesh48.RestMesh(uv=uv, triangles=tri, levels=levels, width=h.width,
                            height=h.height)
    return mesh, vertex_ids, triangle_ids, _adopted_elements(mesh, built), masses, x, v


def _adopted_elements(mesh: _mesh48.RestMesh, built) -> _forces.Elements:
    """A new mesh's Elements from :func:`_mesh_elements`' successful result,
    its hinges cached on the mesh (as ``mesh.hinges()`` would build them)."""
    (_, edge, opposite, tris, hyp, border, ends, half_edge, corner), _, area, coef_u, coef_v, \
        hv, weight = built
    edges = (ends, half_edge, corner)
    mesh._cache["hinges"] = _mesh48.Hinges(edge=edge, opposite=opposite, triangles=tris,
                                           is_hypotenuse=hyp, boundary_edges=border,
                                           edges=edges)
    return _forces.Elements(triangles=mesh.triangles.copy(), area=area, coef_u=coef_u,
                            coef_v=coef_v, hinge_vertices=hv, hinge_weight=weight,
                            hinge_triangles=tris, vertex_count=mesh.vertex_count, edges=edges)


def warm_up() -> None:
    """Compile or load these kernels (the signatures a simulation calls) on
    a one-block mesh, so no timed step pays for it.  Nothing without numba."""
    if not _kernels.enabled():
        return
    mesh = _mesh48.base_mesh(1.0, 1.0, 1, 1)
    precompute(mesh)                            # a new mesh: _mesh_elements
    precompute(mesh)                            # its hinges known: _element_data
    build_hinges(mesh.triangles, mesh.vertex_count)
    from .hierarchy import Hierarchy48
    adopt(Hierarchy48(mesh, np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)]), 0.1, 2))
