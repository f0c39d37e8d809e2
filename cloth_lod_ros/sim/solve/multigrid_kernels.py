"""The lattice V-cycle of :mod:`~cloth_lod_ros.sim.solve.multigrid` on 3 × 3 blocks,
compiled with numba (design §3).

The reference :class:`~cloth_lod_ros.sim.solve.multigrid.VCycle` multiplies scalar
CSR matrices: its Chebyshev smoother makes two products per sweep (``A d``,
then the block-diagonal ``D⁻¹`` as a second sparse matrix) and allocates a
vector for every intermediate.  Here each level keeps ``A`` as BSR arrays and
``D⁻¹`` as ``(n, 3, 3)`` blocks, and one pass over a block row computes
``D⁻¹ (b − A x)``: the matrix is read once per sweep, indices once per 9
numbers.  The prolongation ``P ⊗ I₃`` is applied as the scalar ``P`` to
``(n, 3)`` arrays.  The top of each level's spectrum (the Chebyshev interval)
is estimated by the same power iteration, on matrix-vector products instead
of the product matrix ``D⁻¹ A`` the reference forms, and capped by the same
row-sum bound, computed block by block.

Same cycle, same smoother, same coarse operators (the Galerkin products stay
scipy's, once per rebuild): the result equals the reference's to round-off
(the sums run in another order), which for a preconditioner changes the CG
iterates by round-off only (tested).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..runtime import compiled as _compiled
from .multigrid import largest_eigenvalue

__all__ = ["BlockVCycle", "BlockOperator", "block_arrays", "inverse_blocks",
           "inverse_diagonal_blocks", "warm_up"]

_jit = _compiled._jit


@_jit
def _row_times(indptr, indices, data, x, row):
    """``(A x)_row`` as three sums, ``x`` ``(n, 3)``."""
    y0 = y1 = y2 = 0.0
    for p in range(indptr[row], indptr[row + 1]):
        c = indices[p]
        x0, x1, x2 = x[c, 0], x[c, 1], x[c, 2]
        y0 += data[p, 0, 0] * x0 + data[p, 0, 1] * x1 + data[p, 0, 2] * x2
        y1 += data[p, 1, 0] * x0 + data[p, 1, 1] * x1 + data[p, 1, 2] * x2
        y2 += data[p, 2, 0] * x0 + data[p, 2, 1] * x1 + data[p, 2, 2] * x2
    return y0, y1, y2


@_jit
def _scaled(inverse_diagonal, row, y0, y1, y2, out):
    """``out[row] = D⁻¹_row y``."""
    for a in range(3):
        out[row, a] = (inverse_diagonal[row, a, 0] * y0 + inverse_diagonal[row, a, 1] * y1
                       + inverse_diagonal[row, a, 2] * y2)


@_jit
def _scaled_residual(indptr, indices, data, inverse_diagonal, b, x, out):
    """``out = D⁻¹ (b − A x)``, all ``(n, 3)``."""
    for row in range(len(indptr) - 1):
        y0, y1, y2 = _row_times(indptr, indices, data, x, row)
        _scaled(inverse_diagonal, row, b[row, 0] - y0, b[row, 1] - y1, b[row, 2] - y2, out)


@_jit
def _scaled_product(indptr, indices, data, inverse_diagonal, x, out):
    """``out = D⁻¹ A x``, all ``(n, 3)``."""
    for row in range(len(indptr) - 1):
        y0, y1, y2 = _row_times(indptr, indices, data, x, row)
        _scaled(inverse_diagonal, row, y0, y1, y2, out)


@_jit
def _residual(indptr, indices, data, b, x, out):
    """``out = b − A x`` ``(n, 3)``."""
    for row in range(len(indptr) - 1):
        y0, y1, y2 = _row_times(indptr, indices, data, x, row)
        out[row, 0], out[row, 1], out[row, 2] = b[row, 0] - y0, b[row, 1] - y1, b[row, 2] - y2


@_jit
def _chebyshev(indptr, indices, data, inverse_diagonal, b, x, largest, lower, degree,
               from_zero):
    """Chebyshev iteration for ``A x = b`` preconditioned by ``D⁻¹`` on
    ``[lower λ, λ]`` (``λ`` = ``largest``), ``degree`` sweeps, in place on
    ``x`` ``(n, 3)`` (which is ignored and overwritten when ``from_zero``).
    The recurrence is the reference's (:meth:`VCycle._smooth`)."""
    n = x.shape[0]
    low = lower * largest
    centre, half_width = 0.5 * (largest + low), 0.5 * (largest - low)
    sigma = centre / half_width
    rho = 1.0 / sigma
    r = np.empty((n, 3))
    d = np.empty((n, 3))
    if from_zero:
        # D⁻¹ (b − A·0): no pass over A.
        for i in range(n):
            _scaled(inverse_diagonal, i, b[i, 0], b[i, 1], b[i, 2], r)
            x[i, 0] = x[i, 1] = x[i, 2] = 0.0
    else:
        _scaled_residual(indptr, indices, data, inverse_diagonal, b, x, r)
    for i in range(n):
        for a in range(3):
            d[i, a] = r[i, a] / centre
            x[i, a] += d[i, a]
    d_next = np.empty((n, 3))
    for _ in range(degree - 1):
        rho_next = 1.0 / (2.0 * sigma - rho)
        _sweep(indptr, indices, data, inverse_diagonal, r, d, d_next, x,
               rho_next * rho, 2.0 * rho_next / half_width)
        d, d_next = d_next, d
        rho = rho_next


