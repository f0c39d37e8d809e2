"""Compiled (numba) kernels for the LOD criterion (paper §5.1, §5.4; design §2, §4).

Every LOD check (:meth:`cloth_lod_ros.sim.lod.policy.LodPolicy.decide`) evaluates the
criterion on every hinge (:func:`cloth_lod_ros.sim.lod.policy.hinge_measures`),
lists the triangles to refine, finds the split particles whose merge is
valid (:meth:`Hierarchy48.split_vertices`), tests them (settled hinges, old
children, not held) and computes the energy each would add
(:func:`cloth_lod_ros.sim.lod.merge_energy.merge_energy_change`, compiled in
:mod:`.merge_energy_kernels`).  At adaptive-mesh sizes (a few hundred hinges,
tens of candidates) their numpy code is mostly the overhead of about a
hundred small passes; here each is one loop (:func:`criterion`,
:func:`refine_order`, :func:`split_candidates`, :func:`mergeable`).

The numpy code stays the reference, and the results here are *bitwise* equal:
the thresholds (``added.total <= bound``, the refine and coarsen deviations)
must choose the same operations either way.  So every floating-point
operation is the reference's, in its order (numba contracts nothing into FMAs
without fastmath).  Where the reference reduces with ``np.einsum`` the order
is einsum's, which is not left to right: its product-sum loop keeps two
float64 lanes (even and odd terms), runs a block of 8 terms from its last
pair to its first, the rest in pairs, then adds the two lanes.  So a
3-vector ``'kd,kd->k'`` is ``((0 + p0) + p2) + ((0 + p1) + 0)``, a 2-vector
``p0 + p1`` (:func:`_dot3`, :func:`_dot2`; the 12-term ``'hkd,hkd->h'`` of
the hinge rate in :func:`_criterion`).  The one product left to numpy is the
gravity term's ``(k, 3) @ (3,)`` (BLAS, whose order is the library's).
``np.tan`` and ``np.arctan2`` are the C library's in both.  The tests
(test/sim/lod/test_policy_kernels.py) compare both paths bitwise.

Switch: :func:`cloth_lod_ros.sim.runtime.compiled.enabled` (``CLOTH_LOD_KERNELS=numpy``
selects the reference); without numba everything is the reference.  Inputs
the kernels do not expect (a pool id missing from the compact ids) go to the
reference: its result or its error, never a read out of bounds.  The hinge
and element indices of :class:`~cloth_lod_ros.sim.physics.elements.Elements` are
trusted, as in :mod:`~cloth_lod_ros.sim.physics.forces_kernels`.
"""

from __future__ import annotations

import numpy as np

from ..runtime import compiled as _compiled
from ..physics import hinges_kernels as _hinges_kernels

__all__ = ["criterion", "refine_order", "split_candidates", "mergeable", "merge_candidates",
           "warm_up"]

_jit = _compiled._jit
_hinge_geometry = _hinges_kernels._hinge_geometry
_as_index = _compiled._as_index
_as_float = _compiled._as_float


@_jit
def _dot3(a0, a1, a2, b0, b1, b2):
    """``np.einsum('kd,kd->k')`` of one 3-vector pair, in einsum's order."""
    return ((0.0 + a0 * b0) + a2 * b2) + ((0.0 + a1 * b1) + 0.0)


@_jit
def _dot2(a0, a1, b0, b1):
    """``np.einsum('hd,hd->h')`` of one 2-vector pair, in einsum's order."""
    return (a0 * b0 + 0.0) + (a1 * b1 + 0.0)


