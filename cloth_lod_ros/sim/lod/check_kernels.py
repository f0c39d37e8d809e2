"""A LOD check's whole decision in one compiled call, when no filter applies.

:meth:`~cloth_lod_ros.sim.lod.policy.LodPolicy.decide` runs the criterion, the refine
order, the merge candidates with their tests (a)-(d) and the energy each
merge would add as four compiled calls (:mod:`~cloth_lod_ros.sim.lod.policy_kernels`),
with Python in between for the filters some scenes need (grasp detail,
obstacles holding particles up, layers nearby, particles between two
obstacles).  A scene with none of them (a hanging or draped cloth without
contact) needs nothing in between: :func:`plain_decision` makes the same
calls inside one kernel, which saves the wrappers' conversions and three
dispatches per check, run with the caches cold after a time step.  The
numbers are the same kernels' and the last test's the same operations
(:func:`_kept`; only the gravity term's product stays in numpy, as BLAS
orders it; the bend part of the merge energies is
:func:`~cloth_lod_ros.sim.lod.merge_bend_kernels.bend_changes`, as the staged
path's), so the decision is the staged one's bit for bit (tested:
test/sim/lod/test_check_kernels.py).
"""

from __future__ import annotations

import numpy as np

from ..runtime import compiled as _compiled
from .policy_kernels import _criterion, _merge_candidates, _refine_order
from .merge_bend_kernels import bend_changes
from .merge_energy_kernels import _merge_energies

__all__ = ["plain_decision", "warm_up"]

_jit = _compiled._jit
_as_index, _as_float = _compiled._as_index, _compiled._as_float
_NOTHING_HELD = np.zeros(0, dtype=np.int64)


@_jit
def _plain(hv, weight, ht, triangle_ids, x, v, kb, lookahead, threshold, level, max_level,
           detail, simplify, vertex_active, vertex_end, vertex_parents, children, tri_active,
           coarsen, max_rate, max_force, vertex_ids, birth, cutoff, held, vertex_edge, pool_tri,
           uv, tri, coef_u, coef_v, area, masses, ks, ksh):
    """lod_kernels' _criterion, _refine_order, _merge_candidates and
    _merge_energies in turn (their arguments, as decide passes them):
    ``(ok, refine, candidates passing (a)-(d), their energies without the
    gravity term, kinetic parts, diamond areas, compact midpoints, chord
    offsets)``; ok False where one of them declines.  The energies lack the
    bend part too (merge_bend_kernels.bend_changes, added by the caller)."""
    count = hv.shape[0]
    theta, deviation, refine_deviation = np.empty(count), np.empty(count), np.empty(count)
    rate, force, height = np.empty(count), np.empty(count), np.empty(count)
    _criterion(theta, np.empty((0, 4, 3)), False, x, hv, v, weight, kb, lookahead, deviation,
               refine_deviation, rate, force, height)
    out = np.empty(2 * count + detail.shape[0], np.int64)
    written = _refine_order(refine_deviation, threshold, ht, triangle_ids, level, max_level,
                            detail, out)
    empty, none = np.empty(0), np.empty(0, np.int64)
    if written < 0:
        return False, out[:0], none, empty, empty, empty, none, np.empty((0, 3))
    if not simplify:
        return True, out[:written], none, empty, empty, empty, none, np.empty((0, 3))
    vertices, kids, ok, done = _merge_candidates(
        vertex_active, vertex_end, vertex_parents, children, tri_active, hv, deviation, rate,
        force, coarsen, max_rate, max_force, vertex_ids, birth, cutoff, held)
    if not done:
        return False, out[:0], none, empty, empty, empty, none, np.empty((0, 3))
    kept = vertices[ok]
    k = kept.shape[0]
    delta, kinetic, diamond_area = np.empty(k), np.empty(k), np.empty(k)
    mid, offset = np.empty(k, np.int64), np.empty((k, 3))
    if k and not _merge_energies(kept, vertex_ids, triangle_ids, vertex_edge, vertex_parents,
                                 pool_tri, children, uv, tri, coef_u, coef_v, area, x, v,
                                 masses, ks, ksh, delta, kinetic, diamond_area, mid, offset):
        return False, out[:0], none, empty, empty, empty, none, np.empty((0, 3))
    return True, out[:written], kept, delta, kinetic, diamond_area, mid, offset


