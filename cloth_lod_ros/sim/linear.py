"""Linearised backward Euler with the filtered (modified) PCG (BW §5–§5.3).

One step solves ``(M − h ∂f/∂v − h² ∂f/∂x) Δv = h (f + h ∂f/∂x v)`` (BW eq. 15)
for the velocity change ``Δv``.  Constraints are per particle: a projector
``S_i`` (identity = free, 0 = fully held) and a prescribed velocity change
``z_i`` in the held directions.  The modified PCG of BW §5.3 keeps every
iterate inside the constraint set by filtering with ``S``; the start value is
``Δv₀ = S y + (I − S) z`` (Ascher & Boxerman's correction, so held directions
take exactly ``z`` while ``y`` — the previous solution — warm-starts the rest).

Assembly is vectorised: the block sparsity pattern and the slot of every element
entry are computed once per topology (:class:`SparsePattern`) and each step only
sums values into the fixed slots with ``np.bincount``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import kernels as _kernels
from . import projection_kernels as _projection
from . import pattern_kernels as _patterns

try:        # the compiled kernel behind scipy's CSR products (see CsrOperator)
    from scipy.sparse._sparsetools import bsr_matvec as _bsr_matvec
    from scipy.sparse._sparsetools import csr_matvec as _csr_matvec
except ImportError:             # pragma: no cover - a scipy without it
    _bsr_matvec = _csr_matvec = None

__all__ = ["CsrOperator", "SparsePattern", "PatternStorage", "Constraints", "SolveResult",
           "filtered_pcg", "project_system", "projected_data", "projected_rhs", "bsr_product",
           "relative_residual", "solve_projected_direct", "block_diagonal_matrix"]


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
            hinge's two triangles (:class:`~cloth_lod_ros.sim.forces.Elements`'
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
        # (topology_kernels.py); the 9x larger entry slots only if asked for.
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
        if _kernels.enabled():
            # The compiled scatter: the same sums in the same order, without
            # the concatenated copy of all blocks (kernels.py).
            data = np.zeros(9 * self.block_count)
            offset = 0
            for blocks in element_blocks:
                flat = np.ascontiguousarray(blocks, dtype=np.float64).reshape(-1)
                _kernels._scatter_slots(slots, offset, flat, data)
                offset += flat.size
            return self.finish(data.reshape(-1, 3, 3), diagonal)
        values = np.concatenate([b.ravel() for b in element_blocks])
        data = np.bincount(slots, weights=values,
                           minlength=9 * self.block_count).reshape(-1, 3, 3)
        return self.finish(data, diagonal)

    def finish(self, data: np.ndarray, diagonal: np.ndarray) -> sp.bsr_matrix:
        """The matrix of summed element entries ``data`` ``(blocks, 3, 3)`` (this
        pattern's layout; modified in place) plus ``diagonal[i] * I₃`` ``(n,)``."""
        if _kernels.enabled():
            _kernels._add_diagonal(self.diagonal_block, np.ascontiguousarray(diagonal,
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


@dataclass
class Constraints:
    """Per-particle velocity constraints for the filtered solve (BW §5.3).

    Attributes:
        indices: ``(k,)`` constrained particle indices.
        projectors: ``(k, 3, 3)`` filters ``S_i`` (0 = fully held, ``I − nnᵀ`` =
            held along n only).
        prescribed: ``(k, 3)`` prescribed velocity change ``z_i`` (m/s); only
            its ``(I − S_i)`` part is used.
    """

    indices: np.ndarray
    projectors: np.ndarray
    prescribed: np.ndarray

    @classmethod
    def none(cls) -> "Constraints":
        return cls(np.zeros(0, dtype=np.int64), np.zeros((0, 3, 3)), np.zeros((0, 3)))

    def filter(self, r: np.ndarray) -> np.ndarray:
        """Apply S to an ``(n, 3)`` vector (returns a new array)."""
        out = r.copy()
        if len(self.indices):
            out[self.indices] = np.einsum("kab,kb->ka", self.projectors, r[self.indices])
        return out

    def start(self, guess: np.ndarray) -> np.ndarray:
        """``S y + (I − S) z``: the corrected initial value."""
        out = self.filter(guess)
        if len(self.indices):
            held = self.prescribed - np.einsum("kab,kb->ka", self.projectors,
                                               self.prescribed)
            out[self.indices] += held
        return out


@dataclass
class SolveResult:
    """Outcome of one linear solve.

    Attributes:
        dv: ``(n, 3)`` velocity change, m/s.
        iterations: CG iterations (0 for the direct solver).
        residual: ``|S(b − A Δv)| / |S b|`` (2-norm; 0 if ``S b`` = 0).
        converged: whether ``residual`` met the tolerance.
    """

    dv: np.ndarray
    iterations: int
    residual: float
    converged: bool


def filtered_pcg(matrix, rhs: np.ndarray, constraints: Constraints,
                 block_diagonal: np.ndarray, guess: np.ndarray | None = None,
                 tolerance: float = 1e-4, max_iterations: int = 2000,
                 preconditioner=None, filtered_matrix=None) -> SolveResult:
    """Modified PCG of BW §5.3 with block-Jacobi preconditioning.

    Iterates only in the filtered subspace: with ``c = S c`` for every search
    direction, ``S A c = (S A S) c``, so the filtered matrix ``S A S`` and the
    filtered preconditioner ``S P⁻¹ S`` (``P`` = the 3×3 diagonal blocks) are
    formed once per solve and each iteration is two sparse products.

    Stops when ``rᵀ P⁻¹ r ≤ tol² (S b)ᵀ P⁻¹ (S b)`` (BW's test) *and* the plain
    residual ``|S(b − A Δv)| / |S b| ≤ tol``; ``converged`` reports the latter,
    recomputed from scratch at the end (no recurrence drift).

    Args:
        matrix: SPD ``3n × 3n`` system matrix (BSR with 3×3 blocks, or any
            scipy sparse matrix).
        rhs: ``(n, 3)`` right-hand side.
        constraints: filters and prescribed changes.
        block_diagonal: ``(n, 3, 3)`` diagonal blocks of ``matrix``.
        guess: ``(n, 3)`` warm start for the free directions (defaults to 0).
        preconditioner: instead of block-Jacobi, a callable ``r (3n,) -> z (3n,)``
            approximating the inverse of the filtered system (a multigrid
            V-cycle); it is applied as ``S M⁻¹ S``.
        filtered_matrix: ``S A S`` if the caller has it (any matrix equal to it
            on the free subspace, e.g. :func:`project_system`'s).
    """
    n = rhs.shape[0]
    projectors = None
    if len(constraints.indices) and (filtered_matrix is None or preconditioner is None):
        projectors = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        projectors[constraints.indices] = constraints.projectors
    # CSR products are ~1.5x faster than BSR here, and CsrOperator skips scipy's dispatch.
    if isinstance(filtered_matrix, CsrOperator) or (
            filtered_matrix is not None and not sp.issparse(filtered_matrix)):
        filtered = filtered_matrix          # an operator already (a compiled block product)
    elif filtered_matrix is not None:
        filtered = CsrOperator(filtered_matrix)
    elif projectors is not None:
        filtered = CsrOperator(_filter_matrix(matrix, projectors, constraints))
    else:
        filtered = CsrOperator(matrix)
    if preconditioner is None:
        inverse_blocks = np.linalg.inv(block_diagonal)
        if projectors is not None:
            inverse_blocks = projectors @ inverse_blocks @ projectors
        precond = CsrOperator(block_diagonal_matrix(inverse_blocks)).__matmul__
    elif not len(constraints.indices):
        precond = preconditioner
    else:
        # S M⁻¹ S with S applied to the constrained particles only (a copy
        # elsewhere): most particles are free.
        def precond(r):
            filtered_r = constraints.filter(r.reshape(n, 3)).ravel()
            return constraints.filter(preconditioner(filtered_r).reshape(n, 3)).ravel()

    dv = constraints.start(np.zeros_like(rhs) if guess is None else guess).ravel()
    filtered_rhs = constraints.filter(rhs).ravel()
    rhs_norm = float(np.linalg.norm(filtered_rhs))
    delta0 = float(filtered_rhs @ precond(filtered_rhs))
    residual = constraints.filter(rhs - bsr_product(matrix, dv.reshape(n, 3))).ravel()
    direction = precond(residual)
    delta = float(residual @ direction)
    threshold = tolerance**2 * delta0
    plain_threshold = (tolerance * rhs_norm)**2
    iterations = 0
    while iterations < max_iterations:
        if delta <= threshold and float(residual @ residual) <= plain_threshold:
            break
        q = filtered @ direction
        curvature = float(direction @ q)
        if curvature <= 0.0:      # exact solution reached (or matrix not SPD)
            break
        alpha = delta / curvature
        dv += alpha * direction
        residual -= alpha * q
        s = precond(residual)
        delta_old, delta = delta, float(residual @ s)
        if not delta > 0.0:       # a preconditioner that is not positive definite here
            break
        direction = s + (delta / delta_old) * direction
        iterations += 1
    dv = dv.reshape(n, 3)
    true_residual = constraints.filter(rhs - bsr_product(matrix, dv))
    rel = float(np.linalg.norm(true_residual)) / rhs_norm if rhs_norm > 0 else 0.0
    return SolveResult(dv=dv, iterations=iterations, residual=rel,
                       converged=rel <= tolerance)


def _filter_matrix(matrix, projectors: np.ndarray,
                   constraints: Constraints) -> sp.bsr_matrix:
    """``S A S`` for block-diagonal ``S`` given as ``(n, 3, 3)`` projectors."""
    bsr = matrix if sp.isspmatrix_bsr(matrix) and matrix.blocksize == (3, 3) \
        else sp.bsr_matrix(matrix, blocksize=(3, 3))
    rows = np.repeat(np.arange(len(projectors)), np.diff(bsr.indptr))
    data = np.matmul(np.matmul(projectors[rows], bsr.data), projectors[bsr.indices])
    return sp.bsr_matrix((data, bsr.indices, bsr.indptr), shape=bsr.shape)


def project_system(matrix: sp.bsr_matrix, rhs: np.ndarray, constraints: Constraints,
                   pattern: SparsePattern | None = None):
    """The projected system ``Â y = b̂`` of a filtered step, on the topology's pattern.

    ``Â = S A S + (I − S) D (I − S)`` (D: the 3 × 3 diagonal blocks of A) is SPD,
    equals ``S A S`` on the free subspace and has A's scale in the held
    directions; ``b̂ = S (b − A z)``.  Then ``Δv = z + S y`` solves the filtered
    problem.  Only blocks in a constrained row or column change, so ``Â`` keeps
    A's sparsity pattern (explicit zeros included): a factorisation's symbolic
    analysis stays valid for the whole topology.

    A fully held particle (``S_i = 0``: pins, sticking contacts, most of the
    constraints) zeroes its row and column and keeps its diagonal block, so
    only blocks between partly held particles (sliding contacts) and their
    neighbours need the 3 × 3 products (BW §5.3).

    Args:
        matrix: A, BSR with 3 × 3 blocks (every diagonal block stored).
        rhs: ``(n, 3)`` b.  constraints: S and z.
        pattern: A's :class:`SparsePattern` if the caller has it (saves
            finding the block rows and diagonal blocks again).

    Returns:
        ``(Â as BSR, b̂ (n, 3), z (n, 3))``.
    """
    data, b, z = projected_data(matrix, rhs, constraints, pattern)
    projected = sp.bsr_matrix((data, matrix.indices, matrix.indptr), shape=matrix.shape)
    return projected, b, z


def projected_data(matrix: sp.bsr_matrix, rhs: np.ndarray, constraints: Constraints,
                   pattern: SparsePattern | None = None, out: np.ndarray | None = None):
    """:func:`project_system` without building the BSR matrix: ``(Â's data
    (blocks, 3, 3) on A's pattern, b̂ (n, 3), z (n, 3))``.  Compiled where
    numba is (:mod:`.projection_kernels`, writing ``Â`` into ``out`` if it has
    the right shape); the numpy below is the reference."""
    fast = _projection.projected_data(matrix, rhs, constraints, out)
    if fast is not None:
        return fast
    n = rhs.shape[0]
    z = constraints.start(np.zeros_like(rhs))
    data = matrix.data.copy()
    b = rhs
    if len(constraints.indices):
        # The last entry of a particle listed twice wins, as in Constraints.filter.
        last = len(constraints.indices) - 1 - np.unique(constraints.indices[::-1],
                                                        return_index=True)[1]
        indices, filters = constraints.indices[last], constraints.projectors[last]
        zero = np.zeros(n, dtype=bool)
        partial = np.zeros(n, dtype=bool)
        is_zero = ~filters.reshape(-1, 9).any(axis=1)
        zero[indices[is_zero]] = True
        partial[indices[~is_zero]] = True
        cols = matrix.indices
        if pattern is not None:
            rows, diagonal_block = pattern.block_rows, pattern.diagonal_block
        else:
            rows = np.repeat(np.arange(n), np.diff(matrix.indptr))
            diagonal_block = np.flatnonzero(rows == cols)       # one per row, in row order
        # Blocks in a fully held row or column vanish (their diagonal block is
        # put back below: (I − 0) D (I − 0) = D).
        data[zero[rows] | zero[cols]] = 0.0
        full_diagonal = diagonal_block[indices[is_zero]]
        data[full_diagonal] = matrix.data[full_diagonal]
        if partial.any():
            projectors = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
            projectors[indices[~is_zero]] = filters[~is_zero]
            mixed = np.flatnonzero((partial[rows] | partial[cols])
                                   & ~(zero[rows] | zero[cols]))
            data[mixed] = projectors[rows[mixed]] @ matrix.data[mixed] \
                @ projectors[cols[mixed]]
            diagonal = diagonal_block[indices[~is_zero]]
            complement = np.eye(3) - filters[~is_zero]
            data[diagonal] += complement @ matrix.data[diagonal] @ complement
        b = constraints.filter(rhs - bsr_product(matrix, z))
    return data, b, z


def projected_rhs(matrix: sp.bsr_matrix, rhs: np.ndarray, constraints: Constraints):
    """``(b̂, z)`` of :func:`projected_data` without ``Â`` (both ``(n, 3)``):
    for a solve that reuses a factorisation of the same ``Â``."""
    if not len(constraints.indices):
        return rhs, np.zeros_like(rhs)
    fast = _projection.projected_rhs(matrix, rhs, constraints)
    if fast is not None:
        return fast
    z = constraints.start(np.zeros_like(rhs))
    return constraints.filter(rhs - bsr_product(matrix, z)), z


def bsr_product(matrix: sp.bsr_matrix, x: np.ndarray) -> np.ndarray:
    """``A x`` for a BSR matrix with 3 × 3 blocks and ``x`` ``(n, 3)``, returned
    ``(n, 3)``: scipy's compiled kernel without its per-call checks (which cost
    as much as the product at a few thousand unknowns; cf. :class:`CsrOperator`).
    Any other matrix is multiplied the ordinary way."""
    if _bsr_matvec is None or getattr(matrix, "blocksize", None) != (3, 3) \
            or matrix.format != "bsr" or matrix.data.dtype != np.float64:
        return (matrix @ x.ravel()).reshape(-1, 3)
    n_rows = matrix.shape[0] // 3
    y = np.zeros(3 * n_rows)
    _bsr_matvec(n_rows, matrix.shape[1] // 3, 3, 3, matrix.indptr, matrix.indices,
                matrix.data.ravel(), np.ascontiguousarray(x, dtype=np.float64).ravel(), y)
    return y.reshape(-1, 3)


def relative_residual(matrix, rhs: np.ndarray, constraints: Constraints,
                      dv: np.ndarray) -> float:
    """``|S(b − A Δv)| / |S b|`` (0 if ``S b`` = 0): the measure every backend reports."""
    residual = constraints.filter(rhs - bsr_product(matrix, dv))
    norm_b = float(np.linalg.norm(constraints.filter(rhs)))
    return float(np.linalg.norm(residual)) / norm_b if norm_b > 0 else 0.0


def solve_projected_direct(matrix, rhs: np.ndarray, constraints: Constraints,
                           pattern: SparsePattern | None = None) -> SolveResult:
    """Direct baseline: SuperLU (symmetric mode) of :func:`project_system`'s
    system, analysed anew at every call (design §3); ``Δv = z + S y``."""
    if not (sp.isspmatrix_bsr(matrix) and matrix.blocksize == (3, 3)):
        matrix = sp.bsr_matrix(matrix, blocksize=(3, 3))
    projected, b, z = project_system(matrix, rhs, constraints, pattern)
    lu = spla.splu(projected.tocsc(), permc_spec="MMD_AT_PLUS_A",
                   diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    dv = z + constraints.filter(lu.solve(b.ravel()).reshape(-1, 3))
    rel = relative_residual(matrix, rhs, constraints, dv)
    return SolveResult(dv=dv, iterations=0, residual=rel, converged=bool(np.isfinite(rel)))


def block_diagonal_matrix(blocks: np.ndarray) -> sp.csr_matrix:
    """Block-diagonal CSR matrix from ``(n, 3, 3)`` blocks (no sorting needed)."""
    n = len(blocks)
    indptr = np.arange(0, 9 * n + 1, 3, dtype=np.int32)
    indices = (3 * np.arange(n, dtype=np.int32)[:, None, None]
               + np.arange(3, dtype=np.int32)[None, None, :]).repeat(3, 1).ravel()
    return sp.csr_matrix((np.ascontiguousarray(blocks).ravel(), indices, indptr),
                         shape=(3 * n, 3 * n))


class CsrOperator:
    """``y = A x`` for a fixed CSR matrix without scipy's per-call dispatch.

    The iterative solvers multiply small matrices by vectors hundreds of times
    per step (CG: one product per iteration; the V-cycle: ~28 over its levels);
    ``A @ x`` spends more time in scipy's Python-level checks than in the
    product itself at these sizes (measured: 1.3 s of 2.0 s on uniform L6), so
    this calls the same compiled kernel directly.  Falls back to ``A @ x`` if
    that kernel is missing or ``x`` is not a float vector.

    Args:
        matrix: any scipy sparse matrix (converted to CSR, float64).
    """

    __slots__ = ("matrix", "shape", "_indptr", "_indices", "_data")

    def __init__(self, matrix):
        m = sp.csr_matrix(matrix, dtype=np.float64)
        m.sum_duplicates()
        self.matrix, self.shape = m, m.shape
        self._indptr, self._indices, self._data = m.indptr, m.indices, m.data

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        if _csr_matvec is None or x.ndim != 1 or x.dtype != np.float64:
            return self.matrix @ x
        y = np.zeros(self.shape[0])
        _csr_matvec(self.shape[0], self.shape[1], self._indptr, self._indices, self._data,
                    np.ascontiguousarray(x), y)
        return y
