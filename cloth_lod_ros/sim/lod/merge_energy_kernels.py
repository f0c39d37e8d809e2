"""Compiled (numba) merge energies of every candidate at once, the same numbers
as :func:`cloth_lod_ros.sim.lod.merge_energy.merge_energy_change` (the
reference's operations, in its order: ``test/sim/lod/test_policy_kernels.py``
compares them bitwise), except the bend part, which
:mod:`~cloth_lod_ros.sim.lod.merge_bend_kernels` computes (the stencils of a
piece of mesh around each candidate; within ``test/tolerances.py``).
"""

from __future__ import annotations

import numpy as np

from ..mesh.hierarchy_kernels import merge_kinetic
from ..runtime import compiled as _compiled
from ..runtime.compiled import _as_float, _as_index, _jit
from .merge_bend_kernels import bend_changes
from .policy_kernels import _dot3, _find, split_candidates, warm_up_hierarchy

__all__ = ["merge_energies", "warm_up"]


@_jit
def _membrane(cu0, cu1, cu2, cv0, cv1, cv2, area, x, i0, i1, i2, ks, ksh):
    """energies.membrane_energies of one triangle, J (its operations, in its order)."""
    # einsum 'tk,tkd->td': corners k = 0, 1, 2 added into 0, per component
    # (scalars: an array per call would be a heap allocation per triangle).
    wu0 = ((0.0 + cu0 * x[i0, 0]) + cu1 * x[i1, 0]) + cu2 * x[i2, 0]
    wu1 = ((0.0 + cu0 * x[i0, 1]) + cu1 * x[i1, 1]) + cu2 * x[i2, 1]
    wu2 = ((0.0 + cu0 * x[i0, 2]) + cu1 * x[i1, 2]) + cu2 * x[i2, 2]
    wv0 = ((0.0 + cv0 * x[i0, 0]) + cv1 * x[i1, 0]) + cv2 * x[i2, 0]
    wv1 = ((0.0 + cv0 * x[i0, 1]) + cv1 * x[i1, 1]) + cv2 * x[i2, 1]
    wv2 = ((0.0 + cv0 * x[i0, 2]) + cv1 * x[i1, 2]) + cv2 * x[i2, 2]
    len_u = np.sqrt(_dot3(wu0, wu1, wu2, wu0, wu1, wu2))
    len_v = np.sqrt(_dot3(wv0, wv1, wv2, wv0, wv1, wv2))
    shear = _dot3(wu0, wu1, wu2, wv0, wv1, wv2)
    su, sv = len_u - 1.0, len_v - 1.0
    return 0.5 * area * (ks * (su * su + sv * sv) + ksh * (shear * shear))


