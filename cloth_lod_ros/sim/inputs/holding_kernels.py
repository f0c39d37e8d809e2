"""Compiled (numba) refresh of a holding patch after a topology change.

After a topology change every holding patch (pin or grasp) takes the
particles that splits made inside it
(:meth:`~cloth_lod_ros.sim.inputs.holding.HeldInputs._refresh_held`).  At
adaptive-mesh sizes its numpy code is mostly the overhead of some dozens of
small passes; here it is one or two loops (:func:`patch_refresh`).

The numpy code (:func:`cloth_lod_ros.sim.inputs.holding.patch_refresh`) stays
the reference and the results are *bitwise* equal (the same arrays, dtypes
and order; the one floating-point expression, a patch's distance test, is
the reference's operations in its order, and numba contracts nothing into
FMAs without fastmath).  The switch is
:func:`~cloth_lod_ros.sim.runtime.compiled.enabled` (``CLOTH_LOD_KERNELS=numpy``);
inputs the kernel does not expect (other dtypes, an index out of range) go
to the reference: its result or its error.
"""

from __future__ import annotations

import numpy as np

from ..runtime import compiled as _compiled
from ..runtime.compiled import _jit

__all__ = ["patch_refresh", "warm_up"]


@_jit
def _patch_refresh(vertex_ids, uv, cu, cv, reach, nodes, node, is_pin):
    """One holding patch's refresh (holding.patch_refresh, the reference).

    Args: vertex_ids ``(n,)`` increasing pool ids of the compact particles
    (n > 0); uv ``(n, 2)`` their rest coordinates, m; (cu, cv) the patch
    centre, m; reach its radius + 1e-12, m; nodes ``(k,)`` held pool ids;
    node the centre's pool id (kept whatever its distance) if is_pin.

    Returns ``(keep (k,) bool, every, new (m,) int64, vertices, vertex)``:
    which held nodes stay (all for a grasp) and whether all do; the compact
    particles in reach not held yet, increasing; for a pin the compact
    indices of the nodes it holds after the refresh (``np.searchsorted`` of
    the kept nodes, then the new ones) and of its centre (for a grasp an
    empty array and -1).
    """
    n = vertex_ids.shape[0]
    k_count = nodes.shape[0]
    near = np.empty(n, np.bool_)
    for i in range(n):
        du = uv[i, 0] - cu
        dv = uv[i, 1] - cv
        near[i] = np.sqrt(du * du + dv * dv) <= reach
    keep = np.ones(k_count, np.bool_)
    at = np.empty(k_count, np.int64)          # searchsorted, then -1 if not active
    every = True
    for k in range(k_count):
        raw = np.searchsorted(vertex_ids, nodes[k])
        a = min(raw, n - 1)
        present = vertex_ids[a] == nodes[k]
        if is_pin:
            keep[k] = (present and near[a]) or nodes[k] == node
            every = every and keep[k]
        at[k] = raw
    # A held node that stays is not new.  (One that does not stay is out of
    # reach or inactive: clearing its flag changes nothing.)  After every
    # keep test: a node can be held twice.
    for k in range(k_count):
        a = min(at[k], n - 1)
        if vertex_ids[a] == nodes[k]:
            near[a] = False
    count = 0
    for i in range(n):
        if near[i]:
            count += 1
    new = np.empty(count, np.int64)
    count = 0
    for i in range(n):
        if near[i]:
            new[count] = i
            count += 1
    if not is_pin:
        return keep, every, new, np.empty(0, np.int64), -1
    kept = 0
    for k in range(k_count):
        if keep[k]:
            kept += 1
    vertices = np.empty(kept + count, np.int64)
    j = 0
    for k in range(k_count):
        if keep[k]:
            vertices[j] = at[k]
            j += 1
    for i in range(count):              # searchsorted of a compact particle's own id
        vertices[j + i] = new[i]
    return keep, every, new, vertices, np.searchsorted(vertex_ids, node)


def patch_refresh(vertex_ids: np.ndarray, uv: np.ndarray, centre, radius: float,
                  nodes: np.ndarray, node: int | None):
    """:func:`cloth_lod_ros.sim.inputs.holding.patch_refresh` by :func:`_patch_refresh`:
    ``(keep, new, vertices, vertex)``, the same values; None when the kernels
    are off or the inputs are not what they expect."""
    if (not _compiled.enabled() or len(vertex_ids) == 0 or vertex_ids.dtype != np.int64
            or nodes.dtype != np.int64 or nodes.ndim != 1 or uv.dtype != np.float64
            or uv.ndim != 2 or uv.shape[1] != 2 or len(uv) != len(vertex_ids)
            or len(centre) != 2):
        return None
    keep, every, new, vertices, vertex = _patch_refresh(
        _contiguous(vertex_ids), _contiguous(uv), float(centre[0]), float(centre[1]),
        radius + 1e-12, _contiguous(nodes), -1 if node is None else int(node),
        node is not None)
    if node is None:
        return None, new, None, -1
    return (None if every else keep), new, vertices, int(vertex)


def _contiguous(a: np.ndarray) -> np.ndarray:
    """``a`` if C-contiguous, else a C-contiguous copy (no call when it is)."""
    return a if a.flags.c_contiguous else np.ascontiguousarray(a)


def warm_up() -> None:
    """Compile or load these kernels on a small hierarchy and patch, so no
    timed step pays for it.  Nothing without numba."""
    if not _compiled.enabled():
        return
    from ..mesh.hierarchy import Hierarchy48
    from ..mesh.mesh48 import base_mesh
    base = base_mesh(1.0, 1.0, 1, 1)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(len(base.uv))]), 0.1, 2)
    mesh, vertex_ids, _ = h.active_mesh()
    patch_refresh(vertex_ids, mesh.uv, (0.0, 0.0), 0.5, vertex_ids[:1].copy(), 0)
    patch_refresh(vertex_ids, mesh.uv, (0.0, 0.0), 0.5, vertex_ids[:1].copy(), None)