@_jit
def _maximum(a, b):
    """``np.maximum`` of two floats: NaN if either is NaN."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a >= b else b


@_jit
def _norm(g, k):
    """``|∂θ/∂x_k|`` from a hinge's gradient ``g`` ``(12,)``, 1/m, as
    policy.hinge_measures sums the squares."""
    g0, g1, g2 = g[3 * k], g[3 * k + 1], g[3 * k + 2]
    return np.sqrt((g0 * g0 + g1 * g1) + g2 * g2)


@_jit
def _criterion(theta, grad, given, x, hv, v, weight, kb, lookahead, deviation,
               refine_deviation, rate, force, height):
    """The criterion on every hinge (paper §5.1; policy.hinge_measures, LodPolicy.decide).

    Args:
        theta ``(h,)`` rad and grad ``(h, 4, 3)`` 1/m: the hinge angles and
        their gradients if ``given``; else theta is an output, and both come
        from hinges_kernels._hinge_geometry at x ``(n, 3)`` m (hinges_kernels.hinge_angles'
        numbers, without storing the gradients).  hv ``(h, 4)`` int64; v
        ``(n, 3)`` m/s; weight ``(h,)`` c_e; kb N·m; lookahead s (0: none).
        deviation, refine_deviation, rate, force, height: ``(h,)`` outputs: d
        (m), d refined on (m; the larger of d now and at ``θ + lookahead θ̇``),
        θ̇ (rad/s), the largest bend force (N) and L (m).
    """
    g = np.empty(12)
    for h in range(hv.shape[0]):
        if given:
            th = theta[h]
            for j in range(12):
                g[j] = grad[h, j // 3, j % 3]
        else:
            th = _hinge_geometry(x, hv[h, 0], hv[h, 1], hv[h, 2], hv[h, 3], g)
            theta[h] = th
        n0, n1, n2, n3 = _norm(g, 0), _norm(g, 1), _norm(g, 2), _norm(g, 3)
        length = 0.5 * (1.0 / n2 + 1.0 / n3)
        height[h] = length
        # np.einsum('hkd,hkd->h', grad, v[hv]) over the 12 products: lanes of
        # even and odd terms, the block of 8 from its last pair, then 8..11.
        lane0 = 0.0
        lane1 = 0.0
        for j in (6, 4, 2, 0, 8, 10):
            lane0 = g[j] * v[hv[h, j // 3], j % 3] + lane0
            lane1 = g[j + 1] * v[hv[h, (j + 1) // 3], (j + 1) % 3] + lane1
        th_dot = lane0 + lane1
        rate[h] = th_dot
        largest = _maximum(_maximum(n0, n1), _maximum(n2, n3))
        force[h] = kb * weight[h] * np.abs(th) * largest
        d = 0.5 * length * np.tan(0.25 * np.abs(th))
        deviation[h] = d
        if lookahead > 0.0:
            ahead = th + lookahead * th_dot
            if ahead < -np.pi:              # np.clip (a NaN stays NaN)
                ahead = -np.pi
            elif ahead > np.pi:
                ahead = np.pi
            d = _maximum(d, 0.5 * length * np.tan(0.25 * np.abs(ahead)))
        refine_deviation[h] = d


@_jit
def _mergeable(hv, deviation, rate, force, coarsen, max_rate, max_force, vertex_ids,
               vertices, kids, birth, cutoff, held, vertex_end, ok):
    """Tests (a)–(d) of LodPolicy.decide for every split particle (the numpy
    lines there, per candidate).

    Args:
        hv ``(h, 4)`` int64; deviation (m), rate (rad/s), force (N) ``(h,)``;
        coarsen m, max_rate rad/s, max_force N: the settled-hinge limits;
        vertex_ids ``(n,)`` increasing compact pool ids; vertices ``(k,)``
        pool ids; kids ``(k, 4)`` their children (-1 padding); birth pool
        triangles' birth times, s; cutoff s; held ``(p,)`` pool ids;
        vertex_end the pool's vertex count.
        ok: ``(k,)`` output, whether each candidate passes.

    Returns:
        False if an id is out of range or not in vertex_ids (ok not valid).
    """
    n = vertex_ids.shape[0]
    blocked = np.zeros(n, dtype=np.bool_)
    for h in range(hv.shape[0]):
        if deviation[h] >= coarsen or np.abs(rate[h]) >= max_rate or force[h] >= max_force:
            for k in range(4):
                if hv[h, k] < 0 or hv[h, k] >= n:
                    return False
                blocked[hv[h, k]] = True
    is_held = np.zeros(vertex_end, dtype=np.bool_)
    for j in range(held.shape[0]):
        if held[j] < 0 or held[j] >= vertex_end:
            return False
        is_held[held[j]] = True
    for i in range(vertices.shape[0]):
        c = _find(vertex_ids, vertices[i])
        if c < 0 or vertices[i] >= vertex_end:
            return False
        youngest = -np.inf
        for j in range(4):               # padding -1 is never young
            t = kids[i, j]
            if t >= birth.shape[0]:
                return False
            youngest = _maximum(youngest, birth[t] if t >= 0 else -np.inf)
        ok[i] = not (blocked[c] or youngest > cutoff or is_held[vertices[i]])
    return True


@_jit
def _refine_order(deviation, threshold, hinge_tri, triangle_ids, level, max_level, detail,
                  out):
    """LodPolicy.decide's refine list: both triangles of every hinge with
    ``deviation`` ``(h,)`` above ``threshold`` (m), most curved first (ties in
    hinge order, as a stable argsort), then ``detail`` (pool ids), without
    repeats or triangles at ``max_level``.  Writes pool ids into ``out`` (at
    least ``2h + len(detail)`` long); returns how many, or -1 if an id is
    outside ``level`` (then the reference runs)."""
    over = np.flatnonzero(deviation > threshold)
    order = over[np.argsort(-deviation[over], kind="mergesort")]
    seen = np.zeros(level.shape[0], dtype=np.bool_)
    count = 0
    for j in range(2 * order.shape[0] + detail.shape[0]):
        if j < 2 * order.shape[0]:
            t = triangle_ids[hinge_tri[order[j // 2], j % 2]]
        else:
            t = detail[j - 2 * order.shape[0]]
        if t < 0 or t >= level.shape[0]:
            return -1
        if level[t] < max_level and not seen[t]:
            seen[t] = True
            out[count] = t
            count += 1
    return count


@_jit
def _split_candidates(vertex_active, vertex_end, vertex_parents, children, tri_active,
                      vertices, kids):
    """Hierarchy48.split_vertices: the active split particles (pool ids below
    ``vertex_end``, increasing) whose one or two parents' children are all
    active, into ``vertices`` ``(k,)`` and ``kids`` ``(k, 4)`` (-1 padding for
    a border diamond); returns k."""
    count = 0
    for m in range(vertex_end):
        if not vertex_active[m] or vertex_parents[m, 0] < 0:
            continue
        leaves = True
        for s in range(2):
            p = vertex_parents[m, s]
            for j in range(2):
                t = children[p, j] if p >= 0 else -1
                kids[count, 2 * s + j] = t
                if t >= 0 and not tri_active[t]:
                    leaves = False
        if leaves:
            vertices[count] = m
            count += 1
    return count


@_jit
def _merge_candidates(vertex_active, vertex_end, vertex_parents, children, tri_active, hv,
                      deviation, rate, force, coarsen, max_rate, max_force, vertex_ids, birth,
                      cutoff, held):
    """:func:`_split_candidates` then :func:`_mergeable` on them, in one call.

    Returns ``(vertices (k,), kids (k, 4), ok (k,) bool, done)``; done False
    as _mergeable's (ok not valid)."""
    vertices = np.empty(vertex_end, np.int64)
    kids = np.empty((vertex_end, 4), np.int64)
    count = _split_candidates(vertex_active, vertex_end, vertex_parents, children, tri_active,
                              vertices, kids)
    vertices, kids = vertices[:count].copy(), kids[:count].copy()
    ok = np.empty(count, np.bool_)
    done = _mergeable(hv, deviation, rate, force, coarsen, max_rate, max_force, vertex_ids,
                      vertices, kids, birth, cutoff, held, vertex_end, ok)
    return vertices, kids, ok, done


