"""A LOD check's later refinement rounds, on the hierarchy's pools (compiled).

With ``lod.check_interval`` k > 1 a check refines in up to k rounds
(:meth:`~cloth_lod_ros.sim.cloth.ClothSim.adapt`): after the first round's
operations, the criterion is evaluated again on the hinges those operations
changed, and what is over the threshold is refined further.  The compact
path re-adopts the whole mesh after every round (compact arrays, element
data, held patches) to evaluate some hundreds of hinges (75-600 in
``hang_two_corners``), and then finds them by a pass over every hinge
(:func:`~cloth_lod_ros.sim.lod.policy.changed_hinges`); without those refreshes its
LOD bookkeeping took 4-6 % less time.  Here the changed hinges come straight from the pools and
the edge index, the same hinges with the same numbers, so one adoption after
the last round is enough.

The hinges found are bitwise those of the compact mesh
(:func:`~cloth_lod_ros.sim.mesh.topology_kernels.build_hinges` and
``_element_data``): compact ids are increasing in pool ids, so the compact
order (by edge ``(lo, hi)``; of an edge's two triangles, the lower id first,
whose direction of the edge is ``(e0, e1)``) is the pool order, and every
rest number is the same floating-point expression of the same ``uv``.  The
criterion and the refine order are :mod:`~cloth_lod_ros.sim.lod.policy_kernels`'
own, so the refinements are those :meth:`LodPolicy.decide` makes after
:func:`~cloth_lod_ros.sim.lod.policy.changed_hinges` (tested bitwise:
test/sim/lod/test_lod_rounds.py).
"""

from __future__ import annotations

import numpy as np

from ..mesh import int_table as _table
from ..runtime import compiled as _compiled
from ..mesh.hierarchy_kernels import _edge_key, _LOW
from .policy_kernels import _criterion, _refine_order

__all__ = ["changed_hinge_refinements", "warm_up"]

_jit = _compiled._jit


@_jit
def _triangle_area(uv, tri, t):
    """``elements.triangle_maps``' rest area of pool triangle ``t``, m² (its operations)."""
    p, q, r = tri[t, 0], tri[t, 1], tri[t, 2]
    d1u, d1v = uv[q, 0] - uv[p, 0], uv[q, 1] - uv[p, 1]
    d2u, d2v = uv[r, 0] - uv[p, 0], uv[r, 1] - uv[p, 1]
    return 0.5 * (d1u * d2v - d2u * d1v)


@_jit
def _corner_of(tri, t, a, b):
    """Corner k of triangle ``t`` whose half-edge ``tri[t, k] -> tri[t, k+1]`` is
    ``{a, b}`` either way (-1: not an edge of t)."""
    for k in range(3):
        p, q = tri[t, k], tri[t, (k + 1) % 3]
        if (p == a and q == b) or (p == b and q == a):
            return k
    return -1


@_jit
def _changed_hinges(tri, tri_active, tri_end, birth, time, moved, edges):
    """The hinges of the active mesh with a triangle born at ``time`` or with a
    corner in ``moved`` (pool bool), sorted as the compact mesh's: ``(hv (h, 4),
    hinge_tri (h, 2), hyp (h, 2) bool)`` in pool ids; hv None-like (0 rows) and
    ok False if the edge index disagrees with the pools."""
    changed = np.zeros(tri_end, np.bool_)
    for t in range(tri_end):
        if tri_active[t]:
            hit = birth[t] == time
            for k in range(3):
                hit = hit or moved[tri[t, k]]
            changed[t] = hit
    # Each changed triangle's interior edges, once per hinge (from its lower
    # triangle when both changed), as packed keys and their two triangles.
    keys = np.empty(3 * tri_end, np.int64)
    pairs = np.empty((3 * tri_end, 2), np.int64)
    count = 0
    ok = True
    for t in range(tri_end):
        if not changed[t]:
            continue
        for k in range(3):
            a, b = tri[t, k], tri[t, (k + 1) % 3]
            packed = _table.get(edges, _edge_key(a, b), 0)
            u0, u1 = (packed & _LOW) - 1, (packed >> 32) - 1
            if u0 < 0 or u1 < 0:
                continue                       # a border edge
            if u0 != t and u1 != t:
                ok = False
                continue
            other = u1 if u0 == t else u0
            if changed[other] and other < t:
                continue                       # listed from the other one
            keys[count] = _edge_key(a, b)
            pairs[count, 0], pairs[count, 1] = min(t, other), max(t, other)
            count += 1
    order = np.argsort(keys[:count])            # distinct keys: any sort is the order
    hv = np.empty((count, 4), np.int64)
    hinge_tri = np.empty((count, 2), np.int64)
    hyp = np.empty((count, 2), np.bool_)
    for j in range(count):
        i = order[j]
        lo, hi = keys[i] >> 32, keys[i] & _LOW
        first, second = pairs[i, 0], pairs[i, 1]
        k0, k1 = _corner_of(tri, first, lo, hi), _corner_of(tri, second, lo, hi)
        if k0 < 0 or k1 < 0:
            ok = False
            k0, k1 = max(k0, 0), max(k1, 0)
        hv[j, 0], hv[j, 1] = tri[first, k0], tri[first, (k0 + 1) % 3]
        hv[j, 2], hv[j, 3] = tri[first, (k0 + 2) % 3], tri[second, (k1 + 2) % 3]
        hinge_tri[j, 0], hinge_tri[j, 1] = first, second
        hyp[j, 0], hyp[j, 1] = k0 == 1, k1 == 1       # corner 0 is the apex
    return ok, hv, hinge_tri, hyp


