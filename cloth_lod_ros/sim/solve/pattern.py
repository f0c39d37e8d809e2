"""The 3 × 3-block sparsity pattern of the system matrix, and the assembly into it.

One step solves ``(M − h ∂f/∂v − h² ∂f/∂x) Δv = h (f + h ∂f/∂x v)`` (BW eq. 15)
for the velocity change ``Δv`` (:mod:`.pcg`, :mod:`.backends`).  Assembly is
vectorised: the block sparsity pattern and the slot of every element
entry are computed once per topology (:class:`SparsePattern`) and each step only
sums values into the fixed slots with ``np.bincount`` (compiled:
:mod:`.pattern_kernels`, which also builds the pattern from the mesh's edges).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..runtime import compiled as _compiled
from . import pattern_kernels as _patterns


__all__ = ["SparsePattern", "PatternStorage"]


class SparsePattern:
    """Fixed 3×3-block (BSR) pattern of the 3n×3n system matrix for one topology.

    The pattern is built over *vertex pairs* (one ``np.unique`` on a few keys per
    element) and every scalar entry's slot in the BSR data array is computed by
    arithmetic, so rebuilding after a topology change is cheap.

    Args:
        vertex_count: n.
        element_vertices: list of ``(e, k)`` integer arrays (triangles k=3,
            hinges k=4); each element couples all pairs of its vertices.
        storage: a :class:`PatternStorage` that successive patterns share
            (None: fresh arrays for this one).
        edges, hinge_triangles: with ``element_vertices`` a mesh's
            ``[triangles, hinge_vertices]``, its edge structure and each
            hinge's two triangles (:class:`~cloth_lod_ros.sim.physics.elements.Elements`'
            ``edges``, ``hinge_triangles``): the compiled build then works from
            the edges (the same pattern, in 0.6x the time; pattern_kernels).
    """

    def __init__(self, vertex_count: int, element_vertices: list[np.ndarray],
                 storage: "PatternStorage | None" = None, edges: tuple | None = None,
                 hinge_triangles: np.ndarray | None = None):
        self.vertex_count = n = int(vertex_count)
        element_vertices = [np.asarray(v, dtype=np.int64) for v in element_vertices]
        self.shape = (3 * n, 3 * n)
        self._element_shapes = [v.shape for v in element_vertices]
        self._block_slots = None
        self._entry_slots = None
        self._retired = False
        pairs = sum(v.shape[0] * v.shape[1] ** 2 for v in element_vertices)
        # Compiled when numba is there: one slot per vertex pair (the block
        # slots the compiled assembly adds through), bitwise the reference's,
        # without the key tables and dozens of small numpy passes
        # (pattern_kernels.py); the 9x larger entry slots only if asked for.
        # Its storage is best reused (PatternStorage).
        self._owned = (storage.take_slots(pairs) if storage is not None
                       else np.empty(pairs, dtype=np.int64))
        built = _patterns.sparse_pattern(n, element_vertices, self._owned, storage, edges,
                                         hinge_triangles)
        if built is not None:
            self.indices, self.indptr, self.diagonal_block = built
            self.block_count = len(self.indices)
            return
        if storage is not None:
            storage.spare_slots = self._owned if self._owned.base is None else self._owned.base
        size = 9 * pairs
        self._owned = self._entry_slots = (storage.take_slots(size) if storage is not None
                                           else np.empty(size, dtype=np.int64))
        keys = []
        for v in element_vertices:
            # Key i·n + j of every vertex pair (i, j) of every element, in
            # (e, i, j) order; gathers along whole rows (see the slots below).
            i, j = np.indices((v.shape[1], v.shape[1])).reshape(2, -1)
            keys.append((np.take(v, i, axis=1, mode="clip") * n
                         + np.take(v, j, axis=1, mode="clip")).ravel())
        # Every vertex's own block is present (mass and drag live there).
        keys.append(np.arange(n, dtype=np.int64) * (n + 1))
        rank = storage.rank_table(n * n) if storage is not None and n * n <= _DENSE_KEYS else None
        unique_keys, block_of = _unique_with_inverse(np.concatenate(keys), n * n, rank)
        self.block_count = len(unique_keys)
        self.indices = (unique_keys % n).astype(np.int32)
        self.indptr = np.searchsorted(unique_keys // n, np.arange(n + 1)).astype(np.int32)
        # Entry (e, i, a, j, b) lives at data[block(e,i,j), a, b]: written in
        # place, one pass per element kind (this array is the largest thing a
        # topology change builds).  A gather of whole element rows through a
        # (i, a, j, b) -> (i, j) template, then one add of 3a + b: broadcasting
        # over the 3 × 3 axes directly makes numpy loop over length-3 rows
        # (~4x slower; it was most of a topology change's pattern cost).
        offset = written = 0
        for v in element_vertices:
            e, k = v.shape
            i, a, j, b = np.indices((k, 3, k, 3)).reshape(4, -1)
            block = 9 * block_of[offset:offset + e * k * k].reshape(e, k * k)
            out = self._entry_slots[written:written + 9 * e * k * k].reshape(e, 9 * k * k)
            np.take(block, i * k + j, axis=1, out=out, mode="clip")   # indices < k²
            out += 3 * a + b
            offset += e * k * k
            written += 9 * e * k * k
        self.diagonal_block = block_of[offset:]

    def assemble(self, element_blocks: list[np.ndarray],
                 diagonal: np.ndarray) -> sp.bsr_matrix:
        """Sum element blocks and a per-vertex diagonal into the fixed pattern.

        Args:
            element_blocks: arrays ``(e, k, 3, k, 3)`` (entry ``[e, i, a, j, b]``
                at row ``3·v_i + a``, column ``3·v_j + b``), in the order given at
                construction.
            diagonal: ``(n,)`` scalar added as ``diagonal[i] * I₃`` to each vertex
                block (mass plus drag terms).
        """
        slots = self._all_slots
        if _compiled.enabled():
            # The compiled scatter: the same sums in the same order, without
            # the concatenated copy of all blocks (pattern_kernels.py).
            data = np.zeros(9 * self.block_count)
            offset = 0
            for blocks in element_blocks:
                flat = np.ascontiguousarray(blocks, dtype=np.float64).reshape(-1)
                _patterns._scatter_slots(slots, offset, flat, data)
                offset += flat.size
            return self.finish(data.reshape(-1, 3, 3), diagonal)
        values = np.concatenate([b.ravel() for b in element_blocks])
        data = np.bincount(slots, weights=values,
                           minlength=9 * self.block_count).reshape(-1, 3, 3)
        return self.finish(data, diagonal)

    def finish(self, data: np.ndarray, diagonal: np.ndarray) -> sp.bsr_matrix:
        """The matrix of summed element entries ``data`` ``(blocks, 3, 3)`` (this
        pattern's layout; modified in place) plus ``diagonal[i] * I₃`` ``(n,)``."""
        if _compiled.enabled():
            _patterns._add_diagonal(self.diagonal_block, np.ascontiguousarray(diagonal,
                                    dtype=np.float64), data.reshape(-1))
        else:
            data[self.diagonal_block] += diagonal[:, None, None] * np.eye(3)
        return sp.bsr_matrix((data, self.indices, self.indptr), shape=self.shape)

    @property
    def block_slots(self) -> list[np.ndarray]:
        """Per element kind, ``(e, k, k)`` int64: the flat BSR data index of entry
        ``(a, b) = (0, 0)`` of each vertex pair's block (entry ``(a, b)`` is 3a + b
        further).  What compiled kernels add their blocks through: 1/9 of the
        slots to read (the compiled build writes only these; the numpy one
        writes the entry slots, and these are derived from them, cached)."""
        if self._retired:
            raise RuntimeError("this sparsity pattern was retired")
        if self._block_slots is None:
            out, offset = [], 0
            if self._entry_slots is None:           # the compiled build: pair slots
                for e, k in self._element_shapes:
                    out.append(self._owned[offset:offset + e * k * k].reshape(e, k, k))
                    offset += e * k * k
            else:
                for e, k in self._element_shapes:
                    entries = self._entry_slots[offset:offset + 9 * e * k * k]
                    out.append(np.ascontiguousarray(
                        entries.reshape(e, k, 3, k, 3)[:, :, 0, :, 0]))
                    offset += 9 * e * k * k
            self._block_slots = out
        return self._block_slots

    @property
    def _all_slots(self) -> np.ndarray:
        """``(9 Σ e k²,)`` int64: the flat BSR data index of every scalar entry
        ``(e, i, a, j, b)`` of every element, in that order (what the numpy
        assembly sums through); derived from the block slots when the compiled
        build made those only (cached)."""
        if self._retired:
            raise RuntimeError("this sparsity pattern was retired")
        if self._entry_slots is None:
            parts = [(slots[:, :, None, :, None] + (3 * np.arange(3))[:, None, None]
                      + np.arange(3)).ravel() for slots in self.block_slots]
            self._entry_slots = np.concatenate(parts) if parts else np.zeros(0, np.int64)
        return self._entry_slots

    def retire(self, storage: "PatternStorage") -> None:
        """Give this pattern's slot array to ``storage`` for a successor; this
        pattern can no longer :meth:`assemble`."""
        if self._retired:
            raise RuntimeError("this sparsity pattern was retired already")
        slots, self._owned, self._retired = self._owned, None, True
        self._block_slots = self._entry_slots = None
        storage.spare_slots = slots if slots.base is None else slots.base

    @property
    def block_rows(self) -> np.ndarray:
        """``(blocks,)`` the vertex row of every stored block (cached)."""
        if getattr(self, "_block_rows", None) is None:
            self._block_rows = np.repeat(np.arange(self.vertex_count), np.diff(self.indptr))
        return self._block_rows

    def diagonal_blocks(self, matrix: sp.bsr_matrix) -> np.ndarray:
        """The ``(n, 3, 3)`` vertex diagonal blocks of an assembled matrix."""
        return matrix.data[self.diagonal_block]


#: Largest key range for which :func:`_unique_with_inverse` uses a dense table
#: (4 bytes per possible key: 16 MB at most, i.e. up to ~2,000 particles).
_DENSE_KEYS = 1 << 22


def _unique_with_inverse(keys: np.ndarray, key_range: int,
                         rank: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(keys, return_inverse=True)`` for keys in ``[0, key_range)``.

    Adaptive meshes rebuild their pattern at most topology changes; for their
    sizes a table indexed by key avoids the sort (the same result, ~4x faster).
    ``rank``: scratch int64 table of at least ``key_range`` entries to use
    (its contents do not matter), else a new one.
    """
    if key_range > _DENSE_KEYS:
        return np.unique(keys, return_inverse=True)
    present = np.zeros(key_range, dtype=bool)
    present[keys] = True
    unique_keys = np.flatnonzero(present)
    if rank is None:
        rank = np.empty(key_range, dtype=np.int64)
    rank[unique_keys] = np.arange(len(unique_keys))
    return unique_keys, rank[keys]


class PatternStorage:
    """Arrays that the successive sparsity patterns of one solver reuse.

    An adaptive mesh builds a pattern at most topology changes.  Its two large
    arrays, the slots (block slots, ~170 kB at 400 particles, from the
    compiled build; entry slots, 9x that, from the numpy one) and the key-rank
    scratch table (8 bytes per possible vertex pair), were fresh allocations
    each time: in a running simulation fresh pages of that size cost a page
    fault each on first write, about a third of a pattern build.  The slots
    belong to one pattern until it is retired (:meth:`SparsePattern.retire`);
    the rank table is scratch during a build only.  New arrays get 25 %
    headroom, as a refining mesh grows a little per change.
    """

    def __init__(self):
        self.spare_slots: np.ndarray | None = None
        self._rank = np.zeros(0, dtype=np.int64)

    def take_slots(self, size: int) -> np.ndarray:
        """A 1-D int64 array of ``size`` for a new pattern's slots (owned by it)."""
        spare, self.spare_slots = self.spare_slots, None
        if spare is None or len(spare) < size:
            spare = np.empty(size + size // 4, dtype=np.int64)
        return spare[:size]

    def rank_table(self, size: int) -> np.ndarray:
        """Scratch int64 array of ``size`` entries (contents undefined)."""
        if len(self._rank) < size:
            self._rank = np.empty(size + size // 4, dtype=np.int64)
        return self._rank[:size]
