"""Compiled (numba) compact mesh of a hierarchy's active elements.

After every LOD pass that changes the mesh, :class:`~cloth_lod_ros.sim.cloth.ClothSim`
rebuilds its compact view of the hierarchy
(:meth:`~cloth_lod_ros.sim.mesh.hierarchy.Hierarchy48.active_mesh`: the active
particles and triangles, renumbered).  At adaptive-mesh sizes (a few hundred
particles) its numpy code is mostly the overhead of some dozens of small
passes, run with the caches cold after a time step; here it is one loop
(:func:`active_mesh`).  The holding patches' refresh that follows is
:mod:`cloth_lod_ros.sim.inputs.holding_kernels`'; the whole refresh with the
element data, :func:`cloth_lod_ros.sim.physics.elements_kernels.adopt`.

The numpy code (``Hierarchy48.active_mesh``) stays the reference and the
results are *bitwise* equal (the same arrays, dtypes and order).  The switch
is :func:`~cloth_lod_ros.sim.runtime.compiled.enabled` (``CLOTH_LOD_KERNELS=numpy``);
without numba everything is the reference.  Pools the kernel does not expect
(other dtypes) go to the reference.
"""

from __future__ import annotations

import numpy as np

from ..runtime import compiled as _compiled
from .mesh48 import RestMesh

__all__ = ["active_mesh"]

_jit = _compiled._jit


@_jit
def _active_mesh(vertex_active, vertex_end, tri_active, tri_end, uv, tri, level):
    """Hierarchy48.active_mesh's arrays from the pools.

    Args: vertex_active ``(V,)`` bool and vertex_end (the used part);
    tri_active ``(T,)`` bool and tri_end; uv ``(V, 2)`` m; tri ``(T, 3)``
    int64 pool vertex ids; level ``(T,)`` int64.

    Returns ``(ok, vertex_ids (n,), triangle_ids (t,), uv (n, 2), triangles
    (t, 3) compact (-1 for an inactive corner, as the reference's remap),
    levels (t,))``; ok False (nothing else meaningful) when an active
    triangle's corner is outside ``[0, vertex_end)``.
    """
    n = 0
    for i in range(vertex_end):
        if vertex_active[i]:
            n += 1
    t_count = 0
    for t in range(tri_end):
        if tri_active[t]:
            t_count += 1
    vertex_ids = np.empty(n, np.int64)
    remap = np.full(vertex_end, -1, np.int64)
    compact_uv = np.empty((n, 2))
    k = 0
    for i in range(vertex_end):
        if vertex_active[i]:
            vertex_ids[k] = i
            remap[i] = k
            compact_uv[k, 0], compact_uv[k, 1] = uv[i, 0], uv[i, 1]
            k += 1
    triangle_ids = np.empty(t_count, np.int64)
    triangles = np.empty((t_count, 3), np.int64)
    levels = np.empty(t_count, np.int64)
    k = 0
    for t in range(tri_end):
        if tri_active[t]:
            for c in range(3):
                a = tri[t, c]
                if a < 0 or a >= vertex_end:
                    return False, vertex_ids, triangle_ids, compact_uv, triangles, levels
                triangles[k, c] = remap[a]
            triangle_ids[k] = t
            levels[k] = level[t]
            k += 1
    return True, vertex_ids, triangle_ids, compact_uv, triangles, levels


def active_mesh(hierarchy):
    """:meth:`Hierarchy48.active_mesh` (``(mesh, vertex_ids, triangle_ids)``, the
    same arrays bitwise) by :func:`_active_mesh`; None when the kernels are off
    or the pools are not what they expect (the caller runs the reference)."""
    h = hierarchy
    if (not _compiled.enabled() or h.uv.dtype != np.float64 or h.tri.dtype != np.int64
            or h.level.dtype != np.int64 or h.vertex_active.dtype != np.bool_
            or h.tri_active.dtype != np.bool_ or h.uv.ndim != 2 or h.uv.shape[1] != 2):
        return None
    ok, vertex_ids, triangle_ids, uv, triangles, levels = _active_mesh(
        h.vertex_active, int(h.vertex_end), h.tri_active, int(h.tri_end),
        np.ascontiguousarray(h.uv), np.ascontiguousarray(h.tri), h.level)
    if not ok:
        return None
    mesh = RestMesh(uv=uv, triangles=triangles, levels=levels, width=h.width, height=h.height)
    return mesh, vertex_ids, triangle_ids
