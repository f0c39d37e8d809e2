"""The broad phase of self-collision: candidate pairs kept in a Verlet list.

:class:`BroadPhase` holds the active triangles and the last candidate search
(the *cache*).  A search is built for boxes padded by at least half the
contact band plus a margin of one thickness and reused while later padded
boxes stay inside them: a cloth at rest on itself pays the search once, not
every step.  A search first asks :func:`~cloth_lod_ros.sim.self_geometry.layered_boxes`
which cells may hold two layers; on a cloth without folds it stops there,
and that one question is all self-collision costs.  So it runs compiled
(:func:`~cloth_lod_ros.sim.self_kernels.broad_boxes`: boxes, normals and
flags in one pass) when the kernels are enabled; the numpy code below is the
reference and the fallback, and both give the same cache bit for bit.

Positions m.
"""

from __future__ import annotations

import numpy as np

from . import kernels as _kernels
from . import self_kernels as _sk
from .self_geometry import box_pairs, edges_of, layered_boxes

__all__ = ["BroadPhase"]


class BroadPhase:
    """Candidate vertex–triangle and edge–edge pairs of one cloth's triangles.

    Args:
        thickness: the self-collision thickness, m (the cache's margin).
        counters: :class:`~cloth_lod_ros.sim.self_contact.SelfCounters`
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
        if _kernels.enabled():
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
        if _kernels.enabled():
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