@_jit
def _merge_energies(vertices, vertex_ids, triangle_ids, vertex_edge, vertex_parents,
                    pool_tri, children, uv, tri, coef_u, coef_v, area, x, v, masses, ks, ksh,
                    delta, kinetic, diamond_area, mid, offset):
    """merge_energy.merge_energy_change of every candidate, without the bend
    and gravity terms.

    Args:
        vertices ``(k,)`` pool ids of the split particles; vertex_ids,
        triangle_ids: the increasing pool ids of the compact vertices and
        triangles; vertex_edge, vertex_parents, pool_tri, children, uv: the
        hierarchy's pool arrays; tri, coef_u, coef_v, area: the compact
        elements; x, v ``(n, 3)`` m, m/s; masses ``(n,)`` kg; ks, ksh N/m.
        delta: ``(k,)`` output, the membrane change, J; kinetic
        ``(k,)`` its kinetic change, J; diamond_area ``(k,)`` m²; mid ``(k,)``
        compact m; offset ``(k, 3)`` ``x_mid − ½(x_left + x_right)``, m.

    Returns:
        False if a pool id is not in the compact ids (nothing valid written).
    """
    k_count = vertices.shape[0]
    ends = np.empty((k_count, 2), dtype=np.int64)
    corners = np.empty((k_count, 2, 3), dtype=np.int64)   # compact parent corners
    parent_area = np.zeros((k_count, 2))
    for i in range(k_count):
        m = vertices[i]
        mi = _find(vertex_ids, m)
        left = _find(vertex_ids, vertex_edge[m, 0])
        right = _find(vertex_ids, vertex_edge[m, 1])
        if mi < 0 or left < 0 or right < 0:
            return False
        mid[i], ends[i, 0], ends[i, 1] = mi, left, right
        # Membrane: + the parents (elements.triangle_maps of their rest corners),
        # − their children, in np.bincount's order (parents, then children).
        total = 0.0
        summed_area = 0.0
        for s in range(2):
            p = vertex_parents[m, s]
            if p < 0:
                continue
            for j in range(3):
                c = _find(vertex_ids, pool_tri[p, j])
                if c < 0:
                    return False
                corners[i, s, j] = c
            a0, a1, a2 = pool_tri[p, 0], pool_tri[p, 1], pool_tri[p, 2]
            d1u, d1v = uv[a1, 0] - uv[a0, 0], uv[a1, 1] - uv[a0, 1]
            d2u, d2v = uv[a2, 0] - uv[a0, 0], uv[a2, 1] - uv[a0, 1]
            det = d1u * d2v - d2u * d1v
            ca1, ca2 = d2v / det, -d1v / det
            cb1, cb2 = -d2u / det, d1u / det
            tri_area = 0.5 * det
            parent_area[i, s] = tri_area
            summed_area = summed_area + tri_area
            total = total + _membrane(-(ca1 + ca2), ca1, ca2, -(cb1 + cb2), cb1, cb2,
                                      tri_area, x, corners[i, s, 0], corners[i, s, 1],
                                      corners[i, s, 2], ks, ksh)
        for s in range(2):
            p = vertex_parents[m, s]
            if p < 0:
                continue
            for j in range(2):
                c = _find(triangle_ids, children[p, j])
                if c < 0:
                    return False
                total = total + -1.0 * _membrane(
                    coef_u[c, 0], coef_u[c, 1], coef_u[c, 2], coef_v[c, 0], coef_v[c, 1],
                    coef_v[c, 2], area[c], x, tri[c, 0], tri[c, 1], tri[c, 2], ks, ksh)
        delta[i] = total
        diamond_area[i] = summed_area       # 0 + parent areas, as np.bincount adds them

    for i in range(k_count):
        # Kinetic (merge_kinetic_change) and the offset of m from the chord.
        mi, left, right = mid[i], ends[i, 0], ends[i, 1]
        for d in range(3):
            offset[i, d] = x[mi, d] - 0.5 * (x[left, d] + x[right, d])
        kinetic[i] = merge_kinetic(v, mi, left, right, masses[mi], masses[left],
                                   masses[right])
    return True


def merge_energies(hierarchy, elements, vertex_ids, triangle_ids, vertices, x, v, masses,
                   material, gravity):
    """``(total, kinetic, area)`` ``(k,)`` of merge_energy.merge_energy_change by
    :func:`_merge_energies` and the bend part by
    :func:`~.merge_bend_kernels.bend_changes`, or None when the kernels are off or an input
    is not what they expect (the caller then runs the reference).  Same
    arguments as merge_energy_change, vertices non-empty."""
    if not _compiled.enabled():
        return None
    h = hierarchy
    x = _as_float(x)
    k = len(vertices)
    delta, kinetic, area = np.empty(k), np.empty(k), np.empty(k)
    mid, offset = np.empty(k, dtype=np.int64), np.empty((k, 3))
    ok = _merge_energies(
        _as_index(vertices), _as_index(vertex_ids), _as_index(triangle_ids),
        _as_index(h.vertex_edge), _as_index(h.vertex_parents), _as_index(h.tri),
        _as_index(h.children), _as_float(h.uv),
        _as_index(elements.triangles), _as_float(elements.coef_u),
        _as_float(elements.coef_v), _as_float(elements.area), x, _as_float(v),
        _as_float(masses), float(material.stretch_stiffness),
        float(material.shear_stiffness), delta, kinetic, area, mid, offset)
    if not ok:
        return None
    delta += bend_changes(h, elements, vertex_ids, vertices, mid, x, material.bend_stiffness)
    # The gravity term as the reference computes it (BLAS's order).
    delta += kinetic + masses[mid] * (offset @ np.asarray(gravity, dtype=float))
    return delta, kinetic, area


def warm_up() -> None:
    """Compile or load these kernels on the small refined hierarchy of the LOD
    kernels' warm-ups, so no timed step pays for it.  Nothing without numba."""
    if not _compiled.enabled():
        return
    from types import SimpleNamespace

    h, vertex_ids, triangle_ids, elements = warm_up_hierarchy()
    x, v = h.x[vertex_ids], h.v[vertex_ids]
    vertices, _ = split_candidates(h)
    material = SimpleNamespace(stretch_stiffness=1.0, shear_stiffness=1.0, bend_stiffness=1.0)
    merge_energies(h, elements, vertex_ids, triangle_ids, vertices, x, v,
                   h.masses[vertex_ids], material, np.zeros(3))