@_jit
def _sweep(indptr, indices, data, inverse_diagonal, r, d, d_next, x, keep, push):
    """One Chebyshev sweep in one pass over A: ``r −= D⁻¹ A d``, then
    ``d' = keep · d + push · r`` and ``x += d'`` row by row (``d'`` into
    ``d_next``: the product needs the old ``d`` of every neighbour)."""
    for row in range(len(indptr) - 1):
        y0, y1, y2 = _row_times(indptr, indices, data, d, row)
        for a in range(3):
            r[row, a] -= (inverse_diagonal[row, a, 0] * y0 + inverse_diagonal[row, a, 1] * y1
                          + inverse_diagonal[row, a, 2] * y2)
            d_next[row, a] = keep * d[row, a] + push * r[row, a]
            x[row, a] += d_next[row, a]


@_jit
def _spread(indptr, indices, weights, x, out):
    """``out = P x`` for a scalar CSR ``P`` on ``(n, 3)`` arrays."""
    for i in range(len(indptr) - 1):
        y0 = y1 = y2 = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            w, j = weights[p], indices[p]
            y0 += w * x[j, 0]
            y1 += w * x[j, 1]
            y2 += w * x[j, 2]
        out[i, 0], out[i, 1], out[i, 2] = y0, y1, y2


@_jit
def _row_sum_bound(indptr, indices, data, inverse_diagonal):
    """``max_i Σ_j |(D⁻¹ A)_ij|``: the largest absolute row sum of ``D⁻¹ A``,
    block by block (a bound on its spectral radius)."""
    n = len(indptr) - 1
    largest = 0.0
    for r in range(n):
        s0 = s1 = s2 = 0.0
        for p in range(indptr[r], indptr[r + 1]):
            for b in range(3):
                v0 = (inverse_diagonal[r, 0, 0] * data[p, 0, b]
                      + inverse_diagonal[r, 0, 1] * data[p, 1, b]
                      + inverse_diagonal[r, 0, 2] * data[p, 2, b])
                v1 = (inverse_diagonal[r, 1, 0] * data[p, 0, b]
                      + inverse_diagonal[r, 1, 1] * data[p, 1, b]
                      + inverse_diagonal[r, 1, 2] * data[p, 2, b])
                v2 = (inverse_diagonal[r, 2, 0] * data[p, 0, b]
                      + inverse_diagonal[r, 2, 1] * data[p, 1, b]
                      + inverse_diagonal[r, 2, 2] * data[p, 2, b])
                s0 += abs(v0)
                s1 += abs(v1)
                s2 += abs(v2)
        largest = max(largest, s0, s1, s2)
    return largest


@_jit
def _galerkin(a_indptr, a_indices, a_data, p_indptr, p_indices, p_weights,
              r_indptr, r_indices, r_weights, n_coarse):
    """The coarse operator ``(P ⊗ I₃)ᵀ A (P ⊗ I₃)`` on blocks:
    ``C_IJ = Σ_{r, c} P_rI A_rc P_cJ`` for a block matrix A and a scalar
    prolongation P (``r_*``: Pᵀ in CSR, the rows of P by coarse node).
    Gustavson's row-by-row product with a marker per coarse column: one pass
    counts each row's blocks, the second sums them.

    Returns ``(indptr (N + 1,), indices, data (blocks, 3, 3))``, columns in
    first-touched order.
    """
    marker = np.full(n_coarse, -1, np.int64)
    counts = np.zeros(n_coarse + 1, np.int64)
    for row in range(n_coarse):
        for q in range(r_indptr[row], r_indptr[row + 1]):
            r = r_indices[q]
            for p in range(a_indptr[r], a_indptr[r + 1]):
                c = a_indices[p]
                for t in range(p_indptr[c], p_indptr[c + 1]):
                    col = p_indices[t]
                    if marker[col] != row:
                        marker[col] = row
                        counts[row + 1] += 1
    for row in range(n_coarse):
        counts[row + 1] += counts[row]
    indices = np.empty(counts[n_coarse], np.int64)
    data = np.zeros((counts[n_coarse], 3, 3))
    slot = np.full(n_coarse, -1, np.int64)
    for row in range(n_coarse):
        end = counts[row]
        for q in range(r_indptr[row], r_indptr[row + 1]):
            r, w_row = r_indices[q], r_weights[q]
            for p in range(a_indptr[r], a_indptr[r + 1]):
                c = a_indices[p]
                for t in range(p_indptr[c], p_indptr[c + 1]):
                    col = p_indices[t]
                    k = slot[col]
                    if k < counts[row]:         # first touch in this row
                        k = end
                        slot[col] = k
                        indices[k] = col
                        end += 1
                    w = w_row * p_weights[t]
                    for a in range(3):
                        for b in range(3):
                            data[k, a, b] += w * a_data[p, a, b]
    return counts, indices, data