@_jit
def _find(ids, value):
    """``np.searchsorted(ids, value)`` in the increasing ``ids``; -1 if absent."""
    lo, hi = 0, ids.shape[0]
    while lo < hi:
        half = (lo + hi) >> 1
        if ids[half] < value:
            lo = half + 1
        else:
            hi = half
    if lo < ids.shape[0] and ids[lo] == value:
        return lo
    return -1


def criterion(elements, bend_stiffness: float, x: np.ndarray, v: np.ndarray,
              evaluation=None, lookahead: float = 0.0):
    """The hinge criterion by :func:`_criterion`, or None when the kernels are off.

    Args: elements (elements.Elements, with hinges); bend_stiffness N·m; x, v
    ``(n, 3)`` m, m/s; evaluation: a force evaluation of x whose hinge angles
    and gradients to use (None: computed here); lookahead s.

    Returns:
        ``(deviation, refine_deviation, rate, force, height, theta)``, ``(h,)``
        each (see :func:`_criterion`; theta the angles, rad).
    """
    if not _compiled.enabled():
        return None
    hv = _as_index(elements.hinge_vertices).reshape(-1, 4)
    count = len(hv)
    x = np.empty((0, 3)) if x is None else x        # only with an evaluation
    if evaluation is not None:
        theta = _as_float(evaluation.hinge_angle)
        grad = _as_float(evaluation.hinge_gradient)
    else:
        theta, grad = np.empty(count), np.empty((0, 4, 3))
    out = [np.empty(count) for _ in range(5)]
    _criterion(theta, grad, evaluation is not None, _as_float(x),
               hv, _as_float(v),
               _as_float(elements.hinge_weight),
               float(bend_stiffness), float(lookahead), *out)
    return (*out, theta)