@_jit
def _refinements(tri, tri_active, tri_end, birth, time, moved, edges, uv, x, v, level,
                 max_level, kb, lookahead, threshold, detail):
    """:func:`_changed_hinges`, their weights (``_element_data``'s operations),
    the criterion on them and the refine order: ``(ok, refine (r,) pool ids)``."""
    ok, hv, hinge_tri, hyp = _changed_hinges(tri, tri_active, tri_end, birth, time, moved,
                                             edges)
    count = hv.shape[0]
    weight = np.empty(count)
    for j in range(count):
        e0, e1 = hv[j, 0], hv[j, 1]
        eu, ev = uv[e1, 0] - uv[e0, 0], uv[e1, 1] - uv[e0, 1]
        length2 = eu * eu + ev * ev
        flags = (1.0 if hyp[j, 0] else 0.0) + (1.0 if hyp[j, 1] else 0.0)
        gamma = 1.0 - 0.25 * flags
        weight[j] = gamma * length2 / (_triangle_area(uv, tri, hinge_tri[j, 0])
                                       + _triangle_area(uv, tri, hinge_tri[j, 1]))
    theta = np.empty(count)
    deviation, refine_deviation = np.empty(count), np.empty(count)
    rate, force, height = np.empty(count), np.empty(count), np.empty(count)
    _criterion(theta, np.empty((0, 4, 3)), False, x, hv, v, weight, kb, lookahead, deviation,
               refine_deviation, rate, force, height)
    identity = np.arange(level.shape[0])
    out = np.empty(2 * count + detail.shape[0], np.int64)
    written = _refine_order(refine_deviation, threshold, hinge_tri, identity, level, max_level,
                            detail, out)
    if written < 0:
        ok = False
        written = 0
    return ok, out[:written]


def changed_hinge_refinements(hierarchy, time: float, merged, bend_stiffness: float,
                              lookahead: float, threshold: float, detail: np.ndarray):
    """The refinements :meth:`~cloth_lod_ros.sim.lod.policy.LodPolicy.decide` would
    choose with ``simplify`` off and ``recheck=merged`` on the mesh adopted now
    (``(r,)`` int64 pool triangle ids, in order), without adopting it; None when the
    kernels are off or the index disagrees with the pools (then adopt and
    decide).

    Args: hierarchy (synchronised: its ``x``/``v`` are the state); time s (the
    birth of what this check made); merged: ``(k, 2)`` pool edges the check
    merged (their ends' velocities changed); bend_stiffness N·m; lookahead s;
    threshold m (``lod.refine_threshold``); detail: pool triangles to refine
    for detail (``LodPolicy._detail_triangles``).
    """
    if not _compiled.enabled():
        return None
    h = hierarchy
    index = h._kernel_index()
    moved = np.zeros(len(h.uv), dtype=bool)
    ends = np.asarray(merged, dtype=np.int64).reshape(-1)
    moved[ends[(ends >= 0) & (ends < len(moved))]] = True
    ok, refine = _refinements(h.tri, h.tri_active, int(h.tri_end), h.birth, float(time), moved,
                              index.edges, h.uv, h.x, h.v, h.level, int(h.max_level),
                              float(bend_stiffness), float(lookahead), float(threshold),
                              np.ascontiguousarray(detail, dtype=np.int64).reshape(-1))
    return refine if ok else None


def warm_up() -> None:
    """Compile or load the kernel on a small refined hierarchy.  Nothing without numba."""
    if not _compiled.enabled():
        return
    from ..mesh.hierarchy import Hierarchy48
    from ..mesh.mesh48 import base_mesh
    base = base_mesh(1.0, 1.0, 2, 2)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(len(base.uv))]), 0.1, 3)
    h.refine(0, 1.0)
    changed_hinge_refinements(h, 1.0, np.zeros((0, 2), np.int64), 1e-5, 0.01, 0.0,
                              np.zeros(0, np.int64))