@_jit
def _inverse_blocks(blocks, out):
    """``out[i] = blocks[i]⁻¹`` for ``(n, 3, 3)`` blocks by cofactors; returns
    the first block that is singular or not finite, or −1."""
    for i in range(blocks.shape[0]):
        m = blocks[i]
        c00 = m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]
        c01 = m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2]
        c02 = m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]
        det = m[0, 0] * c00 + m[0, 1] * c01 + m[0, 2] * c02
        if not (det != 0.0 and np.isfinite(det)):
            return i
        inv = 1.0 / det
        o = out[i]
        o[0, 0] = c00 * inv
        o[1, 0] = c01 * inv
        o[2, 0] = c02 * inv
        o[0, 1] = (m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2]) * inv
        o[1, 1] = (m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0]) * inv
        o[2, 1] = (m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1]) * inv
        o[0, 2] = (m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]) * inv
        o[1, 2] = (m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]) * inv
        o[2, 2] = (m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]) * inv
    return -1


def inverse_blocks(blocks: np.ndarray) -> np.ndarray:
    """``(n, 3, 3)`` inverses of ``(n, 3, 3)`` blocks (cofactors: a tenth of
    ``np.linalg.inv``'s time on 3 × 3 blocks, the same to round-off).

    Raises:
        numpy.linalg.LinAlgError: a block is singular or not finite.
    """
    blocks = np.ascontiguousarray(blocks, dtype=np.float64)
    out = np.empty_like(blocks)
    bad = _inverse_blocks(blocks, out)
    if bad >= 0:
        raise np.linalg.LinAlgError(f"singular 3 x 3 block at row {bad}")
    return out