def mergeable(hinge_vertices: np.ndarray, measures, config, vertex_ids: np.ndarray,
              vertices: np.ndarray, kids: np.ndarray, birth: np.ndarray, cutoff: float,
              held, vertex_end: int):
    """Which split particles pass tests (a)–(d) of LodPolicy.decide, by
    :func:`_mergeable`; None when the kernels are off or an input is not what
    they expect (the caller then runs the reference).

    Args: hinge_vertices ``(h, 4)``; measures: policy.HingeMeasures of the
    hinges; config: the LodConfig (coarsen threshold m, max hinge rate
    rad/s, max bend force N); vertex_ids ``(n,)`` increasing pool ids of the
    compact particles; vertices ``(k,)`` and kids ``(k, 4)`` from
    Hierarchy48.split_vertices; birth: the pool triangles' birth times, s;
    cutoff: a child born after it (s) is young; held: pool ids of held
    particles; vertex_end: the pool's vertex count.

    Returns:
        ``(k,)`` bool.
    """
    if not _compiled.enabled():
        return None
    ok = np.empty(len(vertices), dtype=bool)
    done = _mergeable(_as_index(hinge_vertices).reshape(-1, 4), measures.deviation,
                      measures.rate, measures.bend_force, float(config.coarsen_threshold),
                      float(config.max_hinge_rate), float(config.max_bend_force),
                      _as_index(vertex_ids), _as_index(vertices), _as_index(kids),
                      _as_float(birth), float(cutoff),
                      _as_index(np.asarray(held)).ravel(), int(vertex_end), ok)
    return ok if done else None


def refine_order(deviation: np.ndarray, threshold: float, hinge_triangles: np.ndarray,
                 triangle_ids: np.ndarray, level: np.ndarray, max_level: int,
                 detail: np.ndarray):
    """LodPolicy.decide's refine list (pool triangle ids, a Python list) by
    :func:`_refine_order`; None when the kernels are off or an id is out of
    range.  deviation ``(h,)`` m; threshold m; hinge_triangles ``(h, 2)``
    compact; triangle_ids, level, detail: pool ids and levels."""
    if not _compiled.enabled():
        return None
    detail = _as_index(detail).ravel()
    out = np.empty(2 * len(deviation) + len(detail), dtype=np.int64)
    count = _refine_order(_as_float(deviation), float(threshold),
                          _as_index(hinge_triangles).reshape(-1, 2), _as_index(triangle_ids),
                          _as_index(level), int(max_level), detail, out)
    return None if count < 0 else out[:count].tolist()