@_jit
def _kept(kept, delta, kinetic, mass_of_mid, gravity_offset, area, half_density, speed2,
          vertex_edge):
    """merge_energy_change's last line and test (e) of decide, their operations in
    their order: ``delta + (kinetic + m · (offset · g))`` against ``(½ ρ) A v²``.
    Returns the merges that pass: ``(edges (k, 2), energy, kinetic, bound)``."""
    count = kept.shape[0]
    total, bound = np.empty(count), np.empty(count)
    passing = 0
    for i in range(count):
        total[i] = delta[i] + (kinetic[i] + mass_of_mid[i] * gravity_offset[i])
        bound[i] = half_density * area[i] * speed2
        if total[i] <= bound[i]:
            passing += 1
    edges = np.empty((passing, 2), np.int64)
    energy, kept_kinetic, kept_bound = np.empty(passing), np.empty(passing), np.empty(passing)
    j = 0
    for i in range(count):
        if total[i] <= bound[i]:
            edges[j, 0], edges[j, 1] = vertex_edge[kept[i], 0], vertex_edge[kept[i], 1]
            energy[j], kept_kinetic[j], kept_bound[j] = total[i], kinetic[i], bound[i]
            j += 1
    return edges, energy, kept_kinetic, kept_bound


def plain_decision(hierarchy, elements, vertex_ids, triangle_ids, x, v, masses, time, held,
                   config, material, gravity, lookahead: float, detail: np.ndarray,
                   simplify: bool):
    """:meth:`LodPolicy.decide`'s numbers without filters: ``(refine (list of
    pool triangles), merge (list of split edges), energy, kinetic, bound)``
    (J, ``(len(merge),)``), or None when the kernels are off or an id is out
    of their range (then the staged path decides).  Arguments as decide's;
    config, material: its LodConfig and MaterialConfig; gravity ``(3,)`` m/s²;
    detail: the pool triangles to refine for detail."""
    if not _compiled.enabled():
        return None
    h = hierarchy            # (its pools are contiguous with fixed dtypes, as the kernels take them)
    x, hv = _as_float(x), _as_index(elements.hinge_vertices).reshape(-1, 4)
    # (A read-only array is another type to numba: a compilation mid-run.)
    held = np.array(held, dtype=np.int64).ravel() if simplify else _NOTHING_HELD
    ok, refine, kept, delta, kinetic, area, mid, offset = _plain(
        hv, _as_float(elements.hinge_weight), _as_index(elements.hinge_triangles).reshape(-1, 2),
        _as_index(triangle_ids), x, _as_float(v), float(material.bend_stiffness),
        float(lookahead), float(config.refine_threshold), h.level, int(h.max_level),
        _as_index(detail).ravel(), bool(simplify), h.vertex_active, int(h.vertex_end),
        h.vertex_parents, h.children, h.tri_active,
        float(config.coarsen_threshold), float(config.max_hinge_rate),
        float(config.max_bend_force), _as_index(vertex_ids), h.birth,
        float(time - config.min_lifetime), held,
        h.vertex_edge, h.tri, h.uv,
        _as_index(elements.triangles), _as_float(elements.coef_u), _as_float(elements.coef_v),
        _as_float(elements.area), _as_float(masses), float(material.stretch_stiffness),
        float(material.shear_stiffness))
    if not ok:
        return None
    if not len(kept):
        return refine.tolist(), [], np.zeros(0), np.zeros(0), np.zeros(0)
    # The bend part (merge_bend_kernels: compiled, the pieces' stencils).
    delta += bend_changes(h, elements, vertex_ids, kept, mid, x, material.bend_stiffness)
    # The gravity term's product as merge_energy_change makes it (BLAS's order).
    gravity_offset = offset @ np.asarray(gravity, dtype=float)
    edges, energy, kinetic, bound = _kept(kept, delta, kinetic, masses[mid], gravity_offset,
                                          area, 0.5 * material.density,
                                          config.max_merge_speed**2, h.vertex_edge)
    return refine.tolist(), list(map(tuple, edges.tolist())), energy, kinetic, bound


def warm_up() -> None:
    """Compile or load the kernel on a small refined hierarchy.  Nothing without numba."""
    if not _compiled.enabled():
        return
    from types import SimpleNamespace

    from .policy_kernels import warm_up_hierarchy
    h, vertex_ids, triangle_ids, elements = warm_up_hierarchy()
    config = SimpleNamespace(refine_threshold=0.0, coarsen_threshold=1.0, max_hinge_rate=1.0,
                             max_bend_force=1.0, min_lifetime=-1.0, max_merge_speed=1.0)
    material = SimpleNamespace(bend_stiffness=1e-5, stretch_stiffness=1.0,
                               shear_stiffness=1.0, density=0.1)
    plain_decision(h, elements, vertex_ids, triangle_ids, h.x[vertex_ids], h.v[vertex_ids],
                   h.masses[vertex_ids], 0.0, np.zeros(1, dtype=np.int64), config, material,
                   np.zeros(3), 0.01, np.zeros(0, dtype=np.int64), True)
