"""Geometry of self-collision (design §3): broad phase, closest points and
continuous (swept) tests, vectorised over many pairs.  Numpy, the
reference; :func:`layered_boxes` and :func:`box_pairs` run compiled twins from
:mod:`~cloth_lod_ros.sim.self_kernels` when the kernels are enabled.

* :func:`layered_boxes` - a hash of the triangles' boxes asking only
  which cells may hold two layers (cloth far apart in the material, or faces
  turned by more than 90° from their cell's mean): on a cloth without folds
  nothing further runs.
* :func:`box_pairs` - a uniform spatial hash: every axis-aligned box is
  entered in each grid cell it covers, boxes sharing a cell are candidates,
  and candidates whose boxes do not overlap are dropped (a few boxes: every
  pair tested at once).  No Python loop over boxes or pairs.
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

from . import kernels as _kernels
from . import self_kernels as _self_kernels

__all__ = ["box_pairs", "layered_boxes", "point_triangle", "segment_segment", "vf_crossing",
           "ee_crossing", "edges_of"]


#: Up to this many candidate pairs, :func:`box_pairs` tests them all directly.
_ALL_PAIRS = 1 << 15



def edges_of(triangles: np.ndarray) -> np.ndarray:
    """Unique edges ``(e, 2)`` (sorted vertex pairs) of triangles ``(t, 3)``."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    e.sort(axis=1)
    n = int(triangles.max(initial=0)) + 1
    key = np.unique(e[:, 0] * n + e[:, 1])          # 1-D keys: far faster than axis=0
    return np.column_stack([key // n, key % n])


def _extent(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``(k,)`` largest side of each box ``lo``/``hi`` ``(k, 3)``.

    Here and below (k, 3) arrays are handled a column at a time: numpy
    reduces them along either axis, and fancy-indexes their rows, several
    times slower than it works on contiguous columns (this is most of the
    time of a hash over a few thousand boxes)."""
    return np.maximum(np.maximum(hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1]), hi[:, 2] - lo[:, 2])


def _corner(a: np.ndarray, top: bool) -> np.ndarray:
    """``(3,)`` the per-axis minimum (``top``: maximum) of points ``(k, 3)``."""
    return np.array([a[:, d].max() if top else a[:, d].min() for d in range(a.shape[1])])


def _median(values: np.ndarray) -> float:
    """The median of ``values`` ``(k,)``, as ``np.median`` gives it, by a
    partition (``np.median`` costs several times more on short arrays)."""
    middle = len(values) // 2
    if len(values) % 2:
        return float(np.partition(values, middle)[middle])
    part = np.partition(values, (middle - 1, middle))
    return float((part[middle - 1] + part[middle]) / 2.0)


#: The 8 cells of a 2 x 2 x 2 block as offsets ``(i, j, k)``, cell ``o`` having
#: bits ``o = 4 i + 2 j + k``.
_BLOCK = np.array([[(o >> 2) & 1, (o >> 1) & 1, o & 1] for o in range(8)])
#: ``_IN_BLOCK[e, o]``: a box reaching one cell further along the axes of the
#: bits ``e`` covers the block's cell ``o``.
_IN_BLOCK = np.array([[(o & ~e) == 0 for o in range(8)] for e in range(8)])


def _cells(lo: np.ndarray, hi: np.ndarray, cell: float, origin: np.ndarray,
           dims: np.ndarray):
    """Every (box, cell key) for boxes ``lo``/``hi`` ``(k, 3)`` (m) on the grid of
    side ``cell`` (m) from ``origin`` ``(3,)`` with ``dims`` ``(3,)`` cells:
    ``(box index, key)`` arrays of equal length, sorted by box."""
    first = np.floor((lo - origin) / cell).astype(np.int64)
    extra = np.floor((hi - origin) / cell).astype(np.int64) - first     # (k, 3) >= 0
    strides = np.array([dims[1] * dims[2], dims[2], 1])
    base = first @ strides
    if extra.max(initial=0) <= 1:
        # The cell is larger than most boxes, so each covers at most a 2 x 2 x 2
        # block: which of its 8 cells is one table row per box (a handful of
        # numpy calls in all, where a box-by-box expansion takes dozens).
        entry = np.flatnonzero(_IN_BLOCK.take(extra @ np.array([4, 2, 1]), 0))
        box = entry >> 3
        return box, base.take(box) + (_BLOCK @ strides).take(entry & 7)
    span = [np.ascontiguousarray(extra[:, d]) + 1 for d in range(3)]
    count = span[0] * span[1] * span[2]
    box = np.repeat(np.arange(len(lo)), count)
    start = np.cumsum(count) - count
    local = np.arange(int(count.sum())) - start.take(box)
    sy, sz = span[1].take(box), span[2].take(box)
    rest = local // sz
    return box, base.take(box) + ((rest // sy) * dims[1] + rest % sy) * dims[2] + local % sz


def _dense(key: np.ndarray, dims: np.ndarray) -> tuple[np.ndarray, int]:
    """Cell keys as indices into per-cell arrays, and their length: the keys
    themselves while the grid is not much larger than the entries (a cloth's
    bounding box: a few cells per entry), else the keys renumbered."""
    cells = int(dims.prod())
    if cells <= 8 * len(key) + 4096:
        return key, cells
    unique, index = np.unique(key, return_inverse=True)
    return index.ravel(), len(unique)


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
    only the flagged boxes go on to the pair search.  The per-cell maxima,
    minima and sums are scattered into arrays over the cells (``ufunc.at``,
    ``bincount``) rather than grouped by sorting the keys, which cost more
    than all the rest.
    """
    if not len(lo):
        return np.zeros(0, dtype=bool)
    cell = 1.5 * max(_median(_extent(lo, hi)), 1e-9)
    origin, top = _corner(lo, False), _corner(hi, True)
    dims = np.floor((top - origin) / cell).astype(np.int64) + 1
    far = 2.0 * (np.sqrt(3.0) * cell + 2.0 * pad)
    finite = np.isfinite(far) and np.all(np.isfinite(origin)) and np.all(np.isfinite(top))
    # (The cell count in floating point: an int64 product of huge dims wraps.)
    if _kernels.enabled() and finite and dims.prod(dtype=float) <= 8 * len(lo) + 4096:
        # Compiled, on the dense grid (a cloth's bounding box): ~10x faster.
        # (Only for finite boxes: the kernel indexes cells without checks.)
        out = np.zeros(len(lo), dtype=bool)
        _self_kernels.layered_cells(np.ascontiguousarray(lo), np.ascontiguousarray(hi),
                                    np.ascontiguousarray(uv_lo), np.ascontiguousarray(uv_hi),
                                    np.ascontiguousarray(normals), cell, origin, dims, far, out)
        return out
    box, key = _cells(lo, hi, cell, origin, dims)
    key, cells = _dense(key, dims)
    layered = np.zeros(cells, dtype=bool)
    # (Columns one at a time: numpy's fancy indexing of (k, 3) arrays costs
    # several times a take of their columns.)
    for d in (0, 1):
        top = np.full(cells, -np.inf)
        np.maximum.at(top, key, np.ascontiguousarray(uv_lo[:, d]).take(box))
        bottom = np.full(cells, np.inf)
        np.minimum.at(bottom, key, np.ascontiguousarray(uv_hi[:, d]).take(box))
        layered |= top - bottom > far              # cells without boxes: -inf
    # The sum of the unit normals points along their mean direction: the sign
    # of each normal's cosine to it needs no normalisation.
    cosine = np.zeros(len(key))
    for d in range(3):
        n = np.ascontiguousarray(normals[:, d]).take(box)
        cosine += n * np.bincount(key, n, cells).take(key)
    layered[key[cosine < 0.0]] = True
    out = np.zeros(len(lo), dtype=bool)
    out[box[layered.take(key)]] = True
    return out


def box_pairs(lo_a: np.ndarray, hi_a: np.ndarray, lo_b: np.ndarray | None = None,
              hi_b: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(ia, ib)`` of overlapping boxes, each pair once, sorted
    by ``ia`` then ``ib``.

    Args:
        lo_a, hi_a: ``(ka, 3)`` box corners, m.  lo_b, hi_b: ``(kb, 3)``; None:
            pairs within the first set, ``ia < ib``.
    """
    same = lo_b is None
    if same:
        lo_b, hi_b = lo_a, hi_a
    if not len(lo_a) or not len(lo_b):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if _kernels.enabled():
        # Compiled: a sweep along x, a few microseconds where the numpy
        # calls below cost a hundred or more.
        return _self_kernels.overlap_pairs(np.ascontiguousarray(lo_a), np.ascontiguousarray(hi_a),
                                           np.ascontiguousarray(lo_b), np.ascontiguousarray(hi_b),
                                           same)
    if len(lo_a) * len(lo_b) <= _ALL_PAIRS:
        # Few boxes (a small layered region): every pair at once costs a
        # dozen numpy calls, the hash over a hundred.
        overlap = np.ones((len(lo_a), len(lo_b)), dtype=bool)
        for d in range(3):
            overlap &= lo_a[:, d, None] <= hi_b[None, :, d]
            overlap &= lo_b[None, :, d] <= hi_a[:, d, None]
        if same:
            overlap = np.triu(overlap, 1)
        ia, ib = np.nonzero(overlap)                  # row-major: by ia, then ib
        return ia.astype(np.int64), ib.astype(np.int64)
    # Cell: the median extent of the larger set's boxes (the triangles, edges),
    # so a typical box covers a few cells and a cell holds a few boxes.
    ext = _extent(lo_a, hi_a) if len(lo_a) >= len(lo_b) else _extent(lo_b, hi_b)
    cell = max(_median(ext), 1e-9)
    origin = np.minimum(_corner(lo_a, False), _corner(lo_b, False))
    top = np.maximum(_corner(hi_a, True), _corner(hi_b, True))
    dims = np.floor((top - origin) / cell).astype(np.int64) + 1
    box_a, key_a = _cells(lo_a, hi_a, cell, origin, dims)
    box_b, key_b = (box_a, key_a) if same else _cells(lo_b, hi_b, cell, origin, dims)
    order = np.argsort(key_a, kind="stable")
    key_sorted, box_sorted = key_a.take(order), box_a.take(order)
    start = np.searchsorted(key_sorted, key_b, side="left")
    n = np.searchsorted(key_sorted, key_b, side="right") - start
    ib, shared = np.repeat(box_b, n), np.repeat(key_b, n)
    ia = box_sorted.take(np.repeat(start - (np.cumsum(n) - n), n) + np.arange(int(n.sum())))
    # A pair is kept in one cell only, the one holding the low corner of the
    # two boxes' intersection (both boxes cover it when they overlap): no
    # sort of all candidates to remove the repeats.  The floors are those of
    # _cells, on the same numbers, so the cell is one the boxes were entered in.
    keep = ia < ib if same else np.ones(len(ia), dtype=bool)
    low = np.zeros(len(ia), dtype=np.int64)
    for d in range(3):
        la, lb = lo_a[:, d].take(ia), lo_b[:, d].take(ib)
        keep &= (la <= hi_b[:, d].take(ib)) & (lb <= hi_a[:, d].take(ia))
        low = low * dims[d] + np.floor((np.maximum(la, lb) - origin[d]) / cell).astype(np.int64)
    keep &= low == shared
    ia, ib = ia[keep], ib[keep]
    order = np.argsort(ia * len(lo_b) + ib)         # by (ia, ib), as documented
    return ia.take(order), ib.take(order)


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
