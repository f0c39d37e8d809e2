"""An independent interpenetration check for ``cloth-lod stress``.

Written apart from the simulator's self-collision code (which keeps layers
apart with proximity constraints and swept vertex–triangle / edge–edge tests
on a spatial hash): this looks only at one state and asks whether any two
triangles that share no vertex *intersect*.  Two triangles in general
position intersect exactly when an edge of one crosses the other, so every
(edge, triangle) pair that shares no vertex is tested with signed volumes
(the segment's ends strictly on opposite sides of the triangle's plane, and
the segment's line passing strictly inside the three edges).  Touching and
exactly coplanar configurations do not count.  The broad phase is a k-d tree
(scipy) on edge midpoints and triangle centroids with one radius: the
largest edge half-length plus the largest centroid-to-corner distance.

Positions in m.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["intersecting_pairs"]


def _orient(a, b, c, d) -> np.ndarray:
    """Six times the signed volume of tetrahedra ``abcd`` (all ``(k, 3)``)."""
    return np.einsum("kd,kd->k", np.cross(b - a, c - a), d - a)


def intersecting_pairs(x: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Pairs of triangles sharing no vertex that intersect, ``(k, 2)`` sorted
    triangle indices (each pair once).  (A triangle folded through a neighbour
    it shares a corner with is a distorted mesh, not two layers crossing.)

    Args:
        x: ``(n, 3)`` positions, m.  triangles: ``(t, 3)`` vertex indices.
    """
    tri = np.asarray(triangles, dtype=np.int64)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    edges.sort(axis=1)
    edges = np.unique(edges, axis=0)
    mid = 0.5 * (x[edges[:, 0]] + x[edges[:, 1]])
    half = 0.5 * np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1)
    centroid = x[tri].mean(axis=1)
    reach = np.linalg.norm(x[tri] - centroid[:, None, :], axis=2).max(axis=1)
    radius = float(half.max() + reach.max()) if len(tri) else 0.0
    if not len(tri):
        return np.zeros((0, 2), np.int64)
    pairs = cKDTree(mid).sparse_distance_matrix(cKDTree(centroid), radius,
                                                output_type="ndarray")
    ie, it = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64)
    e, t = edges[ie], tri[it]
    shares = (t == e[:, :1]).any(axis=1) | (t == e[:, 1:]).any(axis=1)
    ie, it, e, t = ie[~shares], it[~shares], e[~shares], t[~shares]
    p, q = x[e[:, 0]], x[e[:, 1]]
    a, b, c = x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]
    sp, sq = _orient(a, b, c, p), _orient(a, b, c, q)
    across = sp * sq < 0.0
    o1, o2, o3 = _orient(p, q, a, b), _orient(p, q, b, c), _orient(p, q, c, a)
    inside = ((o1 > 0) & (o2 > 0) & (o3 > 0)) | ((o1 < 0) & (o2 < 0) & (o3 < 0))
    hit = across & inside
    if not hit.any():
        return np.zeros((0, 2), np.int64)
    # The edge's own triangles (one or two) each intersect the hit triangle
    # (a loop over the hits only, which a passing run never has).
    out = set()
    for (i, j), other in zip(e[hit], it[hit]):
        for own in np.flatnonzero((tri == i).any(axis=1) & (tri == j).any(axis=1)):
            if not np.intersect1d(tri[own], tri[other]).size:     # non-adjacent only
                out.add((min(int(own), int(other)), max(int(own), int(other))))
    return np.array(sorted(out), dtype=np.int64).reshape(-1, 2)
