"""The broad phase of self-collision: candidate pairs kept in a Verlet list.

:class:`BroadPhase` holds the active triangles and the last candidate search
(the *cache*).  A search is built for boxes padded by at least half the
contact band plus a margin of one thickness and reused while later padded
boxes stay inside them: a cloth at rest on itself pays the search once, not
every step.  A search first asks :func:`~cloth_lod_ros.sim.contact.self_broad.layered_boxes`
which cells may hold two layers; on a cloth without folds it stops there,
and that one question is all self-collision costs.  So it runs compiled
(:func:`~cloth_lod_ros.sim.contact.self_broad_kernels.broad_boxes`: boxes, normals and
flags in one pass) when the kernels are enabled; the numpy code below is the
reference and the fallback, and both give the same cache bit for bit.

The geometry of the search, numpy (the reference), vectorised, with compiled
twins in :mod:`.self_broad_kernels`:

* :func:`layered_boxes` - a hash of the triangles' boxes asking only
  which cells may hold two layers (cloth far apart in the material, or faces
  turned by more than 90° from their cell's mean): on a cloth without folds
  nothing further runs.
* :func:`box_pairs` - a uniform spatial hash: every axis-aligned box is
  entered in each grid cell it covers, boxes sharing a cell are candidates,
  and candidates whose boxes do not overlap are dropped (a few boxes: every
  pair tested at once).  No Python loop over boxes or pairs.

Positions m.
"""

from __future__ import annotations

import numpy as np

from ..runtime import compiled as _compiled
from . import self_broad_kernels as _sk

__all__ = ["BroadPhase", "box_pairs", "layered_boxes", "edges_of"]