def block_arrays(matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(indptr, indices, data (blocks, 3, 3))`` int64/float64 of a matrix with
    3 × 3 blocks (BSR as is; anything else converted; every diagonal block
    stored, indices in any order)."""
    if not (sp.isspmatrix_bsr(matrix) and matrix.blocksize == (3, 3)):
        matrix = sp.bsr_matrix(matrix, blocksize=(3, 3))
    return (matrix.indptr.astype(np.int64), matrix.indices.astype(np.int64),
            np.ascontiguousarray(matrix.data, dtype=np.float64))


def inverse_diagonal_blocks(indptr, indices, data) -> np.ndarray:
    """``(n, 3, 3)`` inverses of the diagonal blocks (every one stored)."""
    n = len(indptr) - 1
    rows = np.repeat(np.arange(n), np.diff(indptr))
    diagonal = np.zeros((n, 3, 3))
    on_diagonal = rows == indices
    diagonal[rows[on_diagonal]] = data[on_diagonal]
    return inverse_blocks(diagonal)


class BlockVCycle:
    """:class:`~cloth_lod_ros.sim.solve.multigrid.VCycle` on block arrays, compiled.

    Args:
        fine: ``(indptr, indices, data)`` of the fine operator (:func:`block_arrays`).
        fine_inverse_diagonal: ``(n, 3, 3)`` its diagonal blocks' inverses.
        prolongations: scalar CSR ``P_k``
            (:func:`~cloth_lod_ros.sim.solve.multigrid.lattice_hierarchy`).
        degree: Chebyshev sweeps before and after each coarse correction.
    """

    LOWER = 0.3
    POWER_ITERATIONS = 10

    def __init__(self, fine, fine_inverse_diagonal: np.ndarray,
                 prolongations: list[sp.csr_matrix], degree: int = 2):
        self.degree = int(degree)
        self.levels = []
        arrays, inverse_diagonal = fine, fine_inverse_diagonal
        for p in prolongations:
            p = sp.csr_matrix(p, dtype=np.float64)
            r = p.T.tocsr()
            self.levels.append([arrays, inverse_diagonal,
                                (p.indptr.astype(np.int64), p.indices.astype(np.int64), p.data),
                                (r.indptr.astype(np.int64), r.indices.astype(np.int64), r.data),
                                self._largest_eigenvalue(arrays, inverse_diagonal)])
            arrays = _galerkin(*arrays, *self.levels[-1][2], *self.levels[-1][3],
                               p.shape[1])
            inverse_diagonal = inverse_diagonal_blocks(*arrays)
        size = 3 * (len(arrays[0]) - 1)
        self.coarse = spla.splu(sp.bsr_matrix((arrays[2], arrays[1], arrays[0]),
                                              shape=(size, size)).tocsc())

    def _largest_eigenvalue(self, arrays, inverse_diagonal) -> float:
        """λmax of ``D⁻¹ A`` as the reference estimates it (power iteration with
        a 20 % margin, capped by the largest absolute row sum)."""
        indptr, indices, data = arrays
        bound = float(_row_sum_bound(indptr, indices, data, inverse_diagonal))
        n = len(indptr) - 1
        out = np.empty((n, 3))

        def scaled_product(x):                      # D⁻¹ A x on flat vectors
            _scaled_product(indptr, indices, data, inverse_diagonal, x.reshape(n, 3), out)
            return out.ravel().copy()

        return largest_eigenvalue(scaled_product, 3 * n, bound, self.POWER_ITERATIONS)

    def update_fine(self, fine, fine_inverse_diagonal: np.ndarray) -> None:
        """Smooth with a new fine operator, keeping the coarse ones (as the reference)."""
        if self.levels:
            self.levels[0][0] = fine
            self.levels[0][1] = fine_inverse_diagonal

    def __call__(self, residual: np.ndarray) -> np.ndarray:
        """An approximation of ``A⁻¹ residual`` (``(3n,)``), as a ``(3n,)`` array."""
        b = np.ascontiguousarray(residual, dtype=np.float64).reshape(-1, 3)
        return self._cycle(0, b).ravel()

    def _cycle(self, k: int, b: np.ndarray) -> np.ndarray:
        if k == len(self.levels):
            return self.coarse.solve(b.ravel()).reshape(-1, 3)
        (indptr, indices, data), inverse_diagonal, prolong, restrict, largest = self.levels[k]
        x = np.empty_like(b)
        _chebyshev(indptr, indices, data, inverse_diagonal, b, x, largest, self.LOWER,
                   self.degree, True)
        residual = np.empty_like(b)
        _residual(indptr, indices, data, b, x, residual)
        coarse_b = np.empty((len(restrict[0]) - 1, 3))
        _spread(*restrict, residual, coarse_b)
        correction = self._cycle(k + 1, coarse_b)
        fine_correction = np.empty_like(b)
        _spread(*prolong, correction, fine_correction)
        x += fine_correction
        _chebyshev(indptr, indices, data, inverse_diagonal, b, x, largest, self.LOWER,
                   self.degree, False)
        return x


@_jit
def _product(indptr, indices, data, x, out):
    """``out = A x`` ``(n, 3)``."""
    for row in range(len(indptr) - 1):
        out[row, 0], out[row, 1], out[row, 2] = _row_times(indptr, indices, data, x, row)


class BlockOperator:
    """``y = A x`` on flat ``(3n,)`` vectors for block arrays (:func:`block_arrays`):
    what CG multiplies by at every iteration, without a CSR copy of ``A``."""

    __slots__ = ("arrays", "shape")

    def __init__(self, arrays):
        self.arrays = arrays
        self.shape = (3 * (len(arrays[0]) - 1),) * 2

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        out = np.empty((self.shape[0] // 3, 3))
        _product(*self.arrays, np.ascontiguousarray(x, dtype=np.float64).reshape(-1, 3), out)
        return out.ravel()


def warm_up() -> None:
    """Compile or load these kernels on a two-particle system with one coarse
    node, so that a large cloth's first multigrid solve does not pay for it."""
    if not _compiled.enabled():
        return
    blocks = np.stack([np.eye(3) * 4.0, -np.eye(3), -np.eye(3), np.eye(3) * 4.0])
    fine = (np.array([0, 2, 4], np.int64), np.array([0, 1, 0, 1], np.int64), blocks)
    prolongation = sp.csr_matrix(np.array([[1.0], [0.5]]))
    cycle = BlockVCycle(fine, inverse_diagonal_blocks(*fine), [prolongation])
    cycle(np.ones(6))
    BlockOperator(fine) @ np.ones(6)
