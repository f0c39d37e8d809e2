"""The bend part of a merge's energy change: the exact change of the stencil
energy of :mod:`cloth_lod_ros.sim.physics.bending`, for all candidates at once.

The bending energy ``E = k_b/2 Σ_s |D_s x|²`` is a sum over stencils (lines
and twists of the 4-8 lattice, least-squares two-ring fits where one is
missing).  A merge removes the split particle m, its two or four children
and puts back their one or two parents; a stencil changes only if what it is
made of changes, and every ingredient is local:

* line stencils at m and its neighbours (the edge ends l, r and the
  parents' apexes: their neighbours and corner areas change);
* twists of the diamonds made of a child or a parent (hypotenuses at
  distance 1 from m);
* fitted terms where a corner asks for a missing line or twist: at m's
  neighbours, and at the far corner of a triangle across a parent's leg that
  loses its diamond partner (a child) or gains one (distance 2);
* the two-ring fits of every vertex whose two-ring contains m, l–r or a
  changed vertex: distance ≤ 2 from m.

So with every stencil assigned to a *centre* (a line and a fit to its own
vertex, a twist to the lower id of its hypotenuse), the merge changes only
stencils centred within graph distance 2 of m (3 where the merge makes a
clamped triangle whole, below).  A stencil centred at c is made from the
triangles touching c's one-ring (its two-ring fit, its lines' neighbours,
its triangles' diamond partners) and, with clamps, from whether its
two-ring's vertices are held (triangles touching c's two-ring).  For each
candidate this module cuts out the triangles touching the ball of radius
``centre radius + 1`` (+ 2 with clamps) around m, replaces the children by
the parents, and evaluates :func:`~cloth_lod_ros.sim.physics.bending.bend_stencils`
on all those pieces at once (one call, disjoint vertex sets); the energy
after is that of the piece's stencils centred in the ball, the energy before
that of the current mesh's stencils (``elements.bend``) centred in the same
ball.  Everything else cancels: the stencils outside the ball are the same
before and after.  Vectorised over candidates: one sparse product per ball
radius and one ``bend_stencils`` call, no per-candidate Python loop.  Both
radii are the smallest that pass ``test/sim/lod/test_merge_energy.py`` (one
less fails it, with and without clamps).  This is the numpy reference; the
compiled path (:mod:`~cloth_lod_ros.sim.lod.merge_bend_kernels`) makes the
same pieces one candidate at a time in one kernel (the pieces overlap: the
batch here costs ~10 times the whole mesh's stencils).

Clamps (``elements.clamped``): a merge whose parent has all three corners
clamped while m is not makes that parent a whole clamped triangle (its
corners become *held*, which changes one-sided lines and fits up to a
two-ring from them): such candidates, and every candidate with a clamped
particle within distance 4 (a pin's disc cannot make one: m lies between
held corners, so it is held too, and held particles are not merged), use
centre radius 3 and a piece of radius 5.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..physics.bending import bend_stencils

__all__ = ["merge_bend_change", "stencil_centres", "stencil_energies_per_vertex"]


def stencil_centres(verts: np.ndarray, coef: np.ndarray, fitted: bool) -> np.ndarray:
    """The centre vertex of each stencil of one kind of
    :class:`~cloth_lod_ros.sim.physics.bending.BendStencils`, ``(s,)``.

    A line stencil (``[c, j₊, j₋, c]`` with coefficient 0 on the repeat) and a
    fitted one (``fitted``: ``[c, ring...]``) belong to c; a twist
    ``[e0, e1, o0, o1]`` to ``min(e0, e1)``, its hypotenuse's lower id (which
    of its two triangles lists it first does not matter).  Vertex ids as in
    ``verts``.
    """
    if fitted:
        return verts[:, 0]
    line = (verts[:, 3] == verts[:, 0]) & (coef[:, 3] == 0.0)
    return np.where(line, verts[:, 0], np.minimum(verts[:, 0], verts[:, 1]))


def stencil_energies_per_vertex(stencils, x: np.ndarray) -> np.ndarray:
    """``Σ |D_s x|²`` (dimensionless², ×k_b/2 is J) of the stencils centred
    at each vertex, ``(n,)`` for positions ``x`` ``(n, 3)`` m."""
    out = np.zeros(len(x))
    for c, e in _stencil_energies(stencils, x):
        out += np.bincount(c, weights=e, minlength=len(x))
    return out


def _stencil_energies(stencils, x: np.ndarray):
    """``[(centres (s,), |D_s x|² (s,))]`` per kind (centres in ``x``'s ids);
    kind 0 the lines and twists, kind 1 the fits (BendStencils.kinds)."""
    out = []
    for kind, (verts, coef) in enumerate(stencils.kinds):
        D = np.einsum("sk,skd->sd", coef, x[verts])
        out.append((stencil_centres(verts, coef, kind == 1), np.einsum("sd,sd->s", D, D)))
    return out


def _balls(start: sp.csr_matrix, adjacency: sp.csr_matrix, radius: int) -> list:
    """``[B_0, ..., B_radius]``: ``(k, n)`` 0/1 csr, the vertices within graph
    distance d of each row's start vertex."""
    balls = [start]
    for _ in range(radius):
        grown = balls[-1] + balls[-1] @ adjacency
        grown.data[:] = 1.0
        balls.append(grown.tocsr())
    return balls


def merge_bend_change(hierarchy, elements, vertex_ids: np.ndarray, vertices: np.ndarray,
                      mid: np.ndarray, x: np.ndarray, bend_stiffness: float) -> np.ndarray:
    """Bend-energy change, J, ``(k,)``, of merging each split particle alone.

    Args:
        hierarchy: the adaptive mesh (read only).
        elements: rest data of the active (compact) mesh: ``triangles``,
            ``rest_uv`` (m), ``clamped`` and its stencils ``bend``.
        vertex_ids: ``(n,)`` increasing pool ids of the compact vertices.
        vertices: ``(k,)`` pool ids of the split particles (valid merges).
        mid: ``(k,)`` their compact ids.
        x: ``(n, 3)`` compact positions, m.
        bend_stiffness: k_b, N·m.

    Returns:
        ``E_bend(merged) − E_bend(now)`` per candidate, J (module docstring).
    """
    k = len(vertices)
    kinds = elements.bend.kinds
    if k == 0 or not kinds or elements.rest_uv is None:
        return np.zeros(k)
    h = hierarchy
    tri = elements.triangles
    n, t = len(x), len(tri)
    clamped = elements.clamped
    # Parents' corners and the children, compact.
    parents = h.vertex_parents[vertices]                            # (k, 2), -1 pad
    has = parents >= 0
    parent_tri = np.searchsorted(vertex_ids, h.tri[np.maximum(parents, 0)])   # (k, 2, 3)
    rows = np.repeat(np.arange(t), 3)
    incidence = sp.csr_matrix((np.ones(3 * t), (tri.ravel(), rows)), shape=(n, t))
    edge_i = tri[:, [0, 1, 2, 1, 2, 0]].ravel()
    edge_j = tri[:, [1, 2, 0, 0, 1, 2]].ravel()
    adjacency = sp.csr_matrix((np.ones(len(edge_i)), (edge_i, edge_j)), shape=(n, n))
    start = sp.csr_matrix((np.ones(k), (np.arange(k), mid)), shape=(k, n))

    centre_radius = np.full(k, 2)
    if clamped is not None and np.any(clamped):
        balls = _balls(start, adjacency, 5)
        near = np.asarray(balls[4] @ clamped.astype(float)).ravel() > 0
        centre_radius[near] = 3
        piece_radius = centre_radius + np.where(near, 2, 1)
    else:
        balls = _balls(start, adjacency, 3)
        piece_radius = centre_radius + 1
    centre = _pick(balls, centre_radius)                            # (k, n) 0/1
    piece = _pick(balls, piece_radius)

    # Before: the current stencils centred in each ball.
    before = centre @ stencil_energies_per_vertex(elements.bend, x)

    # After: each piece with the children replaced by the parents.
    touching = (piece @ incidence).tocoo()                          # (candidate, triangle)
    key = np.unique(touching.row.astype(np.int64) * t + touching.col)
    owner, tri_id = key // t, key % t
    keep = ~(tri[tri_id] == mid[owner, None]).any(axis=1)           # not a child
    owner, tri_id = owner[keep], tri_id[keep]
    parent_owner = np.nonzero(has)[0]
    owner = np.concatenate([owner, parent_owner])
    corners = np.concatenate([tri[tri_id], parent_tri[has]])        # (p, 3) compact
    local_key, local = np.unique(owner[:, None] * n + corners, return_inverse=True)
    local = local.reshape(-1, 3)
    local_vertex, local_owner = local_key % n, local_key // n
    listed = centre.tocoo()
    in_centre = np.isin(local_key, listed.row.astype(np.int64) * n + listed.col)
    stencils = bend_stencils(elements.rest_uv[local_vertex], local,
                             None if clamped is None else clamped[local_vertex], fit=in_centre)
    after = np.zeros(k)
    for c, e in _stencil_energies(stencils, x[local_vertex]):
        counted = in_centre[c]
        after += np.bincount(local_owner[c[counted]], weights=e[counted], minlength=k)
    return 0.5 * bend_stiffness * (after - before)


def _pick(balls: list, radius: np.ndarray) -> sp.csr_matrix:
    """Row i of ``balls[radius[i]]``, ``(k, n)`` csr."""
    out = None
    for r in np.unique(radius):
        select = sp.diags((radius == r).astype(float))
        part = select @ balls[int(r)]
        out = part if out is None else out + part
    return out.tocsr()