class BroadPhase:
    """Candidate vertex–triangle and edge–edge pairs of one cloth's triangles.

    Args:
        thickness: the self-collision thickness, m (the cache's margin).
        counters: :class:`~cloth_lod_ros.sim.contact.self_contact.SelfCounters`
            (``broad`` counts the searches built).
    """

    def __init__(self, thickness: float, counters):
        self.thickness = thickness
        self.counters = counters
        self.cache = None
        self.triangles = np.zeros((0, 3), np.int64)
        self._uv = np.zeros((0, 2))
        self._edges = np.zeros((0, 2), np.int64)
        self._corner_columns = None
        self._uv_boxes = None

    def set_topology(self, triangles: np.ndarray, uv: np.ndarray) -> None:
        """Use triangles ``(t, 3)`` (compact vertex indices) with the particles'
        rest coordinates ``uv`` ``(n, 2)`` (m) and drop the cache.  Edges,
        corner columns and material boxes are derived when first needed: with
        the level of detail the topology changes many times between two
        searches that use them, and the compiled search needs none of them."""
        self.triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        self._uv = np.array(uv, dtype=np.float64, order="C")     # (a copy, as the boxes were)
        self._edges = self._corner_columns = self._uv_boxes = None
        self.cache = None

    @property
    def edges(self) -> np.ndarray:
        """``(e, 2)`` the mesh's edges (sorted vertex pairs)."""
        if self._edges is None:
            self._edges = edges_of(self.triangles)
        return self._edges

    @property
    def _corners(self):
        # Each corner's column on its own: gathers of (t,) index arrays and
        # element-wise minima instead of reductions along a (t, 3) axis,
        # several times slower in numpy.
        if self._corner_columns is None:
            self._corner_columns = tuple(np.ascontiguousarray(self.triangles[:, k])
                                         for k in range(3))
        return self._corner_columns

    @property
    def uv_boxes(self):
        """``(t, 2)`` material boxes of the triangles, low and high corners
        (stored by columns, Fortran order: the hash reads u and v apart)."""
        if self._uv_boxes is None:
            self._uv_boxes = tuple(np.asfortranarray(b)
                                   for b in self._triangle_boxes(self._uv, self._uv))
        return self._uv_boxes

    def _triangle_boxes(self, lo: np.ndarray, hi: np.ndarray):
        """``(t, k)`` bounds of each triangle's corners' boxes ``lo``/``hi`` ``(n, k)``."""
        t0, t1, t2 = self._corners
        return (np.minimum(np.minimum(lo.take(t0, 0), lo.take(t1, 0)), lo.take(t2, 0)),
                np.maximum(np.maximum(hi.take(t0, 0), hi.take(t1, 0)), hi.take(t2, 0)))

    def _normals(self, x: np.ndarray) -> np.ndarray:
        """``(t, 3)`` unit normals of the triangles at ``x`` (m)."""
        t0, t1, t2 = self._corners
        a = x.take(t0, 0)
        e, f = x.take(t1, 0) - a, x.take(t2, 0) - a
        # The cross product column by column, stored by columns (Fortran
        # order): the hash reads the components apart.
        n = np.empty(a.shape, order="F")
        n[:, 0] = e[:, 1] * f[:, 2] - e[:, 2] * f[:, 1]
        n[:, 1] = e[:, 2] * f[:, 0] - e[:, 0] * f[:, 2]
        n[:, 2] = e[:, 0] * f[:, 1] - e[:, 1] * f[:, 0]
        norm = np.sqrt(n[:, 0] * n[:, 0] + n[:, 1] * n[:, 1] + n[:, 2] * n[:, 2])
        n /= np.maximum(norm, 1e-300)[:, None]
        return n

    @staticmethod
    def _ee_candidates(edges, lo_e, hi_e):
        i, j = box_pairs(lo_e, hi_e)
        e1, e2 = edges.take(i, 0), edges.take(j, 0)
        keep = ((e1[:, 0] != e2[:, 0]) & (e1[:, 0] != e2[:, 1])
                & (e1[:, 1] != e2[:, 0]) & (e1[:, 1] != e2[:, 1]))       # no shared end
        return e1[keep], e2[keep]

    def _boxes(self, x: np.ndarray, y: np.ndarray, pad: float):
        """Padded vertex boxes ``(n, 3)``, triangle boxes ``(t, 3)`` and the
        layered flags ``(t,)`` of a new search (compiled when enabled)."""
        if _compiled.enabled():
            # (Contiguous arrays: the kernels are compiled, and warmed up, for those.)
            lo, hi, lo_t, hi_t, normals, layered, status = _sk.broad_boxes(
                np.ascontiguousarray(x), np.ascontiguousarray(y), pad, self.triangles, self._uv)
            if status == _sk.DONE:
                return lo, hi, lo_t, hi_t, layered
            if status == _sk.SPARSE:        # the hash over a sparse grid: numpy's
                return lo, hi, lo_t, hi_t, layered_boxes(
                    lo_t, hi_t, *self.uv_boxes, 0.5 * float((hi - lo).max(initial=0.0)),
                    normals)
        lo, hi = np.minimum(x, y) - pad, np.maximum(x, y) + pad
        lo_t, hi_t = self._triangle_boxes(lo, hi)
        return lo, hi, lo_t, hi_t, layered_boxes(
            lo_t, hi_t, *self.uv_boxes, 0.5 * float((hi - lo).max(initial=0.0)),
            self._normals(x))

    def _valid(self, x: np.ndarray, y: np.ndarray, need: float) -> bool:
        """Whether the cache holds every box from ``min(x, y) − need`` to
        ``max(x, y) + need``."""
        c = self.cache
        if c is None or len(c["lo"]) != len(x):
            return False
        if _compiled.enabled():
            return not _sk.outside(np.ascontiguousarray(x), np.ascontiguousarray(y), need,
                                   c["lo"], c["hi"])
        return (not np.any(np.minimum(x, y) - need < c["lo"])
                and not np.any(np.maximum(x, y) + need > c["hi"]))

    def query(self, x: np.ndarray, y: np.ndarray, need: float) -> dict:
        """Candidate pairs whose vertex boxes, spanning ``x`` to ``y`` ``(n, 3)``
        (m) and padded by ``need`` m, may overlap; the normals are taken at
        ``x``.  Returns the cache: ``lo``/``hi`` ``(n, 3)`` its padded boxes,
        ``verts`` ``(k,)`` and ``tris`` ``(k, 3)`` vertex–triangle candidates,
        ``e1``/``e2`` ``(m, 2)`` edge–edge ones, ``layered`` whether any cell
        may hold two layers, ``narrow`` the caller's narrow phase (None)."""
        if self._valid(x, y, need):
            return self.cache
        thickness = self.thickness
        pad = max(need, thickness) + thickness
        lo, hi, lo_t, hi_t, layered = self._boxes(x, y, pad)
        t = self.triangles
        empty = np.zeros(0, np.int64)
        c = dict(lo=lo, hi=hi, verts=empty, tris=np.zeros((0, 3), np.int64),
                 e1=np.zeros((0, 2), np.int64), e2=np.zeros((0, 2), np.int64), narrow=None,
                 layered=False)
        self.cache = c
        self.counters.broad += 1
        if not layered.any():
            return c
        c["layered"] = True
        # The pair search covers the flagged triangles, their corners and
        # the edges between those corners.
        tri_ids = np.flatnonzero(layered)
        active = np.zeros(len(lo), bool)
        active[t.take(tri_ids, 0).ravel()] = True
        vert_ids = np.flatnonzero(active)
        it, iv = box_pairs(lo_t.take(tri_ids, 0), hi_t.take(tri_ids, 0),
                           lo.take(vert_ids, 0), hi.take(vert_ids, 0))
        verts, tris = vert_ids.take(iv), t.take(tri_ids.take(it), 0)
        keep = (tris[:, 0] != verts) & (tris[:, 1] != verts) & (tris[:, 2] != verts)
        edges = self.edges
        e = edges[active.take(edges[:, 0]) & active.take(edges[:, 1])]
        p, q = e[:, 0], e[:, 1]
        e1, e2 = self._ee_candidates(e, np.minimum(lo.take(p, 0), lo.take(q, 0)),
                                     np.maximum(hi.take(p, 0), hi.take(q, 0)))
        c.update(verts=verts[keep], tris=tris[keep], e1=e1, e2=e2)
        return c


