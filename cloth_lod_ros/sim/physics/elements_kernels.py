"""Compiled (numba) rest data of a new topology's elements, and a whole
topology change's refresh from a hierarchy's pools in one call.

An adaptive mesh changes topology at a fraction of its steps, and every
change rebuilds the same pure functions of the new triangles: the hinges
(:mod:`cloth_lod_ros.sim.mesh.topology_kernels`) and the rest coefficients of
every element (:func:`cloth_lod_ros.sim.physics.elements.precompute`).  At
adaptive-mesh sizes (a few hundred particles) their numpy code is mostly the
overhead of some dozens of small passes; these kernels do each in a few
loops.  :func:`adopt` adds the compact mesh of the active elements
(:mod:`cloth_lod_ros.sim.mesh.compact_kernels`), masses and state.

The numpy code stays the reference: the results here are *bitwise* equal
(same arrays, dtypes and order; the floating-point operations are the
reference's, in its order).  Inputs the kernels do not expect go to the
reference: its result or its error, never a write out of bounds.
"""

from __future__ import annotations

import numpy as np

from ..mesh import mesh48 as _mesh48
from ..mesh import topology as _topology
from ..mesh.compact_kernels import _active_mesh
from ..mesh.topology_kernels import _hinges, build_hinges
from ..runtime.compiled import _jit
from . import elements as _elements
from ..runtime import compiled as _compiled

__all__ = ["adopt", "precompute", "warm_up"]


@_jit
def _element_data(uv, tri, edge, opposite, hinge_tri, hyp):
    """elements.triangle_maps and hinge_weights in one pass each, the same
    operations in the same order.

    Args: uv ``(n, 2)`` m; tri ``(t, 3)``; edge, opposite, hinge_tri, hyp
    ``(h, 2)`` (topology.Hinges).  Returns ``(ok, area (t,), coef_u (t, 3),
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


def precompute(mesh: _mesh48.RestMesh) -> _elements.Elements:
    """:func:`cloth_lod_ros.sim.physics.elements.precompute` (the same arrays bitwise),
    compiled when :func:`~cloth_lod_ros.sim.runtime.compiled.enabled`."""
    uv, tri = mesh.uv, mesh.triangles
    if (not _compiled.enabled() or uv.dtype != np.float64 or tri.dtype != np.int64
            or uv.ndim != 2 or uv.shape[1] != 2 or tri.ndim != 2 or tri.shape[1] != 3):
        return _elements.precompute(mesh)
    if "hinges" not in mesh._cache:
        # A new mesh (every topology change): hinges and element data in one call.
        built = _mesh_elements(_compiled._as_float(uv), _compiled._as_index(tri),
                               mesh.vertex_count)
        if built[0][0] == 0 and built[1]:
            return _adopted_elements(mesh, built)
    hinges = mesh.hinges()          # the errors of build_hinges, or its cached arrays
    ok, area, coef_u, coef_v, hv, weight = _element_data(
        np.ascontiguousarray(uv), np.ascontiguousarray(tri),
        *(np.ascontiguousarray(a) for a in (hinges.edge, hinges.opposite,
                                            hinges.triangles, hinges.is_hypotenuse)))
    if not ok:
        return _elements.precompute(mesh)
    return _elements.Elements(
        triangles=tri.copy(), area=area, coef_u=coef_u, coef_v=coef_v,
        hinge_vertices=hv, hinge_weight=weight, hinge_triangles=hinges.triangles,
        vertex_count=mesh.vertex_count, edges=hinges.edges, rest_uv=uv)


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
    :meth:`~cloth_lod_ros.sim.mesh.hierarchy.Hierarchy48.active_mesh`, :func:`precompute`
    and the pools' gathers; None when the kernels are off or decline (then
    make those calls)."""
    h = hierarchy
    if (not _compiled.enabled() or h.uv.dtype != np.float64 or h.tri.dtype != np.int64
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


def _adopted_elements(mesh: _mesh48.RestMesh, built) -> _elements.Elements:
    """A new mesh's Elements from :func:`_mesh_elements`' successful result,
    its hinges cached on the mesh (as ``mesh.hinges()`` would build them)."""
    (_, edge, opposite, tris, hyp, border, ends, half_edge, corner), _, area, coef_u, coef_v, \
        hv, weight = built
    edges = (ends, half_edge, corner)
    mesh._cache["hinges"] = _topology.Hinges(edge=edge, opposite=opposite, triangles=tris,
                                             is_hypotenuse=hyp, boundary_edges=border,
                                             edges=edges)
    return _elements.Elements(triangles=mesh.triangles.copy(), area=area, coef_u=coef_u,
                              coef_v=coef_v, hinge_vertices=hv, hinge_weight=weight,
                              hinge_triangles=tris, vertex_count=mesh.vertex_count, edges=edges,
                              rest_uv=mesh.uv)


def warm_up() -> None:
    """Compile or load these kernels (the signatures a simulation calls) on
    a one-block mesh, so no timed step pays for it.  Nothing without numba."""
    if not _compiled.enabled():
        return
    mesh = _mesh48.base_mesh(1.0, 1.0, 1, 1)
    precompute(mesh)                            # a new mesh: _mesh_elements
    precompute(mesh)                            # its hinges known: _element_data
    build_hinges(mesh.triangles, mesh.vertex_count)
    from ..mesh.hierarchy import Hierarchy48
    adopt(Hierarchy48(mesh, np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)]), 0.1, 2))
