"""An independent interpenetration check for ``cloth-lod stress``.

Written apart from the simulator's self-collision code (which keeps layers
apart with proximity constraints and swept vertex–triangle / edge–edge tests
on a spatial hash): this looks only at one state and asks whether any two
triangles that share no vertex *intersect*.  Two triangles in general
position intersect exactly when an edge of one crosses the other, so every
(edge, triangle) pair that shares no vertex is tested with signed volumes
(the segment's ends strictly on opposite sides of the triangle's plane, and
the segment's line passing strictly inside the three edges).  Touching and
coplanar configurations do not count: a signed volume within the rounding
bound of its own evaluation counts as zero (cloth lying flat on a floor has
whole regions in one plane, where the signs of the rounded volumes are noise
and crossed "pairs" would be found between triangles that do not overlap).  The broad phase is a k-d tree
(scipy) on edge midpoints and triangle centroids with one radius: the
largest edge half-length plus the largest centroid-to-corner distance.

Positions in m.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["intersecting_pairs"]


_EPS = float(np.finfo(float).eps)


def _orient(a, b, c, d, size: float) -> np.ndarray:
    """Six times the signed volume of tetrahedra ``abcd`` (all ``(k, 3)``, m),
    m³, set to 0 where its magnitude is within the rounding bound of its
    evaluation: each difference ``b − a`` carries an error up to
    ``eps·size`` per component (``size`` m, the largest coordinate), which
    the triple product multiplies by the other two lengths (a bound with a
    factor 8 of margin, far below any real crossing: a segment end 10⁻¹⁴ m
    through a 1 cm triangle is 10⁻¹⁸ m³)."""
    e, f, g = b - a, c - a, d - a
    volume = np.einsum("kd,kd->k", np.cross(e, f), g)
    le, lf, lg = (np.linalg.norm(w, axis=1) for w in (e, f, g))
    bound = 8.0 * _EPS * (le * lf * lg + size * (le * lf + lf * lg + le * lg))
    return np.where(np.abs(volume) > bound, volume, 0.0)


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
    size = float(np.abs(x).max())
    sp, sq = _orient(a, b, c, p, size), _orient(a, b, c, q, size)
    across = sp * sq < 0.0
    o1, o2, o3 = (_orient(p, q, a, b, size), _orient(p, q, b, c, size),
                  _orient(p, q, c, a, size))
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