#: Up to this many candidate pairs, :func:`box_pairs` tests them all directly.
_ALL_PAIRS = 1 << 15

#: A box covering more grid cells than this is not entered cell by cell.  On a
#: cloth's mesh the cell is about a triangle's size and boxes differ by the
#: levels of detail (a factor 2 in extent per two levels), so a box 16 times
#: the median is still hashed (16 x 16 x 2 = 512 cells); only motion far
#: beyond any physical step (a step that will be refused) reaches the limit,
#: whose cell count would otherwise grow without bound.
_MAX_BOX_CELLS = 4096


#: Directions along which :func:`layered_boxes` measures the spread of a
#: cell's normals (:data:`~cloth_lod_ros.sim.contact.self_broad_kernels.SPREAD_DIRECTIONS`).
SPREAD_DIRECTIONS = _sk.SPREAD_DIRECTIONS
_SPREAD = _sk.SPREAD


def _oversized(lo: np.ndarray, hi: np.ndarray, cell: float) -> np.ndarray:
    """``(k,)`` whether each box ``lo``/``hi`` ``(k, 3)`` (m) covers more than
    :data:`_MAX_BOX_CELLS` cells of side ``cell`` (m), or is not finite.  The
    count is taken in floating point: an integer one of huge boxes wraps."""
    count = np.ones(len(lo))
    for d in range(3):
        count *= np.floor(hi[:, d] / cell) - np.floor(lo[:, d] / cell) + 1.0
    return ~(count <= _MAX_BOX_CELLS)               # (NaN counts are oversized)


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
      their mean direction; or
    * two of its normals are more than 90° apart as seen along one of the 13
      directions of :data:`SPREAD_DIRECTIONS`: their projections on it span
      more than √2 = |n₁ − n₂| at 90°.  Those directions cover the sphere
      to 27.6°, so two normals more than 106° apart always flag their cell,
      and two within 90° never do.

    The two sides of a fold face opposite ways where they come within the
    padding of each other, so a cell holding both is flagged however tight
    the fold.  The mean alone is not enough: a pleat standing up from a
    sheet (its walls facing ±y and both leaning a little towards the sheet's
    +z) has every normal within 90° of the cell's mean, and its walls closed
    on each other unseen (``drop_on_sphere`` at level 5, issue 31: two
    particles 7 mm apart, 2 × 6.25 cm apart in the cloth, reached 0.08 mm
    in two steps, after which every step needed re-solves, halvings and a
    stopped zone).

    A cloth without folds flags nothing and pays this one hash; with them,
    only the flagged boxes go on to the pair search.  The per-cell maxima,
    minima and sums are scattered into arrays over the cells (``ufunc.at``,
    ``bincount``) rather than grouped by sorting the keys, which cost more
    than all the rest.
    """
    if not len(lo):
        return np.zeros(0, dtype=bool)
    cell = 1.5 * max(_median(_extent(lo, hi)), 1e-9)
    if _oversized(lo, hi, cell).any():
        # A box too large to enter cell by cell may reach any other: every box
        # is flagged and the pair search (a sweep, bounded by the pairs it
        # finds) decides.  Only motion no step keeps gets here.
        return np.ones(len(lo), dtype=bool)
    origin, top = _corner(lo, False), _corner(hi, True)
    dims = np.floor((top - origin) / cell).astype(np.int64) + 1
    far = 2.0 * (np.sqrt(3.0) * cell + 2.0 * pad)
    finite = np.isfinite(far) and np.all(np.isfinite(origin)) and np.all(np.isfinite(top))
    # (The cell count in floating point: an int64 product of huge dims wraps.)
    if _compiled.enabled() and finite and dims.prod(dtype=float) <= 8 * len(lo) + 4096:
        # Compiled, on the dense grid (a cloth's bounding box): ~10x faster.
        # (Only for finite boxes: the kernel indexes cells without checks.)
        out = np.zeros(len(lo), dtype=bool)
        _sk.layered_cells(np.ascontiguousarray(lo), np.ascontiguousarray(hi),
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
    n0, n1, n2 = (np.ascontiguousarray(normals[:, d]) for d in range(3))
    for d0, d1, d2 in SPREAD_DIRECTIONS:
        # (The products and sums in the kernel's order: the same flags.)
        along = (n0 * d0 + n1 * d1 + n2 * d2).take(box)
        top = np.full(cells, -np.inf)
        np.maximum.at(top, key, along)
        bottom = np.full(cells, np.inf)
        np.minimum.at(bottom, key, along)
        layered |= top - bottom > _SPREAD
    out = np.zeros(len(lo), dtype=bool)
    out[box[layered.take(key)]] = True
    return out


def _every_pair(lo_a, hi_a, lo_b, hi_b, same: bool):
    """:func:`box_pairs` by testing every pair, in blocks of rows of at most
    :data:`_ALL_PAIRS` pairs (the memory stays bounded)."""
    rows = max(1, _ALL_PAIRS // max(len(lo_b), 1))
    found_a, found_b = [], []
    for first in range(0, len(lo_a), rows):
        a = slice(first, first + rows)
        overlap = np.ones((len(lo_a[a]), len(lo_b)), dtype=bool)
        for d in range(3):
            overlap &= lo_a[a, d, None] <= hi_b[None, :, d]
            overlap &= lo_b[None, :, d] <= hi_a[a, d, None]
        if same:
            overlap = np.triu(overlap, 1 + first)
        ia, ib = np.nonzero(overlap)                  # row-major: by ia, then ib
        found_a.append(ia.astype(np.int64) + first)
        found_b.append(ib.astype(np.int64))
    return np.concatenate(found_a), np.concatenate(found_b)


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
    if _compiled.enabled():
        # Compiled: a sweep along x, a few microseconds where the numpy
        # calls below cost a hundred or more.
        return _sk.overlap_pairs(np.ascontiguousarray(lo_a), np.ascontiguousarray(hi_a),
                                 np.ascontiguousarray(lo_b), np.ascontiguousarray(hi_b),
                                 same)
    if len(lo_a) * len(lo_b) <= _ALL_PAIRS:
        # Few boxes (a small layered region): every pair at once costs a
        # dozen numpy calls, the hash over a hundred.
        return _every_pair(lo_a, hi_a, lo_b, hi_b, same)
    # Cell: the median extent of the larger set's boxes (the triangles, edges),
    # so a typical box covers a few cells and a cell holds a few boxes.
    ext = _extent(lo_a, hi_a) if len(lo_a) >= len(lo_b) else _extent(lo_b, hi_b)
    cell = max(_median(ext), 1e-9)
    if _oversized(lo_a, hi_a, cell).any() or _oversized(lo_b, hi_b, cell).any():
        # Boxes too large to hash (motion no step keeps): pair by pair, in
        # blocks of rows, costing the product of the counts and no more.
        return _every_pair(lo_a, hi_a, lo_b, hi_b, same)
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
