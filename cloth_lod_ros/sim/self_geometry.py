"""Geometry of self-collision (design §3): broad phase, closest points and
continuous (swept) tests, vectorised over many pairs.  Numpy only.

* :func:`layered_boxes` - the same hash of triangle boxes, asking only
  which cells may hold two layers (cloth far apart in the material, or faces
  turned by more than 60°): on a cloth without folds nothing further runs.
* :func:`box_pairs` - a uniform spatial hash: every axis-aligned box is
  entered in each grid cell it covers, boxes sharing a cell are candidates,
  and candidates whose boxes do not overlap are dropped.  No Python loop over
  boxes or pairs.
* :func:`point_triangle` and :func:`segment_segment` - closest points
  (Ericson, *Real-Time Collision Detection*, §5.1.5 and §5.1.9).
* :func:`vf_crossing` and :func:`ee_crossing` - continuous tests over a step
  in which every particle moves on a straight line from ``x0`` to ``x1``:
  the time of coplanarity of the four points is a root of a cubic in t
  (Provot 1997; Bridson et al. 2002), found by splitting [0, 1] at the roots
  of the derivative into monotonic pieces and bisecting each piece whose ends
  differ in sign (32 halvings: the root to 2e-10 of the step, far below
  ``eta`` for any motion a step makes); at each root
  the two primitives are tested for proximity (``eta``, m).  A crossing of a
  layer (a vertex through a triangle or an edge through an edge) changes the
  sign of that cubic, so every crossing is found; a grazing touch that does
  not change sides may be missed, and that is not a crossing.  Four points
  that stay coplanar for the whole step (|f| never above rounding) are not
  reported: their order is not a side.

Positions in m, times as fractions of the step.
"""

from __future__ import annotations

import numpy as np

__all__ = ["box_pairs", "layered_boxes", "point_triangle", "segment_segment", "vf_crossing",
           "ee_crossing", "edges_of"]