def merge_candidates(hierarchy, hinge_vertices: np.ndarray, measures, config,
                     vertex_ids: np.ndarray, cutoff: float, held):
    """:func:`split_candidates` and :func:`mergeable` on them in one compiled
    call: ``(vertices (k,), kids (k, 4), ok (k,) bool or None)`` (ok None
    when mergeable would be None: the caller runs the reference tests), or
    None when the kernels are off.  Arguments as those two functions'."""
    if not _compiled.enabled():
        return None
    h = hierarchy
    vertices, kids, ok, done = _merge_candidates(
        h.vertex_active, int(h.vertex_end), _as_index(h.vertex_parents), _as_index(h.children),
        h.tri_active, _as_index(hinge_vertices).reshape(-1, 4), measures.deviation,
        measures.rate, measures.bend_force, float(config.coarsen_threshold),
        float(config.max_hinge_rate), float(config.max_bend_force), _as_index(vertex_ids),
        _as_float(h.birth), float(cutoff), _as_index(np.asarray(held)).ravel())
    return vertices, kids, (ok if done else None)


def split_candidates(hierarchy):
    """:meth:`Hierarchy48.split_vertices` (``(vertices (k,), children (k, 4))``,
    the reference) by :func:`_split_candidates`; None when the kernels are off."""
    if not _compiled.enabled():
        return None
    h = hierarchy
    end = int(h.vertex_end)
    vertices, kids = np.empty(end, dtype=np.int64), np.empty((end, 4), dtype=np.int64)
    count = _split_candidates(h.vertex_active, end, _as_index(h.vertex_parents),
                              _as_index(h.children), h.tri_active, vertices, kids)
    return vertices[:count].copy(), kids[:count].copy()


def warm_up_hierarchy():
    """What the LOD kernels' warm-ups run on: a 2 x 2-block hierarchy with
    every base triangle refined once, ``(hierarchy, vertex_ids, triangle_ids,
    elements)`` of its compact mesh."""
    from ..mesh.hierarchy import Hierarchy48
    from ..mesh.mesh48 import base_mesh
    from ..physics.elements_kernels import precompute
    base = base_mesh(1.0, 1.0, 2, 2)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(len(base.uv))]), 0.1, 3)
    for t in range(base.triangle_count):
        h.refine(t, 0.0)
    mesh, vertex_ids, triangle_ids = h.active_mesh()
    return h, vertex_ids, triangle_ids, precompute(mesh)


def warm_up() -> None:
    """Compile or load these kernels (the signatures a simulation calls) on a
    small refined hierarchy, so no timed step pays for it.  Nothing without numba."""
    if not _compiled.enabled():
        return
    from types import SimpleNamespace

    h, vertex_ids, triangle_ids, elements = warm_up_hierarchy()
    x, v = h.x[vertex_ids], h.v[vertex_ids]
    theta, grad = _hinges_kernels.hinge_angles(x, elements.hinge_vertices, with_gradient=True)
    criterion(elements, 1e-5, x, v, SimpleNamespace(hinge_angle=theta, hinge_gradient=grad),
              0.01)
    deviation, _, rate, force, _, _ = criterion(elements, 1e-5, x, v, None, 0.01)
    refine_order(deviation, 0.0, elements.hinge_triangles, triangle_ids, h.level, h.max_level,
                 np.zeros(0, dtype=np.int64))
    merge_candidates(h, elements.hinge_vertices,
                     SimpleNamespace(deviation=deviation, rate=rate, bend_force=force),
                     SimpleNamespace(coarsen_threshold=1.0, max_hinge_rate=1.0,
                                     max_bend_force=1.0),
                     vertex_ids, -1.0, np.zeros(1, dtype=np.int64))
    vertices, kids = split_candidates(h)
    mergeable(elements.hinge_vertices,
              SimpleNamespace(deviation=deviation, rate=rate, bend_force=force),
              SimpleNamespace(coarsen_threshold=1.0, max_hinge_rate=1.0, max_bend_force=1.0),
              vertex_ids, vertices, kids, h.birth, -1.0, np.zeros(1, dtype=np.int64),
              h.vertex_end)