def edges_of(triangles: np.ndarray) -> np.ndarray:
    """Unique edges ``(e, 2)`` (sorted vertex pairs) of triangles ``(t, 3)``."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    e.sort(axis=1)
    n = int(triangles.max(initial=0)) + 1
    key = np.unique(e[:, 0] * n + e[:, 1])          # 1-D keys: far faster than axis=0
    return np.column_stack([key // n, key % n])


def _cells(lo: np.ndarray, hi: np.ndarray, cell: float, origin: np.ndarray,
           dims: np.ndarray):
    """Every (box, cell key) for boxes ``lo``/``hi`` ``(k, 3)`` on the grid."""
    c0 = np.floor((lo - origin) / cell).astype(np.int64)
    c1 = np.floor((hi - origin) / cell).astype(np.int64)
    span = c1 - c0 + 1                                   # (k, 3) >= 1
    count = span.prod(axis=1)
    box = np.repeat(np.arange(len(lo)), count)
    first = np.cumsum(count) - count
    local = np.arange(int(count.sum())) - first[box]
    sy, sz = span[box, 1], span[box, 2]
    k = c0[box, 2] + local % sz
    rest = local // sz
    j = c0[box, 1] + rest % sy
    i = c0[box, 0] + rest // sy
    return box, (i * dims[1] + j) * dims[2] + k


def layered_boxes(lo: np.ndarray, hi: np.ndarray, uv_lo: np.ndarray, uv_hi: np.ndarray,
                  pad: float, normals: np.ndarray) -> np.ndarray:
    """Whether any grid cell may hold two layers of cloth: ``(k,)`` bool per box.

    Every box (a triangle's, padded by ``pad`` m) is entered in the cells it
    covers, of side c (1.5 times the median box extent: each box covers a
    few cells).  A cell is flagged when

    * two of its triangles are far apart in the material: their material
      boxes ``uv_lo``/``uv_hi`` ``(k, 2)`` are more than
      ``S = 2 (√3 c + 2 pad)`` apart along u or v (``max(lo) − min(hi)``, one
      reduction per cell).  Two triangles of one piece of cloth without a fold
      that reach into the cell have points within √3 c + 2 pad in space,
      hence (the cloth compressed to no less than half its rest size) within
      S in the material; or
    * its triangles' unit ``normals`` ``(k, 3)`` do not all lie within 90° of
      their mean direction.  The two sides of a fold face opposite ways, so
      a cell holding both (as any cell does where they come within the
      padding of each other) is flagged however tight the fold.

    A cloth without folds flags nothing and pays this one hash; with them,
    only the flagged boxes go on to the pair search.
    """
    if not len(lo):
        return np.zeros(0, dtype=bool)
    cell = 1.5 * max(float(np.median((hi - lo).max(axis=1))), 1e-9)
    origin = lo.min(axis=0)
    dims = np.floor((hi.max(axis=0) - origin) / cell).astype(np.int64) + 1
    box, key = _cells(lo, hi, cell, origin, dims)
    order = np.argsort(key, kind="stable")
    key, box = key[order], box[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    gap = np.full(len(starts), -np.inf)
    for d in (0, 1):
        gap = np.maximum(gap, np.maximum.reduceat(uv_lo[box, d], starts)
                         - np.minimum.reduceat(uv_hi[box, d], starts))
    layered = gap > 2.0 * (np.sqrt(3.0) * cell + 2.0 * pad)
    counts = np.diff(np.r_[starts, len(key)])
    n = normals[box]
    mean = np.add.reduceat(n, starts, axis=0)
    mean /= np.maximum(np.linalg.norm(mean, axis=1), 1e-300)[:, None]
    cosine = np.einsum("kd,kd->k", n, np.repeat(mean, counts, axis=0))
    layered |= np.minimum.reduceat(cosine, starts) < 0.0
    out = np.zeros(len(lo), dtype=bool)
    if layered.any():
        out[box[np.repeat(layered, counts)]] = True
    return out


def box_pairs(lo_a: np.ndarray, hi_a: np.ndarray, lo_b: np.ndarray | None = None,
              hi_b: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(ia, ib)`` of overlapping boxes, each pair once.

    Args:
        lo_a, hi_a: ``(ka, 3)`` box corners, m.  lo_b, hi_b: ``(kb, 3)``; None:
            pairs within the first set, ``ia < ib``.
    """
    same = lo_b is None
    if same:
        lo_b, hi_b = lo_a, hi_a
    if not len(lo_a) or not len(lo_b):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # Cell: the median extent of the larger set's boxes (the triangles, edges),
    # so a typical box covers a few cells and a cell holds a few boxes.
    ext = (hi_a - lo_a).max(axis=1) if len(lo_a) >= len(lo_b) else (hi_b - lo_b).max(axis=1)
    cell = max(float(np.median(ext)), 1e-9)
    origin = np.minimum(lo_a.min(axis=0), lo_b.min(axis=0))
    top = np.maximum(hi_a.max(axis=0), hi_b.max(axis=0))
    dims = np.floor((top - origin) / cell).astype(np.int64) + 1
    box_a, key_a = _cells(lo_a, hi_a, cell, origin, dims)
    box_b, key_b = (box_a, key_a) if same else _cells(lo_b, hi_b, cell, origin, dims)
    order = np.argsort(key_a, kind="stable")
    key_sorted, box_sorted = key_a[order], box_a[order]
    start = np.searchsorted(key_sorted, key_b, side="left")
    stop = np.searchsorted(key_sorted, key_b, side="right")
    n = stop - start
    ib = np.repeat(box_b, n)
    first = np.cumsum(n) - n
    ia = box_sorted[np.repeat(start, n) + (np.arange(int(n.sum())) - np.repeat(first, n))]
    if same:
        keep = ia < ib
        ia, ib = ia[keep], ib[keep]
    if not len(ia):
        return ia, ib
    code = np.unique(ia * len(lo_b) + ib)
    ia, ib = code // len(lo_b), code % len(lo_b)
    overlap = np.all((lo_a[ia] <= hi_b[ib]) & (lo_b[ib] <= hi_a[ia]), axis=1)
    return ia[overlap], ib[overlap]


def _dot(a, b):
    return np.einsum("kd,kd->k", a, b)


def point_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(k, 3)`` of the point of triangle ``abc``
    nearest ``p`` (all ``(k, 3)``, m); Ericson §5.1.5, region by region."""
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        total = va + vb + vc
        v = np.where(total != 0, vb / total, 1.0 / 3.0)
        w = np.where(total != 0, vc / total, 1.0 / 3.0)
        bary = np.stack([1.0 - v - w, v, w], axis=1)
        # Later assignments win: this is Ericson's order of tests, reversed.
        e_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        s = (d4 - d3) / np.where(e_bc, (d4 - d3) + (d5 - d6), 1.0)
        bary[e_bc] = np.stack([np.zeros_like(s), 1 - s, s], axis=1)[e_bc]
        e_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        s = d2 / np.where(e_ac, d2 - d6, 1.0)
        bary[e_ac] = np.stack([1 - s, np.zeros_like(s), s], axis=1)[e_ac]
        bary[(d6 >= 0) & (d5 <= d6)] = (0.0, 0.0, 1.0)
        e_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        s = d1 / np.where(e_ab, d1 - d3, 1.0)
        bary[e_ab] = np.stack([1 - s, s, np.zeros_like(s)], axis=1)[e_ab]
        bary[(d3 >= 0) & (d4 <= d3)] = (0.0, 1.0, 0.0)
        bary[(d1 <= 0) & (d2 <= 0)] = (1.0, 0.0, 0.0)
    return bary


def segment_segment(p1, q1, p2, q2) -> tuple[np.ndarray, np.ndarray]:
    """Parameters ``(s, t)`` ``(k,)`` in [0, 1] of the closest points
    ``p1 + s (q1 − p1)`` and ``p2 + t (q2 − p2)`` (Ericson §5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    c, b = _dot(d1, r), _dot(d1, d2)
    tiny = 1e-30
    a_safe, e_safe = np.maximum(a, tiny), np.maximum(e, tiny)
    denom = a * e - b * b
    s = np.where(denom > 1e-12 * a * e, np.clip((b * f - c * e) / np.where(
        denom > 1e-12 * a * e, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_safe
    low, high = t < 0.0, t > 1.0
    s = np.where(low, np.clip(-c / a_safe, 0.0, 1.0), s)
    s = np.where(high, np.clip((b - c) / a_safe, 0.0, 1.0), s)
    t = np.clip(t, 0.0, 1.0)
    return s, t


def _cubic(b0, db, c0, dc, d0, dd):
    """Coefficients ``(4, k)`` of ``((b0 + t db) × (c0 + t dc)) · (d0 + t dd)``."""
    bc0 = np.cross(b0, c0)
    bc1 = np.cross(b0, dc) + np.cross(db, c0)
    bc2 = np.cross(db, dc)
    return np.stack([_dot(bc0, d0), _dot(bc0, dd) + _dot(bc1, d0),
                     _dot(bc1, dd) + _dot(bc2, d0), _dot(bc2, dd)])


def _roots01(coef: np.ndarray) -> np.ndarray:
    """Roots in [0, 1] of cubics ``(4, k)`` at which the sign changes,
    ``(k, 3)`` (NaN: none in that monotonic piece)."""
    c0, c1, c2, c3 = coef
    k = coef.shape[1]
    w0, w1, w2, w3 = (c[:, None] for c in coef)

    def f(t):                               # t: (k, 3)
        return ((w3 * t + w2) * t + w1) * t + w0

    # Pieces: [0, 1] split at the derivative's roots 3c3 t² + 2c2 t + c1 = 0.
    qa, qb, qc = 3 * c3, 2 * c2, c1
    disc = qb * qb - 4 * qa * qc
    sq = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        quad = np.abs(qa) > 1e-300
        r1 = np.where(quad, (-qb - sq) / (2 * qa), np.where(qb != 0, -qc / qb, np.nan))
        r2 = np.where(quad, (-qb + sq) / (2 * qa), np.nan)
    r1 = np.where(disc >= 0, r1, np.nan)
    r2 = np.where(disc >= 0, r2, np.nan)
    crit = np.sort(np.stack([r1, r2], axis=1), axis=1)            # NaN last
    crit = np.where((crit > 0) & (crit < 1), crit, np.nan)
    crit = np.sort(crit, axis=1)
    bounds = np.column_stack([np.zeros(k), crit, np.ones(k)])    # (k, 4) with NaN gaps
    # Fill gaps so each piece [lo, hi] is valid (empty pieces have lo == hi).
    for col in (1, 2):
        bounds[:, col] = np.where(np.isnan(bounds[:, col]), bounds[:, col - 1], bounds[:, col])
    bounds[:, 1:3] = np.maximum.accumulate(bounds[:, 1:3], axis=1)
    lo, hi = bounds[:, :3], bounds[:, 1:]
    flo, fhi = f(lo), f(hi)
    scale = np.abs(coef).sum(axis=0)[:, None]
    noise = 1e-12 * scale                  # coplanar throughout: no sign to change
    change = (hi > lo) & (((flo <= 0) & (fhi >= 0)) | ((flo >= 0) & (fhi <= 0))) \
        & ((np.abs(flo) > noise) | (np.abs(fhi) > noise))
    # Bisect only the pieces that hold a root (few: most pairs never meet).
    rows, cols = np.nonzero(change)
    a, b = lo[rows, cols], hi[rows, cols]
    rising = fhi[rows, cols] > flo[rows, cols]
    p0, p1, p2, p3 = c0[rows], c1[rows], c2[rows], c3[rows]
    for _ in range(32):
        m = 0.5 * (a + b)
        fm = ((p3 * m + p2) * m + p1) * m + p0
        right = (fm < 0) == rising          # the root is in the right half
        a = np.where(right, m, a)
        b = np.where(right, b, m)
    out = np.full((k, 3), np.nan)
    out[rows, cols] = 0.5 * (a + b)
    return out


def vf_crossing(x0: np.ndarray, x1: np.ndarray, verts: np.ndarray, tris: np.ndarray,
                eta: float) -> np.ndarray:
    """Which vertex–triangle pairs meet during the step, ``(k,)`` bool.

    Args:
        x0, x1: ``(n, 3)`` positions at the start and end of the step, m.
        verts: ``(k,)`` vertex indices; tris: ``(k, 3)`` triangle corners.
        eta: a vertex within ``eta`` m of the triangle at a coplanarity time meets it.
    """
    if not len(verts):
        return np.zeros(0, dtype=bool)
    p0, a0, b0, c0 = x0[verts], x0[tris[:, 0]], x0[tris[:, 1]], x0[tris[:, 2]]
    dp, da, db, dc = (x1[verts] - p0, x1[tris[:, 0]] - a0, x1[tris[:, 1]] - b0,
                      x1[tris[:, 2]] - c0)
    roots = _roots01(_cubic(b0 - a0, db - da, c0 - a0, dc - da, p0 - a0, dp - da))

    def gap(ok, tt):
        p, a, b, c = (p0[ok] + tt * dp[ok], a0[ok] + tt * da[ok], b0[ok] + tt * db[ok],
                      c0[ok] + tt * dc[ok])
        w = point_triangle(p, a, b, c)
        return p - (w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c)
    return _meets_at_roots(roots, gap, eta)


def ee_crossing(x0: np.ndarray, x1: np.ndarray, e1: np.ndarray, e2: np.ndarray,
                eta: float) -> np.ndarray:
    """Which edge–edge pairs (``(k, 2)`` each) meet during the step, ``(k,)`` bool
    (see :func:`vf_crossing`)."""
    if not len(e1):
        return np.zeros(0, dtype=bool)
    p0, q0, r0, s0 = x0[e1[:, 0]], x0[e1[:, 1]], x0[e2[:, 0]], x0[e2[:, 1]]
    dp, dq, dr, ds = (x1[e1[:, 0]] - p0, x1[e1[:, 1]] - q0, x1[e2[:, 0]] - r0,
                      x1[e2[:, 1]] - s0)
    roots = _roots01(_cubic(q0 - p0, dq - dp, s0 - r0, ds - dr, r0 - p0, dr - dp))

    def gap(ok, tt):
        p, q, r, s = (p0[ok] + tt * dp[ok], q0[ok] + tt * dq[ok], r0[ok] + tt * dr[ok],
                      s0[ok] + tt * ds[ok])
        u, v = segment_segment(p, q, r, s)
        return (p + u[:, None] * (q - p)) - (r + v[:, None] * (s - r))
    return _meets_at_roots(roots, gap, eta)


def _meets_at_roots(roots: np.ndarray, gap, eta: float) -> np.ndarray:
    """``(k,)`` bool: a pair meets if, at one of its coplanarity times ``roots``
    ``(k, 3)`` (NaN: none), the closest points are within ``eta`` m.  ``gap(ok,
    t)`` gives the ``(m, 3)`` vector between the closest points of the pairs
    selected by ``ok`` at their times ``t`` ``(m, 1)``."""
    hit = np.zeros(len(roots), dtype=bool)
    for j in range(3):                      # the cubic's (up to) three roots in [0, 1]
        t = roots[:, j]
        ok = ~np.isnan(t)
        if ok.any():
            hit[np.flatnonzero(ok)[np.linalg.norm(gap(ok, t[ok, None]), axis=1) <= eta]] = True
    return hit
